"""System families, excitation signals and simulated record sets.

A *family* samples true systems: the two robot-leg subsystems through the CasADi maps of
``symbolic.leg`` with the paper's parameter ranges (Sec. IV), or generic families given pole and
gain ranges. A *record set* is what an identifier trains and is evaluated on: excitations ``u``,
the exact FOH responses from rest (simulated by this library's own decoder, Eq. 10-13) and,
optionally, measurement noise.

Conventions (DESIGN.md): ``t_k = k*dt``, ``k = 0..steps-1``, zero initial state, first-order hold
between samples, a unit step is ``u_k = 1`` for all k. Noise is white Gaussian with standard
deviation ``noise * max|y_clean|`` per record, so a level is comparable across systems of very
different gains. Every random draw comes from an explicit seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from aeid_struct.simulation import simulate, states

EXCITATIONS = ("step", "ramp", "prbs", "multisine", "noise", "steps", "mix")


@dataclass(frozen=True)
class Systems:
    """A batch of true SISO systems.

    Attributes:
        A: ``(N, n, n)``; b, c: ``(N, n)``; d: ``(N,)`` -- float64. Systems of several records
            (one parameter set, ``R`` subsystems) carry a record axis: ``A (N, R, n, n)``,
            ``b, c (N, R, n)``, ``d (N, R)``.
        params: physical parameters by name, each ``(N,)`` (empty for generic families).
    """

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    params: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return self.A.shape[0]

    @property
    def records(self) -> int:
        """Subsystems per parameter set (1 without a record axis)."""
        return self.A.shape[1] if self.A.ndim == 4 else 1

    def record(self, r: int) -> Systems:
        """The systems of record ``r`` alone, without the record axis."""
        if self.records == 1:
            return self
        return Systems(self.A[:, r], self.b[:, r], self.c[:, r], self.d[:, r], self.params)

    def take(self, index) -> Systems:
        """The systems at ``index`` (an int array, slice or boolean mask)."""
        return Systems(
            self.A[index], self.b[index], self.c[index], self.d[index],
            {k: v[index] for k, v in self.params.items()},
        )


def _positive(name: str, value) -> float:
    """A positive finite number (not a bool, not a string), or a ValueError naming it."""
    if not (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, (bool, np.bool_)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number; got {value!r}")
    return float(value)


def _count(name: str, value) -> int:
    """A positive integer (not a bool), or a ValueError naming it."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or value < 1:
        raise ValueError(f"{name} must be a positive integer; got {value!r}")
    return int(value)


def _check_sample(count, rng) -> None:
    """The arguments of a family's ``sample``: a positive integer and a numpy Generator."""
    _count("count", count)
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator (np.random.default_rng(seed)); "
                         f"got {type(rng).__name__}")


def _check_range(name: str, value) -> tuple[float, float]:
    try:
        if isinstance(value, (str, bytes)):
            raise TypeError    # "12" would unpack to (1.0, 2.0)
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (lo, hi) pair of numbers; got {value!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
        raise ValueError(f"{name} must satisfy lo <= hi, both finite; got ({lo}, {hi})")
    return lo, hi


@dataclass(frozen=True, kw_only=True)
class LegFamily:
    """The robot-leg subsystems of paper Sec. IV with (k, d, m) drawn uniformly from ``ranges``.

    ``subsystem="stable"``: translational, ``G1 = (1/m) / (s^2 + (d/m) s + k/m)``;
    ``subsystem="unstable"``: rotational, ``G2 = (1/(m L^2)) / (s^2 - g/L)``, ``L = l0 - m g/k``;
    ``subsystem="joint"``: both, one parameter set and two records (record axis: G1, G2).
    Systems come in the bottom-row CCF that ``symbolic.leg`` derives. A range with
    ``lo == hi`` holds that parameter at a known value (e.g. a known mass).
    """

    subsystem: str = "stable"
    ranges: dict = field(default_factory=lambda: {"k": (20.0, 25.0), "d": (2.0, 5.0),
                                                  "m": (0.5, 1.5)})
    l0: float = 0.8
    g: float = 9.81

    def __post_init__(self) -> None:
        if self.subsystem not in ("stable", "unstable", "joint"):
            raise ValueError(
                f"subsystem must be 'stable', 'unstable' or 'joint'; got {self.subsystem!r}"
            )
        if not isinstance(self.ranges, dict):
            raise ValueError(f"ranges must be a dict name -> (lo, hi) for k, d, m; got "
                             f"{type(self.ranges).__name__}")
        object.__setattr__(self, "l0", _positive("l0", self.l0))
        object.__setattr__(self, "g", _positive("g", self.g))
        if set(self.ranges) != {"k", "d", "m"}:
            raise ValueError(f"ranges must name exactly k, d, m; got {sorted(self.ranges)}")
        ranges = {}
        for name, value in self.ranges.items():
            lo, hi = _check_range(f"ranges[{name!r}]", value)
            if lo <= 0:
                raise ValueError(f"ranges[{name!r}] must be positive; got ({lo}, {hi})")
            ranges[name] = (lo, hi)
        object.__setattr__(self, "ranges", ranges)
        if self.ranges["m"][1] * self.g / self.ranges["k"][0] >= self.l0:
            raise ValueError(
                "ranges give a leg compressed past zero length (m g / k >= l0); "
                f"got m up to {self.ranges['m'][1]}, k down to {self.ranges['k'][0]}"
            )

    @property
    def records(self) -> int:
        """Records per parameter set: 2 for the joint leg, else 1."""
        return 2 if self.subsystem == "joint" else 1

    def map(self):
        """The CasADi map (k, d, m) -> CCF (A, B, C, D) of this subsystem (``A1, .., D2`` for
        the joint leg)."""
        from symbolic import leg

        f = {"stable": leg.stable_map, "unstable": leg.unstable_map,
             "joint": leg.joint_map}[self.subsystem]
        return f(l0=self.l0, g=self.g)

    def inverse(self):
        """The CasADi inverse of ``map()``: a CCF (A, B, C, D) -> the physical parameters
        (k, d, m for the stable subsystem and the joint leg; k, m for the unstable one, which d
        does not enter)."""
        from symbolic import leg

        f = {"stable": leg.stable_inverse, "unstable": leg.unstable_inverse,
             "joint": leg.joint_inverse}[self.subsystem]
        return f(l0=self.l0, g=self.g)

    def systems(self, k, d, m) -> Systems:
        """The subsystems of given parameter arrays ``(N,)`` (vectorised through ``f.map``):
        positive, finite, one length, and for the rotational subsystem a leg not compressed
        past zero length (``m g / k < l0``)."""
        arrays = {}
        for name, v in (("k", k), ("d", d), ("m", m)):
            try:
                arr = np.atleast_1d(np.asarray(v, dtype=np.float64))
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a positive number or a (N,) array of them; "
                                 f"got {type(v).__name__}") from None
            if arr.ndim != 1 or not np.all(np.isfinite(arr) & (arr > 0)):
                raise ValueError(f"{name} must be a positive finite number or a (N,) array of "
                                 f"them; got {v!r}")
            arrays[name] = arr
        if len({a.shape for a in arrays.values()}) > 1:
            raise ValueError(f"k, d and m must have one length; got "
                             f"{', '.join(f'{n} {a.shape}' for n, a in arrays.items())}")
        if self.subsystem != "stable" and np.any(arrays["m"] * self.g / arrays["k"] >= self.l0):
            # the rotational subsystem's length L = l0 - m g / k must be positive
            raise ValueError(f"k and m give a leg compressed past zero length (m g / k >= l0 = "
                             f"{self.l0})")
        k, d, m = arrays["k"], arrays["d"], arrays["m"]
        if self.subsystem == "joint":
            parts = [LegFamily(subsystem=s, ranges=self.ranges, l0=self.l0, g=self.g)
                     .systems(k, d, m) for s in ("stable", "unstable")]
            return Systems(*(np.stack([getattr(p, f) for p in parts], 1) for f in "Abcd"),
                           parts[0].params)
        k, d, m = (np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in (k, d, m))
        count = k.shape[0]
        f = self.map().map(count)
        out = f(k=k[None, :], d=d[None, :], m=m[None, :])
        # Mapped outputs are concatenated horizontally: A (n, n*N), B (n, N), C (1, n*N), D (1, N)
        A = np.array(out["A"]).reshape(2, count, 2).transpose(1, 0, 2)
        b = np.array(out["B"]).T
        c = np.array(out["C"]).reshape(count, 2)
        dd = np.array(out["D"]).reshape(count)
        return Systems(A, b, c, dd, {"k": k, "d": d, "m": m})

    def sample(self, count: int, rng: np.random.Generator) -> Systems:
        """``count`` systems with (k, d, m) uniform in ``ranges``."""
        _check_sample(count, rng)
        draws = {n: rng.uniform(*self.ranges[n], size=count) for n in ("k", "d", "m")}
        return self.systems(**draws)


@dataclass(frozen=True, kw_only=True)
class PoleFamily:
    """Generic stable all-pole systems ``G(s) = g * a0 / prod(s - p_i)`` (static gain ``g``).

    ``real`` real poles with ``-p`` uniform in ``decay``; ``pairs`` complex pairs
    ``-sigma +- j omega`` with ``sigma`` uniform in ``decay`` and ``omega`` in ``freq``; the
    static gain is uniform in ``gain``. Realised in bottom-row CCF.
    """

    real: int = 1
    pairs: int = 1
    decay: tuple[float, float] = (0.5, 5.0)
    freq: tuple[float, float] = (1.0, 10.0)
    gain: tuple[float, float] = (0.5, 2.0)

    def __post_init__(self) -> None:
        for name in ("real", "pairs"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{name} must be a non-negative integer; got {v!r}")
        if self.real + self.pairs == 0:
            raise ValueError("real + pairs must be at least 1; got 0 poles")
        for name in ("decay", "freq", "gain"):
            lo, hi = _check_range(name, getattr(self, name))
            if lo <= 0:
                raise ValueError(f"{name} must be positive; got ({lo}, {hi})")
            object.__setattr__(self, name, (lo, hi))

    @property
    def n(self) -> int:
        return self.real + 2 * self.pairs

    def sample(self, count: int, rng: np.random.Generator) -> Systems:
        """``count`` systems of the family."""
        _check_sample(count, rng)
        n = self.n
        poles = [-rng.uniform(*self.decay, size=count) + 0j for _ in range(self.real)]
        for _ in range(self.pairs):
            p = -rng.uniform(*self.decay, size=count) + 1j * rng.uniform(*self.freq, size=count)
            poles += [p, p.conj()]
        P = np.stack(poles, axis=1)                              # (N, n)
        den = np.real(np.stack([np.poly(row) for row in P]))     # (N, n+1), monic
        a = den[:, 1:][:, ::-1]                                  # a0..a_{n-1}
        A = np.zeros((count, n, n))
        A[:, np.arange(n - 1), np.arange(1, n)] = 1.0
        A[:, -1, :] = -a
        b = np.zeros((count, n))
        b[:, -1] = 1.0
        c = np.zeros((count, n))
        c[:, 0] = rng.uniform(*self.gain, size=count) * a[:, 0]
        return Systems(A, b, c, np.zeros(count))


def excitation(kind: str, count: int, steps: int, dt: float,
               rng: np.random.Generator, *, first: int = 0) -> np.ndarray:
    """Input records ``u (count, steps)`` of one kind.

    - ``step``: unit step ``u_k = 1`` (the paper's excitation).
    - ``ramp``: ``u_k = t_k / t_end``.
    - ``prbs``: random +-1 levels held for 3-12 samples (a pseudo-random binary sequence).
    - ``multisine``: 4 random-phase sines between 0.2 and 10 Hz (below Nyquist), peak 1.
    - ``noise``: Gaussian noise low-pass filtered (first order, 5 Hz), peak 1.
    - ``steps``: a step of random height in [0.5, 2] at a random sample in the first quarter of
      the samples from ``first`` on (zero before it).
    - ``mix``: each record of a kind drawn at random among ``steps``, ``prbs``, ``multisine``
      and ``noise``.

    ``first``: where the record proper begins (``records(warmup=...)``). Why: a step in the
    first quarter of warmup + window has settled before a mid-motion window opens, and a flat
    window identifies nothing.
    """
    if kind not in EXCITATIONS:
        raise ValueError(f"kind must be one of {EXCITATIONS}; got {kind!r}")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator (np.random.default_rng(seed)); "
                         f"got {type(rng).__name__}")
    t = np.arange(steps) * dt
    if kind == "step":
        return np.ones((count, steps))
    if kind == "ramp":
        return np.tile(t / max(t[-1], dt), (count, 1))
    if kind == "prbs":
        # Each record: levels +-1 held for 3-12 samples. Mark where each hold ends, and the
        # running count of marks is every sample's segment: no loop over the records.
        ends = np.cumsum(rng.integers(3, 13, size=(count, steps)), axis=1)
        marks = np.zeros((count, steps + 1), dtype=np.int64)
        rows, cols = np.nonzero(ends < steps)
        marks[rows, ends[rows, cols]] = 1
        segment = np.cumsum(marks[:, :steps], axis=1)
        levels = rng.choice([-1.0, 1.0], size=(count, steps))
        return np.take_along_axis(levels, segment, axis=1)
    if kind == "multisine":
        fmax = min(10.0, 0.4 / dt)
        f = rng.uniform(0.2, fmax, size=(count, 4, 1))
        phase = rng.uniform(0, 2 * np.pi, size=(count, 4, 1))
        u = np.sin(2 * np.pi * f * t[None, None, :] + phase).sum(axis=1)
        return u / np.max(np.abs(u), axis=1, keepdims=True)
    if kind == "steps":
        height = rng.uniform(0.5, 2.0, size=(count, 1))
        start = first + rng.integers(0, max((steps - first) // 4, 1), size=(count, 1))
        return height * (np.arange(steps)[None, :] >= start)
    if kind == "noise":
        from scipy.signal import lfilter

        alpha = np.exp(-2 * np.pi * 5.0 * dt)
        u = lfilter([1 - alpha], [1, -alpha], rng.normal(size=(count, steps)), axis=1)
        return u / np.max(np.abs(u), axis=1, keepdims=True)
    # mix
    kinds = ("step", "prbs", "multisine", "noise")
    pick = rng.integers(0, len(kinds), size=count)
    u = np.empty((count, steps))
    for j, sub in enumerate(kinds):
        idx = np.flatnonzero(pick == j)
        if idx.size == 0:
            continue
        u[idx] = excitation("steps" if sub == "step" else sub, idx.size, steps, dt, rng,
                            first=first)
    return u


@dataclass(frozen=True)
class Records:
    """Simulated measurements.

    Attributes:
        u: ``(N, steps)`` inputs; y: ``(N, steps)`` measured (noisy) outputs;
        y_clean: ``(N, steps)`` noise-free outputs; systems: the true systems;
        dt: sample time; noise: per-record noise level (std relative to max|y_clean|), ``(N,)``.
        x0: ``(N, n)`` state at the first sample (records that start mid-motion, ``warmup``
            > 0), or None for records from rest.

    Systems of several records (``systems.records = R > 1``) have a record on its own grid each:
    ``u, y, y_clean`` are then tuples of ``R`` arrays ``(N, steps_r)`` and ``dt`` a tuple.
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
        score a single-subsystem identifier on the systems of a joint set."""
        if not isinstance(self.u, tuple):
            if r != 0:
                raise ValueError(f"r must be 0 for a set of one record per system; got {r!r}")
            return self
        if not isinstance(r, int) or not 0 <= r < len(self.u):
            raise ValueError(f"r must be a record index in [0, {len(self.u)}); got {r!r}")
        return Records(self.u[r], self.y[r], self.y_clean[r], self.systems.record(r),
                       self.dt[r], self.noise, None if self.x0 is None else self.x0[r])

    def take(self, index) -> Records:
        def pick(x):
            return tuple(r[index] for r in x) if isinstance(x, tuple) else x[index]

        return Records(pick(self.u), pick(self.y), pick(self.y_clean),
                       self.systems.take(index), self.dt, self.noise[index],
                       None if self.x0 is None else pick(self.x0))


def records(family, count: int, *, steps, dt, excitation_kind: str = "step",
            noise=0.0, seed: int = 0, warmup: int = 0) -> Records:
    """Sample ``count`` systems from ``family``, excite and simulate them exactly.

    Args:
        family: a family with ``sample(count, rng) -> Systems`` (``LegFamily``, ``PoleFamily``).
        count, steps, dt: how many records, of how many samples, at what sample time; for a
            family of several records (the joint leg) ``steps`` and ``dt`` are tuples, one per
            record, and every record gets its own excitation and noise draw at the same level.
        excitation_kind: one of ``EXCITATIONS``.
        noise: a level (std relative to max|y_clean|) or a (lo, hi) range drawn per record.
        seed: seeds every draw.
        warmup: samples simulated (from rest, with the same excitation) before each record
            begins, so that records start mid-motion, like windows cut from a running system;
            their initial states are ``Records.x0``. 0: records from rest (the paper).
    """
    count = _count("count", count)
    if not callable(getattr(family, "sample", None)):
        raise ValueError(f"family must sample systems (LegFamily, PoleFamily: a "
                         f"sample(count, rng) method); got {type(family).__name__}")
    if excitation_kind not in EXCITATIONS:
        raise ValueError(f"excitation_kind must be one of {EXCITATIONS}; got "
                         f"{excitation_kind!r}")
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) \
            or seed < 0:
        raise ValueError(f"seed must be a non-negative integer; got {seed!r}")
    if np.ndim(noise) == 0:
        if isinstance(noise, (bool, str, bytes)) or not (
                isinstance(noise, (int, float, np.integer, np.floating))
                and math.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise must be a finite level >= 0 or a (lo, hi) range; got "
                             f"{noise!r}")
    else:
        lo, hi = _check_range("noise", noise)
        if lo < 0:
            raise ValueError(f"noise must be a finite level >= 0 or a (lo, hi) range; got "
                             f"{noise!r}")
    R = getattr(family, "records", 1)
    grids = _grids(steps, dt, R)
    if not isinstance(warmup, int) or isinstance(warmup, bool) or warmup < 0:
        raise ValueError(f"warmup must be a non-negative integer; got {warmup!r}")
    rng = np.random.default_rng(seed)
    systems = family.sample(count, rng)
    u = [excitation(excitation_kind, count, steps_r + warmup, dt_r, rng, first=warmup)
         for steps_r, dt_r in grids]
    if np.ndim(noise) == 0:
        level = np.full(count, float(noise))
    else:
        level = rng.uniform(*_check_range("noise", noise), size=count)
    if np.any(level < 0):
        raise ValueError(f"noise must be >= 0; got {noise!r}")
    parts, x0 = [], []
    for r, (_, dt_r) in enumerate(grids):
        s = systems.record(r)
        y_clean = simulate(s.A, s.b, s.c, s.d, u[r], dt_r)[:, warmup:]
        if warmup:
            x0.append(states(s.A, s.b, u[r][:, : warmup + 1], dt_r)[:, warmup])
        scale = level * np.max(np.abs(y_clean), axis=1)
        parts.append((u[r][:, warmup:], y_clean + scale[:, None] * rng.normal(size=y_clean.shape),
                      y_clean))
    x0 = x0 or None
    if R == 1:
        return Records(*parts[0], systems, grids[0][1], level, x0[0] if x0 else None)
    u, y, y_clean = (tuple(p[i] for p in parts) for i in range(3))
    return Records(u, y, y_clean, systems, tuple(g[1] for g in grids), level,
                   tuple(x0) if x0 else None)


def _grids(steps, dt, records: int) -> list[tuple[int, float]]:
    """``(steps_r, dt_r)`` per record, validated: ints ``>= 2`` and positive finite ``dt``."""
    steps_t = tuple(steps) if isinstance(steps, (tuple, list)) else (steps,)
    dt_t = tuple(dt) if isinstance(dt, (tuple, list)) else (dt,)
    if records > 1 and (len(steps_t) != records or len(dt_t) != records):
        raise ValueError(f"steps and dt must be tuples of {records} entries (one per record) "
                         f"for this family; got steps={steps!r}, dt={dt!r}")
    if records == 1 and (len(steps_t) != 1 or len(dt_t) != 1):
        raise ValueError(f"steps and dt must be single numbers for a family of one record; "
                         f"got steps={steps!r}, dt={dt!r}")
    for s in steps_t:
        if not isinstance(s, int) or isinstance(s, bool) or s < 2:
            raise ValueError(f"steps must be an integer >= 2; got {steps!r}")
    for t in dt_t:
        if not (isinstance(t, (int, float)) and np.isfinite(t) and t > 0):
            raise ValueError(f"dt must be a positive finite number; got {dt!r}")
    return [(s, float(t)) for s, t in zip(steps_t, dt_t, strict=True)]
