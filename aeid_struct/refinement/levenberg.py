"""The separable Levenberg-Marquardt of the partly fixed CCFs (``refinement.batched``: the
problem and its iterations), one entry over its two back ends: compiled C record by record where
a C compiler is present (``refinement.compiled``), every record at once in numpy otherwise and
for any record the compiled path does not serve. The identifiers' heads and their refinement
call it.
"""

from __future__ import annotations

import math

import numpy as np

from aeid_struct.refinement import compiled
from aeid_struct.refinement.batched import Pattern, SeparableFit, iterate

__all__ = ["CHUNK", "fit_rows", "gauss_newton"]

#: The most records in one ``gauss_newton`` call of :func:`fit_rows`: its arrays stay in cache,
#: and a batch of any size reuses the memory of one chunk.
CHUNK = 256


def gauss_newton(pattern: Pattern, alpha0, y, u, dt: float, *, iterations: int,
                 tol: float | None = None) -> SeparableFit:
    """Levenberg-Marquardt on the separable cost from ``alpha0``.

    Where a C compiler is present, record by record through the compiled solver
    (``refinement.compiled``: the same iterations with an exact Jacobian, built once per
    pattern and record length in a process); else, and for any record it does not serve,
    every record at once in numpy. The two agree to the forward difference's error.

    Parameters
    ----------
    pattern : Pattern
    alpha0 : (B, nf) array
        Start of the free ``a_j`` (the encoder's estimate).
    y, u : (B, N) arrays
        The records (checked by the caller), ``u`` linear between samples.
    dt : float, > 0
    iterations : int, >= 0
        Iterations (a fixed cost: the identifiers' pass), or the cap with ``tol``.
    tol : float, optional
        Stop a record once a step lowers its cost by less than this fraction (refinement).

    Returns
    -------
    SeparableFit
        The best point each record reached (never worse than the start).

    Notes
    -----
    Each trial point is evaluated with the Jacobian the next iteration needs if it is accepted;
    a rejected step keeps the point and its Jacobian: ``K`` iterations are ``K + 1`` calls.
    """
    alpha, y, u = _checked(pattern, alpha0, y, u, dt, iterations, tol)
    # The compiled path costs less than numpy's per-operation overhead at any batch size, so it
    # serves every batch
    fit = compiled.gauss_newton_rows(
        pattern, alpha, y, u, dt, iterations, tol,
        lambda rows: iterate(pattern, alpha[rows], y[rows], u[rows], dt, iterations, tol))
    return iterate(pattern, alpha, y, u, dt, iterations, tol) if fit is None else fit


def fit_rows(pattern: Pattern, alpha0, y, u, dt: float, *, iterations: int,
             tol: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`gauss_newton` in chunks of :data:`CHUNK` records, as the CCF's arrays: what the
    identifiers' head reads (the fit's own record, ``SeparableFit``, stays in this package).

    Parameters
    ----------
    pattern : Pattern
    alpha0 : (B, nf) array
        Start of the free ``a_j``.
    y, u : (B, N) arrays
    dt : float, > 0
    iterations : int, >= 0
    tol : float, optional

    Returns
    -------
    a, c : (B, n) arrays
        The CCF's ``a_j`` and ``c_j``, fixed ones included.
    d : (B,) array
    ok : (B,) bool array
        Whether the record's fit is finite (its cost; False where the fixed values admit no
        finite model).
    """
    B, n = np.shape(y)[0], pattern.n
    a, c, d = np.empty((B, n)), np.empty((B, n)), np.empty(B)
    ok = np.zeros(B, dtype=bool)
    for part in np.array_split(np.arange(B), max(1, -(-B // CHUNK))):
        fit = gauss_newton(pattern, np.asarray(alpha0)[part], np.asarray(y)[part],
                           np.asarray(u)[part], dt, iterations=iterations, tol=tol)
        a[part], c[part], d[part] = fit.a, fit.c, fit.d
        ok[part] = np.isfinite(fit.cost)
    return a, c, d, ok


def _checked(pattern, alpha0, y, u, dt, iterations, tol):
    """``gauss_newton``'s arguments as float64 arrays ``alpha (B, nf), y, u (B, N)``, or a
    ValueError naming the first that is not what it must be."""
    if not isinstance(pattern, Pattern):
        raise ValueError(f"pattern must be a refinement.Pattern; got {type(pattern).__name__}")
    y = np.ascontiguousarray(y, dtype=np.float64)
    u = np.ascontiguousarray(u, dtype=np.float64)
    if y.ndim != 2 or y.shape[1] < 2 or u.shape != y.shape:
        raise ValueError(f"y and u must be (records, samples) arrays of one shape with at least "
                         f"2 samples; got {y.shape} and {u.shape}")
    if not (np.isfinite(y).all() and np.isfinite(u).all()):
        raise ValueError("y and u must be finite")
    if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not (
            math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive finite number; got {dt!r}")
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) \
            or iterations < 0:
        raise ValueError(f"iterations must be an integer >= 0; got {iterations!r}")
    if tol is not None and not (isinstance(tol, float) and 0 < tol < 1):
        raise ValueError(f"tol must be None or a float in (0, 1); got {tol!r}")
    alpha = np.array(alpha0, dtype=np.float64)
    if alpha.shape != (y.shape[0], pattern.free_a.size):
        raise ValueError(f"alpha0 must have {pattern.free_a.size} free a_j per record, shape "
                         f"{(y.shape[0], pattern.free_a.size)}; got shape {alpha.shape}")
    return alpha, y, u
