"""Models given in any realisation -> the bottom-row CCF of their transfer function (numpy).

A model that comes from outside (a user's ``A, b, c, d``, a baseline's estimate) may be in any
basis. Its transfer function

    G(s) = (c_{n-1} s^{n-1} + ... + c_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0) + d

is what a structure's elements describe, so it is reached through the CCF (paper Eq. 5,
``docs/architecture.md``): :func:`ccf_coefficients` evaluates the library's one model -> CCF
conversion, ``symbolic.realisation.ccf`` (Householder reduction to controller-Hessenberg form, La
Budde's characteristic polynomial, Markov parameters), on a batch of float64 models in one
mapped CasADi call. This path is numpy float64 and not differentiable; the forward path of a
structure (``theta -> System``) is torch.
"""

from __future__ import annotations

import functools
from typing import Any

import casadi
import numpy as np

from symbolic.realisation import coefficients_function

__all__ = ["as_float64", "ccf_coefficients", "ccf_matrices", "model_arrays"]


def as_float64(x: Any) -> np.ndarray:
    """``x`` (a tensor, array, list or number) as a float64 numpy array.

    Parameters
    ----------
    x : array-like or torch.Tensor

    Returns
    -------
    numpy.ndarray
        float64, the shape of ``x``.
    """
    if hasattr(x, "detach") and hasattr(x, "is_floating_point"):
        # a torch tensor, recognised without importing torch: this numpy path also serves
        # where torch is not installed (an estimate's physical parameters from an ONNX file)
        x = x.detach().cpu()
        return x.numpy().astype(np.float64) if x.is_floating_point() else x.double().numpy()
    return np.asarray(x, dtype=np.float64)


def _record_arrays(A, b, c, d, n: int, who: str, records: int):
    """:func:`model_arrays` for models with a record axis: flattened record-minor."""
    A_ = as_float64(A)
    if A_.ndim not in (3, 4) or A_.shape[-3:] != (records, n, n):
        raise ValueError(f"A must have shape (batch, {records}, {n}, {n}) or ({records}, {n}, "
                         f"{n}) for {who}; got {A_.shape}")
    batched = A_.ndim == 4
    lead = A_.shape[:-2]
    parts = {}
    for name, x, shape in (("b", b, (*lead, n)), ("c", c, (*lead, n)), ("d", d, lead)):
        try:
            parts[name] = np.broadcast_to(as_float64(x), shape)
        except ValueError:
            raise ValueError(f"{name} must have shape {shape} to match A {A_.shape}; "
                             f"got {as_float64(x).shape}") from None
    flat = model_arrays(A_.reshape(-1, n, n), parts["b"].reshape(-1, n),
                        parts["c"].reshape(-1, n), parts["d"].reshape(-1), n, who)
    return (*flat[:4], batched)


def model_arrays(A, b, c, d, n: int, who: str, records: int = 1):
    """Batched, checked float64 arrays of a given model, and whether it came batched.

    Parameters
    ----------
    A : (batch, n, n) or (n, n) array-like
        With ``records = R > 1``: ``(batch, R, n, n)`` or ``(R, n, n)``.
    b : (batch, n) or (n,) array-like
        Also ``(.., n, 1)``; with records ``(batch, R, n)``.
    c : (batch, n) or (n,) array-like
        Also ``(.., 1, n)``; with records ``(batch, R, n)``.
    d : (batch,) array-like or scalar
        Also ``(.., 1)`` and ``(.., 1, 1)``; with records ``(batch, R)``.
    n : int
        The order the structure expects.
    who : str
        The structure, for error messages.
    records : int
        Records (SISO systems) per model.

    Returns
    -------
    A : (B, n, n) ndarray
    b, c : (B, n) ndarray
    d : (B,) ndarray
        ``B = batch * R`` rows, record-minor (``B = 1`` for an unbatched single model).
    batched : bool

    Raises
    ------
    ValueError
        For shapes that do not match, or values that are not finite.
    """
    if records > 1:
        return _record_arrays(A, b, c, d, n, who, records)
    A_, b_, c_, d_ = as_float64(A), as_float64(b), as_float64(c), as_float64(d)
    if A_.ndim not in (2, 3) or A_.shape[-2:] != (n, n):
        raise ValueError(f"A must have shape (batch, {n}, {n}) or ({n}, {n}) for {who}; "
                         f"got {A_.shape}")
    batched = A_.ndim == 3
    B = A_.shape[0] if batched else 1
    lead = (B,) if batched else ()
    allowed = {
        "b": [(*lead, n), (*lead, n, 1)],
        "c": [(*lead, n), (*lead, 1, n)],
        "d": [lead, (*lead, 1), (*lead, 1, 1)] + ([()] if batched else []),
    }
    out = {}
    for name, x in (("b", b_), ("c", c_), ("d", d_)):
        if x.shape not in allowed[name]:
            raise ValueError(f"{name} must have shape {allowed[name][0]} to match A {A_.shape}; "
                             f"got {x.shape}")
        out[name] = np.broadcast_to(x, (B,)) if name == "d" and x.shape == () else x
    A_, b_ = A_.reshape(B, n, n), out["b"].reshape(B, n)
    c_, d_ = out["c"].reshape(B, n), np.asarray(out["d"]).reshape(B)
    for name, x in (("A", A_), ("b", b_), ("c", c_), ("d", d_)):
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{name} must be finite; got nan or inf")
    return A_, b_, c_, d_.copy(), batched


@functools.lru_cache(maxsize=32)
def _mapped(n: int, batch: int) -> casadi.Function:
    return coefficients_function(n).map(batch)


def ccf_coefficients(A: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """CCF coefficients of any realisations, ``G = sum c_j s^j / (s^n + sum a_i s^i)``.

    ``symbolic.realisation.ccf`` evaluated on the batch in one mapped CasADi call.

    Parameters
    ----------
    A : (B, n, n) float64 ndarray
    b : (B, n) float64 ndarray
    c : (B, n) float64 ndarray

    Returns
    -------
    a : (B, n) ndarray
        ``(a_0, ..., a_{n-1})`` of ``det(sI - A)``.
    c : (B, n) ndarray
        ``(c_0, ..., c_{n-1})``, the numerator of ``c^T (sI - A)^{-1} b``.
    """
    A, b, c = (np.asarray(x, dtype=np.float64) for x in (A, b, c))
    B, n = b.shape
    if B == 0:
        return np.zeros((0, n)), np.zeros((0, n))
    # mapped inputs sit side by side: A (n, B n), b and c (n, B)
    a, num = _mapped(n, B)(np.transpose(A, (1, 0, 2)).reshape(n, B * n), b.T, c.T)
    return a.full().T.copy(), num.full().T.copy()


def ccf_matrices(a: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bottom-row CCF matrices of the coefficients (paper Eq. 5).

    Parameters
    ----------
    a : (B, n) ndarray
        ``(a_0, ..., a_{n-1})``, real or complex (the complex step of a derivative).
    c : (B, n) ndarray or None
        ``(c_0, ..., c_{n-1})``; None where only ``A, b`` are wanted.

    Returns
    -------
    A : (B, n, n) ndarray
        Ones on the superdiagonal, last row ``(-a_0, ..., -a_{n-1})``; the one numpy
        companion matrix of the library (the generic candidates, the separable refinement, the
        classical baselines build theirs here).
    b : (B, n) ndarray
        ``e_n``.
    c : (B, n) ndarray
        ``c`` itself.
    """
    B, n = a.shape
    A = np.zeros((B, n, n), dtype=np.result_type(a, np.float64))
    A[:, np.arange(n - 1), np.arange(1, n)] = 1.0
    A[:, -1, :] = -a
    b = np.zeros((B, n))
    b[:, -1] = 1.0
    return A, b, c
