r"""Separable output-error refinement of the free canonical forms (variable projection in numpy).

The model of a record (docs/architecture.md, "Any system, any record") in normalised time
(``dt = 1``) with an input delay of ``D`` samples (``y[D:]`` against ``u[:N-D]``):

    y = M(alpha) z + e,    M = [X(alpha), u, F(alpha), 1],    z = [c; d; theta; y_offset],

is LINEAR in everything but the ``n`` coefficients of the continuous denominator
``s^n + alpha_{n-1} s^{n-1} + ... + alpha_0`` (the elements ``a_0 .. a_{n-1}`` of a CCF): ``X``
the exact FOH forced states (Eq. 10-12), ``F`` the free responses (a basis of every
``c^T Phi^k x_0``). Variable projection (Golub & Pereyra) eliminates ``z``: the cost

    V(alpha) = ||P_perp(alpha) y||^2 / m,    P_perp = I - Q Q^T,   Q an orthonormal basis of M,

depends on ``alpha`` alone, and ``c, d, x_0, y_offset`` are the exact least-squares solution at
every ``alpha`` (:func:`~aeid_struct.simulation.project`). :func:`refine_separable` minimises it
by Levenberg-Marquardt with Kaufman's Jacobian ``J = -P_perp d(M z)/d alpha`` (``z`` held).

*The Jacobian.* In the shift operator the dynamic part of the output is
``(B(q^-1) u + C(q^-1) delta) / A(q^-1)``, with ``A = 1 + beta_1 q^-1 + ... + beta_n q^-n``
the discrete denominator (poles ``e^p``). A change of the numerators ``B, C`` at fixed ``A``
stays in the span of ``M`` (with a feedthrough ``X, u`` span every ``B / A u``; ``F`` every
``C / A delta``), and ``P_perp`` removes it; what remains is the classical output-error
sensitivity ``d y / d beta_i = -q^-i / A (y_hat - y_offset)``: ONE IIR filter of the model's
dynamic output and ``n`` shifts, chained with the ``n x n`` map ``d beta / d alpha`` (complex
step through the matrix exponential of Eq. 10 and the characteristic polynomial of ``Phi``).
Without a feedthrough the numerators ``B`` of a strictly proper model are an ``n``-dimensional
subspace that moves with ``alpha``; the term ``d B / d alpha (c held) / A u`` is added (the
same complex step). Kaufman's gradient ``J^T r`` is the exact gradient of ``V``.

*Why numpy and not CasADi.* ``refinement.refine_record`` unrolls the FOH response over a bucket
of samples into one CasADi graph and differentiates it in all free elements (``a`` and ``c``,
``d``); the separable problem has ``n`` decision variables and its Jacobian is one ``lfilter``
plus shifts, so it is several times cheaper per iteration (the times side by side are in the
comment above :func:`refine_separable`). It serves the FREE canonical forms only:
``refine_record`` stays the path for structures with fixed elements, physical structures and
bounds (an MCF's ``Re < 0``), and for every structure that is not a CCF in disguise.
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.linalg
import scipy.signal

from aeid_struct.refinement.record import RecordFit
from aeid_struct.simulation import project

__all__ = ["projected_cost", "refine_separable"]

#: Levenberg-Marquardt damping: start (relative to diag(J^T J)), factor, give-up value.
_LAMBDA0, _LAMBDA_FACTOR, _LAMBDA_MAX = 1e-3, 10.0, 1e10
#: Complex step (relative to each coefficient's scale).
_STEP = 1e-20
#: Central-difference step of the denominator map (relative).
_FD = 1e-5
#: Poles closer than this (relative to the largest) take the central differences.
_DISTINCT = 1e-3


def _ccf(alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bottom-row CCF ``(K, n, n), (n,)`` of ``alpha (K, n)`` (real or complex)."""
    K, n = alpha.shape
    A = np.zeros((K, n, n), dtype=alpha.dtype)
    A[:, np.arange(n - 1), np.arange(1, n)] = 1.0
    A[:, n - 1, :] = -alpha
    b = np.zeros(n)
    b[-1] = 1.0
    return A, b


def _discrete(alpha: np.ndarray):
    """The small map of ``alpha (K, n)`` (complex-safe, for the complex step): discrete
    denominator ``a (K, n + 1)`` (``a_0 = 1``), FOH numerators ``num (K, n + 1, n)`` of the
    forced states (as ``simulation.project``) and ``gamma2 (K, n)``."""
    K, n = alpha.shape
    A, b = _ccf(alpha)
    E = np.zeros((K, n + 2, n + 2), dtype=alpha.dtype)
    E[:, :n, :n], E[:, :n, n], E[:, n, n + 1] = A, b, 1.0
    X = scipy.linalg.expm(E)
    Phi, gamma1, gamma2 = X[:, :n, :n], X[:, :n, n], X[:, :n, n + 1]
    Bd = gamma1 - gamma2 + np.einsum("kij,kj->ki", Phi, gamma2)
    # characteristic polynomial of Phi by Faddeev-LeVerrier: only products and traces, so the
    # complex step goes through it (np.poly of the eigenvalues does not)
    a = np.zeros((K, n + 1), dtype=alpha.dtype)
    a[:, 0] = 1.0
    Mk = np.zeros_like(Phi)
    eye = np.eye(n)
    for k in range(1, n + 1):
        Mk = Phi @ Mk + a[:, k - 1, None, None] * eye
        a[:, k] = -np.einsum("kii->k", Phi @ Mk) / k
    markov = np.empty((K, n, n), dtype=alpha.dtype)
    markov[:, 0] = Bd
    for m in range(1, n):
        markov[:, m] = np.einsum("kij,kj->ki", Phi, markov[:, m - 1])
    num = np.zeros((K, n + 1, n), dtype=alpha.dtype)
    for k in range(1, n + 1):
        num[:, k] = sum(a[:, i, None] * markov[:, k - 1 - i] for i in range(k))
    return a, num, gamma2


def _with_derivatives(alpha: np.ndarray):
    """``a, num, gamma2`` at ``alpha (n,)`` and their derivatives along each ``alpha_j`` (a
    leading axis of ``n``), by one batched complex step."""
    n = alpha.shape[0]
    h = _STEP * np.maximum(np.abs(alpha), 1e-8)
    batch = np.repeat(alpha[None].astype(complex), n + 1, axis=0)
    batch[1 + np.arange(n), np.arange(n)] += 1j * h
    a, num, gamma2 = _discrete(batch)
    d = (1.0 / h)[:, None]
    return (a[0].real, num[0].real, gamma2[0].real, a[1:].imag * d,
            num[1:].imag * d[:, :, None], gamma2[1:].imag * d)


def _shifts(x: np.ndarray, first: int, last: int) -> np.ndarray:
    """Columns ``q^-k x`` for ``k = first .. last`` (zeros shifted in), ``(m, last-first+1)``."""
    m = x.shape[0]
    out = np.zeros((m, last - first + 1))
    for j, k in enumerate(range(first, last + 1)):
        out[k:, j] = x[: m - k]
    return out


def _poly(z: np.ndarray, real: bool = True) -> np.ndarray:
    """Monic coefficients ``(K, n + 1)`` (highest power first) of the roots ``z (K, n)``
    (their real parts where ``real``)."""
    K, n = z.shape
    a = np.zeros((K, n + 1), dtype=complex)
    a[:, 0] = 1.0
    for j in range(n):
        a[:, 1 : j + 2] -= z[:, j : j + 1] * a[:, : j + 1]
    return a.real if real else a


def _denominator(alpha: np.ndarray) -> np.ndarray:
    """The discrete denominator ``a (n + 1,)`` of ``alpha (n,)``: poles ``e^p``, ``a_0 = 1``."""
    A, _ = _ccf(alpha[None])
    return _poly(np.exp(np.linalg.eigvals(A)))[0]


def _denominator_derivative(alpha: np.ndarray) -> np.ndarray:
    """``d a / d alpha (n + 1, n)``. Distinct poles: by the chain ``alpha -> p -> z = e^p ->
    a`` (``dp_i / d alpha_j = -p_i^j / A'(p_i)``, ``da / dz_i = -prod_{k != i} (x - z_k)``);
    nearly repeated poles (where ``1 / A'(p_i)`` loses the digits): central differences, all
    ``2 n + 1`` points in one batched eigenvalue call (``a`` is a symmetric function of the
    poles, smooth in ``alpha`` also where they coincide)."""
    n = alpha.shape[0]
    A, _ = _ccf(alpha[None])
    p = np.linalg.eigvals(A)[0]
    gap = np.where(np.eye(n, dtype=bool), np.inf, np.abs(p[:, None] - p[None, :]))
    if n == 1 or gap.min() > _DISTINCT * np.abs(p).max():
        z = np.exp(p)
        powers = p[:, None] ** np.arange(n + 1)[None, :]                     # p_i^k
        coef = np.concatenate([alpha, [1.0]])                                # lowest first
        dA = powers[:, :n] @ (np.arange(1, n + 1) * coef[1:])                # A'(p_i)
        dp = -powers[:, :n] / dA[:, None]                                    # (poles, n)
        rest = np.array([[k for k in range(n) if k != i] for i in range(n)], dtype=int)
        others = _poly(z[rest], real=False)                                  # (n, n)
        da = np.zeros((n + 1, n), dtype=complex)
        da[1:] = -(others.T * z[None, :]) @ dp
        return da.real
    h = _FD * np.maximum(np.abs(alpha), 1e-12 + 1e-8 * np.abs(alpha).max())
    batch = np.repeat(alpha[None], 2 * n + 1, axis=0)
    batch[1 + np.arange(n), np.arange(n)] += h
    batch[1 + n + np.arange(n), np.arange(n)] -= h
    A, _ = _ccf(batch)
    a = _poly(np.exp(np.linalg.eigvals(A)))
    return ((a[1 : n + 1] - a[n + 1 :]) / (2.0 * h)[:, None]).T


def _differences(x: np.ndarray, k: int, out: np.ndarray) -> None:
    """``out[j] = (1 - q^-1)^j x`` for ``j < k``: the shifts' span in a basis that stays well
    conditioned when the poles are slow (shifted copies of a smooth signal are nearly equal)."""
    out[0] = x
    for j in range(1, k):
        out[j, 0] = out[j - 1, 0]
        np.subtract(out[j - 1, 1:], out[j - 1, :-1], out=out[j, 1:])


class _Problem:
    """The projected residual of one record at one delay (normalised time)."""

    def __init__(self, y, u, delay, feedthrough, offset):
        self.m = m = y.shape[0] - delay
        self.y, self.u = y[delay:], u[:m]
        self.feedthrough, self.offset = feedthrough, offset
        self.impulse = np.zeros(m)
        self.impulse[0] = 1.0

    def _regressors(self, alpha: np.ndarray, a: np.ndarray):
        """``(M (p, m), W)``: the regressors one per row (``M = [forced (n + 1 with a
        feedthrough, else n); free (n); ones]``), None where not finite; ``W`` the shifts of the
        filtered input (without a feedthrough)."""
        n, m = alpha.shape[0], self.m
        w = scipy.signal.lfilter([1.0], a, self.u)
        g = scipy.signal.lfilter([1.0], a, self.impulse)
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(g))):
            return None
        forced = n + int(self.feedthrough)
        M = np.empty((forced + n + int(self.offset), m))
        W = None
        if self.feedthrough:
            # with d free, X and u span every B(q^-1) / A(q^-1) u of degree n
            _differences(w, n + 1, M[: n + 1])
        else:
            num, gamma2 = _discrete(alpha[None])[1:]
            W = _shifts(w, 0, n)
            M[:n] = (W @ num[0]).T + gamma2[0][:, None] * self.u
        _differences(g, n, M[forced : forced + n])    # every free response C / A delta
        if self.offset:
            M[-1] = 1.0
        return M, W

    def evaluate(self, alpha: np.ndarray):
        """The projection at ``alpha``: a dict with ``cost = ||r||^2 / m``, ``r = P_perp y``
        and what :meth:`jacobian` reuses; ``cost = inf`` where the response is not finite.

        The least squares by column-scaled normal equations and one step of iterative
        refinement: the difference basis keeps ``cond(M)`` small (below ~1e4 from
        ``|p| = 0.005`` to 2.5 per sample), a QR of ``M`` costs several times more."""
        with np.errstate(all="ignore"):
            a = _denominator(alpha)
            got = self._regressors(alpha, a) if np.all(np.isfinite(a)) else None
            if got is None:
                return {"cost": math.inf}
            M, W = got
            scale = np.abs(M).max(axis=1)
            M /= np.where(scale > 0, scale, 1.0)[:, None]
            try:
                Gi = np.linalg.inv(M @ M.T)
            except np.linalg.LinAlgError:
                return {"cost": math.inf}
            z = Gi @ (M @ self.y)
            r = self.y - z @ M
            z += Gi @ (M @ r)
            fitted = z @ M
            r = self.y - fitted
            cost = float(r @ r) / self.m
        if not math.isfinite(cost):
            return {"cost": math.inf}
        return {"cost": cost, "r": r, "alpha": alpha, "a": a, "M": M, "Gi": Gi, "z": z,
                "fitted": fitted, "scale": scale, "W": W}

    def jacobian(self, e: dict) -> np.ndarray:
        """Kaufman's ``J = dr / d alpha (m, n)`` at the evaluation ``e``."""
        alpha, a, M, z = e["alpha"], e["a"], e["M"], e["z"]
        n = alpha.shape[0]
        with np.errstate(all="ignore"):
            if self.feedthrough:
                da = _denominator_derivative(alpha)
                parts = None
            else:
                _, num, gamma2, da, dnum, dgamma2 = _with_derivatives(alpha)
                da, parts = da.T, (num, gamma2, dnum, dgamma2)
            dynamic = e["fitted"] - (z[-1] if self.offset else 0.0)
            v = scipy.signal.lfilter([1.0], a, dynamic)
            dy = -_shifts(v, 1, n) @ da[1:]               # d y_hat / d alpha, (m, n)
            if parts is not None:
                # no feedthrough: B = num c + (gamma2 . c) a moves outside the span; its
                # derivative with c held
                num, gamma2, dnum, dgamma2 = parts
                c = z[:n] / e["scale"][:n]
                dB = (dnum @ c + (dgamma2 @ c)[:, None] * a[None]
                      + float(gamma2 @ c) * da.T)        # (n, n + 1): row j = d B / d alpha_j
                dy += e["W"] @ dB.T
            return -(dy - M.T @ (e["Gi"] @ (M @ dy)))


def projected_cost(den, y, u, *, delay: int = 0, feedthrough: bool = True,
                   offset: bool = True) -> tuple[float, np.ndarray]:
    """The separable cost ``V(alpha)`` of the module docstring and its gradient.

    Parameters
    ----------
    den : (n + 1,) array
        Monic continuous denominator in normalised time (dt = 1), highest power first:
        ``[1, alpha_{n-1}, ..., alpha_0]``.
    y, u : (steps,) arrays
    delay : int
    feedthrough, offset : bool
        As for :func:`~aeid_struct.simulation.project`.

    Returns
    -------
    cost : float
        Mean squared residual on the fitted samples (``project``'s ``cost``); inf where the
        response is not finite.
    gradient : (n,) array
        ``d cost / d alpha_j``, ``j = 0 .. n - 1`` (lowest power first, the CCF's ``a_j``).
    """
    y, u, den = _arrays(y, u, den)
    _check(den, y, delay)
    problem = _Problem(y, u, int(delay), bool(feedthrough), bool(offset))
    e = problem.evaluate(den[:0:-1].copy())
    if not math.isfinite(e["cost"]):
        return e["cost"], np.full(den.shape[0] - 1, np.nan)
    return e["cost"], 2.0 * (problem.jacobian(e).T @ e["r"]) / problem.m


def _arrays(y, u, den):
    return (np.ascontiguousarray(y, dtype=np.float64), np.ascontiguousarray(u, dtype=np.float64),
            np.asarray(den, dtype=np.float64).reshape(-1))


def _check(den: np.ndarray, y: np.ndarray, delay) -> None:
    if den.shape[0] < 2 or den[0] != 1.0 or not np.all(np.isfinite(den)):
        raise ValueError(f"den must be a finite monic denominator [1, alpha_(n-1), ..., "
                         f"alpha_0] of order n >= 1; got {den!r}")
    n = den.shape[0] - 1
    if isinstance(delay, bool) or not isinstance(delay, (int, np.integer)) or not (
            0 <= delay <= y.shape[0] - 3 * n - 2):
        raise ValueError(f"delay must be an integer in [0, {y.shape[0] - 3 * n - 2}] (the "
                         f"record has {y.shape[0]} samples, order {n}); got {delay!r}")


def _levenberg_marquardt(problem: _Problem, alpha, max_iter, cost_tol, step_tol):
    """Minimise ``V`` from ``alpha``: ``(alpha, cost, iterations, converged)``.

    Converged: a step below ``step_tol`` (relative), an accepted step or the Gauss-Newton
    prediction lowering the cost by less than ``cost_tol`` (relative), or a damping beyond
    :data:`_LAMBDA_MAX` (no damped step descends)."""
    now = problem.evaluate(alpha)
    if not math.isfinite(now["cost"]):
        return alpha, now["cost"], 0, False
    # relative units: alpha_j ~ |p|^(n-j) spans decades; Marquardt's diag(J^T J) damping is
    # scale-free, the step test is relative
    scale = np.maximum(np.abs(alpha), 1e-6 * np.abs(alpha).max())
    J = problem.jacobian(now) * scale
    lam, iterations = _LAMBDA0, 0
    while iterations < max_iter:
        iterations += 1
        r = now["r"]
        g, H = J.T @ r, J.T @ J
        diag = np.diag(H) + 1e-300
        try:
            step = np.linalg.solve(H + lam * np.diag(diag), -g)
        except np.linalg.LinAlgError:
            step = -g / (lam * diag)
        # the linear model's decrease of ||r||^2: below cost_tol, no step can do better
        predicted = -(2.0 * g @ step + step @ H @ step)
        if np.max(np.abs(step)) <= step_tol or predicted <= cost_tol * float(r @ r):
            return alpha, now["cost"], iterations, True
        trial = alpha + scale * step
        new = problem.evaluate(trial)
        if new["cost"] < now["cost"]:
            flat = now["cost"] - new["cost"] <= cost_tol * now["cost"]
            alpha, now = trial, new
            lam = max(lam / _LAMBDA_FACTOR, 1e-15)
            if flat:
                return alpha, now["cost"], iterations, True
            J = problem.jacobian(now) * scale
        else:
            lam *= _LAMBDA_FACTOR
            if lam > _LAMBDA_MAX:
                return alpha, now["cost"], iterations, True
    return alpha, now["cost"], iterations, False


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
                     step_tol: float = 1e-10) -> RecordFit:
    """Refine a free CCF (denominator and, by projection, ``c, d, x_0, y_offset``) on a whole
    record by separable least squares (module docstring).

    Parameters
    ----------
    den : (n + 1,) array
        Monic start denominator in the time unit of ``dt``, highest power first.
    y, u : (steps,) arrays
        The record (checked by the caller), ``u`` linear between samples.
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

    Returns
    -------
    RecordFit
        As :func:`~aeid_struct.refinement.refine_record` for ``CCF(n, feedthrough)``:
        ``elements`` ``a_j, c_j`` (and ``d``) in the time unit of ``dt``, ``A, b, c, d`` that
        CCF, ``x0`` its state at sample ``delay``; ``cost`` normalised
        (``(1 - fit / 100)^2``).

    Raises
    ------
    ValueError
        Naming the argument: a denominator that is not monic and finite, ``y`` and ``u`` of
        other shapes, a bad ``dt``, ``delay`` or ``max_iter``.
    """
    t0 = time.perf_counter()
    y, u, den = _arrays(y, u, den)
    if y.ndim != 1 or u.shape != y.shape:
        raise ValueError(f"y and u must have the same shape (steps,); got {y.shape} and "
                         f"{u.shape}")
    if not (isinstance(dt, (int, float, np.floating)) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive finite number; got {dt!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1; got {max_iter!r}")
    _check(den, y, delay)
    n = den.shape[0] - 1
    powers = float(dt) ** np.arange(n + 1)
    problem = _Problem(y, u, int(delay), bool(feedthrough), bool(offset))
    alpha = (den * powers)[:0:-1].copy()
    alpha, _, iterations, converged = _levenberg_marquardt(problem, alpha, int(max_iter),
                                                           cost_tol, step_tol)
    den_n = np.concatenate([[1.0], alpha[::-1]])
    return _result(den_n, y, u, float(dt), int(delay), feedthrough, offset, iterations,
                   converged, t0)


def _result(den_n, y, u, dt, delay, feedthrough, offset, iterations, converged, t0):
    """The :class:`RecordFit` of the normalised denominator ``den_n``: ``project`` for the
    linear part, then the physical-time CCF (``a_j / dt^(n-j)``, the state transformed)."""
    n = den_n.shape[0] - 1
    An = np.zeros((n, n))
    An[np.arange(n - 1), np.arange(1, n)] = 1.0
    An[-1] = -den_n[:0:-1]
    bn = np.eye(n)[-1]
    p = project(An, bn, y, u, 1.0, delay=delay, feedthrough=feedthrough, offset=offset)
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
    return RecordFit(elements={k: float(v) for k, v in zip(names, values, strict=True)},
                     A=As, b=bn, c=c, d=float(p.d), x0=T @ p.x0, y_offset=p.y_offset,
                     delay=delay, cost=float(cost), fit=float(p.fit), y_hat=p.y_hat,
                     iterations=iterations, seconds=time.perf_counter() - t0,
                     converged=converged)
