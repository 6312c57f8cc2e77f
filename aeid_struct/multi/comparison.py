r"""A several-channel model on a record (``ae.compare`` for several outputs or inputs): each
output's NRMSE fit with the initial state and the output offsets fitted, the model's ``A, B,
C, D`` kept.

    fit_i = 100 (1 - ||y_i - yhat_i|| / ||y_i - mean(y_i)||)   [%],

on the samples from the largest input delay on; ``overall`` is their mean.
"""

from __future__ import annotations

import numpy as np

from aeid_struct.multi.experiments import Experiments, check_delays
from aeid_struct.multi.realisation import project

__all__ = ["compare_channels"]


def compare_channels(A, B, C, D, record, delays) -> dict:
    """The fitted response of a model of several channels on one record.

    Parameters
    ----------
    A : (n, n) array
    B : (n, m) array
    C : (p, n) array
    D : (p, m) array
    record : Record
        With ``p`` outputs and ``m`` inputs.
    delays : int or (m,) ints
        Input delays in samples, >= 0.

    Returns
    -------
    dict
        ``fit (p,)``, ``y_hat (steps, p)`` (NaN before the largest delay), ``x0 (n,)``,
        ``y_offset (p,)``, ``delay (m,)`` (the delays checked).

    Raises
    ------
    ValueError
        Where the model's channels are not the record's, or for a bad delay.
    """
    A, B, C, D = (np.asarray(v, dtype=np.float64) for v in (A, B, C, D))
    n = A.shape[0]
    p, m = record.outputs, record.inputs
    if A.shape != (n, n) or B.shape != (n, m) or C.shape != (p, n) or D.shape != (p, m):
        raise ValueError(f"estimate_or_model must have the record's {p} output(s) and {m} "
                         f"input(s) (B ({n}, {m}), C ({p}, {n}), D ({p}, {m})); got B "
                         f"{B.shape}, C {C.shape}, D {D.shape}")
    if not all(np.all(np.isfinite(v)) for v in (A, B, C, D)):
        raise ValueError("the model (A, B, C, D) must be finite")
    ex = Experiments((record,), (record.Y,), (record.U,), (record.intersample,), record.dt,
                     np.zeros(p), np.ones(p), np.ones(m), None)
    delays = check_delays(delays, m)
    top = int(delays.max())
    if not 0 <= top <= record.steps - 2:
        raise ValueError(f"delay must be in [0, {record.steps - 2}] for this record; got "
                         f"{delays.tolist()}")
    with np.errstate(all="ignore"):
        proj = project(A, C, ex.aligned(delays), record.dt, ex.holds, B=B, D=D)
    Y = record.Y[top:]
    with np.errstate(all="ignore"):
        fit = 100.0 * (1.0 - np.linalg.norm(Y - proj.y_hat[0], axis=0)
                       / np.linalg.norm(Y - Y.mean(axis=0), axis=0))
    y_hat = np.full(record.Y.shape, np.nan)
    y_hat[top:] = proj.y_hat[0]
    return {"fit": fit, "y_hat": y_hat, "x0": proj.x0[0], "y_offset": proj.offset[0],
            "delay": delays}
