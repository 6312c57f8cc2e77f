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

from dataclasses import dataclass, field

import numpy as np

from .decoder import simulate

EXCITATIONS = ("step", "ramp", "prbs", "multisine", "noise", "mix")


@dataclass(frozen=True)
class Systems:
    """A batch of true SISO systems.

    Attributes:
        A: ``(N, n, n)``; b, c: ``(N, n)``; d: ``(N,)`` -- float64.
        params: physical parameters by name, each ``(N,)`` (empty for generic families).
    """

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    params: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return self.A.shape[0]

    def take(self, index) -> Systems:
        """The systems at ``index`` (an int array, slice or boolean mask)."""
        return Systems(
            self.A[index], self.b[index], self.c[index], self.d[index],
            {k: v[index] for k, v in self.params.items()},
        )


def _check_range(name: str, value) -> tuple[float, float]:
    try:
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
    ``subsystem="unstable"``: rotational, ``G2 = (1/(m L^2)) / (s^2 - g/L)``, ``L = l0 - m g/k``.
    Systems come in the bottom-row CCF that ``symbolic.leg`` derives.
    """

    subsystem: str = "stable"
    ranges: dict = field(default_factory=lambda: {"k": (20.0, 25.0), "d": (2.0, 5.0),
                                                  "m": (0.5, 1.5)})
    l0: float = 0.8
    g: float = 9.81

    def __post_init__(self) -> None:
        if self.subsystem not in ("stable", "unstable"):
            raise ValueError(
                f"subsystem must be 'stable' or 'unstable'; got {self.subsystem!r}"
            )
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

    def map(self):
        """The CasADi map (k, d, m) -> CCF (A, B, C, D) of this subsystem."""
        from symbolic import leg

        f = leg.stable_map if self.subsystem == "stable" else leg.unstable_map
        return f(l0=self.l0, g=self.g)

    def inverse(self):
        """The CasADi inverse of ``map()``: a CCF (A, B, C, D) -> the physical parameters
        (k, d, m for the stable subsystem; k, m for the unstable one, which d does not enter)."""
        from symbolic import leg

        f = leg.stable_inverse if self.subsystem == "stable" else leg.unstable_inverse
        return f(l0=self.l0, g=self.g)

    def systems(self, k, d, m) -> Systems:
        """The subsystems of given parameter arrays ``(N,)`` (vectorised through ``f.map``)."""
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
            if not isinstance(v, int) or v < 0:
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
               rng: np.random.Generator) -> np.ndarray:
    """Input records ``u (count, steps)`` of one kind.

    - ``step``: unit step ``u_k = 1`` (the paper's excitation).
    - ``ramp``: ``u_k = t_k / t_end``.
    - ``prbs``: random +-1 levels held for 3-12 samples (a pseudo-random binary sequence).
    - ``multisine``: 4 random-phase sines between 0.2 and 10 Hz (below Nyquist), peak 1.
    - ``noise``: Gaussian noise low-pass filtered (first order, 5 Hz), peak 1.
    - ``mix``: each record of a kind drawn at random among the above, steps of random height
      in [0.5, 2] and random start in the first quarter.
    """
    if kind not in EXCITATIONS:
        raise ValueError(f"kind must be one of {EXCITATIONS}; got {kind!r}")
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
        if sub == "step":
            height = rng.uniform(0.5, 2.0, size=(idx.size, 1))
            start = rng.integers(0, max(steps // 4, 1), size=(idx.size, 1))
            u[idx] = height * (np.arange(steps)[None, :] >= start)
        else:
            u[idx] = excitation(sub, idx.size, steps, dt, rng)
    return u


@dataclass(frozen=True)
class Records:
    """Simulated measurements.

    Attributes:
        u: ``(N, steps)`` inputs; y: ``(N, steps)`` measured (noisy) outputs;
        y_clean: ``(N, steps)`` noise-free outputs; systems: the true systems;
        dt: sample time; noise: per-record noise level (std relative to max|y_clean|), ``(N,)``.
    """

    u: np.ndarray
    y: np.ndarray
    y_clean: np.ndarray
    systems: Systems
    dt: float
    noise: np.ndarray

    def __len__(self) -> int:
        return self.u.shape[0]

    def take(self, index) -> Records:
        return Records(self.u[index], self.y[index], self.y_clean[index],
                       self.systems.take(index), self.dt, self.noise[index])


def records(family, count: int, *, steps: int, dt: float, excitation_kind: str = "step",
            noise=0.0, seed: int = 0) -> Records:
    """Sample ``count`` systems from ``family``, excite and simulate them exactly.

    Args:
        family: a family with ``sample(count, rng) -> Systems`` (``LegFamily``, ``PoleFamily``).
        count, steps, dt: how many records, of how many samples, at what sample time.
        excitation_kind: one of ``EXCITATIONS``.
        noise: a level (std relative to max|y_clean|) or a (lo, hi) range drawn per record.
        seed: seeds every draw.
    """
    if not isinstance(count, int) or count < 1:
        raise ValueError(f"count must be a positive integer; got {count!r}")
    if not isinstance(steps, int) or steps < 2:
        raise ValueError(f"steps must be an integer >= 2; got {steps!r}")
    rng = np.random.default_rng(seed)
    systems = family.sample(count, rng)
    u = excitation(excitation_kind, count, steps, dt, rng)
    y_clean = simulate(systems.A, systems.b, systems.c, systems.d, u, dt)
    if np.ndim(noise) == 0:
        level = np.full(count, float(noise))
    else:
        level = rng.uniform(*_check_range("noise", noise), size=count)
    if np.any(level < 0):
        raise ValueError(f"noise must be >= 0; got {noise!r}")
    scale = level * np.max(np.abs(y_clean), axis=1)
    y = y_clean + scale[:, None] * rng.normal(size=y_clean.shape)
    return Records(u, y, y_clean, systems, float(dt), level)
