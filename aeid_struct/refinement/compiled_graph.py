r"""The CasADi graph of one record's separable Levenberg-Marquardt, which ``compiled.py``
writes to C: the iterations of the numpy path (``batched.py``) as one ``casadi.Function`` per
pattern and ``N``. The seam: this module builds the symbolic graph and nothing else (no compiler,
no cache, no numbers); ``compiled.py`` compiles it, keeps it for the process and runs records
through it.

*The graph, per (pattern, N).* An MX graph calls small SX kernels, each one C function however
often it runs: the Pade approximant of Eq. 10's matrix scaled by ``2^-s`` and its derivatives
in the free ``a_j``; the squarings, each a switch that evaluates only the branch taken; the
response in blocks of samples (``x_{k+1} = Phi x_k + E u_k + gamma2 u_{k+1}``, Eq. 11 with
``E = gamma1 - gamma2``, from ``x_0 = 0``; the free responses ``o_{k+1} = Phi^T o_k``), with and
without the forward derivatives, looped over the blocks (``mapaccum``); the Cholesky solves. The
sums over ``N`` (Gram matrix, projections, ``J^T r``, ``J^T J``) are loops over contiguous
series. :data:`MAX_ITERATIONS` iterations are chained through a switch that skips each once
the record is done or ``iterations`` are spent, so a record costs the iterations it takes, and
``dt``, ``iterations`` and ``tol`` are inputs: one compilation serves the fixed-cost pass and
the refinement. Why not simpler graphs: the response unrolled over ``N`` samples as straight
SX, with its derivatives, is megabytes of C that compile for tens of seconds; CasADi's MX
derivatives of the same loops and the ``N x p`` matrix products give code several times slower.
"""

from __future__ import annotations

import casadi
import numpy as np

from aeid_struct.refinement import batched
from aeid_struct.refinement.config import MAX_SQUARINGS
from aeid_struct.simulation import THETA13, augmented, expm

__all__ = ["BLOCK", "MAX_ITERATIONS", "graph"]

#: Iterations the compiled graph holds; more fall back to numpy.
MAX_ITERATIONS = 50
#: Samples of the response unrolled in one C function (the graph loops over blocks), by order
#: n = 1, 2, 3, 4+: fewer where a sample's code is larger.
BLOCK = (32, 32, 16, 8)


class _Kernels:
    """The SX kernels of one pattern and ``N`` (module docstring), and the Cholesky solves."""

    def __init__(self, pattern, N: int) -> None:
        n, nf = pattern.n, int(pattern.free_a.size)
        m = n + 2
        self.n, self.nf = n, nf
        self.free_c = [i for i, v in enumerate(pattern.c) if v is None]
        self.fixed = any(v not in (None, 0.0) for v in pattern.c)
        # Straight-line SX is the fastest code, but its derivative of the Pade approximant
        # grows as n^4 (for n = 4 it compiles for tens of seconds); MX keeps the matrix
        # products as loops.
        sym = casadi.SX if n <= 2 else casadi.MX
        alpha, dt = sym.sym("alpha", nf), sym.sym("dt")
        free = iter(range(nf))
        a = casadi.vertcat(*[alpha[next(free)] if v is None else v for v in pattern.a])
        A = casadi.vertcat(casadi.horzcat(casadi.DM.zeros(n - 1, 1), casadi.DM.eye(n - 1)),
                           -a.T)
        M = augmented(A, casadi.DM.eye(n)[:, n - 1], dt)
        norm = casadi.mmax(casadi.sum1(casadi.fabs(M)))        # induced 1-norm, >= 1
        s = casadi.fmax(0.0, casadi.ceil(casadi.log(norm / THETA13) / np.log(2.0)))
        E = expm(M * 2.0 ** -s, 0)
        dE = casadi.jacobian(casadi.vec(E), alpha)               # s is piecewise constant
        dE = casadi.horzcat(*[casadi.reshape(dE[:, j], m, m) for j in range(nf)])
        #: (alpha, dt) -> (expm(M / 2^s), its derivatives [dE_1 .. dE_nf], s, a)
        self.pade = casadi.Function("gn_pade", [alpha, dt], [E, dE, s, a])
        E, dE = casadi.SX.sym("E", m, m), casadi.SX.sym("dE", m, m * nf)
        squared = [dE[:, j * m: (j + 1) * m] @ E + E @ dE[:, j * m: (j + 1) * m]
                   for j in range(nf)]
        #: (square?, E, dE) -> (E E, d(E E)) or (E, dE): only the branch taken is evaluated
        self.square = casadi.Function.conditional(
            "gn_square", [casadi.Function("gn_keep", [E, dE], [E, dE])],
            casadi.Function("gn_sq", [E, dE], [E @ E, casadi.horzcat(*squared)]))
        self.block = BLOCK[min(n, len(BLOCK)) - 1]
        self.blocks = -(-N // self.block)
        self.response, self.response_d = self._response(pattern)
        self.solves = {}

    def _response(self, pattern):
        """``self.block`` samples of the states and free responses, ``w = [x; o; E; gamma2;
        vec(Phi)]`` carried from block to block: ``x_{k+1} = Phi x_k + E u_k + gamma2 u_{k+1}``
        (Eq. 11 with ``E = gamma1 - gamma2``; from ``x_0 = 0`` every term is one power of
        ``Phi`` on ``E`` or ``gamma2``, no start value to cancel) and ``o_{k+1} = Phi^T o_k``
        (``o_k^T = e_1^T Phi^k``). Each block returns one column per series (the states of the
        free ``c_i``, ``c_fixed^T x_k`` where fixed ``c_i`` are nonzero, the ``n`` free
        responses with ``initial``) so that the loop's stacked output is each series
        contiguous in time; the derived loop also returns every series' derivative along the
        columns of ``dw (len(w), nf)``."""
        n, nf = pattern.n, self.nf
        fixed_c = casadi.DM([0.0 if v is None else v for v in pattern.c])
        w = casadi.SX.sym("w", 4 * n + n * n)
        dw = casadi.SX.sym("dw", w.shape[0], nf)
        uk, un = casadi.SX.sym("u", self.block), casadi.SX.sym("u_next", self.block)
        x, o, E, gamma2 = w[:n], w[n: 2 * n], w[2 * n: 3 * n], w[3 * n: 4 * n]
        Phi = casadi.reshape(w[4 * n:], n, n)
        rows = []
        for k in range(self.block):
            row = [x[i] for i in self.free_c]
            if self.fixed:
                row.append(fixed_c.T @ x)
            if pattern.initial:
                row.extend(o[i] for i in range(n))
            rows.append(casadi.horzcat(*row))
            x, o = Phi @ x + E * uk[k] + gamma2 * un[k], Phi.T @ o
        S = casadi.vertcat(*rows)                                  # (block, series)
        w_next = casadi.vertcat(x, o, w[2 * n:])
        series = [S[:, q] for q in range(S.shape[1])]
        plain = casadi.Function("gn_block", [w, uk, un], [w_next, *series])
        d = casadi.jtimes(casadi.vertcat(w_next, casadi.vec(S)), w, dw)
        dS = [casadi.reshape(d[w.shape[0]:, j], self.block, S.shape[1]) for j in range(nf)]
        derived = casadi.Function("gn_block_d", [w, dw, uk, un],
                                  [w_next, d[: w.shape[0], :], *series,
                                   *[dSj[:, q] for dSj in dS for q in range(S.shape[1])]])
        return (plain.mapaccum("gn_response", self.blocks),
                derived.mapaccum("gn_response_d", self.blocks, 2))

    def solve(self, G, b):
        """``G^-1 b`` for a small symmetric positive definite ``G`` (one C function per
        size): Cholesky, backward stable where CasADi's symbolic QR (Gram-Schmidt) loses the
        digits of an ill-conditioned Gram matrix. A ``G`` that is not positive definite in
        floating point gives NaN, which the graph treats as a failed point."""
        key = (G.shape[0], b.shape[1])
        if key not in self.solves:
            Gs, bs = casadi.SX.sym("G", *G.shape), casadi.SX.sym("b", *b.shape)
            self.solves[key] = casadi.Function(f"gn_solve{len(self.solves)}", [Gs, bs],
                                               [_cholesky_solve(Gs, bs)])
        return self.solves[key](G, b)


def _cholesky_solve(G, b):
    """``G^-1 b`` by ``G = L L^T`` written out in SX (``G (p, p)`` SPD, ``b (p, k)``)."""
    p = G.shape[0]
    L = [[casadi.SX(0.0)] * p for _ in range(p)]
    for j in range(p):
        L[j][j] = casadi.sqrt(G[j, j] - sum((L[j][k] ** 2 for k in range(j)), 0.0))
        for i in range(j + 1, p):
            L[i][j] = (G[i, j] - sum((L[i][k] * L[j][k] for k in range(j)), 0.0)) / L[j][j]
    columns = []
    for col in range(b.shape[1]):
        v, x = [None] * p, [None] * p
        for i in range(p):                                        # L v = b
            v[i] = (b[i, col] - sum((L[i][k] * v[k] for k in range(i)), 0.0)) / L[i][i]
        for i in reversed(range(p)):                              # L^T x = v
            x[i] = (v[i] - sum((L[k][i] * x[k] for k in range(i + 1, p)), 0.0)) / L[i][i]
        columns.append(casadi.vertcat(*x))
    return casadi.horzcat(*columns)


def _coefficients(pattern, z):
    """The CCF's ``c (n, 1)`` (fixed entries included), ``d``, ``theta (n, 1)`` (None from
    rest) and the offset from the linear least-squares solution ``z`` (numpy's ``_fit``)."""
    c, k = [], 0
    for v in pattern.c:
        c.append(z[k] if v is None else casadi.MX(v))
        k += v is None
    d = casadi.MX(float(pattern.d)) if pattern.d is not None else z[k]
    k += pattern.d is None
    theta = z[k: k + pattern.n] if pattern.initial else None
    k += pattern.n if pattern.initial else 0
    offset = z[k] if pattern.offset else casadi.MX(0.0)
    return casadi.vertcat(*c), d, theta, offset


def _combine(columns: list, weights):
    """``sum_i weights_i columns_i`` (MX vectors)."""
    total = columns[0] * weights[0]
    for i in range(1, len(columns)):
        total = total + columns[i] * weights[i]
    return total


def _dots(columns: list, v):
    """``[columns_i^T v]`` as a column (``v`` a vector or a list of vectors: a matrix)."""
    vs = v if isinstance(v, list) else [v]
    return casadi.vertcat(*[casadi.horzcat(*[casadi.dot(c, w) for w in vs]) for c in columns])


class _Projection:
    """Numpy's ``_solve`` on the columns of ``M`` (contiguous vectors; the inner products are
    loops over ``N``, not products of ``N x p`` matrices): the column-scaled normal equations
    with a Tikhonov floor and one step of iterative refinement. The columns are scaled by
    their norms (numpy: by their largest entries); both only precondition the same solution."""

    def __init__(self, kernels: _Kernels, columns: list, t) -> None:
        p, N = len(columns), t.shape[0]
        G = casadi.vertcat(*[casadi.horzcat(*[casadi.dot(a, b) for b in columns])
                             for a in columns])
        d = casadi.sqrt(casadi.diag(G))
        self.d = casadi.if_else(d > 0, d, 1.0)
        G = G / (self.d @ self.d.T)
        self.G = G + (batched.RIDGE * casadi.trace(G) + 1e-300) * casadi.DM.eye(p)
        self.kernels, self.columns = kernels, columns
        zs = kernels.solve(self.G, _dots(columns, t) / self.d)
        r = t - _combine(columns, zs / self.d)
        zs = zs + kernels.solve(self.G, _dots(columns, r) / self.d)
        self.z = zs / self.d
        self.r = t - _combine(columns, self.z)
        self.cost = casadi.sumsqr(self.r) / N

    def perpendicular(self, vs: list) -> list:
        """``P_perp v`` for each vector of ``vs``."""
        s = self.kernels.solve(self.G, _dots(self.columns, vs) / self.d) / self.d
        return [v - _combine(self.columns, s[:, j]) for j, v in enumerate(vs)]


class _Point:
    """The projection of one record at ``alpha`` (MX): ``cost`` (inf where not finite or out
    of range), ``z``, ``r``, ``a``, ``Phi``; with ``jacobian`` also Kaufman's
    ``g = J^T r (nf, 1)`` and ``H = J^T J`` for ``J = P_perp d(t - M z)/d alpha``, ``z`` held
    (non-finite entries of ``J`` zero, as numpy)."""

    def __init__(self, pattern, kernels: _Kernels, alpha, y, u, dt, jacobian: bool) -> None:
        n, nf, N = kernels.n, kernels.nf, y.shape[0]
        E, dE, s, self.a = kernels.pade(alpha, dt)
        for i in range(MAX_SQUARINGS):
            E, dE = kernels.square(s > i + 0.5, E, dE)
        self.Phi, gamma1, gamma2 = E[:n, :n], E[:n, n], E[:n, n + 1]
        w1 = casadi.vertcat(casadi.DM.zeros(n), casadi.DM.eye(n)[:, 0], gamma1 - gamma2,
                            gamma2, casadi.vec(self.Phi))
        L = kernels.blocks * kernels.block
        padded = casadi.vertcat(u, casadi.DM.zeros(L + 1 - N))
        inputs = [casadi.reshape(padded[:L], kernels.block, kernels.blocks),
                  casadi.reshape(padded[1:], kernels.block, kernels.blocks)]
        if jacobian:
            dw1 = casadi.horzcat(*[casadi.vertcat(
                casadi.DM.zeros(2 * n), dE[:n, j * (n + 2) + n] - dE[:n, j * (n + 2) + n + 1],
                dE[:n, j * (n + 2) + n + 1], casadi.vec(dE[:n, j * (n + 2): j * (n + 2) + n]))
                for j in range(nf)])
            out = kernels.response_d(w1, dw1, *inputs)[2:]
        else:
            out = kernels.response(w1, *inputs)[1:]
        out = [casadi.reshape(v, L, 1)[:N] for v in out]           # series k = 0 .. N-1
        q = len(out) // (nf + 1) if jacobian else len(out)
        series, derived = out[:q], out[q:]
        columns, t, k = series[: len(kernels.free_c)], y, len(kernels.free_c)
        if kernels.fixed:
            t, k = t - series[k], k + 1
        if pattern.d is None:
            columns.append(u)
        elif pattern.d != 0.0:
            t = t - pattern.d * u
        if pattern.initial:
            columns.extend(series[k: k + n])
        if pattern.offset:
            columns.append(casadi.DM.ones(N, 1))
        fit = _Projection(kernels, columns, t)
        self.z, self.r = fit.z, fit.r
        bad = s > MAX_SQUARINGS + 0.5
        self.cost = casadi.if_else(casadi.logic_and(fit.cost < np.inf, casadi.logic_not(bad)),
                                   fit.cost, np.inf)
        if jacobian:
            # d(t - M z) = -(sum_i c_i dx_i + theta^T do), the fixed c_i through t
            c, _, theta, _ = _coefficients(pattern, self.z)
            weights = [c[i] for i in kernels.free_c] + [1.0] * kernels.fixed
            if pattern.initial:
                weights += [theta[i] for i in range(n)]
            J = [-_combine(derived[j * q: (j + 1) * q], weights) for j in range(nf)]
            J = [casadi.if_else(casadi.fabs(v) < np.inf, v, 0.0)
                 for v in fit.perpendicular(J)]
            self.g = _dots(J, self.r)
            self.H = _dots(J, J)


def _symbols(N: int, width: int):
    """Symbols ``x (width), y (N), u (N), p (3)`` of the step and finish Functions."""
    return (casadi.MX.sym("x", width), casadi.MX.sym("y", N), casadi.MX.sym("u", N),
            casadi.MX.sym("p", 3))


def _step(pattern, kernels: _Kernels, N: int) -> casadi.Function:
    """One iteration of numpy's loop on one record: ``(x, y, u, p) -> x`` with
    ``x = [alpha (nf); lambda; done; accepted]`` and ``p = [dt; tol; stop]`` (``stop``: apply
    the tolerance)."""
    nf = int(pattern.free_a.size)
    x, y, u, p = _symbols(N, nf + 3)
    alpha, lam, accepted = x[:nf], x[nf], x[nf + 2]
    dt, tol, stop = p[0], p[1], p[2]
    inputs = [casadi.MX.sym("alpha", nf), y, u, casadi.MX.sym("dt")]
    now = _Point(pattern, kernels, *inputs, jacobian=True)
    point = casadi.Function("gn_point", inputs, [now.cost, now.g, now.H])
    value = casadi.Function("gn_value", inputs,
                            [_Point(pattern, kernels, *inputs, jacobian=False).cost])
    cost, g, H = point(alpha, y, u, dt)
    diag = casadi.diag(H) + 1e-300
    step = -kernels.solve(H + lam * casadi.diag(diag), g)
    trial = value(alpha + step, y, u, dt)
    finite = cost < np.inf
    better = casadi.logic_and(trial < cost, finite)
    predicted = -(2.0 * casadi.dot(g, step) + casadi.bilin(H, step, step)) / N
    # numpy's rule: a small decrease, actual or predicted, no damped step that descends, or an
    # exact fit (min(cost, trial), NaN when the trial is, at rounding level of the record)
    exact = batched.EXACT * casadi.sumsqr(y) / N
    flat = casadi.logic_or(casadi.logic_or(
        casadi.logic_and(better, cost - trial <= tol * cost), predicted <= tol * cost),
        casadi.logic_or(lam > batched.LAMBDA_MAX, casadi.logic_and(
            trial == trial, casadi.logic_or(cost <= exact, trial <= exact))))
    done = casadi.logic_or(casadi.logic_not(finite), casadi.logic_and(stop, flat))
    lam = casadi.if_else(better, casadi.fmax(lam / batched.LAMBDA_FACTOR, batched.LAMBDA_MIN),
                         lam * batched.LAMBDA_FACTOR)
    x_new = casadi.vertcat(casadi.if_else(better, alpha + step, alpha), lam, done,
                           accepted + better)
    return casadi.Function("gn_step", [x, y, u, p], [x_new])


def _finish(pattern, kernels: _Kernels, N: int) -> casadi.Function:
    """``(x, y, u, p) -> [a (n); c (n); d; x0 (n); y_offset; cost; accepted; done]`` at the
    final point: numpy's ``_fit`` (the initial state from ``c^T Phi^k x0 = e_1^T Phi^k theta``
    over ``k < 2n``; from rest the regressors need no ``gamma2 u_0`` term)."""
    n, nf = pattern.n, int(pattern.free_a.size)
    x, y, u, p = _symbols(N, nf + 3)
    e = _Point(pattern, kernels, x[:nf], y, u, p[0], jacobian=False)
    c, d, theta, offset = _coefficients(pattern, e.z)
    x0 = casadi.MX.zeros(n, 1)
    if pattern.initial:
        O, F, o, f = [], [], c.T, casadi.DM.eye(n)[0, :]
        for _ in range(2 * n):
            O.append(o)
            F.append(f @ theta)
            o, f = o @ e.Phi, f @ e.Phi
        O, F = casadi.vertcat(*O), casadi.vertcat(*F)
        G = O.T @ O
        G = G + (1e-14 * casadi.trace(G) + 1e-300) * casadi.DM.eye(n)
        x0 = kernels.solve(G, O.T @ F)
    out = casadi.vertcat(e.a, c, d, x0, offset, e.cost, x[nf + 2], x[nf + 1])
    return casadi.Function("gn_finish", [x, y, u, p], [out])


def graph(pattern, N: int) -> casadi.Function:
    """The graph of one record: up to :data:`MAX_ITERATIONS` steps, each skipped (not
    evaluated) once the record is done or ``iterations`` are spent, then :func:`_finish`.

    Parameters
    ----------
    pattern : Pattern
    N : int
        Samples of the records.

    Returns
    -------
    casadi.Function
        ``(alpha0 (nf), y (N), u (N), q = [dt; iterations; tol; stop]) -> out`` with
        ``out = [a (n); c (n); d; x0 (n); y_offset; cost; accepted; done]``.
    """
    nf = int(pattern.free_a.size)
    kernels = _Kernels(pattern, N)
    step, finish = _step(pattern, kernels, N), _finish(pattern, kernels, N)
    xs, ys, us, ps = _symbols(N, nf + 3)
    keep = casadi.Function("gn_hold", [xs, ys, us, ps], [xs])
    # index 0 keeps x, 1 runs the step
    switch = casadi.Function.conditional("gn_switch", [keep], step)
    alpha0, q = casadi.MX.sym("alpha0", nf), casadi.MX.sym("q", 4)
    y, u = casadi.MX.sym("y", N), casadi.MX.sym("u", N)
    p = casadi.vertcat(q[0], q[2], q[3])
    x = casadi.vertcat(alpha0, batched.LAMBDA0, 0.0, 0.0)
    for i in range(MAX_ITERATIONS):
        run = casadi.logic_and(casadi.logic_not(x[nf + 1]), q[1] > i + 0.5)
        x = switch(run, x, y, u, p)
    return casadi.Function("gn_record", [alpha0, y, u, q], [finish(x, y, u, p)])
