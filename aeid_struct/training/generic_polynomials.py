"""Polynomials in batches, for the draws of ``training.generic_family``: the monic polynomial of
each row of roots, row-wise products of polynomials, and the peak gain of each transfer function
``c(s) / a(s)`` of the bottom-row CCF (paper Eq. 5) over a frequency grid. A module apart from the
family because this is deterministic algebra on coefficient arrays, while the family is the
random draw of the roots it is applied to.

Coefficients are ascending (``p[:, j]`` multiplies ``s^j``), one polynomial per row; roots and
coefficients are complex until the family takes the real part.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GRID", "convolve", "peak_gain", "poly"]

#: Frequencies (rad/sample) of the grid the numerator is scaled on, besides each |pole|.
GRID = np.logspace(-4, np.log10(np.pi), 256)


def poly(roots: np.ndarray) -> np.ndarray:
    """Monic polynomials of rows of roots, ascending: ``(B, k) -> (B, k + 1)`` complex.

    Parameters
    ----------
    roots : (B, k) array
        The roots of each polynomial.

    Returns
    -------
    (B, k + 1) complex array
        ``prod_j (s - roots[:, j])``, ascending; the last column is 1.
    """
    coef = np.ones((roots.shape[0], 1), dtype=complex)
    for j in range(roots.shape[1]):
        shifted = np.concatenate([np.zeros_like(coef[:, :1]), coef], axis=1)   # s * p(s)
        coef = shifted - roots[:, j : j + 1] * np.concatenate([coef, 0 * coef[:, :1]], axis=1)
    return coef


def convolve(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Row-wise products of ascending polynomials ``(B, i) x (B, j) -> (B, i + j - 1)``.

    Parameters
    ----------
    p : (B, i) array
    q : (B, j) array
        Ascending coefficients, one polynomial per row.

    Returns
    -------
    (B, i + j - 1) complex array
        ``p(s) q(s)`` per row, ascending.
    """
    out = np.zeros((p.shape[0], p.shape[1] + q.shape[1] - 1), dtype=complex)
    for j in range(q.shape[1]):
        out[:, j : j + p.shape[1]] += p * q[:, j : j + 1]
    return out


def peak_gain(a: np.ndarray, c: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``max |c(jw) / a(jw)|`` over ``GRID`` and the frequencies ``at`` (B, k), per system.

    Parameters
    ----------
    a : (B, n) float array
        Denominators ``a_0..a_{n-1}`` of the CCF (Eq. 5), the monic ``s^n`` term implied.
    c : (B, n) float array
        Numerators ``c_0..c_{n-1}``, ascending.
    at : (B, k) float array
        Frequencies (rad/sample) to include besides ``GRID``, per system.

    Returns
    -------
    (B,) float array
        The largest gain per system.
    """
    w = np.concatenate([np.broadcast_to(GRID, (a.shape[0], GRID.size)), at], axis=1)
    s = 1j * w
    n = a.shape[1]
    power = s[..., None] ** np.arange(n + 1)                   # (B, W, n + 1)
    den = power[..., :n] @ a[:, :, None] + power[..., n : n + 1]
    num = power[..., :n] @ c[:, :, None].astype(complex)
    return np.max(np.abs(num / den)[..., 0], axis=1)
