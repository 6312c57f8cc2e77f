"""``refine=True`` for a physical structure (one record; the channels of one record; the
records of the joint leg): the output-error optimum of the parameters over every record
(``refinement.fit_joint``) from the estimate's parameters, with their standard errors at the
optimum, as ``greyest`` gives them.

Why not the CasADi NLP (``refinement.refine``) for one record too: the NLP discretises the
structure's canonical form, whose companion matrix grows with the spread of the physical
parameters' scales; for a quarter car (masses 25-400 kg, stiffnesses 1.5e4-2.5e5 N/m, dt 2
ms) it needed 12 squarings, its gradient stalled at a round-off floor of 1e-6 and it ran its
100 iterations to a cost up to 4 % above the optimum of a window cut mid-motion (145 ms a
record), where the Levenberg-Marquardt of ``fit_joint`` reached the optimum in 3-26 ms (the
NLP's projection and stopping rule have been mended since: ``refinement.solve``)."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from aeid_struct.estimates import Estimate
from aeid_struct.identification.physical_errors import parameter_errors, parameters_of
from aeid_struct.identification.physical_head import physical_head

__all__ = ["is_joint", "refine_joint"]


def is_joint(est) -> bool:
    """Whether ``est`` is in a physical structure (refined here, whatever its records).

    Parameters
    ----------
    est : Estimate

    Returns
    -------
    bool
    """
    from aeid_struct.structures import type_of

    return type_of(est.structure) == "Physical"


def refine_joint(est: Estimate, rows=None) -> Estimate:
    """The estimate's parameters polished to the output-error optimum over all its records,
    within the bounds; records set aside (``errors="collect"``) or without finite parameters
    are kept as they are.

    Parameters
    ----------
    est : Estimate
        An identifier's estimate in a physical structure of ``R >= 1`` records.
    rows : (batch,) bool array, optional
        The records to refine (``refine="auto"``: the flagged ones); the others are kept as
        they are (``info["refined_rows"]``). Default: all.

    Returns
    -------
    Estimate
        ``refined`` True; ``info["refine"]``: ``"joint"``, ``info["cost"]`` (the summed NLP
        loss of the records), ``info["iterations"]``, ``info["converged"]`` and
        ``info["std"]``, the standard errors ``sqrt(diag(s^2 (J^T J)^-1))`` of the parameters
        from the Jacobian of the weighted residual, ``s^2`` its mean square over the degrees
        of freedom (samples less parameters less the projected initial states).
    """
    from aeid_struct.refinement import fit_joint

    t0 = time.perf_counter()
    structure, record = est.structure, est.record
    ph = physical_head(structure, est.initial == "fitted")
    names = structure.element_names
    P = parameters_of(est)
    chosen = np.isfinite(P).all(axis=1)
    if est._good is not None:
        chosen &= est._good
    if rows is not None:
        chosen &= np.asarray(rows, dtype=bool).reshape(-1)
    rows = np.flatnonzero(chosen)
    if rows.size == 0:
        return dataclasses.replace(est, info={
            **est.info, "refined_rows": chosen if est.batched else bool(chosen[0])})
    ys = [y[rows] for y in record.y]
    us = [np.broadcast_to(u, y.shape)[rows] for u, y in zip(record.u, record.y, strict=True)]
    initial = est.initial == "fitted"
    fit = fit_joint(ph.at, P[rows], ys, us, record.dt, lower=ph.lo, upper=ph.hi,
                    initial=initial, groups=ph.groups)
    one = structure.records == 1          # the system's arrays have no record axis then
    A, b, c, d = (np.array(np.atleast_1d(v) if est.batched else np.asarray(v)[None],
                           dtype=np.float64, copy=True) for v in (est.A, est.b, est.c, est.d))
    if one:
        A, b, c, d = A[:, None], b[:, None], c[:, None], d[:, None]
    std = np.full(P.shape, math.nan)
    cost = np.full(P.shape[0], math.nan)
    iterations = np.zeros(P.shape[0], dtype=int)
    converged = np.zeros(P.shape[0], dtype=bool)
    for i, row in enumerate(rows):
        p = fit.p[i]
        P[row], cost[row] = p, fit.cost[i]
        iterations[row], converged[row] = fit.iterations[i], fit.converged[i]
        for r, (Ar, br, cr, dr, _) in enumerate(ph.systems(p)):
            A[row, r], b[row, r], c[row, r], d[row, r] = Ar, br, cr, dr
        std[row] = parameter_errors(ph, p, [y[i] for y in ys], [u[i] for u in us],
                                    record.dt, initial)
    if one:
        A, b, c, d = A[:, 0], b[:, 0], c[:, 0], d[:, 0]
    if est.batched:
        elements = {k: P[:, j] for j, k in enumerate(names)}
        errors = {k: std[:, j] for j, k in enumerate(names)}
        info = {"cost": cost, "iterations": iterations, "converged": converged,
                "refined_rows": chosen}
    else:
        A, b, c, d = A[0], b[0], c[0], (float(d[0]) if one else d[0])
        elements = {k: float(P[0, j]) for j, k in enumerate(names)}
        errors = {k: float(std[0, j]) for j, k in enumerate(names)}
        info = {"cost": float(cost[0]), "iterations": int(iterations[0]),
                "converged": bool(converged[0]), "refined_rows": bool(chosen[0])}
    seconds = time.perf_counter() - t0
    info["seconds"] = np.full(P.shape[0], seconds / P.shape[0]) if est.batched else seconds
    return dataclasses.replace(
        est, A=A, b=b, c=c, d=d, elements=elements, refined=True,
        seconds=est.seconds + seconds,
        info={**est.info, **info, "refine": "joint", "std": errors})
