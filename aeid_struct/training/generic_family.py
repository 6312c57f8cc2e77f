"""Generic families in normalised time: SISO systems of order 1-8 (stable, or with the
integrating and unstable shares asked for) that look like real ones
(zeros, resonances to overdamped modes, gains of either sign, feedthrough, input delay) and their
records (excitations people apply, a mid-motion start, offsets, noise), for training and
benchmarking the generic identifiers. This module is the family: the random draw and the
simulation. What it gives, ``GenericSystems`` and ``GenericRecords``, is in
``training.generic_systems`` (re-exported here), and the polynomial algebra of the draw in
``training.generic_polynomials``.

Normalised time: ``dt = 1``, time in samples, poles ``|p| dt`` in rad/sample
(``training.generic_systems``). Systems come in the bottom-row CCF (paper Eq. 5, ``b = e_n``);
every random draw comes from an explicit generator. The model of a record is
docs/architecture.md's: the exact FOH response (Eq. 10-13) of the delayed input from the record's
initial state, plus an output offset.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from aeid_struct.generic import MAX_ORDER
from aeid_struct.simulation import states_batch
from aeid_struct.structures import ccf_matrices
from aeid_struct.training.checks import count as positive_int
from aeid_struct.training.checks import generator, real, value_range
from aeid_struct.training.excitation import GENERIC_EXCITATIONS, generic_excitation
from aeid_struct.training.generic_polynomials import GRID, convolve, peak_gain, poly
from aeid_struct.training.generic_systems import GenericRecords as GenericRecords
from aeid_struct.training.generic_systems import GenericSystems as GenericSystems

__all__ = ["GenericFamily", "GenericRecords", "GenericSystems"]

#: Share of drawn zeros (real ones, and complex pairs) in the right half plane.
RHP_ZEROS = 0.25


def _log_uniform(rng: np.random.Generator, lo: float, hi: float, size) -> np.ndarray:
    return np.exp(rng.uniform(np.log(lo), np.log(hi), size=size))


def _pairs(rng, size, magnitude, damping):
    """Root pairs ``w (-z +- sqrt(z^2 - 1))``: complex for ``z < 1``, two real ones otherwise."""
    w = _log_uniform(rng, *magnitude, size)
    z = _log_uniform(rng, *damping, size)
    root = np.sqrt(z.astype(complex) ** 2 - 1)
    return w * (-z + root), w * (-z - root)


def _pair_range(name: str, value, lower: float, strict: bool) -> tuple[float, float]:
    lo, hi = value_range(name, value)
    if lo < lower or (strict and lo == lower):
        bound = f"> {lower}" if strict else f">= {lower}"
        raise ValueError(f"{name} must have lo {bound}; got {value!r}")
    return lo, hi


def _share(name: str, value) -> float:
    return real(name, value, "a number in [0, 1]", lambda v: 0.0 <= v <= 1.0)


def _whole(name: str, value, lower: int = 0) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or value < lower:
        raise ValueError(f"{name} must be an integer >= {lower}; got {value!r}")
    return int(value)


@dataclass(frozen=True, kw_only=True)
class GenericFamily:
    """SISO systems of one order in normalised time (``dt = 1``), stable unless shares are
    asked to integrate or grow, and their records.

    Poles: ``floor(n/2)`` second-order factors, natural frequency log-uniform in ``band`` and
    damping ratio log-uniform in ``damping`` (above 1: two real poles), or with probability
    ``real_fraction`` two real poles log-uniform in ``band``; and one real pole log-uniform in
    ``band`` for odd ``n``. Every pole has a negative real part unless ``integrating`` or
    ``unstable`` ask otherwise: with probability ``integrating`` one real pole is at 0 (an odd
    order's real pole; for an even order the first factor becomes ``0`` and a real pole
    log-uniform in ``band``), with probability ``unstable`` the same slot holds a pole in the
    right half plane, real part log-uniform in ``growth`` (a real pole, or for ``n >= 2`` with
    probability 1/2 a growing oscillation ``sigma +- j w``, ``w`` log-uniform in ``band``): a
    record of ``N`` samples grows by at most ``e^{growth_hi N}``, so records stay of bounded
    length as a plant run open loop must. Numerator: relative degree uniform in ``1..n``
    (``n`` without ``zeros``), its zeros of magnitude log-uniform in ``band`` (complex pairs
    with the damping range, or real pairs, as the poles), each real zero or pair in the right
    half plane with probability ``RHP_ZEROS``; high-frequency gain of either sign with
    probability 1/2, scaled so that the largest ``|G(j w)|`` over ``w`` in ``[1e-4, pi]`` and
    at each ``|pole|`` (``1e-4`` for a pole at 0) is 1 (outputs of std O(1) for inputs of peak
    1). With probability ``feedthrough`` ``d`` is ``+-(0.2..1)``.

    Attributes
    ----------
    order : int
        ``n``, 1..8 (``generic.MAX_ORDER``; the shipped encoders are for 1-4).
    band : (lo, hi)
        Natural frequencies ``|p| dt`` (rad/sample), log-uniform; ``lo > 0``.
    damping : (lo, hi)
        Damping ratio of the second-order factors, log-uniform; ``lo > 0``.
    real_fraction : float
        Share of second-order factors drawn as two real poles instead, in [0, 1].
    zeros : bool
        Numerators with zeros (relative degree 1..n); all-pole otherwise.
    feedthrough : float
        Share of systems with ``d != 0``, in [0, 1].
    max_delay : int
        Input delays uniform in ``0..max_delay`` samples, >= 0.
    noise : (lo, hi)
        White output noise std over the std of the clean output, uniform; ``lo >= 0``.
    excitations : tuple of str
        The kinds of ``generic_excitation`` the records draw from, uniformly per record.
    preroll : (lo, hi)
        Samples simulated from rest before the record starts, uniform integers; ``lo >= 0``.
    offset : float
        Std of the normal constant input and output offsets added (0: none), >= 0.
    integrating : float
        Share of systems with a pole at 0 (a rigid-body mode, a tank's level), in [0, 1].
    unstable : float
        Share of systems with a pole in the right half plane, in [0, 1];
        ``integrating + unstable <= 1``.
    growth : (lo, hi)
        Real parts (rad/sample) of the unstable poles, log-uniform; ``lo > 0``.

    Raises
    ------
    ValueError
        If a field is out of its range (the message names it).
    """

    order: int
    band: tuple = (0.005, 2.5)
    damping: tuple = (0.005, 4.0)
    real_fraction: float = 0.3
    zeros: bool = True
    feedthrough: float = 0.2
    max_delay: int = 0
    noise: tuple = (0.0, 0.1)
    excitations: tuple = GENERIC_EXCITATIONS
    preroll: tuple = (0, 400)
    offset: float = 0.0
    integrating: float = 0.0
    unstable: float = 0.0
    growth: tuple = (0.0005, 0.005)

    def __post_init__(self) -> None:
        order = self.order
        if isinstance(order, (bool, np.bool_)) or not isinstance(order, (int, np.integer)) \
                or not 1 <= order <= MAX_ORDER:
            raise ValueError(f"order must be an integer in 1..{MAX_ORDER}; got {self.order!r}")
        setattr_ = object.__setattr__
        setattr_(self, "order", int(self.order))
        setattr_(self, "band", _pair_range("band", self.band, 0.0, strict=True))
        setattr_(self, "damping", _pair_range("damping", self.damping, 0.0, strict=True))
        setattr_(self, "real_fraction", _share("real_fraction", self.real_fraction))
        if not isinstance(self.zeros, (bool, np.bool_)):
            raise ValueError(f"zeros must be a bool; got {self.zeros!r}")
        setattr_(self, "zeros", bool(self.zeros))
        setattr_(self, "feedthrough", _share("feedthrough", self.feedthrough))
        setattr_(self, "max_delay", _whole("max_delay", self.max_delay))
        setattr_(self, "noise", _pair_range("noise", self.noise, 0.0, strict=False))
        kinds = self.excitations
        if isinstance(kinds, str) or not isinstance(kinds, (tuple, list)) or not kinds \
                or any(k not in GENERIC_EXCITATIONS for k in kinds):
            raise ValueError(f"excitations must be a non-empty tuple of kinds from "
                             f"{GENERIC_EXCITATIONS}; got {kinds!r}")
        setattr_(self, "excitations", tuple(kinds))
        lo, hi = value_range("preroll", self.preroll)
        if lo < 0 or lo != int(lo) or hi != int(hi):
            raise ValueError(f"preroll must be a (lo, hi) pair of integers, 0 <= lo <= hi; "
                             f"got {self.preroll!r}")
        setattr_(self, "preroll", (int(lo), int(hi)))
        setattr_(self, "offset", real("offset", self.offset, "a finite number >= 0",
                                      lambda v: v >= 0))
        setattr_(self, "integrating", _share("integrating", self.integrating))
        setattr_(self, "unstable", _share("unstable", self.unstable))
        if self.integrating + self.unstable > 1.0:
            raise ValueError(f"integrating + unstable must be at most 1 (shares of the "
                             f"systems); got {self.integrating} + {self.unstable}")
        setattr_(self, "growth", _pair_range("growth", self.growth, 0.0, strict=True))

    def _numerator(self, count: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Ascending numerator coefficients before scaling ``(count, n)``, and relative degrees."""
        n = self.order
        rel = rng.integers(1, n + 1, size=count) if self.zeros else np.full(count, n)
        m = n - rel                                   # zeros per system, 0..n-1
        # Slots: (n - 1) // 2 pair slots (two zeros each), then one real slot; a system with m
        # zeros fills m // 2 pair slots and the real slot when m is odd.
        slots = (n - 1) // 2
        first, second = _pairs(rng, (count, slots), self.band, self.damping)
        rhp = np.where(rng.random((count, slots)) < RHP_ZEROS, -1.0, 1.0)
        single = _log_uniform(rng, *self.band, (count, 1))
        single = single * np.where(rng.random((count, 1)) < RHP_ZEROS, 1.0, -1.0)
        num = np.ones((count, 1), dtype=complex)
        for j in range(slots):
            on = (j < m // 2)[:, None]
            # a pair in the right half plane: both roots mirrored (-conj keeps a pair a pair)
            z1 = np.where(rhp[:, j] < 0, -np.conj(first[:, j]), first[:, j])
            z2 = np.where(rhp[:, j] < 0, -np.conj(second[:, j]), second[:, j])
            factor = np.where(on, poly(np.stack([z1, z2], 1)), np.array([1.0, 0.0, 0.0]))
            num = convolve(num, factor)
        factor = np.where((m % 2 == 1)[:, None], poly(single.astype(complex)),
                          np.array([1.0, 0.0]))
        num = convolve(num, factor).real
        c = np.zeros((count, n))
        width = min(n, num.shape[1])
        c[:, :width] = num[:, :width]
        return c, rel

    def sample(self, count: int, rng: np.random.Generator) -> GenericSystems:
        """Draw ``count`` systems (see the class docstring).

        Parameters
        ----------
        count : int
            Systems, >= 1.
        rng : numpy.random.Generator
            Every random draw.

        Returns
        -------
        GenericSystems
            In normalised time (``dt = 1``).
        """
        count = positive_int("count", count)
        generator(rng)
        n, half = self.order, self.order // 2
        p1, p2 = _pairs(rng, (count, half), self.band, self.damping)
        real_pair = rng.random((count, half)) < self.real_fraction
        reals = -_log_uniform(rng, *self.band, (count, half, 2))
        p1 = np.where(real_pair, reals[..., 0], p1)
        p2 = np.where(real_pair, reals[..., 1], p2)
        poles = np.stack([p1, p2], axis=2).reshape(count, 2 * half)
        if n % 2:
            poles = np.concatenate([poles, -_log_uniform(rng, *self.band, (count, 1))], axis=1)
        poles = poles.astype(complex)
        if self.integrating or self.unstable:      # no extra draws for a stable family
            poles = _growing(self, poles, rng)
        a = poly(poles).real[:, :n]                  # a_0..a_{n-1}; the monic term dropped
        c, _ = self._numerator(count, rng)
        sign = np.where(rng.random(count) < 0.5, -1.0, 1.0)
        # a pole at 0 has an infinite gain there: its magnitude is the grid's lowest frequency
        peak = peak_gain(a, c, np.maximum(np.abs(poles), GRID[0]))
        c = c * (sign / peak)[:, None]
        d = np.where(rng.random(count) < self.feedthrough,
                     rng.choice([-1.0, 1.0], count) * rng.uniform(0.2, 1.0, count), 0.0)
        delay = rng.integers(0, self.max_delay + 1, size=count)
        A, b, c = ccf_matrices(a, c)
        return GenericSystems(A, b, c, d, poles, delay)

    def records(self, count: int, steps: int, rng: np.random.Generator, *,
                systems: GenericSystems | None = None) -> GenericRecords:
        """Simulate ``count`` records of ``steps`` samples that start mid-motion.

        Each system is simulated (exact FOH, Eq. 10-13, :func:`aeid_struct.simulation.states_batch`
        in float64, ``dt = 1``) from rest with zero input over ``preroll + steps`` samples, its
        excitation starting ``preroll`` samples (drawn per record) before the record and reaching
        the plant ``delay`` samples later; the last ``steps`` samples are kept. ``c`` and ``d`` are
        divided by the std of the clean output over the record (the returned ``systems`` are the
        scaled ones: outputs of std 1 before the offset). Then the input and output offsets and
        the noise (std ``noise`` times that of the clean output) are added.

        Parameters
        ----------
        count : int
            Records, >= 1.
        steps : int
            Samples per record, >= 2.
        rng : numpy.random.Generator
            Every random draw.
        systems : GenericSystems, optional
            The systems to simulate (``count`` of this family's order, normalised time);
            drawn by :meth:`sample` when None.

        Returns
        -------
        GenericRecords
        """
        count = positive_int("count", count)
        steps = _whole("steps", steps, 2)
        generator(rng)
        if systems is None:
            systems = self.sample(count, rng)
        elif not isinstance(systems, GenericSystems) or len(systems) != count \
                or systems.order != self.order or systems.dt != 1.0:
            raise ValueError(f"systems must be GenericSystems of {count} systems of order "
                             f"{self.order} in normalised time (dt = 1); got {systems!r:.80}")
        pre = rng.integers(self.preroll[0], self.preroll[1] + 1, size=count)
        first = int(pre.max())
        total = first + steps
        u = _inputs(self, count, total, first, rng)
        k = np.arange(total)[None, :]
        u = np.where(k >= (first - pre)[:, None], u, 0.0)      # at rest before its pre-roll
        lagged = k - systems.delay[:, None]
        plant = np.where(lagged >= 0, np.take_along_axis(u, np.maximum(lagged, 0), 1), 0.0)
        A, b, c, d, v = (torch.from_numpy(np.ascontiguousarray(x)) for x in
                         (systems.A, systems.b, systems.c, systems.d, plant))
        X = states_batch(A, b, v, 1.0).numpy()
        clean = X[:, first:] @ systems.c[:, :, None]
        clean = clean[..., 0] + systems.d[:, None] * plant[:, first:]
        # The output's scale is the record's, not the system's: c and d divided by the clean
        # output's std make it 1 (a constant record, impossible for these excitations, stays).
        spread = clean.std(axis=1)
        spread = np.where(spread > 0, spread, 1.0)
        clean = clean / spread[:, None]
        systems = dataclasses.replace(systems, c=systems.c / spread[:, None],
                                      d=systems.d / spread)
        offsets = (rng.normal(0.0, self.offset, (count, 2)) if self.offset > 0
                   else np.zeros((count, 2)))
        level = rng.uniform(*self.noise, size=count)
        scale = level * clean.std(axis=1)
        y_clean = clean + offsets[:, 1:]
        y = y_clean + scale[:, None] * rng.normal(size=(count, steps))
        return GenericRecords(y=y, y_clean=y_clean, u=u[:, first:] + offsets[:, :1],
                              u_plant=plant[:, first:], x0=X[:, first].copy(), noise=level,
                              offsets=offsets, systems=systems)


def _growing(family: GenericFamily, poles: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``poles`` (count, n) with ``family``'s integrating and unstable shares' slot replaced
    (``GenericFamily``'s docstring): an odd order's real pole, or an even order's first
    factor."""
    count, n = poles.shape
    poles = poles.copy()
    kind = rng.random(count)
    integ = kind < family.integrating
    unst = (kind >= family.integrating) & (kind < family.integrating + family.unstable)
    sigma = _log_uniform(rng, *family.growth, count)
    pair = (rng.random(count) < 0.5) & unst & (n >= 2)
    w = _log_uniform(rng, *family.band, count)
    other = -_log_uniform(rng, *family.band, count)
    root = np.where(integ, 0.0, sigma)
    single = integ | (unst & ~pair)
    if n % 2:
        poles[single, -1] = root[single]
    else:
        poles[single, 0], poles[single, 1] = root[single], other[single]
    if n >= 2:
        poles[pair, 0], poles[pair, 1] = sigma[pair] + 1j * w[pair], sigma[pair] - 1j * w[pair]
    return poles


def _inputs(family: GenericFamily, count: int, total: int, first: int,
            rng: np.random.Generator) -> np.ndarray:
    """``family``'s excitations of ``total`` samples, a kind drawn per record."""
    band = (min(family.band[0], 3.0), min(family.band[1], 3.0))
    pick = rng.integers(0, len(family.excitations), size=count)
    u = np.empty((count, total))
    for j, kind in enumerate(family.excitations):
        idx = np.flatnonzero(pick == j)
        if idx.size:
            u[idx] = generic_excitation(kind, idx.size, total, rng, first=first, band=band)
    return u
