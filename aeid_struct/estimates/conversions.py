"""An estimate's model in other forms: python-control state spaces (``Estimate.to_control``)
and physical parameters (``Estimate.physical``). The seam: these read a finished Estimate and
build something else from it (another library's objects, the structure's inverse map), apart
from the class that holds and derives the estimate (``estimate.py``).
"""

from __future__ import annotations

import numpy as np

from aeid_struct.estimates.physical import inverse_of_models
from aeid_struct.structures import type_of

__all__ = ["physical_parameters", "state_spaces"]


def state_spaces(est):
    """``Estimate.to_control``."""
    import control

    def one(A, b, c, d):
        n = A.shape[0]
        return control.ss(A, b.reshape(n, 1), c.reshape(1, n), np.reshape(d, (1, 1)))

    if np.ndim(est.b) == np.ndim(est.A) or (est.records > 1 and np.ndim(est.A) == 2):
        # one model of several channels, or of several experiments
        return control.ss(est.A, est.B, est.C, est.D)
    if est.records > 1:   # a list per record (per batch row and record when batched)
        A, b, c, d = (np.asarray(x) for x in (est.A, est.b, est.c, est.d))
        rows = [(A, b, c, d)] if not est.batched else list(zip(A, b, c, d, strict=True))
        out = [[one(*m) for m in zip(*row, strict=True)] for row in rows]
        return out if est.batched else out[0]
    if not est.batched:
        return one(est.A, est.b, est.c, est.d)
    return [one(*m) for m in zip(est.A, est.b, est.c, est.d, strict=True)]


def physical_parameters(est) -> dict:
    """``Estimate.physical``: name -> float or ``(batch,)``."""
    inverse = est.provenance.inverse
    if inverse is None:
        return {}
    if isinstance(inverse, tuple) and inverse[0] == "elements":
        return {name: est.elements[name] for name in inverse[1]}
    A = np.asarray(est.A, dtype=np.float64)
    A = A[None] if A.ndim == 2 else A
    count, n = A.shape[0], A.shape[-1]
    b = np.asarray(est.b, dtype=np.float64).reshape(count, n)
    c = np.asarray(est.c, dtype=np.float64).reshape(count, n)
    d = np.asarray(est.d, dtype=np.float64).reshape(count)
    result = inverse_of_models(inverse, A, b, c, d, type_of(est.structure) == "CCF")
    if not est.batched:
        result = {k: float(v[0]) for k, v in result.items()}
    return result
