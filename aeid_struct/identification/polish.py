"""``Identifier.identify(refine=...)``: the estimate handed down to the refinement
(``aeid_struct.refinement``), for every record or exactly the flagged ones."""

from __future__ import annotations

import dataclasses

import numpy as np

from aeid_struct.estimates import Estimate
from aeid_struct.identification.joint_refine import is_joint, refine_joint
from aeid_struct.refinement import refine

__all__ = ["polish", "polish_at_bounds", "with_standard_errors"]


def polish(est: Estimate, mode) -> Estimate:
    """Refine an identifier's estimate.

    Parameters
    ----------
    est : Estimate
        From ``Identifier.identify`` (its structure and record on board).
    mode : {True, "auto"}
        True: every record identified (records set aside by ``errors="collect"`` are kept as
        they are); ``"auto"``: exactly the records flagged ``outside`` the training range.

    Returns
    -------
    Estimate
        With ``info["refined_rows"]`` for ``"auto"`` or a partial refinement.
    """
    if is_joint(est):
        # a physical structure (one record or several sharing the parameters): the fit in the
        # parameters, of every record or of the flagged ones (records set aside are kept)
        return refine_joint(est, rows=None if mode is True else _flags(est))
    if mode == "auto":
        return _flagged(est)
    if est._good is not None:      # errors="collect" set records aside: refine the rest
        return with_standard_errors(_rows(est, est._good))
    return with_standard_errors(refine(est))


def with_standard_errors(est: Estimate) -> Estimate:
    """A refined estimate of a physical structure with its parameters' standard errors in
    ``info["std"]`` (``physical_errors.standard_errors``, as ``greyest`` reports them); any
    other estimate as it is.

    Parameters
    ----------
    est : Estimate

    Returns
    -------
    Estimate
    """
    from aeid_struct.structures import type_of

    if type_of(est.structure) != "Physical" or "std" in est.info:
        return est
    from aeid_struct.identification.physical_errors import standard_errors

    return dataclasses.replace(est, info={**est.info, "std": standard_errors(est)})


def polish_at_bounds(est: Estimate) -> Estimate:
    """The converged head of a physical structure, with the records whose parameters it left
    on a bound refined by the joint fit (``joint_refine.refine_joint``).

    Why: where the map is square, the head's nearest parameters are the structure's optimum
    only if the CCF optimum lies in the image of the box; a noisy record whose CCF optimum
    does not (an ill-conditioned parameter) is stopped on a bound, and the optimum within the
    bounds is then the output-error fit's in the parameters.

    Parameters
    ----------
    est : Estimate
        ``refine=True`` through the converged head (``info["refine"] == "separable"``).

    Returns
    -------
    Estimate
        With ``info["refined_rows"]``, the records the joint fit refined; no standard errors
        yet (``with_standard_errors`` gives every record's).
    """
    mask = np.zeros(np.shape(est.d)[0] if est.batched else 1, dtype=bool)
    for name, (lo, hi) in est.structure.bounds.items():
        value = np.atleast_1d(np.asarray(est.elements[name], dtype=np.float64))
        tol = 1e-6 * (hi - lo)
        mask |= (value <= lo + tol) | (value >= hi - tol)
    if est._good is not None:
        mask &= est._good
    if not mask.any():
        return dataclasses.replace(est, info={**est.info,
                                              "refined_rows": mask if est.batched else False})
    out = refine_joint(est, rows=mask)
    return dataclasses.replace(out, info={k: v for k, v in out.info.items() if k != "std"})


def _flags(est: Estimate):
    """``est.outside``, or the error of an identifier without a calibrated training range."""
    flags = est.outside
    if flags is None:
        raise ValueError("refine='auto' needs an identifier that knows its calibrated "
                         "training range (trained by this version of train(), a shipped "
                         "one, or one passed through training.recalibrate)")
    return flags


def _flagged(est: Estimate) -> Estimate:
    """Refine exactly the records flagged ``outside`` (and identified: a record set aside by
    ``errors="collect"`` has nothing to start from)."""
    flags, good = _flags(est), est._good
    if not est.batched:
        if not flags or (good is not None and not good[0]):
            return dataclasses.replace(est, info={**est.info, "refined_rows": False})
        est = refine(est)
        return dataclasses.replace(est, info={**est.info, "refined_rows": True})
    return _rows(est, flags if good is None else flags & good)


def _rows(est: Estimate, mask: np.ndarray) -> Estimate:
    """Refine the records ``mask (batch,)`` of a batched estimate, keep the others;
    ``info["refined_rows"]`` is ``mask``, ``info["refine"]`` the refinement's info."""
    rows = np.flatnonzero(mask)
    if rows.size == 0:
        return dataclasses.replace(est, info={**est.info, "refined_rows": mask})
    sub = refine(est.take(rows))
    A, b, c, d = (np.array(x, copy=True) for x in (est.A, est.b, est.c, est.d))
    A[rows], b[rows], c[rows], d[rows] = sub.A, sub.b, sub.c, sub.d
    elements = {k: np.array(v, copy=True) for k, v in est.elements.items()}
    for k in elements:
        elements[k][rows] = sub.elements[k]
    return dataclasses.replace(
        est, A=A, b=b, c=c, d=d, elements=elements, refined=True,
        seconds=est.seconds + sub.info["seconds"].sum(),
        info={**est.info, "refined_rows": mask, "refine": sub.info})
