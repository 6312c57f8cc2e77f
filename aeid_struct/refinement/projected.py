r"""The variable-projection problem of one record of a free CCF: the projected cost
``V(alpha)``, its residual and Kaufman's Jacobian (numpy). The seam: this module says what
is minimised and its derivative; ``separable.py`` minimises it (Levenberg-Marquardt) and
returns the model in physical time.

The model of a record (docs/architecture.md, "Any system, any record") in normalised time
(``dt = 1``) with an input delay of ``D`` samples (``y[D:]`` against ``u[:N-D]``):

    y = M(alpha) z + e,    M = [X(alpha), u, F(alpha), 1],    z = [c; d; theta; y_offset],

is LINEAR in everything but the ``n`` coefficients of the continuous denominator
``s^n + alpha_{n-1} s^{n-1} + ... + alpha_0`` (the elements ``a_0 .. a_{n-1}`` of a CCF): ``X``
the exact FOH forced states (Eq. 10-12), ``F`` the free responses (a basis of every
``c^T Phi^k x_0``). Variable projection (Golub & Pereyra) eliminates ``z``: the cost

    V(alpha) = ||P_perp(alpha) y||^2 / m,    P_perp = I - Q Q^T,   Q an orthonormal basis of M,

depends on ``alpha`` alone, and ``c, d, x_0, y_offset`` are the exact least-squares solution at
every ``alpha`` (:func:`~aeid_struct.simulation.project`).
:func:`~aeid_struct.refinement.refine_separable` minimises it by Levenberg-Marquardt with
Kaufman's Jacobian ``J = -P_perp d(M z)/d alpha`` (``z`` held).

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
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.signal

from aeid_struct.records import require_finite
from aeid_struct.simulation import discrete_foh
from aeid_struct.structures import ccf_matrices

__all__ = ["Problem", "as_arrays", "check_arguments", "projected_cost"]

#: Complex step (relative to each coefficient's scale).
_STEP = 1e-20
#: Central-difference step of the denominator map (relative).
_FD = 1e-5
#: Poles closer than this (relative to the largest) take the central differences.
_DISTINCT = 1e-3


def _ccf(alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bottom-row CCF ``(K, n, n), (n,)`` of ``alpha (K, n)`` (real or complex)."""
    A, b, _ = ccf_matrices(alpha, None)
    return A, b[0]


def _discrete(alpha: np.ndarray, intersample: str = "foh"):
    """The small map of ``alpha (K, n)`` (complex-safe, for the complex step): discrete
    denominator ``a (K, n + 1)`` (``a_0 = 1``), numerators ``num (K, n + 1, n)`` of the
    forced states (as ``simulation.project``) and ``gamma2 (K, n)`` (zero for a held input:
    ``simulation.discrete_foh``)."""
    K, n = alpha.shape
    A, b = _ccf(alpha)
    Phi, gamma1, gamma2 = discrete_foh(A, b, 1.0, intersample)
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


def _with_derivatives(alpha: np.ndarray, intersample: str = "foh"):
    """``a, num, gamma2`` at ``alpha (n,)`` and their derivatives along each ``alpha_j`` (a
    leading axis of ``n``), by one batched complex step."""
    n = alpha.shape[0]
    h = _STEP * np.maximum(np.abs(alpha), 1e-8)
    batch = np.repeat(alpha[None].astype(complex), n + 1, axis=0)
    batch[1 + np.arange(n), np.arange(n)] += 1j * h
    a, num, gamma2 = _discrete(batch, intersample)
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


class Problem:
    """The projected residual of one record at one delay (normalised time), under the
    record's hold (``intersample``: with a feedthrough both holds span every ``B / A u`` of
    degree ``n``; without one the strictly proper numerators differ)."""

    def __init__(self, y, u, delay, feedthrough, offset, intersample: str = "foh"):
        self.m = m = y.shape[0] - delay
        self.y, self.u = y[delay:], u[:m]
        self.feedthrough, self.offset = feedthrough, offset
        self.intersample = intersample
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
            num, gamma2 = _discrete(alpha[None], self.intersample)[1:]
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
                _, num, gamma2, da, dnum, dgamma2 = _with_derivatives(alpha, self.intersample)
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
                   offset: bool = True, intersample: str = "foh") -> tuple[float, np.ndarray]:
    """The separable cost ``V(alpha)`` of the module docstring and its gradient.

    Parameters
    ----------
    den : (n + 1,) array
        Monic continuous denominator in normalised time (dt = 1), highest power first:
        ``[1, alpha_{n-1}, ..., alpha_0]``.
    y, u : (steps,) arrays
    delay : int
    feedthrough, offset, intersample
        As for :func:`~aeid_struct.simulation.project`.

    Returns
    -------
    cost : float
        Mean squared residual on the fitted samples (``project``'s ``cost``); inf where the
        response is not finite.
    gradient : (n,) array
        ``d cost / d alpha_j``, ``j = 0 .. n - 1`` (lowest power first, the CCF's ``a_j``).
    """
    y, u, den = as_arrays(y, u, den)
    check_arguments(den, y, delay)
    problem = Problem(y, u, int(delay), bool(feedthrough), bool(offset), intersample)
    e = problem.evaluate(den[:0:-1].copy())
    if not math.isfinite(e["cost"]):
        return e["cost"], np.full(den.shape[0] - 1, np.nan)
    return e["cost"], 2.0 * (problem.jacobian(e).T @ e["r"]) / problem.m


def as_arrays(y, u, den):
    """``y, u`` as contiguous float64 arrays (a ValueError naming one that is not finite) and
    ``den`` as a flat float64 array."""
    y = np.ascontiguousarray(y, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    require_finite("y", y)
    require_finite("u", u)
    return y, u, np.asarray(den, dtype=np.float64).reshape(-1)


def check_arguments(den: np.ndarray, y: np.ndarray, delay) -> None:
    """ValueError, naming the argument, for a denominator that is not finite and monic of
    order >= 1, or a ``delay`` that leaves fewer than ``3 n + 2`` samples of ``y``."""
    if den.shape[0] < 2 or den[0] != 1.0 or not np.all(np.isfinite(den)):
        raise ValueError(f"den must be a finite monic denominator [1, alpha_(n-1), ..., "
                         f"alpha_0] of order n >= 1; got {den!r}")
    n = den.shape[0] - 1
    if isinstance(delay, bool) or not isinstance(delay, (int, np.integer)) or not (
            0 <= delay <= y.shape[0] - 3 * n - 2):
        raise ValueError(f"delay must be an integer in [0, {y.shape[0] - 3 * n - 2}] (the "
                         f"record has {y.shape[0]} samples, order {n}); got {delay!r}")
