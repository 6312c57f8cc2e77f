r"""The refinement NLP: the output-error problem of one record in a structure's elements.

For a record ``y, u (steps,)`` at ``t_k = k dt`` and the structure's free elements ``x``,

    min_x  J(x) = 1/(m+1) sum_k (y~_k - yhat~_k(x))^2,   y~ = 2 y / y_bar - 1,  y_bar = max|y|
    s.t.   lo_i <= x_i <= hi_i            (Structure.element_bounds)

with ``m = steps``: the paper's loss (Eq. 14, ``gamma = 0``) on the normalised record (Eq. 15).
By linearity the NLP's parameters are ``w y`` and ``w u`` with ``w = 2 / (y_bar sqrt(m + 1))``,
its residuals ``r = w y - yhat(w u)`` and ``J = sum_k r_k^2``. ``yhat`` is the decoder's exact
first-order-hold response (Eq. 10-13) unrolled as one CasADi graph
(``simulation.casadi_simulate``, with Higham's Pade [13/13] ``simulation.expm``); a record that
starts mid-motion has its least-squares initial state projected out (variable projection).
Decision variables are the free elements in relative units ``x_i = s_i z_i``; the Hessian is
the Gauss-Newton ``2 (J^T J + mu I)``.

Problems are built once per (structure, steps, dt, squarings, config, initial) and kept in a small
LRU cache (:func:`cache_info`, :func:`clear_cache`); they are evaluated through CasADi's numeric
buffers (:class:`Numeric`): refine from one thread at a time. The design and its measurements:
docs/architecture.md.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from dataclasses import dataclass

import casadi
import numpy as np

from aeid_struct.refinement.config import SOLVERS, CacheInfo, RefineConfig
from aeid_struct.simulation import THETA13, casadi_simulate, expm, squarings_for
from aeid_struct.structures import Numeric, Structure

__all__ = ["SOLVERS", "THETA13", "Numeric", "assembly", "build", "cache_info", "cached",
           "casadi_simulate", "clear_cache", "expm", "problem", "structure_key"]

#: Relative Levenberg floor of the Gauss-Newton Hessian ``2 (J^T J + mu I)``.
_DAMPING = 1e-12
#: Solvers kept in the cache.
_CACHE_SIZE = 32


# ---------------------------------------------------------------------------------------------
# Building the NLP (cached)
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Problem:
    """A built problem in the variables ``z`` with parameters ``p = [s; w y; w u]``."""

    loss: Numeric              # (z, p) -> (J, ||M||_1)
    solver: Numeric            # nlpsol: (x0 = z, p, lbx, ubx) -> (z*, J*, ...)


@dataclass(frozen=True)
class _Assembly:
    """Per structure: numeric assembly, bounds and fixed values, in element order."""

    system: Numeric            # x (q) -> A (column-major), b, c, d, ||M||_1 (needs dt)
    lo: np.ndarray
    hi: np.ndarray
    fixed: np.ndarray           # bool (q,)
    values: np.ndarray          # fixed values (q,), 0 where free


class _Cache:
    """A small LRU cache of built problems with build / hit counters."""

    def __init__(self, size: int) -> None:
        self.size, self.items, self.builds, self.hits = size, OrderedDict(), 0, 0

    def get(self, key, build):
        if key in self.items:
            self.items.move_to_end(key)
            self.hits += 1
            return self.items[key]
        value = build()
        self.builds += 1
        self.items[key] = value
        if len(self.items) > self.size:
            self.items.popitem(last=False)
        return value


_PROBLEMS = _Cache(_CACHE_SIZE)
_ASSEMBLIES = _Cache(_CACHE_SIZE)


def cache_info() -> CacheInfo:
    """Counters of the solver cache (NLP solvers built and reused).

    Returns
    -------
    CacheInfo
    """
    return CacheInfo(builds=_PROBLEMS.builds, hits=_PROBLEMS.hits, size=len(_PROBLEMS.items))


def cached(key, build):
    """The value kept under ``key`` in the solver cache, built by ``build()`` on a miss.

    Shared with other builders of the package (``record.py``), so that :func:`cache_info`
    counts and :func:`clear_cache` empties every built graph.

    Parameters
    ----------
    key : hashable
        Unique among all cached problems (lead it with the builder's name).
    build : callable
        ``build() -> value``, called only on a miss.

    Returns
    -------
    object
        The cached value.
    """
    return _PROBLEMS.get(key, build)


def clear_cache() -> None:
    """Empty the solver cache and reset its counters."""
    for cache in (_PROBLEMS, _ASSEMBLIES):
        cache.items.clear()
        cache.builds = cache.hits = 0


def _norm_1(A, b, dt: float):
    """``||M||_1`` of Eq. 10's matrix (max column sum) as a CasADi expression:
    ``max(max_j sum_i |A_ij| dt, sum_i |b_i| dt, 1)`` (the last column holds the single 1)."""
    cols = casadi.sum1(casadi.fabs(A)) * dt
    return casadi.fmax(casadi.fmax(casadi.mmax(cols), casadi.sum1(casadi.fabs(b)) * dt), 1.0)


def structure_key(structure: Structure) -> str:
    """The cache key of a structure: its configuration as canonical JSON.

    Parameters
    ----------
    structure : Structure

    Returns
    -------
    str
    """
    return json.dumps(structure.config(), sort_keys=True)


def assembly(structure: Structure, key: str) -> _Assembly:
    """The numeric assembly ``x (q) -> A, b, c, d, ||M||_1`` of a structure, with its bounds
    and fixed values in element order (cached by ``key``, :func:`structure_key`).

    Parameters
    ----------
    structure : Structure
    key : str

    Returns
    -------
    _Assembly
        ``system`` (a :class:`Numeric` of ``x, dt``), ``lo, hi, values (q,)``, ``fixed (q,)``
        bool.
    """
    def build_assembly():
        x = casadi.SX.sym("x", structure.q)
        dt = casadi.SX.sym("dt")
        A, b, c, d = structure.casadi_system(x)
        outputs = [casadi.densify(v) for v in (A, b, c, d, _norm_1(A, b, dt))]
        system = Numeric(casadi.Function("system", [x, dt], outputs, ["x", "dt"],
                                         ["A", "b", "c", "d", "norm_M"]))
        bounds = structure.element_bounds()
        fixed = structure.fixed_values
        names = structure.element_names
        return _Assembly(
            system=system,
            lo=np.array([bounds[nm][0] for nm in names]),
            hi=np.array([bounds[nm][1] for nm in names]),
            fixed=np.array([nm in fixed for nm in names]),
            values=np.array([fixed.get(nm, 0.0) for nm in names]),
        )

    return _ASSEMBLIES.get(key, build_assembly)


def _model(structure: Structure, z, scale):
    """``A, b, c, d`` of the elements with the free ones ``scale * z`` (fixed elements are
    constants of the graph, so they stay exact)."""
    fixed = structure.fixed_values
    cols, j = [], 0
    for nm in structure.element_names:
        if nm in fixed:
            cols.append(casadi.DM(fixed[nm]))
        else:
            cols.append(scale[j] * z[j])
            j += 1
    return structure.casadi_system(casadi.vertcat(*cols))


def _residual(model, y, u, dt: float, squarings: int, n: int, initial: str):
    """``r = y - yhat`` (records scaled by ``w``, so that this is the normalised residual)."""
    A, b, c, d = model
    if initial != "fitted":
        return y - casadi_simulate(A, b, c, d, u, dt, squarings=squarings)
    # Variable projection: the record starts mid-motion, and the initial state that fits best
    # is linear least squares for every z (simulation.initial_state). Projecting it out keeps
    # the NLP in the structure's elements alone, with the exact Jacobian of the projected
    # residual (Golub & Pereyra).
    y_forced, O = casadi_simulate(A, b, c, d, u, dt, squarings=squarings, free=True)
    e = y - y_forced
    G = O.T @ O
    # The normal equations with their columns scaled to unit norm (Jacobi): a companion form's
    # free-response columns differ by decades (a quarter car's by 1e8), and a ridge relative to
    # the trace of the unscaled G bent the projection of the small ones, the loss 7e-4 off
    # the least-squares projection's; scaled, the ridge only keeps the solve defined as O -> 0.
    s = 1.0 / casadi.sqrt(casadi.diag(G) + 1e-300)
    Gs = G * (s @ s.T)
    ridge = 1e-12 * n
    return e - O @ (s * casadi.solve(Gs + ridge * casadi.SX.eye(n), s * (O.T @ e)))


def _gauss_newton(r, z):
    """The Gauss-Newton Hessian ``2 (J^T J + mu I)``, ``J = dr/dz``,
    ``mu = _DAMPING trace(J^T J) / p``: positive definite, exact at a zero residual."""
    nz = z.shape[0]
    J = casadi.jacobian(r, z)
    # J^T J from its upper triangle (symmetric): p (p + 1) / 2 dot products instead of p^2.
    JTJ = casadi.SX(nz, nz)
    for i in range(nz):
        for j in range(i, nz):
            JTJ[i, j] = JTJ[j, i] = casadi.dot(J[:, i], J[:, j])
    mu = _DAMPING * casadi.trace(JTJ) / max(nz, 1) + 1e-300
    return 2.0 * (JTJ + mu * casadi.SX.eye(nz))


def _solver_options(config: RefineConfig, hess_args: list, H) -> dict:
    """``nlpsol`` options of ``config.solver`` with the Gauss-Newton Hessian ``H``."""
    verbose, lam_f = config.verbose, hess_args[2]
    names = ["x", "p", "lam_f", "lam_g"]
    if config.solver == "ipopt":
        hess = casadi.Function("nlp_hess_l", hess_args, [casadi.triu(lam_f * H)], names,
                               ["triu_hess_gamma_x_x"])
        return {"hess_lag": hess, "print_time": verbose, "error_on_fail": False,
                "show_eval_warnings": verbose,
                "ipopt": {"print_level": 5 if verbose else 0, "sb": "yes", "tol": config.tol,
                          "max_iter": config.max_iter, "bound_relax_factor": 0.0}}
    hess = casadi.Function("nlp_hess_l", hess_args, [lam_f * H], names, ["hess_gamma_x_x"])
    return {
        "hess_lag": hess,
        "qpsol": "qrqp",
        "qpsol_options": {"print_iter": False, "print_header": False, "print_info": False,
                          "error_on_fail": False},
        "max_iter": config.max_iter,
        "tol_du": config.tol,
        "tol_pr": config.tol,
        "min_step_size": config.step_tol,
        "print_time": verbose,
        "print_header": verbose,
        "print_iteration": verbose,
        "print_status": verbose,
        "error_on_fail": False,
        # A trial step into a region where the model blows up gives NaN; the solver backs off
        # by itself, so CasADi's evaluation warnings are noise unless asked for.
        "show_eval_warnings": verbose,
    }


def build(structure: Structure, steps: int, dt: float, squarings: int,
          config: RefineConfig, initial: str = "rest") -> _Problem:
    """Build the NLP of one record format (uncached; :func:`problem` caches it).

    Parameters
    ----------
    structure : Structure
    steps : int
        Samples per record.
    dt : float > 0
    squarings : int >= 0
        Squarings of the matrix exponential, fixed in the graph.
    config : RefineConfig
    initial : {"rest", "fitted"}
        ``"fitted"`` projects the least-squares initial state out of the residual.

    Returns
    -------
    _Problem
        ``loss`` ``(z, p) -> (J, ||M||_1)`` and ``solver`` ``(z0, p, lbz, ubz) -> z*``, with
        ``p = [s; w y; w u]``.
    """
    free = [nm for nm in structure.element_names if nm not in structure.fixed_values]
    z = casadi.SX.sym("z", len(free))
    scale = casadi.SX.sym("scale", len(free))
    y = casadi.SX.sym("y", steps)
    u = casadi.SX.sym("u", steps)
    model = _model(structure, z, scale)
    r = _residual(model, y, u, dt, squarings, structure.n, initial)
    f = casadi.sumsqr(r)
    p = casadi.vertcat(scale, y, u)
    loss = Numeric(casadi.Function("loss", [z, p], [f, _norm_1(model[0], model[1], dt)],
                                   ["z", "p"], ["J", "norm_M"]))
    hess_args = [z, p, casadi.SX.sym("lam_f"), casadi.SX.sym("lam_g", 0)]
    options = _solver_options(config, hess_args, _gauss_newton(r, z))
    solver = casadi.nlpsol("refine", config.solver, {"x": z, "p": p, "f": f}, options)
    return _Problem(loss=loss, solver=Numeric(solver))


def problem(structure, key: str, steps: int, dt: float, squarings: int,
            config: RefineConfig, initial: str = "rest") -> _Problem:
    """The cached :func:`build` of a record format (``key``: :func:`structure_key`).

    Parameters
    ----------
    structure : Structure
    key : str
    steps, dt, squarings, config, initial
        As for :func:`build`.

    Returns
    -------
    _Problem
    """
    return _PROBLEMS.get((key, steps, dt, squarings, config, initial),
                         lambda: build(structure, steps, dt, squarings, config, initial))


#: The fewest squarings for a bound on ||M||_1 (``simulation.squarings_for``; solve.py uses it).
fewest_squarings = squarings_for
