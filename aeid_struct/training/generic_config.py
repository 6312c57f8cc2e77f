"""The settings of a generic identifier's training: ``GenericTrainConfig``, a frozen dataclass
that checks every field on construction. A module apart from the run (``training.generic``), as
``TrainConfig`` (``training.config``) is apart from ``train()``: the settings are data that the
run, its checkpoint's fingerprint and the recipe stored with the identifier all read, and
checking them needs nothing of the run.
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

from aeid_struct.training import distributed
from aeid_struct.training.checks import real
from aeid_struct.training.generic_objective import LOSSES

__all__ = ["GenericTrainConfig"]


def _positive_int(name: str, v) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or v < 1:
        raise ValueError(f"{name} must be a positive integer; got {v!r}")
    return v


@dataclass(frozen=True, kw_only=True)
class GenericTrainConfig:
    """How to train a generic identifier; validates itself.

    Attributes
    ----------
    epochs : int
        At most this many epochs.
    seconds : float or None
        At most this much wall time (None: no limit); not before ``min_epochs``.
    min_epochs : int
        The fewest epochs a wall-time budget may give, in ``[1, epochs]``.
    target_loss : float or None
        The best held-out loss expected (a run above it warns); None: no expectation.
    count : int
        Fresh training windows per epoch.
    holdout : int
        Held-out windows (fixed for the run).
    batch : int
        Windows per gradient step.
    lr : float
        Peak learning rate of Adam.
    clip : float
        Gradient-norm limit (``math.inf``: none).
    loss : {"log", "nmse"}
        ``log(1 - R^2 + eps)`` or ``1 - R^2`` per window, averaged.
    seed : int
        Seeds the weights and every epoch's records.
    checkpoint : str, os.PathLike or None
        File to checkpoint to and resume from.
    progress : bool
        Print a progress line per epoch (stderr).
    threads : int or None
        Torch threads for the run, restored after it (None: torch's setting).
    device : {"cpu", "cuda", "auto"}
        Where the encoder and the projection run, as ``TrainConfig.device`` (``"cuda"``
        without a GPU is refused); the windows are simulated on the CPU either way.
    workers : int
        Processes that simulate the fresh windows, the next epoch's while one trains
        (``training.window_pool``); 1: the training process itself. The windows, and so the
        result, do not depend on it. The workers are started by ``spawn``: the family must be
        picklable, and a script that trains with ``workers > 1`` guards its entry point
        (``if __name__ == "__main__":``), as ``multiprocessing`` asks.
    """

    epochs: int = 100
    seconds: float | None = None
    min_epochs: int = 1
    target_loss: float | None = None
    count: int = 4096
    holdout: int = 512
    batch: int = 128
    lr: float = 3e-3
    clip: float = 1.0
    loss: str = "log"
    seed: int = 0
    checkpoint: str | None = None
    progress: bool = True
    threads: int | None = None
    device: str = "cpu"
    workers: int = 1

    def __post_init__(self) -> None:
        for name in ("epochs", "count", "holdout", "batch"):
            _positive_int(name, getattr(self, name))
        if self.seconds is not None:
            real("seconds", self.seconds, "positive or None", lambda v: v > 0)
        if (not isinstance(self.min_epochs, int) or isinstance(self.min_epochs, bool)
                or not 1 <= self.min_epochs <= self.epochs):
            raise ValueError(f"min_epochs must be an integer in [1, epochs={self.epochs}]; "
                             f"got {self.min_epochs!r}")
        if self.target_loss is not None:
            real("target_loss", self.target_loss, "a finite number or None", lambda v: True)
        real("lr", self.lr, "positive and finite", lambda v: v > 0)
        if not (isinstance(self.clip, (int, float)) and not isinstance(self.clip, bool)
                and self.clip > 0):
            raise ValueError(f"clip must be positive (inf: no clipping); got {self.clip!r}")
        if self.loss not in LOSSES:
            raise ValueError(f"loss must be one of {LOSSES}; got {self.loss!r}")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer; got {self.seed!r}")
        if not isinstance(self.progress, bool):
            raise ValueError(f"progress must be True or False; got {self.progress!r}")
        if self.threads is not None:
            _positive_int("threads", self.threads)
        _positive_int("workers", self.workers)
        if self.checkpoint is not None and not isinstance(self.checkpoint, (str, os.PathLike)):
            raise ValueError(f"checkpoint must be a file path (str or Path) or None; "
                             f"got {self.checkpoint!r}")
        distributed.resolve_device(self.device)   # a bad name, or "cuda" where there is none

    def to_dict(self) -> dict:
        """The settings as JSON-ready data.

        Returns
        -------
        dict
        """
        d = dataclasses.asdict(self)
        d["checkpoint"] = None if self.checkpoint is None else str(self.checkpoint)
        return d
