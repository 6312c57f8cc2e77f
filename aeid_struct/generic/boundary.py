"""The boundary of :func:`~aeid_struct.generic.identify` and
:func:`~aeid_struct.generic.compare`: a user's record, delay and sample time checked once
(:func:`measured`, :func:`check_grid`), and the estimate of a record identified in other units
(``records.Units``: a level far above the signal's variation removed, amplitudes brought near 1
by powers of two) taken back to the user's (:func:`restore`).

"""

from __future__ import annotations

import numpy as np

from aeid_struct.identification import Estimate
from aeid_struct.records import Record, Units
from aeid_struct.structures import CCF, MCF, Structure

__all__ = ["check_grid", "keeps_gain", "measured", "restore"]


def _delay(name: str, value, steps: int) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not (
            0 <= value <= steps - 2):
        raise ValueError(f"{name} must be None (unknown) or an integer number of samples in "
                         f"[0, {steps - 2}]; got {value!r}")
    return int(value)


def measured(record, delay=None, *, what: str = "ae.identify") -> Record:
    """A user's record as a checked :class:`~aeid_struct.records.Record` (checked once: a
    Record is taken as it is, anything else goes through Record's own checks).

    Parameters
    ----------
    record : Record, (y, u) or (y, u, dt) tuple, or (steps,) array
        Any object with attributes ``y`` (and optionally ``u``, ``dt``, ``delay``, ``t0``); a
        lone array is ``y`` with a unit step input and ``dt = 1``.
    delay : int, optional
        A known input delay in samples, over the record's own.
    what : str
        The entry point, named where a record of several channels is refused.

    Returns
    -------
    Record
        With the known delay (or None); at least 2 samples are left after it.

    Raises
    ------
    ValueError
        Naming the argument: not real numbers, a wrong shape, a non-finite sample, ``u`` of
        another length, a bad ``dt`` or ``delay``; a record of several outputs or inputs.
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
    rec.require_siso(what)
    known = _delay("record.delay", rec.delay, rec.steps)
    given = _delay("delay", delay, rec.steps)
    return rec if given is None or given == known else rec.with_delay(given)


def check_grid(data: Record, identifiers: dict, max_delay: int | None, default: int) -> int:
    """Refuse a record shorter than an identifier's window, a known delay or a given
    ``max_delay`` that leaves less than the window, and a sample time whose de-normalised model
    cannot be represented in float64; return the largest delay to consider.

    Parameters
    ----------
    data : Record
        Checked (:func:`measured`), with its known delay or None.
    identifiers : dict order -> generic identifier
        Their ``config.window`` (samples) and ``config.band`` (``|p| dt``, rad/sample).
    max_delay : int or None
        The user's; None: ``default`` capped by what the record leaves after the window.
    default : int

    Returns
    -------
    int
        The largest delay to consider.

    Raises
    ------
    ValueError
        Naming the record's length, ``delay``, ``max_delay`` or ``dt``.
    """
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


def keeps_gain(structure) -> bool:
    """Whether ``structure`` fixes a gain element at a value other than 0 (or is physical):
    its records keep their gain (``Units.of(..., keep_gain=True)``), since a gain change would
    move that value.

    Parameters
    ----------
    structure : None, str or Structure

    Returns
    -------
    bool
    """
    if not isinstance(structure, Structure):
        return False
    if not isinstance(structure, (CCF, MCF)):
        return True
    return any((k == "d" or k.startswith("c")) and v != 0
               for k, v in structure.fixed_values.items())


def restore(units: Units, est: Estimate, data: Record) -> Estimate:
    """The estimate of ``units.apply(data)`` for ``data`` itself (``Units.estimate``; why the
    units are exact: ``records.units``).

    Parameters
    ----------
    units : Units
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
    if units.identity:
        return est
    c, d, elements, info = units.estimate(est.A, est.b, est.c, est.d, est.elements, est.info)
    return Estimate(A=est.A, b=est.b, c=c, d=d, elements=elements, record=data,
                    provenance=est.provenance, seconds=est.seconds,
                    refined=est.refined, info=info)
