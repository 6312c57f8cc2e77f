r"""Step 2 of the physical head (``identification.physical_head``): the parameters in the box
whose free CCF coefficients (paper Eq. 5) are nearest the fitted ones, the inverse of the
coefficient map ``p -> k(p)``.

Least squares on ``S (k(p) - k_fit)`` by Gauss-Newton with step halving, clipped into the box,
from the encoder's parameters; for a square map (as many free coefficients as parameters) first
as one SX graph of unrolled Newton steps where the map is small (:func:`_newton`), and, where
Gauss-Newton from the encoder's parameters stops short of ``k_fit``, again from fixed points
of the box (:meth:`Inverse.parameters`).
"""

from __future__ import annotations

import math

import casadi
import numpy as np

from aeid_struct.structures import Numeric

__all__ = ["SEED", "Inverse", "box_points"]

#: Iterations of the coefficient fit; each is one evaluation of ``k(p)`` and its Jacobian.
INVERSE_ITERATIONS = 30


class Inverse:
    """The inverse of a coefficient map ``p -> (k(p), dk/dp)`` over a box (module docstring).

    Parameters
    ----------
    k_map : casadi.Function
        ``p (q,) -> (k (k,), J (k, q))``, dense outputs.
    lo, hi : (q,) arrays
        The box.
    square : bool
        As many coefficients as parameters.
    targets : (P, k) array
        Coefficients of points of the box: where the map is square, the inverse from every
        further start must reach the first :data:`PROBE_TARGETS` of them for those starts to
        be left out (:meth:`_retries`).
    """

    def __init__(self, k_map: casadi.Function, lo: np.ndarray, hi: np.ndarray, *,
                 square: bool, targets: np.ndarray) -> None:
        self.coefficients = Numeric(k_map)
        self.lo, self.hi, self.q, self.square = lo, hi, lo.size, square
        # a square map's inverse as one SX graph (the Newton iterations unrolled), where the
        # map expands to SX (a rootfinder's does not) and is small: the graph evaluates it
        # 4 NEWTON_ITERATIONS + 1 times, and a large one (a two-mass system's) costs more
        # than the loop it replaces
        small = (k_map.is_a("SXFunction") and k_map.n_instructions()
                 * (4 * NEWTON_ITERATIONS + 1) <= NEWTON_SIZE)
        self._newton = Numeric(_newton(k_map, lo, hi)) if square and small else None
        self._starts = None
        self._targets = np.asarray(targets)[:PROBE_TARGETS]

    def parameters(self, target: np.ndarray, start: np.ndarray,
                   weight: np.ndarray | None = None) -> np.ndarray:
        """The parameters in the bounds whose free coefficients are nearest ``target``
        (weighted least squares, Gauss-Newton with step halving from ``start``; for a square
        map that does not reach ``target`` from there, also from :data:`INVERSE_STARTS`
        fixed points of the box, the nearest kept).

        Why the further starts: the coefficient map of a mechanism is not one-to-one over
        its box (a two-mass system's springs and masses can trade places), and Gauss-Newton
        from the encoder's parameters can stop on a bound or in another basin of the
        distance although ``target`` is reached elsewhere in the box; each start costs a few
        evaluations of the coefficient map, not a simulation.

        Parameters
        ----------
        target : (k,) array
            The fitted free coefficients.
        start : (q,) array
            The encoder's parameters.
        weight : (k, k) array, optional
            ``S`` of the distance ``||S (k(p) - target)||`` (``PhysicalHead.information``); relative
            (``S = diag(1 / |target|)``) where None.

        Returns
        -------
        (q,) array
        """
        p, cost = self._nearest(target, start, weight)
        if not (self.square and weight is None and cost > REACHED):
            return p
        for point in self._retries():
            found, distance = self._nearest(target, point, None, RETRY_ITERATIONS)
            if distance < cost:
                p, cost = found, distance
                if cost <= REACHED:
                    break
        return p

    @property
    def reached_from_anywhere(self) -> bool:
        """Whether Gauss-Newton reaches the map's coefficients from any start in the box
        (:meth:`_retries`: checked once on probes of the box), so that the parameters
        nearest the fitted coefficients do not depend on where the inverse starts: always
        False for a map that is not square."""
        return self.square and self._retries().size == 0

    def _retries(self) -> np.ndarray:
        """The further starts of a square map's inverse (:meth:`parameters`): the first
        :data:`INVERSE_STARTS` points of :func:`box_points`, or none where the inverse from
        each of them reaches the coefficients of every one of :data:`PROBE_TARGETS` points of
        the box (a map Gauss-Newton inverts from anywhere, the leg's: further starts would
        only cost time where noise puts the fitted coefficients beyond the box's image).
        Decided once, on first use.

        Returns
        -------
        (INVERSE_STARTS or 0, q) array
        """
        if self._starts is None:
            points = box_points(self.lo, self.hi, INVERSE_STARTS)
            reached = all(self._nearest(target, point, None, RETRY_ITERATIONS)[1] <= REACHED
                          for target in self._targets for point in points)
            self._starts = points[:0] if reached else points
        return self._starts

    def _nearest(self, target: np.ndarray, start: np.ndarray, weight: np.ndarray | None,
                 iterations: int = INVERSE_ITERATIONS) -> tuple[np.ndarray, float]:
        """:meth:`parameters` from one start: the parameters and their distance
        ``||S (k(p) - target)||^2``."""
        margin = 1e-9 * (self.hi - self.lo)
        lo, hi = self.lo + margin, self.hi - margin
        p = np.clip(np.asarray(start, dtype=np.float64), lo, hi)
        if weight is None and self._newton is not None:
            found, cost = self._newton(np.ascontiguousarray(target, dtype=np.float64), p)
            if cost[0] <= NEWTON_DONE:
                return found.copy(), float(cost[0])
            if np.isfinite(found).all():
                p = found.copy()                # near a bound, or slow: the loop goes on
        if weight is None:
            S = np.diag(1.0 / (np.abs(target) + 1e-9 * max(np.abs(target).max(), 1e-300)))
        else:
            S = weight
        k, J = self.coefficients(p)
        r = S @ (k - target)
        cost = float(r @ r)
        # Gauss-Newton with step halving: the coefficient map is smooth and, where square,
        # regular near its solution (quadratic convergence in a few steps)
        for _ in range(iterations):
            if not cost > 1e-28:
                break
            Jw = S @ J.reshape(self.q, -1).T                    # column-major (k, q)
            step = np.linalg.lstsq(Jw, -r, rcond=None)[0]
            for _ in range(12):
                trial = np.clip(p + step, lo, hi)
                k2, J2 = self.coefficients(trial)
                r2 = S @ (k2 - target)
                cost2 = float(r2 @ r2)
                if math.isfinite(cost2) and cost2 < cost:
                    break
                step = 0.5 * step
            else:
                break                   # no descent along the Gauss-Newton direction
            done = cost - cost2 <= 1e-14 * cost
            p, r, J, cost = trial, r2, J2, cost2
            if done:
                break
        return p, cost if math.isfinite(cost) else math.inf


def box_points(lower: np.ndarray, upper: np.ndarray, count: int) -> np.ndarray:
    """The first ``count`` points of the scrambled Halton sequence of the box (seed
    :data:`SEED`): the same for every record and call, so an estimate does not depend on a
    random state, and spread over the box as ``count`` random draws are only on average.

    Parameters
    ----------
    lower, upper : (q,) arrays
    count : int, >= 0

    Returns
    -------
    (count, q) array
    """
    from scipy.stats import qmc

    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    unit = qmc.Halton(d=lower.size, scramble=True, seed=SEED).random(count)
    return lower + (upper - lower) * unit


#: The seed of :func:`box_points`' scrambled Halton sequence.
SEED = 0
#: Further starts of a square map's inverse that does not reach the fitted coefficients from
#: the encoder's parameters (:meth:`Inverse.parameters`).
INVERSE_STARTS = 8
#: Points of the box whose coefficients the inverse must reach from every further start for
#: those starts to be left out (:meth:`PhysicalHead._retries`).
PROBE_TARGETS = 4
#: Gauss-Newton iterations from each further start: where the map is regular, its solution is
#: reached in a few (quadratic convergence); a start still short of it after these is headed
#: for a bound, where the nearest point of the fitted coefficients is no solution anyway.
RETRY_ITERATIONS = 10
#: The relative distance ``||(k(p) - target) / |target| ||^2`` below which a square map's
#: inverse has reached the fitted coefficients (relative coefficient errors of 1e-8: far below
#: what noise moves them by, far above round-off).
REACHED = 1e-16


#: Unrolled Newton iterations of a square map's inverse (:func:`_newton`).
NEWTON_ITERATIONS = 8
#: The largest unrolled Newton graph, in evaluations of the coefficient map's SX instructions.
NEWTON_SIZE = 20_000
#: The relative cost ``||(k(p) - target) / |target| ||^2`` at which the unrolled Newton's
#: result is taken (relative coefficient errors of 1e-12); above it the step-halving loop of
#: :meth:`Inverse.parameters` goes on from that result.
NEWTON_DONE = 1e-24


def _newton(k_map: casadi.Function, lo: np.ndarray, hi: np.ndarray) -> casadi.Function:
    """``(target (k,), p0 (q,)) -> (p (q,), cost)``: :data:`NEWTON_ITERATIONS` Newton steps on
    ``k(p) = target`` for a square map, relative residual ``(k(p) - target) / |target|``, each
    step the longest of 1, 1/2, 1/4 and 1/8 of the Newton step that lowers the cost (or none),
    clipped into the box, as one SX graph.

    Why: the step-halving loop of :meth:`Inverse.parameters` costs a few evaluations of
    the map and a least-squares solve per iteration in Python, most of a SISO mechanism's
    one pass; the same iterations as one graph cost one call."""
    q = k_map.size1_in(0)
    k = k_map.size1_out(0)
    target, p0 = casadi.SX.sym("target", k), casadi.SX.sym("p0", q)
    margin = 1e-9 * (hi - lo)
    lo, hi = casadi.DM(lo + margin), casadi.DM(hi - margin)
    scale = 1.0 / (casadi.fabs(target) + 1e-9 * casadi.mmax(casadi.fabs(target)) + 1e-300)

    def at(p):
        values, J = k_map(p)
        r = scale * (values - target)
        return r, casadi.reshape(J, k, q), casadi.sumsqr(r)

    p = casadi.fmin(casadi.fmax(p0, lo), hi)
    r, J, cost = at(p)
    for _ in range(NEWTON_ITERATIONS):
        step = casadi.solve(casadi.diag(scale) @ J, -r)
        new_p, new_r, new_J, new_cost = p, r, J, cost
        for h in (0.125, 0.25, 0.5, 1.0):          # the longest step that lowers the cost
            trial = casadi.fmin(casadi.fmax(p + h * step, lo), hi)
            tr, tJ, tc = at(trial)
            better = tc < cost
            new_p = casadi.if_else(better, trial, new_p)
            new_r = casadi.if_else(better, tr, new_r)
            new_J = casadi.if_else(better, tJ, new_J)
            new_cost = casadi.if_else(better, tc, new_cost)
        p, r, J, cost = new_p, new_r, new_J, new_cost
    return casadi.Function("newton", [target, p0], [p, cost])


