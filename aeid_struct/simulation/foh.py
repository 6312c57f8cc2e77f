r"""The decoder: exact first-order-hold simulation of continuous-time SISO systems.

Paper Eq. 4 and 10-15. The encoder proposes a continuous-time model ``(A, b, c, d)``; the decoder
turns it into the response to the measured input on the record's time grid, differentiably and for
a whole batch at once.

Maths
-----
Time grid (DESIGN.md): a record has ``steps`` samples at ``t_k = k dt``; between samples the input
is linearly interpolated (first-order hold, FOH). On ``[t_k, t_k + dt]`` write ``s = (t - t_k)/dt``
and ``u = u_k + s Du_k`` with ``Du_k = u_{k+1} - u_k`` (Eq. 11). The augmented state
``z = (x, u, Du)`` obeys ``dz/ds = M z`` with (Eq. 10)::

        [A dt  b dt  0]                 [Phi  gamma1  gamma2]
    M = [ 0     0    1],     expm(M) =  [ 0     1       1   ],
        [ 0     0    0]                 [ 0     0       1   ]

so, exactly for piecewise-linear inputs,

    x_{k+1} = Phi x_k + gamma1 u_k + gamma2 Du_k                                  (Eq. 10-12)
    y_k     = c^T x_k + d u_k                                                     (Eq. 13)

with ``Phi = e^{A dt}``, ``gamma1 = int_0^dt e^{A s} ds b`` and
``gamma2 = (1/dt) int_0^dt e^{A (dt - s)} s ds b``. ``x_0`` is zero unless ``x0`` is given.

The recursion in log depth
--------------------------
A per-step Python loop costs ``steps`` sequential kernel launches forward and again backward
(``_simulate_loop``, kept as the benchmark's reference and for the overflow rule below). Three
exact formulations of depth ``O(log steps)`` are implemented. They work in the state ``x`` itself,
with Eq. 11 rearranged so that each step takes the input at both of its ends::

    x_{k+1} = Phi x_k + E u_k + gamma2 u_{k+1},   E = gamma1 - gamma2,
    y_k     = c^T Phi^k x_0 + t0_k u_0 + sum_{m=1}^{k} tk_{k-m} u_m,
    tk      = (d + c^T gamma2, h_0, h_1, ..),   h_m = c^T Phi^m Bd,   Bd = E + Phi gamma2,
    t0      = (d, c^T E, c^T Phi E, ..).

(``Phi, Bd, c, d + c^T gamma2`` is ``cont2discrete(method="foh")``, whose state is the shifted
``xi_k = x_k - gamma2 u_k``.) Why not propagate ``xi``: from rest ``xi_0 = -gamma2 u_0`` is
carried as ``Phi^k xi_0`` and cancelled by the same term inside ``h``; for an unstable pole ``p``
each output is then a difference of terms ``~ e^{p dt} / (p dt)`` times larger than itself, and
lost that many digits (float64: 3e-5 relative at ``p dt = 30``, all of them at 40). Here every
coefficient is one power of ``Phi`` applied to one of the integrals ``E, Bd, gamma2``, with no
cancellation beyond that of the response itself: each sample keeps its own relative accuracy at
any ``|p| dt``.

* **Chunked** (``_simulate_chunked``, the default of ``simulate``): cut the record into ``L`` chunks
  of ``K ~ sqrt(steps)`` samples (``K`` a power of two, at most 32). Inside a chunk starting at
  ``l K`` with state ``s_l = x_{lK}``, ``y_{lK+i} = c^T Phi^i s_l + sum_{j <= i} T_{ij} u_{lK+j}``
  with ``T_{ij} = tk_{i-j}`` except the first column, ``T_{i0} = t0_i`` (``s_l`` already holds
  ``gamma2 u_{lK}``): one batched ``(L, K) x (K, K)`` matmul for every chunk at once. The chunk
  states follow ``s_{l+1} = Phi^K s_l + Phi^{K-1} E u_{lK} + sum_{j=1}^{K-1} Phi^{K-1-j} Bd
  u_{lK+j} + gamma2 u_{(l+1)K}``: a recursion of length ``L`` solved by the scan below.
  ``c^T Phi^i`` and ``Phi^i (Bd, E)`` (``i < K``) come from ``log2 K`` doublings.
* **Odd-even reduction** (``_scan``; ``_simulate_scan``, and ``states``): the recursion
  ``x_k = Phi x_{k-1} + z_k`` (``z_0 = x_0``, ``z_k = gamma1 u_{k-1} + gamma2 Du_{k-1}``) paired by
  neighbours is a recursion of the same form, half as long, with ``Phi^2``::

      x_{2i+1} = Phi^2 x_{2i-1} + (Phi z_{2i} + z_{2i+1})      -> recurse on the odd samples
      x_{2i}   = Phi x_{2i-1} + z_{2i}                          -> fill in the even ones

  ``log2(steps)`` levels, ``O(steps)`` batched mat-vecs in all (a work-efficient, Blelloch-type
  scan specialised to a time-invariant ``Phi``).
* **Markov parameters + FFT** (``_simulate_fft``): ``c^T Phi^k`` for all ``k < steps`` by doubling,
  then the convolution of ``tk`` with ``u`` as one zero-padded real FFT.

Why chunked: measured forward + backward (``aeid_struct.bench.bench_decoder``; numbers in
``_simulate``) it is the fastest: on par with the FFT at 100 samples and 2-3x faster than the FFT
and the scan at 300-1000 (the big Toeplitz matmul replaces most of the scan's small ones), and
2-11x faster than the loop. Accuracy decided against the FFT: its rounding error is spread evenly
at ``eps max|y|`` over the record, which wipes out the early, small part of an unstable response
(float32, pole +12 rad/s over 2 s: per-sample relative error 5e5), whereas the chunked form, the
scan and the loop all keep each sample's own relative accuracy (~1e-5 in float32, ~1e-13 in
float64 there). Relative to ``max|y|``, the measure of the normalised loss (Eq. 15), all reach
~1e-14 in float64 on well-conditioned stable and unstable systems. Per sample, the chunked form
agrees with the per-step loop to ~1e-12 relative for real, oscillatory, stable and unstable poles
up to ``|p| dt = 40`` (tests/test_decoder.py); no choice of kernel by the size of the system is
needed.

Overflow: a response that leaves the floating range (an unstable system over a long record) is
returned as +inf from its first overflowing sample on, with a ``RuntimeWarning``; never NaN (see
``simulate``). Only the public functions apply this rule; the private cores return whatever the
arithmetic gives.

Choices
-------
* numpy in -> numpy float64 out; any torch tensor in -> torch out in the promoted floating dtype of
  the torch inputs (float64 when none is floating), differentiable. Half precision is refused:
  ``matrix_exp`` and the scan need at least float32.
* Shapes are batch first: ``A (batch, n, n)``, ``b, c, x0 (batch, n)``, ``d (batch,)``,
  ``u (batch, steps)``; each may drop its batch axis (one system, or one input signal, shared by the
  batch) or have batch 1; the result drops the batch axis only when every input did.
* Public functions validate (shapes, finiteness, ``dt``) and raise ``ValueError`` naming the
  argument, the expectation and what came. The private cores (``_discretise``, ``_states``,
  ``_simulate``, ``_stationary_value``, ``_record_scale``, ``_loss``) skip all checks, for use
  inside training loops; they expect torch tensors of one dtype with one common batch size.
* Normalisation (Eq. 15) and the loss (Eq. 14) follow the paper: ``y_tilde = 2 y / y_bar - 1``
  with ``y_bar = max|y|`` of the measured record, the same ``y_bar`` applied to the decoded output
  and the stationary values;
  ``J = (sum_i (y_i - yhat_i)^2 + gamma (y_inf - yhat_inf)^2) / (m + 1)``.
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.fft
import torch
import torch.nn.functional as F

__all__ = [
    "Discrete",
    "denormalise",
    "discretise",
    "initial_state",
    "loss",
    "normalise",
    "record_scale",
    "simulate",
    "states",
    "stationary_value",
]

Array = np.ndarray | torch.Tensor


@dataclass(frozen=True)
class Discrete:
    """The FOH-discretised system of Eq. 10: ``x_{k+1} = Phi x_k + gamma1 u_k + gamma2 Du_k``.

    Attributes
    ----------
    Phi : (batch, n, n) or (n, n)
        ``e^{A dt}``.
    gamma1 : (batch, n) or (n,)
        Input column for ``u_k``: ``int_0^dt e^{A s} ds b``.
    gamma2 : (batch, n) or (n,)
        Input column for ``Du_k = u_{k+1} - u_k`` (Eq. 11): ``(1/dt) int_0^dt e^{A(dt-s)} s ds b``.
    dt : float
        The sample time.
    """

    Phi: Array
    gamma1: Array
    gamma2: Array
    dt: float


# ----------------------------------------------------------------------------------------------
# Private cores: torch only, no checks, one common batch size (see the module docstring).
# ----------------------------------------------------------------------------------------------


def _discretise(A: torch.Tensor, b: torch.Tensor, dt: float):
    """Eq. 10 for ``A (batch, n, n)``, ``b (batch, n)``: returns ``Phi, gamma1, gamma2``."""
    n = A.shape[-1]
    M = A.new_zeros(*A.shape[:-2], n + 2, n + 2)
    M[..., :n, :n] = A * dt
    M[..., :n, n] = b * dt
    M[..., n, n + 1] = 1.0
    E = torch.linalg.matrix_exp(M)
    return E[..., :n, :n], E[..., :n, n], E[..., :n, n + 1]


def _scan(z: torch.Tensor, P: torch.Tensor) -> torch.Tensor:
    """Solve ``x_k = P x_{k-1} + z_k`` (``x_{-1} = 0``) along axis 1 by odd-even reduction.

    ``z (batch, L, n)``, ``P (batch, n, n)`` -> ``x (batch, L, n)``, in ``ceil(log2 L)`` levels.
    """
    L = z.shape[1]
    if L == 1:
        return z
    if L % 2:
        z = F.pad(z, (0, 0, 0, 1))  # a zero input at the end changes no earlier sample
    even, odd = z[:, 0::2], z[:, 1::2]
    PT = P.mT  # rows: (P x)^T = x^T P^T
    # Pairs (z_{2i}, z_{2i+1}) act on x_{2i-1} like one step of P^2 with input P z_{2i} + z_{2i+1}.
    x_odd = _scan(odd + even @ PT, P @ P if even.shape[1] > 1 else P)
    # x_{2i} = P x_{2i-1} + z_{2i}, and x_0 = z_0.
    x_even = torch.cat([even[:, :1], even[:, 1:] + x_odd[:, :-1] @ PT], dim=1)
    return torch.stack([x_even, x_odd], dim=2).flatten(1, 2)[:, :L]


def _states(A, b, u, dt: float, x0=None) -> torch.Tensor:
    """Eq. 12 in log depth: ``X (batch, steps, n)`` with ``X[:, k] = x(k dt)``.

    ``A (batch, n, n)``, ``b (batch, n)``, ``u (batch, steps)``, ``x0 (batch, n)`` or None (zero).
    """
    Phi, gamma1, gamma2 = _discretise(A, b, dt)
    # z_k = gamma1 u_{k-1} + gamma2 Du_{k-1} for k >= 1, the input's contribution to x_k.
    w = gamma1[:, None, :] * u[:, :-1, None] + gamma2[:, None, :] * torch.diff(u, dim=1)[..., None]
    first = w.new_zeros(w.shape[0], 1, w.shape[2]) if x0 is None else x0[:, None, :]
    return _scan(torch.cat([first, w], dim=1), Phi)


def _simulate_scan(A, b, c, d, u, dt: float, x0=None) -> torch.Tensor:
    """Eq. 13 on the states of ``_states``: ``y (batch, steps)``."""
    X = _states(A, b, u, dt, x0)
    return (X @ c[:, :, None])[..., 0] + d[:, None] * u


def _foh_columns(Phi, gamma1, gamma2):
    """The input columns of Eq. 11 written as ``x_{k+1} = Phi x_k + E u_k + gamma2 u_{k+1}``:
    ``E = gamma1 - gamma2 (batch, n)`` and ``Bd = E + Phi gamma2 (batch, n)``, the column of
    ``u_k`` once both ends of its steps lie in one chunk (module docstring). Neither grows
    through cancellation: ``E = int_0^dt e^{A(dt-s)} (1 - s/dt) ds b`` loses at most a factor
    ``|p| dt`` to it (a fast stable pole), and ``Bd`` adds two terms of one sign for a real
    unstable pole."""
    E = gamma1 - gamma2
    return E, E + (Phi @ gamma2[..., None])[..., 0]


def _powers(v: torch.Tensor, P: torch.Tensor, count: int):
    """Rows ``v^T P^i`` for ``i < count`` by doubling, and ``P^(2^ceil(log2 count))``.

    ``v (batch, n)`` -> ``(batch, count, n)``, or ``r`` vectors at once, ``v (batch, r, n)`` ->
    ``(batch, count, r, n)``; ``P (batch, n, n)`` -> ``(batch, n, n)``:
    ``[v^T P^0 .. v^T P^(2m-1)] = [[v^T P^0 .. v^T P^(m-1)], [v^T P^0 .. v^T P^(m-1)] P^m]``.
    """
    rows = v if v.ndim == 3 else v[:, None, :]
    r = rows.shape[1]
    while rows.shape[1] < count * r:
        rows = torch.cat([rows, rows @ P], dim=1)
        P = P @ P
    rows = rows[:, : count * r]
    return (rows if v.ndim == 2 else rows.unflatten(1, (count, r))), P


def _chunk_length(steps: int) -> int:
    """``K ~ sqrt(steps)``, a power of two <= 32: balances the O(steps K) Toeplitz matmul against
    the scan over ``steps / K`` chunks (measured best at 8-32 for 50-3000 samples)."""
    return 1 << min(5, max(0, round(math.log2(steps) / 2)))


def _simulate_chunked(A, b, c, d, u, dt: float, x0=None) -> torch.Tensor:
    """Eq. 13 by chunks: a Toeplitz matmul inside chunks, a log-depth scan across them.

    ``y (batch, steps)``; see the module docstring for the derivation.
    """
    Phi, gamma1, gamma2 = _discretise(A, b, dt)
    E, Bd = _foh_columns(Phi, gamma1, gamma2)
    batch, steps = u.shape
    K = _chunk_length(steps)
    L = -(-steps // K)
    O, PK = _powers(c, Phi, K)  # O[:, i] = c^T Phi^i; PK = Phi^K (K is a power of two)
    BE = torch.stack([Bd, E], dim=-1)  # (batch, n, 2)
    V, _ = _powers(BE.mT, Phi.mT, K)  # V[:, m] = (Phi^m Bd, Phi^m E)^T: (batch, K, 2, n)
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
    S = _scan(torch.cat([first, e], dim=1), PK)
    y = uc @ T.mT + S @ O.mT  # (batch, L, K): forced part within the chunk + c^T Phi^i s_l
    return y.reshape(batch, L * K)[:, :steps]


def _simulate_fft(A, b, c, d, u, dt: float, x0=None) -> torch.Tensor:
    """Eq. 13 by Markov parameters (doubling) and one causal FFT convolution: ``y (batch, steps)``.

    ``y_k = c^T Phi^k x_0 + g_k u_0 + sum_{m=1}^{k} tk_{k-m} u_m`` with ``tk`` and ``g = t0``
    as in the chunked form, here over the whole record (module docstring).
    """
    Phi, gamma1, gamma2 = _discretise(A, b, dt)
    E, Bd = _foh_columns(Phi, gamma1, gamma2)
    steps = u.shape[1]
    O, _ = _powers(c, Phi, steps)  # O[:, k] = c^T Phi^k
    start = Bd.new_zeros(Bd.shape) if x0 is None else x0
    H = O @ torch.stack([Bd, E, start], dim=-1)  # (batch, steps, 3)
    kernel = torch.cat([(d + (c * gamma2).sum(-1))[:, None], H[:, :-1, 0]], dim=1)
    first = torch.cat([d[:, None], H[:, :-1, 1]], dim=1)  # the weight of u_0 in y_k
    nfft = scipy.fft.next_fast_len(2 * steps - 1, real=True)  # no circular wrap-around
    later = F.pad(u[:, 1:], (1, 0))  # u_1, u_2, ..: u_0 enters through `first`
    y = torch.fft.irfft(torch.fft.rfft(kernel, nfft) * torch.fft.rfft(later, nfft), nfft)
    return y[:, :steps] + first * u[:, :1] + H[..., 2]


def _states_loop(A, b, u, dt: float, x0=None) -> torch.Tensor:
    """Reference: Eq. 12 as a plain per-step loop, ``X (batch, steps, n)``."""
    Phi, gamma1, gamma2 = _discretise(A, b, dt)
    x = gamma1.new_zeros(gamma1.shape) if x0 is None else x0
    du = torch.diff(u, dim=1)
    xs = [x]
    for k in range(u.shape[1] - 1):
        x = (Phi @ x[:, :, None])[..., 0] + gamma1 * u[:, k, None] + gamma2 * du[:, k, None]
        xs.append(x)
    return torch.stack(xs, dim=1)


def _simulate_loop(A, b, c, d, u, dt: float, x0=None) -> torch.Tensor:
    """Reference: Eq. 12-13 as a plain per-step loop (the benchmark's baseline)."""
    X = _states_loop(A, b, u, dt, x0)
    return (X @ c[:, :, None])[..., 0] + d[:, None] * u


def _simulate(A, b, c, d, u, dt: float, x0=None) -> torch.Tensor:
    """The default decoder, Eq. 10-13: ``y (batch, steps)``; see ``simulate`` for shapes.

    Chosen by measurement (module docstring): forward + backward, batch 256, n = 2, one CPU thread
    of a shared 2-core machine, median of 9 (``aeid_struct.bench.bench_decoder``), in ms,
    chunked / FFT / scan / loop:

    =======  ===================  ===================  =====================
    dtype    100 samples          300 samples          1000 samples
    =======  ===================  ===================  =====================
    float32  11 / 9.3 / 13 / 25   13 / 17 / 21 / 62    20 / 39 / 49 / 215
    float64  11 / 11 / 14 / 25    15 / 25 / 26 / 68    28 / 72 / 71 / 252
    =======  ===================  ===================  =====================
    """
    return _simulate_chunked(A, b, c, d, u, dt, x0)


def _free_response(A, c, dt: float, steps: int) -> torch.Tensor:
    """``O (batch, steps, n)`` with ``O[:, k] = c^T e^{A k dt}``: the output of the free
    response, ``y_k = O[:, k] x_0``, from the doubling of ``_powers``."""
    n = A.shape[-1]
    Phi = torch.linalg.matrix_exp(A * dt)
    O, _ = _powers(c, Phi, steps)
    return O[:, :steps, :n]


def _least_squares_x0(O: torch.Tensor, r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``x0 (batch, n)`` minimising ``||r - O x0||`` for ``O (batch, steps, n)``,
    ``r (batch, steps)``, and the fitted free response ``O x0 (batch, steps)``.

    By a QR of the column-scaled ``O`` (the columns of an unstable or fast mode differ by orders
    of magnitude); scaled by ``max_k |O_k|``, not the 2-norm, whose squares overflow long before
    the entries do (float32 at 1.8e19)."""
    # Detached: the least-squares x0 does not depend on the column scaling, so neither does its
    # gradient; a gradient through the scale would only add rounding and time.
    scale = O.detach().abs().amax(dim=1).clamp_min(torch.finfo(O.dtype).tiny)      # (batch, n)
    Q, R = torch.linalg.qr(O / scale[:, None, :])
    z = torch.linalg.solve_triangular(R, (Q.mT @ r[..., None]), upper=True)
    return z[..., 0] / scale, (Q @ (R @ z))[..., 0]


def _free_fit(A, b, c, d, u, y, dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The least-squares initial state of records that do not start from rest, and the response
    from it: ``x0 (batch, n)`` minimising ``sum_k (y_k - c^T e^{A k dt} x0 - y_forced_k)^2``
    (``y_forced``: Eq. 10-13 from rest), and ``y_hat = y_forced + O x0 (batch, steps)``.

    The free response is linear in ``x0``, so this is exact for noise-free records of the model;
    solved by :func:`_least_squares_x0`, differentiable."""
    y_forced = _simulate(A, b, c, d, u, dt, None)
    x0, free = _least_squares_x0(_free_response(A, c, dt, u.shape[1]), y - y_forced)
    return x0, y_forced + free


def _initial_state(A, b, c, d, u, y, dt: float) -> torch.Tensor:
    """``x0 (batch, n)`` of :func:`_free_fit`."""
    return _free_fit(A, b, c, d, u, y, dt)[0]


def _stationary_value(A, b, c, d) -> torch.Tensor:
    """Eq. 4: ``y_inf = d - c^T A^{-1} b`` (batch,), by a solve, not an inverse."""
    return d - (c * torch.linalg.solve(A, b[..., None])[..., 0]).sum(-1)


def _record_scale(y: torch.Tensor) -> torch.Tensor:
    """Eq. 15's ``y_bar = max_k |y_k|`` per record: ``y (batch, steps)`` -> ``(batch,)``."""
    return y.abs().amax(dim=-1)


def _loss(y_hat, y, yinf_hat=None, yinf=None, gamma: float = 0.0) -> torch.Tensor:
    """Eq. 14 per record, batch mean; ``y_hat, y (batch, steps)``, ``yinf (batch,)`` or None."""
    sse = (y - y_hat).square().sum(-1)
    if gamma != 0.0:
        sse = sse + gamma * (yinf - yinf_hat).square()
    return (sse / (y.shape[-1] + 1)).mean()


# ----------------------------------------------------------------------------------------------
# Input handling for the public functions.
# ----------------------------------------------------------------------------------------------


#: Arguments that may be None (absent); every other one must be given.
_OPTIONAL = frozenset({"x0", "yinf_hat", "yinf"})


def _prepare(named: dict[str, object]) -> tuple[dict[str, torch.Tensor | None], bool]:
    """Array-likes -> tensors of one floating dtype on one device; True when torch came in."""
    for name, v in named.items():
        if v is None and name not in _OPTIONAL:
            raise ValueError(f"{name} must be a real array; got None")
    tensors = [v for v in named.values() if isinstance(v, torch.Tensor)]
    dtype, device = torch.float64, torch.device("cpu")
    if tensors:
        devices = sorted({str(t.device) for t in tensors})
        if len(devices) > 1:
            raise ValueError(f"all tensors must be on one device; got {', '.join(devices)}")
        device = tensors[0].device
        floats = [t.dtype for t in tensors if t.is_floating_point()]
        if floats:
            dtype = functools.reduce(torch.promote_types, floats)
        if dtype not in (torch.float32, torch.float64):
            raise ValueError(f"tensors must be float32 or float64; got {dtype}")
    out: dict[str, torch.Tensor | None] = {}
    for name, v in named.items():
        if v is None:
            out[name] = None
        elif isinstance(v, torch.Tensor):
            if v.is_complex() or v.dtype == torch.bool:
                raise ValueError(f"{name} must be real; got {v.dtype}")
            out[name] = v.to(dtype=dtype)
        else:
            try:
                arr = np.asarray(v)
            except ValueError as err:  # ragged nested sequences
                raise ValueError(f"{name} must be a real array; got {type(v).__name__}") from err
            if arr.dtype.kind not in "iuf":
                raise ValueError(f"{name} must be a real array; got dtype {arr.dtype}")
            out[name] = torch.as_tensor(arr, dtype=dtype, device=device)
    return out, bool(tensors)


def _shape(t: torch.Tensor) -> str:
    return str(tuple(t.shape))


def _check_dt(dt) -> float:
    try:
        value = float(dt) if not isinstance(dt, (bool, str)) else math.nan
    except (TypeError, ValueError, RuntimeError):
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"dt must be a positive finite number; got {dt!r}")
    return value


def _check_finite(name: str, t: torch.Tensor, axes: tuple[str, ...]) -> None:
    """Raise naming the first non-finite entry, e.g. 'nan at record 0, sample 12'."""
    bad = ~torch.isfinite(t)
    if not bool(bad.any()):
        return
    index = tuple(int(i) for i in torch.nonzero(bad)[0])
    value = float(t[index])
    # A record without its batch axis names only the trailing axes ("sample 12", "row 1, ...").
    labels = axes[len(axes) - len(index) :]
    where = ", ".join(f"{axis} {i}" for axis, i in zip(labels, index, strict=True))
    raise ValueError(f"{name} must be finite; got {value}" + (f" at {where}" if where else ""))


_AXES = {
    "A": ("record", "row", "column"),
    "b": ("record", "entry"),
    "c": ("record", "entry"),
    "x0": ("record", "entry"),
    "d": ("record",),
    "u": ("record", "sample"),
    "y": ("record", "sample"),
}


#: Dimensions of one (unbatched) argument: more means a leading batch axis.
_CORE = {"A": 2, "b": 1, "c": 1, "x0": 1, "d": 0, "u": 1, "y": 1}


def _check_system(t: dict[str, torch.Tensor | None]) -> tuple[int, int, bool]:
    """Check shapes and finiteness of ``A, b[, c, d, u, x0]``: returns ``n, batch, batched``."""
    A = t["A"]
    if A.ndim not in (2, 3) or A.shape[-1] != A.shape[-2] or A.shape[-1] == 0:
        raise ValueError(f"A must be square with shape (batch, n, n) or (n, n); got {_shape(A)}")
    n = A.shape[-1]
    for name in ("b", "c", "x0"):
        v = t.get(name)
        if v is not None and (v.ndim not in (1, 2) or v.shape[-1] != n):
            raise ValueError(
                f"{name} must have shape (batch, n) or (n,) with n = {n} from A; got {_shape(v)}"
            )
    d, u = t.get("d"), t.get("u")
    if d is not None and d.ndim > 1:
        raise ValueError(f"d must be a scalar or have shape (batch,); got {_shape(d)}")
    if u is not None and (u.ndim not in (1, 2) or u.shape[-1] == 0):
        raise ValueError(
            f"u must have shape (batch, steps) or (steps,) with steps >= 1; got {_shape(u)}"
        )
    y = t.get("y")
    if y is not None and (y.ndim not in (1, 2) or y.shape[-1] == 0):
        raise ValueError(
            f"y must have shape (batch, steps) or (steps,) with steps >= 1; got {_shape(y)}"
        )
    sizes = {k: v.shape[0] for k, v in t.items() if v is not None and v.ndim > _CORE[k]}
    batch, batched = _common_batch(sizes)
    for name, v in t.items():
        if v is not None:
            _check_finite(name, v, _AXES[name])
    return n, batch, batched


def _common_batch(sizes: dict[str, int]) -> tuple[int, bool]:
    distinct = sorted({s for s in sizes.values() if s != 1})
    if len(distinct) > 1:
        have = ", ".join(f"{k} has {s}" for k, s in sizes.items())
        raise ValueError(
            f"batch sizes disagree: {have} (batched arguments must share one batch size, or have 1)"
        )
    return (distinct[0] if distinct else 1), bool(sizes)


def _batched(t: dict[str, torch.Tensor | None], batch: int) -> dict[str, torch.Tensor | None]:
    """Give every argument the common leading batch axis (views, no copies)."""
    out = {}
    for k, v in t.items():
        if v is not None:
            v = v if v.ndim > _CORE[k] else v[None]
            v = v.expand(batch, *v.shape[1:])
        out[k] = v
    return out


def _output(t: torch.Tensor, torch_out: bool, batched: bool = True):
    """Drop the batch axis for unbatched calls; numpy float64 out for numpy in."""
    if not batched:
        t = t[0]
    if torch_out:
        return t
    arr = t.detach().cpu().numpy()
    return arr[()] if arr.ndim == 0 else arr


# ----------------------------------------------------------------------------------------------
# Overflow: the rule of the public functions (``simulate``'s docstring, "Warns").
# ----------------------------------------------------------------------------------------------


def _nonfinite_records(t: torch.Tensor) -> torch.Tensor:
    """Indices of the records (axis 0) of ``t`` that hold a non-finite entry."""
    return torch.nonzero(~torch.isfinite(t).flatten(1).all(1))[:, 0]


def _overflow_from(t: torch.Tensor) -> torch.Tensor:
    """``(records, steps)`` bool, True from each record's first sample with a non-finite entry on;
    ``t (records, steps)`` or ``(records, steps, n)``."""
    bad = ~torch.isfinite(t)
    if bad.ndim == 3:
        bad = bad.any(-1)
    return bad.cumsum(dim=1) > 0


def _overflow(out: torch.Tensor, index: torch.Tensor, exact: torch.Tensor, caller: str, A,
              dt: float, batched: bool) -> torch.Tensor:
    """``out (batch, steps[, n])`` with the records ``index`` replaced by ``exact``, their values
    by the per-step recursion, +inf from the first sample that overflows on; warns if any does.

    Why the per-step recursion: the chunked and scan kernels raise ``Phi`` to powers up to the
    record's length, which can overflow while every sample is still finite."""
    over = _overflow_from(exact)
    mask = over if exact.ndim == 2 else over[..., None].expand_as(exact)
    out = out.index_put((index,), exact.masked_fill(mask, math.inf))
    hit = torch.nonzero(over.any(1))[:, 0]
    if len(hit):
        first = int(torch.nonzero(over[hit[0]])[0, 0])
        _warn_overflow(caller, index[hit], first, A, dt, out.shape[1], out.dtype, batched,
                       "those samples are +inf", stacklevel=4)
    return out


class OverflowWarning(RuntimeWarning):
    """A simulated response exceeded the dtype's range; the record is +inf from that sample on."""


def _warn_overflow(caller: str, records: torch.Tensor, first: int, A, dt: float, steps: int,
                   dtype: torch.dtype, batched: bool, returned: str, stacklevel: int) -> None:
    """The RuntimeWarning of the overflow rule: which records, from which sample, and why."""
    r = int(records[0])
    pole = float(torch.linalg.eigvals(A[r].detach()).real.max())
    name = str(dtype).removeprefix("torch.")
    where = (f"{len(records)} of {A.shape[0]} records (the first: record {r}, "
             if batched else "the record (")
    growth = pole * dt * steps
    why = (f"its largest pole Re(p) = {pole:.3g} rad/s grows by e^(Re(p) dt steps) = "
           f"e^{growth:.3g} over the record" if growth > 0 else
           f"a stable system (largest Re(p) = {pole:.3g} rad/s): the input or the model's size")
    warnings.warn(
        f"{caller}: the response overflows {name} (largest finite {torch.finfo(dtype).max:.3g}) "
        f"in {where}from sample {first} of {steps}; {why}); {returned}",
        OverflowWarning,
        stacklevel=stacklevel,
    )


def _exact_x0(t: dict[str, torch.Tensor], index: torch.Tensor, dt: float,
              batched: bool) -> torch.Tensor:
    """``initial_state`` of the records ``index`` whose fit came out non-finite, from the per-step
    forced and free responses; +inf (with the overflow warning) where those overflow."""
    A, b, c, d, u, y = (t[k][index] for k in ("A", "b", "c", "d", "u", "y"))
    y_forced = _simulate_loop(A, b, c, d, u, dt)
    # O[:, k] = c^T e^{A k dt}: the states of the transposed system started at c, undriven.
    O = _states_loop(A.mT, torch.zeros_like(b), torch.zeros_like(u), dt, c)
    over = _overflow_from(torch.cat([y_forced[..., None], O], dim=-1))
    hit = over.any(1)
    x0 = torch.full_like(b, math.inf)
    fine = torch.nonzero(~hit)[:, 0]
    if len(fine):
        x0[fine] = _least_squares_x0(O[fine], y[fine] - y_forced[fine])[0]
    singular = torch.nonzero(~torch.isfinite(x0).all(1) & ~hit)[:, 0]
    if len(singular):
        r = int(index[singular[0]])
        record = f" (record {r} of {t['A'].shape[0]})" if batched else ""
        raise ValueError(f"A and c must give an observable model{record}: the free response "
                         "c^T e^{A k dt} has rank < n over the record, so x0 is not determined")
    if bool(hit.any()):
        first = int(torch.nonzero(over[hit][0])[0, 0])
        _warn_overflow("initial_state", index[hit], first, t["A"], dt, u.shape[1], b.dtype,
                       batched, "no finite least-squares x0 exists in that precision: x0 of "
                       "those records is +inf", stacklevel=4)
    return x0


# ----------------------------------------------------------------------------------------------
# Public API.
# ----------------------------------------------------------------------------------------------


def discretise(A: Array, b: Array, dt: float) -> Discrete:
    """Exact first-order-hold discretisation by one matrix exponential (paper Eq. 10).

    ``expm([[A dt, b dt, 0], [0, 0, 1], [0, 0, 0]])`` (block matrix)
    ``= [[Phi, gamma1, gamma2], [0, 1, 1], [0, 0, 1]]``, so that
    ``x_{k+1} = Phi x_k + gamma1 u_k + gamma2 (u_{k+1} - u_k)`` (Eq. 11) for inputs that are linear
    between samples.

    Parameters
    ----------
    A : (batch, n, n) or (n, n)
    b : (batch, n) or (n,)
    dt : float, > 0

    Returns
    -------
    Discrete
        ``Phi (batch, n, n)``, ``gamma1, gamma2 (batch, n)`` (no batch axis when neither input had
        one); numpy float64 for numpy input, torch (differentiable) for torch input.
    """
    t, torch_out = _prepare({"A": A, "b": b})
    dt = _check_dt(dt)
    _, batch, batched = _check_system(t)
    t = _batched(t, batch)
    Phi, gamma1, gamma2 = _discretise(t["A"], t["b"], dt)
    return Discrete(
        Phi=_output(Phi, torch_out, batched),
        gamma1=_output(gamma1, torch_out, batched),
        gamma2=_output(gamma2, torch_out, batched),
        dt=dt,
    )


def states(A: Array, b: Array, u: Array, dt: float, *, x0: Array | None = None) -> Array:
    """The state sequence of Eq. 12, ``X[:, k] = x(k dt)``, exact for a first-order-hold input.

    Parameters
    ----------
    A : (batch, n, n) or (n, n)
    b : (batch, n) or (n,)
    u : (batch, steps) or (steps,)
        Input samples at ``t_k = k dt``; linear in between.
    dt : float, > 0
    x0 : (batch, n) or (n,), optional
        State at ``t_0``; zero by default (the paper's assumption, needed by Eq. 15).

    Returns
    -------
    X : (batch, steps, n), or (steps, n) when no input had a batch axis.

    Warns
    -----
    RuntimeWarning
        When a state leaves the floating range of the dtype: as in :func:`simulate`, every entry
        of a record from its first sample with an overflowing entry on is +inf, never NaN.
    """
    t, torch_out = _prepare({"A": A, "b": b, "u": u, "x0": x0})
    dt = _check_dt(dt)
    _, batch, batched = _check_system(t)
    t = _batched(t, batch)
    X = _states(t["A"], t["b"], t["u"], dt, t["x0"])
    index = _nonfinite_records(X)
    if len(index):
        exact = _states_loop(*(t[k][index] for k in ("A", "b", "u")), dt,
                             None if t["x0"] is None else t["x0"][index])
        X = _overflow(X, index, exact, "states", t["A"], dt, batched)
    return _output(X, torch_out, batched)


def simulate(
    A: Array, b: Array, c: Array, d: Array | float, u: Array, dt: float, *, x0: Array | None = None
) -> Array:
    """The decoder: exact FOH response ``y_k = c^T x_k + d u_k`` on ``t_k = k dt`` (Eq. 10-13).

    Batched over systems and inputs with no Python loop over either; the time recursion runs in
    ``log2(steps)`` levels (see the module docstring). Differentiable with respect to every tensor
    argument; works in float32 and float64.

    Parameters
    ----------
    A : (batch, n, n) or (n, n)
    b, c : (batch, n) or (n,)
    d : (batch,) or scalar
    u : (batch, steps) or (steps,)
        Input samples; linear between samples (first-order hold). A ``(steps,)`` input drives
        every system of the batch; a batch of inputs may drive one system.
    dt : float, > 0
    x0 : (batch, n) or (n,), optional
        Initial state; zero by default.

    Returns
    -------
    y : (batch, steps), or (steps,) when no input had a batch axis. numpy float64 for numpy
        input, torch for torch input. Where it is finite, each sample equals the per-step
        recursion of Eq. 12-13 to its own relative accuracy (~1e-12 in float64), at any
        ``|pole| dt``.

    Warns
    -----
    RuntimeWarning
        When the response leaves the floating range of the dtype (float64: 1.8e308, float32:
        3.4e38; an unstable pole ``p`` over ``steps`` samples grows by ``e^{Re(p) dt steps}``):
        the overflowing records are recomputed by the per-step recursion, and every sample of
        theirs from the first that overflows on is +inf (no sign is implied), never NaN; the
        samples before it are exact. The warning names the records, the first sample and
        ``Re(p) dt steps``. The same rule holds for numpy and torch input, float32 and float64;
        other records of the batch are untouched.
    """
    t, torch_out = _prepare({"A": A, "b": b, "c": c, "d": d, "u": u, "x0": x0})
    dt = _check_dt(dt)
    _, batch, batched = _check_system(t)
    t = _batched(t, batch)
    y = _simulate(t["A"], t["b"], t["c"], t["d"], t["u"], dt, t["x0"])
    index = _nonfinite_records(y)
    if len(index):
        exact = _simulate_loop(*(t[k][index] for k in ("A", "b", "c", "d", "u")), dt,
                               None if t["x0"] is None else t["x0"][index])
        y = _overflow(y, index, exact, "simulate", t["A"], dt, batched)
    return _output(y, torch_out, batched)


def initial_state(A: Array, b: Array, c: Array, d: Array | float, u: Array, y: Array,
                  dt: float) -> Array:
    """The initial state of a record that starts mid-motion, by linear least squares.

    With ``x_0 != 0`` the response is the response from rest (Eq. 10-13) plus the free response
    ``c^T e^{A k dt} x_0``, which is linear in ``x_0``; so ``x_0`` is the least-squares solution
    of ``O x_0 = y - y_forced`` with ``O[k] = c^T e^{A k dt}``. Exact (to rounding) for a
    noise-free record of the model; with noise, the best fit. ``simulate(..., x0=x0)`` then
    reproduces the record.

    Parameters
    ----------
    A, b, c, d : the model, shapes as in :func:`simulate` (observable: ``O`` of full rank)
    u, y : (batch, steps) or (steps,)
        Input and measured output on ``t_k = k dt``.
    dt : float, > 0

    Returns
    -------
    x0 : (batch, n), or (n,) when no input had a batch axis; numpy float64 for numpy input.

    Raises
    ------
    ValueError
        For a model whose free response does not determine ``x0`` (unobservable), naming the
        record.

    Warns
    -----
    RuntimeWarning
        When the model's forced or free response over the record leaves the floating range
        (the overflow rule of :func:`simulate`): no finite least-squares ``x0`` can be computed
        in that precision, and ``x0`` of those records is +inf, never NaN.
    """
    t, torch_out = _prepare({"A": A, "b": b, "c": c, "d": d, "u": u, "y": y})
    dt = _check_dt(dt)
    if t["y"].shape[-1] != t["u"].shape[-1]:
        raise ValueError(f"y must have as many samples as u ({t['u'].shape[-1]}); "
                         f"got {t['y'].shape[-1]}")
    _, batch, batched = _check_system(t)
    t = _batched(t, batch)
    x0 = _initial_state(t["A"], t["b"], t["c"], t["d"], t["u"], t["y"], dt)
    index = _nonfinite_records(x0)
    if len(index):
        x0 = x0.index_put((index,), _exact_x0(t, index, dt, batched))
    return _output(x0, torch_out, batched)



def stationary_value(A: Array, b: Array, c: Array, d: Array | float) -> Array:
    """The step response's final value ``y_inf = G(0) = d - c^T A^{-1} b`` (paper Eq. 4).

    Meaningful for stable systems; computed for any invertible ``A``.

    Parameters
    ----------
    A : (batch, n, n) or (n, n), invertible
    b, c : (batch, n) or (n,)
    d : (batch,) or scalar

    Returns
    -------
    y_inf : (batch,), or a scalar when no input had a batch axis.
    """
    t, torch_out = _prepare({"A": A, "b": b, "c": c, "d": d})
    _, batch, batched = _check_system(t)
    t = _batched(t, batch)
    sol, info = torch.linalg.solve_ex(t["A"], t["b"][..., None])
    singular = torch.nonzero(info)
    if len(singular):
        record = f" (record {int(singular[0, 0])} of {batch})" if batched else ""
        raise ValueError(
            f"A must be invertible{record}: Eq. 4 has no finite stationary value for a pole "
            "at s = 0"
        )
    y_inf = t["d"] - (t["c"] * sol[..., 0]).sum(-1)
    return _output(y_inf, torch_out, batched)


def _check_record(name: str, y: torch.Tensor, *, allow_scalar: bool = False) -> None:
    lowest = 0 if allow_scalar else 1
    if not lowest <= y.ndim <= 2 or (y.ndim > 0 and y.shape[-1] == 0):
        raise ValueError(
            f"{name} must have shape (batch, steps) or (steps,) with steps >= 1; got {_shape(y)}"
        )
    _check_finite(name, y, ("record", "sample"))


def record_scale(y: Array) -> Array:
    """Eq. 15's scale ``y_bar = max_k |y_k|`` of each measured record.

    Parameters
    ----------
    y : (batch, steps) or (steps,)

    Returns
    -------
    y_bar : (batch,), or a scalar for one record.

    Raises
    ------
    ValueError
        For an all-zero record, naming it: Eq. 15 divides by ``y_bar``.
    """
    t, torch_out = _prepare({"y": y})
    y = t["y"]
    _check_record("y", y)
    batched = y.ndim == 2
    y_bar = _record_scale(y if batched else y[None])
    zero = torch.nonzero(y_bar == 0)
    if len(zero):
        which = f" (record {int(zero[0, 0])} of {y_bar.shape[0]})" if batched else ""
        raise ValueError(
            f"y must not be all zero{which}: the normalisation y_tilde = 2 y / max|y| - 1 (Eq. 15) "
            "needs max|y| > 0"
        )
    return _output(y_bar, torch_out, batched)


def _prepare_scaled(name: str, y, y_bar) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Check ``y`` against ``y_bar`` and return ``y_bar`` shaped to broadcast over ``y``."""
    t, torch_out = _prepare({name: y, "y_bar": y_bar})
    y, y_bar = t[name], t["y_bar"]
    if y.ndim > 2:
        raise ValueError(
            f"{name} must have shape (batch, steps), (batch,) or (steps,); got {_shape(y)}"
        )
    if y_bar.ndim > 1:
        raise ValueError(f"y_bar must be a scalar or have shape (batch,); got {_shape(y_bar)}")
    # (batch, steps) with (batch,): one scale per record; (batch,) with (batch,): stationary values.
    want = y.shape[:1] if y.ndim >= 1 else ()
    if y_bar.ndim == 1 and tuple(y_bar.shape) != tuple(want):
        raise ValueError(
            f"y_bar must be a scalar or have shape {tuple(want)} to match {name} {_shape(y)}; "
            f"got {_shape(y_bar)}"
        )
    _check_finite(name, y, ("record", "sample"))
    _check_finite("y_bar", y_bar, ("record",))
    if bool((y_bar <= 0).any()):
        bad = torch.nonzero(y_bar.reshape(-1) <= 0)[0, 0]
        raise ValueError(f"y_bar must be positive; got {float(y_bar.reshape(-1)[bad])}")
    if y.ndim == 2 and y_bar.ndim == 1:
        y_bar = y_bar[:, None]
    return y, y_bar, torch_out


def normalise(y: Array, y_bar: Array | float) -> Array:
    """Eq. 15: ``y_tilde = 2 y / y_bar - 1``.

    Parameters
    ----------
    y : (batch, steps), (batch,) or (steps,)
        Records (scaled per record), stationary values (one per record) or one record.
    y_bar : (batch,) or scalar, > 0
        ``record_scale`` of the measured records; apply the same to the decoded output.

    Returns
    -------
    y_tilde : shaped like ``y``.
    """
    y, y_bar, torch_out = _prepare_scaled("y", y, y_bar)
    return _output(2.0 * y / y_bar - 1.0, torch_out)


def denormalise(y_tilde: Array, y_bar: Array | float) -> Array:
    """Inverse of Eq. 15: ``y = (y_tilde + 1) y_bar / 2``; shapes as in ``normalise``."""
    y_tilde, y_bar, torch_out = _prepare_scaled("y_tilde", y_tilde, y_bar)
    return _output((y_tilde + 1.0) * y_bar / 2.0, torch_out)


def loss(
    y_hat: Array,
    y: Array,
    yinf_hat: Array | None = None,
    yinf: Array | None = None,
    *,
    gamma: float = 0.0,
) -> torch.Tensor:
    """The training loss of Eq. 14, averaged over the batch.

    ``J = (sum_{i=1}^m (y_i - yhat_i)^2 + gamma (y_inf - yhat_inf)^2) / (m + 1)`` per record, with
    ``m = steps``; the ``1/(m+1)`` is kept for ``gamma = 0`` too (it only scales the loss).
    All arguments must already be normalised by the caller (Eq. 15, ``normalise``), the stationary
    values with the same ``y_bar`` as their records.

    Parameters
    ----------
    y_hat, y : (batch, steps) or (steps,)
        Decoded and measured outputs.
    yinf_hat, yinf : (batch,) or scalar, optional
        Decoded (Eq. 4) and true stationary values; required when ``gamma > 0``.
    gamma : float, >= 0
        Weight of the stationary-value term.

    Returns
    -------
    J : 0-d torch tensor (float64 for numpy input), differentiable.
    """
    if isinstance(gamma, bool) or not (isinstance(gamma, (int, float)) and math.isfinite(gamma)):
        raise ValueError(f"gamma must be a finite number >= 0; got {gamma!r}")
    if gamma < 0:
        raise ValueError(f"gamma must be a finite number >= 0; got {gamma!r}")
    if (yinf_hat is None) != (yinf is None):
        raise ValueError("yinf_hat and yinf must be given together (or neither)")
    if gamma > 0 and yinf is None:
        raise ValueError(f"gamma = {gamma} weights the stationary values: give yinf_hat and yinf")
    t, _ = _prepare({"y_hat": y_hat, "y": y, "yinf_hat": yinf_hat, "yinf": yinf})
    y_hat, y = t["y_hat"], t["y"]
    _check_record("y", y)
    if y_hat.shape != y.shape:
        raise ValueError(f"y_hat must have the shape of y {_shape(y)}; got {_shape(y_hat)}")
    _check_finite("y_hat", y_hat, ("record", "sample"))
    y_hat, y = (y_hat, y) if y.ndim == 2 else (y_hat[None], y[None])
    yinf_hat, yinf = t["yinf_hat"], t["yinf"]
    if yinf is not None:
        want = "(batch,)" if y.shape[0] > 1 or t["y"].ndim == 2 else "()"
        for name, v in (("yinf_hat", yinf_hat), ("yinf", yinf)):
            if v.ndim > 1 or (v.ndim == 1 and v.shape[0] != y.shape[0]):
                raise ValueError(
                    f"{name} must have shape {want} with batch = {y.shape[0]} from y; "
                    f"got {_shape(v)}"
                )
            _check_finite(name, v, ("record",))
    return _loss(y_hat, y, yinf_hat, yinf, float(gamma))
