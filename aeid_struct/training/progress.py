"""The training budget as the run sees it: the learning-rate schedule over the budget's
progress, the progress line with its ETA, and the under-training warning.

The budget is an epoch count or a wall time, whichever ends first; the schedule's progress is
the larger of the two fractions, and a wall-time budget cannot end a run before
``TrainConfig.min_epochs``.
"""

from __future__ import annotations

import math

from aeid_struct.training.config import TrainConfig

#: A run has stalled when the largest gradient norm of each of its last :data:`STALL_EPOCHS`
#: epochs is below this share of its first epoch's: the network's outputs have saturated (the
#: sigmoids that map them into their ranges pass no gradient), and the held-out loss stops
#: moving. Seen with a wide generic encoder at ``lr=3e-3``: the norms fell from about 4 to 0 and
#: to 5e-5 within two epochs, where a training run keeps them within a factor of ten of its
#: first epoch's.
STALL = 1e-3
#: Epochs of vanished gradients that make a stall (:data:`STALL`).
STALL_EPOCHS = 3


class UndertrainedWarning(UserWarning):
    """A training run ended worse than its settings promise: its wall-time budget fit fewer
    than ``min_epochs`` epochs (the run trained on past the budget), its best held-out loss
    stayed above ``target_loss``, or (a generic identifier's) its gradients vanished
    (:data:`STALL`). The message gives
    the epochs, the budget, the time per epoch and the losses."""


def learning_rate(peak: float, progress: float) -> float:
    """The schedule: a 2 % linear warm-up from 10 % of the peak, then a cosine decay to 1 %.

    Parameters
    ----------
    peak : float
        ``TrainConfig.lr``.
    progress : float
        The fraction of the budget spent, in ``[0, 1]``.

    Returns
    -------
    lr : float
    """
    if progress < 0.02:
        return peak * (0.1 + 0.9 * progress / 0.02)
    x = (progress - 0.02) / 0.98
    return peak * (0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * x)))


def duration(seconds: float) -> str:
    """A duration as people read it: ``"42 s"``, ``"3 min 05 s"`` or ``"1 h 02 min"``.

    Parameters
    ----------
    seconds : float
        Negative counts as 0.

    Returns
    -------
    str
    """
    seconds = max(0.0, seconds)
    if seconds < 10:
        return f"{seconds:.2g} s"
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"


def eta(epoch: int, elapsed: float, config: TrainConfig) -> float:
    """Seconds left at the mean time per epoch so far, by the loop's stopping rule: the epoch
    budget, or the time budget (but not before ``min_epochs``), whichever ends first.

    Parameters
    ----------
    epoch : int
        Epochs done.
    elapsed : float
        Seconds they took.
    config : TrainConfig
        The budget.

    Returns
    -------
    float
        Seconds.
    """
    per = elapsed / max(epoch, 1)
    left = (config.epochs - epoch) * per
    if config.seconds is not None:
        left = min(left, max(config.seconds - elapsed, (config.min_epochs - epoch) * per, 0.0))
    return left


def progress_line(epoch: int, config: TrainConfig, train: float, held: float, lr: float,
                  elapsed: float, label: str = "") -> str:
    """The progress line after ``epoch`` epochs: the budget that applies (epochs, or the wall
    time with its epoch floor), the losses, and the time to the end.

    Parameters
    ----------
    epoch : int
        Epochs done.
    config : TrainConfig
        The budget.
    train, held : float
        The epoch's training and held-out losses (Eq. 14).
    lr : float
        The last learning rate.
    elapsed : float
        Seconds since the run began.
    label : str
        The run's name, prefixed when given.

    Returns
    -------
    str
    """
    if config.seconds is None:
        budget = f"epoch {epoch:4d}/{config.epochs}"
        clock = f"{duration(elapsed)}"
    else:
        floor = f" (at least {config.min_epochs})" if config.min_epochs > 1 else ""
        budget = f"epoch {epoch:4d}{floor}"
        clock = f"{duration(elapsed)} of {duration(config.seconds)} budget"
    prefix = f"{label}: " if label else ""
    return (f"{prefix}{budget} | loss {train:.3e} | held-out {held:.3e} | lr {lr:.1e} | "
            f"{clock} | ETA {duration(eta(epoch, elapsed, config))}")


def undertrained(config: TrainConfig, history: dict, best: float) -> list[str]:
    """What the run fell short of: the epochs its wall-time budget fit against
    ``min_epochs``, and the best held-out loss against ``target_loss``.

    Parameters
    ----------
    config : TrainConfig
        The budget and the expectation.
    history : dict
        The run's per-epoch history (its ``seconds``).
    best : float
        The best held-out loss.

    Returns
    -------
    list of str
        ``UndertrainedWarning`` messages; empty when the run kept its promises.
    """
    seconds = history["seconds"]
    epochs = len(seconds)
    if not epochs:
        return []
    per = seconds[-1] / epochs
    notes = []
    if config.seconds is not None:
        # epoch i starts when epoch i - 1 ends; the budget alone runs every epoch that starts
        # before it is spent
        fit = 1 + sum(1 for t in seconds[:-1] if t < config.seconds)
        if fit < config.min_epochs:
            notes.append(
                f"the {duration(config.seconds)} training budget fit only {fit} "
                f"epoch{'s' if fit > 1 else ''} "
                f"({per:.1f} s each; a busy machine?); the run trained on to min_epochs="
                f"{config.min_epochs}, {duration(seconds[-1])} in all")
    if config.target_loss is not None and not best <= config.target_loss:
        budget = (f"the {duration(config.seconds)} budget" if config.seconds is not None
                  and epochs < config.epochs else f"an epoch budget of {config.epochs}")
        notes.append(
            f"best held-out loss {best:.3e} after {epochs} epoch{'s' if epochs > 1 else ''} "
            f"({budget}, {per:.1f} s per epoch) is above the expected "
            f"{config.target_loss:.3e}: the identifier is "
            f"under-trained; train for more epochs (an epoch budget is reproducible on a busy "
            f"machine)")
    return notes


def stalled(history: dict) -> list[str]:
    """The stall note (:data:`STALL`), or none: for runs whose loss does not fall to zero (the
    generic identifiers' ``log(1 - R^2)``, held at the records' noise); a least-squares run that
    converges towards zero loss has vanishing gradients by design (a shipped leg identifier's
    fall from 0.66 to 4e-4).

    Parameters
    ----------
    history : dict
        The run's per-epoch history (its ``grad_norm_max``).

    Returns
    -------
    list of str
        ``UndertrainedWarning`` messages (at most one).
    """
    norms = [v for v in history.get("grad_norm_max", ()) if math.isfinite(v)]
    if len(norms) <= STALL_EPOCHS or not norms[0] > 0:
        return []
    tail = norms[-STALL_EPOCHS:]
    if max(tail) >= STALL * norms[0]:
        return []
    since = next(i for i in range(len(norms), 0, -1) if norms[i - 1] >= STALL * norms[0])
    return [f"the gradients vanished after epoch {since}: the largest gradient norm of every "
            f"epoch since is below {STALL:g} of the first epoch's ({norms[0]:.3g}; last "
            f"{tail[-1]:.3g}), the network's outputs have saturated and the held-out loss stopped "
            f"moving (the run stopped at epoch {len(norms)}); train again with a lower lr (a "
            f"third of it, say)"]
