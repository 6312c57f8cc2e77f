"""The stationary value (paper Eq. 4), the normalisation (Eq. 15) and the training loss (Eq. 14).

``y_inf = d - c^T A^{-1} b``; ``y_tilde = 2 y / y_bar - 1`` with ``y_bar = max|y|`` of the measured
record, the same ``y_bar`` applied to the decoded output and the stationary values;
``J = (sum_i (y_i - yhat_i)^2 + gamma (y_inf - yhat_inf)^2) / (m + 1)``, ``m = steps``
(docs/architecture.md, "Conventions"). The ``*_batch`` functions are the unchecked torch cores
that training calls; the others check their arguments (:mod:`aeid_struct.simulation.checks`).
"""

from __future__ import annotations

import math

import torch

from aeid_struct.simulation.checks import (
    Array,
    batched,
    check_finite,
    check_record,
    check_system,
    output,
    prepare,
    shape,
)

__all__ = [
    "denormalise",
    "loss",
    "loss_batch",
    "normalise",
    "record_scale",
    "record_scale_batch",
    "stationary_value",
    "stationary_value_batch",
]


def stationary_value_batch(A, b, c, d) -> torch.Tensor:
    """Eq. 4, ``y_inf = d - c^T A^{-1} b``, unchecked (by a solve, not an inverse).

    Parameters
    ----------
    A : (batch, n, n) tensor, invertible
    b, c : (batch, n) tensors
    d : (batch,) tensor

    Returns
    -------
    y_inf : (batch,) tensor
    """
    return d - (c * torch.linalg.solve(A, b[..., None])[..., 0]).sum(-1)


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

    Raises
    ------
    ValueError
        For a bad argument, or a singular ``A`` (a pole at ``s = 0``), naming the record.
    """
    t, torch_out = prepare({"A": A, "b": b, "c": c, "d": d})
    _, batch, is_batched = check_system(t)
    t = batched(t, batch)
    sol, info = torch.linalg.solve_ex(t["A"], t["b"][..., None])
    singular = torch.nonzero(info)
    if len(singular):
        record = f" (record {int(singular[0, 0])} of {batch})" if is_batched else ""
        raise ValueError(
            f"A must be invertible{record}: Eq. 4 has no finite stationary value for a pole "
            "at s = 0"
        )
    y_inf = t["d"] - (t["c"] * sol[..., 0]).sum(-1)
    return output(y_inf, torch_out, is_batched)


def record_scale_batch(y: torch.Tensor) -> torch.Tensor:
    """Eq. 15's ``y_bar = max_k |y_k|`` per record, unchecked.

    Parameters
    ----------
    y : (batch, steps) tensor

    Returns
    -------
    y_bar : (batch,) tensor
    """
    return y.abs().amax(dim=-1)


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
        For a bad record, or an all-zero record, naming it: Eq. 15 divides by ``y_bar``.
    """
    t, torch_out = prepare({"y": y})
    y = t["y"]
    check_record("y", y)
    is_batched = y.ndim == 2
    y_bar = record_scale_batch(y if is_batched else y[None])
    zero = torch.nonzero(y_bar == 0)
    if len(zero):
        which = f" (record {int(zero[0, 0])} of {y_bar.shape[0]})" if is_batched else ""
        raise ValueError(
            f"y must not be all zero{which}: the normalisation y_tilde = 2 y / max|y| - 1 (Eq. 15) "
            "needs max|y| > 0"
        )
    return output(y_bar, torch_out, is_batched)


def _prepare_scaled(name: str, y, y_bar) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Check ``y`` against ``y_bar`` and return ``y_bar`` shaped to broadcast over ``y``."""
    t, torch_out = prepare({name: y, "y_bar": y_bar})
    y, y_bar = t[name], t["y_bar"]
    if y.ndim > 2:
        raise ValueError(
            f"{name} must have shape (batch, steps), (batch,) or (steps,); got {shape(y)}"
        )
    if y_bar.ndim > 1:
        raise ValueError(f"y_bar must be a scalar or have shape (batch,); got {shape(y_bar)}")
    # (batch, steps) with (batch,): one scale per record; (batch,) with (batch,): stationary values.
    want = y.shape[:1] if y.ndim >= 1 else ()
    if y_bar.ndim == 1 and tuple(y_bar.shape) != tuple(want):
        raise ValueError(
            f"y_bar must be a scalar or have shape {tuple(want)} to match {name} {shape(y)}; "
            f"got {shape(y_bar)}"
        )
    check_finite(name, y, ("record", "sample"))
    check_finite("y_bar", y_bar, ("record",))
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
        :func:`record_scale` of the measured records; apply the same to the decoded output.

    Returns
    -------
    y_tilde : shaped like ``y``.

    Raises
    ------
    ValueError
        For shapes that do not match, a non-finite value or a ``y_bar <= 0``.
    """
    y, y_bar, torch_out = _prepare_scaled("y", y, y_bar)
    return output(2.0 * y / y_bar - 1.0, torch_out)


def denormalise(y_tilde: Array, y_bar: Array | float) -> Array:
    """The inverse of Eq. 15: ``y = (y_tilde + 1) y_bar / 2``.

    Parameters
    ----------
    y_tilde : (batch, steps), (batch,) or (steps,)
        Normalised records, stationary values or one record.
    y_bar : (batch,) or scalar, > 0
        The scale they were normalised with.

    Returns
    -------
    y : shaped like ``y_tilde``.

    Raises
    ------
    ValueError
        As :func:`normalise`.
    """
    y_tilde, y_bar, torch_out = _prepare_scaled("y_tilde", y_tilde, y_bar)
    return output((y_tilde + 1.0) * y_bar / 2.0, torch_out)


def loss_batch(y_hat, y, yinf_hat=None, yinf=None, gamma: float = 0.0) -> torch.Tensor:
    """Eq. 14 per record, averaged over the batch, unchecked.

    Parameters
    ----------
    y_hat, y : (batch, steps) tensors
        Decoded and measured outputs, normalised (Eq. 15).
    yinf_hat, yinf : (batch,) tensors, optional
        Decoded and true stationary values, normalised; needed when ``gamma != 0``.
    gamma : float
        Weight of the stationary-value term.

    Returns
    -------
    J : 0-d tensor
    """
    sse = (y - y_hat).square().sum(-1)
    if gamma != 0.0:
        sse = sse + gamma * (yinf - yinf_hat).square()
    return (sse / (y.shape[-1] + 1)).mean()


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
    All arguments must already be normalised by the caller (Eq. 15, :func:`normalise`), the
    stationary values with the same ``y_bar`` as their records.

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

    Raises
    ------
    ValueError
        For a bad ``gamma``, shapes that do not match, a non-finite value, or stationary values
        missing where ``gamma > 0``.
    """
    if isinstance(gamma, bool) or not (isinstance(gamma, (int, float)) and math.isfinite(gamma)):
        raise ValueError(f"gamma must be a finite number >= 0; got {gamma!r}")
    if gamma < 0:
        raise ValueError(f"gamma must be a finite number >= 0; got {gamma!r}")
    if (yinf_hat is None) != (yinf is None):
        raise ValueError("yinf_hat and yinf must be given together (or neither)")
    if gamma > 0 and yinf is None:
        raise ValueError(f"gamma = {gamma} weights the stationary values: give yinf_hat and yinf")
    t, _ = prepare({"y_hat": y_hat, "y": y, "yinf_hat": yinf_hat, "yinf": yinf})
    y_hat, y = t["y_hat"], t["y"]
    check_record("y", y)
    if y_hat.shape != y.shape:
        raise ValueError(f"y_hat must have the shape of y {shape(y)}; got {shape(y_hat)}")
    check_finite("y_hat", y_hat, ("record", "sample"))
    y_hat, y = (y_hat, y) if y.ndim == 2 else (y_hat[None], y[None])
    yinf_hat, yinf = t["yinf_hat"], t["yinf"]
    if yinf is not None:
        want = "(batch,)" if y.shape[0] > 1 or t["y"].ndim == 2 else "()"
        for name, v in (("yinf_hat", yinf_hat), ("yinf", yinf)):
            if v.ndim > 1 or (v.ndim == 1 and v.shape[0] != y.shape[0]):
                raise ValueError(
                    f"{name} must have shape {want} with batch = {y.shape[0]} from y; "
                    f"got {shape(v)}"
                )
            check_finite(name, v, ("record",))
    return loss_batch(y_hat, y, yinf_hat, yinf, float(gamma))
