r"""Training of a generic identifier (:class:`~aeid_struct.generic.GenericIdentifier`) by variable
projection: the encoder gives the poles, least squares the rest, the residual is the loss.

This module is the run. The loss of a window is ``training.generic_objective``'s (``1 - R^2``
under the encoder's poles with the rest of the model projected, as ``log(e + eps)`` or ``e``) and
the settings are ``training.generic_config``'s (``GenericTrainConfig``), both re-exported here.
Fresh records from the family every epoch (the exact simulator makes them cheap, and a fixed set
is overfitted); a fixed held-out set picks the weights. Adam with the warm-up and cosine decay of
:func:`~aeid_struct.training.progress.learning_rate` over an epoch or wall-time budget, gradient
clipping, non-finite batches skipped and counted, a checkpoint every epoch (a killed run resumes
bit-identically: every epoch's windows come in blocks of ``distributed.BLOCK``, each from a
generator seeded by ``(seed, epoch + 1, block)``: ``distributed.block_windows``).

Launched by ``torchrun``, the run is data-parallel (``training.distributed``, as ``train()``):
``batch`` is the global batch, each process simulates only the blocks that its share of every
batch falls in and computes the loss on that share through ``DistributedDataParallel``; the
held-out set is the same on every process, each evaluates its share and the per-window losses are
gathered, so the loss and the median fit are the single process's. Rank 0 alone writes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import pickle
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from aeid_struct.generic import GenericConfig, GenericIdentifier, normalise_windows
from aeid_struct.training import checkpoints, distributed
from aeid_struct.training.generic_config import GenericTrainConfig as GenericTrainConfig
from aeid_struct.training.generic_family import GenericFamily
from aeid_struct.training.generic_objective import EPS, reduce_loss
from aeid_struct.training.generic_objective import LOSSES as LOSSES
from aeid_struct.training.generic_objective import window_loss as window_loss
from aeid_struct.training.progress import (
    UndertrainedWarning,
    learning_rate,
    progress_line,
    stalled,
    undertrained,
)
from aeid_struct.training.window_pool import WindowPool

__all__ = ["GenericTrainConfig", "train_generic", "window_loss"]


def _windows(family, count: int, steps: int, rng: np.random.Generator):
    """``count`` normalised windows of the family as float64 tensors (constant ones dropped)."""
    rec = family.records(count, steps, rng)
    y, u, ok = normalise_windows(torch.as_tensor(np.asarray(rec.y, dtype=np.float64)),
                                 torch.as_tensor(np.asarray(rec.u, dtype=np.float64)))
    return y[ok], u[ok]


def _family_dict(family) -> dict:
    """The family's settings as JSON data (the recipe, the checkpoint's fingerprint)."""
    fields = (dataclasses.asdict(family) if dataclasses.is_dataclass(family)
              else {k: repr(v) for k, v in sorted(vars(family).items())})
    return json.loads(json.dumps({"type": type(family).__name__, **fields}, default=str))


def _check_shares(train: GenericTrainConfig, world_size: int) -> None:
    """Every process gets at least one window of every global batch (DDP needs each process's
    backward), the last, shorter batch of an epoch included."""
    smallest = min(train.batch, train.count, train.count % train.batch or train.batch)
    if smallest < world_size:
        raise ValueError(f"batch={train.batch} with count={train.count} gives a batch of "
                         f"{smallest} window(s), fewer than the {world_size} processes: every "
                         f"process needs a share of every batch; choose batch and count so that "
                         f"each batch has >= {world_size} windows")


@dataclass
class _Run:
    config: GenericConfig
    train: GenericTrainConfig
    family: object
    ident: GenericIdentifier
    opt: torch.optim.Adam
    generators: dict
    state: dict
    held: tuple
    ckpt: Path | None
    fingerprint: str
    label: str
    ctx: distributed.Context    # the process's place in a data-parallel run (or one process)
    model: torch.nn.Module      # the encoder, in DistributedDataParallel when distributed
    pool: WindowPool | None = None   # simulates the fresh windows when train.workers > 1


def train_generic(config: GenericConfig, train: GenericTrainConfig, *, family=None,
                  on_epoch: Callable[[int, dict], None] | None = None,
                  meta: dict | None = None,
                  init: GenericIdentifier | None = None) -> GenericIdentifier:
    """Train a generic identifier of ``config.order`` on records of ``family``.

    Parameters
    ----------
    config : GenericConfig
        The identifier's order, window, band and encoder.
    train : GenericTrainConfig
        The budget and the optimiser.
    family : object, optional
        Gives ``records(count, steps, rng)`` with ``y`` and ``u`` of shape ``(count, steps)``
        (normalised time) and has ``order == config.order``;
        ``GenericFamily(order=config.order, band=config.band)`` when None.
    on_epoch : callable (epochs done, history) -> None, optional
        Called after each epoch, once its checkpoint is written (an exception propagates; the
        run resumes from the checkpoint).
    meta : dict, optional
        Provenance stored with the identifier (JSON-ready); its ``name`` labels the progress.
    init : GenericIdentifier, optional
        Start from its weights instead of fresh ones (fine-tuning); its configuration must be
        ``config``. The checkpoint's fingerprint holds a hash of them, so a run resumes only
        from the weights it started from.

    Returns
    -------
    GenericIdentifier
        The weights with the lowest held-out loss; ``meta["history"]`` per epoch (the keys of
        :func:`~aeid_struct.training.train`'s history and ``holdout_fit``, the median held-out
        fit in %), ``meta["train"]`` the recipe: every setting, the family, epochs, seconds,
        the best held-out loss and fit.

    Raises
    ------
    ValueError
        A wrong argument, or a checkpoint that cannot be resumed (naming its path).
    RuntimeError
        Under ``torchrun``: another process failed (a collective failed); the message names
        this process and how to resume from the checkpoint.

    Notes
    -----
    Launched by ``torchrun`` (one node or several), the run is data-parallel as
    :func:`~aeid_struct.training.train`'s: ``train.batch`` is the global batch, the result
    depends on it and on the seed, not on the number of processes (up to float32 summation
    order), ``meta["train"]`` records ``world_size``, ``backend`` and ``device``, every process
    returns the identifier and rank 0 alone writes the checkpoint and prints progress.

    Warns
    -----
    UndertrainedWarning
        The budget fit fewer than ``min_epochs`` epochs, the best held-out loss is above
        ``target_loss``, or the gradients vanished (``training.progress.STALL``: the network's
        outputs saturated, as a wide encoder's do at too high a learning rate; the run stops
        there instead of spending its budget on weights that no longer move).
    """
    if not isinstance(config, GenericConfig):
        raise ValueError(f"config must be a GenericConfig; got {type(config).__name__}")
    if not isinstance(train, GenericTrainConfig):
        raise ValueError(f"train must be a GenericTrainConfig; got {type(train).__name__}")
    if family is None:
        family = GenericFamily(order=config.order, band=config.band)
    if not callable(getattr(family, "records", None)) or getattr(family, "order", None) \
            != config.order:
        raise ValueError(f"family must have records(count, steps, rng) and order "
                         f"{config.order}; got {type(family).__name__} of order "
                         f"{getattr(family, 'order', None)!r}")
    if init is not None and (not isinstance(init, GenericIdentifier) or init.config != config):
        raise ValueError(f"init must be a GenericIdentifier of the configuration trained "
                         f"({config!r}); got {getattr(init, 'config', type(init).__name__)!r}")
    threads = torch.get_num_threads()
    if train.threads is not None:
        torch.set_num_threads(train.threads)
    ctx = distributed.setup(train.device)
    try:
        return _train(config, train, family, on_epoch, dict(meta or {}), ctx, init)
    except Exception as err:
        if ctx.distributed and distributed.collective_error(err):
            raise distributed.failure(err, ctx, train.checkpoint) from err
        raise
    finally:
        torch.set_num_threads(threads)     # the setting is the run's, not the process's


def _weights_hash(ident: GenericIdentifier) -> str:
    """SHA-256 of an identifier's encoder weights (names, shapes and values)."""
    h = hashlib.sha256()
    for name, value in ident.encoder.state_dict().items():
        h.update(name.encode())
        h.update(str(tuple(value.shape)).encode())
        h.update(value.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def _setup(config, train, family, meta, ctx: distributed.Context, init=None) -> _Run:
    """The identifier (on the run's device; ``init``'s weights where given), Adam, the held-out
    windows (the same on every process) and the state, resumed where there is a checkpoint
    (every process reads it)."""
    torch.manual_seed(train.seed)
    ident = GenericIdentifier(config, meta=meta)
    if init is not None:
        ident.encoder.load_state_dict(init.encoder.state_dict())
    ident.encoder.to(ctx.device)             # in place: the parameters stay the same objects
    opt = torch.optim.Adam(list(ident.encoder.parameters()), lr=train.lr)
    generators = {"generator": torch.Generator().manual_seed(train.seed + 2)}
    held = _windows(family, train.holdout, config.window, np.random.default_rng([train.seed, 0]))
    recipe = {k: v for k, v in train.to_dict().items()
              if k not in ("epochs", "seconds", "min_epochs", "target_loss", "checkpoint",
                           "progress", "threads", "device", "workers")}
    fingerprint = json.dumps({"config": config.to_dict(), "train": recipe,
                              "family": _family_dict(family),
                              **({"init": _weights_hash(init)} if init is not None else {})},
                             sort_keys=True)
    state = {"epoch": 0, "elapsed": 0.0, "best": math.inf, "best_state": None,
             "history": {key: [] for key in (*checkpoints.HISTORY, "holdout_fit")}}
    ckpt = Path(train.checkpoint) if train.checkpoint else None
    if ckpt is not None:
        if ctx.writer:
            checkpoints.remove_leftover(ckpt)
        ctx.barrier()                        # no process reads while rank 0 tidies up
        if ckpt.exists():
            state = checkpoints.resume(ckpt, fingerprint, ident, opt, generators)
            state["history"].setdefault("holdout_fit", [math.nan] * state["epoch"])
    return _Run(config=config, train=train, family=family, ident=ident, opt=opt,
                generators=generators, state=state, held=tuple(t.to(ctx.device) for t in held),
                ckpt=ckpt, fingerprint=fingerprint, label=str(meta.get("name", "")), ctx=ctx,
                model=ctx.wrap(ident.encoder))


def _train(config, train, family, on_epoch, meta, ctx, init=None) -> GenericIdentifier:
    _check_shares(train, ctx.world_size)
    run = _setup(config, train, family, meta, ctx, init)
    if train.workers > 1:
        try:    # the workers receive the family pickled: a family they cannot is refused here
            pickle.dumps(family)
        except Exception as err:
            raise ValueError(f"family must be picklable for workers={train.workers} (the worker "
                             f"processes receive it); {type(family).__name__} is not: {err}; "
                             f"use workers=1") from None
        run.pool = WindowPool(family, train.seed, train.count, config.window, train.workers)
    try:
        return _loop(run, on_epoch)
    finally:
        if run.pool is not None:
            run.pool.close()


def _loop(run: _Run, on_epoch) -> GenericIdentifier:
    """The epochs until the budget is spent or the run stalls (``training.progress.stalled``),
    then the best weights (:func:`_finish`)."""
    train, ctx = run.train, run.ctx
    tty = sys.stderr.isatty()
    start = time.perf_counter() - run.state["elapsed"]
    while run.state["epoch"] < train.epochs:
        if (train.seconds is not None and ctx.clock(start) >= train.seconds
                and run.state["epoch"] >= train.min_epochs):
            break
        loss, lr, norms, skipped = _epoch(run, start)
        held, fit = _holdout(run)
        _record(run, loss, held, fit, lr, norms, skipped, ctx.clock(start))
        hist = run.state["history"]
        if train.progress and ctx.writer:
            line = progress_line(run.state["epoch"], train, loss, held, lr, run.state["elapsed"],
                                 run.label) + f" | held-out fit {fit:.1f} %"
            sys.stderr.write(("\r" if tty else "") + line + ("\033[K" if tty else "\n"))
            sys.stderr.flush()
        if on_epoch is not None:
            on_epoch(run.state["epoch"], hist)
        if stalled(hist):   # weights that no longer move: the rest of the budget is lost time
            break           # (every process holds the same norms, so all stop together)
    if train.progress and tty and ctx.writer:
        sys.stderr.write("\n")
    return _finish(run)


def _progress(train: GenericTrainConfig, done: float, start: float,
              ctx: distributed.Context) -> float:
    """The share of the budget spent after ``done`` epochs (epochs, or wall time by rank 0's
    clock stretched to the epoch floor), as :func:`~aeid_struct.training.train` counts it."""
    progress = done / train.epochs
    if train.seconds is not None:
        progress = max(progress, min(ctx.clock(start) / train.seconds,
                                     done / train.min_epochs))
    return progress


def _my_windows(run: _Run):
    """This process's share of every global batch of the epoch's fresh windows, on the run's
    device: ``y``, ``u``, ``ok`` (``distributed.block_windows``) and each batch's slice."""
    train, ctx = run.train, run.ctx
    rows, slices = [], []
    for lo in range(0, train.count, train.batch):
        batch = np.arange(lo, min(lo + train.batch, train.count))[ctx.share(
            min(train.batch, train.count - lo))]
        slices.append(slice(sum(len(r) for r in rows), sum(len(r) for r in rows) + len(batch)))
        rows.append(batch)
    y, u, ok = distributed.block_windows(run.family, train.seed, train.count, run.config.window,
                                         run.state["epoch"], np.concatenate(rows), run.pool)
    return y.to(ctx.device), u.to(ctx.device), ok.to(ctx.device), slices


def _epoch(run: _Run, start: float):
    """One epoch on fresh windows: mean loss, last learning rate, gradient norms, skipped.

    A process's loss is the sum of its share's window terms divided by the global batch's
    windows and multiplied by the processes (DDP averages the gradients): the global batch's
    mean, whatever the shares; constant windows weigh nothing.
    """
    train, epoch, ctx = run.train, run.state["epoch"], run.ctx
    y, u, ok, slices = _my_windows(run)
    params = list(run.ident.encoder.parameters())
    running, done, skipped, norms, lr = 0.0, 0, 0, [], train.lr
    encoder, run.ident.encoder = run.ident.encoder, run.model     # DDP's forward, when wrapped
    run.ident.encoder.train()
    try:
        for j, sl in enumerate(slices):
            lr = learning_rate(train.lr, min(_progress(train, epoch + j / len(slices), start,
                                                       ctx), 1.0))
            for group in run.opt.param_groups:
                group["lr"] = lr
            e = window_loss(run.ident, y[sl], u[sl])
            terms = torch.log(e + EPS) if train.loss == "log" else e
            local = torch.where(ok[sl], terms, torch.zeros_like(terms)).sum()
            total, n = ctx.sum([float(local.detach()), int(ok[sl].sum())])
            run.opt.zero_grad(set_to_none=True)
            value = total / n if n else math.nan
            if not math.isfinite(value):
                skipped += 1
                continue
            norm = distributed.gradient_step(run.opt, local * (ctx.world_size / n), params,
                                             train.clip)
            if norm is None:
                skipped += 1
                continue
            norms.append(norm)
            running += value
            done += 1
    finally:
        run.ident.encoder = encoder
    return running / max(done, 1), lr, norms, skipped


def _holdout(run: _Run) -> tuple[float, float]:
    """The held-out loss and median fit (%, ``100 (1 - sqrt(e))``); data-parallel, each process
    evaluates its share and the per-window ``e`` are gathered (summed into zeros)."""
    y, u = run.held
    ctx, mine = run.ctx, run.ctx.share(len(run.held[0]))
    y, u = y[mine], u[mine]
    run.ident.encoder.eval()
    with torch.no_grad():
        e = torch.cat([window_loss(run.ident, y[i: i + 512], u[i: i + 512])
                       for i in range(0, len(y), 512)]).cpu()
    run.ident.encoder.train()
    if ctx.distributed:
        whole = torch.zeros(len(run.held[0]), dtype=torch.float64)
        whole[mine] = e
        e = torch.tensor(ctx.sum(whole.tolist()), dtype=torch.float64)
    fit = 100.0 * (1.0 - torch.sqrt(e.clamp_min(0.0)))
    return float(reduce_loss(e, run.train.loss)), float(torch.nanmedian(fit))


def _record(run: _Run, loss, held, fit, lr, norms, skipped, elapsed) -> None:
    """After an epoch: the history, the best weights so far, the checkpoint (rank 0 writes)."""
    state = run.state
    hist = state["history"]
    for key, value in (("train_loss", loss), ("holdout_loss", held), ("lr", lr),
                       ("seconds", elapsed),
                       ("grad_norm_median", float(np.median(norms)) if norms else math.nan),
                       ("grad_norm_max", max(norms) if norms else math.nan),
                       ("skipped", skipped), ("holdout_fit", fit)):
        hist[key].append(value)
    checkpoints.end_epoch(run, state, held, elapsed)


def _finish(run: _Run) -> GenericIdentifier:
    """Warn if under-trained (rank 0), load the best weights on the CPU, record the history and
    the recipe."""
    state, ident, train, ctx = run.state, run.ident, run.train, run.ctx
    notes = undertrained(train, state["history"], state["best"]) + stalled(state["history"])
    for note in notes if ctx.writer else ():
        warnings.warn(f"{run.label or 'training'}: {note}", UndertrainedWarning, stacklevel=3)
    ident.encoder.to("cpu")                  # identification runs on the CPU
    if state["best_state"] is not None:
        ident.encoder.load_state_dict(state["best_state"])
    ident.encoder.eval()
    hist = state["history"]
    best = int(np.argmin(hist["holdout_loss"])) if hist["holdout_loss"] else 0
    ident.meta["history"] = hist
    ident.meta["train"] = {
        "config": ident.config.to_dict(), "settings": train.to_dict(),
        "family": _family_dict(run.family), "seed": train.seed, "epochs": state["epoch"],
        "seconds": round(state["elapsed"], 2), "best_epoch": best + 1,
        "best_holdout_loss": state["best"],
        "holdout_fit_median": hist["holdout_fit"][best] if hist["holdout_fit"] else math.nan,
        "windows_per_epoch": train.count, "warnings": notes,
        "world_size": ctx.world_size, "backend": ctx.backend, "device": str(ctx.device),
        "init": json.loads(run.fingerprint).get("init"),
    }
    return ident
