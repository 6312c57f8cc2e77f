"""Accuracy measures: the paper's Table I metrics and the NRMSE fit.

Table I (paper Sec. IV), as docs/architecture.md pins them down:

- **step error**: mean absolute difference of the true and identified unit-step responses after
  scaling *both* to [0, 1] by the true response's min and max;
- **Bode magnitude** (dB) and **phase** (rad): mean absolute differences over the frequency grid
  ``FREQUENCIES`` (200 log-spaced points from 0.1 to 100 rad/s, which spans the leg's natural
  frequencies of 3.7-7 rad/s and the unstable poles of 4-12.4 rad/s by more than a decade on
  each side). The phase difference is ``angle(G_hat / G)``, wrapped to (-pi, pi], so a
  constant-phase-pi system (the unstable leg) compares without unwrapping artefacts;
- **parameter errors**: mean absolute percentage deviation of k, d, m recovered from the model.
"""

from __future__ import annotations

import math

import numpy as np

#: The frequency grid of the Bode metrics, rad/s.
FREQUENCIES = np.logspace(-1, 2, 200)


def _real(name: str, value) -> np.ndarray:
    """``value`` as a float64 array, or a ValueError naming ``name``."""
    try:
        arr = np.asarray(value)
        if arr.dtype.kind not in "biuf":
            raise TypeError
        return arr.astype(np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of real numbers; got "
                         f"{type(value).__name__}") from None


def _batch(A, b, c, d):
    """``A (batch, n, n)``, ``b, c (batch, n)``, ``d (batch,)`` of one system or a batch, checked:
    shapes that agree and finite entries (a ValueError naming the argument)."""
    A = _real("A", A)
    if A.ndim not in (2, 3) or A.shape[-1] != A.shape[-2] or A.shape[-1] == 0:
        raise ValueError(f"A must be square with shape (batch, n, n) or (n, n); got {A.shape}")
    single = A.ndim == 2
    A = A[None] if single else A
    count, n = A.shape[0], A.shape[-1]
    out = [A]
    for name, v, core in (("b", b, (n,)), ("c", c, (n,)), ("d", d, ())):
        arr = _real(name, v)
        # any layout of count * n (count) numbers, as the reshape always read them
        if arr.size != count * math.prod(core):
            want = core if single else (count, *core)
            raise ValueError(f"{name} must have shape {want} to match A "
                             f"{A.shape[1:] if single else A.shape}; got {arr.shape}")
        out.append(arr.reshape(count, *core))
    for name, arr in zip("Abcd", out, strict=True):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite; got nan or inf")
    A, b, c, d = out
    return A, b, c, d, single


def frequency_response(A, b, c, d, omega=FREQUENCIES) -> np.ndarray:
    """``G(j omega) = c^T (j omega I - A)^{-1} b + d`` for a batch of systems.

    Parameters
    ----------
    A : (batch, n, n) or (n, n) array
    b, c : (batch, n) or (n,) arrays
    d : (batch,) array or scalar
    omega : (f,) array
        Frequencies in rad/s.

    Returns
    -------
    (batch, f) complex array, or (f,) for a single system

    Notes
    -----
    One batched complex solve instead of python-control's per-system ``frequency_response``:
    the studies evaluate thousands of systems at 200 frequencies, where the per-system overhead
    dominates; tests check this against ``control.frequency_response``.
    """
    A, b, c, d, single = _batch(A, b, c, d)
    n = A.shape[-1]
    omega = _real("omega", omega)
    if omega.ndim != 1 or not np.all(np.isfinite(omega)):
        raise ValueError(f"omega must be a (f,) array of finite frequencies in rad/s; got shape "
                         f"{omega.shape}")
    M = 1j * omega[None, :, None, None] * np.eye(n) - A[:, None]        # (batch, f, n, n)
    rhs = np.broadcast_to(b[:, None, :, None], M.shape[:-1] + (1,)).astype(complex)
    x = np.linalg.solve(M, rhs)[..., 0]                                   # (batch, f, n)
    G = np.einsum("bfn,bn->bf", x, c) + d[:, None]
    return G[0] if single else G


def step_error(y_true, y_hat) -> np.ndarray:
    """Table I step error per record: mean |y_hat_s - y_s| with both scaled to [0, 1] by the
    true response's min and max.

    Parameters
    ----------
    y_true, y_hat : (batch, steps) or (steps,) arrays
        Step responses on the same grid; ``y_true`` finite and not constant.

    Returns
    -------
    (batch,) array, (1,) for single records
        inf or NaN for a record whose ``y_hat`` is not finite (an overflowing or failed
        estimate).
    """
    y_true = np.atleast_2d(_real("y_true", y_true))
    y_hat = np.atleast_2d(_real("y_hat", y_hat))
    if y_true.shape != y_hat.shape:
        raise ValueError(f"y_hat must have the shape of y_true {y_true.shape}; got {y_hat.shape}")
    # The truth must be finite (it scales the error); an estimate's response may not be: an
    # unstable or failed estimate has an infinite (inf) or undefined (NaN) error, which the
    # scorecard counts as such.
    if not np.all(np.isfinite(y_true)):
        r, k = np.argwhere(~np.isfinite(y_true))[0]
        raise ValueError(f"y_true must be finite; got {y_true[r, k]} at record {r}, sample {k}")
    lo = y_true.min(axis=1, keepdims=True)
    span = y_true.max(axis=1, keepdims=True) - lo
    if np.any(span <= 0):
        raise ValueError("y_true must not be constant: the step error scales by its range")
    return np.mean(np.abs(y_hat - y_true), axis=1) / span[:, 0]


def bode_errors(true, est, omega=FREQUENCIES) -> tuple[np.ndarray, np.ndarray]:
    """Mean absolute Bode magnitude (dB) and phase (rad) differences per system.

    Parameters
    ----------
    true, est : tuple (A, b, c, d)
        Systems batched alike (shapes as in :func:`frequency_response`).
    omega : (f,) array
        Frequencies in rad/s.

    Returns
    -------
    magnitude_db, phase_rad : (batch,) arrays
    """
    G = np.atleast_2d(frequency_response(*true, omega=omega))
    H = np.atleast_2d(frequency_response(*est, omega=omega))
    if G.shape != H.shape:
        raise ValueError(f"est must hold as many systems as true ({G.shape[0]}); got "
                         f"{H.shape[0]}")
    with np.errstate(divide="ignore", invalid="ignore"):
        mag = np.mean(np.abs(20 * np.log10(np.abs(H)) - 20 * np.log10(np.abs(G))), axis=1)
        phase = np.mean(np.abs(np.angle(H / G)), axis=1)
    return mag, phase


def parameter_errors(true: dict, est: dict) -> dict[str, np.ndarray]:
    """Absolute percentage deviation ``100 |p_hat - p| / |p|`` per parameter and system.

    Parameters
    ----------
    true, est : dict str -> (batch,) array
        True and estimated parameters; names only in ``est`` are skipped.

    Returns
    -------
    dict str -> (batch,) array
    """
    out = {}
    for name, value in est.items():
        if name not in true:
            continue
        p = _real(f"true[{name!r}]", true[name])
        v = _real(f"est[{name!r}]", value)
        if v.shape != p.shape and p.size != 1:
            raise ValueError(f"est[{name!r}] must have the shape of true[{name!r}] {p.shape}; "
                             f"got {v.shape}")
        if np.any(p == 0) or not np.all(np.isfinite(p)):
            # the relative error of a parameter whose true value is 0 is undefined
            raise ValueError(f"true[{name!r}] must be non-zero and finite (the error is relative "
                             f"to it); got {p if p.size <= 4 else 'an array with 0 or nan'}")
        out[name] = 100.0 * np.abs(v - p) / np.abs(p)
    return out


def nrmse_fit(y, y_hat) -> np.ndarray:
    """NRMSE fit in % (MATLAB's ``compare``): ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)``.

    Parameters
    ----------
    y, y_hat : (batch, steps) or (steps,) arrays
        Measured and simulated outputs.

    Returns
    -------
    (batch,) array, (1,) for single records
        NaN for a constant record, whose fit is undefined (``||y - mean(y)|| = 0``: no model
        explains it better than its mean, and reporting 100 % would call any model perfect).
    """
    y = np.atleast_2d(_real("y", y))
    y_hat = np.atleast_2d(_real("y_hat", y_hat))
    if y.shape != y_hat.shape:
        raise ValueError(f"y_hat must have the shape of y {y.shape}; got {y_hat.shape}")
    # Constant: all samples equal (max == min). Not den == 0: the mean of 60 samples of 0.7
    # is rounded, which leaves den ~ 1e-16 and a fit of -1e17 %. (A record with a non-finite
    # sample has no fit either: NaN.)
    constant = ~(np.max(y, axis=1) > np.min(y, axis=1))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        num = np.linalg.norm(y - y_hat, axis=1)
        den = np.linalg.norm(y - y.mean(axis=1, keepdims=True), axis=1)
        return 100.0 * (1.0 - num / np.where(constant, np.nan, den))
