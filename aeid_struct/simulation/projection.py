r"""The linear part of a record's model, by least squares (variable projection), in numpy.

A measured record is modelled (docs/architecture.md, "Any system, any record") as

    y_{D+k} = c^T x_k + d u_k + y_offset,      k = 0 .. N - D - 1,
    x_{k+1} = Phi x_k + E u_k + gamma2 u_{k+1}  (Eq. 10-12, exact first-order hold),

with an input delay of ``D`` samples (``y[D:]`` against ``u[:N-D]``; the samples before ``D``
depend on inputs before the record and are not fitted) and an initial state ``x_0`` that need not
be rest. For a fixed ``(A, b)`` the output is linear in everything else: ``x_k`` is the forced
response from ``x_0 = gamma2 u_0`` plus the free response ``Phi^k delta``, so

    y = X c + u d + O(c) delta + 1 y_offset,

and with ``c`` unknown the free response ``c^T Phi^k delta`` is spanned by the ``n`` columns
``e_1^T Phi^k e_j`` (the first state of a controllable canonical form is observable, so these span
every free response; for another realisation :func:`project` needs its first state observable).
:func:`project` solves for ``c, d, delta, y_offset`` (the generic identifier's pass: only the
poles come from the network); :func:`fit_initial` solves for ``delta, y_offset`` with ``c, d``
given (MATLAB's ``compare`` with the initial state estimated).

Why not :func:`~aeid_struct.simulation.simulate_outputs`: it convolves directly (``O(N^2)``), which
keeps each sample's relative accuracy for unstable and very fast poles; these fits are for the
generic identifiers' stable band and are called for many candidate models per record, so the
forced response is one IIR filter (``scipy.signal.lfilter``, ``O(N n)``) of the discrete
denominator, then an ``n``-tap FIR per state; ``tests/test_projection.py`` checks both against
the exact kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.signal

from aeid_struct.simulation.numpy_foh import discrete_foh, free_basis

__all__ = ["Projection", "fit_initial", "forced_states", "project"]


@dataclass(frozen=True)
class Projection:
    """The least-squares linear part of a record's model and its fit.

    Attributes
    ----------
    c : (n,) array
    d : float
    x0 : (n,) array
        The state at the first fitted sample (sample ``delay`` of the record).
    y_offset : float
        0 where no offset was fitted.
    y_hat : (steps,) array
        The model's output; NaN on the ``delay`` samples that are not fitted.
    fit : float
        NRMSE fit in % on the fitted samples (MATLAB's ``compare``): ``100 (1 - ||y - y_hat|| /
        ||y - mean y||)``; NaN for a constant record.
    cost : float
        Mean squared residual on the fitted samples.
    delay : int
    """

    c: np.ndarray
    d: float
    x0: np.ndarray
    y_offset: float
    y_hat: np.ndarray
    fit: float
    cost: float
    delay: int


def forced_states(A, b, u, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """States forced by ``u`` (Eq. 12), from ``x_0 = gamma2 u_0``, by one IIR filter.

    With ``xi_k = x_k - gamma2 u_k``, ``xi_{k+1} = Phi xi_k + Bd u_k`` (``Bd = E + Phi gamma2``)
    from ``xi_0 = 0``: ``xi_j = N_j(q) / a(q) u`` with the discrete denominator ``a`` and
    numerators from the first ``n`` Markov parameters ``Phi^m Bd``.

    Parameters
    ----------
    A : (n, n) array
    b : (n,) array
    u : (steps,) array
    dt : float, > 0

    Returns
    -------
    X : (steps, n) array
        ``X[k] = x_k`` of the response from ``x_0 = gamma2 u_0``.
    gamma2 : (n,) array
        So that a state ``x_0`` is reached by adding the free response of ``x_0 - gamma2 u_0``.
    """
    X, gamma2, _ = _forced(A, b, u, dt)
    return X, gamma2


def _forced(A, b, u, dt: float, intersample: str = "foh"):
    """:func:`forced_states` and ``Phi`` (a held input: ``gamma2 = 0``,
    ``simulation.discrete_foh``)."""
    A = np.asarray(A, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    n = A.shape[0]
    Phi, gamma1, gamma2 = discrete_foh(A, b, dt, intersample)
    if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(gamma1))):
        # e^{A dt} overflowed (a fast unstable pole): no response to fit
        return np.full((u.shape[0], n), np.nan), gamma2, Phi
    Bd = gamma1 - gamma2 + Phi @ gamma2
    a = np.real(np.poly(Phi))                     # (n + 1,), a[0] = 1
    markov = np.empty((n, n))                     # markov[m] = Phi^m Bd
    markov[0] = Bd
    for m in range(1, n):
        markov[m] = Phi @ markov[m - 1]
    # xi(z) = sum_{m>=1} Phi^{m-1} Bd z^-m U(z); times a(z^-1) it is a polynomial of degree n in
    # z^-1 (Cayley-Hamilton), whose coefficients are the convolution of a with the Markov
    # parameters truncated at n.
    num = np.zeros((n + 1, n))
    for k in range(1, n + 1):
        num[k] = sum(a[i] * markov[k - 1 - i] for i in range(k))
    w = scipy.signal.lfilter([1.0], a, u)
    W = np.empty((u.shape[0], n + 1))
    W[:, 0] = w
    for k in range(1, n + 1):
        W[:k, k] = 0.0
        W[k:, k] = w[:-k]
    return W @ num + np.outer(u, gamma2), gamma2, Phi


def _solve(M: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Least squares with column scaling (columns of slow and fast modes differ by orders of
    magnitude); a rank-deficient problem gets the minimum-norm solution."""
    if not (np.all(np.isfinite(M)) and np.all(np.isfinite(r))):
        # an overflowed response (a trial model with a fast unstable pole): no solution, and
        # LAPACK would print an error line for the non-finite input
        return np.full(M.shape[1], np.nan)
    scale = np.abs(M).max(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    z = np.linalg.lstsq(M / scale, r, rcond=None)[0]
    return z / scale


def _result(y, fitted, c, d, x0, offset, delay: int) -> Projection:
    used = y[delay:]
    y_hat = np.full(y.shape, np.nan)
    y_hat[delay:] = fitted
    res = used - fitted
    den = np.linalg.norm(used - used.mean())
    constant = not np.max(used) > np.min(used)
    fit = np.nan if constant else 100.0 * (1.0 - np.linalg.norm(res) / den)
    return Projection(c=c, d=float(d), x0=x0, y_offset=float(offset), y_hat=y_hat, fit=fit,
                      cost=float(np.mean(res ** 2)), delay=delay)


def project(A, b, y, u, dt: float, *, delay: int = 0, feedthrough: bool = True,
            offset: bool = True, intersample: str = "foh") -> Projection:
    """``c, d, x_0, y_offset`` minimising the output error for a given ``(A, b)``.

    Unchecked (the caller validated the record); ``(A, b)`` in controllable canonical form, or any
    realisation whose first state is observable.

    Parameters
    ----------
    A : (n, n) array
    b : (n,) array
    y, u : (steps,) arrays
    dt : float, > 0
    delay : int, 0 <= delay < steps - 1
        Input delay in samples: ``y[delay:]`` is fitted against ``u[:steps - delay]``.
    feedthrough : bool
        Fit ``d`` (else ``d = 0``).
    offset : bool
        Fit a constant output offset (else 0).
    intersample : {"foh", "zoh"}
        The input between samples (``records.Record.intersample``).

    Returns
    -------
    Projection
    """
    y = np.asarray(y, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    n = np.shape(A)[0]
    N = y.shape[0] - delay
    uu = u[:N]
    X, gamma2, Phi = _forced(A, b, uu, dt, intersample)
    F = free_basis(Phi, np.eye(n)[:1], N)[:, 0, :]          # (N, n): e_1^T Phi^k
    cols = [X] + ([uu[:, None]] if feedthrough else []) + [F] + (
        [np.ones((N, 1))] if offset else [])
    M = np.concatenate(cols, axis=1)
    z = _solve(M, y[delay:])
    c = z[:n]
    d = z[n] if feedthrough else 0.0
    k = n + int(feedthrough)
    theta = z[k : k + n]
    y_offset = z[-1] if offset else 0.0
    # The free response c^T Phi^k delta equals F theta: delta from the first rows (enough when
    # (c, Phi) is observable; least squares over a few more rows for rounding).
    rows = min(N, 4 * n)
    O = free_basis(Phi, c[None, :], rows)[:, 0, :]
    delta = _solve(O, F[:rows] @ theta)
    x0 = delta + gamma2 * uu[0]
    return _result(y, M @ z, c, d, x0, y_offset, delay)


def fit_initial(A, b, c, d, y, u, dt: float, *, delay: int = 0,
                offset: bool = True, intersample: str = "foh") -> Projection:
    """``x_0`` and ``y_offset`` minimising the output error of a given model (MATLAB's
    ``compare`` with the initial state estimated).

    Parameters
    ----------
    A : (n, n) array
    b, c : (n,) arrays
    d : float
    y, u : (steps,) arrays
    dt : float, > 0
    delay : int, 0 <= delay < steps - 1
    offset : bool
    intersample : {"foh", "zoh"}
        The input between samples (``records.Record.intersample``).

    Returns
    -------
    Projection
    """
    y = np.asarray(y, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    c = np.asarray(c, dtype=np.float64)
    N = y.shape[0] - delay
    uu = u[:N]
    X, gamma2, Phi = _forced(A, b, uu, dt, intersample)
    O = free_basis(Phi, c[None, :], N)[:, 0, :]
    forced = X @ c + float(d) * uu
    M = np.concatenate([O] + ([np.ones((N, 1))] if offset else []), axis=1)
    z = _solve(M, y[delay:] - forced)
    n = c.shape[0]
    x0 = z[:n] + gamma2 * uu[0]
    return _result(y, forced + M @ z, c, d, x0, z[n] if offset else 0.0, delay)
