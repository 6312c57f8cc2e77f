"""The validated record: :class:`RecordBatch`, made once by :func:`check_record` at the public
boundary and taken by everything behind it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeid_struct.records.checks import Checked, check_records, unit_step
from aeid_struct.records.measured import Record

__all__ = ["RecordBatch", "arrays_of", "check_record"]


@dataclass(frozen=True, eq=False)
class RecordBatch:
    """Records checked once, at the public boundary (:func:`check_record`).

    Everything behind the boundary takes this value and checks nothing again. One system's
    data may be ``R`` records (the several-record identifiers: one record per subsystem, each on
    its own grid); ``y``, ``u`` and ``dt`` hold one entry per record (the record axis).

    Attributes
    ----------
    y : tuple of R (count, steps_r) float64 arrays
        The outputs, a batch axis always (``count = 1`` for one unbatched record).
    u : tuple of R (count, steps_r) float64 arrays
        The inputs; a unit step where none was given.
    dt : tuple of R floats
        Sample times.
    batched : bool
        Whether the records came with a batch axis.
    problems : tuple of count (str or None), optional
        Per system, why it cannot be identified (the first of its records' problems), or None
        for a good one; default: all good.
    checked : bool
        Whether the records passed :func:`check_record` (or an equivalent check); a RecordBatch of
        arrays taken as they are (:meth:`of`) is checked by whoever needs it checked.
    """

    y: tuple
    u: tuple
    dt: tuple
    batched: bool
    problems: tuple | None = None
    checked: bool = False

    def __post_init__(self) -> None:
        if self.problems is None:
            object.__setattr__(self, "problems", (None,) * self.count)

    @classmethod
    def of(cls, y, u, dt, *, batched: bool | None = None) -> RecordBatch:
        """A RecordBatch of arrays taken as they are, unchecked (an ``Estimate`` built by hand).

        Parameters
        ----------
        y, u : (steps,) or (count, steps) arrays, or tuples of R of them
            ``u`` None (or None for a record) is a unit step.
        dt : float or tuple of R floats
        batched : bool, optional
            Default: whether ``y`` (its first record) has a batch axis.

        Returns
        -------
        RecordBatch
        """
        several = isinstance(y, tuple)
        ys = tuple(np.asarray(v) for v in (y if several else (y,)))
        us = (None,) * len(ys) if u is None else (tuple(u) if several else (u,))
        us = tuple(unit_step(np.shape(v)) if w is None else np.asarray(w)
                   for v, w in zip(ys, us, strict=True))
        if batched is None:
            batched = ys[0].ndim == 2
        dts = tuple(dt) if isinstance(dt, (tuple, list)) else (dt,)
        return cls(tuple(np.atleast_2d(v) for v in ys), tuple(np.atleast_2d(v) for v in us),
                   dts, batched)

    @property
    def records(self) -> int:
        """``R``: records per system (1, or one per subsystem)."""
        return len(self.y)

    @property
    def count(self) -> int:
        """Systems in the batch (1 for an unbatched record)."""
        return len(self.y[0])

    @property
    def good(self) -> np.ndarray:
        """``(count,)`` bool: the systems without a problem."""
        return np.array([p is None for p in self.problems], dtype=bool)

    def raise_first(self) -> None:
        """Raise the first system's problem as a :class:`RecordError` (none if all good)."""
        Checked(self.y[0], self.u[0], self.batched, self.problems).raise_first()

    def given(self, arrays: tuple):
        """``arrays`` (``y``, ``u`` or one like them) shaped as the user gave them: ``(steps,)``
        unbatched, ``(count, steps)`` batched, a tuple of ``R`` of those for several records.

        Parameters
        ----------
        arrays : tuple of R (count, steps_r) arrays

        Returns
        -------
        array or tuple of R arrays
        """
        out = tuple(a if self.batched else a[0] for a in arrays)
        return out[0] if self.records == 1 else out

    @property
    def times(self):
        """``dt`` as given: a float, or a tuple of ``R`` floats for several records."""
        return self.dt[0] if len(self.dt) == 1 else self.dt

    def take(self, index) -> RecordBatch:
        """The systems ``index`` of a batch (an int gives an unbatched RecordBatch).

        Parameters
        ----------
        index : int, int array, slice or (count,) bool mask

        Returns
        -------
        RecordBatch
        """
        rows = np.atleast_1d(np.arange(self.count)[index])
        batched = np.ndim(np.arange(self.count)[index]) == 1
        return RecordBatch(tuple(v[rows] for v in self.y), tuple(v[rows] for v in self.u), self.dt,
                      batched, tuple(self.problems[i] for i in rows), self.checked)


def check_record(y, u=None, *, steps, dt, reads_u: bool) -> RecordBatch:
    """Check a user's records once, into a :class:`RecordBatch` (the public boundary).

    Parameters
    ----------
    y : (steps,) or (batch, steps) array, or a sequence of R of them
        The outputs; a sequence of ``R`` records (one per subsystem) when ``steps`` is a tuple
        of ``R > 1``.
    u : like y, (steps,) for a whole batch, or None
        The inputs; None (or None for a record) is a unit step.
    steps : int or tuple of R ints
        Samples per record.
    dt : float or tuple of R floats
        Sample times (named in messages).
    reads_u : bool
        Whether the identifier reads ``u`` (otherwise ``u`` must be a constant step).

    Returns
    -------
    RecordBatch
        With each system's problem (non-finite, all zero, ...): the caller decides whether to
        raise (:meth:`RecordBatch.raise_first`) or to set those systems aside.

    Raises
    ------
    ValueError
        For a malformed argument (not real numbers, a wrong shape, no records, several-record
        sequences of another length or batch).
    """
    if not isinstance(steps, tuple):     # one record (a batch-1 call's path: no tuples)
        checked = check_records(y, u, steps=steps, dt=dt, reads_u=reads_u)
        return RecordBatch((checked.y,), (unit_step(checked.y.shape) if checked.u is None
                                          else np.asarray(checked.u),),
                           (float(dt),), checked.batched, checked.problems, checked=True)
    grids = list(zip(*(v if isinstance(v, tuple) else (v,) for v in (steps, dt)), strict=True))
    R = len(grids)
    if R == 1:
        checks = [check_records(y, u, steps=grids[0][0], dt=grids[0][1], reads_u=reads_u)]
    else:
        checks = _check_several(y, u, grids, reads_u)
    # A system is good when each of its R records is; its reason is the first one's.
    problems = checks[0].problems if R == 1 else tuple(
        next((c.problems[i] for c in checks if c.problems[i] is not None), None)
        for i in range(checks[0].count))
    return RecordBatch(tuple(c.y for c in checks),
                  tuple(unit_step(np.shape(c.y)) if c.u is None else np.asarray(c.u)
                        for c in checks),
                  tuple(float(t) for _, t in grids), checks[0].batched, problems, checked=True)


def _check_several(y, u, grids: list, reads_u: bool) -> list[Checked]:
    """:func:`check_records` of ``R`` records ``y[r], u[r]`` on their grids, batched alike."""
    R = len(grids)
    if _not_sequence(y, R):
        raise ValueError(f"y must be a sequence of {R} records (one per subsystem: "
                         f"{', '.join(f'{s} samples at dt={t}' for s, t in grids)}); "
                         f"got {type(y).__name__}")
    if u is not None and _not_sequence(u, R):
        raise ValueError(f"u must be None (unit steps) or a sequence of {R} inputs, one per "
                         f"record; got {type(u).__name__}")
    checks = []
    for r, (steps, dt) in enumerate(grids):
        checked = check_records(y[r], None if u is None else u[r], steps=steps, dt=dt,
                                reads_u=reads_u, names=(f"y[{r}]", f"u[{r}]"))
        if checks and (checked.batched != checks[0].batched
                       or checked.count != checks[0].count):
            raise ValueError(f"y[{r}] must be batched like y[0] ({checks[0].count} "
                             f"record(s), batch axis {checks[0].batched}); got shape "
                             f"{np.shape(y[r])}")
        checks.append(checked)
    return checks


def _not_sequence(value, R: int) -> bool:
    """Whether ``value`` is not a sequence of ``R`` records (an array is one record)."""
    array = isinstance(value, np.ndarray) or (hasattr(value, "detach") and hasattr(value, "cpu"))
    return array or not hasattr(value, "__len__") or len(value) != R


def arrays_of(y, u, dt, *, what: str, records: int = 1, channels=None):
    """The arrays ``(y, u, dt)`` of an entry point that reads arrays and takes a measured
    :class:`~aeid_struct.records.Record` too (``identify(record)``, the identifier protocol):
    a Record (a sequence of ``records`` of them for a several-record identifier) is unpacked,
    anything else is returned as it is, for the entry point's own checks.

    Parameters
    ----------
    y : Record, sequence of Record, or arrays
    u : None where ``y`` is a Record (it carries its input)
    dt : float, tuple or None
        Where given beside Records, it must be theirs.
    what : str
        The entry point, named in the messages.
    records : int
        Records the entry point reads as one set (1: one Record).
    channels : tuple of (output, input), optional
        Where the set is the channels of one measured record (a physical structure's
        ``channels``): one Record with several outputs (and inputs) is split into them
        (``Record.channel``); a sequence of ``records`` single-channel Records reads as well.

    Returns
    -------
    y, u, dt
        ``(steps,)`` arrays and a float for one Record; tuples of ``records`` for several.

    Raises
    ------
    ValueError
        A ``u`` beside a Record, a record of several channels, with a known input delay or a
        held input (``intersample="zoh"``; these identifiers model none of them), a number of
        Records other than ``records``, or a ``dt`` that is not the Records'.
    """
    several = isinstance(y, (list, tuple)) and len(y) > 0 and all(
        isinstance(r, Record) for r in y)
    if not (isinstance(y, Record) or several):
        return y, u, dt
    given = [y] if isinstance(y, Record) else list(y)
    if u is not None:
        raise ValueError(f"u must be None when {what} is given a Record (the record carries its "
                         f"input); got {type(u).__name__}")
    if channels is not None and isinstance(y, Record) and records > 1:
        try:
            given = [y.channel(o, i) for o, i in channels]
        except ValueError as err:
            raise ValueError(f"{what} reads the channels (output, input) {list(channels)} of "
                             f"one record; the record has {y.outputs} output(s) and "
                             f"{y.inputs} input(s): {err}") from None
    if len(given) != records or (records == 1 and several):
        raise ValueError(f"{what} reads {records} record{'s' if records > 1 else ''} as one set; "
                         f"got {len(given)} Record{'s' if len(given) > 1 else ''}"
                         + (" (stack the arrays of same-length records for a batch)"
                            if records == 1 else ""))
    for rec in given:
        rec.require_siso(what)
        if rec.delay:
            raise ValueError(f"{what} models no input delay; the record has delay={rec.delay} "
                             f"samples: pass record.shifted() (y[D:] with u[:steps - D])")
        if rec.intersample != "foh":
            # the encoder was trained on, and the head and refinement model, an input linear
            # between samples; a held input would come back as a slightly wrong model, unflagged
            raise ValueError(f"{what} models an input linear between samples (first-order "
                             f"hold, Eq. 10-13: its encoder was trained on such records); the "
                             f"record's input is held (intersample={rec.intersample!r}): "
                             f"identify it with ae.identify(record, order=n), which models the "
                             f"hold")
    dts = tuple(rec.dt for rec in given)
    if dt is not None and tuple(np.atleast_1d(dt)) != dts:
        raise ValueError(f"dt must be the record's own ({dts[0] if records == 1 else dts}) when "
                         f"given beside a Record; got {dt!r}")
    if records == 1:
        return given[0].y, given[0].u, given[0].dt
    return tuple(r.y for r in given), tuple(r.u for r in given), dts
