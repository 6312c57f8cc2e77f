r"""The refinement NLP: the output-error problem of one record in a structure's elements.

For a record ``y, u (steps,)`` at ``t_k = k dt`` and the structure's free elements ``x``,

    min_x  J(x) = 1/(m+1) sum_k (y~_k - yhat~_k(x))^2,   y~ = 2 y / y_bar - 1,  y_bar = max|y|
    s.t.   lo_i <= x_i <= hi_i            (Structure.element_bounds)

with ``m = steps``: the paper's loss (Eq. 14, ``gamma = 0``) on the normalised record (Eq. 15).
By linearity the NLP's parameters are ``w y`` and ``w u`` with ``w = 2 / (y_bar sqrt(m + 1))``,
its residuals ``r = w y - yhat(w u)`` and ``J = sum_k r_k^2``. ``yhat`` is the decoder's exact
first-order-hold response (Eq. 10-13) unrolled as one CasADi graph (:func:`casadi_simulate`,
with Higham's Pade [13/13] :func:`expm`); a record that starts mid-motion has its least-squares
initial state projected out (variable projection). Decision variables are the free elements in
relative units ``x_i = s_i z_i``; the Hessian is the Gauss-Newton ``2 (J^T J + mu I)``.

Problems are built once per (structure, steps, dt, squarings, config, initial) and kept in a small
LRU cache (:func:`cache_info`, :func:`clear_cache`); they are evaluated through CasADi's numeric
buffers (:class:`Numeric`): refine from one thread at a time. The design and its measurements:
docs/architecture.md.
"""

from __future__ import annotations

import json
import math
from collections import OrderedDict
from dataclasses import dataclass

import casadi
import numpy as np

from aeid_struct.records import as_array
from aeid_struct.records import check_dt as _check_dt  # the one dt rule (foundation)
from aeid_struct.refinement.config import SOLVERS, CacheInfo, RefineConfig
from aeid_struct.structures import Structure

__all__ = ["SOLVERS", "THETA13", "Numeric", "assembly", "build", "cache_info", "casadi_simulate",
           "clear_cache", "expm", "problem", "structure_key"]

# Pade [13/13] coefficients b_0..b_13 and its scaling threshold (Higham 2005, Table 2.3).
_PADE13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
           129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
           40840800.0, 960960.0, 16380.0, 182.0, 1.0)
THETA13 = 5.371920351148152
#: Relative Levenberg floor of the Gauss-Newton Hessian ``2 (J^T J + mu I)``.
_DAMPING = 1e-12
#: Solvers kept in the cache.
_CACHE_SIZE = 32


# ---------------------------------------------------------------------------------------------
# The matrix exponential and the simulation, in CasADi
# ---------------------------------------------------------------------------------------------
def _squarings(norm: float) -> int:
    """Fewest ``s >= 0`` with ``norm / 2^s <= theta_13``."""
    if not math.isfinite(norm):
        raise ValueError(f"||M||_1 must be finite to choose the squarings; got {norm}")
    return max(0, math.ceil(math.log2(norm / THETA13))) if norm > THETA13 else 0


def expm(M, squarings: int | None = None):
    """Matrix exponential with CasADi operations: scaling and squaring, Pade [13/13].

    ``expm(M) = r(M / 2^s)^(2^s)`` with ``r(X) = (V - U)^{-1} (V + U)`` the diagonal Pade
    approximant of degree 13 (``U`` odd, ``V`` even in ``X``; Higham 2005); accurate to rounding
    (backward error below the unit roundoff) when ``||M||_1 / 2^s <= theta_13 = 5.37``.

    Parameters
    ----------
    M : (N, N) casadi SX, MX or DM, or numpy
    squarings : int >= 0, optional
        ``s``, fixed in the graph. Required for a symbolic ``M`` (choose it from a bound on
        ``||M||_1``); for a numeric ``M`` it defaults to the fewest that meet the bound.

    Returns
    -------
    (N, N), the type of ``M`` (DM for numpy).
    """
    if not isinstance(M, (casadi.SX, casadi.MX, casadi.DM)):
        M = casadi.DM(np.asarray(M, dtype=np.float64))
    if M.shape[0] != M.shape[1]:
        raise ValueError(f"M must be square; got shape {M.shape}")
    if squarings is None:
        if not isinstance(M, casadi.DM):
            raise ValueError("squarings must be given for a symbolic M: the graph needs a fixed "
                             "number of squarings (choose it from a bound on ||M||_1)")
        squarings = _squarings(float(casadi.norm_1(M)))
    if isinstance(squarings, bool) or not isinstance(squarings, (int, np.integer)) \
            or squarings < 0:
        raise ValueError(f"squarings must be an integer >= 0; got {squarings!r}")
    N, b = M.shape[0], _PADE13
    X = M / 2.0 ** int(squarings)
    eye = type(X).eye(N)
    X2 = X @ X
    X4 = X2 @ X2
    X6 = X4 @ X2
    U = X @ (X6 @ (b[13] * X6 + b[11] * X4 + b[9] * X2)
             + b[7] * X6 + b[5] * X4 + b[3] * X2 + b[1] * eye)
    V = X6 @ (b[12] * X6 + b[10] * X4 + b[8] * X2) + b[6] * X6 + b[4] * X4 + b[2] * X2 \
        + b[0] * eye
    E = casadi.solve(V - U, V + U)
    for _ in range(int(squarings)):
        E = E @ E
    return E


def _augmented(A, b, dt: float):
    """Eq. 10's ``M = [[A dt, b dt, 0], [0, 0, 1], [0, 0, 0]]`` (CasADi, ``(n+2, n+2)``)."""
    n = A.shape[0]
    zeros = type(A).zeros
    top = casadi.horzcat(A * dt, b * dt, zeros(n, 1))
    bottom = casadi.DM([[0.0] * n + [0.0, 1.0], [0.0] * (n + 2)])
    return casadi.vertcat(top, bottom)


def casadi_simulate(A, b, c, d, u, dt: float, *, squarings: int, free: bool = False):
    """The decoder's exact FOH response (Eq. 10-13) as a CasADi expression, ``x_0 = 0``.

    ``x_{k+1} = Phi x_k + gamma1 u_k + gamma2 (u_{k+1} - u_k)``, ``y_k = c^T x_k + d u_k``, with
    ``(Phi, gamma1, gamma2)`` from :func:`expm` of Eq. 10's augmented matrix; unrolled over the
    record (a graph of ``O(steps n^2)`` nodes).

    Parameters
    ----------
    A : (n, n); b, c : (n, 1); d : (1, 1) -- CasADi (SX, MX or DM) or numpy
    u : (steps, 1) CasADi, or numpy (steps,)
    dt : float > 0
    squarings : int >= 0
        Squarings of the matrix exponential (see :func:`expm`).
    free : bool
        Also return the free-response basis ``O (steps, n)``, row ``k`` = ``c^T Phi^k``: the
        response from an initial state ``x_0`` is ``y + O x_0``.

    Returns
    -------
    y : (steps, 1), CasADi (and ``O`` with ``free``).
    """
    dt = _check_dt(dt)
    A, b, c, d, u = (v if isinstance(v, (casadi.SX, casadi.MX, casadi.DM))
                     else casadi.DM(as_array(name, v))
                     for name, v in zip("Abcdu", (A, b, c, d, u), strict=True))
    n = A.shape[0]
    for name, v, shape in (("A", A, (n, n)), ("b", b, (n, 1)), ("c", c, (n, 1)),
                           ("d", d, (1, 1))):
        if v.shape != shape:
            raise ValueError(f"{name} must have shape {shape} with n = {n} from A; "
                             f"got {v.shape}")
    if u.shape[1] != 1 or u.shape[0] < 1:
        raise ValueError(f"u must have shape (steps, 1) with steps >= 1; got {u.shape}")
    E = expm(_augmented(A, b, dt), squarings)
    Phi, gamma1, gamma2 = E[:n, :n], E[:n, n], E[:n, n + 1]
    # The shifted state xi_k = x_k - gamma2 u_k (as in the decoder) takes the input through one
    # column: xi_{k+1} = Phi xi_k + Bd u_k, y_k = c^T xi_k + Dd u_k, xi_0 = -gamma2 u_0, with
    # Bd = gamma1 - gamma2 + Phi gamma2, Dd = d + c^T gamma2 (substitute x_k = xi_k + gamma2 u_k
    # into Eq. 10-13). Same outputs, ~10 % fewer graph nodes per sample.
    Bd = gamma1 - gamma2 + Phi @ gamma2
    Dd = d + c.T @ gamma2
    steps = u.shape[0]
    xi = -gamma2 * u[0]
    y, rows, o = [], [], c.T
    for k in range(steps):
        y.append(c.T @ xi + Dd * u[k])
        if free:
            rows.append(o)
            o = o @ Phi
        if k + 1 < steps:
            xi = Phi @ xi + Bd * u[k]
    return (casadi.vertcat(*y), casadi.vertcat(*rows)) if free else casadi.vertcat(*y)




#: ``_squarings`` under a name the solving module may use (the simulator above moves to
#: ``aeid_struct.simulation`` in the redesign; this name goes with it).
fewest_squarings = _squarings


# ---------------------------------------------------------------------------------------------
# Building the NLP (cached)
# ---------------------------------------------------------------------------------------------
class Numeric:
    """Numeric evaluation of a ``casadi.Function`` through its buffer.

    Why: a Python call of a CasADi Function converts every numpy argument to a DM and every
    result back, which would dominate a refinement of about a millisecond; the buffer reads and
    writes numpy memory directly.

    Parameters
    ----------
    function : casadi.Function
        Evaluated with contiguous float64 vectors of its inputs' sizes (CasADi's column-major
        order); results come back as flat float64 arrays.
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
        """The Function's statistics after the last evaluation (a solver's iterations, status).

        Returns
        -------
        dict
        """
        return self.buffer.stats()


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
    ridge = 1e-12 * casadi.trace(G) + 1e-300      # keeps the solve defined as O -> 0
    return e - O @ casadi.solve(G + ridge * casadi.SX.eye(n), O.T @ e)


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


def __getattr__(name: str):
    # Old names of this module (``aeid_struct.refine`` is an alias of it): the refinement
    # itself lives in solve.py, which imports this module, so it is looked up on first use.
    if name in ("refine", "refine_elements", "RefineResult"):
        from aeid_struct.refinement import solve

        return getattr(solve, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
