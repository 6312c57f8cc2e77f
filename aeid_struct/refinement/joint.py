r"""The output-error fit of parameters shared by several records: the channels of one measured
record (a cart's position and a pole's angle from one force) or the records of one parameter
set (the joint leg), each record simulated by its own system of the parameters.

For parameters ``p`` (``q``), records ``y_r, u_r (steps_r)`` at ``dt_r`` and the systems
``(A_r, b_r, c_r, d_r)(p)``, the residual stacks, record after record,

    r_r(p) = w_r (I - Q_r Q_r^T) (y_r - yhat_r(p)),    w_r = 2 / (max|y_r| sqrt(steps_r + 1)),

``yhat_r`` the decoder's exact first-order-hold response from rest (Eq. 10-13,
``simulation.simulate_outputs``) and ``Q_r`` an orthonormal basis of the observable part of the
record's free response ``C_r Phi_r^k`` where the records start mid-motion (each record's
least-squares initial state projected out: variable projection). So ``||r||^2`` is the sum over
records of the NLP's loss (paper Eq. 14 with ``gamma = 0`` on the normalised record, Eq. 15).
It is minimised by the library's one Levenberg-Marquardt (``core.minimise``) in the box of the
parameters, in units of the box, with a central-difference Jacobian: ``q`` is a handful of
physical parameters, and ``2 q`` responses of ``R`` short records per iteration cost less than
building a CasADi graph of every record length.

*Several inputs at once.* Where a record's inputs move together (``Physical(mechanism,
outputs=..., inputs=...)``), its records are the channels ``(output, input)`` and each output is
a group: ``yhat_g = sum_{r in g} yhat_r`` and ``Q_g`` spans the group's stacked free responses
(``groups``; ``simulation.summed_response``), one residual per output.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from aeid_struct.refinement import core

__all__ = ["JointFit", "fit_joint", "joint_jacobian", "joint_residual"]

#: Relative step of the central differences, of the box's width.
STEP = 1e-6
#: Stop on a relative cost decrease below this (a flat optimum: noise).
FLAT = 1e-12


def joint_residual(systems: Callable, p: np.ndarray, ys: list, us: list, dts: tuple,
                   initial: bool, groups: tuple | None = None) -> np.ndarray:
    """The stacked residual ``r(p)`` of one set of records (module docstring).

    Parameters
    ----------
    systems : callable
        ``points (P, q) -> [(A (P, n, n), b (P, n), c (P, n), d (P,)), ...]``, the systems
        of every point, one tuple per record (``PhysicalHead.at``).
    p : (q,) array
    ys, us : lists of R (steps_r,) arrays
    dts : tuple of R floats
    initial : bool
        Project each record's initial state out.
    groups : tuple of R ints, optional
        Records of one group are the channels of one output whose inputs move at once (one
        record of several inputs): the group's output is the sum of its channels' responses,
        one residual (and one free response) per group, read from its first record's ``y``
        (``simulation.summed_response``). None: every record its own.

    Returns
    -------
    (sum steps_g,) array
        NaN where a system's response is not finite.
    """
    return _residuals(systems, np.asarray(p, dtype=np.float64)[None], ys, us, dts, initial,
                      groups)[0]


def _residuals(systems: Callable, points: np.ndarray, ys: list, us: list, dts: tuple,
               initial: bool, groups: tuple | None = None) -> np.ndarray:
    """:func:`joint_residual` at ``points (P, q)``: ``(P, N)``, the points' systems simulated
    as one batch per record (``simulation.summed_response``)."""
    from aeid_struct.simulation import output_groups, summed_response

    models = systems(points)
    parts = output_groups(groups, len(models))
    out = np.empty((points.shape[0], sum(ys[g[0]].size for g in parts)))
    start, cache = 0, []          # one discretisation for the records of equal (A, b)
    for group in parts:
        y, dt = ys[group[0]], dts[group[0]]
        y_hat = summed_response([models[r] for r in group], [us[r] for r in group], y, dt,
                                initial, cache=cache)[0]
        out[:, start: start + y.size] = (y - y_hat) * (
            2.0 / (np.abs(y).max() * math.sqrt(y.size + 1)))
        start += y.size
    return out


def joint_jacobian(systems: Callable, p: np.ndarray, ys: list, us: list, dts: tuple,
                   initial: bool, width: np.ndarray, *, residual: bool = False,
                   central: bool = True, groups: tuple | None = None):
    """``dr/dp (q, N)`` by finite differences of :func:`joint_residual` (central by default),
    all points simulated as one batch.

    Parameters
    ----------
    systems, p, ys, us, dts, initial, groups
        As :func:`joint_residual`.
    width : (q,) array
        The box's widths (the steps are :data:`STEP` of them).
    residual : bool
        Also return ``r(p)``, simulated in the same batch.
    central : bool
        Central differences (``2 q`` points, errors of ``STEP^2``); forward ones
        (``q + 1`` points, errors of ``STEP``: a relative ``1e-6`` of the derivatives, below
        what a weighting or a standard error resolves) where False.

    Returns
    -------
    (q, N) array, or ``(J, r (N,))`` where ``residual``
    """
    p = np.asarray(p, dtype=np.float64)
    h = STEP * np.asarray(width, dtype=np.float64)
    steps = np.diag(h)
    q = p.size
    if not central:
        r = _residuals(systems, np.concatenate([p + steps, p[None]]), ys, us, dts, initial,
                       groups)
        J = (r[:q] - r[q]) / h[:, None]
        return (J, r[q]) if residual else J
    points = [p + steps, p - steps] + ([p[None]] if residual else [])
    r = _residuals(systems, np.concatenate(points), ys, us, dts, initial, groups)
    J = (r[:q] - r[q: 2 * q]) / (2 * h[:, None])
    return (J, r[2 * q]) if residual else J


class _Problem:
    """Rows of sets of records as a problem of ``core.minimise`` (in units of the box)."""

    lazy = True

    def __init__(self, systems, ys, us, dts, initial, lo, hi, groups) -> None:
        self.systems, self.ys, self.us, self.dts, self.initial = systems, ys, us, dts, initial
        self.lo, self.width, self.groups = lo, hi - lo, groups

    def _p(self, z):
        return self.lo + self.width * z

    def evaluate(self, z, rows, jacobian, at):
        rows = np.arange(z.shape[0]) if rows is None else rows
        r = np.stack([joint_residual(self.systems, self._p(zi), [y[i] for y in self.ys],
                                     [u[i] for u in self.us], self.dts, self.initial,
                                     self.groups)
                      for zi, i in zip(z, rows, strict=True)])
        cost = np.where(np.isfinite(r).all(axis=1), np.sum(r * r, axis=1), math.inf)
        return {"cost": cost, "r": r, "z": z, "rows": rows}

    def jacobian(self, e):
        # central differences: forward ones (q simulations, not 2 q) were measured to cost
        # the fit more iterations near its optimum than they save per iteration
        return np.stack([
            joint_jacobian(self.systems, self._p(zi), [y[i] for y in self.ys],
                           [u[i] for u in self.us], self.dts, self.initial, self.width,
                           groups=self.groups)
            * self.width[:, None] for zi, i in zip(e["z"], e["rows"], strict=True)])


@dataclass(frozen=True)
class JointFit:
    """Where :func:`fit_joint` ended, one row per set of records.

    Attributes
    ----------
    p : (B, q) array
        The parameters (never worse than the start).
    cost : (B,) array
        ``||r||^2`` there (module docstring).
    iterations : (B,) int array
    converged : (B,) bool array
    """

    p: np.ndarray
    cost: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray


def fit_joint(systems: Callable, start: np.ndarray, ys: list, us: list, dts: tuple, *,
              lower: np.ndarray, upper: np.ndarray, initial: bool,
              max_iter: int = 100, gain: bool = True,
              groups: tuple | None = None) -> JointFit:
    """The output-error optimum of the parameters of each row's records within the box
    (module docstring).

    Parameters
    ----------
    systems : callable
        As :func:`joint_residual`.
    start : (B, q) array
        Taken into the box (a margin of ``1e-9`` of its width inside each bound: a start on a
        bound would hold that parameter there from the first step).
    ys, us : lists of R (B, steps_r) arrays
        The records of each row (checked by the caller; ``u`` a unit step where none).
    dts : tuple of R floats
    lower, upper : (q,) arrays
        The box.
    initial : bool
        Each record's initial state projected out.
    max_iter : int
        Iterations per row at most.
    gain : bool
        Damp by the gain ratio (``core.Rules.gain``), for a fit to convergence; the one pass's
        few fixed iterations keep Marquardt's rule (False), as they were measured.
    groups : tuple of R ints, optional
        Records that are channels of one output, summed (:func:`joint_residual`).

    Returns
    -------
    JointFit
    """
    lo, hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    problem = _Problem(systems, ys, us, dts, initial, lo, hi, groups)
    margin = 1e-9 * (hi - lo)
    start = np.clip(np.asarray(start, dtype=np.float64), lo + margin, hi - margin)
    z0 = (start - lo) / (hi - lo)
    B = z0.shape[0]
    # damped by the gain ratio: at noise the cost's valleys in poorly determined parameters
    # are flat and curved, and Marquardt's rule alternated between a rejected and a barely
    # better step there (a quarter car at 5 % noise: 90th percentile 38 -> 21 iterations, all
    # 40 records converged against 37, the same optimum)
    rules = core.Rules(max_iter=int(max_iter), lambda_max=1e12, cost_tol=FLAT,
                       step_tol=1e-12, gain=bool(gain))
    out = core.minimise(problem, z0, rules, lower=np.zeros((B, lo.size)),
                        upper=np.ones((B, lo.size)))
    return JointFit(lo + (hi - lo) * out.x, out.evaluation["cost"], out.iterations,
                    out.converged)
