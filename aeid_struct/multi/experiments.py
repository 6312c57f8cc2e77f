r"""The boundary of the several-channel fit: records of one system (one record of ``p`` outputs
and ``m`` inputs, or several experiments), checked once into :class:`Experiments`, in working
units.

Working units: each output has its pooled mean removed and is divided by its pooled standard
deviation (the output offsets are parameters of the model, so removing a level is exact); each
input is divided by its pooled root mean square and keeps its level (a constant input is not an
offset for an integrating plant: it drives a ramp). Time is counted in samples. The model is
taken back to the user's units in ``multi.model.physical``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from aeid_struct.records import Record

__all__ = ["Experiments", "check_delays", "experiments_of", "several"]


def several(record) -> bool:
    """Whether ``record`` is for the several-channel fit: a Record of several outputs or
    inputs, or a list or tuple of Records (several experiments).

    Parameters
    ----------
    record : object

    Returns
    -------
    bool
    """
    if isinstance(record, Record):
        return record.outputs > 1 or record.inputs > 1
    return isinstance(record, (list, tuple)) and len(record) > 0 and all(
        isinstance(r, Record) for r in record)


@dataclass(frozen=True, eq=False)
class Experiments:
    """Records of one system in working units (module docstring), checked once.

    Attributes
    ----------
    records : tuple of R Record
        The user's records.
    Y : tuple of R (steps_r, p) arrays
        Outputs in working units.
    U : tuple of R (steps_r, m) arrays
        Inputs in working units.
    holds : tuple of R str
        Each record's ``intersample``.
    dt : float
        The common sample time.
    y_mean : (p,) array
        The outputs' pooled means (``y = y_scale * Y + y_mean``).
    y_scale : (p,) array
        The outputs' pooled standard deviations.
    u_scale : (m,) array
        ``u = u_scale * U``.
    delay : (m,) int array or None
        Known input delays in samples (None: estimated).
    """

    records: tuple
    Y: tuple
    U: tuple
    holds: tuple
    dt: float
    y_mean: np.ndarray
    y_scale: np.ndarray
    u_scale: np.ndarray
    delay: np.ndarray | None

    @property
    def outputs(self) -> int:
        """``p``."""
        return self.Y[0].shape[1]

    @property
    def inputs(self) -> int:
        """``m``."""
        return self.U[0].shape[1]

    @property
    def count(self) -> int:
        """``R``, the experiments."""
        return len(self.Y)

    @property
    def steps(self) -> tuple:
        """Samples per record."""
        return tuple(y.shape[0] for y in self.Y)

    def aligned(self, delays) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per record, the outputs from sample ``max(delays)`` on and each input ``j`` delayed
        by ``delays[j]`` on the same samples: ``(Y[D:], U_delayed)``, both ``(steps - D, .)``.

        Parameters
        ----------
        delays : (m,) ints

        Returns
        -------
        list of R (Y, U) pairs
        """
        delays = np.asarray(delays, dtype=int)
        top = int(delays.max())
        out = []
        for Y, U in zip(self.Y, self.U, strict=True):
            N = Y.shape[0]
            Ud = np.stack([U[top - D: N - D, j] for j, D in enumerate(delays)], axis=1)
            out.append((Y[top:], Ud))
        return out

    def cut(self, share: float) -> tuple[Experiments, Experiments]:
        """The first ``share`` and the rest of every record, in the same working units (the
        order's hold-out split).

        Parameters
        ----------
        share : float in (0, 1)

        Returns
        -------
        (Experiments, Experiments)
        """
        cuts = [int(round(share * y.shape[0])) for y in self.Y]

        def part(first: bool) -> Experiments:
            pick = [slice(0, c) if first else slice(c, None) for c in cuts]
            return dataclasses.replace(self, Y=tuple(y[s] for y, s in zip(self.Y, pick,
                                                                           strict=True)),
                                       U=tuple(u[s] for u, s in zip(self.U, pick, strict=True)))
        return part(True), part(False)


def check_delays(delay, m: int) -> np.ndarray | None:
    """A known delay (an int for every input, or one per input) as ``(m,)`` ints, or None.

    Parameters
    ----------
    delay : None, int or sequence of m ints
    m : int
        Inputs.

    Returns
    -------
    (m,) int array or None

    Raises
    ------
    ValueError
        Naming ``delay``: not integers >= 0, or another count than 1 or ``m``.
    """
    if delay is None:
        return None
    values = np.atleast_1d(np.asarray(delay, dtype=object))
    if values.ndim != 1 or len(values) not in (1, m) or not all(
            isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v >= 0
            for v in values):
        raise ValueError(f"delay must be None (estimated), an integer >= 0 for every input, or "
                         f"{m} integers >= 0 (one per input); got {delay!r}")
    return np.broadcast_to(np.asarray(values, dtype=int), (m,)).copy()


def experiments_of(record, delay=None, *, what: str = "ae.identify") -> Experiments:
    """Check records of one system once (:class:`Experiments`).

    Parameters
    ----------
    record : Record or sequence of Record
        One record of several channels, or several experiments (each with its own initial
        state and offsets): the same outputs, inputs and ``dt``.
    delay : int or sequence of m ints, optional
        Known input delays in samples (over the records'); None: the records' own where they
        give one (all alike), else estimated.
    what : str
        The entry point, named in messages.

    Returns
    -------
    Experiments

    Raises
    ------
    ValueError
        Naming the record: not Records, records of other channels, sample times or delays, a
        constant output or input.
    """
    given = [record] if isinstance(record, Record) else list(record)
    if not given or not all(isinstance(r, Record) for r in given):
        raise ValueError(f"{what}: several experiments must be a list of ae.Record; got "
                         f"{[type(r).__name__ for r in given]}")
    first = given[0]
    for k, r in enumerate(given[1:], 1):
        if (r.outputs, r.inputs) != (first.outputs, first.inputs):
            raise ValueError(f"record[{k}] must have the channels of record[0] ({first.outputs} "
                             f"output(s), {first.inputs} input(s)); got {r.outputs} and "
                             f"{r.inputs}")
        if r.dt != first.dt:
            raise ValueError(f"record[{k}] must have the sample time of record[0] (dt = "
                             f"{first.dt:g}); got dt = {r.dt:g} (resample it first)")
    m = first.inputs
    known = {r.delay for r in given}
    if delay is None and len(known) > 1:
        raise ValueError(f"the records' delays must agree (one system); got "
                         f"{sorted(known, key=str)}")
    delays = check_delays(delay if delay is not None else first.delay, m)
    Ys = [r.Y for r in given]
    Us = [r.U for r in given]
    for k, r in enumerate(given):
        try:
            r.require_informative()
        except ValueError as err:
            raise ValueError(f"record[{k}]: {err}" if len(given) > 1 else str(err)) from None
    allY, allU = np.vstack(Ys), np.vstack(Us)
    y_mean, y_scale = allY.mean(axis=0), allY.std(axis=0)
    u_scale = np.sqrt(np.mean(allU ** 2, axis=0))
    return Experiments(tuple(given), tuple((Y - y_mean) / y_scale for Y in Ys),
                       tuple(U / u_scale for U in Us), tuple(r.intersample for r in given),
                       float(first.dt), y_mean, y_scale, u_scale, delays)
