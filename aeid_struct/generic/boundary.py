"""The boundary of :func:`~aeid_struct.generic.identify` and
:func:`~aeid_struct.generic.compare`: a user's record, delay and sample time checked once
(:func:`measured`, :func:`check_grid`), and a record's amplitudes brought near 1 by powers of two
and the estimate taken back to the user's units (:func:`amplitude_scales`, :func:`unscaled`).

Why an exact rescaling: the model of a record is linear in its amplitudes. With ``y = sy y_s``,
``u = su u_s`` and ``x = su x_s``, a model ``(A, b, c_s, d_s)`` of the scaled record with state
``x_s``, offset ``o_s`` is the model ``(A, b, (sy / su) c_s, (sy / su) d_s)`` of the record with
state ``su x_s`` and offset ``sy o_s``; powers of two change only exponents, so the scaled record
carries the measured digits, and an output of 1e-200 (whose squares underflow) or 1e200 (whose
squares overflow) is identified as exactly as one of 1.
"""

from __future__ import annotations

import numpy as np

from aeid_struct.identification import Estimate
from aeid_struct.records import Record, exact_scale
from aeid_struct.structures import CCF, MCF, Structure

__all__ = ["amplitude_scales", "check_grid", "measured", "unscaled"]


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


def check_grid(data: Record, identifiers: dict, max_delay: int) -> None:
    """Refuse a known delay or ``max_delay`` that leaves less than an identifier's window, and
    a sample time whose de-normalised model cannot be represented in float64."""
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
    if data.delay is None and max_delay > room:
        raise ValueError(f"max_delay must leave at least the identifier's window ({window} "
                         f"samples) after the delay: at most {room} for this record of "
                         f"{data.steps} samples; got {max_delay}")
    n = max(identifiers)
    lo, hi = (min(float(i.config.band[k]) for i in identifiers.values()) if k == 0 else
              max(float(i.config.band[k]) for i in identifiers.values()) for k in (0, 1))
    # the CCF's coefficients in the user's time unit are products of up to n poles |p| / dt
    top, bottom = n * np.log10(hi / data.dt), n * np.log10(lo / data.dt)
    if top > 300 or bottom < -300:
        exponent = top if top > 300 else bottom
        raise ValueError(f"dt must give an order-{n} model that float64 can hold: with dt = "
                         f"{data.dt:g} the poles the identifier sees (|p| in [{lo:g}, {hi:g}] / "
                         f"dt) make CCF coefficients near 1e{exponent:.0f}; give the record in "
                         f"another time unit (dt between about 1e-{300 // n - 1} and "
                         f"1e{300 // n - 3})")


def amplitude_scales(data: Record, structure) -> tuple[float, float]:
    """``(sy, su)``: powers of two that bring the record's peaks near 1 where they are far
    from it (:func:`~aeid_struct.records.exact_scale`); equal where the structure fixes gain
    elements (any fixed ``c``/``d`` value or a physical structure), whose values a gain change
    would move."""
    sy, su = exact_scale(data.y), exact_scale(data.u)
    keeps_gain = isinstance(structure, Structure) and (
        not isinstance(structure, (CCF, MCF)) or any(
            k == "d" or k.startswith("c") for k in structure.fixed_values))
    if keeps_gain and sy != su:
        sy = su = exact_scale(np.concatenate([data.y, data.u]))
    return sy, su


def unscaled(est: Estimate, data: Record, sy: float, su: float) -> Estimate:
    """The estimate of ``data.scaled(sy, su)`` for ``data`` itself: ``c, d`` times ``sy /
    su``, the state times ``su``, offset and output times ``sy``, the squared error times
    ``sy^2`` (powers of two: exact); a ValueError where that model overflows."""
    if sy == 1.0 and su == 1.0:
        return est
    g = sy / su
    with np.errstate(over="ignore", under="ignore"):
        c, d = est.c * g, est.d * g
    lost = np.any((est.c != 0) & (c == 0)) or (est.d != 0 and d == 0)
    if not (np.isfinite(g) and g > 0 and np.all(np.isfinite(c)) and np.isfinite(d)) or lost:
        raise ValueError(f"y and u: the gain of this record (max|y| ~ 2^{np.log2(sy):.0f}, "
                         f"max|u| ~ 2^{np.log2(su):.0f}) makes a model that float64 cannot "
                         f"hold; give y and u in units nearer to each other")
    elements = {k: v * g if (k == "d" or k.startswith("c")) else v
                for k, v in est.elements.items()}
    info = dict(est.info)
    info["x0"] = np.asarray(info["x0"]) * su
    info["y_offset"] = float(info["y_offset"]) * sy
    info["y_hat"] = np.asarray(info["y_hat"]) * sy
    info["cost"] = float(info["cost"]) * sy * sy
    info["scales"] = {"y": sy, "u": su}
    return Estimate(A=est.A, b=est.b, c=c, d=d, elements=elements, y=data.y, u=data.u,
                    dt=data.dt, provenance=est.provenance, seconds=est.seconds,
                    refined=est.refined, info=info)
