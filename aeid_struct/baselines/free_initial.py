r"""n4sid and least squares on a measured :class:`~aeid_struct.records.Record` that is not at rest.

The model of a record (docs/architecture.md, "Any system, any record"): the exact FOH response
(Eq. 10-13) of the input delayed by ``D`` samples, plus the free response of an initial state
``x0`` and a constant output offset. A known delay is applied first (``y[D:]`` against
``u[:N - D]``, ``Record.shifted``); an unknown one (``delay=None``) is taken as 0.

* :func:`n4sid_record`: the subspace method on the record as it is -- no zero padding, which
  would claim the record starts from rest -- with a constant second input channel (zero-order
  hold) whose feedthrough and state column absorb the output offset and the input level
  exactly; the continuous model by :func:`~aeid_struct.baselines.continuous.convert` from the
  input's column, then ``x0`` and the output offset by linear least squares for that model
  (:func:`aeid_struct.simulation.fit_initial`). Removing the means instead (``offset="mean"``)
  is biased: the mean of ``y`` is not the offset plus the stationary response to the mean
  input, since the transient has a mean of its own (``tests/test_baselines.py`` pins both).
* :func:`least_squares_record`: output error in CCF (``b = e_n``), free denominator ``a``; for
  each trial ``a`` the numerator ``c``, ``d``, ``x0`` and the offset come from one linear
  least-squares problem (variable projection, :func:`aeid_struct.simulation.project`), so
  ``scipy.optimize.least_squares`` searches only the ``n`` coefficients -- in normalised time,
  ``alpha_i = a_i dt^(n - i)`` (the denominator of ``A dt``), which keeps them O(1) over sample
  times. Started from the n4sid estimate (an ARX fit where n4sid fails), restarted from poles
  scaled by 1/3 and 3 when the fit stays below :data:`POOR_FIT`.

Both return the library's ``Estimate`` of the fitted samples with the fitted offset removed and
``initial="fitted"``, so that ``Estimate.fit`` equals ``info["fit"]``.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import scipy.optimize

from aeid_struct.baselines.checks import estimate, nan_model
from aeid_struct.baselines.continuous import NoRealLogarithm, convert
from aeid_struct.baselines.subspace_step import nfoursid_model
from aeid_struct.generic import arx
from aeid_struct.records import RecordBatch, Units
from aeid_struct.simulation import fit_initial, project
from aeid_struct.structures import ccf_matrices

__all__ = ["OFFSETS", "POOR_FIT", "least_squares_record", "n4sid_record"]

#: How :func:`n4sid_record` treats an unknown output offset.
OFFSETS = ("mean", "channel")
#: A least-squares fit (%) below which :func:`least_squares_record` tries its restarts.
POOR_FIT = 95.0


def _aligned(record):
    """``y, u`` of the fitted samples and the delay used (module docstring)."""
    delay = record.delay or 0
    return record.y[delay:], record.u[: record.steps - delay], delay


def _finish(model, elements, y, u, dt, start, info, projection):
    """The Estimate of the fitted samples without the offset, ``initial="fitted"``."""
    info = {**info, "x0": projection.x0, "y_offset": projection.y_offset,
            "fit": projection.fit, "cost": projection.cost}
    # copies: the Record's arrays are read-only, which torch (Estimate.fit) warns about
    est = estimate(model, elements, y - projection.y_offset, np.array(u), dt, start, info, None)
    return dataclasses.replace(est, provenance=dataclasses.replace(est.provenance,
                                                                  initial="fitted"))


def _failed(order, y, u, dt, start, info, reason):
    info = {**info, "failed": True, "reason": reason, "x0": np.full(order, np.nan),
            "y_offset": np.nan, "fit": np.nan}
    return estimate(nan_model(order), {}, np.array(y), np.array(u), dt, start, info, None)


def _subspace(y, u, dt, order, block_rows, offset, feedthrough, intersample="foh"):
    """The continuous model ``(A, b, c, d)`` of nfoursid on the record without padding, its
    input converted under the record's hold (``intersample``)."""
    if offset == "mean":
        channels, holds = [u - u.mean()], (intersample,)
        y = y - y.mean()
    else:    # a constant channel: its column absorbs the offset and the input level
        channels, holds = [u, np.ones_like(u)], (intersample, "zoh")
    Phi, B, C, D, sv = nfoursid_model(y, channels, order, block_rows, 0)
    model = convert(Phi, B[:, :1], C[0], D[0][:1], dt, holds[:1], feedthrough)
    return (model.A, model.b, model.c, model.d), (Phi, B, C, D), sv


def n4sid_record(record, *, order: int, feedthrough: bool = False,
                 block_rows: int | None = None, offset: str = "channel"):
    """n4sid on a record not at rest (:func:`_n4sid`: parameters, returns, raises), in the
    record's working units (``records.Units``: a level far above the variation removed, peaks
    far from 1 scaled by powers of two, the model taken back exactly; a ValueError where that
    model leaves float64)."""
    units = Units.of(record)
    return _restored(_n4sid(units.apply(record), order=order, feedthrough=feedthrough,
                            block_rows=block_rows, offset=offset), record, units)


def _n4sid(record, *, order: int, feedthrough: bool = False,
           block_rows: int | None = None, offset: str = "channel"):
    """n4sid on a record not at rest, with ``x0``, offset and known delay (module docstring).

    Parameters
    ----------
    record : Record
    order : int >= 1
    feedthrough : bool
        Estimate ``d`` (else 0).
    block_rows : int > order, optional
        Hankel block rows; default ``min(20, steps // 4)``, at least ``order + 1``.
    offset : {"channel", "mean"}
        Add a constant input channel (module docstring), or remove the means first.

    Returns
    -------
    Estimate
        ``info``: method, failed, reason, order, block_rows, offset, delay, discrete,
        singular_values, x0, y_offset, fit (NRMSE % with ``x0`` and offset fitted), cost.

    Raises
    ------
    ValueError
        For a bad ``offset`` or ``block_rows``, a record too short for them, or a constant
        ``y`` or ``u`` (``Record.require_informative``).
    """
    start = time.perf_counter()
    if offset not in OFFSETS:
        raise ValueError(f"offset must be one of {OFFSETS}; got {offset!r}")
    y, u, delay = _aligned(record)
    m = 1 if offset == "mean" else 2
    if block_rows is None:
        block_rows = max(order + 1, min(20, y.shape[0] // (2 * (m + 1))))
    elif block_rows <= order:
        raise ValueError(f"block_rows must be > order = {order}; got {block_rows}")
    need = 2 * block_rows * (m + 2) - 1
    if y.shape[0] < need:
        raise ValueError(f"record must have at least {need} samples after the delay for "
                         f"order={order}, block_rows={block_rows}; got {y.shape[0]}")
    record.require_informative()
    info = {"method": "n4sid", "failed": False, "reason": "", "order": order,
            "block_rows": block_rows, "pre_zeros": 0, "offset": offset, "delay": delay,
            "intersample": record.intersample}
    try:
        model, discrete, sv = _subspace(y, u, record.dt, order, block_rows, offset, feedthrough,
                                        record.intersample)
    except NoRealLogarithm as err:
        return _failed(order, y, u, record.dt, start, info, str(err))
    except (np.linalg.LinAlgError, ValueError) as err:
        return _failed(order, y, u, record.dt, start, info,
                       f"nfoursid failed: {type(err).__name__}: {err}")
    info |= {"discrete": dict(zip("Phi B C D".split(), discrete, strict=True)),
             "singular_values": sv}
    if not all(np.all(np.isfinite(v)) for v in model):
        return _failed(order, y, u, record.dt, start, info, "non-finite model")
    with np.errstate(all="ignore"):
        fitted = fit_initial(*model, y, u, record.dt, intersample=record.intersample)
    if not np.isfinite(fitted.fit):
        return _failed(order, y, u, record.dt, start, info, "the model's response overflows")
    return _finish(model, {}, y, u, record.dt, start, info, fitted)


def _ccf(alpha: np.ndarray, dt: float):
    """``A, b`` of the bottom-row CCF whose ``A dt`` has the denominator ``alpha``."""
    n = alpha.shape[0]
    A, b, _ = ccf_matrices((alpha / dt ** (n - np.arange(n)))[None], None)
    return A[0], b[0]


def _alpha_of_poles(poles: np.ndarray, dt: float) -> np.ndarray:
    """Normalised CCF coefficients ``alpha_0 .. alpha_{n-1}`` of continuous poles."""
    return np.real(np.poly(np.asarray(poles) * dt))[1:][::-1].copy()


def _arx_poles(y, u, order: int, dt: float) -> np.ndarray:
    """Continuous poles of a least-squares ARX model with a constant (the start where n4sid
    fails); a discrete pole on the negative real axis is taken by its modulus."""
    z = np.roots(arx(y, u, order))
    z = np.where((np.abs(z.imag) < 1e-12) & (z.real <= 0), np.abs(z) + 1e-12, z)
    return np.log(z.astype(complex)) / dt


def _fit_poles(y, u, dt, alpha0, feedthrough, max_nfev, intersample="foh"):
    """Variable-projection output error from the normalised coefficients ``alpha0`` (the input
    under the record's hold, ``intersample``)."""
    scale = 1.0 / max(float(np.max(np.abs(y - y.mean()))), 1e-300)

    def residual(alpha):
        A, b = _ccf(alpha, dt)
        with np.errstate(all="ignore"):
            p = project(A, b, y, u, dt, feedthrough=feedthrough, intersample=intersample)
        r = (p.y_hat - y) * scale
        return r if np.all(np.isfinite(r)) else np.full(y.shape, 1e8)

    result = scipy.optimize.least_squares(residual, alpha0, method="lm", x_scale="jac",
                                          xtol=1e-14, ftol=1e-14, gtol=1e-14,
                                          max_nfev=max_nfev)
    A, b = _ccf(result.x, dt)
    return result, project(A, b, y, u, dt, feedthrough=feedthrough, intersample=intersample)


def least_squares_record(record, *, order: int, feedthrough: bool = False,
                         max_nfev: int = 400):
    """Output-error least squares in CCF on a record not at rest (:func:`_least_squares`:
    parameters, returns, raises), in the record's working units (as :func:`n4sid_record`)."""
    units = Units.of(record)
    return _restored(_least_squares(units.apply(record), order=order, feedthrough=feedthrough,
                                    max_nfev=max_nfev), record, units)


def _restored(est, record, units):
    """The estimate of ``units.apply(record)`` for ``record`` itself (``Units.linear``); the
    estimate's record is the fitted samples without the offset, as ``_finish`` makes it."""
    if units.identity:
        return est
    y, u, _ = _aligned(record)
    if est.info.get("failed"):
        return dataclasses.replace(est, record=_record(y, u, est.dt))
    c, d, elements, info = units.estimate(est.A, est.b, est.c, est.d, est.elements, est.info)
    return dataclasses.replace(est, c=c, d=np.float64(d), elements=elements, info=info,
                               record=_record(y - info["y_offset"], u, est.dt))


def _record(y, u, dt: float) -> RecordBatch:
    """The estimate's record of the fitted samples (copies: the Record's arrays are read-only,
    which torch, through ``Estimate.fit``, warns about)."""
    return RecordBatch.of(np.array(y), np.array(u), dt, batched=False)


def _least_squares(record, *, order: int, feedthrough: bool = False, max_nfev: int = 400):
    """Output-error least squares in CCF on a record not at rest (module docstring).

    Parameters
    ----------
    record : Record
    order : int >= 1
    feedthrough : bool
        Estimate ``d`` (else 0).
    max_nfev : int >= 1
        Residual evaluations per solver run.

    Returns
    -------
    Estimate
        In CCF (``b = e_n``), elements ``a0 .. a_{n-1}, c0 .. c_{n-1}`` (and ``d``). ``info``:
        method, failed, reason, order, delay, start ("n4sid" or "arx"), restarts, nfev, x0,
        y_offset, fit (NRMSE % with ``x0`` and offset fitted), cost.

    Raises
    ------
    ValueError
        For a record with fewer fitted samples than parameters, or a constant ``y`` or ``u``
        (``Record.require_informative``).
    """
    start = time.perf_counter()
    y, u, delay = _aligned(record)
    dt = record.dt
    if y.shape[0] < 3 * order + 3:
        raise ValueError(f"record must have at least {3 * order + 3} samples after the delay "
                         f"for order={order} (denominator, numerator, x0, offset); got "
                         f"{y.shape[0]}")
    record.require_informative()
    info = {"method": "least_squares", "failed": False, "reason": "", "order": order,
            "delay": delay, "start": "n4sid", "intersample": record.intersample}
    try:
        sub = n4sid_record(record, order=order, feedthrough=feedthrough)
        ok = not sub.info["failed"]
    except ValueError:      # a record too short for the subspace method's Hankel matrices
        ok = False
    poles = np.linalg.eigvals(sub.A) if ok else _arx_poles(y, u, order, dt)
    info["start"] = "n4sid" if ok else "arx"
    best, nfev, restarts = None, 0, 0
    for factor in (1.0, 1.0 / 3.0, 3.0):
        if best is not None:
            if best[1].fit >= POOR_FIT:
                break
            restarts += 1
        try:
            result, fitted = _fit_poles(y, u, dt, _alpha_of_poles(poles * factor, dt),
                                        feedthrough, max_nfev, record.intersample)
        except (ValueError, np.linalg.LinAlgError):
            continue
        nfev += int(result.nfev)
        if np.isfinite(fitted.fit) and (best is None or fitted.fit > best[1].fit):
            best = (result.x, fitted)
    info |= {"restarts": restarts, "nfev": nfev}
    if best is None:
        return _failed(order, y, u, dt, start, info, "least squares found no finite model")
    alpha, fitted = best
    A, b = _ccf(alpha, dt)
    model = (A, b, fitted.c, fitted.d if feedthrough else 0.0)
    names = [f"a{i}" for i in range(order)] + [f"c{i}" for i in range(order)]
    values = list(-A[-1]) + list(fitted.c) + ([fitted.d] if feedthrough else [])
    elements = dict(zip(names + ["d"] * feedthrough, map(float, values), strict=True))
    return _finish(model, elements, y, u, dt, start, info, fitted)
