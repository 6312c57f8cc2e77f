"""The training settings: ``TrainConfig``, a frozen dataclass that checks every field on
construction (the reasons for its defaults are in docs/architecture.md, "Training").
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass

import numpy as np

from aeid_struct.identification import INITIAL_STATES
from aeid_struct.training.checks import real
from aeid_struct.training.datasets import grids
from aeid_struct.training.distributed import resolve_device
from aeid_struct.training.excitation import EXCITATIONS


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """How to train an identifier (paper Sec. III-IV); validates itself.

    Attributes
    ----------
    dt : float or tuple of float
        Sample time (s); a tuple, one entry per record, for a several-record structure.
    steps : int or tuple of int
        Samples per record, each ``>= 2`` (``grids``); a tuple like ``dt``.
    count : int
        Simulated records (paper: 10^4).
    holdout : float
        Share of them held out, in ``(0, 1)`` (paper: 20 %); the weights with the lowest
        held-out loss are returned.
    epochs : int
        At most this many epochs.
    seconds : float or None
        At most this much wall time in the epochs (None: no limit); it cannot end the run
        before ``min_epochs`` epochs. Simulating the ``count`` records and calibrating come
        before the epochs and are not counted: the whole call takes longer.
    min_epochs : int
        The fewest epochs a wall-time budget may give, in ``[1, epochs]``. Why: the time an
        epoch takes depends on the machine's load; with a floor the run trains on past
        ``seconds`` (the learning-rate schedule stretches to the floor) and warns.
    target_loss : float or None
        The best held-out loss (Eq. 14) the run is expected to reach; a run that ends above it
        warns (``UndertrainedWarning``). None: no expectation.
    batch : int
        Records per gradient step.
    lr : float
        Peak learning rate of Adam (short warm-up, cosine decay over the budget).
    clip : float
        Gradient-norm limit (``math.inf``: no clipping); the paper reports exploding gradients
        with CCF.
    gamma : float or None
        Weight of the stationary-value term of Eq. 14; None: 1 for step records (the paper), 0
        for other excitations, whose response stays far below the DC gain the term compares.
    noise : float or (lo, hi)
        Measurement noise level (std relative to ``max|y|``), or a range drawn per record and
        epoch.
    excitation : str
        Input kind, one of ``EXCITATIONS``; ``"step"`` is the paper's.
    seed : int
        Seeds the data, the initial weights and the shuffling.
    warmup : int
        Samples each simulated record runs before it begins (records start mid-motion, as
        windows of a running system do); 0 = from rest (the paper).
    initial : {"rest", "fitted"}
        The decoder's initial state: zero (the paper) or least squares per record
        (``simulation.initial_state``), needed when ``warmup > 0``.
    fresh : bool
        Draw new training systems, excitations and initial states every epoch (the held-out
        records stay fixed). Why: an identifier of arbitrary inputs overfits a fixed set, and
        the exact simulator makes new records cheap.
    supervised : float
        Weight (>= 0) of a parameter-space term added to Eq. 14: the mean squared error between
        the encoder's standardised outputs and the true systems' (``Structure.theta_of``). It
        decays linearly to 0 over the run, so the run ends on the paper's loss alone. 0: the
        paper's unsupervised training.
    checkpoint : str, os.PathLike or None
        File to checkpoint to and resume from (None: no checkpoints).
    progress : bool
        Print a progress line (to stderr).
    threads : int or None
        Torch threads for the run, restored after it (None: torch's setting).
    device : {"cpu", "cuda", "auto"}
        Where the encoder, the decoder and the batches run: ``"auto"`` is CUDA when torch finds
        a GPU, else the CPU; ``"cuda"`` without one is refused. Under ``torchrun`` each process
        takes the GPU of its ``LOCAL_RANK`` (``training.distributed``). The records are
        simulated on the CPU either way, and every random stream stays there, so a run's
        records and noise do not depend on the device.
    """

    dt: float | tuple[float, ...]
    steps: int | tuple[int, ...]
    count: int = 10_000
    holdout: float = 0.2
    epochs: int = 200
    seconds: float | None = None
    min_epochs: int = 1
    target_loss: float | None = None
    batch: int = 256
    lr: float = 3e-3
    clip: float = 1.0
    gamma: float | None = None
    noise: float | tuple[float, float] = 0.0
    excitation: str = "step"
    seed: int = 0
    warmup: int = 0
    initial: str = "rest"
    fresh: bool = False
    supervised: float = 0.0
    checkpoint: str | None = None
    progress: bool = True
    threads: int | None = None
    device: str = "cpu"

    def __post_init__(self) -> None:
        grids(self.steps, self.dt)
        for name in ("dt", "steps"):
            if isinstance(getattr(self, name), list):
                object.__setattr__(self, name, tuple(getattr(self, name)))
        self._check_budget()
        self._check_optimiser()
        self._check_data()

    def _check_budget(self) -> None:
        """``count``, ``holdout``, ``epochs``, ``seconds``, ``min_epochs``, ``target_loss``,
        ``threads``."""
        for name in ("count", "epochs", "batch"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name} must be a positive integer; got {v!r}")
        real("holdout", self.holdout, "in (0, 1)", lambda v: 0.0 < v < 1.0)
        if int(self.count * self.holdout) < 1 or self.count - int(self.count * self.holdout) < 1:
            raise ValueError(f"count={self.count} is too small to hold out {self.holdout:.0%}")
        if self.seconds is not None:
            real("seconds", self.seconds, "positive or None", lambda v: v > 0)
        if (not isinstance(self.min_epochs, int) or isinstance(self.min_epochs, bool)
                or not 1 <= self.min_epochs <= self.epochs):
            raise ValueError(f"min_epochs must be an integer in [1, epochs={self.epochs}]; "
                             f"got {self.min_epochs!r}")
        if self.threads is not None and (not isinstance(self.threads, int)
                                         or isinstance(self.threads, bool) or self.threads < 1):
            raise ValueError(f"threads must be a positive integer or None; got {self.threads!r}")
        if self.target_loss is not None:
            real("target_loss", self.target_loss, "a positive finite held-out loss or None",
                 lambda v: v > 0)

    def _check_optimiser(self) -> None:
        """``lr``, ``clip``, ``supervised``, ``gamma``, ``seed``, the switches, ``device``,
        ``checkpoint``."""
        real("lr", self.lr, "positive and finite", lambda v: v > 0)
        # clip = inf is "no clipping" (notebook 03 measures gradient norms without it)
        if not (isinstance(self.clip, (int, float)) and not isinstance(self.clip, bool)
                and self.clip > 0):
            raise ValueError(f"clip must be positive (inf: no clipping); got {self.clip!r}")
        real("supervised", self.supervised, "a finite weight >= 0", lambda v: v >= 0)
        if self.gamma is not None:
            real("gamma", self.gamma, ">= 0 or None", lambda v: v >= 0)
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer; got {self.seed!r}")
        for name in ("fresh", "progress"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False; got {getattr(self, name)!r}")
        resolve_device(self.device)     # a bad name, or "cuda" where there is none
        if self.checkpoint is not None and not isinstance(self.checkpoint, (str, os.PathLike)):
            raise ValueError(f"checkpoint must be a file path (str or Path) or None; "
                             f"got {self.checkpoint!r}")

    def _check_data(self) -> None:
        """``noise``, ``excitation``, ``warmup``, ``initial``."""
        noise, what = self.noise, "a finite level >= 0 or a (lo, hi) range"
        if isinstance(noise, (tuple, list)):
            if len(noise) != 2:
                raise ValueError(f"noise must be {what}; got {noise!r}")
            lo, hi = (real("noise", v, what, lambda v: v >= 0) for v in noise)
            if lo > hi:
                raise ValueError(f"noise must be {what} with lo <= hi; got {noise!r}")
            object.__setattr__(self, "noise", (lo, hi))
        else:
            real("noise", noise, what, lambda v: v >= 0)
        if self.excitation not in EXCITATIONS:
            raise ValueError(f"excitation must be one of {EXCITATIONS}; got {self.excitation!r}")
        if not isinstance(self.warmup, int) or isinstance(self.warmup, bool) or self.warmup < 0:
            raise ValueError(f"warmup must be a non-negative integer; got {self.warmup!r}")
        if self.initial not in INITIAL_STATES:
            raise ValueError(f"initial must be one of {INITIAL_STATES}; got {self.initial!r}")
        if self.warmup and self.initial == "rest":
            raise ValueError("records that start mid-motion (warmup > 0) need initial='fitted': "
                             "a decoder from rest cannot explain their free response")

    @property
    def stationary_weight(self) -> float:
        """``gamma`` as used: given, or 1 for step records and 0 otherwise."""
        if self.gamma is not None:
            return float(self.gamma)
        return 1.0 if self.excitation == "step" else 0.0

    @property
    def grids(self) -> tuple[tuple[int, float], ...]:
        """``(steps, dt)`` of each record (``training.grids``)."""
        return grids(self.steps, self.dt)

    @property
    def noise_range(self) -> tuple[float, float]:
        """``(lo, hi)`` of the noise level (``lo == hi`` for a fixed level)."""
        if np.ndim(self.noise) == 0:
            return float(self.noise), float(self.noise)
        return float(self.noise[0]), float(self.noise[1])


def config_dict(config: TrainConfig) -> dict:
    """The settings as JSON-ready data (``ident.meta["train"]["config"]``, the checkpoint's
    fingerprint); ``noise`` as a ``[lo, hi]`` list.

    Parameters
    ----------
    config : TrainConfig

    Returns
    -------
    dict
        Field name -> value.
    """
    d = dataclasses.asdict(config)
    d["noise"] = list(config.noise_range)
    return d
