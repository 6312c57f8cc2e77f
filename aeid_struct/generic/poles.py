r"""The generic identifier's output map: raw network outputs -> poles -> a monic denominator that
is stable by construction.

For order ``n`` the network gives ``n`` raw numbers: two per second-order factor
``s^2 + 2 zeta w s + w^2`` (``floor(n/2)`` of them) and one for the first-order factor ``s + w`` of
an odd order. Each maps through a sigmoid onto a log range,

    log w    = log w_lo + (log w_hi - log w_lo) sigmoid(raw),     w in band (rad/sample),
    log zeta = log z_lo + (log z_hi - log z_lo) sigmoid(raw),     zeta in damping,

so every pole has a negative real part (``zeta > 0``, ``w > 0``) and a natural frequency inside
the band the identifier was trained for; ``zeta > 1`` gives two real poles. The denominator
``a(s)`` is the product of the factors (normalised time, ``dt = 1``); its companion matrix is the
CCF of paper Eq. 5.
"""

from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["denominator", "factors", "poles_of", "raw_of"]


def _log_range(raw: torch.Tensor, lo: float, hi: float) -> torch.Tensor:
    return torch.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * torch.sigmoid(raw))


def factors(raw: torch.Tensor, band: tuple[float, float], damping: tuple[float, float]):
    """Natural frequencies and damping ratios of the factors.

    Parameters
    ----------
    raw : (batch, n) tensor
        Pairs ``(w, zeta)`` of raw numbers for each second-order factor, then one ``w`` for an
        odd order.
    band : (lo, hi)
        Natural frequencies (rad/sample), ``0 < lo < hi``.
    damping : (lo, hi)
        Damping ratios, ``0 < lo < hi``.

    Returns
    -------
    w : (batch, ceil(n/2)) tensor
        The second-order factors' natural frequencies, then the first-order one's.
    zeta : (batch, floor(n/2)) tensor
    """
    half = raw.shape[1] // 2
    w = _log_range(raw[:, 0: 2 * half: 2], *band)
    zeta = _log_range(raw[:, 1: 2 * half: 2], *damping)
    if raw.shape[1] % 2:
        w = torch.cat([w, _log_range(raw[:, -1:], *band)], dim=1)
    return w, zeta


def denominator(w: torch.Tensor, zeta: torch.Tensor) -> torch.Tensor:
    """The monic denominator of the factors, ascending and without its leading 1.

    Parameters
    ----------
    w : (batch, ceil(n/2)) tensor
    zeta : (batch, floor(n/2)) tensor

    Returns
    -------
    a : (batch, n) tensor
        ``(a_0, .., a_{n-1})`` of ``a(s) = s^n + a_{n-1} s^{n-1} + .. + a_0`` (the CCF's last
        row is ``-a``, paper Eq. 5).
    """
    half = zeta.shape[1]
    coef = torch.ones_like(w[:, :1])                               # ascending, monic
    parts = [torch.stack([w[:, j] ** 2, 2 * zeta[:, j] * w[:, j]], dim=1) for j in range(half)]
    if w.shape[1] > half:
        parts.append(w[:, half:])
    for low in parts:                    # multiply by s^k + low (k = its length), out of place
        k = low.shape[1]
        factor = torch.cat([low, torch.ones_like(low[:, :1])], dim=1)
        m = coef.shape[1]
        terms = [sum(coef[:, i] * factor[:, j - i] for i in range(m) if 0 <= j - i <= k)
                 for j in range(m + k)]
        coef = torch.stack(terms, dim=1)
    return coef[:, :-1]


def poles_of(w: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """The poles of the factors: ``w (-zeta +- sqrt(zeta^2 - 1))`` per pair, ``-w`` for the
    first-order factor.

    Parameters
    ----------
    w : (batch, ceil(n/2)) array
    zeta : (batch, floor(n/2)) array

    Returns
    -------
    (batch, n) complex array
        Each pair as ``(p, conj p)`` (or two real poles, the slower first), then the real pole.
    """
    half = zeta.shape[1]
    wp = w[:, :half].astype(np.complex128)
    root = np.sqrt(zeta.astype(np.complex128) ** 2 - 1)
    first, second = wp * (-zeta + root), wp * (-zeta - root)
    out = np.stack([first, second], axis=2).reshape(w.shape[0], 2 * half)
    if w.shape[1] > half:
        out = np.concatenate([out, -w[:, half:].astype(np.complex128)], axis=1)
    return out


def raw_of(w: np.ndarray, zeta: np.ndarray, band: tuple[float, float],
           damping: tuple[float, float]) -> np.ndarray:
    """The raw outputs that :func:`factors` maps to ``(w, zeta)`` (its inverse).

    Parameters
    ----------
    w : (batch, ceil(n/2)) array
        Strictly inside ``band``.
    zeta : (batch, floor(n/2)) array
        Strictly inside ``damping``.
    band, damping : (lo, hi)

    Returns
    -------
    raw : (batch, n) array
    """
    def logit(x, lo, hi):
        s = (np.log(x) - np.log(lo)) / (np.log(hi) - np.log(lo))
        return np.log(s) - np.log1p(-s)

    half = zeta.shape[1]
    raw = np.empty((w.shape[0], half * 2 + (w.shape[1] - half)))
    raw[:, 0: 2 * half: 2] = logit(w[:, :half], *band)
    raw[:, 1: 2 * half: 2] = logit(zeta, *damping)
    if w.shape[1] > half:
        raw[:, -1] = logit(w[:, -1], *band)
    return raw
