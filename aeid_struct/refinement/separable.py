r"""Separable output-error refinement of the free canonical forms (variable projection in numpy).

This module holds the minimiser: Levenberg-Marquardt on the projected cost ``V(alpha)`` of
``projected.py`` (the model, the projection and Kaufman's Jacobian are there), and the
result in physical time. The seam: the problem (what is minimised, and its derivative)
against the iterations that minimise it and the model they return.

*Why numpy and not CasADi.* ``refinement.refine_record`` unrolls the FOH response over a bucket
of samples into one CasADi graph and differentiates it in all free elements (``a`` and ``c``,
``d``); the separable problem has ``n`` decision variables and its Jacobian is one ``lfilter``
plus shifts, so it is several times cheaper per iteration (the times side by side are in the
comment above :func:`refine_separable`). It serves the FREE canonical forms only:
``refine_record`` stays the path for structures with fixed elements, physical structures and
bounds (an MCF's ``Re < 0``), and for every structure that is not a CCF in disguise.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np

from aeid_struct.estimates import Estimate
from aeid_struct.records import INTERSAMPLE
from aeid_struct.refinement import core
from aeid_struct.refinement.projected import Problem, as_arrays, check_arguments, projected_cost
from aeid_struct.refinement.result import fitted
from aeid_struct.simulation import project
from aeid_struct.structures import CCF

# projected_cost was defined here before the problem moved to projected.py: still exported here
__all__ = ["projected_cost", "refine_separable"]

#: The damping and stopping rules (``core.Rules``) besides the tolerances: start (relative to
#: diag(J^T J)), factor, floor and give-up value.
_LAMBDA0, _LAMBDA_FACTOR, _LAMBDA_MIN, _LAMBDA_MAX = 1e-3, 10.0, 1e-15, 1e10


class _One:
    """The projected problem of one record as a one-row problem of ``core.minimise``: the
    Jacobian (an eigenvalue problem, an IIR filter and a projection) only at accepted points."""

    lazy = True

    def __init__(self, problem: Problem) -> None:
        self.problem = problem

    def evaluate(self, alpha, rows, jacobian, at):
        e = self.problem.evaluate(alpha[0])
        return {"cost": np.array([e["cost"]]), "r": e["r"][None] if "r" in e else None,
                "one": e}

    def jacobian(self, e: dict) -> np.ndarray:
        return self.problem.jacobian(e["one"]).T[None]


def _levenberg_marquardt(problem: Problem, alpha, max_iter, cost_tol, step_tol):
    """Minimise ``V`` from ``alpha`` (``core.minimise``): ``(alpha, iterations, converged)``.

    Converged: a step below ``step_tol`` (relative), an accepted step or the Gauss-Newton
    prediction lowering the cost by less than ``cost_tol`` (relative), or a damping beyond
    :data:`_LAMBDA_MAX` (no damped step descends)."""
    # relative units: alpha_j ~ |p|^(n-j) spans decades; Marquardt's diag(J^T J) damping is
    # scale-free, the step test is relative
    scale = np.maximum(np.abs(alpha), 1e-6 * np.abs(alpha).max())
    rules = core.Rules(max_iter=max_iter, lambda0=_LAMBDA0, factor=_LAMBDA_FACTOR,
                       lambda_min=_LAMBDA_MIN, lambda_max=_LAMBDA_MAX, cost_tol=cost_tol,
                       predicted_tol=cost_tol, step_tol=step_tol,
                       predicted_first=True)
    out = core.minimise(_One(problem), alpha[None], rules, scale=scale[None])
    return out.x[0], int(out.iterations[0]), bool(out.converged[0])


def _controllability(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    cols = [b]
    for _ in range(A.shape[0] - 1):
        cols.append(A @ cols[-1])
    return np.stack(cols, axis=1)


# Why numpy (measured on a loaded 2-core machine, load average ~3, OMP_NUM_THREADS=1, 1,000
# samples, one delay, warm caches, from a 10 % perturbed start, 2 % noise; median of 20):
#   order 2: separable 3.7 ms (5 iterations)  vs CasADi refine_record 6.8 ms (5 iterations)
#   order 4: separable 8.4 ms (13 iterations) vs CasADi refine_record 46 ms (13 iterations)
# both reaching the same cost (tests/test_refine_separable.py checks it to 1e-8 relative).
def refine_separable(den, y, u, dt: float = 1.0, *, delay: int = 0, feedthrough: bool = True,
                     offset: bool = True, max_iter: int = 100, cost_tol: float = 1e-10,
                     step_tol: float = 1e-10, intersample: str = "foh") -> Estimate:
    """Refine a free CCF (denominator and, by projection, ``c, d, x_0, y_offset``) on a whole
    record by separable least squares (module docstring).

    Parameters
    ----------
    den : (n + 1,) array
        Monic start denominator in the time unit of ``dt``, highest power first.
    y, u : (steps,) arrays
        The record (checked by the caller), ``u`` linear between samples (held for
        ``intersample="zoh"``).
    dt : float, > 0
        Sample time; the refinement runs in normalised time (``alpha_j dt^(n-j)``).
    delay : int
        Input delay in samples: ``y[delay:]`` against ``u[:steps - delay]``.
    feedthrough, offset : bool
        Fit ``d`` and a constant output offset (else 0).
    max_iter : int, >= 1
    cost_tol : float
        Stop when an accepted step lowers the cost by less than this fraction.
    step_tol : float
        Stop when a step changes every ``alpha_j`` by less than this fraction.
    intersample : {"foh", "zoh"}
        The input between samples (``records.Record.intersample``).

    Returns
    -------
    Estimate
        As :func:`~aeid_struct.refinement.refine_record`'s for ``CCF(n, feedthrough)``:
        ``elements`` ``a_j, c_j`` (and ``d``) in the time unit of ``dt``, ``A, b, c, d`` that
        CCF, ``x0`` its state at sample ``delay``; ``info["cost"]`` normalised
        (``(1 - fit / 100)^2``).

    Raises
    ------
    ValueError
        Naming the argument: a denominator that is not monic and finite, ``y`` and ``u`` of
        other shapes, a bad ``dt``, ``delay`` or ``max_iter``.
    """
    t0 = time.perf_counter()
    y, u, den = as_arrays(y, u, den)
    if y.ndim != 1 or u.shape != y.shape:
        raise ValueError(f"y and u must have the same shape (steps,); got {y.shape} and "
                         f"{u.shape}")
    if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive finite number; got {dt!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1; got {max_iter!r}")
    if intersample not in INTERSAMPLE:
        raise ValueError(f"intersample must be one of {', '.join(map(repr, INTERSAMPLE))}; "
                         f"got {intersample!r}")
    check_arguments(den, y, delay)
    n = den.shape[0] - 1
    powers = float(dt) ** np.arange(n + 1)
    problem = Problem(y, u, int(delay), bool(feedthrough), bool(offset), intersample)
    alpha = (den * powers)[:0:-1].copy()
    alpha, iterations, converged = _levenberg_marquardt(problem, alpha, int(max_iter),
                                                        float(cost_tol), float(step_tol))
    den_n = np.concatenate([[1.0], alpha[::-1]])
    return _result(den_n, y, u, float(dt), int(delay), feedthrough, offset, iterations,
                   converged, t0, intersample)


@functools.lru_cache(maxsize=32)
def _ccf_structure(n: int, feedthrough: bool) -> CCF:
    """The free CCF an estimate of order ``n`` is in (one object per order: a structure is
    immutable, and building one costs as much as the rest of the result)."""
    return CCF(n, feedthrough=feedthrough)


def _result(den_n, y, u, dt, delay, feedthrough, offset, iterations, converged, t0,
            intersample):
    """The Estimate of the normalised denominator ``den_n``: ``project`` for the
    linear part, then the physical-time CCF (``a_j / dt^(n-j)``, the state transformed)."""
    n = den_n.shape[0] - 1
    An = np.zeros((n, n))
    An[np.arange(n - 1), np.arange(1, n)] = 1.0
    An[-1] = -den_n[:0:-1]
    bn = np.eye(n)[-1]
    p = project(An, bn, y, u, 1.0, delay=delay, feedthrough=feedthrough, offset=offset,
                intersample=intersample)
    den = den_n / dt ** np.arange(n + 1)
    As = np.zeros((n, n))
    As[np.arange(n - 1), np.arange(1, n)] = 1.0
    As[-1] = -den[:0:-1]
    # the model (An / dt, bn / dt, c, d) in the physical CCF: x = T x_n
    T = _controllability(As, bn) @ np.linalg.inv(_controllability(An / dt, bn / dt))
    c = np.linalg.solve(T.T, p.c)
    used = y[delay:]
    spread = float(np.sum((used - used.mean()) ** 2))
    cost = p.cost * used.shape[0] / spread if spread > 0 else p.cost
    names = [f"a{i}" for i in range(n)] + [f"c{i}" for i in range(n)]
    values = list(den[:0:-1]) + list(c)
    if feedthrough:
        names.append("d")
        values.append(p.d)
    return fitted(_ccf_structure(n, bool(feedthrough)), (As, bn, c, float(p.d)),
                  {k: float(v) for k, v in zip(names, values, strict=True)}, y, u, dt,
                  seconds=time.perf_counter() - t0, method="refine_separable", delay=delay,
                  x0=T @ p.x0, y_offset=p.y_offset, fit=float(p.fit), y_hat=p.y_hat,
                  cost=float(cost), iterations=iterations, converged=converged,
                  intersample=intersample)
