r"""The several-channel fit: output error over every record by variable projection, and the
model taken back to the user's units.

Only ``theta = (a, C without its reference row)`` is iterated (``multi.realisation``); at each
point ``B, D`` and every record's ``x0`` and offset are the least-squares solution, so the
residual is a function of ``theta`` alone (Golub and Pereyra's variable projection). MINPACK's
Levenberg-Marquardt iterates it with Kaufman's Jacobian, each column by a forward difference of
the model's output at fixed linear parameters, projected (:func:`_residual`): ``theta`` has
``n p`` entries and one simulation costs one matrix exponential and ``p m`` convolutions, so
differences cost less than an analytic Jacobian would to write and to keep right; in the time
unit ``h`` (``multi.start.scale_of``) the entries of ``theta`` are of order one, so scipy's
relative steps suit them all.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from aeid_struct.multi.realisation import Layout, Projection, basis, outputs, project

__all__ = ["MAX_ITERATIONS", "TOL", "Fitted", "iterate", "physical", "rescan"]

#: Relative tolerances of the iterations (cost, step, gradient): below them the fit moves by
#: far less than the noise.
TOL = 1e-9
#: Iterations at most to convergence: an order above the system's has directions the data do
#: not fix, along which MINPACK's default (``100 (k + 1)`` Jacobians for ``k`` parameters) crawled
#: for minutes (order 8 of a 2x2 order-4 record while the order was selected).
MAX_ITERATIONS = 100


@dataclass(frozen=True)
class Fitted:
    """A several-channel model in working units (``multi.experiments``), time unit ``h`` per
    sample.

    Attributes
    ----------
    layout : Layout
    theta : (n p,) array
    h : float
    delays : (m,) int array
    projection : Projection
    iterations : int
        Residual evaluations of the iterations (0: the start's projection).
    converged : bool
    start : str
        ``"encoder"`` or ``"classical"``: where the start's poles came from.
    """

    layout: Layout
    theta: np.ndarray
    h: float
    delays: np.ndarray
    projection: Projection
    iterations: int = 0
    converged: bool = False
    start: str = "classical"

    @property
    def cost(self) -> float:
        """Mean squared residual (working units)."""
        return self.projection.cost


def _residual(layout: Layout, parts, holds, h: float, feedthrough: bool, big: np.ndarray):
    """``(residual, jacobian)`` of the projected output error at ``theta``.

    The Jacobian is Kaufman's for variable projection: with ``B, D``, the initial states and
    offsets held at their projected values, the model's output moved along each entry of
    ``theta`` (forward differences, scipy's two-point step; ``multi.realisation.outputs``) and
    projected off the design's column space at ``theta`` (``multi.realisation.basis``):
    ``J = -P (dX / dtheta) beta``. It drops a term that lies in the design's column space, so
    ``J^T r`` is the exact gradient and the optimum is the same; each column costs one
    simulation with ``p m`` convolutions instead of a projection (``p n m`` convolutions and a
    least-squares solve), the several-channel fit's largest cost (a 4x4 order-8 record of 4,000
    samples: 32 projections per Jacobian). The residual at ``theta`` is reused where the last
    evaluation was there (MINPACK asks for the Jacobian at the point it just accepted).

    Why our own Jacobian at all: with scipy's finite differences (scipy 1.17 hands them to
    MINPACK as a Jacobian function) ``max_nfev`` counts the residuals of the steps only, not
    the differences, so the refinement's cap of :data:`MAX_ITERATIONS` iterations, written as
    that many times ``len(theta) + 1`` evaluations, allowed ``len(theta) + 1`` times as many (a
    closed-loop 2x2 record: 893 Jacobians, 6 s); with a Jacobian of ours the cap counts
    iterations whatever scipy's version."""
    last = {}

    def residual(theta):
        A, C = layout.model(theta)
        with np.errstate(all="ignore"):
            proj = project(A, C, parts, h, holds, feedthrough)
        finite = bool(np.all(np.isfinite(proj.residual)))
        # a point whose response overflows (an unstable trial over a long record) is a large
        # finite residual, so the trust region shrinks instead of failing
        r = proj.residual if finite else big
        last["theta"], last["r"], last["proj"] = theta.copy(), r, proj if finite else None
        return r

    def jacobian(theta):
        if not np.array_equal(last.get("theta"), theta):
            residual(theta)
        proj = last["proj"]
        if proj is None:        # MINPACK accepts no overflowing point; nothing to follow
            return np.zeros((big.shape[0], theta.shape[0]))
        A, C = layout.model(theta)
        step = _STEP * np.where(theta >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(theta))
        with np.errstate(all="ignore"):
            Q = basis(A, C, parts, h, holds, feedthrough)
            fixed = (proj.B, proj.D, proj.x0, proj.offset, parts, h, holds)
            y0 = outputs(A, C, *fixed)
            moves = np.empty((y0.shape[0], theta.shape[0]))
            for k in range(theta.shape[0]):
                moved = theta.copy()
                moved[k] += step[k]
                moves[:, k] = (outputs(*layout.model(moved), *fixed) - y0) / (moved[k]
                                                                            - theta[k])
        moves[~np.isfinite(moves)] = 0.0
        return -(moves - Q @ (Q.T @ moves))

    return residual, jacobian


#: Forward differences' relative step (scipy's two-point one, the square root of float64's eps).
_STEP = float(np.sqrt(np.finfo(np.float64).eps))


def iterate(layout: Layout, theta: np.ndarray, h: float, experiments, delays, feedthrough: bool,
            iterations: int | None, start: str = "classical") -> Fitted:
    """Output-error iterations from ``theta`` (module docstring).

    Parameters
    ----------
    layout : Layout
    theta : (n p,) array
    h : float
    experiments : Experiments
    delays : (m,) ints
    feedthrough : bool
    iterations : int or None
        The one pass's bounded cost: ``iterations (len(theta) + 1)`` Levenberg-Marquardt
        iterations at most, the residual evaluations of ``iterations`` Jacobians by differences
        and steps (what the one pass ran and was measured with: exactly ``iterations`` left it
        4 points below refined on one of five 2x2 records of the channels benchmark); None: to
        convergence (:data:`TOL`), at most :data:`MAX_ITERATIONS` iterations.
    start : str

    Returns
    -------
    Fitted
        The better of the start and the iterate.
    """
    parts = experiments.aligned(delays)
    holds = experiments.holds
    first = project(*layout.model(theta), parts, h, holds, feedthrough)
    begin = Fitted(layout, theta, h, np.asarray(delays), first, 0, False, start)
    if iterations == 0 or not np.isfinite(first.cost):
        return begin
    big = np.full_like(first.residual, 1e3 * (1.0 + np.sqrt(first.cost)))
    residual, jacobian = _residual(layout, parts, holds, h, feedthrough, big)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # MINPACK's Levenberg-Marquardt: on 2x2 and 3x3 records it took a third fewer
        # residuals to the same optimum than the trust-region reflective method; with a
        # Jacobian of ours it counts the step's residuals only: about one per iteration, and
        # the first one at theta
        sol = scipy.optimize.least_squares(
            residual, theta, jac=jacobian, method="lm",
            max_nfev=(MAX_ITERATIONS if iterations is None
                      else iterations * (len(theta) + 1)) + 1,
            ftol=TOL, xtol=TOL, gtol=TOL)
    with np.errstate(all="ignore"):
        proj = project(*layout.model(sol.x), parts, h, holds, feedthrough)
    if not np.all(np.isfinite(proj.residual)) or proj.cost >= first.cost:
        return begin
    return Fitted(layout, sol.x, h, np.asarray(delays), proj, int(sol.nfev),
                  bool(sol.status > 0), start)


def rescan(fitted: Fitted, experiments, top: int, feedthrough: bool) -> np.ndarray:
    """The delays walked downhill from ``fitted``'s, per input one sample at a time while the
    projection at its ``theta`` improves; the best delays found (``fitted.delays`` where none
    is better).

    Why a walk, not one step: the start's delay (``multi.start.arx_delays``) can be several
    samples off on a noisy record, and the cost at fixed poles falls towards the right delay
    (a 2x1 unstable record at 4 % noise: ARX chose 5 for a true 2, one step stopped at 4 with
    a validation fit 10 points below the fit at 2).

    Parameters
    ----------
    fitted : Fitted
    experiments : Experiments
    top : int
        The largest delay allowed.
    feedthrough : bool

    Returns
    -------
    (m,) int array
    """
    A, C = fitted.layout.model(fitted.theta)
    best, cost = fitted.delays.copy(), fitted.cost
    for j in range(len(best)):
        for step in (-1, 1):
            while 0 <= best[j] + step <= top:
                trial = best.copy()
                trial[j] += step
                with np.errstate(all="ignore"):
                    c = project(A, C, experiments.aligned(trial), fitted.h, experiments.holds,
                                feedthrough).cost
                if not c < cost * 0.999:
                    break
                best, cost = trial, c
    return best


def physical(fitted: Fitted, experiments) -> dict:
    """The model in the user's units and time, in the observer form (superdiagonal ones, the
    reference row of ``C`` equal to ``e_1``).

    Parameters
    ----------
    fitted : Fitted
    experiments : Experiments

    Returns
    -------
    dict
        ``A (n, n), B (n, m), C (p, n), D (p, m)``, ``x0`` (per record, at its first fitted
        sample), ``offset`` (per record, ``(p,)``), ``y_hat`` (per record, ``(steps, p)``,
        NaN before the largest delay), ``a`` (``a_0 .. a_{n-1}``).
    """
    layout, proj = fitted.layout, fitted.projection
    A_s, C_s = layout.model(fitted.theta)
    g = fitted.h / experiments.dt
    n = layout.n
    # x = T x_s with T = diag(s g^i) gives superdiagonal ones in the time unit dt: (T A_s g T^-1)
    # has g t_i / t_(i+1) = 1 above the diagonal, and the reference row t_0 = 1 stays e_1
    # and the reference output's scale joins T, so that its row of C stays e_1 in the user's
    # units (a scalar commutes with A)
    t = experiments.y_scale[layout.reference] * g ** np.arange(n, dtype=np.float64)
    A = (A_s * g) * t[:, None] / t[None, :]
    B = (proj.B * g) * t[:, None] / experiments.u_scale[None, :]
    C = experiments.y_scale[:, None] * C_s / t[None, :]
    D = experiments.y_scale[:, None] * proj.D / experiments.u_scale[None, :]
    top = int(np.max(fitted.delays))
    y_hat = []
    for Y, est in zip(experiments.Y, proj.y_hat, strict=True):
        full = np.full(Y.shape, np.nan)
        full[top:] = est * experiments.y_scale + experiments.y_mean
        y_hat.append(full)
    return {"A": A, "B": B, "C": C, "D": D, "a": -A[::-1, 0].copy(),
            "x0": tuple(t * x for x in proj.x0),
            "offset": tuple(experiments.y_scale * o + experiments.y_mean for o in proj.offset),
            "y_hat": tuple(y_hat)}
