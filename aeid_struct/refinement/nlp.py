r"""Refinement: polish an estimate with a CasADi NLP in the same structure and constraints.

Problem
-------
For one record ``y, u (steps,)`` sampled at ``t_k = k dt`` from rest and a start vector of the
structure's elements, solve

    min_x  J(x) = 1/(m+1) sum_k (y~_k - yhat~_k(x))^2,   y~ = 2 y / y_bar - 1,  y_bar = max|y|
    s.t.   lo_i <= x_i <= hi_i            (Structure.element_bounds)

over the *free* elements; ``m = steps``. ``J`` is the paper's loss (Eq. 14) on the normalised
record (Eq. 15), so tolerances and the reported losses are scale-free. The stationary-value
term of Eq. 14 is left out (``gamma = 0``): a measured record does not come with its true final
value. Because ``y~ - yhat~ = 2 (y - yhat) / y_bar`` and the response is linear in the input,
``w yhat(u) = yhat(w u)``: with ``w = 2 / (y_bar sqrt(m + 1))`` the NLP's parameters are
``w y`` and ``w u``, its residuals ``r = w y - yhat(w u)`` and ``J = sum_k r_k^2``.

``yhat`` is the exact first-order-hold simulation of the decoder (Eq. 10-13) from ``x_0 = 0``::

    expm([[A dt, b dt, 0], [0, 0, 1], [0, 0, 0]]) = [[Phi, gamma1, gamma2], [0, 1, 1], [0, 0, 1]]
    x_{k+1} = Phi x_k + gamma1 u_k + gamma2 (u_{k+1} - u_k),    yhat_k = c^T x_k + d u_k,

unrolled over the record as one CasADi expression graph (:func:`casadi_simulate`).

Constraints
-----------
The structure is kept exactly: ``A, b, c, d`` are assembled from the elements by
:meth:`Structure.casadi_system` (the same assembly as the torch path), fixed elements are
constants of the graph (not decision variables), and every constraint map becomes a bound on its
element: Descartes ``a_i >= 0``; MCF ``lambda_i, delta_j <= -1e-8``, ``omega_j >= 1e-8`` (the
maps' margin, so the result is Hurwitz); physical ``lo <= p <= hi``. Working on elements rather
than on the raw softplus / sigmoid parameters keeps the problem well conditioned near the
boundary (where a sigmoid's derivative vanishes) and lets bounds be active. The solution is
clipped into the bounds (a QP solver may miss one by a rounding error).

Decision variables are the free elements in relative units, ``x_i = s_i z_i`` with
``s_i = max(|x0_i|, 1e-2 max_j |x0_j|)`` (``x0`` the start). ``s`` is an NLP parameter, so one
solver serves every scale; the tolerance ``RefineConfig.tol`` is then on the gradient of ``J``
with respect to relative changes of the elements.

Matrix exponential
------------------
CasADi has no ``expm`` plugin, so :func:`expm` is Higham's (2005) scaling and squaring with the
diagonal Pade approximant of degree 13, written with CasADi operations: with
``||M / 2^s||_1 <= theta_13 = 5.37`` its backward error is below the unit roundoff. The number of
squarings ``s`` is part of the graph, so it is fixed when a problem is built, from the start's
``||M(x0)||_1`` with a margin of 8 (three spare doublings), and is part of the solver cache key.
After the solve the bound is checked at the solution; if the iterates went further
(``||M(x*)||_1 > theta_13 2^s``), the problem is rebuilt with enough squarings and re-solved from
``x*``. So every reported loss, and the accept/reject decision below, uses an exponential accurate
to rounding. Spare squarings cost nothing measurable: for orders 1-8 and ``||M||_1 <= 5`` the
result differs from a 40-digit mpmath ``expm`` by <= 5e-15 relative with up to 3 extra squarings
(scipy's ``expm`` by up to 2e-13 there).

Solver (chosen by measurement)
------------------------------
Gauss-Newton SQP: CasADi's ``sqpmethod`` with the ``qrqp`` QP solver and the Hessian of the
Lagrangian replaced (option ``hess_lag``) by ``2 (J^T J + mu I)``, ``J = dr/dz``,
``mu = 1e-12 trace(J^T J) / p``: positive definite, exact at a zero-residual solution (so the
convergence is quadratic on noise-free data), and the tiny ``mu`` keeps the QP well posed for an
element the record does not determine (``d`` of the unstable leg) without moving it. Bounds are
the QP's bounds, the line search keeps each step a descent step.

Measured on the robot leg (``CCF(2, descartes=True)`` stable, ``CCF(2)`` unstable; noise-free
unit-step records; solver already built; median over 40 starts, or 60 random leg systems for
the pretrained start; one thread on a 2-core machine whose two cores were both busy with other
jobs during the measurement, so an idle core is faster; ranges over repeated runs)::

                                          stable (300 samples)     unstable (100 samples)
    start 1 % off          (3 iterations)  1.2 - 1.4 ms              0.65 - 1.0 ms
    start 15 % off         (4-5 it.)       1.6 - 1.9 ms              0.75 - 1.1 ms
    pretrained encoder     (2 it.)         1.1 - 1.4 ms              0.8 - 1.1 ms
      (``refine`` of the Estimate; start errors median 1.5e-4 / 4.6e-3, max 0.04 relative)

Parameter errors after refinement <= 3e-12 (stable) and 2e-10 (unstable) relative. Building a
solver takes 0.12 s (stable) / 0.05 s (unstable). Alternatives, measured the same way:
``ipopt`` with the same Gauss-Newton Hessian 4.0 / 6.0 ms (stable, 1 % / 15 %), 3.1 / 3.4 ms
(unstable), 4.3 ms from the pretrained start (its barrier stops at parameter errors ~2e-11);
``ipopt`` with the exact Hessian 4.2 / 5.4 ms; ``sqpmethod`` with the exact (regularised)
Hessian did not converge in 50 iterations; a hand-written projected Gauss-Newton loop on the
same CasADi functions (one fused residual-Jacobian function, ``qrqp`` box QP, Armijo search)
was within +-10 % of ``sqpmethod`` when interleaved, so the library's SQP was kept. The time
is the SX virtual machine evaluating the unrolled graph (stable leg: 6.7k instructions for
``J``, 27.6k for the Gauss-Newton Hessian, 16.4k for the gradient, per iteration);
CasADi's JIT (gcc -O1) evaluates the Hessian 4.5x faster but compiles for 12 s per solver.
``RefineConfig(solver="ipopt")`` remains available (print level 0, no bound relaxation).

Guarantees
----------
The result never has a higher loss than its start: both are evaluated with the same exact
graph, and if the solver's point is worse (or not finite, or the solver raised), the start is
returned with ``success = False``. ``success`` is CasADi's own convergence flag (for
``sqpmethod`` also a step below ``RefineConfig.step_tol``, status
``Search_Direction_Becomes_Too_Small``), and only when the result was kept.

Noise and the choice of structure
---------------------------------
The refinement returns the least-squares model *in the given structure*; on noisy records that
is only as good as the structure is tight. Measured on 30 random unstable-leg records with 1 %
noise (of ``max|y|``), starting from the pretrained encoder: median ``|k|`` error of the encoder
5.2 %, after refining in ``CCF(2)`` 60 % (the four free coefficients fit the noise in the early,
tiny part of the growing response: lower loss, worse physics), in
``CCF(2).fixed(a1=0.0, c1=0.0)`` 1.4 %, in ``Physical(unstable_map, bounds=...)`` 1.2 %. On the
stable leg, ``CCF(2, descartes=True)`` refines to a median ``|k|`` error of 0.1 % under the same
noise.

Caching
-------
Solvers are built once per (structure configuration, steps, dt, squarings, config) and kept in
a small LRU cache (:func:`cache_info`, :func:`clear_cache`): the records enter as parameters.
Cached solvers are evaluated through CasADi's numeric buffers (no DM conversions, see
``_Numeric``), one buffer per solver: refine from one thread at a time.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections import OrderedDict
from dataclasses import dataclass

import casadi
import numpy as np

from aeid_struct.identification import Estimate
from aeid_struct.records import as_array, require_finite
from aeid_struct.simulation import casadi_simulate as casadi_simulate
from aeid_struct.simulation import check_dt as _check_dt
from aeid_struct.simulation import expm as expm
from aeid_struct.simulation import squarings_for as _squarings
from aeid_struct.structures import Structure

__all__ = [
    "CacheInfo",
    "RefineConfig",
    "RefineResult",
    "cache_info",
    "casadi_simulate",
    "clear_cache",
    "expm",
    "refine",
    "refine_elements",
]

SOLVERS = ("sqpmethod", "ipopt")

#: Headroom of the squarings over the start's ||M||_1 (three spare doublings).
_NORM_MARGIN = 8.0
#: Relative Levenberg floor of the Gauss-Newton Hessian (see the module docstring).
_DAMPING = 1e-12
#: How many times the squarings may be raised and the problem re-solved.
_MAX_RESOLVES = 3
#: Solvers kept in the cache.
_CACHE_SIZE = 32


# ---------------------------------------------------------------------------------------------
# Configuration and results
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, kw_only=True)
class RefineConfig:
    """How to refine; validates itself.

    Attributes:
        solver: ``"sqpmethod"`` (the default: CasADi's SQP with a Gauss-Newton Hessian and the
            ``qrqp`` QP solver, the fastest, see the module docstring) or ``"ipopt"`` (interior
            point, same Hessian).
        max_iter: at most this many solver iterations per record (>= 1).
        tol: convergence tolerance on the gradient of ``J`` with respect to relative element
            changes: ``sqpmethod``'s ``tol_du`` and ``tol_pr``, ``ipopt``'s ``tol``.
        step_tol: ``sqpmethod`` also stops, converged, when its step changes no element by more
            than this, relatively (its ``min_step_size``): the Gauss-Newton step vanishes at a
            stationary point, also where noise keeps the gradient from reaching ``tol`` in the
            few iterations its linear convergence there allows.
        verbose: print the solver's iterations; silent otherwise.
    """

    solver: str = "sqpmethod"
    max_iter: int = 100
    tol: float = 1e-12
    step_tol: float = 1e-10
    verbose: bool = False

    def __post_init__(self) -> None:
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}; got {self.solver!r}")
        if (isinstance(self.max_iter, bool) or not isinstance(self.max_iter, (int, np.integer))
                or self.max_iter < 1):
            raise ValueError(f"max_iter must be an integer >= 1; got {self.max_iter!r}")
        for name in ("tol", "step_tol"):
            v = getattr(self, name)
            if (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                    or v <= 0):
                raise ValueError(f"{name} must be a finite number > 0; got {v!r}")
            object.__setattr__(self, name, float(v))
        if not isinstance(self.verbose, bool):
            raise ValueError(f"verbose must be a bool; got {self.verbose!r}")
        object.__setattr__(self, "max_iter", int(self.max_iter))


@dataclass(frozen=True)
class RefineResult:
    """The refinement of one record.

    Attributes:
        elements: ``(q,)`` float64, all elements in ``structure.element_names`` order (fixed
            ones at exactly their values), inside ``structure.element_bounds()``.
        loss_start, loss: ``J`` (Eq. 14, normalised record, ``gamma = 0``) at the start (after
            clipping it into the bounds) and at ``elements``; ``loss <= loss_start`` always.
        iterations: solver iterations (summed over re-solves).
        success: the solver converged and its result was kept.
        seconds: wall time of the refinement.
        solver: the NLP solver used.
        status: the solver's return status, or why the start was kept.
        squarings: the squarings of the matrix exponential at the result.
    """

    elements: np.ndarray
    loss_start: float
    loss: float
    iterations: int
    success: bool
    seconds: float
    solver: str
    status: str
    squarings: int


@dataclass(frozen=True)
class CacheInfo:
    """Solver cache counters: ``builds`` (solvers built), ``hits`` (reused), ``size`` (kept)."""

    builds: int
    hits: int
    size: int


# ---------------------------------------------------------------------------------------------
# Building the NLP (cached)
# ---------------------------------------------------------------------------------------------
class _Numeric:
    """Numeric evaluation of a ``casadi.Function`` through its buffer.

    Why: a Python call of a CasADi Function converts every numpy argument to a DM and every
    result back, ~20 us per call plus ~40 us per numpy argument (measured, CasADi 3.8), which
    would dominate a refinement of ~1 ms; the buffer reads and writes numpy memory directly
    (~10 us per call). Arguments must be contiguous float64 vectors of the inputs' sizes
    (CasADi's column-major order); results come back as flat float64 arrays.
    """

    def __init__(self, function: casadi.Function) -> None:
        self.function = function
        self.buffer, self.eval = function.buffer()
        self.sizes = [function.nnz_out(i) for i in range(function.n_out())]

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        out = [np.empty(k) for k in self.sizes]
        for i, a in enumerate(args):
            self.buffer.set_arg(i, memoryview(a))
        for i, r in enumerate(out):
            self.buffer.set_res(i, memoryview(r))
        self.eval()
        return out

    def stats(self) -> dict:
        return self.buffer.stats()


@dataclass(frozen=True)
class _Problem:
    """A built problem in the variables ``z`` with parameters ``p = [s; w y; w u]``."""

    loss: _Numeric              # (z, p) -> (J, ||M||_1)
    solver: _Numeric            # nlpsol: (x0 = z, p, lbx, ubx) -> (z*, J*, ...)


@dataclass(frozen=True)
class _Assembly:
    """Per structure: numeric assembly, bounds and fixed values, in element order."""

    system: _Numeric            # x (q) -> A (column-major), b, c, d, ||M||_1 (needs dt)
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
    """Counters of the solver cache (NLP solvers built and reused)."""
    return CacheInfo(builds=_PROBLEMS.builds, hits=_PROBLEMS.hits, size=len(_PROBLEMS.items))


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


def _assembly(structure: Structure, key: str) -> _Assembly:
    def build():
        x = casadi.SX.sym("x", structure.q)
        dt = casadi.SX.sym("dt")
        A, b, c, d = structure.casadi_system(x)
        outputs = [casadi.densify(v) for v in (A, b, c, d, _norm_1(A, b, dt))]
        system = _Numeric(casadi.Function("system", [x, dt], outputs, ["x", "dt"],
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

    return _ASSEMBLIES.get(key, build)


def _build(structure: Structure, steps: int, dt: float, squarings: int,
           config: RefineConfig, initial: str = "rest") -> _Problem:
    names = structure.element_names
    fixed = structure.fixed_values
    free = [nm for nm in names if nm not in fixed]
    z = casadi.SX.sym("z", len(free))
    scale = casadi.SX.sym("scale", len(free))
    y = casadi.SX.sym("y", steps)
    u = casadi.SX.sym("u", steps)
    cols, j = [], 0
    for nm in names:
        if nm in fixed:
            cols.append(casadi.DM(fixed[nm]))  # a constant: fixed elements stay exact
        else:
            cols.append(scale[j] * z[j])
            j += 1
    A, b, c, d = structure.casadi_system(casadi.vertcat(*cols))
    # y and u come scaled by w = 2 / (y_bar sqrt(m + 1)), so that r = y - y_hat (linearity).
    if initial == "fitted":
        # Variable projection: the record starts mid-motion, and the initial state that fits
        # best is linear least squares for every z (decoder.initial_state). Projecting it out
        # keeps the NLP in the structure's elements alone, with the exact Jacobian of the
        # projected residual (Golub & Pereyra).
        y_forced, O = casadi_simulate(A, b, c, d, u, dt, squarings=squarings, free=True)
        e = y - y_forced
        G = O.T @ O
        ridge = 1e-12 * casadi.trace(G) + 1e-300      # keeps the solve defined as O -> 0
        r = e - O @ casadi.solve(G + ridge * casadi.SX.eye(structure.n), O.T @ e)
    else:
        r = y - casadi_simulate(A, b, c, d, u, dt, squarings=squarings)
    f = casadi.sumsqr(r)
    p = casadi.vertcat(scale, y, u)
    # The Gauss-Newton Hessian 2 (J^T J + mu I), see the module docstring.
    nz = len(free)
    J = casadi.jacobian(r, z)
    # J^T J from its upper triangle (symmetric): p (p + 1) / 2 dot products instead of p^2.
    JTJ = casadi.SX(nz, nz)
    for i in range(nz):
        for j in range(i, nz):
            JTJ[i, j] = JTJ[j, i] = casadi.dot(J[:, i], J[:, j])
    mu = _DAMPING * casadi.trace(JTJ) / max(nz, 1) + 1e-300
    H = 2.0 * (JTJ + mu * casadi.SX.eye(nz))
    loss = _Numeric(casadi.Function("loss", [z, p], [f, _norm_1(A, b, dt)], ["z", "p"],
                                    ["J", "norm_M"]))
    verbose = config.verbose
    lam_f, lam_g = casadi.SX.sym("lam_f"), casadi.SX.sym("lam_g", 0)
    nlp = {"x": z, "p": p, "f": f}
    if config.solver == "sqpmethod":
        hess = casadi.Function("nlp_hess_l", [z, p, lam_f, lam_g], [lam_f * H],
                               ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])
        options = {
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
            # A trial step into a region where the model blows up gives NaN; the solver backs
            # off by itself, so CasADi's evaluation warnings are noise unless asked for.
            "show_eval_warnings": verbose,
        }
    else:
        hess = casadi.Function("nlp_hess_l", [z, p, lam_f, lam_g], [casadi.triu(lam_f * H)],
                               ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
        options = {
            "hess_lag": hess,
            "print_time": verbose,
            "error_on_fail": False,
            "show_eval_warnings": verbose,
            "ipopt": {"print_level": 5 if verbose else 0, "sb": "yes", "tol": config.tol,
                      "max_iter": config.max_iter, "bound_relax_factor": 0.0},
        }
    solver = casadi.nlpsol("refine", config.solver, nlp, options)
    return _Problem(loss=loss, solver=_Numeric(solver))


def _problem(structure, key: str, steps: int, dt: float, squarings: int,
             config: RefineConfig, initial: str = "rest") -> _Problem:
    return _PROBLEMS.get((key, steps, dt, squarings, config, initial),
                         lambda: _build(structure, steps, dt, squarings, config, initial))


def _structure_key(structure: Structure) -> str:
    return json.dumps(structure.config(), sort_keys=True)


# ---------------------------------------------------------------------------------------------
# Refinement of one record from an element vector
# ---------------------------------------------------------------------------------------------
def _record(name: str, value, steps: int | None = None) -> np.ndarray:
    arr = as_array(name, value)
    want = "(steps,)" if steps is None else f"({steps},) like y"
    if arr.ndim != 1 or arr.shape[0] < 1 or (steps is not None and arr.shape[0] != steps):
        raise ValueError(f"{name} must have shape {want}; got {arr.shape}")
    require_finite(name, arr)
    return arr


def _start_vector(structure: Structure, x0) -> np.ndarray:
    names = structure.element_names
    if isinstance(x0, dict):
        missing = [nm for nm in names if nm not in x0]
        if missing:
            raise ValueError(f"x0 is missing the element(s) {', '.join(missing)} of "
                             f"{structure!r}; elements: {', '.join(names)}")
        x0 = [x0[nm] for nm in names]
    try:
        x = np.array(x0, dtype=np.float64).reshape(-1) if np.ndim(x0) <= 1 else None
    except (TypeError, ValueError):
        raise ValueError(f"x0 must be a sequence of {structure.q} numbers or a dict name -> "
                         f"value; got {type(x0).__name__}") from None
    if x is None or x.shape != (structure.q,):
        raise ValueError(f"x0 must have shape ({structure.q},) for {structure!r} (elements "
                         f"{', '.join(names)}); got {np.shape(x0)}")
    if not np.all(np.isfinite(x)):
        i = int(np.flatnonzero(~np.isfinite(x))[0])
        raise ValueError(f"x0 must be finite; got {x[i]} for element {names[i]}")
    return x


def refine_elements(structure: Structure, x0, y, u, dt: float,
                    config: RefineConfig = RefineConfig(),  # noqa: B008
                    initial: str = "rest") -> RefineResult:
    """Refine one record from any start vector of elements (see the module docstring).

    Parameters
    ----------
    structure : Structure
        The structure whose elements are refined; its constraints hold for the result.
    x0 : (q,) numbers or dict name -> value
        Start, all elements in ``structure.element_names`` order. Fixed elements must hold their
        fixed values (to ``1e-6`` relative: a float32 start is fine) and are set exactly; free
        ones outside ``structure.element_bounds()`` are clipped into them.
    y : (steps,)
        The measured output at ``t_k = k dt`` from rest; not all zero.
    u : (steps,) or None
        The input (linear between samples); None means a unit step.
    dt : float > 0
    config : RefineConfig
    initial : "rest" or "fitted"
        ``"fitted"``: the record may start mid-motion; its initial state is fitted by least
        squares for every candidate (projected out of the NLP).

    Returns
    -------
    RefineResult
    """
    start = time.perf_counter()
    if not isinstance(structure, Structure):
        raise ValueError(f"structure must be a Structure (CCF, MCF, Physical, ...); "
                         f"got {type(structure).__name__}")
    if not isinstance(config, RefineConfig):
        raise ValueError(f"config must be a RefineConfig; got {type(config).__name__}")
    if initial not in ("rest", "fitted"):
        raise ValueError(f"initial must be 'rest' or 'fitted'; got {initial!r}")
    dt = _check_dt(dt)
    y = _record("y", y)
    u = np.ones_like(y) if u is None else _record("u", u, y.shape[0])
    key = _structure_key(structure)
    x = _start_vector(structure, x0)
    return _refine_one(structure, key, x, y, u, dt, config, start, initial)


#: sqpmethod's status for a step below ``min_step_size`` (``RefineConfig.step_tol``): converged.
_SMALL_STEP = "Search_Direction_Becomes_Too_Small"


def _solve(problem: _Problem, z, p, lbz, ubz):
    """Run the solver from ``z``: ``(z*, iterations, status, converged)``."""
    z_new = problem.solver(z, p, lbz, ubz)[0]
    stats = problem.solver.stats()
    status = str(stats.get("return_status", ""))
    return (z_new, int(stats.get("iter_count", 0)), status,
            bool(stats.get("success")) or status == _SMALL_STEP)


def _refine_one(structure, key, x, y, u, dt, config, start,
                initial: str = "rest") -> RefineResult:
    y_bar = float(np.abs(y).max())
    if y_bar == 0.0:
        raise ValueError("y must not be all zero: the normalisation y_tilde = 2 y / max|y| - 1 "
                         "(Eq. 15) needs max|y| > 0")
    asm = _assembly(structure, key)
    names = structure.element_names
    tol = 1e-6 * (1.0 + np.abs(x).max())
    off = asm.fixed & (np.abs(x - asm.values) > tol)
    if np.any(off):
        i = int(np.flatnonzero(off)[0])
        raise ValueError(f"x0: element {names[i]} is fixed at {float(asm.values[i])!r} in "
                         f"{structure!r}; got {x[i]:.6g}")
    x = np.where(asm.fixed, asm.values, np.clip(x, asm.lo, asm.hi))
    free = ~asm.fixed
    x_free = x[free]
    scale = np.maximum(np.abs(x_free), 1e-2 * np.abs(x_free).max(initial=0.0))
    scale = np.where(scale > 0.0, scale, 1.0)
    w = 2.0 / (y_bar * math.sqrt(y.shape[0] + 1))  # residual weight, see _build
    p = np.concatenate([scale, w * y, w * u])
    lbz, ubz = asm.lo[free] / scale, asm.hi[free] / scale
    steps, dt_ = y.shape[0], np.array([dt])

    squarings = start_squarings = _squarings(_NORM_MARGIN * asm.system(x, dt_)[4][0])
    problem = _problem(structure, key, steps, dt, squarings, config, initial)
    z0 = x_free / scale
    loss_start = float(problem.loss(z0, p)[0][0])
    z, iterations, status, converged = z0, 0, "", False
    for _ in range(_MAX_RESOLVES + 1):
        try:
            z_new, its, status, converged = _solve(problem, z, p, lbz, ubz)
        except RuntimeError as err:  # an evaluation failing inside the solver
            status, converged, loss = f"solver error: {err}".splitlines()[0], False, math.nan
            break
        iterations += its
        if not np.all(np.isfinite(z_new)):
            loss = math.nan
            break
        z = np.clip(z_new, lbz, ubz)
        loss, norm = (v[0] for v in problem.loss(z, p))
        if not math.isfinite(norm):  # overflow far from the start: a failure, keep the start
            loss = math.nan
            break
        if _squarings(norm) <= squarings:
            break
        # The iterates left the exponential's accurate range: rebuild and go on from here.
        squarings = _squarings(_NORM_MARGIN * norm)
        problem = _problem(structure, key, steps, dt, squarings, config, initial)
    else:
        loss = problem.loss(z, p)[0][0]  # with enough squarings at z now
        status, converged = f"{status}; squarings still too few after re-solves", False
    loss = float(loss)
    if math.isfinite(loss) and (loss <= loss_start or not math.isfinite(loss_start)):
        x[free] = scale * z
        x = np.clip(x, asm.lo, asm.hi)
        success = converged
    else:
        status = f"kept the start: the solver's result has loss {loss:.6g} > {loss_start:.6g}" \
                 f" ({status})"
        loss, success, squarings = loss_start, False, start_squarings
    return RefineResult(x, float(loss_start), loss, iterations, success,
                        time.perf_counter() - start, config.solver, status, squarings)


# ---------------------------------------------------------------------------------------------
# Refinement of an Estimate
# ---------------------------------------------------------------------------------------------
def _records(name: str, value, count: int, batched: bool) -> np.ndarray:
    """``(count, steps)`` from ``(steps,)`` or ``(count, steps)``."""
    arr = as_array(name, value)
    want = f"(steps,) or ({count}, steps) like the estimate" if batched else "(steps,)"
    ok = arr.ndim == 1 or (batched and arr.ndim == 2 and arr.shape[0] in (1, count))
    if not ok or arr.shape[-1] < 1:
        raise ValueError(f"{name} must have shape {want}; got {arr.shape}")
    if arr.shape[-1] < 2:
        # one sample holds no dynamics: the FOH response needs two to interpolate between
        raise ValueError(f"{name} must have steps >= 2 samples; got {arr.shape}")
    arr = np.broadcast_to(np.atleast_2d(arr), (count, arr.shape[-1]))
    require_finite(name, arr)
    return arr


def refine(estimate: Estimate, y, u, dt: float, *, structure: Structure | None = None,
           config: RefineConfig = RefineConfig()) -> Estimate:  # noqa: B008
    """Polish an estimate by a CasADi NLP in its structure (module docstring), record by record.

    Parameters
    ----------
    estimate : Estimate
        The start; its ``elements`` must hold every element of ``structure``.
    y : (steps,) or (batch, steps)
        Measured output(s), ``batch`` as the estimate's (a single record for an unbatched
        estimate); not all zero. From rest, or mid-motion for an estimate with
        ``initial="fitted"`` (its initial state is fitted for every candidate model).
    u : like ``y``, ``(steps,)`` for every record, or None (unit step)
    dt : float > 0
    structure : Structure, optional
        Default: the structure the estimate carries (estimates from an ``Identifier`` do).
    config : RefineConfig

    Returns
    -------
    Estimate
        ``refined=True``; ``elements``, ``A, b, c, d`` assembled from the refined elements;
        ``y, u, dt`` the records refined against; ``seconds`` the estimate's plus the
        refinement's; ``info`` with ``iterations, loss_start, loss, success, seconds`` (scalars,
        or ``(batch,)`` arrays for a batch), ``status`` (str or list) and ``solver``.
        Per record, ``loss <= loss_start``.
    """
    start = time.perf_counter()
    if not isinstance(estimate, Estimate):
        raise ValueError(f"estimate must be an Estimate; got {type(estimate).__name__}")
    if structure is None:
        structure = estimate.structure
        if structure is None:
            raise ValueError("structure must be given: this estimate does not carry one (only "
                             "estimates from an Identifier do)")
    if not isinstance(structure, Structure):
        raise ValueError(f"structure must be a Structure (CCF, MCF, Physical, ...); "
                         f"got {type(structure).__name__}")
    if not isinstance(config, RefineConfig):
        raise ValueError(f"config must be a RefineConfig; got {type(config).__name__}")
    if structure.records > 1:
        raise ValueError(f"structure must describe one record; {structure!r} describes "
                         f"{structure.records} (a joint estimate): refine each subsystem's "
                         "estimate in its own structure")
    dt = _check_dt(dt)
    batched = estimate.batched
    count = estimate.A.shape[0] if batched else 1
    Y = _records("y", y, count, batched)
    U = np.ones_like(Y) if u is None else _records("u", u, count, batched)
    if U.shape != Y.shape:
        raise ValueError(f"u must have {Y.shape[1]} samples like y; got {U.shape[1]}")
    zero = ~np.any(Y != 0, axis=1)
    if zero.any():
        raise ValueError(f"y must not be all zero (record {int(np.argmax(zero))} of {count}): "
                         "the normalisation y_tilde = 2 y / max|y| - 1 (Eq. 15) needs max|y| > 0")
    names = structure.element_names
    missing = [nm for nm in names if nm not in estimate.elements]
    if missing:
        raise ValueError(f"estimate.elements must hold every element of {structure!r}; missing "
                         f"{', '.join(missing)}")
    X0 = np.stack([np.asarray(estimate.elements[nm], dtype=np.float64).reshape(count)
                   for nm in names], axis=1)
    key = _structure_key(structure)
    initial = getattr(estimate, "initial", "rest")
    results = [_refine_one(structure, key, X0[i].copy(), Y[i], U[i], dt, config,
                           time.perf_counter(), initial) for i in range(count)]
    asm = _assembly(structure, key)
    parts = [asm.system(r.elements, np.array([dt])) for r in results]
    n = structure.n
    A = np.stack([pt[0].reshape(n, n, order="F") for pt in parts])  # CasADi is column-major
    b, c = (np.stack([pt[i] for pt in parts]) for i in (1, 2))
    d = np.array([pt[3][0] for pt in parts])
    X = np.stack([r.elements for r in results])
    seconds = time.perf_counter() - start

    def field(name, dtype=None):
        values = np.array([getattr(r, name) for r in results], dtype=dtype)
        return values if batched else values[0].item()

    info = {
        "iterations": field("iterations", np.int64),
        "loss_start": field("loss_start", np.float64),
        "loss": field("loss", np.float64),
        "success": field("success", bool),
        "seconds": seconds if not batched else field("seconds", np.float64),
        "solver": config.solver,
        "status": [r.status for r in results] if batched else results[0].status,
    }
    if batched:
        elements = {nm: X[:, i].copy() for i, nm in enumerate(names)}
        out = (A, b, c, d, elements, Y.copy(), U.copy())
    else:
        elements = {nm: float(X[0, i]) for i, nm in enumerate(names)}
        out = (A[0], b[0], c[0], float(d[0]), elements, Y[0].copy(), U[0].copy())
    return dataclasses.replace(
        estimate, A=out[0], b=out[1], c=out[2], d=out[3], elements=out[4], y=out[5], u=out[6],
        dt=dt, seconds=estimate.seconds + seconds, refined=True, info=info,
    )
