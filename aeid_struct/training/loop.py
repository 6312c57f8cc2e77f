"""Unsupervised training of an identifier (paper Sec. III): encoder -> structure -> decoder.

The loss is Eq. 14 on records normalised by Eq. 15: the mean squared error between the measured
record and the decoded response of the identified system (exact FOH simulation, Eq. 10-13), plus
``gamma`` times the squared error of the normalised stationary value (Eq. 4). No parameter labels
enter the loss; the true systems of the simulated family are used only (i) for the stationary
value ``y_inf`` of Eq. 14, as in the paper, and (ii) once, before training, to standardise the
network's output (the median and spread of the family's raw parameters), which is knowledge of the
parameter ranges, not of any record's label.

Choices the paper leaves open, and ours:
- 80/20 split of the simulated records (paper Sec. IV); the held-out loss is evaluated every
  epoch and the weights with the lowest held-out loss are returned.
- Adam with a short warm-up and a cosine learning-rate decay over the budget, which is an epoch
  count or a wall-time limit, whichever ends first (progress = the larger of the two fractions).
- Gradient-norm clipping: the paper reports exploding gradients with CCF; clipping keeps one bad
  batch (a nearly unstable estimate of an unstable system) from wrecking the weights
  (``clip=math.inf`` turns it off, to observe the explosion). A batch whose loss or gradient is
  not finite (a decoded response that overflowed) is skipped rather than stepped on, and
  counted. The history records, per epoch, the median and largest gradient norm before
  clipping and the number of skipped batches: the training-stability evidence.
- float32 by default (the decoder is exact to float32 precision, far below the targets).
- Noise: ``noise`` adds white measurement noise with a std drawn per record and per epoch from a
  range (relative to max|y|), so a noise-trained identifier sees fresh noise every epoch.
- Several records (a ``Physical`` structure of ``R`` subsystems, e.g. the joint leg): ``dt`` and
  ``steps`` are tuples, one per record; the loss is the mean of Eq. 14 over the records, each
  normalised by its own ``y_bar``, so that no record dominates by its magnitude.
- Records mid-motion (``warmup > 0``, windows cut from a running system): the decoder cannot
  assume rest, so with ``initial="fitted"`` it fits the initial state by linear least squares
  (``decoder.initial_state``; the free response is linear in ``x0``) and the loss compares the
  record with the response from that state. The encoder still outputs only the structure's
  parameters: ``x0`` is profiled out, exactly for noise-free windows.
- Checkpoints: every epoch, atomically (written to ``<path>.tmp``, flushed to disk with
  ``fsync``, then renamed over the previous one; a ``.tmp`` left by a kill mid-write is removed
  at the next start). A checkpoint holds tensors and numbers only and is read with
  ``weights_only=True``, so a file that asks for code is refused, never run; a file that is
  truncated, not a checkpoint, or written for another setup is refused with its path and how to
  start over. A killed run started again with the same checkpoint path resumes at the epoch
  after the last checkpoint and ends bit-identical to an uninterrupted run: every random
  stream is in the checkpoint (torch's global generator, the shuffling and training-noise
  generator, the held-out noise generator) or derived from ``(seed, epoch)`` (the fresh
  records of ``TrainConfig.fresh``).
- Budget: ``epochs``, or a wall time ``seconds`` that cannot end the run before ``min_epochs``
  (on a busy machine an epoch can take 10-30 times longer, and a time budget alone then trains
  an identifier that is silently far worse). A run that the time budget would have cut short,
  or that ends above its ``target_loss``, warns (``UndertrainedWarning``) with the numbers.
"""

from __future__ import annotations

import dataclasses
import math
import os
import pickle
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from aeid_struct.encoder import Encoder, EncoderConfig
from aeid_struct.identification.identifier import (
    FLAG_FALSE_RATE,
    INITIAL_STATES,
    Identifier,
    _excess,
)
from aeid_struct.simulation.foh import (
    _free_fit,
    _loss,
    _record_scale,
    _simulate,
    _stationary_value,
    stationary_value,
)
from aeid_struct.structures import Physical, Structure
from aeid_struct.training.families import EXCITATIONS, Records, records


class UndertrainedWarning(UserWarning):
    """A training run ended worse than its settings promise: its wall-time budget fit fewer
    than ``min_epochs`` epochs (the run trained on past the budget), or its best held-out loss
    stayed above ``target_loss``. The message gives the epochs, the budget, the time per epoch
    and the losses."""



def _real(name: str, value, what: str, test: Callable[[float], bool]) -> float:
    """``value`` as a float when it is a finite real number passing ``test``; else a ValueError
    "<name> must be <what>; got <value>" (strings, bools, NaN and inf included)."""
    ok = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
    v = float(value) if ok else math.nan
    if not (math.isfinite(v) and test(v)):
        raise ValueError(f"{name} must be {what}; got {value!r}")
    return v


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """How to train; validates itself.

    Attributes:
        dt, steps: the record format (sample time, samples); tuples (one entry per record) for
            a several-record structure.
        count: simulated records (paper: 10^4), ``holdout`` of them held out (paper: 20 %).
        epochs: at most this many epochs; ``seconds``: at most this much wall time (None = no
            limit), which cannot end the run before ``min_epochs`` epochs.
        min_epochs: the fewest epochs a wall-time budget may give (default 1). Why: the time
            an epoch takes depends on the machine's load, and a busy machine fit 14 epochs
            where a quiet one fit 171, a 14x worse identifier; with a floor the run trains on
            past ``seconds`` (the learning-rate schedule stretches to the floor) and warns.
        target_loss: the best held-out loss (Eq. 14) the run is expected to reach; a run that
            ends above it warns (``UndertrainedWarning``). None: no expectation.
        batch: records per gradient step; lr: peak learning rate; clip: gradient-norm limit.
        gamma: weight of the stationary-value term of Eq. 14; None (default): 1 for step
            records (the paper), 0 for other excitations. Why: the term compares DC gains in
            units of the record's ``y_bar``, and for a PRBS or a multisine, whose response stays
            far below the DC gain, it swamps the record's own error (measured on a first-order
            family with mixed excitations: held-out loss 0.81 with gamma = 1, 0.19 with 0).
        noise: measurement noise level, or a (lo, hi) range drawn per record and epoch.
        excitation: input kind (data.EXCITATIONS); "step" is the paper's.
        seed: seeds the data, the initial weights and the shuffling.
        warmup: samples each simulated record runs before it begins (records start
            mid-motion, as windows of a running system do); 0 = from rest (the paper).
        initial: the decoder's initial state: ``"rest"`` (zero, the paper) or ``"fitted"``
            (least squares per record, ``decoder.initial_state``), needed when ``warmup > 0``.
        fresh: draw new training systems, excitations and initial states every epoch (the
            held-out records stay fixed). Why: an identifier of arbitrary inputs overfits a
            fixed set -- measured on the stable leg's mid-motion windows with mixed excitation,
            8,000 fixed records gave a training loss of 0.018 against 0.062 held out -- and the
            exact simulator makes new records cheap.
        supervised: weight of a parameter-space term added to Eq. 14: the mean squared error
            between the encoder's standardised outputs and the true systems' standardised raw
            parameters (``Structure.theta_of``; the simulator knows them). It decays linearly
            to 0 over the run, so the run ends on the paper's unsupervised loss alone, and the
            held-out loss that picks the weights is Eq. 14 only. 0 (default): the paper's
            training. Why one would: with arbitrary inputs the output-error loss of Eq. 14 is
            far from convex in the parameters (a resonance matched at the wrong frequency is a
            local minimum), and the parameter term pulls the outputs towards the true
            parameters (1.5x closer on a first-order family, a test). Measured where it was
            meant to help, it did not: on the stable leg's mixed-input windows (60 epochs,
            fresh records) the median k error was 11 % without it and 14 % with weight 1; no
            shipped identifier uses it.
        checkpoint: file to checkpoint to and resume from (None = no checkpoints).
        progress: print a progress line (to stderr).
        threads: torch threads for the run, restored after it (None = torch's setting).
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

    def __post_init__(self) -> None:
        grid = {}
        for name in ("dt", "steps"):
            v = getattr(self, name)
            grid[name] = tuple(v) if isinstance(v, (tuple, list)) else (v,)
            if isinstance(v, list):
                object.__setattr__(self, name, tuple(v))
        if len(grid["dt"]) != len(grid["steps"]):
            raise ValueError(f"dt and steps must have one entry per record alike; got "
                             f"dt={self.dt!r}, steps={self.steps!r}")
        for t in grid["dt"]:
            if not (isinstance(t, (int, float)) and math.isfinite(t) and t > 0):
                raise ValueError(f"dt must be a positive finite number (or a tuple of them, one "
                                 f"per record); got {self.dt!r}")
        for v in grid["steps"]:
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"steps must be a positive integer (or a tuple of them, one "
                                 f"per record); got {self.steps!r}")
        for name in ("count", "epochs", "batch"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name} must be a positive integer; got {v!r}")
        _real("holdout", self.holdout, "in (0, 1)", lambda v: 0.0 < v < 1.0)
        if int(self.count * self.holdout) < 1 or self.count - int(self.count * self.holdout) < 1:
            raise ValueError(f"count={self.count} is too small to hold out {self.holdout:.0%}")
        if self.seconds is not None:
            _real("seconds", self.seconds, "positive or None", lambda v: v > 0)
        if (not isinstance(self.min_epochs, int) or isinstance(self.min_epochs, bool)
                or not 1 <= self.min_epochs <= self.epochs):
            raise ValueError(f"min_epochs must be an integer in [1, epochs={self.epochs}]; "
                             f"got {self.min_epochs!r}")
        if self.threads is not None and (not isinstance(self.threads, int)
                                         or isinstance(self.threads, bool) or self.threads < 1):
            raise ValueError(f"threads must be a positive integer or None; got {self.threads!r}")
        if self.target_loss is not None:
            _real("target_loss", self.target_loss, "a positive finite held-out loss or None",
                  lambda v: v > 0)
        _real("lr", self.lr, "positive and finite", lambda v: v > 0)
        # clip = inf is "no clipping" (notebook 03 measures gradient norms without it)
        if not (isinstance(self.clip, (int, float)) and not isinstance(self.clip, bool)
                and self.clip > 0):
            raise ValueError(f"clip must be positive (inf: no clipping); got {self.clip!r}")
        _real("supervised", self.supervised, "a finite weight >= 0", lambda v: v >= 0)
        if self.gamma is not None:
            _real("gamma", self.gamma, ">= 0 or None", lambda v: v >= 0)
        noise, what = self.noise, "a finite level >= 0 or a (lo, hi) range"
        if isinstance(noise, (tuple, list)):
            if len(noise) != 2:
                raise ValueError(f"noise must be {what}; got {noise!r}")
            lo, hi = (_real("noise", v, what, lambda v: v >= 0) for v in noise)
            if lo > hi:
                raise ValueError(f"noise must be {what} with lo <= hi; got {noise!r}")
            object.__setattr__(self, "noise", (lo, hi))
        else:
            _real("noise", noise, what, lambda v: v >= 0)
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise ValueError(f"seed must be a non-negative integer; got {self.seed!r}")
        for name in ("fresh", "progress"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False; got {getattr(self, name)!r}")
        if self.checkpoint is not None and not isinstance(self.checkpoint, (str, os.PathLike)):
            raise ValueError(f"checkpoint must be a file path (str or Path) or None; "
                             f"got {self.checkpoint!r}")
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
        """``(steps, dt)`` of each record."""
        steps = self.steps if isinstance(self.steps, tuple) else (self.steps,)
        dt = self.dt if isinstance(self.dt, tuple) else (self.dt,)
        return tuple((s, float(t)) for s, t in zip(steps, dt, strict=True))

    @property
    def noise_range(self) -> tuple[float, float]:
        if np.ndim(self.noise) == 0:
            return float(self.noise), float(self.noise)
        return float(self.noise[0]), float(self.noise[1])


def _batch_loss(ident: Identifier, y, u, yinf, gamma: float, z=None,
                weight: float = 0.0) -> torch.Tensor:
    """Eq. 14 on Eq. 15-normalised records, averaged over the batch (and the records).

    ``y_tilde - y_hat_tilde = 2 (y - y_hat) / y_bar`` (the shift of Eq. 15 cancels), so the
    records, the decoded responses and the stationary values are scaled by ``2 / y_bar`` of the
    measured record and handed to the decoder's Eq. 14.

    Args:
        y: ``(batch, steps)`` measured records (noisy when training with noise); a list of
            ``R`` of them ``(batch, steps_r)`` for several records.
        u: ``(batch, steps)`` inputs (a list like ``y``).
        yinf: ``(batch,)`` true stationary values (Eq. 4); ``(batch, R)`` for several records.
        z: ``(batch, p)`` the true systems' standardised raw parameters, weighted by ``weight``
            in a mean-squared term against the encoder's outputs (``TrainConfig.supervised``).
    """
    R = ident.records
    sys, _, raw = ident._forward(y, u, raw=True)
    ys, us = (y, u) if R > 1 else ((y,), (u,))
    total = 0.0
    for r in range(R):
        A, b, c, d = (x[:, r] for x in sys) if R > 1 else sys
        if ident.initial == "fitted":
            y_hat = _free_fit(A, b, c, d, us[r], ys[r], ident._dts[r])[1]
        else:
            y_hat = _simulate(A, b, c, d, us[r], ident._dts[r], None)
        scale = 2.0 / _record_scale(ys[r])
        yinf_r = yinf[:, r] if R > 1 else yinf
        yinf_hat = _stationary_value(A, b, c, d) * scale if gamma > 0 else None
        total = total + _loss(y_hat * scale[:, None], ys[r] * scale[:, None], yinf_hat,
                              yinf_r * scale, gamma)
    total = total / R
    if weight > 0:
        total = total + weight * torch.mean((raw - z.to(raw.dtype)) ** 2)
    return total


def _add_noise(y: torch.Tensor, y_bar: torch.Tensor, lo: float, hi: float,
               generator: torch.Generator) -> torch.Tensor:
    """White measurement noise for training: per record a level drawn uniformly from
    ``[lo, hi]``, std = level * ``y_bar`` (max|y| of the clean record).

    Args:
        y: ``(batch, steps)`` clean records. y_bar: ``(batch,)``.
    """
    if hi <= 0:
        return y
    level = lo + (hi - lo) * torch.rand(len(y), generator=generator)
    return y + (level * y_bar)[:, None] * torch.randn(y.shape, generator=generator)


def _theta(structure: Structure, systems, gain: np.ndarray | None) -> np.ndarray:
    """Raw parameters ``(N, p)`` of the true systems as the encoder describes them: for
    ``scale="denormalise"`` the system from ``u / u_bar`` to ``y / y_bar`` (``gain (N,)``)."""
    c, d = systems.c, systems.d
    if gain is not None:
        c, d = c / gain[:, None], d / gain
    return np.asarray(structure.theta_of(systems.A, systems.b, c, d), dtype=np.float64)


def _raw_statistics(structure: Structure, systems, gain: np.ndarray | None):
    """Centre and spread of the raw parameters of the family's systems (output standardisation).

    Robust: the median and ``IQR / 1.349`` (the standard deviation for a normal distribution).
    Why not the mean and standard deviation: one near-degenerate system can dominate them. In a
    4th-order MCF family two almost equal real poles (3.5e-6 apart) have residues of +-1e5
    against a median |c0| of 7; the standard deviation then scaled every output by 2e5, the
    gradients reached 2e10 and one training seed never learned (measured in notebook 03 before
    this change). The median and IQR ignore such a tail.
    """
    theta = _theta(structure, systems, gain)
    centre = np.median(theta, axis=0)
    q75, q25 = np.percentile(theta, [75, 25], axis=0)
    scale = (q75 - q25) / 1.349
    tiny = 1e-8 * (1 + np.abs(centre))
    # a parameter that hardly varies over the IQR (e.g. a discrete spread): the std, else 1
    scale = np.where(scale > tiny, scale, theta.std(axis=0))
    scale = np.where(scale > tiny, scale, 1.0)
    return centre, scale


def _duration(seconds: float) -> str:
    """``"42 s"``, ``"3 min 05 s"`` or ``"1 h 02 min"``."""
    seconds = max(0.0, seconds)
    if seconds < 10:
        return f"{seconds:.2g} s"
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"


def _eta(epoch: int, elapsed: float, config: TrainConfig) -> float:
    """Seconds left after ``epoch`` epochs in ``elapsed`` s, at the mean time per epoch so far:
    the epoch budget, or the time budget (but not before ``min_epochs``), whichever ends first
    (the loop's stopping rule)."""
    per = elapsed / max(epoch, 1)
    left = (config.epochs - epoch) * per
    if config.seconds is not None:
        left = min(left, max(config.seconds - elapsed, (config.min_epochs - epoch) * per, 0.0))
    return left


def _progress_line(epoch: int, config: TrainConfig, train: float, held: float, lr: float,
                   elapsed: float, label: str = "") -> str:
    """The progress line after ``epoch`` epochs: the budget that applies (epochs, or the wall
    time with its epoch floor), the losses, and the time to the end."""
    if config.seconds is None:
        budget = f"epoch {epoch:4d}/{config.epochs}"
        clock = f"{_duration(elapsed)}"
    else:
        floor = f" (at least {config.min_epochs})" if config.min_epochs > 1 else ""
        budget = f"epoch {epoch:4d}{floor}"
        clock = f"{_duration(elapsed)} of {_duration(config.seconds)} budget"
    prefix = f"{label}: " if label else ""
    return (f"{prefix}{budget} | loss {train:.3e} | held-out {held:.3e} | lr {lr:.1e} | "
            f"{clock} | ETA {_duration(_eta(epoch, elapsed, config))}")


def _undertrained(config: TrainConfig, history: dict, best: float) -> list[str]:
    """What the run fell short of (``UndertrainedWarning`` messages; empty when nothing):
    the epochs its wall-time budget fit against ``min_epochs``, and the best held-out loss
    against ``target_loss``. ``history``: the run's per-epoch history (``seconds``)."""
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
                f"the {_duration(config.seconds)} training budget fit only {fit} "
                f"epoch{'s' if fit > 1 else ''} "
                f"({per:.1f} s each; a busy machine?); the run trained on to min_epochs="
                f"{config.min_epochs}, {_duration(seconds[-1])} in all")
    if config.target_loss is not None and not best <= config.target_loss:
        budget = (f"the {_duration(config.seconds)} budget" if config.seconds is not None
                  and epochs < config.epochs else f"an epoch budget of {config.epochs}")
        notes.append(
            f"best held-out loss {best:.3e} after {epochs} epoch{'s' if epochs > 1 else ''} "
            f"({budget}, {per:.1f} s per epoch) is above the expected "
            f"{config.target_loss:.3e}: the identifier is "
            f"under-trained; train for more epochs (an epoch budget is reproducible on a busy "
            f"machine)")
    return notes


def train(structure: Structure, family, config: TrainConfig, *,
          encoder: EncoderConfig | None = None, inverse=None,
          meta: dict | None = None,
          on_epoch: Callable[[int, dict], None] | None = None) -> Identifier:
    """Train an identifier for ``structure`` on records simulated from ``family``.

    Args:
        structure: the parameterisation the encoder outputs (CCF, MCF, fixed, Physical).
        family: samples the true systems (``data.LegFamily``, ``data.PoleFamily``).
        config: the training settings.
        encoder: the network's shape; ``steps``, ``outputs``, ``inputs`` and ``features`` are
            set from the structure and ``config`` (paper widths by default).
        inverse: optional casadi.Function CCF -> physical parameters, stored in the identifier.
        meta: provenance stored with the identifier; its ``name``, if any, labels the
            progress line.
        on_epoch: called after each epoch, once its checkpoint is on disk, with the number of
            epochs done and the history so far (read it, do not change it): for logging, or to
            stop a run (an exception propagates; the run resumes from the checkpoint).

    Warns:
        UndertrainedWarning: the wall-time budget fit fewer than ``config.min_epochs`` epochs,
            or the best held-out loss is above ``config.target_loss`` (the messages are also
            in ``ident.meta["train"]["warnings"]``).

    Returns:
        The trained ``Identifier`` (weights with the lowest held-out loss); its per-epoch
        history (``train_loss``, ``holdout_loss``, ``lr``, ``seconds``, ``grad_norm_median``,
        ``grad_norm_max`` (before clipping), ``skipped`` (non-finite batches)) is in
        ``ident.meta["history"]`` and the run's settings in ``ident.meta["train"]``.

    Raises:
        ValueError: ``config.checkpoint`` names a file that cannot be resumed (unreadable,
            truncated, not a checkpoint, or written for another structure, family settings or
            encoder); the message names the path and how to start over.
    """
    if not isinstance(structure, Structure):
        raise ValueError(f"structure must be a Structure (CCF, MCF, Physical, ...); "
                         f"got {type(structure).__name__}")
    if not isinstance(config, TrainConfig):
        raise ValueError(f"config must be a TrainConfig (ae.TrainConfig(dt=..., steps=...)); "
                         f"got {type(config).__name__}")
    if not callable(getattr(family, "sample", None)):
        raise ValueError(f"family must be a system family with a sample(count, rng) method "
                         f"(LegFamily, PoleFamily); got {type(family).__name__}")
    order = getattr(family, "n", None)
    if isinstance(order, int) and order != structure.n:
        raise ValueError(f"family gives systems of order {order}, but {structure!r} has order "
                         f"{structure.n}: they must agree")
    R = structure.records
    if len(config.grids) != R or getattr(family, "records", 1) != R:
        raise ValueError(
            f"{structure!r} describes {R} record(s) per parameter set; config.dt and "
            f"config.steps give {len(config.grids)} and the family "
            f"{getattr(family, 'records', 1)}: they must agree")
    if config.threads is None:
        return _train(structure, family, config, encoder, inverse, meta, on_epoch)
    threads = torch.get_num_threads()
    torch.set_num_threads(config.threads)
    try:
        return _train(structure, family, config, encoder, inverse, meta, on_epoch)
    finally:
        torch.set_num_threads(threads)     # the setting is the run's, not the process's


def _train(structure: Structure, family, config: TrainConfig, encoder, inverse, meta,
           on_epoch) -> Identifier:
    """``train()`` after its checks, on the run's torch threads."""
    R = structure.records
    torch.manual_seed(config.seed)
    rec = records(family, config.count, steps=config.steps, dt=config.dt,
                  excitation_kind=config.excitation, seed=config.seed, warmup=config.warmup)
    scale_mode = "feature" if isinstance(structure, Physical) or not _c_free(structure) \
        else "denormalise"
    ys_clean, us = (rec.y_clean, rec.u) if R > 1 else ((rec.y_clean,), (rec.u,))
    y_bar = np.stack([np.max(np.abs(y), axis=1) for y in ys_clean], 1)     # (count, R)
    u_bar = np.stack([np.max(np.abs(u), axis=1) for u in us], 1)
    gain = y_bar / u_bar
    mean, spread = _raw_statistics(structure, rec.systems,
                                   gain[:, 0] if scale_mode == "denormalise" else None)
    log_gain = np.log(gain)
    log_spread = log_gain.std(axis=0)

    base = encoder or EncoderConfig(steps=config.steps, outputs=structure.p)
    enc_config = dataclasses.replace(
        base, steps=config.steps, outputs=structure.p,
        inputs=base.inputs or config.excitation != "step",
        features=R if scale_mode == "feature" else 0,
    )
    ident = Identifier(
        Encoder(enc_config), structure, dt=config.dt,
        theta_mean=torch.tensor(mean), theta_scale=torch.tensor(spread), scale=scale_mode,
        initial=config.initial,
        feature_mean=log_gain.mean(axis=0), feature_scale=np.where(log_spread > 0, log_spread,
                                                                   1.0),
        inverse=inverse, meta=meta,
    )

    train_idx, held_idx = _split(config.count, config.holdout, config.seed)
    dtype = torch.float32
    u_all = [torch.tensor(u, dtype=dtype) for u in us]
    y_all = [torch.tensor(y, dtype=dtype) for y in ys_clean]
    yinf_all = torch.tensor(np.stack([
        stationary_value(*(getattr(rec.systems.record(r), f) for f in "Abcd"))
        for r in range(R)], 1), dtype=dtype)                                  # (count, R)
    scale_all = torch.tensor(y_bar, dtype=dtype)

    def targets(systems, gain: np.ndarray) -> torch.Tensor:
        """Standardised true raw parameters ``(N, p)`` (``TrainConfig.supervised``)."""
        theta = _theta(structure, systems, gain[:, 0] if scale_mode == "denormalise" else None)
        return torch.tensor((theta - mean) / spread, dtype=dtype)

    z_all = targets(rec.systems, gain) if config.supervised > 0 else None
    noise_lo, noise_hi = config.noise_range
    gamma = config.stationary_weight

    def batch(idx: torch.Tensor, ys: list[torch.Tensor]):
        """``(y, u, yinf, z)`` of the records ``idx`` as the loss takes them (tensors for one
        record, lists for several); ``ys`` are their outputs, already taken (and noisy)."""
        u = [v[idx] for v in u_all]
        z = None if z_all is None else z_all[idx]
        if R == 1:
            return ys[0], u[0], yinf_all[idx, 0], z
        return ys, u, yinf_all[idx], z

    params = list(ident.encoder.parameters())
    opt = torch.optim.Adam(params, lr=config.lr)
    # Every random stream of the run, all checkpointed: the shuffling and training noise, the
    # held-out noise (fresh each epoch), and torch's global generator (nothing draws from it
    # after the weights are initialised today; kept so that nothing can break resumption).
    generator = torch.Generator().manual_seed(config.seed + 2)
    held_noise_gen = torch.Generator().manual_seed(config.seed + 3)
    generators = {"generator": generator, "held_generator": held_noise_gen}
    state = {"epoch": 0, "elapsed": 0.0, "best": math.inf, "best_state": None,
             "history": {"train_loss": [], "holdout_loss": [], "lr": [], "seconds": [],
                         "grad_norm_median": [], "grad_norm_max": [], "skipped": []}}
    ckpt = Path(config.checkpoint) if config.checkpoint else None
    fingerprint = _fingerprint(structure, config, enc_config)
    if ckpt is not None:
        _remove_leftover(ckpt)
        if ckpt.exists():
            state = _resume(ckpt, fingerprint, ident, opt, generators)

    def noisy(idx: torch.Tensor):
        return batch(idx, [_add_noise(y[idx], scale_all[idx, r], noise_lo, noise_hi, generator)
                           for r, y in enumerate(y_all)])

    held_t = torch.as_tensor(held_idx)

    def holdout_loss() -> float:
        ident.encoder.eval()
        total = 0.0
        with torch.no_grad():
            for i in range(0, len(held_t), 1024):
                idx = held_t[i: i + 1024]
                ys = [y[idx] for y in y_all]
                if noise_hi > 0:
                    level = (noise_lo + noise_hi) / 2
                    ys = [y + (level * scale_all[idx, r])[:, None] * torch.randn(
                        y.shape, generator=held_noise_gen) for r, y in enumerate(ys)]
                y_, u_, yinf_, _ = batch(idx, ys)
                total += float(_batch_loss(ident, y_, u_, yinf_, gamma)) * len(idx)
        ident.encoder.train()
        return total / len(held_t)

    train_t = torch.as_tensor(train_idx)
    steps_per_epoch = math.ceil(len(train_t) / config.batch)
    tty = sys.stderr.isatty()
    start = time.perf_counter() - state["elapsed"]
    ident.encoder.train()
    epoch = state["epoch"]
    label = str((meta or {}).get("name", ""))
    while epoch < config.epochs:
        elapsed = time.perf_counter() - start
        if (config.seconds is not None and elapsed >= config.seconds
                and epoch >= config.min_epochs):
            break
        if config.fresh and epoch > 0:
            new = _redraw(family, config, epoch, train_idx, u_all, y_all, yinf_all, scale_all)
            if z_all is not None:
                new_u = new.u if R > 1 else (new.u,)
                u_new = np.stack([np.max(np.abs(u), axis=1) for u in new_u], 1)
                z_all[torch.as_tensor(train_idx)] = targets(
                    new.systems, scale_all[torch.as_tensor(train_idx)].double().numpy() / u_new)
        perm = train_t[torch.randperm(len(train_t), generator=generator)]
        running, skipped, norms = 0.0, 0, []
        for j in range(steps_per_epoch):
            # the fraction of the budget spent: of the epochs, or of the wall time -- but a
            # run the floor keeps going is only as far as its epochs towards min_epochs, so
            # the schedule stretches to the floor instead of idling at its end
            done = epoch + j / steps_per_epoch
            progress = done / config.epochs
            if config.seconds is not None:
                progress = max(progress, min((time.perf_counter() - start) / config.seconds,
                                             done / config.min_epochs))
            lr = _learning_rate(config.lr, min(progress, 1.0))
            for group in opt.param_groups:
                group["lr"] = lr
            idx = perm[j * config.batch: (j + 1) * config.batch]
            y_, u_, yinf_, z_ = noisy(idx)
            loss = _batch_loss(ident, y_, u_, yinf_, gamma, z_,
                               config.supervised * max(0.0, 1.0 - progress))
            opt.zero_grad(set_to_none=True)
            value = float(loss.detach())
            if not math.isfinite(value):
                skipped += 1
                continue
            loss.backward()
            norm = float(torch.nn.utils.clip_grad_norm_(params, config.clip))
            if not math.isfinite(norm):
                skipped += 1
                continue
            norms.append(norm)
            opt.step()
            running += value
        epoch += 1
        held = holdout_loss()
        elapsed = time.perf_counter() - start
        hist = state["history"]
        hist["train_loss"].append(running / max(steps_per_epoch - skipped, 1))
        hist["holdout_loss"].append(held)
        hist["lr"].append(lr)
        hist["seconds"].append(elapsed)
        hist["grad_norm_median"].append(float(np.median(norms)) if norms else math.nan)
        hist["grad_norm_max"].append(max(norms) if norms else math.nan)
        hist["skipped"].append(skipped)
        if held < state["best"] and math.isfinite(held):
            state["best"] = held
            state["best_state"] = {k: v.detach().clone()
                                   for k, v in ident.encoder.state_dict().items()}
        state["epoch"], state["elapsed"] = epoch, elapsed
        if ckpt is not None:
            _save_checkpoint(ckpt, fingerprint, ident, opt, generators, state)
        if config.progress:
            sys.stderr.write(("\r" if tty else "") + _progress_line(
                epoch, config, hist["train_loss"][-1], held, lr, elapsed, label)
                + ("\033[K" if tty else "\n"))
            sys.stderr.flush()
        if on_epoch is not None:
            on_epoch(epoch, hist)
    if config.progress and tty:
        sys.stderr.write("\n")
    notes = _undertrained(config, state["history"], state["best"])
    for note in notes:
        warnings.warn(f"{label or 'training'}: {note}", UndertrainedWarning, stacklevel=3)
    if state["best_state"] is not None:
        ident.encoder.load_state_dict(state["best_state"])
    ident.encoder.eval()
    ident.meta["history"] = state["history"]
    ident.meta["train"] = {
        "epochs": state["epoch"], "seconds": round(state["elapsed"], 2),
        "best_holdout_loss": state["best"], "config": _config_dict(config),
        "encoder": enc_config.to_dict(), "warnings": notes,
    }
    if R == 1:
        ident.meta["training_range"] = _training_range(ident, rec, held_idx, noise_hi,
                                                       config.seed + 4)
    return ident


def _split(count: int, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The run's ``(training, held-out)`` record indices: a ``holdout`` share held out, drawn
    with the run's seed (``recalibrate`` re-creates the split from the stored settings)."""
    held = int(count * holdout)
    order = np.random.default_rng(seed + 1).permutation(count)
    return order[held:], order[:held]


def recalibrate(ident: Identifier, family) -> Identifier:
    """Recompute ``ident``'s training range and flag thresholds (``Estimate.outside``) as
    ``train()`` does at its end, for a file trained before them: the run's records and held-out
    split are re-created from the settings it recorded (``meta["train"]["config"]``) and
    ``family``, which must be the family it was trained on. The weights are untouched; returns
    ``ident`` with ``meta["training_range"]`` replaced."""
    if not isinstance(ident, Identifier):
        raise ValueError(f"ident must be an Identifier (ae.Identifier.load(path)); "
                         f"got {type(ident).__name__}")
    cfg = ident.meta.get("train", {}).get("config")
    if not cfg:
        raise ValueError("ident must carry its training settings (meta['train']['config'])")
    if ident.records != 1:
        raise ValueError("recalibrate covers identifiers of one record")
    rec = records(family, cfg["count"], steps=cfg["steps"], dt=cfg["dt"],
                  excitation_kind=cfg["excitation"], seed=cfg["seed"],
                  warmup=cfg.get("warmup", 0))
    held = _split(cfg["count"], cfg["holdout"], cfg["seed"])[1]
    ident.meta["training_range"] = _training_range(ident, rec, held, max(cfg["noise"]),
                                                   cfg["seed"] + 4)
    return ident


def _training_range(ident: Identifier, rec, held: np.ndarray, noise: float,
                    seed: int) -> dict:
    """What ``Estimate.outside`` compares with: per free element and physical parameter, its
    ``[lo, hi]`` over the training family and the identifier's 90th-percentile absolute error on
    the held-out records at the largest training noise (one record per system); and the two
    flag thresholds calibrated on those records: ``excess`` (its ``1 - FLAG_FALSE_RATE``
    quantile) and ``fit`` (NRMSE %, its ``FLAG_FALSE_RATE`` quantile)."""
    systems = rec.systems
    X = ident.structure.elements_of(systems.A, systems.b, systems.c, systems.d).numpy()
    rng = np.random.default_rng(seed)
    y = rec.y_clean[held]
    y = y + noise * np.abs(y).max(axis=1, keepdims=True) * rng.normal(size=y.shape)
    est = ident.identify(y, rec.u[held])
    out: dict[str, dict] = {"elements": {}, "physical": {}}
    for i, name in enumerate(ident.structure.element_names):
        if name in ident.structure.free_names:
            err = np.abs(np.asarray(est.elements[name]) - X[held, i])
            out["elements"][name] = [float(X[:, i].min()), float(X[:, i].max()),
                                     float(np.nanpercentile(err, 90))]
    for name, value in (est.physical or {}).items():
        if name in systems.params:
            truth = systems.params[name]
            err = np.abs(np.asarray(value) - truth[held])
            out["physical"][name] = [float(truth.min()), float(truth.max()),
                                     float(np.nanpercentile(err, 90))]
    # The flag thresholds (Estimate.outside): the quantiles of excess and fit on these
    # in-range records that flag FLAG_FALSE_RATE of them each.
    excess = _excess({**est.elements, **(est.physical or {})}, out)
    out["excess"] = float(np.nanquantile(excess, 1.0 - FLAG_FALSE_RATE))
    out["fit"] = float(np.nanquantile(est.fit, FLAG_FALSE_RATE))
    return out


def _redraw(family, config: TrainConfig, epoch: int, rows: np.ndarray, u_all, y_all,
            yinf_all, scale_all) -> Records:
    """New training records for ``epoch`` (``TrainConfig.fresh``): the rows ``rows`` of the
    record tensors are replaced in place by records drawn with a seed of their own, so that a
    resumed run draws the same ones. Returns the new records."""
    rec = records(family, len(rows), steps=config.steps, dt=config.dt,
                  excitation_kind=config.excitation, seed=config.seed + 7919 * epoch,
                  warmup=config.warmup)
    multi = isinstance(rec.u, tuple)
    ys, us = (rec.y_clean, rec.u) if multi else ((rec.y_clean,), (rec.u,))
    index = torch.as_tensor(rows)
    for r, (y, u) in enumerate(zip(ys, us, strict=True)):
        y_all[r][index] = torch.as_tensor(y, dtype=y_all[r].dtype)
        u_all[r][index] = torch.as_tensor(u, dtype=u_all[r].dtype)
        scale_all[index, r] = torch.as_tensor(np.max(np.abs(y), axis=1), dtype=scale_all.dtype)
        s = rec.systems.record(r)
        yinf_all[index, r] = torch.as_tensor(stationary_value(s.A, s.b, s.c, s.d),
                                             dtype=yinf_all.dtype)
    return rec


def _c_free(structure: Structure) -> bool:
    """Whether every output element ``c_i`` (and ``d``) may be rescaled: then de-normalise."""
    fixed = getattr(structure, "fixed_values", {}) or {}
    return all(v == 0.0 for k, v in fixed.items() if k.startswith("c") or k == "d")


def _learning_rate(peak: float, progress: float) -> float:
    """2 % linear warm-up, then cosine decay to 1 % of the peak."""
    if progress < 0.02:
        return peak * (0.1 + 0.9 * progress / 0.02)
    x = (progress - 0.02) / 0.98
    return peak * (0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * x)))


def _config_dict(config: TrainConfig) -> dict:
    d = dataclasses.asdict(config)
    d["noise"] = list(config.noise_range)
    return d


def _fingerprint(structure, config: TrainConfig, enc: EncoderConfig) -> str:
    """What must match for a checkpoint to be resumed (not the budget or the progress flag)."""
    import json

    d = _config_dict(config)
    for key in ("epochs", "seconds", "min_epochs", "target_loss", "progress", "checkpoint",
                "threads"):
        d.pop(key)
    return json.dumps({"structure": structure.config(), "config": d,
                       "encoder": enc.to_dict()}, sort_keys=True)


def _tmp_path(path: Path) -> Path:
    """Where a checkpoint is written before the atomic rename."""
    return path.with_name(path.name + ".tmp")


def _remove_leftover(path: Path) -> None:
    """Remove the ``.tmp`` file a kill between write and rename leaves: never a checkpoint
    (the rename did not happen), so nothing is lost."""
    tmp = _tmp_path(path)
    if tmp.is_file():
        tmp.unlink()


def _save_checkpoint(path: Path, fingerprint: str, ident, opt, generators: dict,
                     state) -> None:
    """Write the run's state atomically: to ``<path>.tmp``, flushed to the disk (``fsync``),
    then renamed over ``path``, so that a kill or a power loss at any point leaves the previous
    checkpoint or this one, never a torn file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "fingerprint": fingerprint,
        "encoder": ident.encoder.state_dict(),
        "optimizer": opt.state_dict(),
        **{name: g.get_state() for name, g in generators.items()},
        "torch_rng": torch.get_rng_state(),
        "epoch": state["epoch"],
        "elapsed": state["elapsed"],
        "best": state["best"],
        "best_state": state["best_state"],
        "history": state["history"],
    }
    tmp = _tmp_path(path)
    try:
        with open(tmp, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())     # the bytes reach the disk before the name points at them
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_directory(path.parent)    # and the rename itself


def _fsync_directory(folder: Path) -> None:
    """Flush a directory entry (a rename) to the disk where the platform allows it (POSIX; a
    directory cannot be opened on Windows, where ``os.replace`` is durable by itself)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


#: The checkpoint's entries: written by every version (``_REQUIRED``), and since resumption is
#: bit-identical (older checkpoints without them resume with fresh held-out noise).
_REQUIRED = ("fingerprint", "encoder", "optimizer", "generator", "epoch", "elapsed", "best",
             "best_state", "history")
_RANDOM_STATES = ("held_generator", "torch_rng")
_HISTORY = ("train_loss", "holdout_loss", "lr", "seconds", "grad_norm_median", "grad_norm_max",
            "skipped")


def _unusable(payload, fingerprint: str, encoder_state: dict, opt) -> str | None:
    """Why ``payload`` (what ``torch.load`` returned) cannot be resumed by this run, or None.

    Checked before anything is loaded, so that a wrong file changes nothing: the entries and
    their types, the fingerprint (structure, family settings, encoder), every weight's name and
    shape (the encoder's, the best epoch's, the optimizer's moments), the generator states and
    the history's length.
    """
    if not isinstance(payload, dict):
        return f"it holds a {type(payload).__name__}, not a training checkpoint"
    missing = [k for k in _REQUIRED if k not in payload]
    if missing:
        return f"it is not a training checkpoint (no {', '.join(missing)})"
    if payload["fingerprint"] != fingerprint:
        return "it was written for a different structure, family settings or encoder"

    def weights(name: str, tensors) -> str | None:
        if not isinstance(tensors, dict) or set(tensors) != set(encoder_state):
            return f"its {name} are not this encoder's weights"
        for key, ref in encoder_state.items():
            value = tensors[key]
            if not isinstance(value, torch.Tensor):
                return f"its {name} {key!r} are a {type(value).__name__}, not a tensor"
            if value.shape != ref.shape:
                return (f"its {name} {key!r} have shape {tuple(value.shape)}, expected "
                        f"{tuple(ref.shape)}")
        return None

    reason = weights("weights", payload["encoder"])
    if reason is None and payload["best_state"] is not None:
        reason = weights("best weights", payload["best_state"])
    if reason:
        return reason
    epoch = payload["epoch"]
    if not isinstance(epoch, int) or isinstance(epoch, bool) or epoch < 0:
        return f"its epoch is {epoch!r}, not a count"
    for key in ("elapsed", "best"):
        if not isinstance(payload[key], (int, float)) or math.isnan(payload[key]):
            return f"its {key} is {payload[key]!r}, not a number"
    history = payload["history"]
    if not isinstance(history, dict) or any(
            not isinstance(history.get(k), list) or len(history[k]) != epoch
            for k in _HISTORY[:4]):
        return f"its history does not hold {epoch} epochs of {', '.join(_HISTORY[:4])}"
    reference = torch.Generator().get_state()
    for key in ("generator", *_RANDOM_STATES):
        g = payload.get(key, reference)
        expected = torch.get_rng_state() if key == "torch_rng" else reference
        if not (isinstance(g, torch.Tensor) and g.dtype == expected.dtype
                and g.shape == expected.shape):
            return f"its {key} is not a random generator's state"
    state = payload["optimizer"]
    params = [p for group in opt.param_groups for p in group["params"]]
    if not (isinstance(state, dict) and isinstance(state.get("state"), dict)
            and isinstance(state.get("param_groups"), list)):
        return "its optimizer state is not Adam's"
    for i, moments in state["state"].items():
        if not (isinstance(i, int) and 0 <= i < len(params) and isinstance(moments, dict)):
            return "its optimizer state is for other parameters"
        for name, value in moments.items():
            if (not isinstance(value, torch.Tensor)
                    or (value.dim() > 0 and value.shape != params[i].shape)):
                return f"its optimizer's {name} of parameter {i} does not match the weights"
    return None


def _unreadable(err: Exception) -> str:
    """Why ``torch.load(..., weights_only=True)`` could not read a checkpoint, in our words
    (torch's own message for a refused pickle suggests ``weights_only=False``: never here)."""
    if isinstance(err, pickle.UnpicklingError):
        return ("it is not a file of tensors and numbers only (refused unread: loading it could "
                "run code)")
    if isinstance(err, EOFError):
        return "it is empty or truncated"
    if isinstance(err, OSError):
        return f"it cannot be opened ({err.strerror or err})"
    if isinstance(err, RuntimeError) and "zip archive" in str(err):
        return "it is truncated or not a torch file"
    first = (str(err).strip().splitlines() or [""])[0][:120]
    return f"it cannot be read as a training checkpoint ({type(err).__name__}: {first})"


def _resume(path: Path, fingerprint: str, ident, opt, generators: dict) -> dict:
    """Load a checkpoint into the run (encoder, optimizer, generators) and return its state.

    Raises ``ValueError`` naming ``path`` and how to start over for any file that is not a
    checkpoint of this run; nothing is changed then. ``weights_only=True``: the file is read as
    tensors and numbers only, a pickle that asks for anything else (code) is refused unrun.
    """
    def refused(reason: str) -> ValueError:
        return ValueError(f"checkpoint {str(path)!r} cannot be resumed: {reason}; delete it or "
                          "choose another checkpoint path to start over")

    try:
        payload = torch.load(path, weights_only=True, map_location="cpu")
    except Exception as err:    # truncated, not a torch file, a directory, a pickle of code
        raise refused(_unreadable(err)) from None
    reason = _unusable(payload, fingerprint, ident.encoder.state_dict(), opt)
    if reason is not None:
        raise refused(reason)
    try:
        opt.load_state_dict(payload["optimizer"])
    except (ValueError, KeyError, TypeError, RuntimeError) as err:
        raise refused(f"its optimizer state cannot be loaded ({err})") from None
    ident.encoder.load_state_dict(payload["encoder"])
    for name, g in generators.items():
        if name in payload:
            g.set_state(payload[name])
    if "torch_rng" in payload:
        torch.set_rng_state(payload["torch_rng"])
    state = {k: payload[k] for k in ("epoch", "elapsed", "best", "best_state", "history")}
    for key in _HISTORY[4:]:   # older checkpoints
        state["history"].setdefault(key, [math.nan] * state["epoch"])
    return state
