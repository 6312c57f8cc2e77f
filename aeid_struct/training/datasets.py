"""Simulated record sets: what an identifier trains and is evaluated on.

A record set holds excitations ``u``, the exact FOH responses of the true systems (simulated by
this library's own decoder, Eq. 10-13) and, optionally, measurement noise: white Gaussian with
standard deviation ``noise * max|y_clean|`` per record, so a level is comparable across systems
of very different gains. Records start from rest, or mid-motion after a ``warmup``. The time grid
of each record (``grids``) is the one rule for ``dt`` and ``steps`` of the training package.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aeid_struct.simulation import output_groups, simulate, states
from aeid_struct.training.checks import count as counted
from aeid_struct.training.checks import value_range
from aeid_struct.training.excitation import EXCITATIONS, excitation
from aeid_struct.training.families import Systems


def grids(steps, dt, records: int | None = None) -> tuple[tuple[int, float], ...]:
    """The time grid ``(steps_r, dt_r)`` of each record, validated.

    One record is given by numbers, several (a structure of ``R`` subsystems, e.g. the joint
    leg) by tuples (or lists) with one entry per record. Every record needs ``steps >= 2``
    samples: a response from rest is ``y_0 = d u_0``, zero for a strictly proper system, so a
    one-sample record has nothing to identify (and Eq. 15 would divide by ``max|y| = 0``).

    Parameters
    ----------
    steps : int or tuple of int
        Samples per record, each an integer ``>= 2``.
    dt : float or tuple of float
        Sample time per record (s), each positive and finite.
    records : int, optional
        Records per parameter set the grids must describe: 1 (numbers, or 1-tuples) or ``R``
        (tuples of ``R``); None (default): any count, as long as ``steps`` and ``dt`` agree.

    Returns
    -------
    grids : tuple of (steps_r, dt_r)
        One ``(int, float)`` pair per record.

    Raises
    ------
    ValueError
        Naming ``steps`` or ``dt``, what was expected and what came.
    """
    steps_t = tuple(steps) if isinstance(steps, (tuple, list)) else (steps,)
    dt_t = tuple(dt) if isinstance(dt, (tuple, list)) else (dt,)
    if records is None:
        if len(steps_t) != len(dt_t) or not steps_t:
            raise ValueError(f"dt and steps must have one entry per record alike; got "
                             f"dt={dt!r}, steps={steps!r}")
        how = " (or a tuple of them, one per record)"
    elif records > 1:
        if len(steps_t) != records or len(dt_t) != records:
            raise ValueError(f"steps and dt must be tuples of {records} entries (one per record) "
                             f"for this family; got steps={steps!r}, dt={dt!r}")
        how = f" in each of the {records} entries (one per record)"
    else:
        if len(steps_t) != 1 or len(dt_t) != 1:
            raise ValueError(f"steps and dt must be single numbers for a family of one record; "
                             f"got steps={steps!r}, dt={dt!r}")
        how = ""
    for s in steps_t:
        if not isinstance(s, int) or isinstance(s, bool) or s < 2:
            raise ValueError(f"steps must be an integer >= 2{how}; got {steps!r}")
    for t in dt_t:
        if not (isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t)
                and t > 0):
            raise ValueError(f"dt must be a positive finite number{how}; got {dt!r}")
    return tuple((s, float(t)) for s, t in zip(steps_t, dt_t, strict=True))


def holdout_split(count: int, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The training and held-out record indices of a run (paper Sec. IV: 80/20).

    ``recalibrate`` re-creates a run's split from its stored settings with this function.

    Parameters
    ----------
    count : int
        Records in the set.
    holdout : float
        The share held out, in ``(0, 1)``.
    seed : int
        The run's seed (the permutation is drawn with ``seed + 1``).

    Returns
    -------
    train : (count - held,) int array
    held : (held,) int array
        ``held = int(count * holdout)`` indices.
    """
    held = int(count * holdout)
    order = np.random.default_rng(seed + 1).permutation(count)
    return order[held:], order[:held]


@dataclass(frozen=True)
class Records:
    """Simulated measurements of a batch of true systems.

    Systems of several records (``systems.records = R > 1``) have a record on its own grid
    each: ``u, y, y_clean`` are then tuples of ``R`` arrays ``(N, steps_r)`` and ``dt`` a tuple.

    Attributes
    ----------
    u : (N, steps) array
        Inputs.
    y : (N, steps) array
        Measured (noisy) outputs.
    y_clean : (N, steps) array
        Noise-free outputs.
    systems : Systems
        The true systems.
    dt : float or tuple of float
        Sample time (s).
    noise : (N,) array
        Per-record noise level (std relative to ``max|y_clean|``).
    x0 : (N, n) array or None
        State at the first sample of records that start mid-motion (``warmup > 0``); None for
        records from rest.
    """

    u: np.ndarray
    y: np.ndarray
    y_clean: np.ndarray
    systems: Systems
    dt: float
    noise: np.ndarray
    x0: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.noise)

    def record(self, r: int) -> Records:
        """The records of subsystem ``r`` alone (one record per system, its own grid), e.g. to
        score a single-subsystem identifier on the systems of a joint set.

        Parameters
        ----------
        r : int
            In ``[0, R)``; 0 for a set of one record per system.

        Returns
        -------
        Records
        """
        if not isinstance(self.u, tuple):
            if r != 0:
                raise ValueError(f"r must be 0 for a set of one record per system; got {r!r}")
            return self
        if not isinstance(r, int) or not 0 <= r < len(self.u):
            raise ValueError(f"r must be a record index in [0, {len(self.u)}); got {r!r}")
        return Records(self.u[r], self.y[r], self.y_clean[r], self.systems.record(r),
                       self.dt[r], self.noise,
                       None if self.x0 is None else self.x0[r])

    def take(self, index) -> Records:
        """The records at ``index``.

        Parameters
        ----------
        index : int array, slice or boolean mask
            Along the batch axis.

        Returns
        -------
        Records
        """
        def pick(x):
            return tuple(r[index] for r in x) if isinstance(x, tuple) else x[index]

        return Records(pick(self.u), pick(self.y), pick(self.y_clean),
                       self.systems.take(index), self.dt, self.noise[index],
                       None if self.x0 is None else pick(self.x0))


def _noise(noise) -> float | tuple[float, float]:
    """``noise`` checked: a finite level >= 0, or a ``(lo, hi)`` range of them."""
    what = f"noise must be a finite level >= 0 or a (lo, hi) range; got {noise!r}"
    if np.ndim(noise) == 0:
        if isinstance(noise, (bool, str, bytes)) or not (
                isinstance(noise, (int, float, np.integer, np.floating))
                and math.isfinite(noise) and noise >= 0):
            raise ValueError(what)
        return float(noise)
    lo, hi = value_range("noise", noise)
    if lo < 0:
        raise ValueError(what)
    return lo, hi


def excitations(family, grid, kind: str, count: int, warmup: int,
                rng: np.random.Generator) -> list[np.ndarray]:
    """The inputs of ``count`` systems' records, one ``(count, warmup + steps_r)`` array per
    record of ``grid``; records that are channels of one experiment (the family's
    ``shared_inputs``: one input index per record) read one excitation per input.

    Parameters
    ----------
    family : object
        Its optional ``shared_inputs``.
    grid : tuple of (steps_r, dt_r)
    kind : str
        One of ``EXCITATIONS``.
    count, warmup : int
    rng : numpy.random.Generator

    Returns
    -------
    list of R arrays

    Raises
    ------
    ValueError
        Channels of one input on different grids.
    """
    shared = getattr(family, "shared_inputs", None)
    u = []
    for r, (steps_r, dt_r) in enumerate(grid):
        first = r if shared is None else shared.index(shared[r])
        if first < r:
            if grid[first] != grid[r]:
                raise ValueError(f"records {first} and {r} are channels of one input: steps "
                                 f"and dt must be equal; got {grid[first]} and {grid[r]}")
            u.append(u[first])
        else:
            u.append(excitation(kind, count, steps_r + warmup, dt_r, rng, first=warmup))
    return u


def one_per_output(measure, R: int, groups: tuple | None) -> list:
    """Records that are channels of one output hold one measurement of it: ``measure(r)``
    (the record ``r`` with its measurement noise) for the first record of each output, in
    record order, shared by the output's other records (``Physical.groups``; every record its
    own output where None). Noise is so drawn once per output, and no draw is thrown away:
    where ``groups`` is None the draws are exactly those of measuring every record in turn.

    Parameters
    ----------
    measure : callable
        ``r -> array or tensor``.
    R : int
        Records.
    groups : tuple of R ints or None

    Returns
    -------
    list of R arrays or tensors
    """
    keys = range(R) if groups is None else groups
    measured = {}
    for r, g in enumerate(keys):
        if g not in measured:
            measured[g] = measure(r)
    return [measured[g] for g in keys]


def summed_outputs(family, ys: list) -> list:
    """The records' outputs where the family's records are channels of outputs whose inputs
    move at once (its ``shared_outputs``, ``Physical.groups``): each record holds the sum of its
    output's channels (one array per output); ``ys`` as it is otherwise.

    Parameters
    ----------
    family : object
        Its optional ``shared_outputs``.
    ys : list of R (count, steps) arrays
        Each channel's response.

    Returns
    -------
    list of R arrays
    """
    groups = getattr(family, "shared_outputs", None)
    if groups is None:
        return ys
    out = list(ys)
    for group in output_groups(groups, len(ys)):
        total = sum(ys[r] for r in group)
        for r in group:
            out[r] = total
    return out


def records(family, count: int, *, steps, dt, excitation_kind: str = "step",
            noise=0.0, seed: int = 0, warmup: int = 0) -> Records:
    """Sample ``count`` systems from ``family``, excite and simulate them exactly (Eq. 10-13).

    Parameters
    ----------
    family : LegFamily, PoleFamily or any object with ``sample(count, rng) -> Systems``
        The true systems; its ``records`` (default 1) is the records per system, and its
        ``shared_inputs`` (optional, one input index per record) marks records that are channels
        of one experiment: records of one input share its excitation; its ``shared_outputs``
        (optional, one output index per record) marks channels of one output whose inputs move
        at once: their responses sum into that output, measured (noise drawn) once, and each
        of its records holds it.
    count : int
        Records (systems), positive.
    steps : int or tuple of int
        Samples per record (``grids``); for a family of several records (the joint leg) a tuple,
        one per record, and every record gets its own excitation (but for shared inputs) and
        noise draw at the same level.
    dt : float or tuple of float
        Sample time per record (s), like ``steps``.
    excitation_kind : str
        One of ``EXCITATIONS``.
    noise : float or (lo, hi)
        A level (std relative to ``max|y_clean|``) or a range drawn per record.
    seed : int
        Seeds every draw.
    warmup : int
        Samples simulated (from rest, with the same excitation) before each record begins, so
        that records start mid-motion, like windows cut from a running system; their initial
        states are ``Records.x0``. 0: records from rest (the paper).

    Returns
    -------
    Records
        ``u, y, y_clean (count, steps)`` (tuples of ``R`` for several records).
    """
    count = counted("count", count)
    if not callable(getattr(family, "sample", None)):
        raise ValueError(f"family must sample systems (LegFamily, PoleFamily: a "
                         f"sample(count, rng) method); got {type(family).__name__}")
    if excitation_kind not in EXCITATIONS:
        raise ValueError(f"excitation_kind must be one of {EXCITATIONS}; got "
                         f"{excitation_kind!r}")
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) \
            or seed < 0:
        raise ValueError(f"seed must be a non-negative integer; got {seed!r}")
    noise = _noise(noise)
    R = getattr(family, "records", 1)
    grid = grids(steps, dt, R)
    if not isinstance(warmup, int) or isinstance(warmup, bool) or warmup < 0:
        raise ValueError(f"warmup must be a non-negative integer; got {warmup!r}")
    rng = np.random.default_rng(seed)
    systems = family.sample(count, rng)
    u = excitations(family, grid, excitation_kind, count, warmup, rng)
    # a range is drawn per record, after the excitations (the order fixes what a seed gives)
    level = (np.full(count, noise) if isinstance(noise, float)
             else rng.uniform(*noise, size=count))
    clean, x0 = [], []
    for r, (_, dt_r) in enumerate(grid):
        s = systems.record(r)
        clean.append(simulate(s.A, s.b, s.c, s.d, u[r], dt_r)[:, warmup:])
        if warmup:
            x0.append(states(s.A, s.b, u[r][:, : warmup + 1], dt_r)[:, warmup])
    clean = summed_outputs(family, clean)
    # the channels of one output (its inputs moving at once) are measured once
    noisy = one_per_output(lambda r: clean[r] + (level * np.max(np.abs(clean[r]), axis=1))[
        :, None] * rng.normal(size=clean[r].shape), R, getattr(family, "shared_outputs", None))
    parts = [(u[r][:, warmup:], noisy[r], clean[r]) for r in range(R)]
    if R == 1:
        return Records(*parts[0], systems, grid[0][1], level, x0[0] if x0 else None)
    u, y, y_clean = (tuple(p[i] for p in parts) for i in range(3))
    return Records(u, y, y_clean, systems, tuple(g[1] for g in grid), level,
                   tuple(x0) if x0 else None)
