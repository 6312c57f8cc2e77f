"""The head of a physical structure whose records are channels summed into outputs (one record
of several inputs moving at once, ``Physical(mechanism, outputs=..., inputs=...)``): the steps of
``identification.physical_head`` with step 1 over every channel at once."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["summed_head"]


def summed_head(ph, ident, head, ys: list, us: list, model: tuple,
                rows: np.ndarray) -> tuple:
    """:func:`~aeid_struct.identification.physical_head.apply_physical_head` where the records
    are channels summed into outputs: no channel can be fitted alone from its output, so
    step 1 fits every channel's CCF at once, their common denominator from the encoder's
    (``refinement.fit_summed``), step 2 takes the parameters nearest those coefficients, and
    as many iterations of the joint output-error fit in the parameters (``groups`` of
    ``refinement.fit_joint``, what ``refine=True`` converges) follow, within the box.

    Parameters
    ----------
    ph : identification.physical_head.PhysicalHead
    ident : Identifier
    head : Head
    ys, us : lists of R (count, steps_r) arrays (``u`` None: a unit step)
    model : tuple
        ``A, b, c, d, elements`` of the encoder's pass (float64, changed in place).
    rows : int array
        The rows whose encoder model is finite.

    Returns
    -------
    (model, failed (count,) bool array)
    """
    from aeid_struct.refinement import fit_joint, fit_summed
    from aeid_struct.simulation import output_groups

    A, b, c, d, el = model
    failed = np.zeros(A.shape[0], dtype=bool)
    us = [np.ones_like(y) if u is None else np.broadcast_to(u, y.shape)
          for y, u in zip(ys, us, strict=True)]
    ys, us = [y[rows] for y in ys], [u[rows] for u in us]
    initial = ident.initial == "fitted"
    free_a = [j for j, v in enumerate(ph.pattern.a) if v is None]
    a0 = np.stack([ph.systems(el[row])[0][4][free_a] for row in rows])
    fit = fit_summed(ph.patterns, output_groups(ph.groups, ph.records), a0, ys, us,
                     ident._dts, iterations=head.iterations, initial=initial)
    found = el[rows].copy()
    for i, row in enumerate(rows):
        target = np.concatenate([np.concatenate([fit.a[i], fit.c[i, r], fit.d[i, r: r + 1]])
                                 for r in range(ph.records)])[ph.free]
        if np.isfinite(fit.cost[i]) and np.isfinite(target).all():
            found[i] = ph.inverse.parameters(target, el[row])
    found = fit_joint(ph.at, found, ys, us, ident._dts, lower=ph.lo, upper=ph.hi,
                      initial=initial, max_iter=head.iterations, gain=False,
                      groups=ph.groups).p
    for i, row in enumerate(rows):
        if not np.isfinite(found[i]).all():
            failed[row] = True
            A[row], b[row], c[row], d[row], el[row] = (math.nan,) * 5
            continue
        for r, (Ar, br, cr, dr, _) in enumerate(ph.systems(found[i])):
            A[row, r], b[row, r], c[row, r], d[row, r] = Ar, br, cr, dr
        el[row] = found[i]
    return (A, b, c, d, el), failed
