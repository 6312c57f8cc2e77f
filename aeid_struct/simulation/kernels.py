r"""The decoder's kernels (paper Eq. 10-13): no checks; torch with one common batch size, and one
numpy kernel for a single system.

For use inside training loops and by the public functions of :mod:`aeid_struct.simulation`, which
check their arguments first. Every torch kernel takes ``A (batch, n, n)``, ``b, c (batch, n)``,
``d (batch,)``, ``u (batch, steps)``, ``x0 (batch, n)`` or None (zero), all of one dtype, and
returns what the arithmetic gives (the overflow rule is the public functions').

The state is carried as ``x`` itself, Eq. 11 rearranged so that each step takes the input at both
of its ends (``E = gamma1 - gamma2``)::

    x_{k+1} = Phi x_k + E u_k + gamma2 u_{k+1}

(``cont2discrete(method="foh")`` works in the shifted state ``xi_k = x_k - gamma2 u_k``, which
loses all digits for an unstable pole with large ``p dt``: from rest ``xi_0 = -gamma2 u_0`` is
carried as ``Phi^k xi_0`` and cancelled by a term as large inside the input's kernel.)

:func:`simulate_batch` cuts the record into ``L`` chunks of ``K ~ sqrt(steps)`` samples. Inside a
chunk that starts at ``l K`` with state ``s_l = x_{lK}``,
``y_{lK+i} = c^T Phi^i s_l + sum_{j <= i} T_{ij} u_{lK+j}``, with ``T`` the Toeplitz matrix of
``tk = (d + c^T gamma2, h_0, h_1, ..)``, ``h_m = c^T Phi^m Bd``, ``Bd = E + Phi gamma2``, except its
first column ``t0 = (d, c^T E, c^T Phi E, ..)`` (``s_l`` already holds ``gamma2 u_{lK}``): one
batched matmul for every chunk at once. The chunk states follow
``s_{l+1} = Phi^K s_l + Phi^{K-1} E u_{lK} + sum_{j=1}^{K-1} Phi^{K-1-j} Bd u_{lK+j}
+ gamma2 u_{(l+1)K}``, a recursion of length ``L`` solved by :func:`scan` in ``log2 L`` levels.
Every coefficient is one power of ``Phi`` applied to one of ``E, Bd, gamma2``, so each sample keeps
its own relative accuracy at any ``|p| dt`` (tests/test_decoder.py checks it against the per-step
recursion :func:`simulate_loop`).

:func:`simulate_outputs` is the same convolution form over the whole record in numpy float64, for
one system with several outputs: callers that simulate one record many times (the classical
baselines' least squares) would spend most of their time in torch's per-call overhead.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from aeid_struct.simulation.numpy_foh import discrete_foh, free_basis, simulate_outputs

__all__ = [
    "chunk_length",
    "discrete_foh",
    "discretise_batch",
    "foh_columns",
    "free_basis",
    "powers",
    "scan",
    "simulate_batch",
    "simulate_loop",
    "simulate_outputs",
    "states_batch",
    "states_loop",
]


def discretise_batch(A: torch.Tensor, b: torch.Tensor, dt: float):
    """Eq. 10 by one matrix exponential, unchecked.

    ``expm([[A dt, b dt, 0], [0, 0, 1], [0, 0, 0]])``
    ``= [[Phi, gamma1, gamma2], [0, 1, 1], [0, 0, 1]]``.

    Parameters
    ----------
    A : (batch, n, n) tensor
    b : (batch, n) tensor
    dt : float, > 0

    Returns
    -------
    Phi : (batch, n, n) tensor
        ``e^{A dt}``.
    gamma1, gamma2 : (batch, n) tensors
        The input columns of ``u_k`` and of ``u_{k+1} - u_k`` (Eq. 11).
    """
    n = A.shape[-1]
    M = A.new_zeros(*A.shape[:-2], n + 2, n + 2)
    M[..., :n, :n] = A * dt
    M[..., :n, n] = b * dt
    M[..., n, n + 1] = 1.0
    E = torch.linalg.matrix_exp(M)
    return E[..., :n, :n], E[..., :n, n], E[..., :n, n + 1]


def scan(z: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    """Solve ``x_k = P x_{k-1} + z_k`` (``x_{-1} = 0``) along axis 1 by odd-even reduction.

    Paired by neighbours the recursion is one of the same form, half as long, with ``P^2``:
    ``x_{2i+1} = P^2 x_{2i-1} + (P z_{2i} + z_{2i+1})``; the even samples follow from
    ``x_{2i} = P x_{2i-1} + z_{2i}``. ``ceil(log2 L)`` levels, ``O(L)`` batched mat-vecs in all.

    Parameters
    ----------
    z : (batch, L, n) tensor
    P : (batch, n, n) tensor

    Returns
    -------
    x : (batch, L, n) tensor
    """
    L = z.shape[1]
    if L == 1:
        return z
    if L % 2:
        z = F.pad(z, (0, 0, 0, 1))  # a zero input at the end changes no earlier sample
    even, odd = z[:, 0::2], z[:, 1::2]
    PT = P.mT  # rows: (P x)^T = x^T P^T
    # Pairs (z_{2i}, z_{2i+1}) act on x_{2i-1} like one step of P^2 with input P z_{2i} + z_{2i+1}.
    x_odd = scan(odd + even @ PT, P @ P if even.shape[1] > 1 else P)
    # x_{2i} = P x_{2i-1} + z_{2i}, and x_0 = z_0.
    x_even = torch.cat([even[:, :1], even[:, 1:] + x_odd[:, :-1] @ PT], dim=1)
    return torch.stack([x_even, x_odd], dim=2).flatten(1, 2)[:, :L]


def states_batch(A, b, u, dt: float, x0=None) -> torch.Tensor:
    """Eq. 12 in log depth (:func:`scan`), unchecked.

    Parameters
    ----------
    A : (batch, n, n) tensor
    b : (batch, n) tensor
    u : (batch, steps) tensor
    dt : float, > 0
    x0 : (batch, n) tensor, optional
        Zero when None.

    Returns
    -------
    X : (batch, steps, n) tensor
        ``X[:, k] = x(k dt)``.
    """
    Phi, gamma1, gamma2 = discretise_batch(A, b, dt)
    # z_k = gamma1 u_{k-1} + gamma2 Du_{k-1} for k >= 1, the input's contribution to x_k.
    w = gamma1[:, None, :] * u[:, :-1, None] + gamma2[:, None, :] * torch.diff(u, dim=1)[..., None]
    first = w.new_zeros(w.shape[0], 1, w.shape[2]) if x0 is None else x0[:, None, :]
    return scan(torch.cat([first, w], dim=1), Phi)


def foh_columns(Phi, gamma1, gamma2):
    """The input columns of ``x_{k+1} = Phi x_k + E u_k + gamma2 u_{k+1}`` (Eq. 11 rearranged).

    Neither grows through cancellation: ``E = int_0^dt e^{A(dt-s)} (1 - s/dt) ds b`` loses at most
    a factor ``|p| dt`` to it (a fast stable pole), and ``Bd`` adds two terms of one sign for a
    real unstable pole.

    Parameters
    ----------
    Phi : (batch, n, n) tensor
    gamma1, gamma2 : (batch, n) tensors
        From :func:`discretise_batch`.

    Returns
    -------
    E : (batch, n) tensor
        ``gamma1 - gamma2``, the column of ``u_k``.
    Bd : (batch, n) tensor
        ``E + Phi gamma2``, the column of ``u_k`` once both ends of its steps lie in one chunk.
    """
    E = gamma1 - gamma2
    return E, E + (Phi @ gamma2[..., None])[..., 0]


def powers(v: torch.Tensor, P: torch.Tensor, count: int):
    """Rows ``v^T P^i`` for ``i < count`` by doubling, and ``P^(2^ceil(log2 count))``.

    ``[v^T P^0 .. v^T P^(2m-1)] = [[v^T P^0 .. v^T P^(m-1)], [v^T P^0 .. v^T P^(m-1)] P^m]``.

    Parameters
    ----------
    v : (batch, n) or (batch, r, n) tensor
        One row, or ``r`` rows at once.
    P : (batch, n, n) tensor
    count : int, >= 1

    Returns
    -------
    rows : (batch, count, n) or (batch, count, r, n) tensor
    P_last : (batch, n, n) tensor
        ``P`` raised to the first power of two ``>= count``.
    """
    rows = v if v.ndim == 3 else v[:, None, :]
    r = rows.shape[1]
    while rows.shape[1] < count * r:
        rows = torch.cat([rows, rows @ P], dim=1)
        P = P @ P
    rows = rows[:, : count * r]
    return (rows if v.ndim == 2 else rows.unflatten(1, (count, r))), P


def chunk_length(steps: int) -> int:
    """The chunk length ``K ~ sqrt(steps)`` of :func:`simulate_batch`, a power of two <= 32.

    It balances the ``O(steps K)`` Toeplitz matmul against the scan over ``steps / K`` chunks
    (``aeid-struct bench`` measures the kernels).

    Parameters
    ----------
    steps : int, >= 1

    Returns
    -------
    int
    """
    return 1 << min(5, max(0, round(math.log2(steps) / 2)))


def simulate_batch(A, b, c, d, u, dt: float, x0=None) -> torch.Tensor:
    """The decoder, Eq. 10-13, unchecked: chunks of a Toeplitz matmul, a log-depth scan across.

    What training calls (no validation, no overflow rule); the derivation is in the module
    docstring. Differentiable with respect to every tensor argument.

    Parameters
    ----------
    A : (batch, n, n) tensor
    b, c : (batch, n) tensors
    d : (batch,) tensor
    u : (batch, steps) tensor
        Input samples at ``t_k = k dt``, linear in between.
    dt : float, > 0
    x0 : (batch, n) tensor, optional
        Zero when None.

    Returns
    -------
    y : (batch, steps) tensor
    """
    Phi, gamma1, gamma2 = discretise_batch(A, b, dt)
    E, Bd = foh_columns(Phi, gamma1, gamma2)
    batch, steps = u.shape
    K = chunk_length(steps)
    L = -(-steps // K)
    O, PK = powers(c, Phi, K)  # O[:, i] = c^T Phi^i; PK = Phi^K (K is a power of two)
    BE = torch.stack([Bd, E], dim=-1)  # (batch, n, 2)
    V, _ = powers(BE.mT, Phi.mT, K)  # V[:, m] = (Phi^m Bd, Phi^m E)^T: (batch, K, 2, n)
    # Chunk matrix T[i, j] (i, j < K), the weight of u_{lK+j} in y_{lK+i}: Toeplitz tk[i - j]
    # with tk = (d + c^T gamma2, h_0, .., h_{K-2}), h_m = c^T Phi^m Bd, except the first column
    # t0 = (d, c^T E, c^T Phi E, .., c^T Phi^{K-2} E): the chunk's start state holds gamma2 u_{lK}.
    H = O[:, : K - 1] @ BE  # (batch, K - 1, 2): (h_m, c^T Phi^m E)
    Dd = d + (c * gamma2).sum(-1)
    # coef = (tk_0, t0_0, tk_1, t0_1, .., 0): T is one gather from it, zeros above the diagonal
    # (a gather, not an index with a mask: its backward is a scatter, the fastest on CPU).
    coef = torch.cat([Dd[:, None], d[:, None], H.flatten(1), torch.zeros_like(d)[:, None]], dim=1)
    index = torch.arange(K, device=u.device)
    lag = index[:, None] - index[None, :]
    at = torch.where(index[None, :] == 0, 2 * index[:, None] + 1, 2 * lag)
    at = torch.where(lag < 0, 2 * K, at)
    T = coef.gather(1, at.flatten().expand(batch, -1)).view(batch, K, K)  # lower triangular
    # Zeros appended to u change no earlier output (causality); they are cut off at the end.
    uc = F.pad(u, (0, L * K - steps)).view(batch, L, K)
    # Chunk-start states s_0 = x_0, s_{l+1} = Phi^K s_l + Phi^{K-1} E u_{lK}
    #   + sum_{j=1}^{K-1} Phi^{K-1-j} Bd u_{lK+j} + gamma2 u_{(l+1)K}.
    W = torch.cat([V[:, K - 1 :, 1], V[:, : K - 1, 0].flip(1)], dim=1)  # (batch, K, n)
    e = uc[:, :-1] @ W + uc[:, 1:, :1] * gamma2[:, None, :]  # (batch, L - 1, n)
    first = u.new_zeros(batch, 1, A.shape[-1]) if x0 is None else x0[:, None, :]
    S = scan(torch.cat([first, e], dim=1), PK)
    y = uc @ T.mT + S @ O.mT  # (batch, L, K): forced part within the chunk + c^T Phi^i s_l
    return y.reshape(batch, L * K)[:, :steps]


def states_loop(A, b, u, dt: float, x0=None) -> torch.Tensor:
    """Eq. 12 as a plain per-step loop: the reference recursion and the overflow rule's.

    Its powers of ``Phi`` never exceed one step, so where a state overflows it is because the
    state itself does (the log-depth kernels can overflow in ``Phi^K`` first).

    Parameters
    ----------
    A : (batch, n, n) tensor
    b : (batch, n) tensor
    u : (batch, steps) tensor
    dt : float, > 0
    x0 : (batch, n) tensor, optional
        Zero when None.

    Returns
    -------
    X : (batch, steps, n) tensor
    """
    Phi, gamma1, gamma2 = discretise_batch(A, b, dt)
    x = gamma1.new_zeros(gamma1.shape) if x0 is None else x0
    du = torch.diff(u, dim=1)
    xs = [x]
    for k in range(u.shape[1] - 1):
        x = (Phi @ x[:, :, None])[..., 0] + gamma1 * u[:, k, None] + gamma2 * du[:, k, None]
        xs.append(x)
    return torch.stack(xs, dim=1)


def simulate_loop(A, b, c, d, u, dt: float, x0=None) -> torch.Tensor:
    """Eq. 12-13 as a plain per-step loop (:func:`states_loop`); shapes as in
    :func:`simulate_batch`.

    Parameters
    ----------
    A : (batch, n, n) tensor
    b, c : (batch, n) tensors
    d : (batch,) tensor
    u : (batch, steps) tensor
    dt : float, > 0
    x0 : (batch, n) tensor, optional
        Zero when None.

    Returns
    -------
    y : (batch, steps) tensor
    """
    X = states_loop(A, b, u, dt, x0)
    return (X @ c[:, :, None])[..., 0] + d[:, None] * u
