r"""The several-channel model and its projection: the observer canonical form with one output
as reference, and the parameters that enter linearly solved for exactly.

The model of experiment ``r`` (time in units of ``h`` per sample; ``multi.fit``):

    x' = A x + B u,   y_k = C x_k + D u_k + o_r,   x(first sample) = x_{0,r},

    A = [[-a_{n-1}, 1, 0, ..], [-a_{n-2}, 0, 1, ..], .., [-a_0, 0, .., 0]],   C[ref] = e_1^T,

the observer canonical form of ``det(sI - A) = s^n + a_{n-1} s^{n-1} + .. + a_0`` seen from the
reference output. Why this form: with ``A`` and ``C`` given, the output is linear in ``B, D``
and every ``x_{0,r}, o_r`` (Eq. 10-13 are linear in the input and the state), so only
``theta = (a, C without its reference row)``, ``n p`` numbers, is iterated (variable
projection) and ``B (n, m)`` joins the linear part. The dual choice (``B`` fixed in controllable
form, ``C`` linear) would make the free response ``C e^{A t} x_0`` bilinear. Every state-space
model whose ``A`` is cyclic and which is observable from the reference output has this form
(the reference is the output that sees every mode best: ``multi.start``).

Regressors by the convolution form of Eq. 10-13 (``simulation.free_basis``): the response of
output ``i`` to input ``j`` through state direction ``e_l`` is the input convolved with the
Markov parameters ``C_i Phi^k Bd e_l`` (``Bd = E + Phi Gamma_2``, ``E = Gamma_1 - Gamma_2``, and
``C_i Gamma_2 e_l`` at lag 0; ``C_i Phi^k E e_l`` for the first sample), by FFT (the sums are
formed once per parameter point, so FFT's error, relative to the largest term, is far below the
noise; ``simulation.simulate_outputs`` keeps each sample's relative accuracy for one response,
but at ``p n m`` direct convolutions per point).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.signal

from aeid_struct.simulation import discrete_inputs, free_basis

__all__ = ["Factor", "Layout", "Projection", "factor", "markov", "observer_form", "outputs",
           "project", "responses", "through_state"]


def observer_form(a: np.ndarray) -> np.ndarray:
    """``A`` of the observer canonical form of ``s^n + a_{n-1} s^{n-1} + .. + a_0``.

    Parameters
    ----------
    a : (n,) array
        ``a_0 .. a_{n-1}``.

    Returns
    -------
    (n, n) array
    """
    n = len(a)
    A = np.eye(n, k=1)
    A[:, 0] = -np.asarray(a)[::-1]
    return A


@dataclass(frozen=True)
class Layout:
    """Where the iterated parameters ``theta`` sit: ``a (n,)``, then the rows of ``C`` other
    than the reference one, ``(p - 1) n``.

    Attributes
    ----------
    n : int
        Order.
    p : int
        Outputs.
    m : int
        Inputs.
    reference : int
        The output whose row of ``C`` is ``e_1``.
    """

    n: int
    p: int
    m: int
    reference: int

    @property
    def size(self) -> int:
        """Entries of ``theta``."""
        return self.n * self.p

    def model(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``A (n, n), C (p, n)`` of ``theta``.

        Parameters
        ----------
        theta : (n p,) array

        Returns
        -------
        A : (n, n) array
        C : (p, n) array
        """
        n = self.n
        rest = np.asarray(theta[n:]).reshape(self.p - 1, n)
        C = np.insert(rest, self.reference, np.eye(n)[0], axis=0)
        return observer_form(theta[:n]), C

    def theta(self, a: np.ndarray, C: np.ndarray) -> np.ndarray:
        """``theta`` of ``a`` and a ``C`` whose reference row is ``e_1``.

        Parameters
        ----------
        a : (n,) array
            ``a_0 .. a_{n-1}``.
        C : (p, n) array

        Returns
        -------
        (n p,) array
        """
        return np.concatenate([a, np.delete(C, self.reference, axis=0).ravel()])


def responses(A: np.ndarray, C: np.ndarray, U: np.ndarray, h: float, hold: str):
    """Regressors of one record: the outputs' responses to every input through every state
    direction, from rest, and the free response's basis (module docstring).

    Parameters
    ----------
    A : (n, n) array
    C : (r, n) array
    U : (steps, m) array
        Inputs on the record's samples (delays applied).
    h : float, > 0
        The sample time in the model's time unit.
    hold : {"foh", "zoh"}

    Returns
    -------
    R : (steps, r, n, m) array
        ``y_i(k) = sum_{l, j} R[k, i, l, j] B[l, j]`` from rest.
    O : (steps, r, n) array
        ``C Phi^k``.
    """
    steps = U.shape[0]
    tk, t0, O = _kernels(A, C, steps, h, hold)
    later = U.copy()
    later[0] = 0.0                               # u_0 enters through t0
    R = t0[..., None] * U[0]
    R += scipy.signal.fftconvolve(tk[..., None], later[:, None, None, :], axes=0)[:steps]
    return R, O


def _kernels(A: np.ndarray, C: np.ndarray, steps: int, h: float, hold: str):
    """:func:`responses`' Markov parameters: ``tk (steps, r, n)`` (``C Gamma_2`` at lag 0,
    ``C Phi^(k-1) Bd`` after), ``t0 (steps, r, n)`` (``C Phi^(k-1) E``, the first sample's own
    term) and ``O = C Phi^k (steps, r, n)``."""
    n = A.shape[0]
    Phi, G1, G2 = discrete_inputs(A, np.eye(n), h, hold)
    E = G1 - G2
    O = free_basis(Phi, C, steps)                                       # (steps, r, n)
    tk = np.empty((steps,) + C.shape)
    tk[0] = C @ G2
    tk[1:] = O[:-1] @ (E + Phi @ G2)
    t0 = np.zeros((steps,) + C.shape)
    t0[1:] = O[:-1] @ E
    return tk, t0, O


def markov(A: np.ndarray, C: np.ndarray, parts, h: float, holds) -> tuple:
    """Per record the Markov parameters of :func:`responses` (``tk, t0, O``, each
    ``(steps, p, n)``; the exact first-order-hold or held-input discretisation, Eq. 10-13),
    which :func:`outputs` and :func:`transposed` read: one matrix exponential and one set of
    powers per parameter point for both.

    Parameters
    ----------
    A : (n, n) array
    C : (p, n) array
    parts, h, holds
        As :func:`project`.

    Returns
    -------
    tuple of R ``(tk, t0, O)``
    """
    return tuple(_kernels(A, C, Y.shape[0], h, hold)
                 for (Y, _), hold in zip(parts, holds, strict=True))


@dataclass(frozen=True)
class Projection:
    """The linear parameters of one parameter point and what they leave.

    Attributes
    ----------
    B : (n, m) array
    D : (p, m) array
        Zero without a feedthrough.
    x0 : tuple of R (n,) arrays
        The state at each record's first fitted sample.
    offset : tuple of R (p,) arrays
    residual : (rows,) array
        Stacked over records, samples and outputs.
    y_hat : tuple of R (steps_r, p) arrays
    """

    B: np.ndarray
    D: np.ndarray
    x0: tuple
    offset: tuple
    residual: np.ndarray
    y_hat: tuple

    @property
    def cost(self) -> float:
        """Mean squared residual."""
        return float(np.mean(self.residual ** 2))


def project(A, C, parts, h: float, holds, feedthrough: bool = True, B=None, D=None) -> Projection:
    """Solve for ``B, D`` (unless given) and each record's ``x0`` and offset by least squares.

    Parameters
    ----------
    A : (n, n) array
    C : (p, n) array
    parts : list of R (Y (steps, p), U (steps, m)) pairs
        Aligned records (``Experiments.aligned``).
    h : float
    holds : sequence of R str
    feedthrough : bool
    B, D : arrays, optional
        A model's own (only the initial states and offsets are fitted: a comparison).

    Returns
    -------
    Projection
    """
    n, p, m = A.shape[0], C.shape[0], parts[0][1].shape[1]
    fixed = B is not None
    shared = 0 if fixed else n * m + (p * m if feedthrough else 0)
    X, target, known = _design(A, C, parts, h, holds, feedthrough, B, D)
    scale = np.sqrt(np.sum(X ** 2, axis=0))
    scale[scale == 0] = 1.0
    beta = scipy.linalg.lstsq(X / scale, target, lapack_driver="gelsy",
                              check_finite=False)[0] / scale
    fitted = X @ beta
    residual = target - fitted
    if fixed:
        B, D = np.asarray(B, dtype=np.float64), np.asarray(D, dtype=np.float64)
    else:
        B = beta[: n * m].reshape(n, m)
        D = beta[n * m: shared].reshape(p, m) if feedthrough else np.zeros((p, m))
    x0, offset, y_hat, at = [], [], [], 0
    for r, (Y, _) in enumerate(parts):
        base = shared + r * (n + p)
        x0.append(beta[base: base + n])
        offset.append(beta[base + n: base + n + p])
        rows = Y.size
        y_hat.append((fitted[at: at + rows] + known[r].reshape(-1)).reshape(Y.shape))
        at += rows
    return Projection(B, D, tuple(x0), tuple(offset), residual, tuple(y_hat))


def _design(A, C, parts, h: float, holds, feedthrough: bool, B=None, D=None):
    """:func:`project`'s least squares: the design ``X`` (columns ``B`` (n m, unless given),
    ``D`` (p m, with a feedthrough and unless given), then per record ``x0`` (n) and offset
    (p)), the target (rows: records, samples, outputs) and per record the given ``B, D``'s
    part of the output ``(steps, p)``."""
    n, p, m = A.shape[0], C.shape[0], parts[0][1].shape[1]
    fixed = B is not None
    shared = 0 if fixed else n * m + (p * m if feedthrough else 0)
    width = shared + len(parts) * (n + p)
    blocks, targets, known = [], [], []
    for r, ((Y, U), hold) in enumerate(zip(parts, holds, strict=True)):
        Rg, O = responses(A, C, U, h, hold)
        steps = Y.shape[0]
        X = np.zeros((steps, p, width))
        if fixed:
            known.append(np.einsum("kilj,lj->ki", Rg, B) + U @ np.asarray(D).T)
        else:
            X[..., : n * m] = Rg.reshape(steps, p, n * m)
            if feedthrough:
                X[..., n * m: shared] = _feedthrough_columns(U, p)
            known.append(np.zeros((steps, p)))
        base = shared + r * (n + p)
        X[..., base: base + n] = O
        X[..., base + n: base + n + p] = np.eye(p)
        blocks.append(X.reshape(steps * p, width))
        targets.append(Y.reshape(-1))
    X = np.vstack(blocks)
    target = np.concatenate(targets) - np.concatenate([k.reshape(-1) for k in known])
    return X, target, known


@dataclass(frozen=True)
class Factor:
    """A rank-revealing QR of :func:`project`'s design ``X`` (``B`` free), its columns scaled:
    ``X[:, perm] / scale[perm] = Q R`` on the first ``rank`` columns of ``perm``.

    Attributes
    ----------
    Q : (rows, rank) array
        An orthonormal basis of ``X``'s column space (rows as :class:`Projection`'s
        ``residual``).
    R : (rank, rank) array
    perm : (rank,) int array
    scale : (width,) array
    """

    Q: np.ndarray
    R: np.ndarray
    perm: np.ndarray
    scale: np.ndarray

    def pinv_transposed(self, g: np.ndarray) -> np.ndarray:
        """``(X^+)^T g`` for ``g (width, k)``: ``(rows, k)`` (the columns below the rank
        left out, as the projection's solver leaves them)."""
        picked = g[self.perm] / self.scale[self.perm, None]
        return self.Q @ scipy.linalg.solve_triangular(self.R, picked, trans="T")


def factor(A, C, parts, h: float, holds, feedthrough: bool = True) -> Factor:
    """The :class:`Factor` of :func:`project`'s design at ``A, C``.

    Parameters
    ----------
    A, C, parts, h, holds, feedthrough
        As :func:`project`.

    Returns
    -------
    Factor
    """
    X = _design(A, C, parts, h, holds, feedthrough)[0]
    scale = np.sqrt(np.sum(X ** 2, axis=0))
    scale[scale == 0] = 1.0
    Q, R, perm = scipy.linalg.qr(X / scale, mode="economic", pivoting=True, check_finite=False)
    d = np.abs(np.diag(R))
    # gelsy's rank rule (project's solver): columns below eps times the largest pivot add
    # nothing to the fit
    rank = int(np.sum(d > np.finfo(np.float64).eps * max(X.shape) * d[0])) if d.size else 0
    return Factor(Q[:, :rank], R[:rank, :rank], perm[:rank], scale)


def outputs(kernels: tuple, B, D, x0s, offsets, parts) -> np.ndarray:
    """The model's output on every record with all its linear parameters given (Eq. 10-13 in
    convolution form), stacked as :class:`Projection`'s ``residual`` is: ``(rows,)``.

    The forced part as :func:`responses`' sums with ``B`` applied first: the Markov
    parameters ``C Phi^k Bd B`` convolved with the ``m`` inputs, ``p m`` convolutions instead of
    the regressors' ``p n m``.

    Parameters
    ----------
    kernels : tuple
        :func:`markov` of the model's ``A, C``.
    B : (n, m) array
    D : (p, m) array
    x0s, offsets : sequences of R (n,) and (p,) arrays
    parts : list of R (Y, U) pairs
        As :func:`project`.

    Returns
    -------
    (rows,) array
    """
    out = []
    for (_, U), kernel, x0, offset in zip(parts, kernels, x0s, offsets, strict=True):
        out.append((through_state(kernel, B, U, x0) + U @ D.T + offset).reshape(-1))
    return np.concatenate(out)


def through_state(kernel: tuple, B, U: np.ndarray, x0) -> np.ndarray:
    """``C x`` on one record's samples, ``(steps, r)``: the state from ``x0`` driven by ``B u``
    (Eq. 10-13 in convolution form), without the feedthrough and the offset.

    Parameters
    ----------
    kernel : tuple
        One record's ``(tk, t0, O)`` of :func:`markov` of ``A, C``.
    B : (n, m) array
    U : (steps, m) array
    x0 : (n,) array

    Returns
    -------
    (steps, r) array
    """
    tk, t0, O = kernel
    later = U.copy()
    later[0] = 0.0
    forced = scipy.signal.fftconvolve(tk @ B, later[:, None, :], axes=0)[:U.shape[0]]
    return t0 @ (B @ U[0]) + forced.sum(axis=2) + O @ x0


def _feedthrough_columns(U: np.ndarray, p: int) -> np.ndarray:
    """``(steps, p, p m)``: output ``i``'s row holds ``u`` in the columns of ``D[i, :]``."""
    steps, m = U.shape
    out = np.zeros((steps, p, p, m))
    for i in range(p):
        out[:, i, i, :] = U
    return out.reshape(steps, p, p * m)
