"""Training windows as identification reads them: a generic family's records, each read
unweighted or under one of the growth weights of :data:`aeid_struct.generic.windows.GROWTH`.

At identification every window is read unweighted and under the weights ``e^{-sigma k}``
(``sigma = g / window``), and the poles found under a weight are shifted back
(:mod:`aeid_struct.generic.windows`, "Growth in the normalisation"): the encoder sees the record
of the shifted system ``G(s + sigma)`` under the weighted input. An encoder trained on unweighted
records of stable systems only never saw such windows, nor an integrating or unstable plant's.
:class:`GrowthFamily` gives it both: each record of its ``base`` family is read under a weight
drawn per record among those that leave the shifted system stable (a stable plant: every
weight, none included; an integrating one: every weight but none; an unstable one: those with
``sigma`` above its largest real part, or the strongest where none is), so the encoder learns the
windows it will be asked about, with stable poles to find in each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeid_struct.generic import GROWTH, weighted
from aeid_struct.training.checks import count as positive_int
from aeid_struct.training.checks import generator
from aeid_struct.training.generic_family import GenericFamily

__all__ = ["GrowthFamily", "GrowthWindows"]


@dataclass(frozen=True)
class GrowthWindows:
    """Records read under their weights (:meth:`GrowthFamily.records`).

    Attributes
    ----------
    y, u : (N, steps) float64 arrays
        The weighted records (``y`` less its first sample where weighted).
    sigma : (N,) float64 array
        Each record's weight, per sample (0: unweighted).
    """

    y: np.ndarray
    u: np.ndarray
    sigma: np.ndarray


@dataclass(frozen=True, kw_only=True)
class GrowthFamily:
    """A generic family's records under the growth weights, for training.

    Attributes
    ----------
    base : GenericFamily
        The systems and records (its ``integrating`` and ``unstable`` shares decide how many
        plants need a weight).
    growth : tuple of float
        The weights' decay over one record, ``g > 0`` (:data:`~aeid_struct.generic.GROWTH`
        by default: the identification's).

    Raises
    ------
    ValueError
        ``base`` is not a GenericFamily, or ``growth`` is not a non-empty tuple of positive
        numbers.
    """

    base: GenericFamily
    growth: tuple = GROWTH

    def __post_init__(self) -> None:
        if not isinstance(self.base, GenericFamily):
            raise ValueError(f"base must be a GenericFamily; got {type(self.base).__name__}")
        g = self.growth
        if not isinstance(g, (tuple, list)) or not g or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                and v > 0 for v in g):
            raise ValueError(f"growth must be a non-empty tuple of positive numbers (decay over "
                             f"one record); got {g!r}")
        object.__setattr__(self, "growth", tuple(float(v) for v in g))

    @property
    def order(self) -> int:
        """The base family's order."""
        return self.base.order

    def records(self, count: int, steps: int, rng: np.random.Generator) -> GrowthWindows:
        """``count`` records of ``base``, each read under a weight drawn uniformly among those
        that leave its shifted system stable (the module docstring).

        Parameters
        ----------
        count : int
            Records, >= 1.
        steps : int
            Samples per record (the window).
        rng : numpy.random.Generator

        Returns
        -------
        GrowthWindows
        """
        count = positive_int("count", count)
        generator(rng)
        rec = self.base.records(count, steps, rng)
        top = rec.systems.poles.real.max(axis=1)             # rad/sample
        options = np.array((0.0, *self.growth)) / steps      # sigma per sample
        # allowed: the shifted poles p - sigma all in the left half plane (a stable plant:
        # every option, none included); where none is, the strongest weight
        allowed = options[None, :] > top[:, None]
        allowed[~allowed.any(axis=1), -1] = True
        # one draw per record, in record order: the shipped fine-tuned generic-1..3 were trained
        # on this stream (a vectorised draw would give other windows); it costs ~5 us a record
        # beside the ~70 us of its simulation (4,096 records, one thread)
        pick = np.array([rng.choice(np.flatnonzero(row)) for row in allowed])
        Y, U, sigma = np.empty_like(rec.y), np.empty_like(rec.u), options[pick]
        for j in range(options.size):
            rows = pick == j
            if not rows.any():
                continue
            if j == 0:
                Y[rows], U[rows] = rec.y[rows], rec.u[rows]
            else:
                y, u, _ = weighted(rec.y[rows], rec.u[rows], (self.growth[j - 1],))
                n = int(rows.sum())
                Y[rows], U[rows] = y[n:], u[n:]
        return GrowthWindows(y=Y, u=U, sigma=sigma)
