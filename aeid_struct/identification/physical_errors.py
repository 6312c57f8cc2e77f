"""Standard errors of a physical estimate's parameters at its optimum, as ``greyest`` reports
them: from the Jacobian of the residual of its records (``refinement.joint_residual``), one
record or several, with the initial states projected out."""

from __future__ import annotations

import math

import numpy as np

from aeid_struct.identification.physical_head import PhysicalHead, physical_head

__all__ = ["parameter_errors", "parameters_of", "standard_errors"]


def standard_errors(est) -> dict[str, np.ndarray]:
    """Standard errors of a physical estimate's parameters at its optimum, as ``greyest``
    gives them: ``sqrt(diag(s^2 (J^T J)^-1))`` with ``J = dr / dp`` the Jacobian of the
    residual of its records (forward differences of the decoder's response, Eq. 10-13, each
    record weighted by its normalisation, Eq. 15: ``refinement.joint_residual``) and ``s^2``
    the residual's mean square over the degrees of freedom (samples less parameters less the
    fitted initial states, which are projected out of ``J`` and the residual first: their
    uncertainty is the parameters' too).

    Parameters
    ----------
    est : Estimate
        A refined estimate in a physical structure (batched or not; one record or several).

    Returns
    -------
    dict name -> (batch,) array, or float per name for an unbatched estimate
        NaN for a record set aside or whose ``J`` is rank deficient.
    """
    initial = est.initial == "fitted"
    ph = physical_head(est.structure, initial)
    names = est.structure.element_names
    record = est.record
    P = parameters_of(est)
    out = np.full(P.shape, math.nan)
    for i, p in enumerate(P):
        if not np.isfinite(p).all():
            continue
        ys = [y[i] for y in record.y]
        us = [np.broadcast_to(u, y.shape)[i] for u, y in zip(record.u, record.y, strict=True)]
        out[i] = parameter_errors(ph, p, ys, us, record.dt, initial)
    if not est.batched:
        return {k: float(out[0, j]) for j, k in enumerate(names)}
    return {k: out[:, j] for j, k in enumerate(names)}


def parameters_of(est) -> np.ndarray:
    """A physical estimate's parameters as ``(batch, q)`` float64 rows (one row unbatched), in
    the structure's element order.

    Parameters
    ----------
    est : Estimate

    Returns
    -------
    (batch, q) array
    """
    return np.atleast_2d(np.stack([np.atleast_1d(np.asarray(est.elements[k], dtype=np.float64))
                                   for k in est.structure.element_names], 1))


def parameter_errors(ph: PhysicalHead, p: np.ndarray, ys: list, us: list, dts: tuple,
                     initial: bool) -> np.ndarray:
    """:func:`standard_errors` of one set of records at the parameters ``p``.

    Parameters
    ----------
    ph : PhysicalHead
    p : (q,) array
    ys, us : lists of R (steps_r,) arrays
    dts : tuple of R floats
    initial : bool

    Returns
    -------
    (q,) array
        NaN where ``J`` is rank deficient or no degree of freedom is left.
    """
    from aeid_struct.refinement import joint_jacobian

    J, r = joint_jacobian(ph.at, p, ys, us, dts, initial, ph.hi - ph.lo, residual=True,
                          central=False, groups=ph.groups)
    # one initial state per output: a record's own, or one of the channels summed into it
    outputs = ph.records if ph.groups is None else len(set(ph.groups))
    dof = r.size - ph.q - (outputs * ph.n if initial else 0)
    JJ = J @ J.T
    if dof <= 0 or not np.isfinite(JJ).all() or np.linalg.matrix_rank(JJ) < ph.q:
        return np.full(ph.q, math.nan)
    return np.sqrt(np.diag(np.linalg.inv(JJ)) * float(r @ r) / dof)
