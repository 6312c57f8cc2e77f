"""The calibrated training range: how far an estimate lies beyond it (``Estimate.excess``) and
whether it is flagged (``Estimate.outside``); the rule is in docs/architecture.md."""

from __future__ import annotations

import numpy as np

__all__ = ["FLAG_FALSE_RATE", "excess", "outside"]

#: The calibrated rule's false-flag budget per criterion (excess and fit) on held-out records
#: inside the training range: each threshold is that quantile of its statistic there.
FLAG_FALSE_RATE = 0.015


def excess(values: dict, rng: dict) -> np.ndarray:
    """How far element and parameter ``values`` lie beyond a training range, in units of the
    identifier's held-out error: ``max_q max(lo_q - v_q, v_q - hi_q, 0) / err_q``.

    Parameters
    ----------
    values : dict name -> float or (batch,) array
        The estimate's free elements and physical parameters.
    rng : dict
        A training range (``Identifier.training_range``): ``{"elements": {name: (lo, hi,
        err)}, "physical": {...}, ...}``. Quantities the family held constant (``hi - lo``
        within rounding of 0, the leg's ``c1 = 0``) are not compared.

    Returns
    -------
    float array shaped like the values
        0 inside the range, inf for a non-finite value.
    """
    shape = np.shape(np.asarray(next(iter(values.values()))))
    out = np.zeros(shape)
    for group in ("elements", "physical"):
        for name, (lo, hi, err) in rng.get(group, {}).items():
            if name not in values or not hi - lo > 1e-8 * max(abs(lo), abs(hi), 1e-300):
                continue          # held constant by the family (the leg's c1 = 0)
            v = np.asarray(values[name], dtype=np.float64)
            beyond = np.maximum(np.maximum(lo - v, v - hi), 0.0) / max(err, 1e-300)
            out = np.maximum(out, np.where(np.isfinite(v), beyond, np.inf))
    return out


def outside(excess_value, fit, rng: dict, records: int, good) -> np.ndarray:
    """The calibrated flag: ``excess`` above its threshold, or a fit (NRMSE %) below its own,
    or an undefined fit (NaN: a constant record, one set aside), or a record set aside.

    Parameters
    ----------
    excess_value : float or (batch,) array
    fit : float, (batch,), (R,) or (batch, R) array
        Per record; with several records (``records > 1``) any low record flags its system.
    rng : dict
        The training range with its thresholds ``"excess"`` and ``"fit"``.
    records : int
    good : (batch,) bool array or bool, or None
        The systems identified (``errors="collect"``); None when all were.

    Returns
    -------
    bool array shaped like ``excess_value``
    """
    fit = np.asarray(fit)
    # An undefined fit (NaN: a constant record, or one set aside by errors="collect") is no
    # evidence that the estimate is inside the range: flagged.
    low = (fit < rng["fit"]) | ~np.isfinite(fit)
    if records > 1:                    # (batch, R) or (R,): any record of the system
        low = np.any(low, axis=-1)
    value = np.asarray(excess_value)
    flags = (value > rng["excess"]) | ~np.isfinite(value) | low
    if good is not None:
        flags = flags | ~good
    return flags
