"""Batched small-matrix kernels of the separable Gauss-Newton (``refinement.batched``): Eq. 10's
``Phi, gamma1, gamma2`` of many bottom-row CCFs, the matrix exponential behind them, and the rows
``e_i^T Phi^k`` of their powers.

Why not scipy or numpy's ``matmul``: ``scipy.linalg.expm`` loops over a batch in Python, and
``matmul`` over many ``1 x n`` by ``n x n`` products spends its time per product, not per flop;
here every kernel is a handful of vectorised operations over the whole batch.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["discrete", "expm_batch", "state_rows"]


def discrete(a: np.ndarray, dt: float):
    """``Phi (B, n, n), gamma1, gamma2 (B, n)`` of Eq. 10 for the CCFs of ``a (B, n)``."""
    B, n = a.shape
    E = np.zeros((B, n + 2, n + 2))
    E[:, np.arange(n - 1), np.arange(1, n)] = dt
    E[:, n - 1, :n] = -a * dt
    E[:, n - 1, n] = dt
    E[:, n, n + 1] = 1.0
    X = expm_batch(E)
    return X[:, :n, :n], X[:, :n, n], X[:, :n, n + 1]


#: Taylor coefficients ``1/k!``, ``k = 0 .. 15``, in four blocks (:func:`expm_batch`).
_TAYLOR = np.array([[1.0 / math.factorial(4 * i + j) for j in range(4)] for i in range(4)])


def expm_batch(E: np.ndarray) -> np.ndarray:
    """``expm`` of each small matrix of ``E (B, m, m)``: Taylor of degree 15 with scaling and
    squaring (truncation below ``0.5^16 / 16! < 1e-18`` for ``||X||_1 <= 1/2``), each matrix
    squared its own number of times.

    Why not ``scipy.linalg.expm``: it loops over a batch in Python (tens of microseconds per
    4 x 4 matrix). Here the polynomial is evaluated the Paterson-Stockmeyer way, ``X^2, X^3,
    X^4``, the four blocks ``sum_j c_{4i+j} X^j`` in one product with :data:`_TAYLOR` and
    Horner in ``X^4``: six batched products and a handful of additions whatever the batch,
    which matters where a call costs numpy's per-operation overhead (a few records)."""
    with np.errstate(all="ignore"):
        norm = np.abs(E).sum(axis=1).max(axis=1)
        s = np.where(norm > 0.5, np.ceil(np.log2(np.maximum(norm, 0.5) / 0.5)), 0.0)
        s = np.where(np.isfinite(s), s, 0.0).astype(int)
        X = E / np.ldexp(1.0, s)[:, None, None]
        P = np.empty((3, *X.shape))                                   # X, X^2, X^3
        P[0] = X
        np.matmul(X, X, out=P[1])
        np.matmul(P[1], X, out=P[2])
        m = X.shape[1]
        blocks = (_TAYLOR[:, 1:] @ P.reshape(3, -1)).reshape(4, *X.shape)
        blocks[:, :, np.arange(m), np.arange(m)] += _TAYLOR[:, :1, None]
        X4 = P[1] @ P[1]
        T = blocks[3]
        for i in (2, 1, 0):
            T = T @ X4 + blocks[i]
        for i in range(int(s.max(initial=0))):
            more = s > i
            T = T @ T if more.all() else np.where(more[:, None, None], T @ T, T)
    return T


def state_rows(Phi: np.ndarray, rows: np.ndarray, N: int) -> np.ndarray:
    """``e_i^T Phi^k`` for the states ``rows`` and ``k < N``, ``(B, r, N, n)``, by doubling:
    ``log2 N`` levels, each one batched product ``R[.., m:m+k, :] = R[.., :k, :] Phi^m``.

    Why time before the state: each level is then one ``(k x n) (n x n)`` product per record
    and state, a few calls whatever the batch (not ``k`` products of ``1 x n`` rows, nor ``n^2``
    broadcast operations)."""
    B, n, _ = Phi.shape
    R = np.empty((B, rows.size, N, n))
    R[:, :, 0] = np.eye(n)[rows]
    m, step = 1, Phi[:, None]
    while m < N:
        k = min(m, N - m)
        np.matmul(R[:, :, :k], step, out=R[:, :, m: m + k])
        m += k
        if m < N:
            step = step @ step
    return R
