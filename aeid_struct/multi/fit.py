r"""The several-channel fit: output error over every record by variable projection, and the
model taken back to the user's units.

Only ``theta = (a, C without its reference row)`` is iterated (``multi.realisation``); at each
point ``B, D`` and every record's ``x0`` and offset are the least-squares solution, so the
residual is a function of ``theta`` alone (Golub and Pereyra's variable projection). The
library's one Levenberg-Marquardt (``refinement.core.minimise``) iterates it with Golub and
Pereyra's Jacobian of ``r = P(theta) t`` (``multi.jacobian``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from aeid_struct.multi.jacobian import jacobian
from aeid_struct.multi.realisation import Layout, Projection, project
from aeid_struct.refinement import Rules, minimise

__all__ = ["CLEARLY_BETTER", "LAMBDA_FACTOR", "MAX_ITERATIONS", "TOL", "TRIAL", "Fitted",
           "beyond_stable", "is_stable", "iterate", "output_fits", "physical", "rescan",
           "validation_fit", "without_delay"]

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
    unstable : dict, optional
        Where the fit was held to stable models (``stable``) and the unconstrained fit from it
        is unstable and clearly better (:func:`beyond_stable`): its ``poles`` (in the inverse
        of the records' time unit) and ``fit`` (% per output, over every record's samples).
    """

    layout: Layout
    theta: np.ndarray
    h: float
    delays: np.ndarray
    projection: Projection
    iterations: int = 0
    converged: bool = False
    start: str = "classical"
    unstable: dict | None = None

    @property
    def cost(self) -> float:
        """Mean squared residual (working units)."""
        return self.projection.cost


class _Problem:
    """The projected output error as a one-row problem of ``refinement.core.minimise``: the
    residual by projection, the Jacobian (``multi.jacobian``) at accepted points only."""

    lazy = True

    def __init__(self, layout: Layout, parts, holds, h: float, feedthrough: bool,
                 stable: bool = False) -> None:
        self.layout, self.parts, self.holds, self.h = layout, parts, holds, h
        self.feedthrough, self.stable = feedthrough, stable

    def evaluate(self, x, rows, jacobian, at):
        theta = np.asarray(x[0], dtype=np.float64)
        A, C = self.layout.model(theta)
        if self.stable and not is_stable(A):
            # outside the stable models: an infinite cost, which the Levenberg-Marquardt
            # rejects as it rejects an overflow, damping the step until it stays inside
            return {"cost": np.array([np.inf]), "r": None, "theta": theta[None],
                    "proj": [None]}
        with np.errstate(all="ignore"):
            proj = project(A, C, self.parts, self.h, self.holds, self.feedthrough)
        finite = bool(np.all(np.isfinite(proj.residual)))
        return {"cost": np.array([proj.cost if finite else np.inf]),
                "r": proj.residual[None] if finite else None,
                "theta": theta[None], "proj": [proj if finite else None]}

    def jacobian(self, e: dict) -> np.ndarray:
        J = jacobian(self.layout, e["theta"][0], e["proj"][0], self.parts, self.holds,
                      self.h, self.feedthrough)
        return J.T[None]


def is_stable(A: np.ndarray) -> bool:
    """Whether every eigenvalue of ``A`` has a negative real part (the fit's ``stable``).

    Parameters
    ----------
    A : (n, n) array

    Returns
    -------
    bool
    """
    with np.errstate(all="ignore"):
        eig = np.linalg.eigvals(A) if np.all(np.isfinite(A)) else np.array([np.nan])
    return bool(np.all(eig.real < 0.0))


def iterate(layout: Layout, theta: np.ndarray, h: float, experiments, delays, feedthrough: bool,
            iterations: int | None, start: str = "classical", stable: bool = False) -> Fitted:
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
    stable : bool
        Hold the iterations to stable models (every pole with a negative real part): a step
        out of them is rejected like one whose response overflows. The start must be stable.

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
    out = minimise(_Problem(layout, parts, holds, h, feedthrough, stable), theta[None], rules)
    proj = out.evaluation["proj"][0]
    if proj is None or not proj.cost < first.cost:
        return begin
    return Fitted(layout, out.x[0], h, np.asarray(delays), proj, int(out.iterations[0]),
                  bool(out.converged[0]), start)


#: :func:`without_delay`'s trial, in :func:`iterate`'s units (``TRIAL (len(theta) + 1)``
#: Levenberg-Marquardt iterations), before it is fitted to convergence where it is already
#: the better.
TRIAL = 1


def without_delay(fitted: Fitted, experiments, feedthrough: bool, top: int,
                  stable: bool = False) -> Fitted:
    """``fitted`` (a fit to convergence at estimated input delays), or, where a delay is the
    largest allowed (``top``), the fit from its poles with no delay where that reaches a lower
    cost.

    Why: a delay and a slow pole trade off, and the common-denominator ARX picks the delay
    at fixed low order: on a measured heater record's sluggish start it chose the largest
    delay allowed, and the output-error fit there ended in another basin than the fit without
    a delay, whose cost was lower. The walk over the delays (:func:`rescan`) moves one sample
    at a time at fixed poles and does not cross to it. A delay at the top of its range is the
    sign (a real delay lies inside the range): only there a short trial (:data:`TRIAL`)
    decides, and only a better one is run to convergence; a trial at every nonzero delay
    changed no fit of the channels benchmark and cost it time.

    Parameters
    ----------
    fitted : Fitted
    experiments : Experiments
    feedthrough : bool
    top : int
        The largest delay the estimate was allowed.
    stable : bool
        As :func:`iterate`.

    Returns
    -------
    Fitted
    """
    if top <= 0 or not np.any(fitted.delays >= top):
        return fitted
    zero = np.zeros_like(fitted.delays)
    trial = iterate(fitted.layout, fitted.theta, fitted.h, experiments, zero, feedthrough,
                    TRIAL, fitted.start, stable)
    if not trial.cost < fitted.cost:
        return fitted
    done = iterate(trial.layout, trial.theta, trial.h, experiments, zero, feedthrough, None,
                   trial.start, stable)
    return done if done.cost < trial.cost else trial


#: A model outside the stable ones is reported where its mean squared residual is below this
#: share of the stable fit's (``generic.polish.better_of``'s margin for one channel).
CLEARLY_BETTER = 0.99


def beyond_stable(fitted: Fitted, experiments, feedthrough: bool) -> Fitted:
    """``fitted``, a fit held to stable models, with ``unstable`` set where the same
    iterations without that constraint, from its point, end at an unstable model whose cost
    is below :data:`CLEARLY_BETTER` times its own: the records' best model is then unstable,
    and a stable-only estimate must say so rather than pass for the system (the modal form's
    rule for one channel, ``generic.pipeline``).

    Parameters
    ----------
    fitted : Fitted
    experiments : Experiments
    feedthrough : bool

    Returns
    -------
    Fitted
    """
    free = iterate(fitted.layout, fitted.theta, fitted.h, experiments, fitted.delays,
                   feedthrough, None, fitted.start)
    A = free.layout.model(free.theta)[0]
    if is_stable(A) or not free.cost < CLEARLY_BETTER * fitted.cost:
        return fitted
    Y = np.vstack([Y for Y, _ in experiments.aligned(free.delays)])
    fit = output_fits(Y, np.vstack(free.projection.y_hat))
    return dataclasses.replace(fitted, unstable={
        "poles": np.linalg.eigvals(A) * free.h / experiments.dt, "fit": fit})


def validation_fit(fitted: Fitted, ex, feedthrough: bool) -> np.ndarray:
    """NRMSE fit in % per record and output of a fitted model on ``ex`` (its initial states
    and offsets fitted, ``B, D`` kept): ``(R, p)``.

    Parameters
    ----------
    fitted : Fitted
    ex : Experiments
    feedthrough : bool

    Returns
    -------
    (R, p) array
    """
    A, C = fitted.layout.model(fitted.theta)
    parts = ex.aligned(fitted.delays)
    with np.errstate(all="ignore"):
        proj = project(A, C, parts, fitted.h, ex.holds, feedthrough,
                       B=fitted.projection.B, D=fitted.projection.D)
    return np.array([output_fits(Y, Yh) for (Y, _), Yh in zip(parts, proj.y_hat, strict=True)])


def output_fits(Y: np.ndarray, Y_hat: np.ndarray) -> np.ndarray:
    """NRMSE fit in % per column: ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)``, ``-inf``
    where it is not finite.

    Parameters
    ----------
    Y, Y_hat : (steps, p) arrays

    Returns
    -------
    (p,) array
    """
    with np.errstate(all="ignore"):
        fit = 100.0 * (1.0 - np.linalg.norm(Y - Y_hat, axis=0)
                       / np.linalg.norm(Y - Y.mean(axis=0), axis=0))
    return np.where(np.isfinite(fit), fit, -np.inf)


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
