"""The benchmark's failure rule for any estimate, the encoder's included.

An estimate fails when the method reported a failure, its model is not finite, it violates the
structure, a physical parameter is not positive, or its unit-step response is further than a
Table I step error of ``step_tol`` (0.05) from the true one.
"""

from __future__ import annotations

import warnings

import numpy as np

from aeid_struct.identification import Estimate
from aeid_struct.records import as_array, unit_step
from aeid_struct.simulation import OverflowWarning, simulate

__all__ = ["failed", "failure"]


def failure(estimate: Estimate, *, structure=None, truth_y=None, step_tol: float = 0.05):
    """Why an estimate counts as a failure, or ``""`` when it does not.

    In this order: the method reported a failure (``info["failed"]``, e.g. a negative real
    discrete pole, an exception); the model is not finite; it violates ``structure`` (when
    given: fixed elements, Descartes, bounds, via ``structure.elements_of(strict=True)``); a
    physical parameter (``Estimate.physical``) is non-finite or not positive; its unit-step
    response (Eq. 10-13, :func:`aeid_struct.simulation.simulate`) differs from ``truth_y`` by a
    Table I step error above ``step_tol``.

    Parameters
    ----------
    estimate : Estimate
        Single or batched (from any method, the encoder's included).
    structure : Structure, optional
    truth_y : (steps,) or (batch, steps), optional
        The true system's unit-step response on the estimate's grid ``k dt``.
    step_tol : float
        The benchmark's threshold, 0.05.

    Returns
    -------
    str for a single estimate, a list of str for a batched one.

    Raises
    ------
    ValueError
        For an ``estimate`` that is not an Estimate, a bad ``step_tol`` or ``truth_y``.
    """
    if not isinstance(estimate, Estimate):
        raise ValueError(f"estimate must be an Estimate; got {type(estimate).__name__}")
    if not (isinstance(step_tol, (int, float)) and step_tol > 0):
        raise ValueError(f"step_tol must be a positive number; got {step_tol!r}")
    count = estimate.A.shape[0] if estimate.batched else 1
    truth = None
    if truth_y is not None:
        truth = np.atleast_2d(as_array("truth_y", truth_y))
        if truth.ndim != 2 or truth.shape[0] != count or not np.all(np.isfinite(truth)):
            raise ValueError(f"truth_y must be finite with shape (steps,) or ({count}, steps) "
                             f"for this estimate; got {np.shape(truth_y)}")
    A = np.asarray(estimate.A, dtype=np.float64).reshape(count, *estimate.A.shape[-2:])
    n = A.shape[-1]
    b = np.asarray(estimate.b, dtype=np.float64).reshape(count, n)
    c = np.asarray(estimate.c, dtype=np.float64).reshape(count, n)
    d = np.asarray(estimate.d, dtype=np.float64).reshape(count)
    info = estimate.info or {}
    physical = {}
    finite = all(np.all(np.isfinite(m)) for m in (A, b, c, d))
    if not info.get("failed") and finite:
        try:
            physical = {k: np.reshape(v, count) for k, v in estimate.physical.items()}
        except Exception as err:  # a CasADi inverse that cannot evaluate this model
            physical = {"<inverse>": np.full(count, np.nan)}
            info = {**info, "inverse_error": str(err)}
    reasons = []
    for i in range(count):
        reasons.append(_failure_one(A[i], b[i], c[i], d[i], info, structure,
                                    {k: v[i] for k, v in physical.items()},
                                    None if truth is None else truth[i], estimate.dt, step_tol))
    return reasons if estimate.batched else reasons[0]


def _failure_one(A, b, c, d, info, structure, physical, truth, dt, step_tol) -> str:
    from aeid_struct.metrics import step_error

    if info.get("failed"):
        return info.get("reason") or "the method failed"
    if not all(np.all(np.isfinite(m)) for m in (A, b, c, d)):
        return "non-finite model"
    if structure is not None:
        try:
            structure.elements_of(A, b, c, d, strict=True)
        except ValueError as err:
            return f"outside the structure: {err}"
    for name, v in physical.items():
        if not (np.isfinite(v) and v > 0):
            return f"physical parameter {name} = {float(v):.6g} is not positive"
    if truth is not None:
        with warnings.catch_warnings():
            # an overflowing step response is +inf, and a failure here, not a warning
            warnings.simplefilter("ignore", OverflowWarning)
            y_hat = simulate(A, b, c, d, unit_step(truth.shape[0]), dt)
        if not np.all(np.isfinite(y_hat)):
            return "step response not finite"
        err = float(step_error(truth, y_hat)[0])
        if not err <= step_tol:
            return f"step error {err:.3g} > {step_tol:g}"
    return ""


def failed(estimate: Estimate, *, structure=None, truth_y=None, step_tol: float = 0.05):
    """``bool(failure(...))``: whether an estimate counts as a failure.

    Parameters
    ----------
    estimate : Estimate
        Single or batched.
    structure : Structure, optional
    truth_y : (steps,) or (batch, steps), optional
    step_tol : float
        As in :func:`failure`.

    Returns
    -------
    bool for a single estimate, a ``(batch,)`` bool array for a batch.
    """
    why = failure(estimate, structure=structure, truth_y=truth_y, step_tol=step_tol)
    return bool(why) if isinstance(why, str) else np.array([bool(w) for w in why])
