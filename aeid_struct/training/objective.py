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
    loss,
    normalise,
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
    total = 0.0
    for r in range(R):
        A, b, c, d = (x[:, r] for x in sys) if R > 1 else sys
        if ident.initial == "fitted":
            y_hat = fit_initial_state(A, b, c, d, us[r], ys[r], dts[r])[1]
        else:
            y_hat = simulate_batch(A, b, c, d, us[r], dts[r], None)
        yinf_hat = stationary_value_batch(A, b, c, d) if gamma > 0 else None
        if not bool(torch.isfinite(y_hat).all()) or (
                yinf_hat is not None and not bool(torch.isfinite(yinf_hat).all())):
            # overflowed: a skipped batch
            return torch.full((), math.nan, dtype=y_hat.dtype, device=y_hat.device)
        y_bar = record_scale(ys[r])
        yinf_r = yinf[:, r] if R > 1 else yinf
        total = total + loss(normalise(y_hat, y_bar), normalise(ys[r], y_bar),
                             None if yinf_hat is None else normalise(yinf_hat, y_bar),
                             None if yinf_hat is None else normalise(yinf_r, y_bar), gamma=gamma)
    total = total / R
    if weight > 0:
        total = total + weight * torch.mean((raw - z.to(raw.dtype)) ** 2)
    return total


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
