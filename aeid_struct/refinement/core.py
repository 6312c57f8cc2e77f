r"""The one Levenberg-Marquardt of the library's own fits: every least-squares / output-error
fit that the library iterates itself (the identifiers' separable pass over many records, the
separable refinement of a free CCF, the refinement of any structure over a CasADi graph) is
this loop over a *problem* that says what the residual is. The CasADi NLP (``nlp.py``,
``solve.py``) is the other solver, for constraints this loop does not know; the compiled C of
``compiled_graph.py`` is this loop's iterations written as one CasADi graph (its back end for
the partly fixed CCFs, tested against this one).

The problem of ``B`` rows (records, or one record): a residual ``r(x) (B, N)`` of ``f``
variables ``x (B, f)``, with the cost ``V = ||r||^2 / N`` and a Jacobian ``J = dr/dx
(B, f, N)`` (for the separable problems Kaufman's Jacobian of the projected residual). Each
iteration of each row takes Marquardt's step (Levenberg 1944, Marquardt 1963)

    (J J^T + lambda diag(J J^T)) s = -J r,

in the scaled variables ``x / scale`` where a scale is given; in a box ``[lower, upper]`` a
variable at a bound that the gradient pushes against is held and the others' step is projected
on the box (an active set: a projected step alone stalls short of the constrained optimum).
It keeps the trial point where it lowers the cost
(``lambda / factor``), else the point (``lambda * factor``). A row stops, converged, on the
first of the :class:`Rules` it is given: a gradient ``max |J r|`` below ``gradient_tol`` or a
step below ``step_tol`` (both before the trial is evaluated); once a trial is evaluated, an
accepted decrease below ``cost_tol`` of the cost, a predicted decrease
``-(2 s^T J r + s^T J J^T s)`` below ``predicted_tol`` of ``||r||^2``, a damping above
``lambda_max``, or a cost below ``exact`` times the record's mean square. Without rules
(the identifiers' fixed-cost pass) every row takes ``max_iter`` iterations.

The problem protocol: ``problem.evaluate(x, rows, jacobian, at)`` returns a dict of arrays
whose first axis is the rows given (``rows`` None: all ``B``): ``cost (b,)`` (inf where the
model is not finite), ``r (b, N)`` and, with ``jacobian``, ``J (b, f, N)``; ``at`` is the
current evaluation of those rows (a problem whose Jacobian depends on the current point's
linear parameters reads them there). A problem whose Jacobian costs more than its residual
sets ``lazy = True`` and gives ``problem.jacobian(e) -> J`` for the accepted points only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["Outcome", "Rules", "minimise"]


@dataclass(frozen=True)
class Rules:
    """The damping and the stopping rules of :func:`minimise` (module docstring).

    Attributes
    ----------
    max_iter : int, >= 0
        Iterations per row (a fixed cost without the other rules).
    lambda0 : float
        The damping's start (relative to ``diag(J J^T)``).
    factor : float, > 1
        The damping's factor.
    lambda_min : float
        The damping's floor.
    lambda_max : float, optional
        Stop, converged, once the damping exceeds it (no damped step descends).
    cost_tol : float, optional
        Stop once an accepted step lowers the cost by less than this fraction.
    predicted_tol : float, optional
        Stop once the Gauss-Newton prediction lowers the cost by less than this fraction.
    gradient_tol : float, optional
        Stop before the step where ``max |J r|`` is below it.
    step_tol : float, optional
        Stop before the trial where the step (scaled, after the box) is below it.
    exact : float, optional
        Stop where the cost is below this share of the mean square of ``energy``.
    predicted_first : bool
        Apply ``predicted_tol`` before the trial (a row that predicts too little decrease
        stops where it is, one evaluation fewer) instead of after it (the row still takes a
        trial that lowers the cost: the compiled graph's order).
    gain : bool
        Damp by the gain ratio ``rho`` (the cost's decrease over the Gauss-Newton model's,
        Moré 1978): an accepted step with ``rho < 0.25`` raises the damping, one with ``rho >
        0.75`` lowers it, others keep it. Without it every accepted step lowers it (Marquardt
        1963), and where the model overshoots along a flat, curved valley (the residual's own
        curvature, at noise) the damping alternates between a rejected and a barely better
        step.
    """

    max_iter: int
    lambda0: float = 1e-3
    factor: float = 10.0
    lambda_min: float = 1e-15
    lambda_max: float | None = None
    cost_tol: float | None = None
    predicted_tol: float | None = None
    gradient_tol: float | None = None
    step_tol: float | None = None
    exact: float | None = None
    predicted_first: bool = False
    gain: bool = False

    def __post_init__(self):
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, (int, np.integer)) \
                or self.max_iter < 0:
            raise ValueError(f"max_iter must be an integer >= 0; got {self.max_iter!r}")
        for name in ("lambda0", "factor", "lambda_min"):
            value = getattr(self, name)
            if not (isinstance(value, float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite float; got {value!r}")
        if self.factor <= 1.0:
            raise ValueError(f"factor must be > 1; got {self.factor!r}")
        for name in ("lambda_max", "cost_tol", "predicted_tol", "gradient_tol", "step_tol",
                     "exact"):
            value = getattr(self, name)
            if value is not None and not (isinstance(value, float) and value >= 0):
                raise ValueError(f"{name} must be None or a float >= 0; got {value!r}")

    @property
    def stops(self) -> bool:
        """Whether any rule but ``max_iter`` can end a row."""
        return any(v is not None for v in (self.lambda_max, self.cost_tol, self.predicted_tol,
                                           self.exact))


@dataclass(frozen=True)
class Outcome:
    """Where :func:`minimise` ended, one row per row of the problem.

    Attributes
    ----------
    x : (B, f) array
        The best point each row reached (never worse than its start).
    evaluation : dict
        The problem's evaluation at ``x`` (its rows in order).
    iterations : (B,) int array
        Iterations each row ran.
    accepted : (B,) int array
        Steps each row accepted.
    converged : (B,) bool array
        The row stopped on a rule (not on ``max_iter`` or a start that is not finite).
    """

    x: np.ndarray
    evaluation: dict
    iterations: np.ndarray
    accepted: np.ndarray
    converged: np.ndarray


def _rows(e: dict, rows: np.ndarray, B: int) -> dict:
    """The entries of evaluation ``e`` (of ``B`` rows) at ``rows``; others as they are."""
    return {k: (v[rows] if isinstance(v, np.ndarray) and v.shape[:1] == (B,) else v)
            for k, v in e.items()}


def _step(J: np.ndarray, r: np.ndarray, lam: np.ndarray, frozen=None):
    """Marquardt's step ``s (b, f)`` with ``g = J r``, ``H = J J^T`` (row by row where the
    stacked solve meets a singular matrix: that row takes the scaled gradient step). The
    ``frozen (b, f)`` variables (at a bound that the gradient pushes against) do not move: the
    step solves the system of the others (a projected step alone stalls where it would have
    left the box, away from the constrained optimum)."""
    g = (J @ r[:, :, None])[:, :, 0]
    H = J @ J.transpose(0, 2, 1)
    if frozen is not None and frozen.any():
        keep = ~frozen
        g = np.where(keep, g, 0.0)
        H = H * (keep[:, :, None] & keep[:, None, :])
        H[frozen[:, :, None] & np.eye(H.shape[1], dtype=bool)] = 1.0
    diag = np.einsum("bjj->bj", H) + 1e-300
    K = H + lam[:, None, None] * diag[:, :, None] * np.eye(H.shape[1])
    try:
        step = -np.linalg.solve(K, g[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        step = np.empty_like(g)
        for b in range(g.shape[0]):
            try:
                step[b] = -np.linalg.solve(K[b], g[b])
            except np.linalg.LinAlgError:
                step[b] = -g[b] / (lam[b] * diag[b])
    return g, H, step


def minimise(problem, x0, rules: Rules, *, scale=None, lower=None, upper=None, energy=None,
             progress: Callable[[int, float], None] | None = None) -> Outcome:
    """Levenberg-Marquardt from ``x0`` on every row of ``problem`` (module docstring).

    Parameters
    ----------
    problem : object
        ``evaluate(x, rows, jacobian, at) -> dict`` and ``lazy`` (with ``jacobian(e)``).
    x0 : (B, f) array
        The start, inside the box.
    rules : Rules
    scale : (B, f) array, optional
        The steps are taken in ``x / scale`` (Marquardt's damping is scale-free; the step and
        gradient rules then read relative units).
    lower, upper : (B, f) arrays, optional
        The box the trial points are projected on.
    energy : (B,) array, optional
        The records' mean squares, for ``rules.exact``.
    progress : callable, optional
        ``progress(iteration, cost)`` after each accepted step of a single row.

    Returns
    -------
    Outcome
    """
    x = np.array(x0, dtype=np.float64)
    B = x.shape[0]
    lazy = bool(getattr(problem, "lazy", False))
    now = problem.evaluate(x, None, rules.max_iter > 0 and not lazy, None)
    finite = np.isfinite(now["cost"])
    if lazy and rules.max_iter > 0 and finite.any():
        now["J"] = problem.jacobian(now)
    lam = np.full(B, rules.lambda0)
    done = ~finite
    converged = np.zeros(B, dtype=bool)
    iterations = np.zeros(B, dtype=int)
    accepted = np.zeros(B, dtype=int)
    every, stops = np.arange(B), rules.stops
    for it in range(rules.max_iter):
        # while every row is active (the usual case) the arrays are used whole: per-operation
        # overhead, not arithmetic, is the cost of a small problem's iteration
        active = np.flatnonzero(~done) if done.any() else every
        if active.size == 0:
            break
        whole = active.size == B
        if whole:
            iterations += 1
        else:
            iterations[active] += 1
        sub = now if whole else _rows(now, active, B)
        trial, stop, small, expect = _trial(
            rules, x if whole else x[active], sub, lam if whole else lam[active],
            None if scale is None else scale if whole else scale[active],
            None if lower is None else (lower, upper) if whole else (lower[active],
                                                                     upper[active]))
        if stop.any():
            done[active[stop]] = converged[active[stop]] = True
            active, trial, small = active[~stop], trial[~stop], small[~stop]
            expect = None if expect is None else expect[~stop]
            if active.size == 0:
                continue
            whole = active.size == B
            sub = now if whole else _rows(now, active, B)
        new = problem.evaluate(trial, None if whole else active,
                               not lazy and it < rules.max_iter - 1, sub)
        better = new["cost"] < sub["cost"]
        # before _accept, which may write the accepted rows into ``now`` (``sub``)
        damped = _damping(rules, lam if whole else lam[active], better, sub["cost"],
                          new["cost"], expect)
        if stops:
            flat = _flat(rules, sub["cost"], new["cost"], better, small,
                         lam if whole else lam[active],
                         None if energy is None else energy if whole else energy[active])
            if whole:
                done |= flat
                converged |= flat
            else:
                done[active[flat]] = converged[active[flat]] = True
        if whole and better.all():
            jacobian = lazy and it < rules.max_iter - 1 and not done.all()
            now = _accept(problem, now, new, better, active, lazy, jacobian)
            x, lam = trial, damped
            accepted += 1
        else:
            rows = active[better]
            if rows.size:
                jacobian = lazy and it < rules.max_iter - 1 and not done[rows].all()
                now = _accept(problem, now, new, better, rows, lazy, jacobian)
                x[rows] = trial[better]
            accepted[rows] += 1
            lam[active] = damped
        if progress is not None and B == 1 and better[0]:
            progress(int(iterations[0]), float(now["cost"][0]))
    return Outcome(x=x, evaluation=now, iterations=iterations, accepted=accepted,
                   converged=converged)


def _step_one(J: np.ndarray, r: np.ndarray, lam: float, frozen):
    """:func:`_step` of one row: ``J (f, N)``, ``r (N,)``."""
    g = J @ r
    H = J @ J.T
    if frozen is not None and frozen.any():
        keep = ~frozen
        g = np.where(keep, g, 0.0)
        H = H * np.outer(keep, keep)
        H[np.flatnonzero(frozen), np.flatnonzero(frozen)] = 1.0
    diag = np.diag(H) + 1e-300
    try:
        step = np.linalg.solve(H + lam * np.diag(diag), -g)
    except np.linalg.LinAlgError:
        step = -g / (lam * diag)
    return g, H, step


def _trial(rules: Rules, x, sub: dict, lam, scale, box):
    """The trial points of the active rows at ``x (b, f)`` from their evaluation ``sub``:
    ``(trial (b, f), stop (b,), small (b,), expect)``, ``stop`` the rows that end before their
    trial (gradient, step, and the prediction where it comes first), ``small`` those whose
    predicted decrease is below ``rules.predicted_tol``, ``expect (b,)`` that decrease relative
    to ``||r||^2`` (None where no rule reads it)."""
    if x.shape[0] == 1:
        return _trial_one(rules, x, sub, lam, scale, box)
    J = sub["J"] if scale is None else sub["J"] * scale[:, :, None]
    frozen = None
    if box is not None:
        slope = (J @ sub["r"][:, :, None])[:, :, 0]
        frozen = ((x <= box[0]) & (slope > 0)) | ((x >= box[1]) & (slope < 0))
    g, H, step = _step(J, sub["r"], lam, frozen)
    stop = np.zeros(x.shape[0], dtype=bool)
    small = np.zeros(x.shape[0], dtype=bool)
    if rules.gradient_tol is not None:
        stop |= np.max(np.abs(g), axis=1, initial=0.0) <= rules.gradient_tol
    trial = x + (step if scale is None else scale * step)
    if box is not None:
        trial = np.clip(trial, *box)
    expect = None
    if rules.predicted_tol is not None or rules.gain:
        rr = np.einsum("bn,bn->b", sub["r"], sub["r"])
        predicted = -(2.0 * np.einsum("bj,bj->b", g, step)
                      + np.einsum("bj,bjk,bk->b", step, H, step))
        expect = predicted / rr
    if rules.predicted_tol is not None:
        small = predicted <= rules.predicted_tol * rr
        if rules.predicted_first:
            stop |= small
    if rules.step_tol is not None:
        # in scaled units: the step itself, or what the box left of it
        moved = step if box is None else (trial - x if scale is None else (trial - x) / scale)
        stop |= np.max(np.abs(moved), axis=1, initial=0.0) <= rules.step_tol
    return trial, stop, small, expect


def _trial_one(rules: Rules, x, sub: dict, lam, scale, box):
    """:func:`_trial` of one row (a single record's fit) in two-dimensional products and
    scalars: at these sizes the stacked operations' per-call cost is most of an iteration's."""
    J, r, x1 = sub["J"][0], sub["r"][0], x[0]
    if scale is not None:
        J = J * scale[0][:, None]
    frozen = None
    if box is not None:
        slope = J @ r
        frozen = ((x1 <= box[0][0]) & (slope > 0)) | ((x1 >= box[1][0]) & (slope < 0))
    g, H, step = _step_one(J, r, float(lam[0]), frozen)
    stop = small = False
    if rules.gradient_tol is not None:
        stop = float(np.abs(g).max(initial=0.0)) <= rules.gradient_tol
    trial = x1 + (step if scale is None else scale[0] * step)
    if box is not None:
        trial = np.clip(trial, box[0][0], box[1][0])
    expect = None
    if rules.predicted_tol is not None or rules.gain:
        predicted = -(2.0 * float(g @ step) + float(step @ H @ step))
        expect = np.array([predicted / float(r @ r)])
    if rules.predicted_tol is not None:
        small = predicted <= rules.predicted_tol * float(r @ r)
        stop = stop or (small and rules.predicted_first)
    if rules.step_tol is not None:
        moved = step if box is None else (trial - x1 if scale is None else (trial - x1) / scale[0])
        stop = stop or float(np.abs(moved).max(initial=0.0)) <= rules.step_tol
    return trial[None], np.array([stop]), np.array([small]), expect


def _damping(rules: Rules, lam, better, cost, trial_cost, expect) -> np.ndarray:
    """The active rows' next damping: raised where the trial failed; where it was taken,
    lowered (Marquardt), or by the gain ratio where ``rules.gain`` (:class:`Rules`)."""
    lowered = np.maximum(lam / rules.factor, rules.lambda_min)
    if rules.gain and expect is not None:
        with np.errstate(all="ignore"):
            rho = (cost - trial_cost) / cost / expect
        lowered = np.where(rho > 0.75, lowered, np.where(rho < 0.25, lam * rules.factor, lam))
    return np.where(better, lowered, lam * rules.factor)


def _flat(rules: Rules, cost, trial_cost, better, small, lam, energy) -> np.ndarray:
    """The rows that stop, converged, once their trial is evaluated (module docstring)."""
    flat = np.zeros(cost.shape[0], dtype=bool)
    if rules.cost_tol is not None:
        flat |= better & (cost - trial_cost <= rules.cost_tol * cost)
    if rules.predicted_tol is not None and not rules.predicted_first:
        flat |= small
    if rules.lambda_max is not None:
        flat |= lam > rules.lambda_max
    if rules.exact is not None:
        flat |= np.minimum(cost, trial_cost) <= rules.exact * energy
    return flat


def _accept(problem, now: dict, new: dict, better, rows, lazy: bool, jacobian: bool) -> dict:
    """``now`` with the trial evaluation ``new`` (of the active rows) at the rows that took
    their step, ``rows`` (a lazy problem's Jacobian evaluated there where ``jacobian``)."""
    size = better.shape[0]
    if lazy:
        new = new if better.all() else _rows(new, np.flatnonzero(better), size)
        if jacobian:
            new["J"] = problem.jacobian(new)
        pick, size = slice(None), rows.size
    else:
        pick = better
    if rows.size == now["cost"].shape[0]:
        return new
    for k, v in new.items():
        if isinstance(v, np.ndarray) and v.shape[:1] == (size,) and k in now:
            now[k][rows] = v[pick]
    return now
