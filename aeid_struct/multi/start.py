r"""Where the several-channel fit starts: input delays, candidate poles, the candidates scored by
a relaxed projection, and the start in the observer form.

1. *Delays* (:func:`arx_delays`): per input, a scan of the common-denominator ARX's residual
   over ``0 .. max_delay``, one input at a time with the others held (two sweeps).
2. *Candidates* (:func:`classical_poles`): the common-denominator ARX of every output on every
   input (``a(q) y_i = sum_j b_ij(q) u_j + c_i``, one ``a`` shared by all outputs: the poles are
   common to every channel), and its Steiglitz-McBride refits (prefiltered by ``1 / a``, the
   prefilter's unstable roots reflected into the unit circle) after five refits and at the
   fixed point. The caller adds its own (``ae.identify``: the generic encoders' candidates of
   every output-input pair).
3. *Scoring* (:func:`relaxed`): with the poles fixed, every output gets its own numerators over
   the common denominator (a non-minimal model: ``p`` times ``n`` states, linear in all its
   parameters), so each candidate costs one least-squares solve; the lowest residual wins.
   This relaxation ranks poles without the bilinear ``B, C`` coupling of the minimal model.
4. *The start* (:func:`start_of`): the reference output is the one the relaxed fit explains
   best; its numerators are ``B`` in the observer form (``C_ref = e_1``), and the other rows of
   ``C`` come from the states this ``B`` drives (one least-squares solve per output). The
   iterations of ``multi.fit`` take it from there.

Poles are in per-sample units; each candidate is scored in its own time unit (``h``: the
geometric mean of its pole magnitudes), where the coefficients of ``a`` are of order one.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.signal

from aeid_struct.multi.realisation import Layout, observer_form, responses

__all__ = ["EARLY", "arx_delays", "classical_poles", "continuous_poles", "reflected", "relaxed",
           "stabilised",
           "scale_of", "start_of"]

#: Steiglitz-McBride refits of the early candidate (the fixed point is the other).
EARLY = 5
#: Refits at most, and the relative change in ``a`` at which the fixed point is reached.
MAX_REFITS, TOL = 50, 1e-10


def _arx(parts, n: int, filt=None):
    """The common denominator ``[1, a_1 .. a_n]`` (discrete, ``q^-1`` powers) and the mean
    squared residual; ``filt``: the Steiglitz-McBride prefilter's denominator. Filtering from
    zero initial conditions leaves a transient of ``1 / filt`` driven by the first ``n``
    equation errors and by the constant: its ``n`` impulse responses and its step response
    are each output's regressors, so the fixed point stays exact on noise-free data (as
    ``generic.classical``'s for one channel).

    The least squares ``t_i = Psi_i a + Phi beta_i`` over every output ``i`` (``Psi_i`` the
    output's own lags, ``Phi`` the inputs' lags and each record's extra columns, the same for
    every output) is solved with ``beta_i`` eliminated: ``a`` solves ``sum_i ||P t_i - P Psi_i
    a||^2`` (``P`` the projection off ``Phi``'s columns), whose sums of squares one Householder
    QR of ``[Phi, Psi, t]`` gives in its lower right block -- the same solution as the whole
    design's, whose ``p`` copies of ``Phi`` (``n + p (m (n + 1) + R e)`` columns) made each
    solve 15-25 times dearer for 4 outputs and inputs.
    """
    R = len(parts)
    phis, psis, targets = [], [], []
    for r, (Y, U) in enumerate(parts):
        L, m = Y.shape[0], U.shape[1]
        if filt is None:
            extra = np.ones((L, 1))
        else:
            extra = np.zeros((L, n + 1))
            extra[np.arange(n), np.arange(n)] = 1.0
            extra[:, n] = 1.0
            Y, U, extra = (scipy.signal.lfilter([1.0], filt, v, axis=0) for v in (Y, U, extra))
        e = extra.shape[1]
        Phi = np.zeros((L - n, m * (n + 1) + R * e))
        for j in range(m):
            for lag in range(n + 1):
                Phi[:, j * (n + 1) + lag] = U[n - lag: L - lag, j]
        Phi[:, m * (n + 1) + r * e: m * (n + 1) + (r + 1) * e] = extra[n:]
        phis.append(Phi)
        # (rows, p, n): output i's lag l in column l - 1
        psis.append(np.stack([-Y[n - lag: L - lag] for lag in range(1, n + 1)], axis=2))
        targets.append(Y[n:])
    Phi, Psi, t = np.vstack(phis), np.concatenate(psis), np.concatenate(targets)
    rows, p = t.shape
    if rows * p <= Phi.shape[1] * p + n:        # each output's own k columns, one shared a
        # no more equations than unknowns (short records, each with its own constants or, for
        # the prefiltered refits, its own transients): no estimate, where the QR below left
        # nothing to solve and raised numpy's zero-size error
        return np.full(n + 1, np.nan), math.inf
    scale = np.abs(Phi).max(axis=0)
    scale[scale == 0] = 1.0
    k = Phi.shape[1]
    # one Householder QR of [Phi, Psi, t]: its lower right block holds P Psi_i, P t_i up to an
    # orthogonal factor (what the sums of squares depend on), accurate to round-off of the
    # whole columns however close to Phi's span they lie (a subtraction of Phi's fit from them
    # is not: the Steiglitz-McBride prefilter makes Phi ill-conditioned)
    T = scipy.linalg.qr(np.concatenate([Phi / scale, Psi.reshape(rows, p * n), t], axis=1),
                        mode="r", check_finite=False)[0][k:, k:]
    lhs = np.concatenate([T[:, i * n: (i + 1) * n] for i in range(p)])
    rhs = np.concatenate([T[:, p * n + i] for i in range(p)])
    scale = np.abs(lhs).max(axis=0)
    scale[scale == 0] = 1.0
    a = scipy.linalg.lstsq(lhs / scale, rhs, lapack_driver="gelsy", check_finite=False)[0] / scale
    return np.concatenate([[1.0], a]), float(np.sum((rhs - lhs @ a) ** 2)) / (rows * p)


def arx_delays(experiments, order: int, top: int) -> np.ndarray:
    """Input delays by the common-denominator ARX (module docstring, step 1).

    Parameters
    ----------
    experiments : Experiments
    order : int
    top : int
        The largest delay considered.

    Returns
    -------
    (m,) int array
    """
    m = experiments.inputs
    delays = np.zeros(m, dtype=int)
    if top == 0:
        return delays
    for _ in range(2):
        before = delays.copy()
        for j in range(m):
            costs = []
            for D in range(top + 1):
                trial = delays.copy()
                trial[j] = D
                costs.append(_arx(experiments.aligned(trial), order)[1])
            delays[j] = int(np.argmin(costs))
        if np.array_equal(before, delays):
            break
    return delays


def reflected(a: np.ndarray) -> np.ndarray:
    """``a`` with its roots outside (or on) the unit circle reflected inside
    (``z -> 1 / conj z``): the Steiglitz-McBride prefilter of an unstable fit (one channel's,
    ``generic.classical``, and this module's).

    Parameters
    ----------
    a : (n + 1,) array
        A discrete denominator, highest power first.

    Returns
    -------
    (n + 1,) array
    """
    roots = np.roots(a)
    outside = np.abs(roots) >= 1.0
    if not outside.any():
        return a
    roots[outside] = 1.0 / np.conj(roots[outside])
    return np.real(np.poly(roots))


def stabilised(poles: np.ndarray) -> np.ndarray:
    """``poles`` with each one on or right of the imaginary axis mirrored into the open left
    half-plane (``s -> -conj(s)``, the continuous-time counterpart of :func:`reflected`): the
    same magnitudes and oscillation, so a start of a fit held to stable models (``stable=True``)
    keeps the candidate's time scales. A pole at zero (an integrator) moves to a thousandth of
    the largest magnitude on the left (at least float64's smallest normal number).

    Parameters
    ----------
    poles : (n,) complex array
        Per sample.

    Returns
    -------
    (n,) complex array
    """
    s = np.asarray(poles, dtype=complex)
    floor = max(1e-3 * float(np.abs(s).max(initial=0.0)), np.finfo(np.float64).tiny)
    return -np.maximum(np.abs(s.real), floor) + 1j * s.imag


def continuous_poles(a: np.ndarray) -> np.ndarray:
    """Per-sample continuous poles ``s = log z`` of a discrete denominator: a negative real
    root (no real continuous pole gives one) by ``log |z|``, a root at zero by a very fast pole
    (``log 1e-300``), so that the candidate is kept and scored like any other.

    Parameters
    ----------
    a : (n + 1,) array
        Highest power first.

    Returns
    -------
    (n,) complex array
    """
    z = np.roots(a)
    z = np.where((np.abs(z.imag) < 1e-12) & (z.real < 0), np.abs(z), z)
    z = np.where(np.abs(z) > 0, z, 1e-300)
    return np.log(z.astype(complex))


def classical_poles(parts, order: int) -> list[np.ndarray]:
    """The ARX and Steiglitz-McBride candidates (module docstring, step 2).

    One channel in one record keeps ``generic.classical``'s loop: the shipped generic
    estimates are its arithmetic (means removed, one record, columns scaled to unit peak); this
    one is its generalisation to a denominator shared by several outputs, inputs and records,
    each record's constants as regressors. Both use :func:`reflected` and
    :func:`continuous_poles`.

    Parameters
    ----------
    parts : list of R (Y, U) pairs
        Aligned records.
    order : int

    Returns
    -------
    list of (order,) complex arrays
        Per-sample poles.
    """
    den, _ = _arx(parts, order)
    if not np.all(np.isfinite(den)):
        return []
    found = [den]
    den = reflected(den)
    for k in range(1, MAX_REFITS + 1):
        new, _ = _arx(parts, order, reflected(den))
        if not np.all(np.isfinite(new)):
            break
        change = np.max(np.abs(new - den)) / max(1.0, np.max(np.abs(den)))
        den = new
        if k == EARLY:
            found.append(den)
        if change < TOL:
            break
    found.append(den)
    poles = [continuous_poles(d) for d in found]
    return [s for s in poles if np.all(np.isfinite(s))]


def scale_of(poles: np.ndarray) -> float:
    """The time unit ``h`` (per sample) in which ``poles`` are of order one: the geometric mean
    of their magnitudes (an integrator's zero raised to a thousandth of the largest)."""
    mag = np.abs(poles)
    top = float(mag.max())
    if top == 0.0:
        return 1.0
    return float(np.exp(np.mean(np.log(np.maximum(mag, 1e-3 * top)))))


def _coefficients(poles: np.ndarray, h: float) -> np.ndarray:
    """``a_0 .. a_{n-1}`` of the poles in the time unit ``h``."""
    return np.real(np.poly(poles / h))[1:][::-1].copy()


def relaxed(poles: np.ndarray, parts, holds, feedthrough: bool = True):
    """The relaxed projection of one candidate (module docstring, step 3).

    Parameters
    ----------
    poles : (n,) complex array
        Per sample.
    parts : list of R (Y, U) pairs
    holds : sequence of R str
    feedthrough : bool

    Returns
    -------
    cost : float
        Mean squared residual over all outputs.
    per_output : (p,) array
        Each output's residual over its variation.
    beta : (columns, p) array
        Per output: ``B_i`` (n m), ``D_i`` (m, with a feedthrough), then per record ``x0``
        (n) and offset (1).
    h : float
    """
    h = scale_of(poles)
    A = observer_form(_coefficients(poles, h))
    n = A.shape[0]
    m = parts[0][1].shape[1]
    e1 = np.eye(n)[:1]
    shared = n * m + (m if feedthrough else 0)
    width = shared + len(parts) * (n + 1)
    blocks = []
    for r, ((_, U), hold) in enumerate(zip(parts, holds, strict=True)):
        Rg, O = responses(A, e1, U, h, hold)
        X = np.zeros((U.shape[0], width))
        X[:, : n * m] = Rg[:, 0].reshape(U.shape[0], n * m)
        if feedthrough:
            X[:, n * m: shared] = U
        base = shared + r * (n + 1)
        X[:, base: base + n] = O[:, 0]
        X[:, base + n] = 1.0
        blocks.append(X)
    X = np.vstack(blocks)
    Y = np.vstack([Y for Y, _ in parts])
    if not np.all(np.isfinite(X)):
        return np.inf, np.full(Y.shape[1], np.inf), None, h
    scale = np.sqrt(np.sum(X ** 2, axis=0))
    scale[scale == 0] = 1.0
    beta = scipy.linalg.lstsq(X / scale, Y, lapack_driver="gelsy",
                              check_finite=False)[0] / scale[:, None]
    resid = Y - X @ beta
    per = np.sum(resid ** 2, axis=0) / np.maximum(np.sum((Y - Y.mean(0)) ** 2, axis=0), 1e-300)
    return float(np.mean(resid ** 2)), per, beta, h


def start_of(poles: np.ndarray, parts, holds, feedthrough: bool = True, fit=None):
    """The start in the observer form (module docstring, step 4).

    Parameters
    ----------
    poles : (n,) complex array
    parts, holds, feedthrough
        As :func:`relaxed`.
    fit : tuple, optional
        ``relaxed(poles, parts, holds, feedthrough)`` where the caller has it (the ranking).

    Returns
    -------
    layout : Layout
    theta : (n p,) array
    h : float
    """
    _, per, beta, h = relaxed(poles, parts, holds, feedthrough) if fit is None else fit
    n, p, m = len(poles), parts[0][0].shape[1], parts[0][1].shape[1]
    a = _coefficients(poles, h)
    if p == 1:
        return Layout(n, p, m, 0), a, h
    ref = int(np.argmin(per))
    layout = Layout(n, p, m, ref)
    A = observer_form(a)
    B = beta[: n * m, ref].reshape(n, m)
    shared = n * m + (m if feedthrough else 0)
    rows, targets = [], []
    for r, ((Y, U), hold) in enumerate(zip(parts, holds, strict=True)):
        Rx, Ox = responses(A, np.eye(n), U, h, hold)
        x0 = beta[shared + r * (n + 1): shared + r * (n + 1) + n, ref]
        x = np.einsum("kilj,lj->ki", Rx, B) + Ox @ x0
        ones = np.zeros((U.shape[0], len(parts)))
        ones[:, r] = 1.0
        rows.append(np.hstack([x, U if feedthrough else U[:, :0], ones]))
        targets.append(Y)
    X, T = np.vstack(rows), np.vstack(targets)
    coef = scipy.linalg.lstsq(X, T, lapack_driver="gelsy", check_finite=False)[0]
    C = coef[:n].T.copy()
    C[ref] = np.eye(n)[0]
    return layout, layout.theta(a, C), h
