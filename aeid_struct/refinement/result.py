"""What a fit over a whole record returns: the one :class:`~aeid_struct.estimates.Estimate`,
built here for the refinement over a CasADi graph (``record.py``) and the separable one of a
free CCF (``separable.py``)."""

from __future__ import annotations

import numpy as np

from aeid_struct.estimates import Estimate, Provenance
from aeid_struct.records import RecordBatch
from aeid_struct.structures import Structure

__all__ = ["fitted"]


def fitted(structure: Structure, model: tuple, elements: dict, y: np.ndarray, u: np.ndarray,
           dt: float, *, seconds: float, **info) -> Estimate:
    """The Estimate of a record's fit.

    Parameters
    ----------
    structure : Structure
        The structure the model is in (its provenance: ``refine`` and ``physical`` read it).
    model : (A (n, n), b (n,), c (n,), d float)
        In the time unit of ``dt``.
    elements : dict name -> float
    y, u : (N,) arrays
        The record (checked by the caller).
    dt : float
    seconds : float
        Wall time of the fit.
    **info
        ``delay, x0, y_offset, fit, y_hat`` (what the estimate reads of a record with a delay
        and an offset: ``Estimate.delay``, ``offset``, ``x0``, ``fit``, ``y_hat``), ``cost``,
        ``iterations``, ``converged`` and the method's own.

    Returns
    -------
    Estimate
        Of one record, ``initial="fitted"``, ``refined=True``.
    """
    A, b, c, d = model
    # the record as the checked batch of one an identifier's estimate holds: y and u were
    # checked by the fit, and a Record would check them again
    record = RecordBatch.of(y, u, dt, batched=False)
    return Estimate(A=A, b=b, c=c, d=float(d), elements=elements, record=record,
                    provenance=Provenance(structure=structure, initial="fitted"),
                    seconds=seconds, refined=True, info=info)
