"""The result stage of the generic pipeline: a normalised-time :class:`~aeid_struct.generic.
normalised.Model` in the user's structure and time unit (:func:`estimate_of`), and the record's
units taken back (:func:`restore`). The last stage of ``ae.identify``'s walk: the check
(``boundary``), the start (``delay``, ``windows``, ``scoring``), the fit (``polish``), then this
module, each entered once.
"""

from __future__ import annotations

import numpy as np
import torch

from aeid_struct.generic.normalised import Model
from aeid_struct.generic.scoring import ccf
from aeid_struct.identification import Estimate, Provenance
from aeid_struct.records import Record, Units
from aeid_struct.simulation import fit_initial
from aeid_struct.structures import CCF, Structure

__all__ = ["controllability", "estimate_of", "in_structure", "restore"]


def estimate_of(m: Model, structure: Structure, data, seconds: float, refined: bool,
            info: dict) -> Estimate:
    """The Estimate of a normalised-time model in physical time and in ``structure``:
    ``A / dt, b / dt``, the same ``c, d``, the state transformed (:func:`in_structure`).

    Parameters
    ----------
    m : Model
        In normalised time (dt = 1).
    structure : Structure
    data : Record
        The record ``m`` was fitted to (its ``dt``).
    seconds : float
    refined : bool
    info : dict
        The pipeline's diagnostics; ``delay, x0, y_offset, fit, y_hat, cost`` and the record's
        ``intersample`` are added.

    Returns
    -------
    Estimate
    """
    dt = data.dt
    A, b, c, d, x0, elements = in_structure(structure, m, dt)
    y_offset, fit, y_hat, cost = m.y_offset, m.fit, m.y_hat, m.cost
    if not _free_ccf(structure):
        # elements_of gives the closest model the structure admits, not this one (a fixed
        # element the data contradict moves it): the initial state, offset, output and
        # fit are the returned model's own
        with np.errstate(all="ignore"):
            p = fit_initial(A, b, c, d, data.y, data.u, dt, delay=m.delay, offset=True,
                            intersample=data.intersample)
        x0, y_offset, fit, y_hat, cost = p.x0, p.y_offset, p.fit, p.y_hat, p.cost
    info = {**info, "delay": m.delay, "x0": x0, "y_offset": y_offset,
            "fit": fit, "y_hat": y_hat, "cost": cost, "intersample": data.intersample}
    return Estimate(A=A, b=b, c=c, d=d, elements=elements, record=data,
                    provenance=Provenance(structure=structure, initial="fitted"),
                    seconds=seconds, refined=refined, info=info)


def _free_ccf(structure: Structure) -> bool:
    """The structure :func:`in_structure` converts exactly: the free CCF with a feedthrough."""
    return isinstance(structure, CCF) and not structure.fixed_values and structure.feedthrough


def in_structure(structure: Structure, m: Model, dt: float):
    """``A, b, c, d, x0, elements`` of the physical-time model ``(A_n / dt, b_n / dt, c, d)``
    in ``structure``'s realisation (the state transformed with it, ``x = T x_n``: for the free
    CCF the exact diagonal ``T = diag(dt^(n-i))``, else ``T = C_s C_n^-1`` from the
    controllability matrices)."""
    A, b = m.A / dt, m.b / dt
    n = A.shape[0]
    if _free_ccf(structure):
        # m.A is a CCF in normalised time (the projection's, or refined in CCF): its
        # coefficients in physical time are a_i / dt^(n-i), no torch needed
        den = np.concatenate([[1.0], -m.A[-1, ::-1]]) / dt ** np.arange(n + 1)
        As, bs = ccf(den)
        # the state in physical time is z_i = dt^(n-i) x_i (i = 0..n-1): z_(i+1) = dz_i/dt
        # and b = e_n hold exactly. Diagonal, so exact where the controllability matrices of a
        # stiff model (a pole at -1e5 per sample) are singular to working precision: their
        # T = C_s C_n^-1 gave a c whose fit was -1e6 % for a model that fits 90 %.
        T = dt ** (n - np.arange(n, dtype=np.float64))
        cs = m.c / T
        values = np.concatenate([den[:0:-1], cs, [m.d]])
        names = [f"a{i}" for i in range(n)] + [f"c{i}" for i in range(n)] + ["d"]
        return As, bs, cs, m.d, T * m.x0, dict(zip(names, values.tolist(), strict=True))
    x = structure.elements_of(A, b, m.c, m.d, strict=False).to(torch.float64)
    s = structure.assemble(x)
    As, bs, cs = (t.numpy() for t in (s.A, s.b, s.c))
    T = controllability(As, bs) @ np.linalg.inv(controllability(A, b))
    elements = dict(zip(structure.element_names, x.tolist(), strict=True))
    return As, bs, cs, float(s.d), T @ m.x0, elements


def controllability(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    cols = [b]
    for _ in range(A.shape[0] - 1):
        cols.append(A @ cols[-1])
    return np.stack(cols, axis=1)


def restore(units: Units, est: Estimate, data: Record) -> Estimate:
    """The estimate of ``units.apply(data)`` for ``data`` itself (``Units.estimate``; why the
    units are exact: ``records.units``).

    Parameters
    ----------
    units : Units
    est : Estimate
        Of the record in these units.
    data : Record
        The user's record.

    Returns
    -------
    Estimate

    Raises
    ------
    ValueError
        Where that model leaves float64.
    """
    if units.identity:
        return est
    c, d, elements, info = units.estimate(est.A, est.b, est.c, est.d, est.elements, est.info)
    return Estimate(A=est.A, b=est.b, c=c, d=d, elements=elements, record=data,
                    provenance=est.provenance, seconds=est.seconds,
                    refined=est.refined, info=info)
