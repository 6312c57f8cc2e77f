"""Unsupervised training of an identifier (paper Sec. III): encoder -> structure -> decoder.

``train()`` runs in stages: the data (``tensors.record_tensors``: simulated records, their
split and scales), the model (encoder, identifier, optimiser, random streams, a resumed
checkpoint), the epochs (gradient steps on Eq. 14, ``objective.batch_loss``), the held-out
evaluation that picks the weights, and the finish (best weights, history, training range).
Choices the paper leaves open: 80/20 split (paper Sec. IV); Adam with a short warm-up and a
cosine decay over an epoch or wall-time budget; gradient-norm clipping, and batches whose loss
or gradient is not finite are skipped and counted; float32.

Launched by ``torchrun``, the same loop runs data-parallel (``training.distributed``): every
process draws the same global batches and noise, computes the loss on its share of each batch
through ``DistributedDataParallel``, and sums the held-out loss with the others; rank 0 alone
writes. Not launched by ``torchrun``, nothing of that runs.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from aeid_struct.encoder import Encoder, EncoderConfig
from aeid_struct.identification import Head, Identifier
from aeid_struct.structures import Physical, Structure
from aeid_struct.training import checkpoints, distributed
from aeid_struct.training.calibration import training_range
from aeid_struct.training.config import TrainConfig, config_dict
from aeid_struct.training.datasets import one_per_output
from aeid_struct.training.objective import add_noise, batch_loss
from aeid_struct.training.progress import (
    UndertrainedWarning,
    learning_rate,
    progress_line,
    undertrained,
)
from aeid_struct.training.tensors import RecordTensors, record_tensors, refresh


@dataclass
class _Run:
    """Everything an epoch reads and changes."""

    structure: Structure
    family: object
    config: TrainConfig
    data: RecordTensors
    ident: Identifier
    enc_config: EncoderConfig
    opt: torch.optim.Adam
    generators: dict            # "generator" (shuffling, noise), "held_generator"
    state: dict                 # epoch, elapsed, best, best_state, history (checkpointed)
    ckpt: Path | None
    fingerprint: str
    label: str
    ctx: distributed.Context    # the process's place in a data-parallel run (or one process)
    model: torch.nn.Module      # the encoder, in DistributedDataParallel when distributed


def train(structure: Structure, family, config: TrainConfig, *,
          encoder: EncoderConfig | None = None, inverse=None,
          meta: dict | None = None,
          on_epoch: Callable[[int, dict], None] | None = None,
          head: Head | None | str = "auto") -> Identifier:
    """Train an identifier for ``structure`` on records simulated from ``family``.

    Parameters
    ----------
    structure : Structure
        The parameterisation the encoder outputs (CCF, MCF, fixed, Physical).
    family : LegFamily, PoleFamily or any family
        Samples the true systems (``sample(count, rng)``); its order and records per system
        must be the structure's.
    config : TrainConfig
        The training settings.
    encoder : EncoderConfig, optional
        The network's shape; ``steps``, ``outputs``, ``inputs`` and ``features`` are set from
        the structure and ``config`` (paper widths by default).
    inverse : casadi.Function, optional
        CCF -> physical parameters, stored in the identifier.
    meta : dict, optional
        Provenance stored with the identifier; its ``name``, if any, labels the progress line.
    on_epoch : callable (epochs done, history) -> None, optional
        Called after each epoch, once its checkpoint is on disk (read the history, do not
        change it): for logging, or to stop a run (an exception propagates; the run resumes
        from the checkpoint).
    head : identification.Head, None or "auto", optional
        The head the identifier carries (``Identifier.head``), set before its training range
        is calibrated: the range's fit threshold is then the one pass's, not the encoder's
        alone (a head set afterwards needs ``training.recalibrate``). ``"auto"`` (the
        default): :data:`PHYSICAL_HEAD` for a ``Physical`` structure, whose one pass is the
        encoder and a fixed number of iterations in the parameters; None (the encoder alone,
        as the paper's identifiers) for the canonical structures.

    Returns
    -------
    Identifier
        The weights with the lowest held-out loss; its per-epoch history (``train_loss``,
        ``holdout_loss``, ``lr``, ``seconds``, ``grad_norm_median``, ``grad_norm_max`` (before
        clipping), ``skipped`` (non-finite batches)) in ``ident.meta["history"]``, the run's
        settings in ``ident.meta["train"]`` and the training range in
        ``ident.meta["training_range"]``.

    Raises
    ------
    ValueError
        A wrong argument, or ``config.checkpoint`` names a file that cannot be resumed
        (unreadable, truncated, not a checkpoint, or written for another structure, family
        settings or encoder); the message names the path and how to start over.
    RuntimeError
        Under ``torchrun``: another process failed (a collective failed); the message names
        this process and how to resume from the checkpoint.

    Notes
    -----
    Launched by ``torchrun`` (one node or several), the run is data-parallel: ``config.batch``
    is the global batch, split over the processes; the result depends on the global batch and
    the seed, not on the number of processes (up to float32 summation order), and
    ``ident.meta["train"]`` records ``world_size``, ``backend`` and ``device``. Every process
    returns the identifier; rank 0 alone writes the checkpoint and prints progress.

    Warns
    -----
    UndertrainedWarning
        The wall-time budget fit fewer than ``config.min_epochs`` epochs, or the best held-out
        loss is above ``config.target_loss`` (the messages are also in
        ``ident.meta["train"]["warnings"]``).
    """
    _check_arguments(structure, family, config)
    head = _head(structure, head)
    ctx = distributed.setup(config.device)
    threads = torch.get_num_threads()
    if config.threads is not None:
        torch.set_num_threads(config.threads)
    try:
        return _train(structure, family, config, encoder, inverse, meta, on_epoch, ctx, head)
    except Exception as err:
        if ctx.distributed and distributed.collective_error(err):
            raise distributed.failure(err, ctx, config.checkpoint) from err
        raise
    finally:
        torch.set_num_threads(threads)     # the setting is the run's, not the process's


#: The head ``train(head="auto")`` gives a physical structure's identifier: the encoder alone
#: lands some tens of percent from the parameters that the least-squares optimum holds, and a
#: few Levenberg-Marquardt iterations in the parameters (``identification.physical_head``)
#: close that gap at a fixed cost, where a canonical identifier's encoder is the paper's one
#: pass on its own.
PHYSICAL_HEAD = Head(iterations=5)


def _head(structure: Structure, head) -> Head | None:
    """``train()``'s ``head`` argument resolved: ``"auto"`` by the structure's kind."""
    if isinstance(head, str) and head == "auto":
        return PHYSICAL_HEAD if isinstance(structure, Physical) else None
    if head is not None and not isinstance(head, Head):
        got = repr(head) if isinstance(head, str) else type(head).__name__
        raise ValueError(f"head must be an identification.Head (ae.Head(iterations=...)), "
                         f"None or 'auto'; got {got}")
    return head


def _check_arguments(structure, family, config) -> None:
    """``train()``'s arguments agree: types, the family's order and records per system."""
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


def _check_shares(config: TrainConfig, world_size: int) -> None:
    """Every process gets at least one record of every global batch (DDP needs each process's
    backward), the last, shorter batch of an epoch included."""
    n_train = config.count - int(config.count * config.holdout)
    sizes = {min(config.batch, n_train), n_train % config.batch or config.batch}
    if min(sizes) < world_size:
        raise ValueError(
            f"batch={config.batch} with {n_train} training records gives a batch of "
            f"{min(sizes)} record(s), fewer than the {world_size} processes: every process needs "
            f"a share of every batch; choose batch and count so that each batch has >= "
            f"{world_size} records")


def _train(structure: Structure, family, config: TrainConfig, encoder, inverse, meta,
           on_epoch, ctx: distributed.Context, head) -> Identifier:
    """``train()`` after its checks, on the run's torch threads: the stages in order."""
    _check_shares(config, ctx.world_size)
    torch.manual_seed(config.seed)
    data = record_tensors(structure, family, config)
    run = _model(structure, family, config, data, encoder, inverse, meta, ctx)
    tty = sys.stderr.isatty()
    start = time.perf_counter() - run.state["elapsed"]
    run.ident.encoder.train()
    while run.state["epoch"] < config.epochs:
        if (config.seconds is not None and ctx.clock(start) >= config.seconds
                and run.state["epoch"] >= config.min_epochs):
            break
        train_loss, lr, norms, skipped = _epoch(run, start)
        _record(run, train_loss, _holdout_loss(run), lr, norms, skipped, ctx.clock(start))
        hist = run.state["history"]
        if config.progress and ctx.writer:
            sys.stderr.write(("\r" if tty else "") + progress_line(
                run.state["epoch"], config, hist["train_loss"][-1], hist["holdout_loss"][-1],
                lr, run.state["elapsed"], run.label) + ("\033[K" if tty else "\n"))
            sys.stderr.flush()
        if on_epoch is not None:
            on_epoch(run.state["epoch"], hist)
    if config.progress and tty and ctx.writer:
        sys.stderr.write("\n")
    return _finish(run, head)


def _model(structure: Structure, family, config: TrainConfig, data: RecordTensors, encoder,
           inverse, meta, ctx: distributed.Context) -> _Run:
    """Stage 2: the encoder and identifier (on the run's device), Adam, the run's random streams
    and state, resumed from the checkpoint when there is one (every process reads it)."""
    R = structure.records
    base = encoder or EncoderConfig(steps=config.steps, outputs=structure.p)
    enc_config = dataclasses.replace(
        base, steps=config.steps, outputs=structure.p,
        inputs=base.inputs or config.excitation != "step",
        features=R if data.scale_mode == "feature" else 0,
    )
    log_gain = np.log(data.gain)
    log_spread = log_gain.std(axis=0)
    ident = Identifier(
        Encoder(enc_config), structure, dt=config.dt,
        theta_mean=torch.tensor(data.mean), theta_scale=torch.tensor(data.spread),
        scale=data.scale_mode, initial=config.initial,
        feature_mean=log_gain.mean(axis=0),
        feature_scale=np.where(log_spread > 0, log_spread, 1.0),
        inverse=inverse, meta=meta,
    )
    ident.encoder.to(ctx.device)             # in place: the parameters stay the same objects
    opt = torch.optim.Adam(list(ident.encoder.parameters()), lr=config.lr)
    # Every random stream of the run, all checkpointed: the shuffling and training noise, the
    # held-out noise (fresh each epoch), and torch's global generator (nothing draws from it
    # after the weights are initialised today; kept so that nothing can break resumption).
    generators = {"generator": torch.Generator().manual_seed(config.seed + 2),
                  "held_generator": torch.Generator().manual_seed(config.seed + 3)}
    state = {"epoch": 0, "elapsed": 0.0, "best": math.inf, "best_state": None,
             "history": {key: [] for key in checkpoints.HISTORY}}
    ckpt = Path(config.checkpoint) if config.checkpoint else None
    fingerprint = checkpoints.fingerprint(structure, config, enc_config)
    if ckpt is not None:
        if ctx.writer:
            checkpoints.remove_leftover(ckpt)
        ctx.barrier()                        # no process reads while rank 0 tidies up
        if ckpt.exists():
            state = checkpoints.resume(ckpt, fingerprint, ident, opt, generators)
    return _Run(structure=structure, family=family, config=config, data=data, ident=ident,
                enc_config=enc_config, opt=opt, generators=generators, state=state, ckpt=ckpt,
                fingerprint=fingerprint, label=str((meta or {}).get("name", "")), ctx=ctx,
                model=ctx.wrap(ident.encoder))


def _epoch(run: _Run, start: float) -> tuple[float, float, list[float], int]:
    """Stage 3: one epoch of gradient steps (fresh records first when asked).

    Returns the mean training loss, the last learning rate, the gradient norms before clipping
    and the number of skipped (non-finite) batches. Data-parallel, every process draws the
    epoch's permutation and each batch's noise whole (its streams stay in step with the
    others') and trains on its share; its loss is weighted by ``n_rank W / n`` so that the
    gradients DDP averages are those of the global batch's mean.
    """
    config, data, epoch, ctx = run.config, run.data, run.state["epoch"], run.ctx
    generator = run.generators["generator"]
    train_t = torch.as_tensor(data.train)
    steps_per_epoch = math.ceil(len(train_t) / config.batch)
    if config.fresh and epoch > 0 and not ctx.distributed:
        refresh(data, run.structure, run.family, config, epoch)
    perm = train_t[torch.randperm(len(train_t), generator=generator)]
    if config.fresh and epoch > 0 and ctx.distributed:      # the rows this process trains on
        refresh(data, run.structure, run.family, config, epoch, np.concatenate(
            [part[ctx.share(len(part))].numpy() for part in perm.split(config.batch)]))
    params = [p for group in run.opt.param_groups for p in group["params"]]
    lo, hi = config.noise_range
    groups = getattr(run.structure, "groups", None)
    running, skipped, norms, lr = 0.0, 0, [], config.lr
    encoder, run.ident.encoder = run.ident.encoder, run.model     # DDP's forward, when wrapped
    try:
        for j in range(steps_per_epoch):
            progress = _progress(config, epoch + j / steps_per_epoch, start, ctx)
            lr = learning_rate(config.lr, min(progress, 1.0))
            for group in run.opt.param_groups:
                group["lr"] = lr
            idx = perm[j * config.batch: (j + 1) * config.batch]
            mine = ctx.share(len(idx))
            ys = one_per_output(lambda r, idx=idx, mine=mine: add_noise(
                data.y[r][idx], data.scale[idx, r], lo, hi, generator)[mine], len(data.y), groups)
            y_, u_, yinf_, z_ = _on(ctx.device, data.batch(idx[mine], ys))
            loss = batch_loss(run.ident, y_, u_, yinf_, config.stationary_weight, z_,
                              config.supervised * max(0.0, 1.0 - progress))
            run.opt.zero_grad(set_to_none=True)
            value = float(loss.detach())
            if ctx.distributed:                  # the global batch's mean, on every process
                share = mine.stop - mine.start
                value = ctx.sum([value * share])[0] / len(idx)
                loss = loss * (share * ctx.world_size / len(idx))
            if not math.isfinite(value):
                skipped += 1
                continue
            norm = distributed.gradient_step(run.opt, loss, params, config.clip)
            if norm is None:
                skipped += 1
                continue
            norms.append(norm)
            running += value
    finally:
        run.ident.encoder = encoder
    return running / max(steps_per_epoch - skipped, 1), lr, norms, skipped


def _on(device: torch.device, tensors):
    """``tensors`` (tensors, lists of them, None) on ``device`` (themselves on the CPU)."""
    if isinstance(tensors, (list, tuple)):
        return type(tensors)(_on(device, t) for t in tensors)
    return None if tensors is None else tensors.to(device)


def _progress(config: TrainConfig, done: float, start: float,
              ctx: distributed.Context) -> float:
    """The fraction of the budget spent after ``done`` epochs: of the epochs, or of the wall
    time (rank 0's clock) -- but a run the floor keeps going is only as far as its epochs
    towards ``min_epochs``, so the schedule stretches to the floor instead of idling at its
    end."""
    progress = done / config.epochs
    if config.seconds is not None:
        progress = max(progress, min(ctx.clock(start) / config.seconds,
                                     done / config.min_epochs))
    return progress


def _holdout_loss(run: _Run) -> float:
    """Stage 4: Eq. 14 on the held-out records, with fresh noise at the middle of the training
    range each epoch (the held-out generator's draws); data-parallel, each process evaluates
    its share of every chunk and the sums are added up across the processes."""
    data, ident, ctx = run.data, run.ident, run.ctx
    lo, hi = run.config.noise_range
    held_t = torch.as_tensor(data.held)
    ident.encoder.eval()
    total = 0.0
    with torch.no_grad():
        for i in range(0, len(held_t), 1024):
            idx = held_t[i: i + 1024]
            ys = [y[idx] for y in data.y]
            if hi > 0:
                level = (lo + hi) / 2
                ys = one_per_output(
                    lambda r, clean=ys, idx=idx, level=level: clean[r]
                    + (level * data.scale[idx, r])[:, None] * torch.randn(
                        clean[r].shape, generator=run.generators["held_generator"]),
                    len(ys), getattr(run.structure, "groups", None))
            mine = ctx.share(len(idx))
            if mine.stop == mine.start:
                continue
            y_, u_, yinf_, _ = _on(ctx.device, data.batch(idx[mine], [y[mine] for y in ys]))
            total += float(batch_loss(ident, y_, u_, yinf_, run.config.stationary_weight)) \
                * (mine.stop - mine.start)
    ident.encoder.train()
    return ctx.sum([total])[0] / len(held_t)


def _record(run: _Run, train_loss: float, held: float, lr: float, norms: list[float],
            skipped: int, elapsed: float) -> None:
    """After an epoch: its history, the best weights so far, and the checkpoint."""
    state = run.state
    hist = state["history"]
    hist["train_loss"].append(train_loss)
    hist["holdout_loss"].append(held)
    hist["lr"].append(lr)
    hist["seconds"].append(elapsed)
    hist["grad_norm_median"].append(float(np.median(norms)) if norms else math.nan)
    hist["grad_norm_max"].append(max(norms) if norms else math.nan)
    hist["skipped"].append(skipped)
    checkpoints.end_epoch(run, state, held, elapsed)


def _finish(run: _Run, head) -> Identifier:
    """Stage 5: warn if under-trained, load the best weights, record the history, the settings
    and the training range, calibrated with ``head`` (the identifier's)."""
    config, state, ident = run.config, run.state, run.ident
    notes = undertrained(config, state["history"], state["best"])
    for note in notes if run.ctx.writer else ():
        warnings.warn(f"{run.label or 'training'}: {note}", UndertrainedWarning, stacklevel=4)
    ident.encoder.to("cpu")                  # identification runs on the CPU
    if state["best_state"] is not None:
        ident.encoder.load_state_dict(state["best_state"])
    ident.encoder.eval()
    ident.meta["history"] = state["history"]
    ident.meta["train"] = {
        "epochs": state["epoch"], "seconds": round(state["elapsed"], 2),
        "best_holdout_loss": state["best"], "config": config_dict(config),
        "encoder": run.enc_config.to_dict(), "warnings": notes,
        "world_size": run.ctx.world_size, "backend": run.ctx.backend,
        "device": str(run.ctx.device),
    }
    ident.head = head
    ident.meta["training_range"] = training_range(ident, run.data.rec, run.data.held,
                                                  config.noise_range[1], config.seed + 4)
    return ident
