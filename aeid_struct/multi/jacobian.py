r"""Golub and Pereyra's Jacobian of the several-channel fit's projected residual
``r = P(theta) t`` (``multi.fit``), without a projection per column.

    J = -P (dX / dtheta) beta - (X^+)^T (dX / dtheta)^T r.

Along ``a`` (the denominator) each term by forward
differences: the first (Kaufman's) is the model's output at fixed ``B, D``, initial states and
offsets (``multi.realisation.outputs``: one matrix exponential and ``p m`` convolutions)
projected off the design's column space; the second moves ``X^T r``, which the Markov
parameters against the residual's correlations with the inputs give without forming ``X``
(:func:`correlations`, :func:`transposed`), through the design's QR
(``multi.realisation.factor``). Along the free rows of ``C`` both terms are exact: the output is
linear in them at fixed ``B`` and ``x0`` (:func:`output_rows`). A projection per column
(``p n m`` convolutions and a least-squares solve: 32 of them per Jacobian of a 4x4 order-8
record) was the fit's largest cost. Why not Kaufman's term alone (it has the exact gradient
``J^T r``): far from the optimum, where ``r`` is large, it is a poor model of the residual,
and the iterations stalled there (least squares of three 1x1 experiments from ARX poles: a
cost 700 times the optimum's). In the time unit ``h`` (``multi.start.scale_of``) the entries of
``theta`` are of order one, so one relative step suits them all.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from aeid_struct.multi.realisation import (
    Layout,
    Projection,
    factor,
    markov,
    outputs,
    through_state,
)

__all__ = ["correlations", "jacobian", "output_rows", "transposed"]

#: Forward differences' relative step (the square root of float64's eps).
_STEP = float(np.sqrt(np.finfo(np.float64).eps))


def jacobian(layout: Layout, theta, proj: Projection, parts, holds, h: float,
             feedthrough: bool) -> np.ndarray:
    """Golub and Pereyra's Jacobian ``(rows, n p)`` of the projected residual at ``theta``,
    ``proj`` its projection (module docstring).

    Parameters
    ----------
    layout : Layout
    theta : (n p,) array
    proj : Projection
        ``multi.realisation.project`` at ``theta``.
    parts, holds, h, feedthrough
        As ``multi.realisation.project``.

    Returns
    -------
    (rows, n p) array
    """
    A, C = layout.model(theta)
    step = _STEP * np.where(theta >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(theta))
    with np.errstate(all="ignore"):
        F = factor(A, C, parts, h, holds, feedthrough)
        seen = correlations(proj.residual, parts)
        fixed = (proj.B, proj.D, proj.x0, proj.offset, parts)
        # y0 and g0 are the projection's fitted output and X^T r (zero up to round-off), taken
        # again by the path the moved points take, so that the differences cancel its round-off
        here = markov(A, C, parts, h, holds)
        y0 = outputs(here, *fixed)
        g0 = transposed(here, parts, feedthrough, seen)
        moves = np.empty((y0.shape[0], theta.shape[0]))
        turns = np.empty((g0.shape[0], theta.shape[0]))
        n = layout.n
        if layout.p > 1:          # C's free rows: exact, from the state's Markov parameters
            states = markov(A, np.eye(n), parts, h, holds)
            moves[:, n:], turns[:, n:] = output_rows(layout, states, proj.B, proj.x0, parts,
                                                     feedthrough, seen)
        for k in range(n):        # a: forward differences
            moved = theta.copy()
            moved[k] += step[k]
            there = markov(*layout.model(moved), parts, h, holds)
            moves[:, k] = (outputs(there, *fixed) - y0) / (moved[k] - theta[k])
            turns[:, k] = (transposed(there, parts, feedthrough, seen) - g0) / (moved[k]
                                                                               - theta[k])
    moves[~np.isfinite(moves)] = 0.0
    turns[~np.isfinite(turns)] = 0.0
    return -(moves - F.Q @ (F.Q.T @ moves)) - F.pinv_transposed(turns)


def correlations(residual: np.ndarray, parts) -> tuple:
    """Per record ``c[tau, i, j] = sum_k r[k, i] u_j[k - tau]`` (``u_0`` left out, as
    :func:`responses`' convolutions leave it) and ``r (steps, p)``: what :func:`transposed`
    reads, formed once for every parameter point of a Jacobian.

    Parameters
    ----------
    residual : (rows,) array
        Stacked as ``Projection``'s.
    parts : list of R (Y, U) pairs

    Returns
    -------
    tuple of R ``(r (steps, p), c (steps, p, m))``
    """
    out, at = [], 0
    for Y, U in parts:
        steps, p = Y.shape
        r = residual[at: at + Y.size].reshape(steps, p)
        at += Y.size
        later = U.copy()
        later[0] = 0.0
        c = scipy.signal.fftconvolve(r[:, :, None], later[::-1, None, :], axes=0)
        out.append((r, c[steps - 1:]))
    return tuple(out)


def transposed(kernels: tuple, parts, feedthrough: bool, seen: tuple) -> np.ndarray:
    """``X^T r`` of ``multi.realisation.project``'s design (``B`` free) for the residual whose
    :func:`correlations` are ``seen``, ``(width,)``: without forming ``X``, the ``B`` columns by
    the Markov parameters against the correlations (``p n m`` sums of ``steps`` terms, not
    ``p n m`` convolutions).

    Parameters
    ----------
    kernels : tuple
        :func:`~aeid_struct.multi.realisation.markov` of the model's ``A, C``.
    parts, feedthrough
        As ``multi.realisation.project``.
    seen : tuple
        :func:`correlations` of the residual.

    Returns
    -------
    (width,) array
    """
    _, p, n = kernels[0][0].shape
    m = parts[0][1].shape[1]
    shared = n * m + (p * m if feedthrough else 0)
    out = np.zeros(shared + len(parts) * (n + p))
    for k, ((_, U), (tk, t0, O), (r, c)) in enumerate(zip(parts, kernels, seen, strict=True)):
        out[: n * m] += (np.einsum("kil,kij->lj", tk, c)
                         + np.einsum("kil,ki->l", t0, r)[:, None] * U[0]).ravel()
        if feedthrough:
            out[n * m: shared] += (r.T @ U).ravel()
        base = shared + k * (n + p)
        out[base: base + n] = np.einsum("kil,ki->l", O, r)
        out[base + n: base + n + p] = r.sum(axis=0)
    return out


def output_rows(layout: Layout, states: tuple, B, x0s, parts, feedthrough: bool,
                seen: tuple) -> tuple[np.ndarray, np.ndarray]:
    r"""The derivatives along the entries of ``C``'s rows other than the reference one, exact:
    at fixed ``B``, ``x0`` the output ``y_i = C_i x + D_i u + o_i`` is linear in ``C_i``, and
    so is every column of the design, so that ``d y_i / d C_{il} = x_l`` (the state's ``l``-th
    component on every record) and ``d (X^T r) / d C_{il}`` is ``X^T r`` of the state's own
    design (``C = I``) read at output ``i``'s residual. One set of the state's Markov parameters
    replaces a point (a matrix exponential, ``p m`` convolutions and the sums of
    :func:`transposed`) per entry, ``n (p - 1)`` of the ``n p`` that ``multi.fit``'s Jacobian
    moves.

    Parameters
    ----------
    layout : Layout
    states : tuple
        :func:`~aeid_struct.multi.realisation.markov` of the model's ``A`` and ``C = I (n, n)``.
    B : (n, m) array
    x0s : sequence of R (n,) arrays
    parts, feedthrough
        As ``multi.realisation.project``.
    seen : tuple
        :func:`correlations` of the residual.

    Returns
    -------
    moves : (rows, (p - 1) n) array
        The output's derivatives, stacked as ``Projection``'s ``residual``; columns in
        ``theta``'s order after ``a`` (``Layout``).
    turns : (width, (p - 1) n) array
        The derivatives of ``X^T r`` (``X`` with ``B`` free: :func:`transposed`'s entries).
    """
    n, p, m = layout.n, layout.p, layout.m
    rows = [i for i in range(p) if i != layout.reference]
    shared = n * m + (p * m if feedthrough else 0)
    moves, turns = [], np.zeros((shared + len(parts) * (n + p), len(rows), n))
    for k, ((Y, U), (tk, t0, O), x0, (r, c)) in enumerate(
            zip(parts, states, x0s, seen, strict=True)):
        steps = Y.shape[0]
        x = through_state((tk, t0, O), B, U, x0)          # the state itself: C = I
        move = np.zeros((steps, p, len(rows), n))
        for q, i in enumerate(rows):
            move[:, i, q, :] = x
        moves.append(move.reshape(steps * p, len(rows) * n))
        # X^T r of the state's design: [l', l, j, i] for B[l, j] (row l' of C = I), and
        # [l', l, i] for x0[l]; output i's residual picks the derivative along C_{i l'}
        forced = (np.einsum("kab,kij->abji", tk, c[:, rows])
                  + np.einsum("kab,ki->abi", t0, r[:, rows])[:, :, None, :]
                  * U[0][None, None, :, None])
        turns[: n * m] += forced.reshape(n, n * m, len(rows)).transpose(1, 2, 0)
        base = shared + k * (n + p)
        turns[base: base + n] = np.einsum("kab,ki->bia", O, r[:, rows])
    return np.vstack(moves), turns.reshape(turns.shape[0], len(rows) * n)
