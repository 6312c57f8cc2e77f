r"""The separable fit of channels summed into outputs: a record in which several inputs move at
once (``Physical(mechanism, outputs=..., inputs=...)``), each output the sum of its channels.

Every channel's CCF (paper Eq. 5) has the same denominator ``a`` (the mechanism's
characteristic polynomial), and for a given ``a`` each output is linear in the rest: with
``X_r (steps, n)`` the states of the CCF ``(A(a), e_n)`` driven by channel ``r``'s input from
rest (Eq. 10-12, :class:`Kernel`) and ``O (steps, n)`` the free response
``e_1^T Phi^k`` (the first state of a companion is observable, so it spans every free response
of the output),

    y_g = sum_{r in g} (X_r c_r + u_r d_r) + O x_g,

and the residual of ``a`` is ``w_g (I - P_g) y_g`` stacked over the outputs ``g`` (``P_g`` the
projection on those columns; fixed coefficients of a channel's pattern moved to the left;
``w_g`` the weight of ``refinement.joint``). The library's Levenberg-Marquardt
(``core.minimise``) runs in the free entries of ``a`` alone (variable projection, a
forward-difference Jacobian: ``a`` has at most a few entries). This is the first step of the
head of such a structure (``identification.physical_head``): from the fitted coefficients of
every channel to the nearest physical parameters, as for channels fitted alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from aeid_struct.refinement import core
from aeid_struct.refinement.batched import Pattern

__all__ = ["Kernel", "SummedFit", "fit_summed"]

#: Relative step of the forward differences.
STEP = 1e-7


@dataclass(frozen=True)
class SummedFit:
    """Where :func:`fit_summed` ended, one row per set of records.

    Attributes
    ----------
    a : (B, n) array
        The common denominator.
    c : (B, R, n) array
        Each channel's numerator.
    d : (B, R) array
        Each channel's feedthrough.
    cost : (B,) array
        ``||r||^2`` at ``a``; inf where not finite.
    """

    a: np.ndarray
    c: np.ndarray
    d: np.ndarray
    cost: np.ndarray


class _Problem:
    """Rows of record sets as a problem of ``core.minimise`` in the free entries of ``a``."""

    lazy = True

    def __init__(self, patterns, groups, ys, us, dts, initial) -> None:
        self.patterns, self.groups = patterns, groups
        self.ys, self.us, self.dts, self.initial = ys, us, dts, initial
        self.base = np.array([0.0 if v is None else v for v in patterns[0].a])
        self.free = np.flatnonzero([v is None for v in patterns[0].a])

    def full(self, z: np.ndarray) -> np.ndarray:
        a = np.tile(self.base, (z.shape[0], 1))
        a[:, self.free] = z
        return a

    def solve(self, z: np.ndarray, i: int, coefficients: bool = False):
        """The residual ``(P, N)`` of row ``i``'s records at the points ``z (P, f)``, and, where
        ``coefficients``, each channel's ``c (P, R, n)`` and ``d (P, R)``."""
        return _solve(self.full(z), self.patterns, self.groups, [y[i] for y in self.ys],
                      [u[i] for u in self.us], self.dts, self.initial, coefficients)

    def evaluate(self, z, rows, jacobian, at):
        rows = np.arange(z.shape[0]) if rows is None else rows
        r = np.concatenate([self.solve(zi[None], i)[0] for zi, i in zip(z, rows, strict=True)])
        cost = np.where(np.isfinite(r).all(axis=1), np.sum(r * r, axis=1), math.inf)
        return {"cost": cost, "r": r, "z": z, "rows": rows}

    def jacobian(self, e):
        out = []
        for zi, i, ri in zip(e["z"], e["rows"], e["r"], strict=True):
            h = STEP * np.maximum(np.abs(zi), 1e-3 * np.abs(zi).max() + 1e-12)
            r = self.solve(zi + np.diag(h), i)[0]
            out.append((r - ri) / h[:, None])
        return np.stack(out)


def _solve(a, patterns, groups, ys, us, dts, initial, coefficients):
    """:meth:`_Problem.solve` for one row's records at denominators ``a (P, n)``."""
    from aeid_struct.structures import ccf_matrices

    P, n = a.shape
    A, b, _ = ccf_matrices(a, None)
    R = len(patterns)
    kernels = {}

    def kernel(dt: float, steps: int) -> Kernel:
        # one per grid, shared by every input and the free response
        if (dt, steps) not in kernels:
            kernels[dt, steps] = Kernel(A, b, dt, steps)
        return kernels[dt, steps]

    c_out, d_out = np.full((P, R, n), math.nan), np.full((P, R), math.nan)
    parts, states = [], {}
    with np.errstate(all="ignore"):
        for group in groups:
            y, dt = ys[group[0]], dts[group[0]]
            target = np.tile(y, (P, 1))
            columns, where = [], []
            for r in group:
                # the channels of one input share their states (one array in memory)
                key = (us[r].ctypes.data, us[r].strides, us[r].size, dt)
                if key not in states:
                    states[key] = kernel(dt, y.size).forced(us[r])    # (P, steps, n)
                X = states[key]
                pattern = patterns[r]
                for j, value in enumerate(pattern.c):
                    if value is None:
                        columns.append(X[:, :, j])
                        where.append(("c", r, j))
                    elif value != 0.0:
                        target -= value * X[:, :, j]
                if pattern.d is None:
                    columns.append(np.broadcast_to(us[r], (P, y.size)))
                    where.append(("d", r, 0))
                elif pattern.d != 0.0:
                    target -= pattern.d * us[r]
            if initial:
                free = kernel(dt, y.size).free                       # e_1^T Phi^k
                columns.extend(free[:, :, j] for j in range(n))
            M = np.stack(columns, axis=2)                              # (P, steps, k)
            bad = ~np.isfinite(M).all(axis=(1, 2))
            M[bad] = 0.0
            scale = np.abs(M).max(axis=1)
            scale[scale == 0.0] = 1.0
            U, sv, Vt = np.linalg.svd(M / scale[:, None, :], full_matrices=False)
            keep = sv > max(M.shape[1:]) * np.finfo(float).eps * sv[:, :1]
            z = np.einsum("psk,ps->pk", U * keep[:, None, :], target)
            e = target - np.einsum("psk,pk->ps", U * keep[:, None, :], z)
            e[bad] = math.nan
            parts.append(e * (2.0 / (np.abs(y).max() * math.sqrt(y.size + 1))))
            if coefficients:
                inverse = np.divide(keep, sv, out=np.zeros_like(sv), where=keep)
                theta = np.einsum("pkm,pk->pm", Vt, z * inverse) / scale
                for column, (kind, r, j) in enumerate(where):
                    (c_out[:, r, j] if kind == "c" else d_out[:, r])[...] = theta[:, column]
    if coefficients:
        for r, pattern in enumerate(patterns):
            for j, value in enumerate(pattern.c):
                if value is not None:
                    c_out[:, r, j] = value
            if pattern.d is not None:
                d_out[:, r] = pattern.d
    return np.concatenate(parts, axis=1), c_out, d_out


class Kernel:
    """The responses of ``P`` systems on one grid that the separable fit reads: the states
    driven by an input from rest (:meth:`forced`, Eq. 10-12, the decoder's first-order hold:
    ``x_{k+1} = Phi x_k + E u_k + gamma2 u_{k+1}``, ``x_0 = 0``, so ``x_k = gamma2 u_k -
    Phi^k gamma2 u_0 + sum_j Phi^j Bd u_{k-1-j}``) and the free response ``e_1^T Phi^k``
    (:attr:`free`), from one discretisation and one doubling of the powers for every input.

    Why not ``simulation.outputs_and_basis`` or ``forced_states``: the one convolves each
    state's row directly (``O(N^2)``, a loop over points and states) and the other filters
    point by point; both spent most of the head's time in Python calls. Here the convolution
    is one FFT for all points and states (its rounding is relative to a record's largest
    state, ample for a step that only starts the nearest parameters and the exact joint fit).

    Parameters
    ----------
    A : (P, n, n) array
    b : (P, n) array
    dt : float, > 0
    steps : int
    """

    def __init__(self, A: np.ndarray, b: np.ndarray, dt: float, steps: int) -> None:
        from aeid_struct.simulation import discrete_foh, free_basis

        Phi, gamma1, gamma2 = discrete_foh(A, b, dt)
        Bd = gamma1 - gamma2 + (Phi @ gamma2[..., None])[..., 0]
        P, n = b.shape
        e1 = np.zeros((P, 1, n))
        e1[:, 0, 0] = 1.0
        #: ``(P, steps, n)``: ``e_1^T Phi^k``
        self.free = free_basis(Phi, e1, steps)[:, :, 0]
        # rows (Phi^j Bd)^T = Bd^T (Phi^T)^j and (Phi^j gamma2)^T, j < steps
        powers = free_basis(np.swapaxes(Phi, 1, 2), np.stack([Bd, gamma2], axis=1), steps)
        self.size, self.steps, self.gamma2 = 2 * steps, steps, gamma2
        self.decay = powers[:, :, 1]
        self.markov = np.fft.rfft(powers[:, : steps - 1, 0], self.size, axis=1)

    def forced(self, u: np.ndarray) -> np.ndarray:
        """The states driven by ``u (steps,)`` from rest: ``(P, steps, n)``."""
        steps = self.steps
        xi = np.fft.irfft(self.markov * np.fft.rfft(u, self.size)[None, :, None], self.size,
                          axis=1)[:, : steps - 1]
        out = self.gamma2[:, None, :] * u[None, :, None] - self.decay * u[0]
        out[:, 1:] += xi
        return out


def fit_summed(patterns: tuple, groups: list, a0: np.ndarray, ys: list, us: list,
               dts: tuple, *, iterations: int, initial: bool) -> SummedFit:
    """The separable output-error fit of every channel's CCF with one common denominator,
    each output the sum of its channels (module docstring).

    Parameters
    ----------
    patterns : tuple of R Pattern
        Each channel's fixed and free coefficients (one ``a`` pattern for all).
    groups : list of lists of record indices
        The channels of each output (``simulation.output_groups``).
    a0 : (B, f) array
        The start: the free entries of ``a`` of each row.
    ys, us : lists of R (B, steps_r) arrays
        Each channel's output (its group's, repeated) and input.
    dts : tuple of R floats
    iterations : int
        Levenberg-Marquardt iterations per row (a fixed cost).
    initial : bool
        Fit each output's initial state.

    Returns
    -------
    SummedFit
    """
    if not all(isinstance(p, Pattern) and p.a == patterns[0].a for p in patterns):
        raise ValueError("patterns must share one denominator pattern (a)")
    problem = _Problem(patterns, groups, ys, us, dts, initial)
    z0 = np.asarray(a0, dtype=np.float64)
    rules = core.Rules(max_iter=int(iterations), lambda_max=1e12, cost_tol=1e-12,
                       step_tol=1e-12)
    out = core.minimise(problem, z0, rules)
    z = out.x
    B = z.shape[0]
    n = len(patterns[0].a)
    c = np.full((B, len(patterns), n), math.nan)
    d = np.full((B, len(patterns)), math.nan)
    for i in range(B):
        _, ci, di = problem.solve(z[i][None], i, coefficients=True)
        c[i], d[i] = ci[0], di[0]
    return SummedFit(problem.full(z), c, d, np.asarray(out.evaluation["cost"]))
