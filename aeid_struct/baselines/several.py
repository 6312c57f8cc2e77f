r"""The classical baselines for several inputs and outputs (and, for least squares, several
experiments), so that ``ae.identify``'s model of such records is compared on equal terms.

* :func:`n4sid_channels`: nfoursid's PO-MOESP/N4SID on all outputs and inputs at once, with a
  constant input channel under a zero-order hold (it absorbs the outputs' offsets and the
  inputs' levels, as ``free_initial``'s one-channel form), converted exactly to continuous time
  under each record's hold: ``A = logm(Phi) / dt``, then per input ``B_d[:, j] = (Gamma_1 -
  Gamma_2 + Phi Gamma_2) B[:, j]`` (first-order hold; ``Gamma_1`` alone for a held input) and
  ``D = D_d - C Gamma_2 B``. The initial state and offsets are then fitted by least squares
  (``multi.compare_channels``). Known input delays are applied; none are estimated.
* :func:`least_squares_channels`: the output-error fit of ``multi`` (variable projection in
  the observer form) started from n4sid's poles, or from the common-denominator ARX where
  n4sid fails: the classical route to the same optimum, without the encoders' candidates or
  the Steiglitz-McBride start.
"""

from __future__ import annotations

import math
import time

import numpy as np

from aeid_struct.baselines.continuous import NoRealLogarithm, hold_matrices, logm_real
from aeid_struct.baselines.subspace_step import nfoursid_model
from aeid_struct.identification import Estimate
from aeid_struct.multi import compare_channels, experiments_of, fit_from_poles, packed
from aeid_struct.records import Record

__all__ = ["least_squares_channels", "n4sid_channels"]


def _nan_estimate(record, order: int, info: dict, seconds: float) -> Estimate:
    """A failed baseline's Estimate: NaN model, the reason in ``info``."""
    p, m = record.outputs, record.inputs
    nan = {"A": np.full((order, order), math.nan), "B": np.full((order, m), math.nan),
           "C": np.full((p, order), math.nan), "D": np.full((p, m), math.nan),
           "x0": (np.full(order, math.nan),), "offset": (np.full(p, math.nan),),
           "y_hat": (np.full(record.Y.shape, math.nan),)}
    return packed(nan, (record,), np.zeros(m, dtype=int), False, {**info, "failed": True},
                  seconds)


def n4sid_channels(record, *, order: int, block_rows: int | None = None) -> Estimate:
    """n4sid on a record of several outputs and inputs (module docstring).

    Parameters
    ----------
    record : Record
    order : int, >= 1
    block_rows : int > order, optional
        Default ``min(20, (steps + 1) // (2 (m + 3)))``, at least ``order + 1``.

    Returns
    -------
    Estimate
        ``B, C, D`` as in ``ae.identify``'s estimate of such a record; ``info``: method,
        failed, reason, order, block_rows, delay, fit per output. A failure (no real
        logarithm, nfoursid's error, a non-finite model) is a NaN model with the reason.

    Raises
    ------
    ValueError
        For a record too short for ``block_rows``.
    """
    began = time.perf_counter()
    ex = experiments_of(record, what="n4sid")
    m = ex.inputs
    delays = np.zeros(m, dtype=int) if ex.delay is None else ex.delay
    (Y, U), = ex.aligned(delays)
    # m inputs and the constant channel: nfoursid's QR needs 2 block_rows (m + 3) - 1 samples,
    # so the default takes the most block rows (up to 20) that the record holds
    need_per_row = 2 * (m + 3)
    if block_rows is None:
        block_rows = max(order + 1, min(20, (Y.shape[0] + 1) // need_per_row))
    need = need_per_row * block_rows - 1
    if Y.shape[0] < need:
        raise ValueError(f"record must have at least {need} samples after the delay for "
                         f"order={order}, block_rows={block_rows}; got {Y.shape[0]}")
    info = {"method": "n4sid", "failed": False, "reason": "", "order": order,
            "block_rows": block_rows}
    hold = record.intersample
    try:
        channels = [*U.T, np.ones(Y.shape[0])]
        Phi, Bd, C, Dd, _ = nfoursid_model(Y, channels, order, block_rows, 0)
        A = logm_real(Phi, 1.0)
        Phi_c, G1, G2 = hold_matrices(A, 1.0)
        column = G1 if hold == "zoh" else G1 - G2 + Phi_c @ G2
        B = np.linalg.solve(column, Bd[:, :m])
        D = Dd[:, :m] - (C @ G2 @ B if hold == "foh" else 0.0)
    except NoRealLogarithm as err:
        return _nan_estimate(record, order, {**info, "reason": str(err)},
                             time.perf_counter() - began)
    except (np.linalg.LinAlgError, ValueError) as err:
        return _nan_estimate(record, order, {**info, "reason": f"nfoursid failed: "
                                             f"{type(err).__name__}: {err}"},
                             time.perf_counter() - began)
    g = 1.0 / ex.dt
    model = {"A": A * g, "B": B * g / ex.u_scale[None, :], "C": ex.y_scale[:, None] * C,
             "D": ex.y_scale[:, None] * D / ex.u_scale[None, :]}
    if not all(np.all(np.isfinite(v)) for v in model.values()):
        return _nan_estimate(record, order, {**info, "reason": "non-finite model"},
                             time.perf_counter() - began)
    out = compare_channels(model["A"], model["B"], model["C"], model["D"], record, delays)
    model |= {"x0": (out["x0"],), "offset": (out["y_offset"],), "y_hat": (out["y_hat"],)}
    return packed(model, (record,), delays, False, info, time.perf_counter() - began)


def least_squares_channels(record, *, order: int) -> Estimate:
    """Output-error least squares for several channels or experiments (module docstring).

    Parameters
    ----------
    record : Record or list of Record
    order : int, >= 1

    Returns
    -------
    Estimate
        As ``ae.identify``'s; ``info["start"]`` is ``"n4sid"`` or ``"arx"``.
    """
    poles, origin = None, "arx"
    if isinstance(record, Record):
        try:
            sub = n4sid_channels(record, order=order)
        except ValueError:
            sub = None
        if sub is not None and not sub.info["failed"]:
            poles, origin = np.linalg.eigvals(sub.A) * record.dt, "n4sid"
    info = {"method": "least_squares", "failed": False, "reason": "", "order": order}
    return fit_from_poles(record, order, poles, origin=origin, info=info)
