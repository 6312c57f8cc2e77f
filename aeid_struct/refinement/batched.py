r"""Separable Gauss-Newton for many records at once, in any partly fixed controllable canonical
form: the identifiers' near-optimal pass (a fixed number of iterations after the encoder) and
the batched refinement (iterations to convergence).

A record of ``N`` samples at sample time ``dt`` and a bottom-row CCF (paper Eq. 5) whose
elements ``a_j, c_j, d`` are each free or fixed (the robot leg's physics: ``c_1 = 0``; the
rotational leg also ``a_1 = 0``) is modelled, exactly under the first-order hold (Eq. 10-13), as

    y = sum_{c_i free} c_i X_i(alpha) + d u + F(alpha) theta + 1 y_offset + e,

with ``alpha`` the free denominator elements, ``X_i`` state ``i``'s response (from rest:
``x_0 = 0``), ``F`` the free responses ``e_1^T Phi^k`` when the initial state is fitted, and the
fixed ``c_i, d`` moved to the left-hand side. Everything but ``alpha`` enters linearly, so it is
projected out (variable projection, Golub & Pereyra): the cost ``V(alpha) = ||P_perp y||^2`` has
one or two variables for the leg, and Levenberg-Marquardt on it with Kaufman's Jacobian
``J = -P_perp dM/dalpha z`` needs a handful of iterations from the encoder's estimate. The
linear part is then the exact least-squares solution, so a noise-free record is fitted exactly.

Why batched numpy and not ``refine_separable`` or CasADi: those serve one record of any length;
the identifiers' records share one length and sample time, so the responses of a whole batch
are one FFT convolution of impulse responses ``Phi^k Bd`` computed by doubling (``log2 N``
batched matrix products), and the small least-squares problems are one batched solve. The
Jacobian is a forward difference in each free ``alpha_j`` (relative step :data:`_FD`): its error
only moves the converged point by that relative amount times the residual, far below the noise.

Where a C compiler is present, ``refinement.gauss_newton`` (``refinement.levenberg``) runs the
same iterations compiled, one record per call (``refinement.compiled``), which costs less than
this path's per-operation overhead; this path (:func:`iterate`) stays the reference and the
fallback.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import scipy.fft

from aeid_struct.refinement import core
from aeid_struct.refinement.powers import discrete, state_rows

__all__ = ["EXACT", "LAMBDA0", "LAMBDA_FACTOR", "LAMBDA_MAX", "LAMBDA_MIN", "RIDGE", "Pattern",
           "SeparableFit", "evaluate", "iterate", "rules"]

#: Forward-difference step of the Jacobian, relative to each free element.
_FD = 1e-7
#: Levenberg-Marquardt damping: start (relative to diag(J^T J)), factor, cap (shared with the
#: compiled path, refinement.compiled, as are EXACT and RIDGE).
LAMBDA0, LAMBDA_FACTOR, LAMBDA_MAX = 1e-4, 10.0, 1e8
#: The damping's floor (shared with the compiled path).
LAMBDA_MIN = 1e-12
#: An exact fit: a mean squared residual below this share of the record's mean square (a
#: residual of 1e-12 relative: rounding, where every further step is rejected).
EXACT = 1e-24
#: Tikhonov floor of the normal equations, relative to the trace of the scaled Gram matrix.
RIDGE = 1e-13
#: The most rows (records times points) evaluated in one basis call (:func:`_bases`).
_TOGETHER = 64


@dataclass(frozen=True)
class Pattern:
    """Which elements of a bottom-row CCF of order ``n`` are free (None) or fixed (a number).

    Attributes
    ----------
    a : tuple of n (float or None)
        ``a_0 .. a_{n-1}`` (the characteristic polynomial ``s^n + a_{n-1} s^{n-1} + ... + a_0``).
    c : tuple of n (float or None)
        ``c_0 .. c_{n-1}``.
    d : float or None
        The feedthrough.
    initial : bool
        Fit the initial state (a record that starts mid-motion); else from rest.
    offset : bool
        Fit a constant output offset.
    """

    a: tuple
    c: tuple
    d: float | None = 0.0
    initial: bool = False
    offset: bool = False

    def __post_init__(self):
        n = len(self.a)
        if n < 1 or len(self.c) != n:
            raise ValueError(f"a and c must have the same length n >= 1; got {len(self.a)} and "
                             f"{len(self.c)}")
        for name, value in [*(("a", v) for v in self.a), *(("c", v) for v in self.c),
                            ("d", self.d)]:
            if value is not None and not (isinstance(value, (int, float)) and
                                          not isinstance(value, bool) and math.isfinite(value)):
                raise ValueError(f"every entry of {name} must be None (free) or a finite "
                                 f"number; got {value!r}")
        if all(v is not None for v in self.a):
            raise ValueError("at least one a_j must be free: with every pole fixed there is "
                             "nothing to iterate (use simulation.project)")

    @classmethod
    def of(cls, names: tuple, fixed: dict, n: int, *, initial: bool, offset: bool = False,
           feedthrough: bool = False) -> Pattern:
        """The pattern of a CCF whose elements ``names`` are free unless ``fixed``.

        Parameters
        ----------
        names : tuple of str
            All element names of the structure (``a0 .. a{n-1}, c0 .. c{n-1}[, d]``).
        fixed : dict str -> float
        n : int
        initial, offset, feedthrough : bool

        Returns
        -------
        Pattern
        """
        def entry(name):
            return float(fixed[name]) if name in fixed else None
        return cls(a=tuple(entry(f"a{j}") for j in range(n)),
                   c=tuple(entry(f"c{j}") for j in range(n)),
                   d=entry("d") if feedthrough else 0.0, initial=initial, offset=offset)

    @property
    def n(self) -> int:
        return len(self.a)

    @property
    def free_a(self) -> np.ndarray:
        return np.array([j for j, v in enumerate(self.a) if v is None], dtype=int)

    @property
    def free_c(self) -> np.ndarray:
        return np.array([j for j, v in enumerate(self.c) if v is None], dtype=int)


@dataclass(frozen=True)
class SeparableFit:
    """What :func:`gauss_newton` returns, one row per record.

    Attributes
    ----------
    a : (B, n) array
        The CCF's ``a_j``, fixed ones included.
    c : (B, n) array
        Its ``c_j``, fixed ones included.
    d : (B,) array
    y_offset : (B,) array
    x0 : (B, n) array
        The initial state (zeros from rest), a property solved on first use.
    cost : (B,) array
        Mean squared residual; inf where the model's response is not finite.
    iterations : (B,) int array
        Accepted Levenberg-Marquardt steps.
    converged : (B,) bool array
    initial : tuple, array or None
        What ``x0`` is solved from, ``Phi (B, n, n)``, the free-response coefficients
        ``theta (B, n)`` and ``g2 u_0 (B, n)``; or ``x0 (B, n)`` itself (the compiled path
        solves it); None from rest.
    """

    a: np.ndarray
    c: np.ndarray
    d: np.ndarray
    y_offset: np.ndarray
    cost: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    initial: tuple | np.ndarray | None = field(default=None, repr=False, compare=False)

    @functools.cached_property
    def x0(self) -> np.ndarray:
        """``(B, n)``, solved on first read (the head never reads it): ``e_1^T Phi^k theta =
        c^T Phi^k delta`` for all ``k``, ``delta`` from ``2n`` samples, ``x0 = delta + g2 u_0``."""
        if self.initial is None:
            return np.zeros_like(self.c)
        if isinstance(self.initial, np.ndarray):
            return self.initial
        Phi, theta, g2u0 = self.initial
        n = Phi.shape[1]
        P = state_rows(Phi, np.arange(n), 2 * n)                        # (B, n, 2n, n): Phi^k
        O = np.einsum("bi,bikj->bkj", self.c, P)                   # c^T Phi^k, (B, 2n, n)
        F = np.einsum("bkj,bj->bk", P[:, 0], theta)
        with np.errstate(all="ignore"):
            G = O.transpose(0, 2, 1) @ O
            G += (1e-14 * np.einsum("bii->b", G) + 1e-300)[:, None, None] * np.eye(n)
            good = np.isfinite(G).all(axis=(1, 2)) & np.isfinite(F).all(axis=1)
            G[~good] = np.eye(n)
            delta = np.linalg.solve(G, (O.transpose(0, 2, 1) @ F[:, :, None]))[:, :, 0]
            delta[~good] = np.nan
        return delta + g2u0


def _full_a(pattern: Pattern, alpha: np.ndarray) -> np.ndarray:
    a = np.array([0.0 if v is None else v for v in pattern.a])[None].repeat(alpha.shape[0], 0)
    a[:, pattern.free_a] = alpha
    return a


def _states(pattern: Pattern) -> np.ndarray:
    """The states whose responses the regressors need: state 1 (the free responses, and the
    first state of every CCF output) and those of the free and nonzero fixed ``c_i``."""
    used = {0} | {i for i, v in enumerate(pattern.c) if v != 0.0}
    return np.array(sorted(used), dtype=int)


def _basis(pattern: Pattern, a: np.ndarray, y: np.ndarray, u: np.ndarray, dt: float,
           U: np.ndarray):
    """Regressors ``M (B, p, N)`` and target ``t (B, N)`` (``y`` less the fixed terms);
    ``U`` is ``rfft(u, L)``, shared by every evaluation of a call."""
    B, N = y.shape
    states = _states(pattern)
    with np.errstate(all="ignore"):
        Phi, g1, g2 = discrete(a, dt)
        R = state_rows(Phi, states, N)                                  # (B, r, N, n)
        Bd = g1 - g2 + (Phi @ g2[:, :, None])[:, :, 0]
        h = (R @ Bd[:, None, :, None])[..., 0]                     # e_i^T Phi^k Bd
        L = 2 * (U.shape[1] - 1)
        xi = scipy.fft.irfft(scipy.fft.rfft(h, L) * U[:, None], L)[:, :, : N - 1]
        X = np.empty((B, states.size, N))
        X[:, :, 0] = 0.0
        X[:, :, 1:] = xi                                           # xi_k, from xi_0 = 0
        X += g2[:, states, None] * u[:, None, :]                   # x_k = xi_k + g2 u_k ...
        if not pattern.initial:                                    # ... + Phi^k (x_0 - g2 u_0)
            X -= (R @ g2[:, None, :, None])[..., 0] * u[:, None, :1]
        where = {int(i): j for j, i in enumerate(states)}
        cols, t = [], y.copy()
        for i, ci in enumerate(pattern.c):
            if ci is None:
                cols.append(X[:, where[i]])
            elif ci != 0.0:
                t -= ci * X[:, where[i]]
        if pattern.d is None:
            cols.append(u)
        elif pattern.d != 0.0:
            t -= pattern.d * u
        if pattern.initial:
            cols.extend(np.moveaxis(R[:, where[0]], 2, 0))         # e_1^T Phi^k e_j
        if pattern.offset:
            cols.append(np.ones_like(y))
        M = np.stack(cols, axis=1)
    return M, t, (Phi, g2)


def _spectrum(u: np.ndarray) -> np.ndarray:
    """``rfft(u)`` zero-padded to a fast length >= 2 N - 1 (a linear, not circular,
    convolution)."""
    return scipy.fft.rfft(u, scipy.fft.next_fast_len(2 * u.shape[1] - 1, real=True))


def _coefficients(Ms: np.ndarray, Gi: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``G^-1 M v`` per record, ``(B, p)`` (``M (B, p, N)``, ``v (B, N)``)."""
    return (Gi @ (Ms @ v[:, :, None]))[:, :, 0]


def _combine(Ms: np.ndarray, z: np.ndarray) -> np.ndarray:
    """``M^T z`` per record, ``(B, N)``."""
    return (z[:, None, :] @ Ms)[:, 0]


def _solve(M: np.ndarray, t: np.ndarray):
    """Row-scaled normal equations per record: ``z (B, p)``, residual ``r (B, N)``,
    ``(M_scaled, G^-1)`` for the projection, and finiteness ``ok (B,)``."""
    ok = np.isfinite(M).all(axis=(1, 2)) & np.isfinite(t).all(axis=1)
    whole = ok.all()                   # the usual case: no row to blank (fewer operations)
    if not whole:
        M, t = np.where(ok[:, None, None], M, 0.0), np.where(ok[:, None], t, 0.0)
    scale = np.abs(M).max(axis=2)
    scale = np.where(scale > 0, scale, 1.0)
    Ms = M / scale[:, :, None]
    G = Ms @ Ms.transpose(0, 2, 1)
    eye = np.eye(G.shape[1])
    G += (RIDGE * np.einsum("bii->b", G) + 1e-300)[:, None, None] * eye
    if not whole:
        G[~ok] = eye
    try:
        Gi = np.linalg.inv(G)
    except np.linalg.LinAlgError:      # a degenerate trial model: minimum-norm solutions
        Gi = np.linalg.pinv(G)
    zs = _coefficients(Ms, Gi, t)
    r = t - _combine(Ms, zs)
    zs += _coefficients(Ms, Gi, r)                    # one step of iterative refinement
    r = t - _combine(Ms, zs)
    return zs / scale, r, Ms, Gi, ok


def evaluate(pattern: Pattern, alpha: np.ndarray, y: np.ndarray, u: np.ndarray,
             dt: float, U: np.ndarray | None = None, *, jacobian: bool = False) -> dict:
    """The projection at ``alpha (B, nf)``: ``cost (B,)`` (mean squared residual, inf where not
    finite), ``r (B, N)``, ``z (B, p)``, and with ``jacobian`` Kaufman's ``J (B, nf, N)``.

    Parameters
    ----------
    pattern : Pattern
    alpha : (B, nf) array
        The free ``a_j`` (in ``pattern.free_a`` order).
    y, u : (B, N) arrays
    dt : float
    U : array, optional
        ``rfft`` of ``u`` as :func:`_spectrum` gives it (computed when not given).
    jacobian : bool
        Also ``J = d r / d alpha = -P_perp dM/dalpha z``, by forward differences of
        ``M^T z - t`` (relative step ``_FD``).

    Notes
    -----
    The shifted models go through the basis call of ``alpha`` (:func:`_bases`): for a few
    records a call costs numpy's per-operation overhead, not its size.
    """
    U = _spectrum(u) if U is None else U
    B, nf = alpha.shape
    points = [alpha]
    if jacobian:
        h = _FD * np.maximum(np.abs(alpha), 1e-8)                    # (B, nf)
        for j in range(nf):
            points.append(alpha.copy())
            points[-1][:, j] += h[:, j]
    (M, t, (Phi, g2)), *shifted = _bases(pattern, points, y, u, dt, U)
    z, r, Ms, Gi, ok = _solve(M, t)
    with np.errstate(all="ignore"):
        cost = np.where(ok, np.mean(r * r, axis=1), np.inf)
    cost = np.where(np.isfinite(cost), cost, np.inf)
    out = {"alpha": alpha, "a": _full_a(pattern, alpha), "M": M, "t": t, "z": z, "r": r,
           "Ms": Ms, "Gi": Gi, "cost": cost, "Phi": Phi, "g2": g2}
    if jacobian:
        with np.errstate(all="ignore"):
            base = _combine(M, z) - t
            dy = np.stack([(_combine(Mj, z) - tj - base) / h[:, j, None]
                           for j, (Mj, tj, _) in enumerate(shifted)], axis=1)   # (B, nf, N)
            # -P_perp dy, every column at once: dy - M^T G^-1 M dy
            J = dy @ Ms.transpose(0, 2, 1) @ Gi @ Ms - dy
        out["J"] = np.where(np.isfinite(J), J, 0.0)
    return out


def _bases(pattern: Pattern, points: list, y, u, dt: float, U) -> list:
    """:func:`_basis` at each ``alpha (B, nf)`` of ``points``: one call over all of them for a
    few records (per-operation overhead), one each for many (their arrays stay in cache)."""
    B, k = y.shape[0], len(points)
    if k == 1 or B * k > _TOGETHER:
        return [_basis(pattern, _full_a(pattern, a), y, u, dt, U) for a in points]
    M, t, (Phi, g2) = _basis(pattern, _full_a(pattern, np.concatenate(points)),
                             *(np.concatenate([v] * k) for v in (y, u)), dt,
                             np.concatenate([U] * k))
    return [(M[i * B: (i + 1) * B], t[i * B: (i + 1) * B],
             (Phi[i * B: (i + 1) * B], g2[i * B: (i + 1) * B])) for i in range(k)]


class _Records:
    """The separable problem of every record at once, for ``core.minimise``."""

    lazy = False

    def __init__(self, pattern: Pattern, y: np.ndarray, u: np.ndarray, dt: float) -> None:
        self.pattern, self.y, self.u, self.dt = pattern, y, u, dt
        self.U = _spectrum(u)

    def evaluate(self, alpha, rows, jacobian, at):
        y, u, U = (self.y, self.u, self.U) if rows is None else (
            self.y[rows], self.u[rows], self.U[rows])
        return evaluate(self.pattern, alpha, y, u, self.dt, U, jacobian=jacobian)


def rules(iterations: int, tol: float | None) -> core.Rules:
    """The damping and stopping rules of the partly fixed CCFs' pass (:func:`iterate`; the
    compiled graph holds the same): ``iterations`` steps, or to ``tol`` where given."""
    if tol is None:
        return core.Rules(max_iter=int(iterations), lambda0=LAMBDA0, factor=LAMBDA_FACTOR,
                          lambda_min=LAMBDA_MIN)
    return core.Rules(max_iter=int(iterations), lambda0=LAMBDA0, factor=LAMBDA_FACTOR,
                      lambda_min=LAMBDA_MIN, lambda_max=LAMBDA_MAX, cost_tol=tol, predicted_tol=tol,
                      exact=EXACT)


def iterate(pattern: Pattern, alpha: np.ndarray, y: np.ndarray, u: np.ndarray, dt: float,
            iterations: int, tol: float | None) -> SeparableFit:
    """``refinement.gauss_newton`` in numpy, every record at once (arguments checked): the
    library's Levenberg-Marquardt (``core.minimise``) on the separable problem.

    Parameters
    ----------
    pattern : Pattern
    alpha : (B, nf) array
    y, u : (B, N) arrays
    dt : float
    iterations : int
    tol : float or None

    Returns
    -------
    SeparableFit
    """
    out = core.minimise(_Records(pattern, y, u, dt), alpha, rules(iterations, tol),
                        energy=np.mean(y * y, axis=1))
    return _fit(pattern, out.evaluation, u, out.accepted, out.converged)


def _fit(pattern: Pattern, e: dict, u: np.ndarray, iterations, converged) -> SeparableFit:
    """The CCF, initial state and offset of the evaluation ``e``."""
    B, n = e["a"].shape
    z = e["z"]
    c = np.array([0.0 if v is None else v for v in pattern.c])[None].repeat(B, 0)
    free_c = pattern.free_c
    c[:, free_c] = z[:, : free_c.size]
    k = free_c.size
    if pattern.d is None:
        d, k = z[:, k], k + 1
    else:
        d = np.full(B, float(pattern.d))
    initial = None
    if pattern.initial:
        initial = (e["Phi"], z[:, k: k + n], e["g2"] * u[:, :1])
        k += n
    y_offset = z[:, k] if pattern.offset else np.zeros(B)
    return SeparableFit(a=e["a"], c=c, d=d, y_offset=y_offset, cost=e["cost"],
                        iterations=iterations, converged=np.asarray(converged, dtype=bool),
                        initial=initial)
