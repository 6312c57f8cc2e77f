r"""The units a record is identified in: a level far above a signal's variation removed, and
amplitudes far from 1 divided by powers of two; and a model's linear parts taken back.

Why an exact rescaling: the model of a record is linear in its amplitudes. With ``y = sy y_w``,
``u = su u_w`` and ``x = su x_w``, a model ``(A, b, c_w, d_w)`` of the scaled record with state
``x_w``, offset ``o_w`` is the model ``(A, b, (sy / su) c_w, (sy / su) d_w)`` of the record with
state ``su x_w`` and offset ``sy o_w``; powers of two change only exponents, so the scaled record
carries the measured digits, and an output of 1e-200 (whose squares underflow) or 1e200 (whose
squares overflow) is identified as exactly as one of 1. Why a level is removed: with a free
initial state and offset, an input level ``u_l`` is absorbed exactly (``x = x_w + x_ss``,
``x_ss = -A^-1 b u_l``; the offset takes ``y_l - c^T x_ss - d u_l``), and an input of 1e6 +- 1
would otherwise leave its variation in the last six digits of every regressor.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from aeid_struct.records.measured import SAFE_EXPONENT, Record, exact_scale

__all__ = ["LEVEL", "Units"]

#: A level is removed where it exceeds this many times the signal's peak-to-peak variation.
LEVEL = 4.0


@dataclass(frozen=True)
class Units:
    """The units a record is identified in: ``y_w = (y - y_level) / sy`` and ``u_w = (u -
    u_level) / su`` (module docstring).

    Parameters
    ----------
    sy, su : float
        Powers of two.
    y_level, u_level : float
        Removed levels (0 where the level is not far above the variation).
    """

    sy: float = 1.0
    su: float = 1.0
    y_level: float = 0.0
    u_level: float = 0.0

    @classmethod
    def of(cls, data: Record, keep_gain: bool = False) -> Units:
        """The units of ``data``.

        Parameters
        ----------
        data : Record
        keep_gain : bool
            ``sy = su``: for a structure that fixes a gain element at a value other than 0,
            which a gain change would move.

        Returns
        -------
        Units

        Raises
        ------
        ValueError
            Naming ``y`` and ``u``, where the gain is kept and their magnitudes are too far
            apart for float64.
        """
        def level(x):
            m = float(np.mean(x))
            return m if abs(m) > LEVEL * float(np.ptp(x)) else 0.0

        y_level, u_level = level(data.y), level(data.u)
        y, u = data.y - y_level, data.u - u_level
        sy, su = exact_scale(y), exact_scale(u)
        if keep_gain and sy != su:
            sy = su = exact_scale(np.concatenate([y, u]))
            if min(float(np.max(np.abs(v))) / sy for v in (y, u)) < 2.0 ** -SAFE_EXPONENT:
                raise ValueError(f"y and u: a structure with fixed gain elements keeps the "
                                 f"record's gain, and max|y| = {np.max(np.abs(data.y)):.3g} and "
                                 f"max|u| = {np.max(np.abs(data.u)):.3g} are too far apart for "
                                 f"float64; give y and u in units nearer to each other")
        return cls(sy, su, y_level, u_level)

    @property
    def identity(self) -> bool:
        """The record's own units (nothing removed, nothing scaled)."""
        return self == Units()

    def apply(self, data: Record) -> Record:
        """The record in these units (its offsets carry what was removed).

        Parameters
        ----------
        data : Record

        Returns
        -------
        Record
        """
        if self.identity:
            return data
        # the measured signals are y + y_offset: the removed level joins the offset, and both
        # are in the new amplitude unit
        return dataclasses.replace(
            data, y=(data.y - self.y_level) / self.sy, u=(data.u - self.u_level) / self.su,
            y_offset=(data.y_offset + self.y_level) / self.sy,
            u_offset=(data.u_offset + self.u_level) / self.su)

    def linear(self, A, b, c, d, x0, y_offset):
        """A model's linear parts in the record's units: ``c, d`` times ``sy / su``, the state
        ``su x0 + x_ss``, the offset ``sy o + y_level - c^T x_ss - d u_level``.

        Parameters
        ----------
        A : (n, n) array
        b, c, x0 : (n,) arrays
        d, y_offset : float

        Returns
        -------
        c : (n,) array
        d : float
        x0 : (n,) array
        y_offset : float

        Raises
        ------
        ValueError
            Naming ``y`` and ``u``, where that model leaves float64.
        """
        sy, su = self.sy, self.su
        g = sy / su
        c_w, d_w = np.asarray(c, dtype=np.float64), float(d)
        with np.errstate(over="ignore", under="ignore"):
            c, d = c_w * g, d_w * g
        lost = np.any((c_w != 0) & (c == 0)) or (d_w != 0 and d == 0)
        if not (np.isfinite(g) and g > 0 and np.all(np.isfinite(c)) and np.isfinite(d)) or lost:
            raise ValueError(f"y and u: the gain of this record (max|y| ~ 2^{np.log2(sy):.0f}, "
                             f"max|u| ~ 2^{np.log2(su):.0f}) makes a model that float64 cannot "
                             f"hold; give y and u in units nearer to each other")
        x_ss = (-np.linalg.solve(np.asarray(A, dtype=np.float64), np.asarray(b, dtype=np.float64))
                * self.u_level if self.u_level else np.zeros_like(c))
        x0 = np.asarray(x0, dtype=np.float64) * su + x_ss
        y_offset = float(y_offset) * sy + self.y_level - float(c @ x_ss) - d * self.u_level
        return c, d, x0, y_offset

    def estimate(self, A, b, c, d, elements: dict, info: dict):
        """An estimate's parts in the record's units: :meth:`linear`'s ``c, d``, the elements
        ``c_i, d`` times ``sy / su``, and the ``info`` entries ``x0``, ``y_offset``, ``y_hat``
        (where present) and ``cost`` (times ``sy^2``), with ``units`` added.

        Parameters
        ----------
        A : (n, n) array
        b, c : (n,) arrays
        d : float
        elements : dict name -> float
        info : dict
            With ``x0``, ``y_offset`` and ``cost``.

        Returns
        -------
        c : (n,) array
        d : float
        elements : dict
        info : dict
        """
        c, d, x0, y_offset = self.linear(A, b, c, d, info["x0"], info["y_offset"])
        g = self.sy / self.su
        elements = {k: v * g if (k == "d" or k.startswith("c")) else v
                    for k, v in elements.items()}
        info = {**info, "x0": x0, "y_offset": y_offset, "units": dataclasses.asdict(self),
                "cost": float(info["cost"]) * self.sy * self.sy}
        if "y_hat" in info:
            info["y_hat"] = self.output(np.asarray(info["y_hat"]))
        return c, d, elements, info

    def output(self, y_w: np.ndarray) -> np.ndarray:
        """An output in these units in the record's: ``sy y_w + y_level``.

        Parameters
        ----------
        y_w : array

        Returns
        -------
        array
        """
        return y_w * self.sy + self.y_level
