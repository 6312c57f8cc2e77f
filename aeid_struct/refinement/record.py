r"""Output-error refinement over a whole measured record: any length, any ``dt``, an initial
state, an output offset and an input delay (docs/architecture.md, issue 14).

The model of a record ``y, u (N,)`` at ``t_k = k dt`` with an input delay of ``D`` samples::

    yhat_k = y_forced_k(A, b, c, d; u_{k-D}) + c^T Phi^(k-D) x0 + y_offset,   k = D .. N-1,

the exact first-order-hold response (Eq. 10-13) of the delayed input from rest, the free
response of the state ``x0`` at sample ``D`` and a constant offset; ``y[D:]`` is fitted against
``u[:N-D]`` (``y_0 .. y_{D-1}`` depend on inputs before the record). For every value of the
free elements, ``x0`` and the offset are linear least squares (variable projection, Golub &
Pereyra): with ``R = [O, 1]`` (``O`` the free-response basis ``c^T Phi^k``) and
``P = I - Q Q^T`` (``Q`` an orthonormal basis of ``R``'s columns),

    r(x) = w P (y[D:] - y_forced(x)),    J(x) ~= -w P d(y_forced + O x0)/dx,

Kaufman's Jacobian (the projected model Jacobian at the current ``x0``), with
``w = 1 / ||y[D:] - mean||`` so that the cost ``||r||^2 = (1 - fit / 100)^2`` compares delays.

*One graph per (structure, length bucket).* The CasADi Function ``(z, p) -> (yhat, O, dyhat/dz)``
holds the response unrolled over a bucket of ``B`` samples (:data:`BUCKETS`): a record of
``N - D <= B`` samples takes the first rows, the zero-padded input after them never reaches
them. ``dt``, the Pade scaling ``2^-s`` and the squarings ``s`` are parameters (squaring ``i``
is ``if_else(s > i, E E, E)``, up to :data:`MAX_SQUARINGS`), so the same graph serves every
``dt``, length in the bucket, delay and offset choice; the elements stay in physical units.

Design measurements (docs/architecture.md; CCF order 4, bucket 1024): the unrolled SX graph
evaluates its response and Jacobian about 5x faster than a ``mapaccum`` fold of a one-step
Function (which builds 3-4x faster), so the graph is unrolled. Projecting ``x0`` and the offset
inside the graph (as ``nlp.py`` does) made the Jacobian 4-5x dearer than projecting in numpy
after it (one QR of ``(N - D, n + 1)``). The iterations are our own Levenberg-Marquardt on
``(r, J)`` from one evaluation per trial point; ``sqpmethod`` evaluates the gradient and the
Gauss-Newton Hessian in separate sweeps.
"""

from __future__ import annotations

import math
import time

import casadi
import numpy as np

from aeid_struct.estimates import Estimate
from aeid_struct.records import INTERSAMPLE, require_finite
from aeid_struct.refinement import core, nlp
from aeid_struct.refinement.config import MAX_SQUARINGS, RefineConfig
from aeid_struct.refinement.result import fitted
from aeid_struct.simulation import augmented, expm, squarings_for
from aeid_struct.structures import Structure

__all__ = ["BUCKETS", "MAX_SQUARINGS", "refine_record"]

#: Record lengths (samples after the delay) that one graph serves: the smallest bucket that
#: holds ``N - D``. Longer records are refused (a larger bucket takes seconds to build).
BUCKETS = (256, 512, 1024, 2048, 4096, 8192)
#: Headroom of the squarings over the current ``||M||_1`` (three spare doublings).
_NORM_MARGIN = 8.0
#: Levenberg-Marquardt damping: start (relative to diag(J^T J)), factor, give-up value.
_LAMBDA0, _LAMBDA_FACTOR, _LAMBDA_MAX = 1e-3, 10.0, 1e12
#: A cost decrease below this fraction ends the iterations (a flat optimum).
_FLAT = 1e-10


# ---------------------------------------------------------------------------------------------
# The graph (cached per structure and bucket)
# ---------------------------------------------------------------------------------------------
def _elements(structure: Structure, z, scale):
    """All elements with the free ones ``scale * z`` (fixed ones constants of the graph)."""
    fixed, cols, j = structure.fixed_values, [], 0
    for nm in structure.element_names:
        if nm in fixed:
            cols.append(casadi.DM(fixed[nm]))
        else:
            cols.append(scale[j] * z[j])
            j += 1
    return casadi.vertcat(*cols)


def build_record_graph(structure: Structure, bucket: int,
                       intersample: str = "foh") -> nlp.Numeric:
    """Build the response graph of one structure and bucket (uncached).

    Parameters
    ----------
    structure : Structure
    bucket : int
        Samples ``B`` of the unrolled response.
    intersample : {"foh", "zoh"}
        The input between samples: a held input is the same recursion with ``gamma2 = 0``
        (``simulation.discrete_foh``).

    Returns
    -------
    Numeric
        ``(z (f,), p) -> (yhat (B,), O (B, n), dyhat/dz (B, f))`` (column-major), with ``f``
        free elements ``scale * z`` and ``p = [scale (f); dt; 2^-s; s; x0 (n); u (B)]``:
        ``yhat`` the FOH response (Eq. 10-13) from state ``x0`` plus ``O x0``'s basis ``O``
        (row ``k``: ``c^T Phi^k``).
    """
    n, f = structure.n, len(structure.free_names)
    z, scale = casadi.SX.sym("z", f), casadi.SX.sym("scale", f)
    dt, h, s = casadi.SX.sym("dt"), casadi.SX.sym("h"), casadi.SX.sym("s")
    x0, u = casadi.SX.sym("x0", n), casadi.SX.sym("u", bucket)
    A, b, c, d = structure.casadi_system(_elements(structure, z, scale))
    E = expm(augmented(A * dt, b * dt, 1.0) * h, 0)    # Eq. 10's M scaled by 2^-s
    for i in range(MAX_SQUARINGS):
        # Squarings chosen at run time: both branches are evaluated (cheap at n + 2), the
        # derivative follows the branch taken.
        E = casadi.if_else(s > i + 0.5, E @ E, E)
    Phi, gamma1, gamma2 = E[:n, :n], E[:n, n], E[:n, n + 1]
    if intersample == "zoh":
        gamma2 = casadi.SX.zeros(n, 1)
    # As simulation.casadi_simulate, from x_0 = x0: x_1 = Phi x0 + (gamma1 - gamma2) u_0 +
    # gamma2 u_1, and zeta_k = x_k - gamma2 u_k obeys zeta_{k+1} = Phi zeta_k + Bd u_k.
    Bd, Dd = gamma1 - gamma2 + Phi @ gamma2, d + c.T @ gamma2
    yhat, rows, o = [c.T @ x0 + d * u[0]], [c.T], c.T
    zeta = Phi @ x0 + (gamma1 - gamma2) * u[0]
    for k in range(1, bucket):
        yhat.append(c.T @ zeta + Dd * u[k])
        o = o @ Phi
        rows.append(o)
        if k + 1 < bucket:
            zeta = Phi @ zeta + Bd * u[k]
    yhat, O = casadi.vertcat(*yhat), casadi.vertcat(*rows)
    p = casadi.vertcat(scale, dt, h, s, x0, u)
    outputs = [casadi.densify(v) for v in (yhat, O, casadi.jacobian(yhat, z))]
    return nlp.Numeric(casadi.Function("record", [z, p], outputs, ["z", "p"],
                                       ["yhat", "O", "J"]))


def record_graph(structure: Structure, key: str, length: int,
                 intersample: str = "foh") -> tuple[int, nlp.Numeric]:
    """The cached graph of the smallest bucket holding ``length`` samples.

    Parameters
    ----------
    structure : Structure
    key : str
        :func:`nlp.structure_key` of ``structure``.
    length : int
        Samples to fit (``N - D``).
    intersample : {"foh", "zoh"}

    Returns
    -------
    (bucket, Numeric)
    """
    bucket = next(bk for bk in BUCKETS if bk >= length)
    # the first-order hold keeps the key it always had (its cached graphs are shared)
    cache_key = ("record", key, bucket) if intersample == "foh" else (
        "record", key, bucket, intersample)
    return bucket, nlp.cached(cache_key,
                              lambda: build_record_graph(structure, bucket, intersample))


# ---------------------------------------------------------------------------------------------
# One delay: variable projection + Levenberg-Marquardt
# ---------------------------------------------------------------------------------------------
class _Delay:
    """The projected residual of one record at one delay, evaluated on the cached graph."""

    def __init__(self, structure, key, asm, y, u, dt, delay, offset, intersample="foh"):
        self.asm, self.n, self.dt, self.offset = asm, structure.n, dt, offset
        self.m = m = y.shape[0] - delay
        self.bucket, self.graph = record_graph(structure, key, m, intersample)
        self.y = y[delay:]
        self.u = np.zeros(self.bucket)
        self.u[:m] = u[:m]
        spread = float(np.linalg.norm(self.y - self.y.mean()))
        # w makes ||r||^2 = (1 - fit/100)^2; a constant record falls back to its size.
        self.w = 1.0 / (spread if spread > 0 else max(float(np.abs(self.y).max()), 1.0))
        self.squarings = 0

    def full(self, z, scale):
        x = self.asm.values.copy()
        x[~self.asm.fixed] = scale * z
        return x

    def squarings_ok(self, x) -> bool:
        """Raise the run-time squarings when ``||M||_1`` at ``x`` needs more; False beyond
        :data:`MAX_SQUARINGS` or on overflow."""
        norm = float(self.asm.system(x, np.array([self.dt]))[4][0])
        if not math.isfinite(norm):
            return False
        if squarings_for(norm) > self.squarings:
            self.squarings = squarings_for(_NORM_MARGIN * norm)
        return self.squarings <= MAX_SQUARINGS

    def parts(self, z, scale, x0):
        """``(yhat (m,), O (m, n), dyhat/dz (m, f))`` at ``z`` from state ``x0``."""
        s = self.squarings
        p = np.concatenate([scale, [self.dt, 2.0 ** -s, s], x0, self.u])
        yhat, O, J = self.graph(z, p)
        B, m = self.bucket, self.m
        return (yhat[:m], O.reshape(self.n, B).T[:m], J.reshape(-1, B).T[:m])

    def evaluate(self, z, scale, x0):
        """``(cost, r, J, theta, forced, O)`` at ``z``: ``theta = [x0; offset]`` the
        least-squares linear parameters, ``forced`` the response from rest (Kaufman's Jacobian
        ``J`` uses the given ``x0``); ``cost = inf`` and Nones where the model overflows."""
        failed = (math.inf, None, None, None, None, None)
        if not self.squarings_ok(self.full(z, scale)):
            return failed
        # A trial far out may overflow: checked below, so numpy's warnings are noise.
        with np.errstate(over="ignore", invalid="ignore"):
            yhat, O, J = self.parts(z, scale, x0)
            forced = yhat - O @ x0
            if not (np.all(np.isfinite(forced)) and np.all(np.isfinite(O))
                    and np.all(np.isfinite(J))):
                return failed
            R = np.column_stack([O, np.ones(self.m)]) if self.offset else O
            e = self.y - forced
            Q, Rr = np.linalg.qr(R)
            qe = Q.T @ e
            r = self.w * (e - Q @ qe)
            Jr = -self.w * (J - Q @ (Q.T @ J))
            theta = np.linalg.lstsq(Rr, qe, rcond=None)[0]
            return float(r @ r), r, Jr, theta, forced, O


class _Row:
    """One delay's projected residual in the scaled free elements ``z`` as a one-row problem of
    ``core.minimise`` (the graph gives the residual and the Jacobian in one call)."""

    lazy = False

    def __init__(self, problem: _Delay, scale: np.ndarray) -> None:
        self.problem, self.scale = problem, scale

    def evaluate(self, z, rows, jacobian, at):
        n = self.problem.n
        if at is None:
            got = self.problem.evaluate(z[0], self.scale, np.zeros(n))
            if math.isfinite(got[0]):
                # Kaufman's Jacobian needs x0: evaluate again with the start's least-squares
                # state (from x0 = 0 the first direction misses d(O x0)/dz and overshoots)
                got = self.problem.evaluate(z[0], self.scale, got[3][:n])
        else:
            got = self.problem.evaluate(z[0], self.scale, at["theta"][0][:n])
        cost, r, J, theta = got[:4]
        return {"cost": np.array([cost]), "r": None if r is None else r[None],
                "J": None if J is None else J.T[None],
                "theta": None if theta is None else theta[None], "got": got}


def _levenberg_marquardt(problem: _Delay, z, scale, lbz, ubz, config: RefineConfig):
    """Minimise ``||r(z)||^2`` in the box ``[lbz, ubz]`` (``core.minimise``, projected steps):
    ``(z, evaluation at z, iterations, converged)``.

    Stops converged on a gradient below ``config.tol``, a step below ``config.step_tol``
    (relative units), a cost decrease below :data:`_FLAT` relative (a flat optimum: noise, a
    wrong delay) or a damping beyond :data:`_LAMBDA_MAX` (no damped step descends)."""
    rules = core.Rules(max_iter=int(config.max_iter), lambda0=_LAMBDA0, factor=_LAMBDA_FACTOR,
                       lambda_min=1e-15, lambda_max=_LAMBDA_MAX, cost_tol=_FLAT,
                       gradient_tol=float(config.tol), step_tol=float(config.step_tol))

    def progress(iteration, cost):
        print(f"refine_record: iteration {iteration}, cost {cost:.6e}")

    out = core.minimise(_Row(problem, scale), z[None], rules, lower=lbz[None],
                        upper=ubz[None], progress=progress if config.verbose else None)
    return (out.x[0], out.evaluation["got"], int(out.iterations[0]),
            bool(out.converged[0]))


# ---------------------------------------------------------------------------------------------
# The public entry point
# ---------------------------------------------------------------------------------------------
def _start_elements(structure: Structure, start) -> np.ndarray:
    """All elements ``(q,)`` from the free ones (dict, ``(p,)`` free or ``(q,)`` all); fixed
    ones are set to their values."""
    names, free = structure.element_names, structure.free_names
    fixed = structure.fixed_values
    if isinstance(start, dict):
        missing = [nm for nm in free if nm not in start]
        if missing:
            raise ValueError(f"start is missing the free element(s) {', '.join(missing)} of "
                             f"{structure!r}")
        return np.array([fixed[nm] if nm in fixed else float(start[nm]) for nm in names])
    x = np.asarray(start, dtype=np.float64).reshape(-1)
    if x.shape[0] == len(free) and len(free) != len(names):
        x = np.array([fixed[nm] if nm in fixed else x[free.index(nm)] for nm in names])
    if x.shape != (len(names),):
        raise ValueError(f"start must hold the {len(free)} free elements ({', '.join(free)}) "
                         f"or all {len(names)} of {structure!r}; got shape {np.shape(start)}")
    return np.array([fixed.get(nm, v) for nm, v in zip(names, x, strict=True)])


def _candidates(delay, delays, steps: int, n: int) -> tuple[int, ...]:
    values = (delay,) if delays is None else tuple(delays)
    bad = [D for D in values if isinstance(D, bool) or not isinstance(D, (int, np.integer))
           or D < 0 or steps - D < n + 2]
    if not values or bad:
        raise ValueError(f"{'delay' if delays is None else 'delays'} must be integers 0 <= D <= "
                         f"{steps - n - 2} (the record has {steps} samples, order {n}); got "
                         f"{values!r}")
    return tuple(int(D) for D in values)


def _fit(problem: _Delay, x, config):
    """Refine one delay from elements ``x (q,)``: ``(x, evaluation, iterations, converged)``."""
    asm = problem.asm
    free = ~asm.fixed
    x = np.where(asm.fixed, asm.values, np.clip(x, asm.lo, asm.hi))
    x_free = x[free]
    scale = np.maximum(np.abs(x_free), 1e-2 * np.abs(x_free).max(initial=0.0))
    scale = np.where(scale > 0.0, scale, 1.0)
    z, now, iterations, converged = _levenberg_marquardt(
        problem, x_free / scale, scale, asm.lo[free] / scale, asm.hi[free] / scale, config)
    x = x.copy()
    x[free] = np.clip(scale * z, asm.lo[free], asm.hi[free])
    return x, now, iterations, converged


def _result(structure, problem: _Delay, x, now, delay, iterations, converged, y, u, seconds,
            intersample: str):
    """The Estimate at elements ``x`` from its evaluation ``now``: ``x0`` and the offset by
    least squares (SVD) on the unweighted record."""
    n = structure.n
    A, b, c, d = problem.asm.system(x, np.array([problem.dt]))[:4]
    forced, O = now[4], now[5]
    R = np.column_stack([O, np.ones(problem.m)]) if problem.offset else O
    theta = np.linalg.lstsq(R, problem.y - forced, rcond=None)[0]
    model = forced + R @ theta
    y_hat = np.full(y.shape[0], np.nan)
    y_hat[delay:] = model
    cost = float(np.sum((problem.y - model) ** 2) * problem.w ** 2)
    return fitted(structure, (A.reshape(n, n, order="F"), b, c, float(d[0])),
                  {nm: float(v) for nm, v in zip(structure.element_names, x, strict=True)},
                  y, u, problem.dt, seconds=seconds, method="refine_record", delay=int(delay),
                  x0=theta[:n], y_offset=float(theta[n]) if problem.offset else 0.0,
                  fit=100.0 * (1.0 - math.sqrt(cost)), y_hat=y_hat, cost=cost,
                  iterations=iterations, converged=converged, intersample=intersample)


def refine_record(structure: Structure, start, y: np.ndarray, u: np.ndarray, dt: float, *,
                  delay: int = 0, delays=None, offset: bool = True,
                  config: RefineConfig | None = None, intersample: str = "foh") -> Estimate:
    """Refine a structure's elements on a whole record with its initial state, an output
    offset and an input delay (the module docstring's model; docs/architecture.md).

    Parameters
    ----------
    structure : Structure
        Of one record (CCF, MCF, Physical, with fixed elements or not); its bounds hold for
        the result (an MCF keeps ``Re < 0``) and fixed elements stay at their values.
    start : dict name -> float, or (p,) or (q,) numbers
        The free elements to start from (a dict may also hold the fixed ones; a ``(q,)``
        vector holds all elements in ``structure.element_names`` order, fixed ones ignored).
    y, u : (N,) float64 arrays
        The measured output and input at ``t_k = k dt`` (checked by the caller; ``u`` linear
        between samples).
    dt : float > 0
    delay : int >= 0
        The input delay in samples, used when ``delays`` is None.
    delays : iterable of int, optional
        Candidate delays, each refined from ``start``; the lowest ``cost`` wins.
    offset : bool
        Fit a constant output offset (else it is 0).
    config : RefineConfig, optional
        ``max_iter`` (per delay), ``tol`` (on the gradient of the cost with respect to
        relative element changes), ``step_tol`` and ``verbose`` apply; ``solver`` does not
        (the iterations are this module's Levenberg-Marquardt).
    intersample : {"foh", "zoh"}
        The input between samples (``records.Record.intersample``): linear, or held.

    Returns
    -------
    Estimate
        Of the record, in ``structure`` (``elements``, ``A, b, c, d`` in the time unit of
        ``dt``); ``delay`` (the best of the candidates by cost), ``x0`` (the state at sample
        ``delay``), ``offset``, ``fit`` (NRMSE % on the used samples ``y[delay:]``) and
        ``y_hat`` (NaN before ``delay``) from ``info``, which also holds ``cost``
        (``||y - yhat||^2 / ||y - mean y||^2`` on the used samples, ``(1 - fit / 100)^2``),
        ``iterations`` (summed over the candidate delays) and ``converged`` (the iterations at
        ``delay`` stopped on a tolerance).

    Raises
    ------
    ValueError
        Naming the argument: a structure of several records, a start without the free
        elements, delays outside ``0 .. N - n - 2``, a record longer than ``max(BUCKETS)``
        after the delay, ``y`` and ``u`` of different lengths or not finite.
    """
    t0 = time.perf_counter()
    config = RefineConfig() if config is None else config
    if not isinstance(structure, Structure) or structure.records != 1:
        raise ValueError(f"structure must be a Structure of one record; got {structure!r}")
    y = np.ascontiguousarray(y, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    if y.ndim != 1 or u.shape != y.shape:
        raise ValueError(f"y and u must have the same shape (N,); got {y.shape} and {u.shape}")
    require_finite("y", y)
    require_finite("u", u)
    if intersample not in INTERSAMPLE:
        raise ValueError(f"intersample must be one of {', '.join(map(repr, INTERSAMPLE))}; "
                         f"got {intersample!r}")
    candidates = _candidates(delay, delays, y.shape[0], structure.n)
    if y.shape[0] - min(candidates) > BUCKETS[-1]:
        raise ValueError(f"y must have at most {BUCKETS[-1]} samples after the delay (the "
                         f"largest bucket); got {y.shape[0] - min(candidates)}: refine a window")
    key = nlp.structure_key(structure)
    asm = nlp.assembly(structure, key)
    x = _start_elements(structure, start)
    best, iterations = None, 0
    for D in candidates:
        # Every candidate starts from the caller's start, not from its neighbour's result: a
        # wrong delay is absorbed by a fast pole far from the start (measured: CCF order 4,
        # delay 1 of a delay-2 record ends at a_i 70x off), and the next delay then converged
        # to a worse optimum than from the start itself.
        problem = _Delay(structure, key, asm, y, u, float(dt), D, bool(offset), intersample)
        x_D, now, its, converged = _fit(problem, x, config)
        iterations += its
        if now[4] is None:     # the start itself overflows at this delay's length
            continue
        if best is None or now[0] < best[2][0]:
            best = (x_D, problem, now, D, converged)
    if best is None:
        raise ValueError(f"start: the model of these elements overflows on this record "
                         f"(dt={dt}); start from a model that does not")
    x, problem, now, D, converged = best
    return _result(structure, problem, x, now, D, iterations, converged, y, u,
                   time.perf_counter() - t0, intersample)
