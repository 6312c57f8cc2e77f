"""Physical parameters of identified models: a CasADi inverse map (CCF -> parameters) applied to
models in any realisation, through the CCF of their transfer function."""

from __future__ import annotations

import math

import numpy as np

from aeid_struct.structures import Numeric

__all__ = ["apply_inverse", "inverse_of_models", "through_ccf"]

#: casadi.Function -> its buffer evaluation (``Numeric``), by identity; a few entries.
_NUMERIC: dict[int, tuple] = {}


def inverse_of_models(inverse, A: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray,
                      ccf: bool) -> dict[str, np.ndarray]:
    """Physical parameters of models through a CCF -> parameters map.

    Parameters
    ----------
    inverse : casadi.Function
        ``A, B, C, D`` of a bottom-row CCF -> named parameters.
    A : (N, n, n) array
    b, c : (N, n) arrays
    d : (N,) array
    ccf : bool
        The models are bottom-row CCFs already; otherwise (an MCF or n4sid model, another
        realisation of the same transfer function) they are converted first.

    Returns
    -------
    dict name -> (N,) array
    """
    if ccf:
        return apply_inverse(inverse, A, b, c, d)
    return through_ccf(A, b, c, d, inverse)


def apply_inverse(inverse, A: np.ndarray, b: np.ndarray, c: np.ndarray,
                  d: np.ndarray) -> dict[str, np.ndarray]:
    """A CCF -> parameters map on bottom-row CCF models (one model through the Function's
    buffer, the tracker's hot path; a batch through one map over all).

    Parameters
    ----------
    inverse : casadi.Function
    A : (N, n, n) array
    b, c : (N, n) arrays
    d : (N,) array

    Returns
    -------
    dict name -> (N,) array
    """
    count, n = A.shape[0], A.shape[-1]
    if count == 1 and list(inverse.name_in()) == ["A", "B", "C", "D"]:
        hit = _NUMERIC.get(id(inverse))
        if hit is None or hit[0] is not inverse:
            if len(_NUMERIC) >= 16:
                _NUMERIC.clear()
            hit = _NUMERIC[id(inverse)] = (inverse, Numeric(inverse))
        # the buffer reads CasADi's column-major order: A transposed, then row by row
        out = hit[1](np.ascontiguousarray(A[0].T).ravel(), np.ascontiguousarray(b[0]),
                     np.ascontiguousarray(c[0]), np.asarray(d[:1], dtype=np.float64))
        return dict(zip(inverse.name_out(), out, strict=True))
    # Mapped casadi inputs are concatenated horizontally: A (n, n*N), B (n, N), C (1, n*N).
    out = inverse.map(count)(A=np.concatenate(list(A), axis=1), B=b.T,
                             C=c.reshape(1, count * n), D=d.reshape(1, count))
    return {name: np.array(out[name]).reshape(count) for name in inverse.name_out()}


def through_ccf(A: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray,
                inverse) -> dict[str, np.ndarray]:
    """A CCF -> parameters map on models in any realisation.

    Each finite model is converted to the bottom-row CCF of its transfer function
    (characteristic polynomial and Markov parameters, as ``Structure.elements_of`` does), then
    mapped; NaN for non-finite models.

    Parameters
    ----------
    A : (N, n, n) array
    b, c : (N, n) arrays
    d : (N,) array
    inverse : casadi.Function

    Returns
    -------
    dict name -> (N,) array
    """
    # the one model -> CCF conversion (structures.realisation, over symbolic.realisation)
    from aeid_struct.structures import ccf_coefficients, ccf_matrices

    finite = (np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(b), axis=1)
              & np.all(np.isfinite(c), axis=1) & np.isfinite(d))
    out = {name: np.full(A.shape[0], math.nan) for name in inverse.name_out()}
    rows = np.flatnonzero(finite)
    if rows.size:
        Ac, bc, cc = ccf_matrices(*ccf_coefficients(A[rows], b[rows], c[rows]))
        for name, value in apply_inverse(inverse, Ac, bc, cc, d[rows]).items():
            out[name][rows] = value
    return out
