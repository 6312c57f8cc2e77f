r"""``identify(refine=True, starts=k)`` for a physical structure: the refined estimate set
beside the output-error fits in the parameters from ``k`` fixed points of the box, and the
lowest cost kept, record by record.

Why: at noise the output-error cost of a mechanism can hold several optima of nearly equal
cost far apart in an ill-conditioned parameter (a drive train's motor inertia, a two-mass
system's springs), and the refinement is local: it converges to the optimum of the one pass's
basin. A cold grey-box fit (``greyest`` from guesses) meets the same landscape with the same
remedy, several starts; here the one pass is one of them, so ``k`` extra starts make
``k + 1``.

The points are the first ``k`` of a scrambled Halton sequence of the box (``scipy.stats.qmc``,
seed :data:`SEED`): the same for every record and call, so an estimate does not depend on a
random state, and spread over the box as ``k`` random draws are only on average. Each start is
fitted by ``refinement.fit_joint`` (the output-error fit in the parameters within the box, the
records' initial states projected out where they are fitted: the cost the joint refinement
minimises, one record or several), all records and starts as one batch; the refined estimate's
own cost is that fit's at its parameters, so the costs compare like with like.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from aeid_struct.estimates import Estimate
from aeid_struct.identification.inverse import SEED, box_points
from aeid_struct.identification.physical_errors import parameter_errors, parameters_of
from aeid_struct.identification.physical_head import physical_head

__all__ = ["SEED", "best_of_starts", "box_points", "from_starts", "no_worse_than"]

#: A start replaces the refined estimate only where its cost is lower by more than this,
#: relative, and by more than :data:`FLOOR`: the same optimum reached twice differs in the last
#: digits, and the costs of noise-free records are round-off.
BETTER = 1e-9
#: Costs closer than this are equal (a normalised mean square: round-off is ~1e-30).
FLOOR = 1e-24


def best_of_starts(ph, P: np.ndarray, ys: list, us: list, dts: tuple, initial: bool,
                   starts) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each row's parameters or the output-error fit from :func:`box_points` (or from each
    row's own starts), whichever costs less (module docstring).

    Parameters
    ----------
    ph : PhysicalHead
        The structure's systems and box.
    P : (B, q) array
        The refined parameters, finite.
    ys, us : lists of R (B, steps_r) arrays
    dts : tuple of R floats
    initial : bool
        The records' initial states projected out.
    starts : int >= 1, or (B, S, q) array
        The first ``starts`` points of :func:`box_points`, the same for every row; or each
        row's own ``S`` starts.

    Returns
    -------
    P : (B, q) array
    cost : (B,) array
        ``refinement.fit_joint``'s cost at ``P``.
    start : (B,) int array
        0 where the refined parameters were kept, ``j`` where the fit from point ``j``
        (1-based) replaced them.
    """
    from aeid_struct.refinement import fit_joint

    B = P.shape[0]
    if isinstance(starts, (int, np.integer)):
        points = np.tile(box_points(ph.lo, ph.hi, int(starts)), (B, 1))
    else:
        points = np.asarray(starts, dtype=np.float64).reshape(-1, P.shape[1])
        starts = points.shape[0] // B
    kw = dict(lower=ph.lo, upper=ph.hi, initial=initial, groups=ph.groups)
    own = fit_joint(ph.at, P, ys, us, dts, max_iter=0, **kw).cost
    # rows are (record, start), record-major
    fit = fit_joint(ph.at, points, [np.repeat(y, starts, 0) for y in ys],
                    [np.repeat(u, starts, 0) for u in us], dts, **kw)
    cost = np.where(np.isfinite(fit.cost), fit.cost, math.inf).reshape(B, starts)
    best = np.argmin(cost, axis=1)
    found = cost[np.arange(B), best]
    better = found < np.where(np.isfinite(own), own, math.inf) * (1.0 - BETTER) - FLOOR
    out = P.copy()
    out[better] = fit.p.reshape(B, starts, -1)[np.flatnonzero(better), best[better]]
    return out, np.where(better, found, own), np.where(better, best + 1, 0)


def from_starts(est: Estimate, starts: int) -> Estimate:
    """A refined physical estimate, each record's parameters replaced by the best fit from
    ``starts`` points of the box where that costs less (module docstring); the systems and
    standard errors of the replaced records follow their new parameters.

    Parameters
    ----------
    est : Estimate
        ``identify(refine=True)`` of a physical structure.
    starts : int, >= 1

    Returns
    -------
    Estimate
        ``info["start"]``: per record 0 (the refinement's optimum kept) or the 1-based box
        point whose fit replaced it; ``info["cost"]``: the output-error cost
        (``refinement.fit_joint``'s) at the returned parameters; ``info["starts"]``:
        ``starts``. Records set aside (``errors="collect"``) or without finite parameters
        are kept as they are (start 0, cost NaN).
    """
    out, start, cost = _refitted(est, lambda rows: starts)
    if est.batched:
        info = {"start": start, "cost": cost}
    else:
        info = {"start": int(start[0]), "cost": float(cost[0])}
    return dataclasses.replace(out, info={**out.info, **info, "starts": int(starts)})


def no_worse_than(est: Estimate, one: Estimate) -> Estimate:
    """``est``, a refined physical estimate, with each record whose own one pass ``one``
    costs less replaced by the output-error fit from the one pass's parameters (where that
    costs less still); ``info["from_one_pass"]``: the records replaced.

    Why: the refinement of a structure of one record starts over from the encoder's poles
    (``head.refine_route``), and where its coefficient map is not inverted from anywhere
    (not square, or not one-to-one over the box), the converged CCF's nearest parameters can
    lie in another basin of the output error than the one pass's few iterations did, which
    the fit from there then cannot leave (a two-mass record at 2 % noise: refined to a cost
    60 times its one pass's). A refinement is never worse than the estimate it refines.

    Parameters
    ----------
    est : Estimate
        ``identify(refine=True)`` of a physical structure of one record.
    one : Estimate
        The one pass of the same records.

    Returns
    -------
    Estimate
    """
    from aeid_struct.refinement import fit_joint

    initial = est.initial == "fitted"
    ph = physical_head(est.structure, initial)
    P, start = parameters_of(est), parameters_of(one)
    good = np.isfinite(P).all(axis=1) & np.isfinite(start).all(axis=1)
    if est._good is not None:
        good &= est._good
    rows = np.flatnonzero(good)
    lower = np.zeros(P.shape[0], dtype=bool)
    if rows.size:
        record = est.record
        ys = [y[rows] for y in record.y]
        us = [np.broadcast_to(u, y.shape)[rows] for u, y in zip(record.u, record.y, strict=True)]
        kw = dict(lower=ph.lo, upper=ph.hi, initial=initial, groups=ph.groups, max_iter=0)
        both = fit_joint(ph.at, np.concatenate([P[rows], start[rows]]),
                         [np.concatenate([y, y]) for y in ys],
                         [np.concatenate([u, u]) for u in us], record.dt, **kw).cost
        refined, first = both[: rows.size], both[rows.size:]
        # only where the one pass costs less is the fit from it run
        lower[rows] = first < np.where(np.isfinite(refined), refined, math.inf) \
            * (1.0 - BETTER) - FLOOR
    if not lower.any():
        return dataclasses.replace(est, info={
            **est.info, "from_one_pass": lower if est.batched else False})
    out, replaced, _ = _refitted(est, lambda rows: start[rows][:, None, :], lower)
    return dataclasses.replace(out, info={
        **out.info, "from_one_pass": replaced.astype(bool) if est.batched
        else bool(replaced[0])})


def _refitted(est: Estimate, starts_of, only: np.ndarray | None = None
              ) -> tuple[Estimate, np.ndarray, np.ndarray]:
    """:func:`best_of_starts` on ``est``'s good records (of those marked in ``only``, where
    given; ``starts_of(rows)``: its ``starts`` for those rows), their parameters, systems and
    standard errors replaced where a start's fit costs less. Returns the estimate, the
    1-based start per record (0: kept) and the cost per record (NaN where not fitted)."""
    t0 = time.perf_counter()
    structure, record = est.structure, est.record
    initial = est.initial == "fitted"
    ph = physical_head(structure, initial)
    P = parameters_of(est)
    rows = np.isfinite(P).all(axis=1)
    if est._good is not None:
        rows &= est._good
    if only is not None:
        rows &= only
    rows = np.flatnonzero(rows)
    start = np.zeros(P.shape[0], dtype=int)
    cost = np.full(P.shape[0], math.nan)
    R = ph.records
    A, b, c, d = (np.array(np.atleast_1d(v) if est.batched else np.asarray(v)[None],
                           dtype=np.float64, copy=True) for v in (est.A, est.b, est.c, est.d))
    std = {k: np.atleast_1d(np.array(v, dtype=np.float64))
           for k, v in est.info.get("std", {}).items()}
    if rows.size:
        ys = [y[rows] for y in record.y]
        us = [np.broadcast_to(u, y.shape)[rows] for u, y in zip(record.u, record.y, strict=True)]
        found, cost[rows], start[rows] = best_of_starts(ph, P[rows], ys, us, record.dt, initial,
                                                        starts_of(rows))
        names = structure.element_names
        for i in np.flatnonzero(start[rows]):
            row, p = rows[i], found[i]
            P[row] = p
            for r, (Ar, br, cr, dr, _) in enumerate(ph.systems(p)):
                if R == 1:
                    A[row], b[row], c[row], d[row] = Ar, br, cr, dr
                else:
                    A[row, r], b[row, r], c[row, r], d[row, r] = Ar, br, cr, dr
            if std:
                errors = parameter_errors(ph, p, [y[i] for y in ys], [u[i] for u in us],
                                          record.dt, initial)
                for j, k in enumerate(names):
                    std[k][row] = errors[j]
    if est.batched:
        elements = {k: P[:, j] for j, k in enumerate(structure.element_names)}
    else:
        A, b, c, d = A[0], b[0], c[0], d[0]
        elements = {k: float(P[0, j]) for j, k in enumerate(structure.element_names)}
        std = {k: float(v[0]) for k, v in std.items()}
    info = {**est.info, "std": std} if std else est.info
    return (dataclasses.replace(est, A=A, b=b, c=c, d=d, elements=elements,
                                seconds=est.seconds + time.perf_counter() - t0, info=info),
            start, cost)
