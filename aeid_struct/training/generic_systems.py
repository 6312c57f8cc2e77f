"""The batches a generic family gives, in normalised time: ``GenericSystems`` (SISO
systems in the bottom-row CCF of paper Eq. 5, with an input delay) and ``GenericRecords`` (their
simulated records). A module apart from the family (``training.generic_family``) because these
are data that the benchmarks and tests hand around and read at any sample time, which needs
nothing of how the family draws and simulates them.

Normalised time: ``dt = 1``, time in samples, poles ``|p| dt`` in rad/sample. A normalised model
``(A_n, b_n, c, d)`` is, at sample time ``dt``, ``A = A_n / dt``, ``b = b_n / dt`` with the same
``c``, ``d`` and state (:meth:`GenericSystems.at`); the samples of a record do not change.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from aeid_struct.training.checks import positive

__all__ = ["GenericRecords", "GenericSystems"]


@dataclass(frozen=True)
class GenericSystems:
    """A batch of SISO systems (stable unless drawn otherwise) in the bottom-row CCF (paper
    Eq. 5) with an input delay.

    Attributes
    ----------
    A : (N, n, n) float64 array
        Companion matrices (ones above the diagonal, last row ``-a``).
    b : (N, n) float64 array
        ``e_n`` (``e_n / dt`` after :meth:`at`).
    c : (N, n) float64 array
        Numerator coefficients ``c_0..c_{n-1}`` (ascending).
    d : (N,) float64 array
        Feedthrough (0 for most systems).
    poles : (N, n) complex array
        The eigenvalues of ``A``: the pairs first (conjugate pairs, or two real poles), then the
        real pole of an odd order.
    delay : (N,) int array
        Input delay in samples.
    dt : float
        The sample time these matrices are for (1: normalised time).
    """

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    poles: np.ndarray
    delay: np.ndarray
    dt: float = 1.0

    def __len__(self) -> int:
        return self.A.shape[0]

    @property
    def order(self) -> int:
        """The order ``n``."""
        return self.A.shape[-1]

    def take(self, index) -> GenericSystems:
        """The systems at ``index`` (int array, slice or boolean mask along the batch axis).

        Parameters
        ----------
        index : int array, slice or boolean mask

        Returns
        -------
        GenericSystems
        """
        return GenericSystems(self.A[index], self.b[index], self.c[index], self.d[index],
                              self.poles[index], self.delay[index], self.dt)

    def at(self, dt: float) -> GenericSystems:
        """The same systems for records sampled at ``dt``: ``A dt_0 / dt``, ``b dt_0 / dt``.

        With ``dt_0 = self.dt`` (1 in normalised time): ``A = A_n / dt``, ``b = b_n / dt``, the
        same ``c``, ``d``, state and delay in samples; poles scale as ``A``. The samples of a
        record are the same at any ``dt``.

        Parameters
        ----------
        dt : float
            Sample time (s), positive.

        Returns
        -------
        GenericSystems
        """
        scale = self.dt / positive("dt", dt)
        return dataclasses.replace(self, A=self.A * scale, b=self.b * scale,
                                   poles=self.poles * scale, dt=float(dt))


@dataclass(frozen=True)
class GenericRecords:
    """Simulated records of generic systems (:meth:`GenericFamily.records`).

    Attributes
    ----------
    y : (N, steps) float64 array
        Measured output: ``y_clean`` plus white noise.
    y_clean : (N, steps) float64 array
        Noise-free output, offset included: ``c^T x_k + d u_plant_k + offsets[:, 1]`` with the
        exact FOH state ``x_k`` from ``x0`` (Eq. 10-13).
    u : (N, steps) float64 array
        Measured input: the excitation plus ``offsets[:, 0]``.
    u_plant : (N, steps) float64 array
        The input the plant saw over the record, without offset: ``u - offsets[:, 0]`` delayed
        by ``systems.delay`` samples, its first ``delay`` samples from before the record.
    x0 : (N, n) float64 array
        The state at the record's first sample (mid-motion).
    noise : (N,) float64 array
        Noise std over the std of the clean output, per record.
    offsets : (N, 2) float64 array
        The constant (input, output) offsets added.
    systems : GenericSystems
        The true systems.
    """

    y: np.ndarray
    y_clean: np.ndarray
    u: np.ndarray
    u_plant: np.ndarray
    x0: np.ndarray
    noise: np.ndarray
    offsets: np.ndarray
    systems: GenericSystems

    def __len__(self) -> int:
        return self.y.shape[0]

    def at(self, dt: float) -> GenericRecords:
        """The same records read at sample time ``dt``: samples unchanged, systems
        :meth:`GenericSystems.at` ``dt``.

        Parameters
        ----------
        dt : float
            Sample time (s), positive.

        Returns
        -------
        GenericRecords
        """
        return dataclasses.replace(self, systems=self.systems.at(dt))
