r"""The input delay of a record, in samples: a classical ARX scan, then a re-scan by projection.

*ARX scan* (:func:`arx_delay`, like MATLAB's ``delayest``): for each ``D = 0 .. max_delay`` the
ARX model of order ``n`` with ``n + 1`` input terms (the FOH discretisation of a strictly proper
``n``-th order system has ``n + 1`` numerator terms, Eq. 10-12) and a constant,

    y_k = -a_1 y_{k-1} - ... - a_n y_{k-n} + b_0 u_{k-D} + ... + b_n u_{k-D-n} + e,

is fitted by least squares on the same samples ``k >= max_delay + n`` for every ``D``; the
shortest delay whose residual sum of squares is within
:func:`~aeid_struct.generic.scoring.delay_margin` of the least is the estimate. A delay one
sample too short misses the term ``u_{k-D-n}``, one too long the term ``u_{k-D}``, so the true
``D`` has the least residual on noise-free data (a held input's strictly proper model has no
``b_0``: ``D`` and ``D + 1`` then fit alike, and the smaller is kept). All ``D`` share one Gram
matrix of the lagged signals; each ``D`` is a small sub-block solve.

*Re-scan* (:func:`rescan`): equation error is biased by noise, so ``D`` is re-scanned over
``D_arx - width .. D_arx + width`` by the model of a record (output error with ``c, d, x_0``
and the offset projected, :func:`~aeid_struct.generic.scoring.select`): the rule is the least
mean squared residual per FITTED sample (a longer delay fits ``steps - D`` samples, so the
mean, not the sum, compares them); ties go to the smaller delay. ``identify`` does this jointly
with the choice of the candidate denominator (every candidate at every delay of the range, one
batched evaluation).
"""

from __future__ import annotations

import numpy as np

from aeid_struct.generic.scoring import delay_margin, select

__all__ = ["arx_delay", "rescan"]


def arx_delay(y: np.ndarray, u: np.ndarray, order: int, max_delay: int) -> int:
    """The input delay with the least ARX equation error (see the module docstring).

    Parameters
    ----------
    y, u : (steps,) arrays
        ``steps > max_delay + 3 order + 2`` (enough rows for every regression).
    order : int, >= 1
    max_delay : int, >= 0

    Returns
    -------
    int
        In ``[0, max_delay]``.
    """
    if max_delay == 0:
        return 0
    n, N = order, y.shape[0]
    k0 = max_delay + n
    width = 2 * n + max_delay + 2
    # the lagged signals in blocks of rows (a long record with a long delay range would
    # otherwise hold N x (max_delay + 2n + 2) numbers at once)
    step = max(1, _BLOCK // (8 * width))
    blocks = [np.arange(a, min(N, a + step)) for a in range(k0, N, step)]
    # each column's largest magnitude from the lagged slices themselves (no matrix built)
    scale = np.array([np.abs(y[k0 - i: N - i]).max() for i in range(1, n + 1)]
                     + [np.abs(u[k0 - j: N - j]).max() for j in range(max_delay + n + 1)]
                     + [1.0])
    scale = np.where(scale > 0, scale, 1.0)
    G, g = np.zeros((width, width)), np.zeros(width)
    for rows in blocks:
        Z = _lagged(y, u, n, max_delay, rows) / scale
        G += Z.T @ Z
        g += Z.T @ y[rows]
    idx = np.array([list(range(n)) + list(range(n + D, n + D + n + 1)) + [width - 1]
                    for D in range(max_delay + 1)])
    Gs = G[idx[:, :, None], idx[:, None, :]]
    Gs += 1e-12 * np.trace(Gs, axis1=1, axis2=2)[:, None, None] * np.eye(idx.shape[1])
    z = np.linalg.solve(Gs, g[idx][..., None])[..., 0]
    # residuals explicitly (not y^T y - g^T z, which cancels on a near-exact fit)
    # each delay's coefficients scattered into a row over all columns: one matmul, no gather
    coef = np.zeros((idx.shape[0], width))
    np.put_along_axis(coef, idx, z, axis=1)
    rss = np.zeros(max_delay + 1)
    for rows in blocks:
        # one block (every record up to ~250k samples here): its lagged matrix is still Z
        lagged = Z if len(blocks) == 1 else _lagged(y, u, n, max_delay, rows) / scale
        rss += np.sum((y[rows][None, :] - coef @ lagged.T) ** 2, axis=1)
    # the smallest delay within the noise of the least residual (generic.scoring.delay_margin:
    # the regression's 2n + 2 parameters are its p; 2 / rows, AIC's margin, let the longest
    # delays win on short records)
    return int(np.flatnonzero(rss <= rss.min() * (1.0 + delay_margin(N - k0, n)))[0])


#: Bytes of lagged signals :func:`arx_delay` holds at once.
_BLOCK = 64 * 2 ** 20


def _lagged(y: np.ndarray, u: np.ndarray, n: int, max_delay: int,
            rows: np.ndarray) -> np.ndarray:
    """The regressors of rows ``rows``: ``y`` lags 1..n, ``u`` lags 0..max_delay + n, 1."""
    cols = [y[rows - i] for i in range(1, n + 1)]
    cols += [u[rows - j] for j in range(max_delay + n + 1)]
    cols.append(np.ones(rows.shape[0]))
    return np.stack(cols, axis=1)


def rescan(den: np.ndarray, y: np.ndarray, u: np.ndarray, around: int, max_delay: int, *,
           width: int = 1, feedthrough: bool = True, offset: bool = True,
           intersample: str = "foh") -> tuple[int, float]:
    """The delay in ``around - width .. around + width`` (within ``[0, max_delay]``) with the
    least output error per fitted sample for the denominator ``den`` (normalised time).

    Parameters
    ----------
    den : (n + 1,) array
        Monic, highest power first.
    y, u : (steps,) arrays
    around : int
        The ARX estimate.
    max_delay : int
    width : int, >= 0
    feedthrough, offset : bool
    intersample : {"foh", "zoh"}

    Returns
    -------
    delay : int
    cost : float
        Its mean squared residual.
    """
    delays = range(max(0, around - width), min(max_delay, around + width) + 1)
    chosen = select(den[None], y, u, delays, feedthrough=feedthrough, offset=offset,
                    intersample=intersample)
    return chosen.delay, float(chosen.costs[0, list(delays).index(chosen.delay)])
