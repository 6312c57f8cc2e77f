r"""The linear part of a record's model by least squares (variable projection), batched and
differentiable in torch: what the generic identifiers train through.

The model is :mod:`~aeid_struct.simulation.projection`'s (docs/architecture.md, "Any system, any
record"), without the input delay: for a fixed ``(A, b)`` with its first state observable (the
controllable canonical form, paper Eq. 5), a window's output is linear in the rest,

    y = X c + u d + F theta + 1 y_offset,

with ``X`` the states forced by ``u`` from rest (Eq. 10-12, exact first-order hold,
:func:`~aeid_struct.simulation.states_batch`), ``F[k, j] = e_1^T Phi^k e_j`` the free-response
basis (:func:`~aeid_struct.simulation.free_response`), which spans every free response
``c^T Phi^k delta``, and a ones column. :func:`project_batch` solves the least squares of every
window at once by the normal equations of the unit-norm columns with a tiny ridge (a Cholesky
factorisation: differentiable, and defined where the columns are nearly dependent, as the free
basis of a slow pole and the ones column are); the residual carries the gradient to ``A``. Use
float64: the normal equations square the columns' condition number.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from aeid_struct.simulation.initial import free_response
from aeid_struct.simulation.kernels import discretise_batch, powers, states_batch

__all__ = ["BatchProjection", "initial_states_batch", "project_batch"]


class BatchProjection(NamedTuple):
    """The least-squares linear part of a batch of windows (:func:`project_batch`).

    Attributes
    ----------
    residual : (batch, steps) tensor
        ``y - y_hat``.
    y_hat : (batch, steps) tensor
    c : (batch, n) tensor
    d : (batch,) tensor
        0 where no feedthrough was fitted.
    theta : (batch, n) tensor
        The free response's coefficients in the basis ``e_1^T Phi^k e_j``
        (:func:`initial_states_batch` turns them into the initial state).
    y_offset : (batch,) tensor
        0 where no offset was fitted.
    """

    residual: torch.Tensor
    y_hat: torch.Tensor
    c: torch.Tensor
    d: torch.Tensor
    theta: torch.Tensor
    y_offset: torch.Tensor


def project_batch(A: torch.Tensor, b: torch.Tensor, y: torch.Tensor, u: torch.Tensor,
                  dt: float = 1.0, *, feedthrough: bool = True, offset: bool = True,
                  ridge: float = 1e-10) -> BatchProjection:
    """``c, d, theta, y_offset`` minimising each window's output error for given ``(A, b)``.

    Unchecked; differentiable with respect to ``A``, ``b``, ``y`` and ``u``.

    Parameters
    ----------
    A : (batch, n, n) tensor
        Its first state observable (CCF, paper Eq. 5).
    b : (batch, n) tensor
    y, u : (batch, steps) tensors
        ``steps >= 2 n + 2`` for a unique solution.
    dt : float, > 0
        1 in normalised time.
    feedthrough : bool
        Fit ``d`` (else 0).
    offset : bool
        Fit a constant output offset (else 0).
    ridge : float, >= 0
        Added to the diagonal of the normal equations of the unit-norm columns: it bounds the
        solution where columns are (nearly) dependent and changes a well-posed one by about
        ``ridge`` times its condition number.

    Returns
    -------
    BatchProjection
    """
    batch, steps = y.shape
    n = A.shape[-1]
    X = states_batch(A, b, u, dt)                                    # (batch, steps, n)
    e1 = torch.zeros_like(b)
    e1[:, 0] = 1.0
    F = free_response(A, e1, dt, steps)                              # (batch, steps, n)
    cols = [X] + ([u[..., None]] if feedthrough else []) + [F]
    if offset:
        cols.append(torch.ones_like(y)[..., None])
    M = torch.cat(cols, dim=2)                                       # (batch, steps, m)
    # Unit-norm columns: slow and fast modes' columns differ by orders of magnitude.
    scale = torch.linalg.vector_norm(M, dim=1).clamp_min(torch.finfo(M.dtype).tiny)
    Ms = M / scale[:, None, :]
    G = Ms.mT @ Ms
    G = G + ridge * torch.eye(G.shape[-1], dtype=G.dtype, device=G.device)
    L = torch.linalg.cholesky(G)
    z = torch.cholesky_solve((Ms.mT @ y[..., None]), L)[..., 0] / scale
    y_hat = (M @ z[..., None])[..., 0]
    zero = y.new_zeros(batch)
    k = n + int(feedthrough)
    return BatchProjection(residual=y - y_hat, y_hat=y_hat, c=z[:, :n],
                           d=z[:, n] if feedthrough else zero, theta=z[:, k: k + n],
                           y_offset=z[:, -1] if offset else zero)


def initial_states_batch(A: torch.Tensor, b: torch.Tensor, c: torch.Tensor, theta: torch.Tensor,
                         dt: float = 1.0) -> torch.Tensor:
    """The initial state of :func:`project_batch`'s fit, comparable with
    :func:`~aeid_struct.simulation.project`'s ``x0``.

    The free response ``F theta`` equals ``c^T Phi^k x_0`` (the forced states start from rest),
    solved on the first ``4 n`` samples (enough where ``(c, A)`` is observable). Unchecked.

    Parameters
    ----------
    A : (batch, n, n) tensor
    b, c, theta : (batch, n) tensors
    dt : float, > 0

    Returns
    -------
    x0 : (batch, n) tensor
    """
    n = A.shape[-1]
    rows = 4 * n
    Phi, _, _ = discretise_batch(A, b, dt)
    e1 = torch.zeros_like(c)
    e1[:, 0] = 1.0
    F, _ = powers(e1, Phi, rows)
    O, _ = powers(c, Phi, rows)
    return torch.linalg.lstsq(O, (F @ theta[..., None]))[0][..., 0]
