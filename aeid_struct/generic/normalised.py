"""A model of a record in normalised time (dt = 1): what the generic pipeline's stages hand
each other (:class:`Model`: the start builds it, the fit improves it, the result turns it into an
Estimate), and the two measures on it they share. Cut from the fit (``polish``) so that the
result stage reads it without going back into the fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeid_struct.generic.scoring import ccf
from aeid_struct.structures import CCF, MCF, Structure

__all__ = ["Model", "common_cost", "denominator_of", "feedthrough_of", "held_stable", "separable",
           "structure_of"]


def common_cost(m: Model, y: np.ndarray, first: int) -> float:
    """Mean squared residual of ``m`` on the samples from ``first`` on.

    Models at different delays fit different samples (``y[D:]``); per fitted sample, a longer
    delay wins by dropping the record's first samples, the hardest to fit mid-motion. Compared
    on common samples (``first`` >= every delay compared), they are compared fairly.

    Parameters
    ----------
    m : Model
    y : (steps,) array
    first : int

    Returns
    -------
    float
    """
    return float(np.mean((y[first:] - m.y_hat[first:]) ** 2))


def denominator_of(A: np.ndarray) -> np.ndarray:
    """The monic denominator of a bottom-row CCF ``A``.

    Parameters
    ----------
    A : (n, n) array

    Returns
    -------
    (n + 1,) array
        Highest power first.
    """
    return np.concatenate([[1.0], -A[-1, ::-1]])


@dataclass(frozen=True)
class Model:
    """A model of a record in NORMALISED time (dt = 1): ``A, b, c, d`` in some realisation,
    its state at sample ``delay``, offset, output and mean squared residual."""

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: float
    x0: np.ndarray
    y_offset: float
    delay: int
    y_hat: np.ndarray
    fit: float
    cost: float

    @classmethod
    def of_ccf(cls, den, p) -> Model:
        A, b = ccf(den)
        return cls(A, b, p.c, p.d, p.x0, p.y_offset, p.delay, p.y_hat, p.fit, p.cost)


def separable(structure) -> bool:
    """Whether the separable refinement (``refinement.refine_separable``) serves a structure
    spec (None, ``"ccf"``, ``"mcf"`` or a Structure): the free CCF and MCF.

    Parameters
    ----------
    structure : None, str or Structure

    Returns
    -------
    bool
    """
    if structure is None or structure in ("ccf", "mcf"):
        return True
    return isinstance(structure, (CCF, MCF)) and not structure.fixed_values


def held_stable(structure) -> bool:
    """Whether a structure spec holds its models stable by construction: the modal form
    (``"mcf"`` or an MCF, ``Re(eig) < 0``; ``stable=True`` of one channel).

    Parameters
    ----------
    structure : None, str or Structure

    Returns
    -------
    bool
    """
    return (isinstance(structure, str) and structure == "mcf") or isinstance(structure, MCF)


def feedthrough_of(structure) -> bool:
    """Whether a structure spec has a free feedthrough ``d`` (the default specs do).

    Parameters
    ----------
    structure : None, str or Structure

    Returns
    -------
    bool
    """
    if isinstance(structure, Structure):
        return "d" in structure.element_names and "d" not in structure.fixed_values
    return True


def structure_of(structure, order: int, den: np.ndarray) -> Structure:
    """The structure of the estimate a spec names at ``order`` (``"mcf"``: the real poles and
    pairs of the denominator ``den``; None or ``"ccf"``: the free CCF with a feedthrough).

    Parameters
    ----------
    structure : None, str or Structure
    order : int
    den : (order + 1,) array
        Monic denominator, highest power first.

    Returns
    -------
    Structure
    """
    if isinstance(structure, Structure):
        return structure
    if structure == "mcf":
        poles = np.roots(den)
        real = int(np.sum(np.abs(poles.imag) <= 1e-9 * np.abs(poles).max()))
        return MCF(real=real, pairs=(order - real) // 2, feedthrough=True)
    return CCF(order, feedthrough=True)
