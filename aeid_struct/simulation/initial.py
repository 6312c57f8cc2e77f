"""The initial state of a record that starts mid-motion, by linear least squares.

With ``x_0 != 0`` the response is the response from rest (Eq. 10-13) plus the free response
``c^T e^{A k dt} x_0``, which is linear in ``x_0``; so ``x_0`` is the least-squares solution of
``O x_0 = y - y_forced`` with ``O[k] = c^T e^{A k dt}`` (variable projection: exact for a
noise-free record of the model, the best fit with noise).
"""

from __future__ import annotations

import math

import torch

from aeid_struct.simulation.checks import (
    Array,
    batched,
    check_dt,
    check_system,
    output,
    prepare,
)
from aeid_struct.simulation.kernels import powers, simulate_batch, simulate_loop, states_loop
from aeid_struct.simulation.overflow import nonfinite_records, overflow_from, warn_overflow

__all__ = ["fit_initial_state", "free_response", "initial_state", "least_squares_x0"]


def free_response(A, c, dt: float, steps: int) -> torch.Tensor:
    """The output basis of the free response, ``y_k = O[:, k] x_0``, unchecked.

    Parameters
    ----------
    A : (batch, n, n) tensor
    c : (batch, n) tensor
    dt : float, > 0
    steps : int, >= 1

    Returns
    -------
    O : (batch, steps, n) tensor
        ``O[:, k] = c^T e^{A k dt}``, by doubling (:func:`~aeid_struct.simulation.kernels.powers`).
    """
    n = A.shape[-1]
    Phi = torch.linalg.matrix_exp(A * dt)
    O, _ = powers(c, Phi, steps)
    return O[:, :steps, :n]


def least_squares_x0(O: torch.Tensor, r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``x0`` minimising ``||r - O x0||`` per record, and the fitted free response.

    By a QR of the column-scaled ``O`` (the columns of an unstable or fast mode differ by orders
    of magnitude); scaled by ``max_k |O_k|``, not the 2-norm, whose squares overflow long before
    the entries do (float32 at 1.8e19).

    Parameters
    ----------
    O : (batch, steps, n) tensor
    r : (batch, steps) tensor

    Returns
    -------
    x0 : (batch, n) tensor
    fitted : (batch, steps) tensor
        ``O x0``.
    """
    # Detached: the least-squares x0 does not depend on the column scaling, so neither does its
    # gradient; a gradient through the scale would only add rounding and time.
    scale = O.detach().abs().amax(dim=1).clamp_min(torch.finfo(O.dtype).tiny)      # (batch, n)
    Q, R = torch.linalg.qr(O / scale[:, None, :])
    z = torch.linalg.solve_triangular(R, (Q.mT @ r[..., None]), upper=True)
    return z[..., 0] / scale, (Q @ (R @ z))[..., 0]


def fit_initial_state(A, b, c, d, u, y, dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The least-squares initial state of records that do not start from rest, and the response
    from it; unchecked and differentiable (what training calls for ``initial="fitted"``).

    ``x0`` minimises ``sum_k (y_k - c^T e^{A k dt} x0 - y_forced_k)^2`` (``y_forced``: Eq. 10-13
    from rest, :func:`~aeid_struct.simulation.kernels.simulate_batch`).

    Parameters
    ----------
    A : (batch, n, n) tensor
    b, c : (batch, n) tensors
    d : (batch,) tensor
    u, y : (batch, steps) tensors
        Input and measured output on ``t_k = k dt``.
    dt : float, > 0

    Returns
    -------
    x0 : (batch, n) tensor
    y_hat : (batch, steps) tensor
        ``y_forced + O x0``, the model's response from ``x0``.
    """
    y_forced = simulate_batch(A, b, c, d, u, dt, None)
    x0, free = least_squares_x0(free_response(A, c, dt, u.shape[1]), y - y_forced)
    return x0, y_forced + free


def initial_state(A: Array, b: Array, c: Array, d: Array | float, u: Array, y: Array,
                  dt: float) -> Array:
    """The initial state of a record that starts mid-motion, by linear least squares.

    ``x_0`` solves ``O x_0 = y - y_forced`` in the least-squares sense, ``O[k] = c^T e^{A k dt}``,
    ``y_forced`` the response from rest (Eq. 10-13). Exact (to rounding) for a noise-free record of
    the model; with noise, the best fit. ``simulate(..., x0=x0)`` then reproduces the record.

    Parameters
    ----------
    A : (batch, n, n) or (n, n)
    b, c : (batch, n) or (n,)
    d : (batch,) or scalar
        The model (observable: ``O`` of full rank); shapes as in
        :func:`~aeid_struct.simulation.simulate`.
    u, y : (batch, steps) or (steps,)
        Input and measured output on ``t_k = k dt``.
    dt : float, > 0

    Returns
    -------
    x0 : (batch, n), or (n,) when no input had a batch axis; numpy float64 for numpy input.

    Raises
    ------
    ValueError
        For a bad argument, or a model whose free response does not determine ``x0``
        (unobservable), naming the record.

    Warns
    -----
    RuntimeWarning
        When the model's forced or free response over the record leaves the floating range
        (the overflow rule of :func:`~aeid_struct.simulation.simulate`): no finite least-squares
        ``x0`` can be computed in that precision, and ``x0`` of those records is +inf, never NaN.
    """
    t, torch_out = prepare({"A": A, "b": b, "c": c, "d": d, "u": u, "y": y})
    dt = check_dt(dt)
    if t["y"].shape[-1] != t["u"].shape[-1]:
        raise ValueError(f"y must have as many samples as u ({t['u'].shape[-1]}); "
                         f"got {t['y'].shape[-1]}")
    _, batch, is_batched = check_system(t)
    t = batched(t, batch)
    x0 = fit_initial_state(t["A"], t["b"], t["c"], t["d"], t["u"], t["y"], dt)[0]
    index = nonfinite_records(x0)
    if len(index):
        x0 = x0.index_put((index,), _exact_x0(t, index, dt, is_batched))
    return output(x0, torch_out, is_batched)


def _exact_x0(t: dict[str, torch.Tensor], index: torch.Tensor, dt: float,
              is_batched: bool) -> torch.Tensor:
    """``initial_state`` of the records ``index`` whose fit came out non-finite, from the per-step
    forced and free responses; +inf (with the overflow warning) where those overflow."""
    A, b, c, d, u, y = (t[k][index] for k in ("A", "b", "c", "d", "u", "y"))
    y_forced = simulate_loop(A, b, c, d, u, dt)
    # O[:, k] = c^T e^{A k dt}: the states of the transposed system started at c, undriven.
    O = states_loop(A.mT, torch.zeros_like(b), torch.zeros_like(u), dt, c)
    over = overflow_from(torch.cat([y_forced[..., None], O], dim=-1))
    hit = over.any(1)
    x0 = torch.full_like(b, math.inf)
    fine = torch.nonzero(~hit)[:, 0]
    if len(fine):
        x0[fine] = least_squares_x0(O[fine], y[fine] - y_forced[fine])[0]
    singular = torch.nonzero(~torch.isfinite(x0).all(1) & ~hit)[:, 0]
    if len(singular):
        r = int(index[singular[0]])
        record = f" (record {r} of {t['A'].shape[0]})" if is_batched else ""
        raise ValueError(f"A and c must give an observable model{record}: the free response "
                         "c^T e^{A k dt} has rank < n over the record, so x0 is not determined")
    if bool(hit.any()):
        first = int(torch.nonzero(over[hit][0])[0, 0])
        warn_overflow("initial_state", index[hit], first, t["A"], dt, u.shape[1], b.dtype,
                      is_batched, "no finite least-squares x0 exists in that precision: x0 of "
                      "those records is +inf", stacklevel=4)
    return x0
