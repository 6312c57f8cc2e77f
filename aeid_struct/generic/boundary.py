"""The boundary of :func:`~aeid_struct.generic.identify` and
:func:`~aeid_struct.generic.compare`: a user's record, delay and sample time checked once
(:func:`measured`, :func:`check_grid`), and whether a structure must keep the record's gain
(:func:`keeps_gain`, which decides the ``records.Units`` the record is identified in; the
estimate is taken back to the user's units by ``generic.result.restore``, the last stage).
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass

import numpy as np

from aeid_struct.generic.normalised import feedthrough_of, separable
from aeid_struct.records import Record, Units
from aeid_struct.structures import CCF, MCF, Structure

__all__ = ["METHODS", "Call", "check_grid", "checked", "keeps_gain", "measured", "warn_caller"]

#: Refinement methods of ``ae.identify``.
METHODS = ("auto", "separable", "casadi")


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
        Any object with attributes ``y`` (and optionally ``u``, ``dt``, ``delay``, ``t0``,
        ``intersample``); a
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
                     delay=getattr(record, "delay", None), t0=getattr(record, "t0", 0.0),
                     intersample=getattr(record, "intersample", "foh"))
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


def shortest(order: int) -> int:
    """The fewest samples a record must leave after its delay for a model of ``order``: twice
    the parameters fitted to it (``n`` poles, ``n`` numerator terms, a feedthrough, ``n``
    initial states, an offset: ``3 n + 2``).

    Parameters
    ----------
    order : int, >= 1

    Returns
    -------
    int
    """
    return 2 * (3 * int(order) + 2)


def check_grid(data: Record, identifiers: dict, max_delay: int | None, default: int) -> int:
    """Refuse a record too short for the model (:func:`shortest` samples after the delay), a
    known delay or a given ``max_delay`` that leaves fewer, and a sample time whose
    de-normalised model cannot be represented in float64; return the largest delay to consider.
    A record shorter than an identifier's window is read at a finer grid
    (``generic.windows.Windows``).

    Parameters
    ----------
    data : Record
        Checked (:func:`measured`), with its known delay or None.
    identifiers : dict order -> generic identifier
        Their ``config.window`` (samples) and ``config.band`` (``|p| dt``, rad/sample).
    max_delay : int or None
        The user's; None: ``default`` capped by what the record leaves.
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
    n = max(identifiers)
    need = shortest(n)
    if data.steps < need:
        raise ValueError(f"the record has {data.steps} samples; a model of order {n} needs at "
                         f"least {need} (twice its {3 * n + 2} fitted parameters)")
    room = data.steps - need
    if data.delay is not None and data.delay > room:
        raise ValueError(f"delay must leave at least {need} samples after it (twice the "
                         f"{3 * n + 2} parameters of an order-{n} model): at most {room} for "
                         f"this record of {data.steps} samples; got {data.delay}")
    if max_delay is None:
        max_delay = min(default, room)
    if data.delay is None and max_delay > room:
        raise ValueError(f"max_delay must leave at least {need} samples after the delay "
                         f"(twice the {3 * n + 2} parameters of an order-{n} model): at most "
                         f"{room} for this record of {data.steps} samples; got {max_delay}")
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


@dataclass(frozen=True)
class Call:
    """A call of ``ae.identify`` after its check stage: everything the later stages read.

    Attributes
    ----------
    data : Record
        The user's record, checked (with the known delay, if any).
    work : Record
        The same record in its working units (``units.apply(data)``).
    units : records.Units
    order : int or None
        None: selected among ``identifiers``.
    identifiers : dict order -> generic identifier
    max_delay : int
        The largest delay to consider.
    feedthrough : bool
        Whether the structure has a free feedthrough.
    """

    data: Record
    work: Record
    units: Units
    order: int | None
    identifiers: dict
    max_delay: int
    feedthrough: bool


def checked(resolve, record, order, *, structure, refine, delay, max_delay, method, iterations,
            classical, what: str, default_max_delay: int) -> Call:
    """The check stage of ``ae.identify`` (``generic.pipeline.run``): every argument checked
    once, the identifiers resolved, the record checked against their grid and taken to its
    working units.

    Parameters
    ----------
    resolve : callable
        ``resolve(order) -> dict order -> identifier`` (``generic.pipeline.run``).
    record, order, structure, refine, delay, max_delay, method, iterations, classical
        As ``ae.identify``.
    what : str
        The entry point, named where a record of several channels is refused.
    default_max_delay : int
        ``max_delay`` where None is given (capped by the record).

    Returns
    -------
    Call

    Raises
    ------
    ValueError
        Naming the argument, in the order the arguments are listed above (the record's own
        checks after ``refine`` and ``classical``).
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(map(repr, METHODS))}; got "
                         f"{method!r}")
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or (
            iterations < 0):
        raise ValueError(f"iterations must be an integer >= 0 (Levenberg-Marquardt iterations "
                         f"of the one pass); got {iterations!r}")
    for name, value in (("refine", refine), ("classical", classical)):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{name} must be True or False; got {value!r}")
    data = measured(record, delay, what=what)
    if max_delay is not None and (isinstance(max_delay, bool) or not isinstance(
            max_delay, (int, np.integer)) or max_delay < 0):
        raise ValueError(f"max_delay must be None or an integer >= 0; got {max_delay!r}")
    order = _order(order, structure)
    if method == "separable" and not separable(structure):
        raise ValueError(f"method='separable' refines the free CCF and MCF only; got "
                         f"structure {structure!r} (use 'auto' or 'casadi')")
    identifiers = resolve(order)
    if order is None:
        # the orders the record can carry (twice their parameters), the smallest at least:
        # a short record is not refused for the highest order it was never asked to fit
        carried = {n: i for n, i in identifiers.items() if shortest(n) <= data.steps}
        identifiers = carried or {min(identifiers): identifiers[min(identifiers)]}
    data.require_informative()
    max_delay = check_grid(data, identifiers, max_delay, default_max_delay)
    # levels far above the variation removed, amplitudes far from 1 rescaled by powers of two
    # (both exact; records.Units); a structure with fixed gain elements keeps its gain
    units = Units.of(data, keeps_gain(structure))
    return Call(data, units.apply(data), units, order, identifiers, max_delay,
                feedthrough_of(structure))


def _order(order, structure):
    """The model order a call asks for (None: selected), checked against the structure."""
    if structure is not None and not isinstance(structure, (str, Structure)):
        raise ValueError(f"structure must be None, 'ccf', 'mcf' or a Structure; got "
                         f"{type(structure).__name__}")
    if isinstance(structure, str) and structure not in ("ccf", "mcf"):
        raise ValueError(f"structure must be 'ccf', 'mcf' or a Structure; got {structure!r}")
    if isinstance(structure, Structure):
        if order is not None and order != structure.n:
            raise ValueError(f"order must match the structure's order {structure.n}; got "
                             f"{order}")
        order = structure.n
    if order is not None and (isinstance(order, bool) or not isinstance(order, (int, np.integer))
                              or order < 1):
        raise ValueError(f"order must be None (selected) or an integer >= 1; got {order!r}")
    return None if order is None else int(order)


def warn_caller(message: str, category: type[Warning]) -> None:
    """``warnings.warn`` attributed to the caller's first frame outside ``aeid_struct``: the
    entry points reach their warnings through a varying depth of the library's frames (the
    thread limit's wrapper, the one-call body, the fit stage), which a fixed ``stacklevel``
    would attribute to one of them.

    Parameters
    ----------
    message : str
    category : Warning subclass
    """
    frame, level = sys._getframe(1), 2      # stacklevel 1 is this function
    while frame is not None and frame.f_globals.get("__name__", "").startswith("aeid_struct"):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level)
