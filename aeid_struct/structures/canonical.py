r"""The canonical forms: controllable (CCF, paper Eq. 5) and modal (MCF, paper Eq. 6).

CCF
---
Bottom-row controllable canonical form (paper Eq. 5)::

    A = [[0, 1, ..., 0], ..., [0, ..., 0, 1], [-a_0, -a_1, ..., -a_{n-1}]],  b = e_n,
    c = (c_0, ..., c_{n-1}),  d (0 unless feedthrough=True),
    G(s) = (c_{n-1} s^{n-1} + ... + c_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0) + d.

Elements ``a0..a{n-1}, c0..c{n-1}[, d]``; all free reals (identity map), or with
``descartes=True`` ``a_i = softplus(theta_i) >= 0``. Descartes' rule of signs: with no sign
change in ``(a_0, ..., a_{n-1}, 1)`` the characteristic polynomial has no positive real root,
so no pole lies on the positive real axis (``a_0 = 0``, reachable by fixing, puts a pole at
the origin). Complex pairs with a positive real part are *not* excluded
(``s^3 + s^2 + s + 10`` has poles ``0.68 +- 1.94j``); the paper (Sec. III-B) says the same.

MCF
---
Modal canonical form (paper Eq. 6), real modes first, then the complex pairs::

    A = blkdiag(lambda_0, ..., lambda_{r-1}, [[delta_0, omega_0], [-omega_0, delta_0]], ...),
    lambda_i = -(softplus(theta) + eps),  delta_j = -(softplus(theta) + eps),
    omega_j = softplus(theta) + eps,      eps = 1e-8,

so every sampled ``A`` is Hurwitz by construction, also where softplus underflows to 0. The
margin ``eps`` keeps ``Re(eig) < 0`` strictly; it is far below any pole that a record of
finite length can resolve.

*Scaling redundancy.* ``(T b, c T^-1)`` with any ``T`` commuting with ``A`` (a diagonal
scaling of a real mode, ``[[x, y], [-y, x]]`` on a pair) gives the same transfer function, so
the paper's ``3n`` numbers (poles, ``b~``, ``c~``) are not identifiable. We fix
``b = 1`` for each real mode and ``b = (0, 1)`` for each pair and estimate ``c`` only: ``2n``
elements (+ ``d``). ``b = (0, 1)`` keeps a pair controllable (its controllability matrix is
``[[0, omega], [1, delta]]``, ``omega > 0``), and the only ``T`` of the commuting form with
``T b = b`` is the identity, so no redundancy remains but the order of the modes.

*Permutation redundancy.* Reordering real modes (or pairs) among themselves reorders the
elements without changing the model. The forward map leaves it alone (the training loss is
invariant to it; forcing an order would need a non-elementwise map). ``elements_of`` returns
the canonical order: real modes slowest first (``lambda_0 >= lambda_1 >= ...``), pairs by
increasing ``omega``; with fixed elements it picks the first ordering consistent with them.

Elements ``lambda0..``, then ``delta0, omega0, delta1, omega1, ..``, then ``c0..c{n-1}``
(state order: ``c_i`` for real mode ``i``, ``c_{r+2j}, c_{r+2j+1}`` for pair ``j``), then
``d`` if ``feedthrough``. Pair ``j`` contributes
``(c_{r+2j+1} s + c_{r+2j} omega_j - c_{r+2j+1} delta_j) / ((s - delta_j)^2 + omega_j^2)``.
"""

from __future__ import annotations

import itertools
import math

import casadi
import numpy as np
import torch

from aeid_struct.structures.base import Structure
from aeid_struct.structures.constraints import ElementMap, switch
from aeid_struct.structures.realisation import ccf_coefficients
from aeid_struct.structures.system import System

__all__ = ["CCF", "MCF"]

#: Largest number of mode orderings MCF.elements_of tries when matching fixed elements.
_MAX_PERMUTATIONS = 5040


def _constant(x: torch.Tensor, values: list[float]) -> torch.Tensor:
    """A constant (batch, len(values)) tensor like ``x``."""
    return x.new_tensor(values).expand(x.shape[0], len(values)).clone()


def _matrix(entries: dict[tuple[int, int], torch.Tensor], n: int, like: torch.Tensor):
    """(batch, n, n) from its nonzero entries; out of place, so autograd sees every entry."""
    zero = like.new_zeros(like.shape[0])
    flat = [entries.get((i, j), zero) for i in range(n) for j in range(n)]
    return torch.stack(flat, 1).reshape(-1, n, n)


# ---------------------------------------------------------------------------------------------
# Controllable canonical form
# ---------------------------------------------------------------------------------------------
class CCF(Structure):
    """Bottom-row controllable canonical form (paper Eq. 5), see the module docstring.

    Elements: ``a0..a{n-1}, c0..c{n-1}`` (+ ``d``); ``p = 2n`` (+1).

    Parameters
    ----------
    n : int
        Order, >= 1.
    descartes : bool
        Constrain ``a_i = softplus(theta_i) >= 0`` (no positive real pole, by Descartes' rule of
        signs; unstable complex pairs remain possible).
    feedthrough : bool
        Estimate ``d`` (element ``"d"``); otherwise ``d = 0``.

    Raises
    ------
    ValueError
        If ``n`` is not an integer ``>= 1`` or a switch is not a bool.
    """

    def __init__(self, n: int, *, descartes: bool = False, feedthrough: bool = False) -> None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"n must be an integer >= 1; got {n!r}")
        self.descartes = switch("descartes", descartes)
        self.feedthrough = switch("feedthrough", feedthrough)
        a_map = ElementMap("nonneg", note="Descartes") if self.descartes else ElementMap("real")
        maps = {f"a{i}": a_map for i in range(n)}
        maps |= {f"c{i}": ElementMap("real") for i in range(n)}
        if self.feedthrough:
            maps["d"] = ElementMap("real")
        super().__init__(int(n), maps)

    def _config(self) -> dict:
        return {"n": self.n, "descartes": self.descartes, "feedthrough": self.feedthrough}

    def _assemble(self, x: torch.Tensor) -> System:
        n = self.n
        one = x.new_ones(x.shape[0])
        entries = {(i, i + 1): one for i in range(n - 1)}
        entries |= {(n - 1, j): -x[:, j] for j in range(n)}
        b = _constant(x, [0.0] * (n - 1) + [1.0])
        d = self._column(x, "d") if self.feedthrough else x.new_zeros(x.shape[0])
        return System(_matrix(entries, n, x), b, x[:, n : 2 * n], d)

    def _casadi_assemble(self, x) -> tuple:
        n = self.n
        A = type(x).zeros(n, n)
        for i in range(n - 1):
            A[i, i + 1] = 1.0
        A[n - 1, :] = -x[:n].T
        b = casadi.DM([0.0] * (n - 1) + [1.0])
        d = x[2 * n] if self.feedthrough else casadi.DM(0.0)
        return A, b, x[n : 2 * n], d

    def _elements_of(self, A, b, c, d, strict):
        if not self.feedthrough:
            self._no_feedthrough(d, strict)
        a, num = ccf_coefficients(A, b, c)
        return np.concatenate([a, num] + ([d[:, None]] if self.feedthrough else []), 1)


# ---------------------------------------------------------------------------------------------
# Modal canonical form
# ---------------------------------------------------------------------------------------------
class MCF(Structure):
    """Modal canonical form (paper Eq. 6), stable by construction; see the module docstring.

    Order ``n = real + 2 pairs``; ``b`` is fixed (1 per real mode, ``(0, 1)`` per pair) and ``c``
    estimated: ``p = 2n`` (+1) raw parameters, where the paper counts ``3n``.

    Parameters
    ----------
    real : int
        Number of real poles ``lambda_i < 0``.
    pairs : int
        Number of complex pairs ``delta_j +- i omega_j``, ``delta_j < 0 < omega_j``.
    feedthrough : bool
        Estimate ``d``; otherwise ``d = 0``.

    Raises
    ------
    ValueError
        If ``real`` or ``pairs`` is not an integer ``>= 0``, both are 0, or a switch is not a
        bool.
    """

    def __init__(self, *, real: int = 0, pairs: int = 1, feedthrough: bool = False) -> None:
        for name, v in (("real", real), ("pairs", pairs)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"{name} must be an integer >= 0; got {v!r}")
        if real == 0 and pairs == 0:
            raise ValueError("MCF needs at least one mode; got real=0 and pairs=0")
        self.real, self.pairs = int(real), int(pairs)
        self.feedthrough = switch("feedthrough", feedthrough)
        n = self.real + 2 * self.pairs
        hurwitz = "poles in the open left half-plane"
        maps = {f"lambda{i}": ElementMap("neg", note=hurwitz) for i in range(self.real)}
        for j in range(self.pairs):
            maps[f"delta{j}"] = ElementMap("neg", note=hurwitz)
            maps[f"omega{j}"] = ElementMap("pos", note="imaginary part of the upper pole")
        maps |= {f"c{i}": ElementMap("real") for i in range(n)}
        if self.feedthrough:
            maps["d"] = ElementMap("real")
        super().__init__(n, maps)

    def _config(self) -> dict:
        return {"real": self.real, "pairs": self.pairs, "feedthrough": self.feedthrough}

    def _assemble(self, x: torch.Tensor) -> System:
        r, n = self.real, self.n
        entries = {(i, i): x[:, i] for i in range(r)}
        for j in range(self.pairs):
            k = r + 2 * j
            delta, omega = x[:, r + 2 * j], x[:, r + 2 * j + 1]
            entries |= {(k, k): delta, (k, k + 1): omega, (k + 1, k): -omega,
                        (k + 1, k + 1): delta}
        b = _constant(x, [1.0] * r + [0.0, 1.0] * self.pairs)
        d = self._column(x, "d") if self.feedthrough else x.new_zeros(x.shape[0])
        return System(_matrix(entries, n, x), b, x[:, n : 2 * n], d)

    def _casadi_assemble(self, x) -> tuple:
        r, n = self.real, self.n
        A = type(x).zeros(n, n)
        for i in range(r):
            A[i, i] = x[i]
        for j in range(self.pairs):
            k = r + 2 * j
            delta, omega = x[k], x[k + 1]
            A[k, k], A[k, k + 1], A[k + 1, k], A[k + 1, k + 1] = delta, omega, -omega, delta
        b = casadi.DM([1.0] * r + [0.0, 1.0] * self.pairs)
        d = x[2 * n] if self.feedthrough else casadi.DM(0.0)
        return A, b, x[n : 2 * n], d

    def _elements_of(self, A, b, c, d, strict):
        if not self.feedthrough:
            self._no_feedthrough(d, strict)
        B, n, r = A.shape[0], self.n, self.real
        poles, V = np.linalg.eig(A)
        # A defective A (a repeated pole with a Jordan block, e.g. G = 1/(s+1)^2) has no modal
        # form; its eigenvector matrix is then (nearly) singular.
        cond = np.linalg.cond(V)
        bad = ~np.isfinite(cond) | (cond > 1e12)
        if np.any(bad):
            row = int(np.flatnonzero(bad)[0])
            raise ValueError(f"the model (row {row}) has a repeated pole without a full set of "
                             f"eigenvectors (poles {np.round(poles[row], 6)}); {self!r} cannot "
                             "represent it")
        # Residues of G at each pole: (c v_i) (w_i^T b), W = V^-1.
        cV = np.einsum("bi,bij->bj", c.astype(complex), V)
        res = cV * np.linalg.solve(V, b.astype(complex)[..., None])[..., 0]
        scale = np.abs(poles).max(1, keepdims=True)
        rel = np.abs(poles.imag) / np.where(scale > 0, scale, 1.0)    # all poles at 0: real
        n_real = (rel <= math.sqrt(np.finfo(float).eps)).sum(1)
        # the r poles nearest the real axis are the real modes, where each is real to working
        # precision; the others pair up, a pair whose imaginary part is below that precision
        # included (the form's own floor on omega: a fit held stable ends there, and counting
        # it as two real poles refused the model the form had just produced)
        is_real = np.zeros(poles.shape, dtype=bool)
        np.put_along_axis(is_real, np.argsort(rel, axis=1, kind="stable")[:, :r], True, 1)
        wrong = (np.any(is_real & (rel > math.sqrt(np.finfo(float).eps)), axis=1)
                 | np.any(~is_real & (poles.imag == 0), axis=1))
        if np.any(wrong):
            row = int(np.flatnonzero(wrong)[0])
            raise ValueError(
                f"{self!r} expects {r} real pole(s) and {self.pairs} complex pair(s); the model "
                f"(row {row}) has {n_real[row]} real and {(n - n_real[row]) // 2} complex pair(s): "
                f"poles {np.round(poles[row], 6)}"
            )
        # Canonical order: real poles slowest first, then upper poles of pairs by omega;
        # lower (conjugate) poles last, unused.
        group = np.where(is_real, 0, np.where(poles.imag > 0, 1, 2))
        key = np.where(is_real, -poles.real, np.abs(poles.imag))
        order = np.lexsort((-poles.real, key, group), axis=-1)
        poles = np.take_along_axis(poles, order, 1)
        res = np.take_along_axis(res, order, 1)
        lam, cr = poles[:, :r].real, res[:, :r].real
        p, rho = poles[:, r : r + self.pairs], res[:, r : r + self.pairs]
        delta, omega = p.real, np.abs(p.imag)
        # Pair: rho/(s-p) + conj = (beta1 s + beta0) / ((s-delta)^2 + omega^2) with
        # beta1 = 2 Re rho, beta0 = -2 Re(rho conj(p)); our block gives
        # (c_b s + c_a omega - c_b delta) / (...): c_b = beta1, c_a = (beta0 + beta1 delta) / omega.
        beta1, beta0 = 2 * rho.real, -2 * (rho * np.conj(p)).real
        cb, ca = beta1, (beta0 + beta1 * delta) / omega
        x = np.empty((B, self.q))
        j = np.arange(self.pairs)
        x[:, :r], x[:, n : n + r] = lam, cr
        x[:, r + 2 * j], x[:, r + 2 * j + 1] = delta, omega
        x[:, n + r + 2 * j], x[:, n + r + 2 * j + 1] = ca, cb
        if self.feedthrough:
            x[:, -1] = d
        return x

    def _align(self, x: torch.Tensor, atol: torch.Tensor) -> torch.Tensor:
        # Among the orderings of the real modes and of the pairs, take per row the first (in
        # canonical-first order) whose elements match the fixed values.
        r, n = self.real, self.n
        if not self._fixed or math.factorial(r) * math.factorial(self.pairs) > _MAX_PERMUTATIONS:
            return x
        modes_r = [[i, n + i] for i in range(r)]
        modes_p = [[r + 2 * j, r + 2 * j + 1, n + r + 2 * j, n + r + 2 * j + 1]
                   for j in range(self.pairs)]
        names = list(self._maps)
        idx = [names.index(k) for k in self._fixed]
        vals = x.new_tensor(list(self._fixed.values()))
        out, found = x.clone(), torch.zeros(x.shape[0], dtype=torch.bool, device=x.device)
        for pr in itertools.permutations(range(r)):
            for pp in itertools.permutations(range(self.pairs)):
                perm = list(range(self.q))
                for slot, mode in [*zip(modes_r, (modes_r[k] for k in pr), strict=True),
                                   *zip(modes_p, (modes_p[k] for k in pp), strict=True)]:
                    for a, b in zip(slot, mode, strict=True):
                        perm[a] = b
                xp = x[:, perm]
                ok = ((xp[:, idx] - vals).abs() <= atol[:, None]).all(1)
                take = ok & ~found
                out[take] = xp[take]
                found |= ok
        return out
