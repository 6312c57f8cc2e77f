r"""MATLAB's ``compare``: a model's NRMSE fit on a record with the initial state (and the output
offset) fitted, and the figure of measured vs simulated output.

For a model ``(A, b, c, d)`` and a record with input delay ``D`` (docs/architecture.md, "Any
system, any record"), ``x_0`` (the state at sample ``D``) and ``y_offset`` minimise
``||y[D:] - yhat||`` (:func:`~aeid_struct.simulation.fit_initial`, exact under the record's
hold: first order, Eq. 10-13, or zero order for ``Record(..., intersample="zoh")``), and

    fit = 100 (1 - ||y[D:] - yhat|| / ||y[D:] - mean(y[D:])||)   [%].
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import control
import numpy as np

from aeid_struct.generic.boundary import measured
from aeid_struct.multi import compare_channels
from aeid_struct.records import Record, Units
from aeid_struct.simulation import fit_initial
from aeid_struct.threads import one_thread

__all__ = ["Comparison", "compare"]


@dataclass(frozen=True)
class Comparison:
    """A model's output on a record next to the measured one (:func:`compare`).

    Attributes
    ----------
    fit : float or (p,) array
        NRMSE fit in % on the fitted samples (NaN for a constant record); per output for a
        record of several (:attr:`overall`: their mean).
    y_hat : (steps,) or (steps, p) array
        The model's output (NaN on the first ``delay`` samples).
    x0 : (n,) array
        The fitted state at sample ``delay``.
    y_offset : float or (p,) array
        The fitted output offset(s).
    y : (steps,) or (steps, p) array
        The measured output.
    t : (steps,) array
        Sample times ``t0 + k dt``.
    delay : int or (m,) ints
        Input delay in samples (per input for several).
    """

    fit: float
    y_hat: np.ndarray
    x0: np.ndarray
    y_offset: float
    y: np.ndarray
    t: np.ndarray
    delay: int

    @property
    def overall(self) -> float:
        """The mean of the outputs' fits (the fit itself for one output)."""
        return float(np.mean(self.fit))

    def __repr__(self) -> str:
        if np.ndim(self.fit):
            return (f"Comparison(fit={np.round(self.fit, 2).tolist()} % (overall "
                    f"{self.overall:.2f} %), steps={self.y.shape[0]}, "
                    f"delay={np.ravel(self.delay).tolist()})")
        return (f"Comparison(fit={self.fit:.2f} %, steps={self.y.shape[0]}, delay={self.delay}, "
                f"y_offset={self.y_offset:.4g})")

    def figure(self, path=None, *, y_label: str = "y", time_unit: str = "s",
               title: str | None = None):
        """Measured and simulated output over time, the fit in the legend.

        Parameters
        ----------
        path : str or path-like, optional
            Where to save the figure as PNG.
        y_label : str
            The output's name and unit, e.g. ``"temperature [K]"``.
        time_unit : str
            The unit of ``t`` (the record's ``dt``).
        title : str, optional

        Returns
        -------
        matplotlib.figure.Figure
        """
        from matplotlib.figure import Figure  # noqa: PLC0415 (matplotlib only for figures)

        Y, Y_hat = self.y.reshape(len(self.t), -1), self.y_hat.reshape(len(self.t), -1)
        p = Y.shape[1]
        fig = Figure(figsize=(7.0, 3.2 if p == 1 else 2.2 * p), layout="constrained")
        axes = np.atleast_1d(fig.subplots(p, 1, sharex=True, squeeze=False)[:, 0])
        for i, ax in enumerate(axes):
            fit = float(np.ravel(self.fit)[i])
            ax.plot(self.t, Y[:, i], color="0.6", lw=1.0, label="measured")
            ax.plot(self.t, Y_hat[:, i], color="C0", lw=1.2, label=f"model (fit {fit:.2f} %)")
            ax.set_ylabel(y_label if p == 1 else f"{y_label}[{i}]")
            ax.legend(loc="best")
        axes[-1].set_xlabel(f"time [{time_unit}]")
        if title:
            axes[0].set_title(title)
        if path is not None:
            fig.savefig(path, format="png", dpi=120)
        return fig


def _model(model):
    """``A, b, c, d``, the delay (or None) and its sample time (or None) of an Estimate, a
    continuous-time python-control system or a tuple ``(A, b, c, d)``."""
    if isinstance(model, control.LTI):
        if control.isdtime(model, strict=True):
            raise ValueError(f"estimate_or_model is a discrete-time system (dt = {model.dt}); "
                             f"compare simulates continuous-time models (the record's input "
                             f"held between samples): give the continuous model it was "
                             f"discretised from (e.g. aeid_struct.baselines.to_continuous)")
        model = control.ss(model) if isinstance(model, control.TransferFunction) else model
    if isinstance(model, (tuple, list)) and len(model) == 4:
        A, b, c, d = model
        delay = step = None
    elif all(hasattr(model, k) for k in ("A", "b", "c", "d")):        # Estimate
        A, b, c, d = model.A, model.b, model.c, model.d
        delay, step = getattr(model, "delay", None), getattr(model, "dt", None)
    elif all(hasattr(model, k) for k in ("A", "B", "C", "D")):       # control.StateSpace
        A, b, c, d = model.A, model.B, model.C, model.D
        delay = step = None
    else:
        raise ValueError(f"estimate_or_model must be an Estimate, a continuous-time "
                         f"control.StateSpace or TransferFunction, or a tuple (A, b, c, d); "
                         f"got {type(model).__name__}")
    A = np.asarray(A, dtype=np.float64)
    if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] < 1:
        raise ValueError(f"A must be a square (n, n) matrix of one model; got shape {A.shape}")
    n = A.shape[0]
    b, c = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (b, c))
    d = np.asarray(d, dtype=np.float64).reshape(-1)
    if b.shape != (n,) or c.shape != (n,) or d.shape != (1,):
        raise ValueError(f"b, c must have n = {n} entries and d one (a SISO model); got "
                         f"{b.shape[0]}, {c.shape[0]} and {d.shape[0]}")
    if not all(np.isfinite(v).all() for v in (A, b, c, d)):
        raise ValueError("the model (A, b, c, d) must be finite")
    return A, b, c, float(d[0]), delay, step


def _channels(model, record) -> bool:
    """Whether the comparison is of several outputs or inputs."""
    if isinstance(record, Record) and (record.outputs > 1 or record.inputs > 1):
        return True
    if isinstance(model, control.LTI):
        return model.ninputs > 1 or model.noutputs > 1
    if hasattr(model, "B") and hasattr(model, "A") and hasattr(model, "b"):   # Estimate
        return np.shape(model.B)[-1] > 1 or np.shape(model.C)[-2] > 1
    return False


def _compare_channels(model, record, delay) -> Comparison:
    """:func:`compare` of several outputs or inputs (``multi.compare_channels``)."""
    if not isinstance(record, Record):
        raise ValueError(f"record must be an ae.Record for a model of several outputs or "
                         f"inputs; got {type(record).__name__}")
    if isinstance(model, control.LTI):
        if control.isdtime(model, strict=True):
            raise ValueError("estimate_or_model must be a continuous-time system")
        model = control.ss(model)
        model_delay = step = None
    elif all(hasattr(model, k) for k in ("A", "B", "C", "D")):
        model_delay, step = getattr(model, "delay", None), getattr(model, "dt", None)
        step = step[0] if isinstance(step, tuple) else step    # experiments share one dt
    else:
        raise ValueError(f"estimate_or_model must be an Estimate or a continuous-time "
                         f"control.StateSpace for several outputs or inputs; got "
                         f"{type(model).__name__}")
    # the delay as for one channel: the given one, else the model's, else the record's, else 0
    if delay is not None:
        delays = delay
    elif model_delay is None:
        delays = 0 if record.delay is None else record.delay
    else:
        delays = [_in_samples(int(k), step, record.dt) for k in np.ravel(model_delay)]
    out = compare_channels(model.A, model.B, model.C, model.D, record, delays)
    fit = out["fit"] if record.outputs > 1 else float(out["fit"][0])
    y_hat = out["y_hat"] if record.outputs > 1 else out["y_hat"][:, 0]
    offset = out["y_offset"] if record.outputs > 1 else float(out["y_offset"][0])
    D = out["delay"]
    return Comparison(fit=fit, y_hat=y_hat, x0=out["x0"], y_offset=offset, y=record.y,
                      t=record.t, delay=int(D[0]) if D.size == 1 else D)


def _in_samples(delay: int, step: float | None, dt: float) -> int:
    """An estimate's delay (samples of its own sample time ``step``) in samples of ``dt``,
    through seconds; a ValueError where it does not land on a sample."""
    if step is None or delay == 0 or step == dt:
        return delay
    samples = delay * step / dt
    if abs(samples - round(samples)) > 1e-6 * max(1.0, samples):
        raise ValueError(f"the estimate's delay ({delay} samples of dt = {step:g}, "
                         f"{delay * step:g} time units) is {samples:g} samples of this record "
                         f"(dt = {dt:g}), not a whole number: pass delay= explicitly")
    return int(round(samples))


@one_thread
def compare(estimate_or_model, record, *, delay=None) -> Comparison:
    """NRMSE fit of a model on a record with ``x_0`` and the output offset fitted.

    Parameters
    ----------
    estimate_or_model : Estimate, control.StateSpace, control.TransferFunction or (A, b, c, d)
        A continuous-time model in the record's time unit (a discrete-time one is refused);
        one of several outputs or inputs is compared output by output (an Estimate or a
        StateSpace, on a Record: ``Comparison.fit`` per output, ``overall`` their mean).
    record : Record, (y, u) or (y, u, dt) tuple, or (steps,) array
        As for :func:`~aeid_struct.generic.boundary.measured`; the model is simulated under
        the record's hold (``Record.intersample``).
    delay : int, optional
        Input delay in samples; default: the estimate's (converted through time units to the
        record's ``dt``), else the record's, else 0.

    Returns
    -------
    Comparison

    Raises
    ------
    ValueError
        For a bad model (a discrete-time one included), record or delay, or an estimate's
        delay that is not a whole number of the record's samples.
    """
    if _channels(estimate_or_model, record):
        return _compare_channels(estimate_or_model, record, delay)
    A, b, c, d, model_delay, step = _model(estimate_or_model)
    data = measured(record, delay, what="ae.compare")
    D = (data.delay if delay is not None or model_delay is None else
         _in_samples(int(model_delay), step, data.dt))
    D = 0 if D is None else int(D)
    if not 0 <= D <= data.steps - 2:
        raise ValueError(f"delay must be in [0, {data.steps - 2}] for this record; got {D}")
    # compared in the record's working units (records.Units: exact); an input level is
    # absorbed by x0 and the offset only where A is invertible (not by an integrator)
    units = Units.of(data)
    if units.u_level and not np.linalg.cond(A) < 1e12:
        units = dataclasses.replace(units, u_level=0.0)
    work = units.apply(data)
    g = units.su / units.sy
    with np.errstate(over="ignore", under="ignore"):
        cs, ds = c * g, d * g
    if not (np.all(np.isfinite(cs)) and np.isfinite(ds)) or np.any((c != 0) & (cs == 0)):
        raise ValueError(f"estimate_or_model: its gain (c, d up to {np.max(np.abs(c)):.3g}, "
                         f"{abs(d):.3g}) on a record with max|y| = {units.sy:.3g} and max|u| = "
                         f"{units.su:.3g} (powers of two) leaves float64")
    with np.errstate(all="ignore"):
        p = fit_initial(A, b, cs, ds, work.y, work.u, data.dt, delay=D, offset=True,
                        intersample=data.intersample)
    _, _, x0, y_offset = units.linear(A, b, cs, ds, p.x0, p.y_offset)
    t = data.t0 + data.dt * np.arange(data.steps)
    return Comparison(fit=float(p.fit), y_hat=units.output(p.y_hat), x0=x0,
                      y_offset=y_offset, y=data.y, t=t, delay=D)
