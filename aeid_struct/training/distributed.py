"""Data-parallel training on ``torch.distributed``: the process group that ``torchrun``
describes, each process's share of a global batch, sums across the processes, the device.

Launched by ``torchrun`` (which sets ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``, ``MASTER_ADDR``
and ``MASTER_PORT``), a training loop calls ``setup`` and gets a ``Context``: it joins the
process group (gloo on the CPU, NCCL on CUDA), wraps the encoder in
``DistributedDataParallel`` (``Context.wrap``) and lets each process compute the loss on its
share (``shares``) of every global batch. Every process holds the same weights, optimiser and
random streams (drawn for the whole global batch, so they stay in step); DDP averages the
gradients, and a process's loss is weighted by ``n_rank W / n`` so that the average is the
global batch's mean whatever the shares. Sums across processes (the held-out loss, the training
loss) go through ``Context.sum``; only rank 0 (``Context.writer``) writes. Fresh records are
drawn per record from a stream of their own (``row_records``), so each process simulates only
the records it trains on and the result does not depend on the number of processes; the generic
identifiers' windows (``train_generic``) come in blocks of ``BLOCK`` (``block_windows``). Not
launched by ``torchrun``, ``setup`` returns a one-process ``Context`` and nothing of this runs.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.distributed as dist

from aeid_struct.generic import normalise_windows
from aeid_struct.simulation import simulate
from aeid_struct.training.datasets import Records, excitations, summed_outputs
from aeid_struct.training.families import Systems

#: ``TrainConfig.device``'s values.
DEVICES = ("cpu", "cuda", "auto")
#: The variables ``torchrun`` sets for every process it starts.
LAUNCH_VARIABLES = ("RANK", "WORLD_SIZE", "LOCAL_RANK")
#: Fresh generic windows per random stream (``block_windows``): a process simulates whole
#: blocks, so a global batch whose shares are multiples of ``BLOCK`` wastes no simulation.
BLOCK = 64


def resolve_device(device: str, local_rank: int = 0) -> torch.device:
    """The torch device that ``TrainConfig.device`` names, for the process of ``local_rank``.

    Parameters
    ----------
    device : {"cpu", "cuda", "auto"}
        ``"auto"``: CUDA when torch finds a GPU, else the CPU.
    local_rank : int
        The process's rank on its node (``LOCAL_RANK``): it takes GPU
        ``local_rank % torch.cuda.device_count()``.

    Returns
    -------
    torch.device

    Raises
    ------
    ValueError
        ``device`` not one of ``DEVICES``, or ``"cuda"`` where torch finds no GPU.
    """
    if not isinstance(device, str) or device not in DEVICES:
        raise ValueError(f"device must be one of {DEVICES}; got {device!r}")
    if device == "cpu" or (device == "auto" and not torch.cuda.is_available()):
        return torch.device("cpu")
    if not torch.cuda.is_available():
        raise ValueError(f"device='cuda' but torch finds no CUDA GPU (torch {torch.__version__}, "
                         f"built for CUDA {torch.version.cuda}); use device='auto' to fall back "
                         "to the CPU, or device='cpu'")
    return torch.device("cuda", local_rank % torch.cuda.device_count())


def launched(env=None) -> bool:
    """Whether this process was started by ``torchrun`` (all of ``LAUNCH_VARIABLES`` set).

    Parameters
    ----------
    env : mapping, optional
        The environment (default ``os.environ``).

    Returns
    -------
    bool
    """
    env = os.environ if env is None else env
    return all(key in env for key in LAUNCH_VARIABLES)


def process_rank(env=None) -> int:
    """This process's rank under ``torchrun`` (``RANK``), 0 when not launched by it: the
    process that writes files and reports.

    Parameters
    ----------
    env : mapping, optional
        The environment (default ``os.environ``).

    Returns
    -------
    int
    """
    env = os.environ if env is None else env
    return int(env["RANK"]) if launched(env) else 0


def shares(count: int, world_size: int) -> list[slice]:
    """Each process's rows of a global batch of ``count`` rows: contiguous, in rank order,
    sizes differing by at most one (the first ``count % world_size`` ranks take one more).

    Parameters
    ----------
    count : int
        Rows of the global batch, ``>= 0``.
    world_size : int
        Processes, ``>= 1``.

    Returns
    -------
    list of ``world_size`` slices
        Covering ``range(count)`` exactly once.
    """
    if not isinstance(world_size, int) or world_size < 1:
        raise ValueError(f"world_size must be a positive integer; got {world_size!r}")
    if not isinstance(count, int) or count < 0:
        raise ValueError(f"count must be a non-negative integer; got {count!r}")
    size, extra = divmod(count, world_size)
    bounds = np.cumsum([0] + [size + (r < extra) for r in range(world_size)])
    return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


class _Parallel(torch.nn.parallel.DistributedDataParallel):
    """DDP that still answers ``config`` (the Identifier reads its encoder's config)."""

    @property
    def config(self):
        return self.module.config


@dataclass(frozen=True)
class Context:
    """The process's place in a data-parallel run (one process: the defaults).

    Attributes
    ----------
    rank, world_size, local_rank : int
        As ``torchrun`` numbers the processes.
    backend : str or None
        ``"gloo"`` or ``"nccl"``; None when not launched by ``torchrun``.
    device : torch.device
        Where the encoder, the decoder and the batches run.
    """

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    backend: str | None = None
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))

    @property
    def distributed(self) -> bool:
        """Whether the run is data-parallel (launched by ``torchrun``, any world size)."""
        return self.backend is not None

    @property
    def writer(self) -> bool:
        """Whether this process writes (checkpoints, the identifier, progress): rank 0."""
        return self.rank == 0

    def share(self, count: int) -> slice:
        """This process's rows of a global batch of ``count`` rows (``shares``)."""
        return shares(count, self.world_size)[self.rank]

    def sum(self, values) -> list[float]:
        """Sum float64 ``values`` over the processes (``all_reduce``); unchanged in one."""
        if not self.distributed:
            return [float(v) for v in values]
        t = torch.tensor([float(v) for v in values], dtype=torch.float64, device=self._comm)
        dist.all_reduce(t)
        return t.tolist()

    def clock(self, start: float) -> float:
        """Seconds since ``start`` by rank 0's clock, so that every process takes the same
        decisions from the wall time (a budget's end, the learning rate)."""
        elapsed = time.perf_counter() - start
        if not self.distributed:
            return elapsed
        t = torch.tensor([elapsed], dtype=torch.float64, device=self._comm)
        dist.broadcast(t, 0)
        return float(t[0])

    def barrier(self) -> None:
        """Wait for every process (nothing in one)."""
        if self.distributed:
            dist.barrier()

    def wrap(self, encoder: torch.nn.Module) -> torch.nn.Module:
        """``encoder`` in ``DistributedDataParallel`` (itself in one process): its backward
        averages the gradients over the processes."""
        if not self.distributed:
            return encoder
        ids = [self.device.index] if self.device.type == "cuda" else None
        return _Parallel(encoder, device_ids=ids)

    @property
    def _comm(self) -> torch.device:
        return self.device if self.backend == "nccl" else torch.device("cpu")


def setup(device: str, env=None) -> Context:
    """The run's ``Context``: one process, or the process group ``torchrun`` describes.

    Parameters
    ----------
    device : {"cpu", "cuda", "auto"}
        ``TrainConfig.device``; on CUDA the backend is NCCL, else gloo.
    env : mapping, optional
        The environment (default ``os.environ``).

    Returns
    -------
    Context
        Joined to the process group: created here, or the one already initialised (by an
        earlier run of the process, or by the caller). It stays for the process's later runs:
        a process group destroyed and created again under the same ``torchrun`` store can read
        the old group's addresses and fail to connect.

    Raises
    ------
    ValueError
        A bad ``device``, or torchrun's variables are not integers.
    RuntimeError
        The process group cannot be formed (the message says which variables it used).
    """
    env = os.environ if env is None else env
    if not launched(env):
        return Context(device=resolve_device(device))
    try:
        rank, world, local = (int(env[key]) for key in LAUNCH_VARIABLES)
    except ValueError:
        raise ValueError(f"torchrun's {', '.join(LAUNCH_VARIABLES)} must be integers; got "
                         f"{[env[k] for k in LAUNCH_VARIABLES]}") from None
    dev = resolve_device(device, local)
    if dist.is_initialized():
        return Context(rank=dist.get_rank(), world_size=dist.get_world_size(), local_rank=local,
                       backend=str(dist.get_backend()), device=dev)
    backend = "nccl" if dev.type == "cuda" else "gloo"
    if dev.type == "cuda":
        torch.cuda.set_device(dev)
    try:
        dist.init_process_group(backend, rank=rank, world_size=world)
    except (RuntimeError, ValueError) as err:
        where = f"{env.get('MASTER_ADDR', '?')}:{env.get('MASTER_PORT', '?')}"
        raise RuntimeError(f"training process {rank} of {world} could not join the process "
                           f"group ({backend} at {where}): {_first_line(err)}") from err
    return Context(rank=rank, world_size=world, local_rank=local, backend=backend, device=dev)


def _first_line(err: BaseException) -> str:
    line = (str(err).strip().splitlines() or [type(err).__name__])[0]
    return line if len(line) <= 240 else line[:240] + "..."


def failure(err: BaseException, ctx: Context, checkpoint) -> RuntimeError:
    """The error a process raises when a collective fails: another process died or stopped
    answering; it names this process, the cause and how to resume.

    Parameters
    ----------
    err : BaseException
        What torch raised.
    ctx : Context
    checkpoint : path or None
        ``TrainConfig.checkpoint``.

    Returns
    -------
    RuntimeError
    """
    resume = (f"launch the same command again to resume from the checkpoint {str(checkpoint)!r}"
              if checkpoint else "no checkpoint was set (TrainConfig.checkpoint), so a new "
              "launch starts over")
    return RuntimeError(f"training process {ctx.rank} of {ctx.world_size} ({ctx.backend}): a "
                        f"collective operation failed, another process probably died or stopped "
                        f"answering (torchrun's summary names it): {_first_line(err)}; {resume}")


def collective_error(err: BaseException) -> bool:
    """Whether ``err`` is a failed collective (a peer gone, a timeout) rather than a bug.

    Parameters
    ----------
    err : BaseException

    Returns
    -------
    bool
    """
    if isinstance(err, dist.DistError):
        return True
    text = str(err).lower()
    return isinstance(err, RuntimeError) and any(
        word in text for word in ("gloo", "nccl", "connection", "timed out", "peer"))


def row_records(family, config, epoch: int, rows) -> Records:
    """Fresh training records for ``rows``, each drawn from a stream of its own seeded by
    ``(seed, epoch, row)``: a record is the same whichever process draws it, with whichever
    others (``TrainConfig.fresh`` under ``torchrun``). The systems and excitations are drawn
    row by row, the exact simulation (Eq. 10-13) runs once for all of them.

    Parameters
    ----------
    family : LegFamily, PoleFamily or any family
    config : TrainConfig
        Its ``seed``, ``steps``, ``dt``, ``excitation`` and ``warmup``.
    epoch : int
    rows : (M,) int array
        Row indices of the run's record set, ``M >= 1``.

    Returns
    -------
    Records
        ``M`` noise-free records in the order of ``rows`` (``y == y_clean``, no ``x0``).
    """
    grid, warmup = config.grids, config.warmup
    systems, inputs = [], []
    for row in np.asarray(rows).reshape(-1):
        rng = np.random.default_rng([config.seed, 7919, epoch, int(row)])
        systems.append(family.sample(1, rng))
        inputs.append(excitations(family, grid, config.excitation, 1, warmup, rng))
    systems = Systems(*(np.concatenate([getattr(s, k) for s in systems]) for k in "Abcd"),
                      {k: np.concatenate([s.params[k] for s in systems])
                       for k in systems[0].params})
    u, y = [], []
    for r, (_, dt) in enumerate(grid):
        s = systems.record(r)
        u_r = np.concatenate([row[r] for row in inputs])
        y.append(simulate(s.A, s.b, s.c, s.d, u_r, dt)[:, warmup:])
        u.append(u_r[:, warmup:])
    y = summed_outputs(family, y)
    if len(grid) == 1:
        return Records(u[0], y[0], y[0], systems, grid[0][1], np.zeros(len(systems)))
    return Records(tuple(u), tuple(y), tuple(y), systems, tuple(g[1] for g in grid),
                   np.zeros(len(systems)))


def block_records(family, seed: int, count: int, window: int, epoch: int, block: int):
    """Block ``block`` of an epoch's fresh windows, unnormalised: ``family.records`` of its
    ``min(BLOCK, count - block BLOCK)`` windows on the generator seeded by
    ``(seed, epoch + 1, block)`` (a top-level function: worker processes run it,
    ``training.window_pool``).

    Parameters
    ----------
    family : object
        Gives ``records(count, steps, rng)`` with ``y`` and ``u`` of shape ``(count, steps)``.
    seed, count, window, epoch : int
        As :func:`block_windows`.
    block : int
        In ``[0, ceil(count / BLOCK))``.

    Returns
    -------
    y, u : (size, window) float64 arrays
    """
    size = min(BLOCK, count - block * BLOCK)
    rec = family.records(size, window, np.random.default_rng([seed, epoch + 1, block]))
    return np.asarray(rec.y, dtype=np.float64), np.asarray(rec.u, dtype=np.float64)


def block_windows(family, seed: int, count: int, window: int, epoch: int, rows, pool=None):
    """Rows of an epoch's fresh windows (``train_generic``): the epoch's ``count`` windows are
    blocks of ``BLOCK``, block ``k`` drawn (and simulated in one batch) by ``family.records`` from
    a generator seeded by ``(seed, epoch + 1, k)`` (:func:`block_records`); only the blocks that
    ``rows`` fall in are simulated, so a window is the same whichever process draws it, with
    whichever others, and whether a pool of workers simulated it or not.

    Parameters
    ----------
    family : object
        Gives ``records(count, steps, rng)`` with ``y`` and ``u`` of shape ``(count, steps)``.
    seed : int
        ``GenericTrainConfig.seed``.
    count : int
        Windows per epoch (``GenericTrainConfig.count``).
    window : int
        Samples per window.
    epoch : int
    rows : (M,) int array
        Row indices in ``[0, count)``.
    pool : training.window_pool.WindowPool, optional
        Simulates the blocks in worker processes (``pool.blocks(epoch, blocks)``); None: here.

    Returns
    -------
    y, u : (M, window) float64 tensors
        Normalised (:func:`~aeid_struct.generic.normalise_windows`), in the order of ``rows``;
        a window that could not be normalised (constant) is a ramp in both.
    ok : (M,) bool tensor
        The windows that could be normalised (the others weigh nothing in the loss).
    """
    rows = np.asarray(rows, dtype=np.int64).reshape(-1)
    y = torch.linspace(-1.0, 1.0, window, dtype=torch.float64).repeat(len(rows), 1)
    u, ok = y.clone(), torch.zeros(len(rows), dtype=torch.bool)
    blocks = np.unique(rows // BLOCK).tolist()
    got = (pool.blocks(epoch, blocks) if pool is not None else
           {k: block_records(family, seed, count, window, epoch, k) for k in blocks})
    for block in blocks:
        yb, ub, okb = normalise_windows(*(torch.from_numpy(a) for a in got[block]))
        at = np.flatnonzero(rows // BLOCK == block)
        keep = torch.as_tensor(at)[okb[rows[at] - block * BLOCK]]
        pick = torch.as_tensor(rows[keep.numpy()] - block * BLOCK)
        y[keep], u[keep], ok[keep] = yb[pick], ub[pick], True
    return y, u, ok


def gradient_step(opt, loss, params, clip: float) -> float | None:
    """One optimiser step of ``train()`` and ``train_generic()``: backward (DDP averages the
    gradients over the processes here), the gradient norm clipped at ``clip``, the step.

    Parameters
    ----------
    opt : torch.optim.Optimizer
    loss : 0-d tensor
        This process's share of the global batch's loss.
    params : list of tensors
        The encoder's parameters.
    clip : float
        Largest gradient norm (``inf``: none).

    Returns
    -------
    float or None
        The norm before clipping, or None where it is not finite (no step is taken: the batch
        is skipped on every process alike, as every process sees the same averaged gradient).
    """
    loss.backward()
    norm = float(torch.nn.utils.clip_grad_norm_(params, clip))
    if not math.isfinite(norm):
        return None
    opt.step()
    return norm

