"""The boundary of :func:`~aeid_struct.generic.identify` and
:func:`~aeid_struct.generic.compare`: a user's record, delay and sample time checked once
(:func:`measured`, :func:`check_grid`), and the units the record is identified in
(:class:`Units`: a level far above the signal's variation removed, amplitudes brought near 1 by
powers of two) and the estimate taken back to the user's.

Why an exact rescaling: the model of a record is linear in its amplitudes. With ``y = sy y_s``,
``u = su u_s`` and ``x = su x_s``, a model ``(A, b, c_s, d_s)`` of the scaled record with state
``x_s``, offset ``o_s`` is the model ``(A, b, (sy / su) c_s, (sy / su) d_s)`` of the record with
state ``su x_s`` and offset ``sy o_s``; powers of two change only exponents, so the scaled record
carries the measured digits, and an output of 1e-200 (whose squares underflow) or 1e200 (whose
squares overflow) is identified as exactly as one of 1. Why a level is removed: with a free
initial state and offset, an input level ``u_l`` is absorbed exactly (``x = x_w + x_ss``,
``x_ss = -A^-1 b u_l``), and an input of 1e6 +- 1 would otherwise leave its variation in the last
six digits of every regressor.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from aeid_struct.identification import Estimate
from aeid_struct.records import SAFE_EXPONENT, Record, exact_scale
from aeid_struct.structures import CCF, MCF, Structure

__all__ = ["LEVEL", "Units", "check_grid", "measured"]


def _delay(name: str, value, steps: int) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not (
            0 <= value <= steps - 2):
        raise ValueError(f"{name} must be None (unknown) or an integer number of samples in "
                         f"[0, {steps - 2}]; got {value!r}")
    return int(value)


def measured(record, delay=None) -> Record:
    """A user's record as a checked :class:`~aeid_struct.records.Record` (checked once: a
    Record is taken as it is, anything else goes through Record's own checks).

    Parameters
    ----------
    record : Record, (y, u) or (y, u, dt) tuple, or (steps,) array
        Any object with attributes ``y`` (and optionally ``u``, ``dt``, ``delay``, ``t0``); a
        lone array is ``y`` with a unit step input and ``dt = 1``.
    delay : int, optional
        A known input delay in samples, over the record's own.

    Returns
    -------
    Record
        With the known delay (or None); at least 2 samples are left after it.

    Raises
    ------
    ValueError
        Naming the argument: not real numbers, a wrong shape, a non-finite sample, ``u`` of
        another length, a bad ``dt`` or ``delay``.
    """
    if isinstance(record, Record):
        rec = record
    elif hasattr(record, "y"):
        rec = Record(record.y, getattr(record, "u", None), getattr(record, "dt", 1.0),
                     delay=getattr(record, "delay", None), t0=getattr(record, "t0", 0.0))
    elif isinstance(record, (tuple, list)) and len(record) in (2, 3):
        rec = Record(*record)
    elif isinstance(record, (tuple, list)):
        raise ValueError(f"record must be a Record, a (y, u) or (y, u, dt) tuple, or an array "
                         f"y; got a {type(record).__name__} of {len(record)} items")
    else:
        rec = Record(record)
    known = _delay("record.delay", rec.delay, rec.steps)
    given = _delay("delay", delay, rec.steps)
    return rec if given is None or given == known else rec.with_delay(given)


def check_grid(data: Record, identifiers: dict, max_delay: int | None, default: int) -> int:
    """Refuse a record shorter than an identifier's window, a known delay or a given
    ``max_delay`` that leaves less than the window, and a sample time whose de-normalised model
    cannot be represented in float64; return the largest delay to consider (``max_delay``, or
    ``default`` capped by what the record leaves when it is None)."""
    window = max(int(i.config.window) for i in identifiers.values())
    if data.steps < window:
        raise ValueError(f"the record has {data.steps} samples; the generic identifier"
                         f"{'s' if len(identifiers) > 1 else ''} of order "
                         f"{'/'.join(map(str, sorted(identifiers)))} need"
                         f"{'' if len(identifiers) > 1 else 's'} at least {window} (its "
                         f"window)")
    room = data.steps - window
    if data.delay is not None and data.delay > room:
        raise ValueError(f"delay must leave at least the identifier's window ({window} samples) "
                         f"after it: at most {room} for this record of {data.steps} samples; "
                         f"got {data.delay}")
    if max_delay is None:
        max_delay = min(default, room)
    if data.delay is None and max_delay > room:
        raise ValueError(f"max_delay must leave at least the identifier's window ({window} "
                         f"samples) after the delay: at most {room} for this record of "
                         f"{data.steps} samples; got {max_delay}")
    n = max(identifiers)
    lo = min(float(i.config.band[0]) for i in identifiers.values())
    hi = max(float(i.config.band[1]) for i in identifiers.values())
    # the CCF's coefficients in the user's time unit are products of up to n poles |p| / dt
    top, bottom = n * np.log10(hi / data.dt), n * np.log10(lo / data.dt)
    if top > 300 or bottom < -300:
        exponent = top if top > 300 else bottom
        raise ValueError(f"dt must give an order-{n} model that float64 can hold: with dt = "
                         f"{data.dt:g} the poles the identifier sees (|p| in [{lo:g}, {hi:g}] / "
                         f"dt) make CCF coefficients near 1e{exponent:.0f}; give the record in "
                         f"another time unit (dt between about 1e-{300 // n - 1} and "
                         f"1e{300 // n - 3})")
    return int(max_delay)


#: A level is removed where it exceeds this many times the signal's peak-to-peak variation.
LEVEL = 4.0


@dataclass(frozen=True)
class Units:
    """The units a record is identified in: ``y_work = (y - y_level) / sy`` and ``u_work = (u
    - u_level) / su`` (module docstring).

    Levels far above a signal's variation (an input of 1e6 +- 1) are removed first: a constant
    input level is absorbed exactly by the initial state and the offset (``x = x_w + x_ss``,
    ``x_ss = -A^-1 b u_level``), and without it the regressors cancel in the last digits. Then
    peaks outside ``2^-64 .. 2^64`` are scaled by powers of two.

    Attributes
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
    def of(cls, data: Record, structure) -> Units:
        """The units of ``data`` for ``structure``: ``sy = su`` where the structure fixes a
        gain element at a value other than 0 (or is physical), whose value a gain change would
        move.

        Parameters
        ----------
        data : Record
        structure : None, str or Structure

        Returns
        -------
        Units

        Raises
        ------
        ValueError
            Naming ``y`` and ``u``, where such a structure meets a record whose output and
            input are too far apart in magnitude for float64.
        """
        def level(x):
            m = float(np.mean(x))
            return m if abs(m) > LEVEL * float(np.ptp(x)) else 0.0

        y_level, u_level = level(data.y), level(data.u)
        y, u = data.y - y_level, data.u - u_level
        sy, su = exact_scale(y), exact_scale(u)
        fixed = getattr(structure, "fixed_values", {}) if isinstance(structure, Structure) else {}
        keeps_gain = isinstance(structure, Structure) and (
            not isinstance(structure, (CCF, MCF)) or any(
                (k == "d" or k.startswith("c")) and v != 0 for k, v in fixed.items()))
        if keeps_gain and sy != su:
            sy = su = exact_scale(np.concatenate([y, u]))
            if min(float(np.max(np.abs(v))) / sy for v in (y, u)) < 2.0 ** -SAFE_EXPONENT:
                raise ValueError(f"y and u: a structure with fixed gain elements "
                                 f"({structure!r}) keeps the record's gain, and max|y| = "
                                 f"{np.max(np.abs(data.y)):.3g} and max|u| = "
                                 f"{np.max(np.abs(data.u)):.3g} are too far apart for float64; "
                                 f"give y and u in units nearer to each other")
        return cls(sy, su, y_level, u_level)

    def apply(self, data: Record) -> Record:
        """The record in these units.

        Parameters
        ----------
        data : Record

        Returns
        -------
        Record
        """
        if self == Units():
            return data
        return dataclasses.replace(data, y=data.y - self.y_level, u=data.u - self.u_level,
                                   y_offset=data.y_offset + self.y_level,
                                   u_offset=data.u_offset + self.u_level).scaled(self.sy, self.su)

    def restore(self, est: Estimate, data: Record) -> Estimate:
        """The estimate of ``self.apply(data)`` for ``data`` itself: ``c, d`` times ``sy /
        su``, the state times ``su`` plus ``x_ss``, the offset ``sy o_w + y_level - c^T x_ss -
        d u_level``, the output times ``sy`` plus ``y_level``, the squared error times
        ``sy^2``.

        Parameters
        ----------
        est : Estimate
            Of the record in these units.
        data : Record
            The user's record.

        Returns
        -------
        Estimate

        Raises
        ------
        ValueError
            Where that model leaves float64.
        """
        if self == Units():
            return est
        sy, su = self.sy, self.su
        g = sy / su
        with np.errstate(over="ignore", under="ignore"):
            c, d = est.c * g, est.d * g
        lost = np.any((est.c != 0) & (c == 0)) or (est.d != 0 and d == 0)
        if not (np.isfinite(g) and g > 0 and np.all(np.isfinite(c)) and np.isfinite(d)) or lost:
            raise ValueError(f"y and u: the gain of this record (max|y| ~ 2^{np.log2(sy):.0f}, "
                             f"max|u| ~ 2^{np.log2(su):.0f}) makes a model that float64 cannot "
                             f"hold; give y and u in units nearer to each other")
        x_ss = (-np.linalg.solve(est.A, est.b) * self.u_level if self.u_level
                else np.zeros_like(est.b))
        elements = {k: v * g if (k == "d" or k.startswith("c")) else v
                    for k, v in est.elements.items()}
        info = dict(est.info)
        info["x0"] = np.asarray(info["x0"]) * su + x_ss
        info["y_offset"] = (float(info["y_offset"]) * sy + self.y_level - float(c @ x_ss)
                            - d * self.u_level)
        info["y_hat"] = np.asarray(info["y_hat"]) * sy + self.y_level
        info["cost"] = float(info["cost"]) * sy * sy
        info["units"] = dataclasses.asdict(self)
        return Estimate(A=est.A, b=est.b, c=c, d=d, elements=elements, y=data.y, u=data.u,
                        dt=data.dt, provenance=est.provenance, seconds=est.seconds,
                        refined=est.refined, info=info)
