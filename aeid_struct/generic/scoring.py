r"""The whole-record choice among candidate denominators: every candidate at every delay scored
by the model of a record, in blocks of bounded memory.

*Aggregation.* Every candidate (:func:`~aeid_struct.generic.windows.candidates`) is evaluated on
the WHOLE record by the model of a record (:func:`~aeid_struct.simulation.project`: ``c, d,
x_0`` and the output offset projected for the candidate's poles) and the one with the least mean
squared output error is kept. This is the criterion the estimate is judged by, it needs no
matching of poles across windows (real vs complex pairs, ordering), and a window with poor
excitation or out of the network's band yields a candidate that simply loses; averaging poles (a
median) lets such windows pull the estimate. :func:`select` evaluates all candidates at once:
the same regressors as :func:`~aeid_struct.simulation.project` (CCF forced states, input, the
first state's free response, ones), solved by column-scaled normal equations with one step of
iterative refinement (the ranking needs the cost, not ``lstsq``'s last digits, and this is one
batched product for all candidates).

*Memory.* Candidates and delays are scored in blocks of at most :data:`BLOCK_BYTES` of working
arrays, and only the winner's regressors are rebuilt for its projection, so a record's memory
grows with its length, not with candidates x delays x samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.signal

from aeid_struct.simulation import Projection, discrete_foh
from aeid_struct.structures import ccf_matrices

__all__ = ["BLOCK_BYTES", "PREFIX", "PREFIX_SHORTLIST", "Selection", "ccf", "delay_margin",
           "scores", "select", "solution"]


def ccf(den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bottom-row controllable canonical form (Eq. 5) of monic denominators.

    Parameters
    ----------
    den : (K, n + 1) or (n + 1,) array

    Returns
    -------
    A : (K, n, n) or (n, n) array
    b : (K, n) or (n,) array
    """
    den = np.asarray(den, dtype=np.float64)
    one = den.ndim == 1
    den = np.atleast_2d(den)
    A, b, _ = ccf_matrices(den[:, :0:-1], None)
    return (A[0], b[0]) if one else (A, b)


def _regressors(dens: np.ndarray, uu: np.ndarray, feedthrough: bool, offset: bool,
                intersample: str = "foh"):
    """The regressors of :func:`~aeid_struct.simulation.project` for each candidate (dt = 1),
    one per row: ``M (K, p, N)``, with ``Phi (K, n, n)`` and ``gamma2 (K, n)`` (zero for a held
    input, ``simulation.discrete_foh``)."""
    A, b = ccf(dens)
    K, n = b.shape
    N = uu.shape[0]
    Phi, gamma1, gamma2 = discrete_foh(A, b, 1.0, intersample)
    Bd = gamma1 - gamma2 + np.einsum("kij,kj->ki", Phi, gamma2)
    # discrete denominator from the poles (exp of the continuous ones), as np.poly would
    z = np.exp(np.linalg.eigvals(A))
    a = np.zeros((K, n + 1), dtype=complex)
    a[:, 0] = 1.0
    for j in range(n):
        a[:, 1 : j + 2] = a[:, 1 : j + 2] - z[:, j : j + 1] * a[:, : j + 1]
    a = a.real
    markov = np.empty((K, n, n))
    markov[:, 0] = Bd
    for m in range(1, n):
        markov[:, m] = np.einsum("kij,kj->ki", Phi, markov[:, m - 1])
    num = np.zeros((K, n + 1, n))
    for k in range(1, n + 1):
        num[:, k] = sum(a[:, i, None] * markov[:, k - 1 - i] for i in range(k))
    # one regressor per row of M (K, p, N): each column of the least-squares problem is
    # contiguous, and nothing is concatenated (memory traffic dominates at these sizes)
    M = np.empty((K, 2 * n + int(feedthrough) + int(offset), N))
    # forced states X = W num + u gamma2^T (W: the filtered input and its n shifts)
    W = np.zeros((K, n + 1, N))
    for i in range(K):
        W[i, 0] = scipy.signal.lfilter([1.0], a[i], uu)
    for k in range(1, n + 1):
        W[:, k, k:] = W[:, 0, : N - k]
    M[:, :n] = num.transpose(0, 2, 1) @ W
    M[:, :n] += gamma2[:, :, None] * uu
    col = n
    if feedthrough:
        M[:, n] = uu
        col += 1
    # free response of the first state, (Phi^T)^k e_1, by doubling (one batched product a level)
    F = M[:, col : col + n]
    F[:, :, 0] = 0.0
    F[:, 0, 0] = 1.0
    P, k = Phi.transpose(0, 2, 1), 1
    while k < N:
        m = min(k, N - k)
        F[:, :, k : k + m] = P @ F[:, :, :m]
        k += m
        if k < N:
            P = P @ P
    if offset:
        M[:, -1] = 1.0
    return M, Phi, gamma2


@dataclass(frozen=True)
class Selection:
    """The best (candidate, delay) pair of :func:`select`.

    Attributes
    ----------
    index : int
        The candidate's row.
    delay : int
    costs : (K, L) array
        Mean squared residual per fitted sample of every candidate at every delay (``inf``
        where the response is not finite).
    projection : Projection
        The winner's ``c, d, x_0, y_offset``, output and fit.
    """

    index: int
    delay: int
    costs: np.ndarray
    projection: Projection


def select(dens: np.ndarray, y: np.ndarray, u: np.ndarray, delays, *,
           feedthrough: bool = True, offset: bool = True,
           shortlist: int | None = None, around: int | None = None,
           intersample: str = "foh") -> Selection:
    """Every candidate denominator at every delay, evaluated on the whole record with ``c, d,
    x_0`` and the offset projected (normalised time, dt = 1), and the best pair by the mean
    squared residual on the samples that every delay fits (from the largest delay on).

    The regressors of :func:`~aeid_struct.simulation.project` are causal in the input, so those
    of delay ``D`` are the first ``steps - D`` rows of those of the smallest delay: one set of
    regressors per candidate serves every delay, and each (candidate, delay) is one small
    normal-equation solve (column-scaled, one refinement step; the ranking needs the cost, not
    ``lstsq``'s last digits).

    Parameters
    ----------
    dens : (K, n + 1) array
        Monic denominators, highest power first.
    y, u : (steps,) arrays
    delays : sequence of int
        Each in ``[0, steps - 2]``.
    feedthrough, offset : bool
        As for :func:`~aeid_struct.simulation.project`.
    shortlist : int, optional
        Evaluate every candidate at the delay ``around`` only, and the ``shortlist`` best of
        them at every delay (their other costs stay ``inf``); default: every pair. On a record
        longer than :data:`PREFIX` samples the first ranking reads its first ``PREFIX``
        samples only and keeps at least :data:`PREFIX_SHORTLIST` candidates, which are then
        scored on the whole record (the others' costs are ``inf``): scoring a hundred
        candidates on ten million samples took minutes, and a candidate that is not among the
        best few on 32,768 samples of a stationary record does not win on all of them.
    around : int, optional
        One of ``delays`` (default: the middle one).
    intersample : {"foh", "zoh"}
        The input between samples (``records.Record.intersample``).

    Returns
    -------
    Selection

    Raises
    ------
    ValueError
        When no candidate has a finite response.
    """
    delays = sorted({int(D) for D in delays})
    D0 = delays[0]
    N = y.shape[0] - D0
    K, L = dens.shape[0], len(delays)
    costs = np.full((K, L), np.inf)
    pool = np.arange(K)
    prefix = shortlist is not None and N > PREFIX and K > max(shortlist, PREFIX_SHORTLIST)
    if shortlist is not None and (L > 1 or prefix) and K > shortlist:
        # the candidates at one delay, then the best few at every delay
        mid = L // 2 if around is None else delays.index(int(around))
        P = PREFIX if prefix else N
        for part, M, G_all, *_ in _blocks(dens, pool, u[:P], feedthrough, offset, 1,
                                          intersample):
            costs[part, mid] = _solve_delays(M, G_all, y[: D0 + P], [delays[mid]], D0,
                                             delays[-1])[0][:, 0]
        ranked = np.argsort(costs[:, mid], kind="stable")
        pool = ranked[np.isfinite(costs[ranked, mid])][
            : max(shortlist, PREFIX_SHORTLIST) if prefix else shortlist]
        if prefix:       # costs on the prefix do not compare with the whole record's
            costs[:, mid] = np.inf
    last = None
    for last in _blocks(dens, pool, u[:N], feedthrough, offset, L, intersample):
        part, M, G_all = last[:3]
        for js in _delay_blocks(L, part.size, N):
            costs[part[:, None], js[None, :]] = _solve_delays(
                M, G_all, y, [delays[j] for j in js], D0, delays[-1])[0]
    costs = np.where(np.isfinite(costs), costs, np.inf)
    if not np.isfinite(costs).any():
        raise ValueError(f"no candidate denominator has a finite response on this record "
                         f"({y.shape[0]} samples)")
    k, j = np.unravel_index(np.argmin(costs), costs.shape)
    # Parsimony in the delay: the smallest delay within delay_margin of the best cost. A delay
    # is often barely identifiable (slow dynamics, a staircase input: fits differ in the third
    # decimal) and noise then picks any; measured, the least-cost delay was the largest
    # allowed for true delays 0-5, costing validation fit.
    common = y.shape[0] - max(delays)
    margin = delay_margin(common, dens.shape[1] - 1)
    j = int(np.flatnonzero(costs[k] <= costs[k, j] * (1.0 + margin))[0])
    # the winner's regressors for its projection: from the last block where it is there (a
    # record of ordinary length is one block), else built once more (only costs were kept)
    if last is not None and k in last[0]:
        i = int(np.flatnonzero(last[0] == k)[0])
        M, G_all, Phi, gamma2 = (v[i : i + 1] for v in last[1:])
    else:
        with np.errstate(all="ignore"):
            M, Phi, gamma2 = _regressors(dens[k : k + 1], u[:N], feedthrough, offset,
                                         intersample)
        G_all = M @ M.transpose(0, 2, 1)
    _, Z, fitted, rows = _solve_delays(M, G_all, y, [delays[j]], D0, delays[-1])
    return Selection(int(k), delays[j], costs, _projection(
        Z[0, 0], fitted[0, : rows[0], 0], M[0], Phi[0], gamma2[0], y, u, delays[j],
        feedthrough, offset))


def delay_margin(samples: int, order: int) -> float:
    r"""The relative cost margin within which two delays fit a record alike (the shorter one is
    then kept): ``2 sqrt(2 p) / (samples - p)``, ``p = 2 order + 2`` (the projected ``c, x_0``,
    ``d`` and the offset).

    Why this size: two fits of ``p`` parameters to the same ``samples`` residuals that describe
    the record alike (neither nearer the truth) have residual sums near ``sigma^2 (samples -
    p)`` that differ by up to about ``2 sqrt(p) sigma^2`` in standard deviation (the noise's
    projections on their two column spaces, chi-square with ``p`` degrees each; less where the
    spaces overlap, as neighbouring delays' do): the margin is at least 1.4 of those. The margin
    it replaced, ``2 / samples`` (AIC's for one parameter), is seven times smaller on a
    64-sample record of order 6: there noise chose the delay and the longest delays won
    (``aeid-struct bench-generic``'s rows of 64 and 200 samples; on 400-1000 samples the two
    margins won and lost alike).

    Parameters
    ----------
    samples : int
        The samples every compared delay's cost counts.
    order : int

    Returns
    -------
    float
    """
    p = 2 * order + 2
    return 2.0 * np.sqrt(2.0 * p) / max(samples - p, 1)


#: Samples the first ranking of :func:`select` reads on a longer record, and the candidates
#: it keeps for the whole record.
PREFIX = 32768
PREFIX_SHORTLIST = 4

#: Bytes of working arrays :func:`select` holds at once (regressors, targets and outputs of a
#: block of candidates and delays): a record of any length is scored in blocks, so that its
#: memory grows with the record and not with candidates x delays x samples.
BLOCK_BYTES = 256 * 2 ** 20


def _blocks(dens: np.ndarray, pool: np.ndarray, uu: np.ndarray, feedthrough: bool,
            offset: bool, delays: int, intersample: str = "foh"):
    """``(candidates, M, G, Phi, gamma2)`` of the finite candidates of ``pool`` in blocks
    that fit :data:`BLOCK_BYTES` (with ``delays`` targets each)."""
    n = dens.shape[1] - 1
    p = 2 * n + int(feedthrough) + int(offset)
    per = 8 * uu.shape[0] * (p + n + 2 + 2 * min(delays, 8))
    size = max(1, BLOCK_BYTES // per)
    for start in range(0, pool.size, size):
        part = pool[start : start + size]
        with np.errstate(all="ignore"):
            M, Phi, gamma2 = _regressors(dens[part], uu, feedthrough, offset, intersample)
            good = np.isfinite(M).all(axis=(1, 2))
        if good.any():
            M = M[good]
            yield part[good], M, M @ M.transpose(0, 2, 1), Phi[good], gamma2[good]


def _delay_blocks(L: int, K: int, N: int):
    """Index blocks of the ``L`` delays whose ``(K, N, block)`` outputs fit
    :data:`BLOCK_BYTES`."""
    size = max(1, BLOCK_BYTES // (8 * N * (3 * K + 2)))
    for start in range(0, L, size):
        yield np.arange(start, min(L, start + size))


def _solve_delays(M: np.ndarray, G_all: np.ndarray, y: np.ndarray, delays: list, D0: int,
                  last: int | None = None):
    """Costs ``(K, L)``, solutions ``Z (K, L, p)``, outputs ``(K, N, L)`` and fitted rows
    ``(L,)`` of regressors ``M (K, p, N)`` (of delay ``D0``) at each delay.

    Column scaling from the Gram matrix's diagonal (slow and fast modes' columns differ by
    orders of magnitude); a tiny ridge keeps a rank-deficient problem solvable (a step input:
    its column equals the offset's). Every delay at once: its target ``y[D:]`` zero-padded to
    ``N`` rows (the padded rows add nothing to the normal equations), its Gram matrix that of
    the first ``N - (D - D0)`` rows."""
    N = M.shape[2]
    scale = np.sqrt(np.einsum("kii->ki", G_all))
    scale = np.where(scale > 0, scale, 1.0)
    outer = scale[:, :, None] * scale[:, None, :]
    ridge = 1e-13 * M.shape[1] * np.eye(M.shape[1])
    L = len(delays)
    rows = N - (np.asarray(delays) - D0)
    T = np.zeros((N, L))
    for j, D in enumerate(delays):
        T[: rows[j], j] = y[D:]
    mask = np.arange(N)[:, None] < rows[None, :]                          # (N, L)
    G = np.repeat(G_all[:, None], L, axis=1)                              # (K, L, p, p)
    for j in range(L):
        tail = M[:, :, rows[j]:]
        if tail.shape[2]:
            G[:, j] -= tail @ tail.transpose(0, 2, 1)
    G = G / outer[:, None] + ridge
    Mt = M.transpose(0, 2, 1)                                             # (K, N, p)
    zs = np.linalg.solve(G, ((M @ T) / scale[:, :, None]).transpose(0, 2, 1)[..., None])
    fitted = (Mt @ (zs[..., 0] / scale[:, None, :]).transpose(0, 2, 1)) * mask  # (K, N, L)
    zs += np.linalg.solve(G, ((M @ (T - fitted)) / scale[:, :, None]).transpose(0, 2, 1)
                          [..., None])
    Z = zs[..., 0] / scale[:, None, :]                                    # (K, L, p)
    fitted = (Mt @ Z.transpose(0, 2, 1)) * mask
    # Ranked on the samples every delay fits (from the largest delay on): per fitted sample, a
    # longer delay won by dropping the record's first samples, the hardest to fit mid-motion
    # (measured: delay 10 chosen for a true 0, validation fit 83 % against 94 %).
    last = max(delays) if last is None else last      # the largest delay of the comparison
    skip = last - np.asarray(delays)
    common = (np.arange(N)[:, None] >= skip[None, :]) & mask
    cost = np.sum(((T - fitted) * common) ** 2, axis=1) / (N - (last - D0))
    return cost, Z, fitted, rows


def _projection(z, fitted, M, Phi, gamma2, y, u, delay, feedthrough, offset) -> Projection:
    """The :class:`~aeid_struct.simulation.Projection` of one solved candidate."""
    n = Phi.shape[0]
    c = z[:n]
    f = n + int(feedthrough)
    theta = z[f : f + n]
    # delta from c^T Phi^k delta = F theta on the first rows, as project does
    rows = min(fitted.shape[0], 4 * n)
    O = np.empty((rows, n))
    O[0] = c
    for k in range(1, rows):
        O[k] = O[k - 1] @ Phi
    delta = np.linalg.lstsq(O, theta @ M[f : f + n, :rows], rcond=None)[0]
    used = y[delay:]
    y_hat = np.full(y.shape, np.nan)
    y_hat[delay:] = fitted
    res = used - fitted
    fit = (100.0 * (1.0 - np.linalg.norm(res) / np.linalg.norm(used - used.mean()))
           if np.ptp(used) > 0 else np.nan)
    return Projection(c=c, d=float(z[n]) if feedthrough else 0.0, x0=delta + gamma2 * u[0],
                      y_offset=float(z[-1]) if offset else 0.0, y_hat=y_hat, fit=fit,
                      cost=float(np.mean(res ** 2)), delay=delay)


def scores(dens: np.ndarray, y: np.ndarray, u: np.ndarray, *, delay: int = 0,
           feedthrough: bool = True, offset: bool = True,
           intersample: str = "foh") -> np.ndarray:
    """Mean squared output error on the whole record of each candidate denominator at one
    delay (:func:`select`'s costs).

    Parameters
    ----------
    dens : (K, n + 1) array
    y, u : (steps,) arrays
    delay : int, 0 <= delay < steps - 1
    feedthrough, offset : bool
    intersample : {"foh", "zoh"}

    Returns
    -------
    (K,) array
        ``inf`` where the candidate's response is not finite.
    """
    try:
        return select(dens, y, u, [delay], feedthrough=feedthrough, offset=offset,
                      intersample=intersample).costs[:, 0]
    except ValueError:
        return np.full(dens.shape[0], np.inf)


def solution(den: np.ndarray, y: np.ndarray, u: np.ndarray, *, delay: int = 0,
             feedthrough: bool = True, offset: bool = True,
             intersample: str = "foh") -> Projection:
    """:func:`~aeid_struct.simulation.project` of the CCF of one denominator (dt = 1) by the
    solver of :func:`select`: the same model, a cheaper solve.

    Parameters
    ----------
    den : (n + 1,) array
    y, u : (steps,) arrays
    delay : int
    feedthrough, offset : bool
    intersample : {"foh", "zoh"}

    Returns
    -------
    Projection
    """
    return select(den[None], y, u, [delay], feedthrough=feedthrough, offset=offset,
                  intersample=intersample).projection
