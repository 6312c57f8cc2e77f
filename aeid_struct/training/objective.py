"""The training objective: Eq. 14 on Eq. 15-normalised records, the training noise, and the
standardisation of the network's outputs over the family.

The loss is the mean squared error between the measured record and the decoded response of the
identified system (exact FOH simulation, Eq. 10-13), plus ``gamma`` times the squared error of
the normalised stationary value (Eq. 4). No parameter labels enter it: the true systems of the
simulated family are used only for the stationary value of Eq. 14, as in the paper, and once,
before training, to standardise the network's output (``raw_statistics``).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from aeid_struct.identification import Identifier

# The unchecked batch kernels: a training step needs a non-finite response to come back as it is
# (the batch is skipped), not recomputed and warned about as the public simulate() does.
from aeid_struct.simulation import (
    fit_initial_state,
    free_response,
    least_squares_x0,
    loss,
    normalise,
    output_groups,
    record_scale,
    simulate_batch,
    stationary_value_batch,
)
from aeid_struct.structures import Structure
from aeid_struct.training.families import Systems


def batch_loss(ident: Identifier, y, u, yinf, gamma: float, z=None,
               weight: float = 0.0) -> torch.Tensor:
    """Eq. 14 on Eq. 15-normalised records, averaged over the batch (and the records).

    The measured record, the decoded response (Eq. 10-13, from rest or from the least-squares
    initial state) and both stationary values (Eq. 4) are normalised by Eq. 15 with ``y_bar``
    of the measured record, so that no record dominates by its magnitude.

    Parameters
    ----------
    ident : Identifier
        Being trained.
    y : (batch, steps) tensor, or a list of ``R`` tensors (batch, steps_r)
        Measured records (noisy when training with noise).
    u : like ``y``
        Inputs.
    yinf : (batch,) tensor, or (batch, R)
        True stationary values (Eq. 4).
    gamma : float
        Weight of the stationary-value term.
    z : (batch, p) tensor, optional
        The true systems' standardised raw parameters (``TrainConfig.supervised``), in a
        mean-squared term against the encoder's outputs, weighted by ``weight``.
    weight : float
        Weight of that term.

    Returns
    -------
    0-d tensor
        The loss, differentiable; NaN when a decoded response is not finite (the caller skips
        such a batch).
    """
    R = ident.records
    dts = ident.dt if R > 1 else (ident.dt,)
    sys, _, raw = ident.forward(y, u, raw=True)
    ys, us = (y, u) if R > 1 else ((y,), (u,))
    parts = [tuple(x[:, r] for x in sys) if R > 1 else tuple(sys) for r in range(R)]
    groups = output_groups(getattr(ident.structure, "groups", None), R)
    total = 0.0
    for group in groups:
        first = group[0]
        y_hat, yinf_hat = decoded_output([parts[r] for r in group],
                                         [us[r] for r in group], ys[first], dts[first],
                                         initial=ident.initial == "fitted", gamma=gamma)
        if not bool(torch.isfinite(y_hat).all()) or (
                yinf_hat is not None and not bool(torch.isfinite(yinf_hat).all())):
            # overflowed: a skipped batch
            return torch.full((), math.nan, dtype=y_hat.dtype, device=y_hat.device)
        y_bar = record_scale(ys[first])
        yinf_g = None if yinf_hat is None else (
            yinf if R == 1 else sum(yinf[:, r] for r in group))
        total = total + loss(normalise(y_hat, y_bar), normalise(ys[first], y_bar),
                             None if yinf_hat is None else normalise(yinf_hat, y_bar),
                             None if yinf_hat is None else normalise(yinf_g, y_bar), gamma=gamma)
    total = total / len(groups)
    if weight > 0:
        total = total + weight * torch.mean((raw - z.to(raw.dtype)) ** 2)
    return total


def decoded_output(systems: list, us: list, y, dt: float, *, initial: bool,
                   gamma: float = 0.0) -> tuple:
    """The decoded response of one output (Eq. 10-13) and its stationary value (Eq. 4): one
    record's system, or the channels of an output whose inputs move at once, summed
    (``Physical.groups``), from rest or from the least-squares initial state; unchecked and
    differentiable.

    Why the free response of a sum in the span of ``e_1^T e^{A k dt}``: the channels of one
    output share the poles (one companion ``A``, paper Eq. 5), whose first state is observable,
    so these ``n`` columns span every free response of the output, and a QR of the channels'
    stacked free responses (rank ``n`` of ``n R``) would be singular.

    Parameters
    ----------
    systems : list of tuples ``(A (batch, n, n), b (batch, n), c (batch, n), d (batch,))``
        One per channel of the output (one for a record of its own).
    us : list of (batch, steps) tensors
        Each channel's input.
    y : (batch, steps) tensor
        The measured output (read where ``initial``).
    dt : float
    initial : bool
        Fit the initial state (``Identifier.initial == "fitted"``).
    gamma : float
        The stationary value's weight: None is returned for it where 0.

    Returns
    -------
    y_hat : (batch, steps) tensor
    yinf_hat : (batch,) tensor or None
    """
    if len(systems) == 1:
        A, b, c, d = systems[0]
        if initial:
            y_hat = fit_initial_state(A, b, c, d, us[0], y, dt)[1]
        else:
            y_hat = simulate_batch(A, b, c, d, us[0], dt, None)
        return y_hat, stationary_value_batch(A, b, c, d) if gamma > 0 else None
    y_hat = sum(simulate_batch(A, b, c, d, u, dt, None)
                for (A, b, c, d), u in zip(systems, us, strict=True))
    if initial:
        A = systems[0][0]
        e1 = torch.zeros(A.shape[:-1], dtype=A.dtype, device=A.device)
        e1[:, 0] = 1.0
        y_hat = y_hat + least_squares_x0(free_response(A, e1, dt, y.shape[1]), y - y_hat)[1]
    yinf_hat = sum(stationary_value_batch(*system) for system in systems) if gamma > 0 else None
    return y_hat, yinf_hat


def add_noise(y: torch.Tensor, y_bar: torch.Tensor, lo: float, hi: float,
              generator: torch.Generator) -> torch.Tensor:
    """White measurement noise for training: per record a level drawn uniformly from
    ``[lo, hi]``, std = level * ``y_bar`` (max|y| of the clean record).

    Parameters
    ----------
    y : (batch, steps) tensor
        Clean records.
    y_bar : (batch,) tensor
        Their ``max|y|``.
    lo, hi : float
        The level's range; ``hi <= 0``: no noise, ``y`` itself is returned.
    generator : torch.Generator
        Every draw.

    Returns
    -------
    (batch, steps) tensor
    """
    if hi <= 0:
        return y
    level = lo + (hi - lo) * torch.rand(len(y), generator=generator)
    return y + (level * y_bar)[:, None] * torch.randn(y.shape, generator=generator)


def theta(structure: Structure, systems: Systems, gain: np.ndarray | None) -> np.ndarray:
    """Raw parameters of the true systems as the encoder describes them.

    Parameters
    ----------
    structure : Structure
        Its ``theta_of``.
    systems : Systems
        ``N`` systems of one record.
    gain : (N,) array or None
        ``max|y| / max|u|`` per record for ``scale="denormalise"``, where the encoder describes
        the system from ``u / u_bar`` to ``y / y_bar`` (``c, d`` divided by it); None: as they
        are.

    Returns
    -------
    theta : (N, p) float64 array
    """
    elements = true_elements(structure, systems)
    if gain is None and elements is not None:
        return structure.raw(torch.from_numpy(elements)).numpy()
    c, d = systems.c, systems.d
    if gain is not None:
        c, d = c / gain[:, None], d / gain
    return np.asarray(structure.theta_of(systems.A, systems.b, c, d), dtype=np.float64)


def true_elements(structure: Structure, systems: Systems) -> np.ndarray | None:
    """The true elements of a physical structure without an inverse map, read from the
    family's parameters (``ParameterFamily`` keeps them; fixed elements at their values), or
    None where the structure recovers them from the models itself (``elements_of``).

    Parameters
    ----------
    structure : Structure
    systems : Systems

    Returns
    -------
    (N, q) float64 array or None
    """
    names, fixed = structure.element_names, structure.fixed_values
    if getattr(structure, "inverse", False) is not None or not all(
            name in systems.params or name in fixed for name in names):
        return None
    return np.stack([np.full(len(systems), fixed[k]) if k in fixed
                     else np.asarray(systems.params[k], np.float64) for k in names], 1)


def raw_statistics(structure: Structure, systems: Systems,
                   gain: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Centre and spread of the raw parameters of the family's systems, with which the
    network's outputs are standardised (knowledge of the parameter ranges, not of any label).

    Robust: the median and ``IQR / 1.349`` (the standard deviation for a normal distribution).
    Why not the mean and standard deviation: one near-degenerate system (two almost equal real
    poles of an MCF, with huge opposite residues) can dominate them; the median and IQR ignore
    such a tail.

    Parameters
    ----------
    structure, systems, gain
        As in ``theta``.

    Returns
    -------
    centre, scale : (p,) float64 arrays
    """
    values = theta(structure, systems, gain)
    centre = np.median(values, axis=0)
    q75, q25 = np.percentile(values, [75, 25], axis=0)
    scale = (q75 - q25) / 1.349
    tiny = 1e-8 * (1 + np.abs(centre))
    # a parameter that hardly varies over the IQR (e.g. a discrete spread): the std, else 1
    scale = np.where(scale > tiny, scale, values.std(axis=0))
    scale = np.where(scale > tiny, scale, 1.0)
    return centre, scale


def output_free(structure: Structure) -> bool:
    """Whether every output element ``c_i`` (and ``d``) may be rescaled; then the identifier
    de-normalises exactly (``scale="denormalise"``), else it reads the scale as a feature.

    Parameters
    ----------
    structure : Structure

    Returns
    -------
    bool
    """
    fixed = getattr(structure, "fixed_values", {}) or {}
    return all(v == 0.0 for k, v in fixed.items() if k.startswith("c") or k == "d")
