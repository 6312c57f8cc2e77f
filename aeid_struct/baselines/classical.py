"""A classical method behind an identifier's interface, record by record (:class:`Classical`).

The methods themselves: :func:`~aeid_struct.baselines.n4sid`,
:func:`~aeid_struct.baselines.least_squares`, :func:`~aeid_struct.baselines.casadi_cold`.
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from aeid_struct.identification import Estimate, Provenance
from aeid_struct.records import RecordBatch, arrays_of, as_array, unit_step
from aeid_struct.simulation import check_dt

__all__ = ["Classical"]


@dataclass(frozen=True)
class Classical:
    """A classical method behind an identifier's interface, record by record.

    ``identify(y, u)`` applies the method to each record and stacks the estimates into one
    batched :class:`Estimate` (NaN rows where a record failed), so that scorecards and
    benchmarks score a classical method exactly like an encoder. ``info["records"]`` keeps each
    record's own ``info`` and ``info["failed"]`` is a ``(batch,)`` bool array.

    Attributes
    ----------
    method : callable
        One of the baselines with its keyword arguments bound, e.g.
        ``functools.partial(least_squares, structure=CCF(2).fixed(a1=0.0), inverse=f)``;
        called as ``method(y, u, dt)`` on one record.
    dt : float
        The record format's sample time.
    steps : int
        The record format's samples per record.
    """

    method: object
    dt: float
    steps: int

    def __post_init__(self) -> None:
        if not callable(self.method):
            raise ValueError(f"method must be callable (e.g. functools.partial(least_squares, "
                             f"structure=...)); got {type(self.method).__name__}")
        check_dt(self.dt)
        if not isinstance(self.steps, int) or self.steps < 2:
            raise ValueError(f"steps must be an integer >= 2; got {self.steps!r}")

    def identify(self, y, u=None, *, refine: bool = False) -> Estimate:
        """Identify each record with the method.

        Parameters
        ----------
        y : Record, (batch, steps) or (steps,)
            A measured ``records.Record`` at the format's ``dt`` (which carries ``u``), or
            the outputs.
        u : like ``y``, or (steps,) for every record, or None for unit steps
        refine : bool
            Polish each estimate that did not fail (:mod:`aeid_struct.refinement`).

        Returns
        -------
        Estimate
            Batched for a ``(batch, steps)`` ``y``, single for ``(steps,)``.

        Raises
        ------
        ValueError
            For a ``y`` or ``u`` of the wrong shape.
        """
        start = time.perf_counter()
        y, u, dt = arrays_of(y, u, None, what="Classical.identify")
        if dt is not None and dt != self.dt:
            raise ValueError(f"the record's dt must be this method's dt = {self.dt}; got {dt}")
        Y = np.atleast_2d(as_array("y", y))
        if Y.ndim != 2 or Y.shape[1] != self.steps:
            raise ValueError(f"y must have shape ({self.steps},) or (batch, {self.steps}); "
                             f"got {np.shape(y)}")
        U = unit_step(Y.shape) if u is None else np.atleast_2d(as_array("u", u))
        if U.ndim != 2 or U.shape[1] != self.steps or U.shape[0] not in (1, len(Y)):
            raise ValueError(f"u must have shape ({self.steps},) or ({len(Y)}, {self.steps}) "
                             f"like y; got {np.shape(u)}")
        U = np.broadcast_to(U, Y.shape)
        parts = []
        for y_i, u_i in zip(Y, U, strict=True):
            est = self.method(y_i, u_i, self.dt)
            if refine and not est.info.get("failed") and est.structure is not None:
                from aeid_struct.refinement import refine as _refine

                est = _refine(est, y_i, u_i, self.dt)
            parts.append(est)
        est = _stack(parts, Y, np.asarray(U), self.dt, time.perf_counter() - start, refine)
        return est if np.ndim(y) == 2 else _single(est)


def _stack(parts: list[Estimate], Y, U, dt: float, seconds: float, refined: bool) -> Estimate:
    """One batched estimate of the records' estimates, NaN where a record's model is missing."""
    n = max(np.shape(p.A)[-1] for p in parts)
    names = list(dict.fromkeys(k for p in parts for k in p.elements))

    def stack(get, shape):
        out = np.full((len(parts), *shape), math.nan)
        for i, p in enumerate(parts):
            value = np.asarray(get(p), dtype=np.float64)
            if value.shape == shape:
                out[i] = value
        return out

    A, b, c = stack(lambda p: p.A, (n, n)), stack(lambda p: p.b, (n,)), \
        stack(lambda p: p.c, (n,))
    d = stack(lambda p: p.d, ())
    elements = {k: stack(lambda p, k=k: p.elements.get(k, math.nan), ()) for k in names}
    source = next((p.provenance.inverse for p in parts if p.provenance.inverse is not None),
                  None)
    info = {"method": parts[0].info.get("method", ""), "records": [p.info for p in parts],
            "failed": np.array([bool(p.info.get("failed")) for p in parts])}
    return Estimate(A=A, b=b, c=c, d=d, elements=elements,
                    record=RecordBatch.of(Y, U, dt, batched=True),
                    provenance=Provenance(structure=parts[0].structure, inverse=source),
                    seconds=seconds, refined=bool(refined), info=info)


def _single(est: Estimate) -> Estimate:
    """The one record of a batch-1 estimate, unbatched."""
    one = est.take(0)
    return dataclasses.replace(one, elements={k: float(v) for k, v in one.elements.items()},
                               d=float(one.d), info={**est.info,
                                                     "failed": bool(est.info["failed"][0])})
