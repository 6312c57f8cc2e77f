"""System families: the true SISO systems an identifier is trained on.

A *family* samples true systems: the two robot-leg subsystems through the CasADi maps of
``symbolic.leg`` with the paper's parameter ranges (Sec. IV), or generic all-pole families given
pole and gain ranges. Systems come in the bottom-row CCF (docs/architecture.md, "Conventions");
every random draw comes from an explicit generator.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from aeid_struct.training.checks import count as counted
from aeid_struct.training.checks import generator, positive, value_range


@dataclass(frozen=True)
class Systems:
    """A batch of true SISO systems ``dx/dt = A x + b u``, ``y = c^T x + d u``.

    Systems of several records (one parameter set, ``R`` subsystems, e.g. the joint leg) carry a
    record axis after the batch axis.

    Attributes
    ----------
    A : (N, n, n) or (N, R, n, n) float64 array
    b : (N, n) or (N, R, n) float64 array
    c : (N, n) or (N, R, n) float64 array
    d : (N,) or (N, R) float64 array
    params : dict of str -> (N,) array
        Physical parameters by name (empty for generic families).
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
        """The systems of record ``r`` alone, without the record axis.

        Parameters
        ----------
        r : int
            The record (subsystem) index.

        Returns
        -------
        Systems
            ``A (N, n, n)``, ...; the systems themselves when they have one record.
        """
        if self.records == 1:
            return self
        return Systems(self.A[:, r], self.b[:, r], self.c[:, r], self.d[:, r], self.params)

    def take(self, index) -> Systems:
        """The systems at ``index``.

        Parameters
        ----------
        index : int array, slice or boolean mask
            Along the batch axis.

        Returns
        -------
        Systems
        """
        return Systems(
            self.A[index], self.b[index], self.c[index], self.d[index],
            {k: v[index] for k, v in self.params.items()},
        )


@dataclass(frozen=True, kw_only=True)
class LegFamily:
    """The robot-leg subsystems of paper Sec. IV with (k, d, m) drawn uniformly from ``ranges``.

    Systems come in the bottom-row CCF that ``symbolic.leg`` derives.

    Attributes
    ----------
    subsystem : {"stable", "unstable", "joint"}
        ``"stable"``: translational, ``G1 = (1/m) / (s^2 + (d/m) s + k/m)``; ``"unstable"``:
        rotational, ``G2 = (1/(m L^2)) / (s^2 - g/L)``, ``L = l0 - m g/k``; ``"joint"``: both,
        one parameter set and two records (record axis: G1, G2).
    ranges : dict of str -> (lo, hi)
        Uniform ranges of ``k``, ``d`` and ``m`` (paper Sec. IV by default), all positive. A
        range with ``lo == hi`` holds that parameter at a known value (e.g. a known mass).
    l0 : float
        Unloaded leg length (m), positive.
    g : float
        Gravity (m/s^2), positive.
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
        object.__setattr__(self, "l0", positive("l0", self.l0))
        object.__setattr__(self, "g", positive("g", self.g))
        if set(self.ranges) != {"k", "d", "m"}:
            raise ValueError(f"ranges must name exactly k, d, m; got {sorted(self.ranges)}")
        ranges = {}
        for name, value in self.ranges.items():
            lo, hi = value_range(f"ranges[{name!r}]", value)
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
        """The CasADi map of this subsystem.

        Returns
        -------
        casadi.Function
            ``(k, d, m) -> CCF (A, B, C, D)`` (``A1, .., D2`` for the joint leg).
        """
        from symbolic import leg

        f = {"stable": leg.stable_map, "unstable": leg.unstable_map,
             "joint": leg.joint_map}[self.subsystem]
        return f(l0=self.l0, g=self.g)

    def inverse(self):
        """The CasADi inverse of ``map()``.

        Returns
        -------
        casadi.Function
            A CCF ``(A, B, C, D)`` -> the physical parameters (k, d, m for the stable subsystem
            and the joint leg; k, m for the unstable one, which d does not enter).
        """
        from symbolic import leg

        f = {"stable": leg.stable_inverse, "unstable": leg.unstable_inverse,
             "joint": leg.joint_inverse}[self.subsystem]
        return f(l0=self.l0, g=self.g)

    def systems(self, k, d, m) -> Systems:
        """The subsystems of given parameters (vectorised through ``casadi.Function.map``).

        Parameters
        ----------
        k, d, m : float or (N,) array
            Positive, finite, one length; for the rotational subsystem a leg not compressed
            past zero length (``m g / k < l0``).

        Returns
        -------
        Systems
            ``N`` systems (with a record axis of 2 for the joint leg), ``params`` k, d, m.
        """
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
        """``count`` systems with (k, d, m) uniform in ``ranges``.

        Parameters
        ----------
        count : int
            Positive.
        rng : numpy.random.Generator

        Returns
        -------
        Systems
        """
        count = counted("count", count)
        generator(rng)
        draws = {n: rng.uniform(*self.ranges[n], size=count) for n in ("k", "d", "m")}
        return self.systems(**draws)


@dataclass(frozen=True, kw_only=True)
class PoleFamily:
    """Generic stable all-pole systems ``G(s) = g * a0 / prod(s - p_i)`` (static gain ``g``),
    realised in bottom-row CCF.

    Attributes
    ----------
    real : int
        Real poles, ``-p`` uniform in ``decay``.
    pairs : int
        Complex pairs ``-sigma +- j omega``, ``sigma`` uniform in ``decay``, ``omega`` in
        ``freq``; ``real + pairs >= 1``.
    decay : (lo, hi)
        Positive range of the poles' decay rates ``-Re(p)`` (1/s).
    freq : (lo, hi)
        Positive range of the pairs' frequencies ``Im(p)`` (rad/s).
    gain : (lo, hi)
        Positive range of the static gain.
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
            lo, hi = value_range(name, getattr(self, name))
            if lo <= 0:
                raise ValueError(f"{name} must be positive; got ({lo}, {hi})")
            object.__setattr__(self, name, (lo, hi))

    @property
    def n(self) -> int:
        """The systems' order, ``real + 2 pairs``."""
        return self.real + 2 * self.pairs

    def sample(self, count: int, rng: np.random.Generator) -> Systems:
        """``count`` systems of the family.

        Parameters
        ----------
        count : int
            Positive.
        rng : numpy.random.Generator

        Returns
        -------
        Systems
            ``A (count, n, n)``, ``b, c (count, n)``, ``d (count,)`` (zero).
        """
        count = counted("count", count)
        generator(rng)
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
