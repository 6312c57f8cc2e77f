r"""The several-channel fit: output error over every record by variable projection, and the
model taken back to the user's units.

Only ``theta = (a, C without its reference row)`` is iterated (``multi.realisation``); at each
point ``B, D`` and every record's ``x0`` and offset are the least-squares solution, so the
residual is a function of ``theta`` alone (Golub and Pereyra's variable projection). The
library's one Levenberg-Marquardt (``refinement.core.minimise``) iterates it with Golub and
Pereyra's Jacobian of ``r = P(theta) t`` (``multi.jacobian``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeid_struct.multi.jacobian import jacobian
from aeid_struct.multi.realisation import Layout, Projection, project
from aeid_struct.refinement import Rules, minimise

__all__ = ["LAMBDA_FACTOR", "MAX_ITERATIONS", "TOL", "Fitted", "iterate", "physical", "rescan"]

#: Relative tolerances of the iterations (cost, step, gradient): below them the fit moves by
#: far less than the noise.
TOL = 1e-9
#: Iterations at most to convergence: an order above the system's has directions the data do
#: not fix, along which MINPACK's default (``100 (k + 1)`` Jacobians for ``k`` parameters, when
#: this fit ran on it) crawled for minutes (order 8 of a 2x2 order-4 record while the order was
#: selected).
MAX_ITERATIONS = 100
#: The damping's factor (``refinement.Rules``; :func:`iterate` says why not Marquardt's 10).
LAMBDA_FACTOR = 3.0


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
        Levenberg-Marquardt iterations (0: the start's projection).
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


class _Problem:
    """The projected output error as a one-row problem of ``refinement.core.minimise``: the
    residual by projection, the Jacobian (``multi.jacobian``) at accepted points only."""

    lazy = True

    def __init__(self, layout: Layout, parts, holds, h: float, feedthrough: bool) -> None:
        self.layout, self.parts, self.holds, self.h = layout, parts, holds, h
        self.feedthrough = feedthrough

    def evaluate(self, x, rows, jacobian, at):
        theta = np.asarray(x[0], dtype=np.float64)
        with np.errstate(all="ignore"):
            proj = project(*self.layout.model(theta), self.parts, self.h, self.holds,
                           self.feedthrough)
        finite = bool(np.all(np.isfinite(proj.residual)))
        return {"cost": np.array([proj.cost if finite else np.inf]),
                "r": proj.residual[None] if finite else None,
                "theta": theta[None], "proj": [proj if finite else None]}

    def jacobian(self, e: dict) -> np.ndarray:
        J = jacobian(self.layout, e["theta"][0], e["proj"][0], self.parts, self.holds,
                      self.h, self.feedthrough)
        return J.T[None]


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
        iterations at most (the cost of ``iterations`` Jacobians by full projections, what
        the one pass was measured with: exactly ``iterations`` left it 4 points below refined
        on one of five 2x2 records of the channels benchmark); None: to convergence
        (:data:`TOL`), at most :data:`MAX_ITERATIONS` iterations.
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
    cap = MAX_ITERATIONS if iterations is None else iterations * (len(theta) + 1)
    # the damping by the gain ratio, by a factor of 3: with Marquardt's factor of 10 and no
    # gain ratio a 2x2 order-4 record of bench-channels crawled along a curved valley and
    # stopped at the cap, 1 point of validation fit short of the optimum (which this reaches in
    # 60 iterations, MINPACK's Levenberg-Marquardt in 56)
    rules = Rules(max_iter=int(cap), factor=LAMBDA_FACTOR, gain=True, lambda_max=1e12,
                  cost_tol=TOL, predicted_tol=TOL, step_tol=TOL)
    out = minimise(_Problem(layout, parts, holds, h, feedthrough), theta[None], rules)
    proj = out.evaluation["proj"][0]
    if proj is None or not proj.cost < first.cost:
        return begin
    return Fitted(layout, out.x[0], h, np.asarray(delays), proj, int(out.iterations[0]),
                  bool(out.converged[0]), start)


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
