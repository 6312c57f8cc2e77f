"""The validated record: :class:`RecordBatch`, made once by :func:`check_record` at the public
boundary and taken by everything behind it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeid_struct.records.checks import Checked, check_records, unit_step

__all__ = ["RecordBatch", "check_record"]


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
    grids = list(zip(*(v if isinstance(v, tuple) else (v,) for v in (steps, dt)), strict=True))
    R = len(grids)
    if R == 1:
        checks = [check_records(y, u, steps=grids[0][0], dt=grids[0][1], reads_u=reads_u)]
    else:
        checks = _check_several(y, u, grids, reads_u)
    # A system is good when each of its R records is; its reason is the first one's.
    problems = tuple(next((c.problems[i] for c in checks if c.problems[i] is not None), None)
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
