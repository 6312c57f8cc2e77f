r"""The objective of a generic identifier's training by variable projection: per window, the share
of the output variance that the encoder's poles leave unexplained once least squares has fitted
the rest of the model. A module apart from the run (``training.generic``), as
``training.objective`` is apart from ``train()``: this is the method's maths (paper Eq. 5 and a
linear least-squares fit), the run is bookkeeping (batches, budget, checkpoints, processes).

Per window (normalised as at identification, :func:`~aeid_struct.generic.normalise_windows`) the
encoder's denominator fixes ``(A, b)`` (CCF, paper Eq. 5) and
:func:`~aeid_struct.simulation.project_batch` fits ``c``, ``d``, the initial state and the output
offset exactly; the loss is the unexplained share of the window's output variance,
``e = ||y - y_hat||^2 / ||y - mean y||^2`` (``1 - R^2``), as ``log(e + eps)`` (``loss="log"``, the
default: windows whose best fit is 99.9 % and windows whose best fit is 60 % weigh alike, so the
easy majority does not drown the hard ones) or as ``e`` itself (``loss="nmse"``).
"""

from __future__ import annotations

import math

import torch

from aeid_struct.generic import GenericIdentifier
from aeid_struct.simulation import project_batch

__all__ = ["EPS", "LOSSES", "reduce_loss", "window_loss"]

#: The per-window losses ``GenericTrainConfig.loss`` may name: ``log(e + EPS)`` or ``e``.
LOSSES = ("log", "nmse")
#: Floor of ``e`` inside the log loss: a fit of 99.99 % counts as perfect.
EPS = 1e-8


def window_loss(ident: GenericIdentifier, y: torch.Tensor, u: torch.Tensor):
    """The unexplained output variance ``e = 1 - R^2`` of each window under the encoder's poles
    with the rest of the model projected (differentiable).

    Parameters
    ----------
    ident : GenericIdentifier
    y, u : (batch, window) float64 tensors
        Normalised windows (:func:`~aeid_struct.generic.normalise_windows`).

    Returns
    -------
    e : (batch,) float64 tensor
        All NaN where the encoder gives non-finite poles (weights gone non-finite): the batch
        is skipped.
    """
    w, zeta = ident.factors_batch(y, u)
    if not bool(torch.isfinite(w).all() and torch.isfinite(zeta).all()):
        return torch.full_like(y[:, 0], math.nan)
    A, b = ident.companion(w, zeta)
    r = project_batch(A, b, y, u).residual
    centred = y - y.mean(dim=1, keepdim=True)
    return (r ** 2).sum(dim=1) / (centred ** 2).sum(dim=1)


def reduce_loss(e: torch.Tensor, kind: str) -> torch.Tensor:
    """The loss of a set of windows: the mean of ``log(e + EPS)`` (``kind="log"``) or of ``e``.

    Parameters
    ----------
    e : (batch,) float64 tensor
        The windows' ``1 - R^2`` (:func:`window_loss`).
    kind : {"log", "nmse"}
        One of :data:`LOSSES`.

    Returns
    -------
    torch.Tensor
        The scalar mean.
    """
    return torch.log(e + EPS).mean() if kind == "log" else e.mean()
