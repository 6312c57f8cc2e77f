"""An identified model (:class:`Estimate`) and where it comes from (:class:`Provenance`).

An Estimate holds the validated :class:`~aeid_struct.records.RecordBatch` it was made from and
refers to its provenance (one object per identifier) instead of copying the identifier's fields;
its fit, response, initial state and physical parameters are computed on first access, so that a
plain identification costs one encoder pass.

A generic estimate (``aeid_struct.identify``) models a measured record with an input delay and
an output offset (docs/architecture.md, "Any system, any record"). Its ``info`` holds ``delay``
(samples), ``x0`` (the state at sample ``delay``), ``y_offset``, ``fit`` and ``y_hat`` (NaN on
the first ``delay`` samples); ``Estimate.delay``, ``offset``, ``x0``, ``fit`` and ``y_hat``
return those instead of computing them for a record without delay and offset.

Beside it: the fields an Estimate reads from its ``info``, record and provenance
(``estimate_fields.py``), the old forms of its constructor (``old_forms.py``) and its model in
other forms, python-control and physical parameters (``conversions.py``).
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass, field
from functools import cached_property
from importlib import import_module

import numpy as np

from aeid_struct.estimates import calibration, old_forms
from aeid_struct.estimates.conversions import physical_parameters, state_spaces
from aeid_struct.estimates.estimate_fields import EstimateFields, from_info
from aeid_struct.metrics import nrmse_fit
from aeid_struct.records import RecordBatch

__all__ = ["Estimate", "Provenance"]


def _decoder():
    """``(simulate, initial_state)`` where an estimate simulates its record: the torch decoder's
    (``simulation.simulate``, ``initial_state``: the overflow rule, float32 models), or, where
    torch is not installed (an ONNX runner's estimates), the numpy kernels'
    (``simulation.simulate_numpy``, ``initial_state_numpy``: the same response of a finite
    model). Imported here, not with the module: an estimate that carries its response and
    initial state (a generic one) is built and read without either."""
    simulation = import_module("aeid_struct.simulation")
    try:
        return simulation.simulate, simulation.initial_state
    except ImportError:
        return simulation.simulate_numpy, simulation.initial_state_numpy


@dataclass(frozen=True, eq=False)
class Provenance:
    """What an estimate inherits from the identifier (or method) that made it; built once per
    identifier and shared by its estimates.

    Attributes
    ----------
    structure : Structure or None
        The structure the model is in, where known, so that ``refine(estimate)`` needs no
        further argument.
    inverse : casadi.Function, ("elements", names) or None
        Where the physical parameters come from: a CCF -> parameters map, or the elements
        themselves (a ``Physical`` structure); None for none.
    initial : {"rest", "fitted"}
        ``"rest"``: the records start from rest; ``"fitted"``: mid-motion, the initial state is
        fitted by least squares.
    training_range : dict or None
        The identifier's calibrated training range (``Identifier.training_range``), or None
        where unknown; see ``Estimate.outside``.
    """

    structure: object = None
    inverse: object = None
    initial: str = "rest"
    training_range: dict | None = None


@dataclass(frozen=True, eq=False, init=False)
class Estimate(EstimateFields):
    """An identified continuous-time model (batched or single), built with keywords.

    Parameters
    ----------
    *legacy
        The old positional form ``Estimate(A, b, c, d, elements, y, u, dt, seconds, refined,
        info, _inverse)``: still read, with a DeprecationWarning (keywords are the one way).
    A : (batch, n, n) or (n, n) float64 array
        A several-record estimate (``records = R > 1``) has a record axis after the batch axis
        (``(batch, R, n, n)`` or ``(R, n, n)``), likewise ``b, c, d``.
    b, c : (batch, n) or (n,) float64 arrays
    d : (batch,) array or float
    elements : dict name -> (batch,) array or float
        The structure's named elements (e.g. ``a0``, ``c1``, ``k``).
    record : RecordBatch or Record
        The records the estimate was made from (checked once, at the boundary); a measured
        ``Record`` is one unbatched record.
    provenance : Provenance
        Structure, physical parameters' source, initial state mode, training range.
    seconds : float
        Wall time of the identification.
    refined : bool
        Whether a CasADi refinement polished the estimate.
    info : dict
        Diagnostics (refinement iterations, loss, ...).
    errors : tuple of (str or None), optional
        Set by ``Identifier.identify(errors="collect")``: per record of ``y``, why it could not
        be identified, or None for a good one (its model rows are NaN). None when every record
        was good by ``errors="raise"``.
    **old
        The old keywords ``y, u, dt`` (a new record) and ``structure, initial,
        training_range, _inverse`` (a changed provenance), also through ``dataclasses.replace``
        (which passes them on); given to the constructor they warn (DeprecationWarning).

    Notes
    -----
    The model's matrices in the shapes of several inputs and outputs are :attr:`B` ``(n, m)``,
    :attr:`C` ``(p, n)`` and :attr:`D` ``(p, m)`` (with the leading axes of ``A``); the
    one-channel fields ``b (n,)``, ``c (n,)``, ``d ()`` are their views for ``p = m = 1``.
    """

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    elements: dict
    record: RecordBatch = field(repr=False)
    provenance: Provenance = field(repr=False)
    seconds: float = 0.0
    refined: bool = False
    info: dict = field(default_factory=dict)
    errors: tuple | None = None

    def __init__(self, *legacy, A=None, b=None, c=None, d=None, elements=None, record=None,
                 provenance=None, seconds=0.0, refined=False, info=None, errors=None, **old):
        if not (legacy or old) and isinstance(record, RecordBatch) and (
                A is not None and b is not None and c is not None and d is not None
                and elements is not None):
            # the library's own keyword form (one per tracker window): nothing to translate,
            # the fields set at once (a frozen dataclass's fields live in its __dict__)
            self.__dict__.update(A=A, b=b, c=c, d=d, elements=elements, record=record,
                                 provenance=_provenance(provenance, old), seconds=seconds,
                                 refined=refined, info={} if info is None else info,
                                 errors=errors)
            return
        values = old_forms.arguments(legacy, {"A": A, "b": b, "c": c, "d": d,
                                              "elements": elements, "seconds": seconds,
                                              "refined": refined, "info": info}, old)
        if old and not legacy:
            warnings.warn(f"Estimate's keywords {sorted(old)} are deprecated: pass "
                          f"record=RecordBatch.of(y, u, dt, ...) or a records.Record, and "
                          f"provenance=Provenance(structure=..., initial=..., "
                          f"training_range=..., inverse=...)", DeprecationWarning, stacklevel=2)
        values["info"] = {} if values["info"] is None else values["info"]
        values["record"] = old_forms.record_of(record, old, np.ndim(values["A"]))
        values["provenance"] = _provenance(provenance, old)
        values["errors"] = errors
        for name, value in values.items():
            object.__setattr__(self, name, value)

    # -- derived on first access ---------------------------------------------------------------
    @cached_property
    @from_info("y_hat")
    def y_hat(self):
        """The decoded response of the estimate to ``u`` (Eq. 10-13), shaped like ``y``; where
        the records are channels summed into outputs (several inputs at once,
        ``Physical.groups``), each record's is its output's, the sum of its channels."""
        if self._groups() is not None:
            return _summed(self)[0]
        return self._per_record(
            lambda A, b, c, d, u, y, x, dt: _decoder()[0](A, b, c, d, u, dt, x0=x),
            lambda r: np.shape(self.y if self.records == 1 else self.y[r]), self._x0())

    @cached_property
    @from_info("x0")
    def x0(self):
        """The state at the first sample: zeros for a record from rest, else the least-squares
        initial state (``simulation.initial_state``); ``(n,)`` / ``(batch, n)``, a tuple of
        them for several records."""
        x0 = self._x0()
        if x0 is not None:
            return x0
        if self._groups() is not None:
            return _summed(self)[1]
        if self.records == 1:
            return np.zeros(np.shape(self.b))                 # (n,) or (batch, n)
        return tuple(np.zeros(np.shape(self.b[..., r, :])) for r in range(self.records))

    @cached_property
    @from_info("fit")
    def fit(self):
        """NRMSE fit in %: ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` per record (a float,
        ``(batch,)``, or ``(R,)`` / ``(batch, R)``); NaN where undefined (a constant record,
        one set aside by ``errors="collect"``); such records are flagged ``outside``."""
        if self.records == 1:
            fit = nrmse_fit(self.y, self.y_hat)
            return fit if self.batched else float(fit[0])
        fit = np.stack([nrmse_fit(y, h) for y, h in zip(self.y, self.y_hat, strict=True)], 1)
        return fit if self.batched else fit[0]

    @cached_property
    def physical(self) -> dict:
        """Physical parameters by name: a ``Physical`` structure's elements, or a canonical
        structure's model through its CasADi inverse map (e.g. the leg's CCF -> k, d, m);
        empty otherwise."""
        return physical_parameters(self)

    @cached_property
    def excess(self):
        """How far the estimate lies beyond the identifier's training range, in units of its
        held-out error (``calibration.excess`` over the free elements and physical
        parameters): a float or ``(batch,)``; None without a training range."""
        rng = self.training_range
        if not rng:
            return None
        out = calibration.excess({**self.elements, **(self.physical or {})}, rng)
        return out if self.batched else float(out)

    @cached_property
    def outside(self):
        """Whether the estimate lies outside the identifier's training range (the calibrated
        rule, ``calibration.outside``): a bool or ``(batch,)``; None without a calibrated
        range (``training.recalibrate`` adds it)."""
        rng = self.training_range
        if not rng or "excess" not in rng:
            return None
        good = self._good
        if good is not None and not self.batched:
            good = good[0]
        flags = calibration.outside(self.excess, self.fit, rng, self.records, good)
        return flags if self.batched else bool(flags)

    # -- batches -------------------------------------------------------------------------------
    def take(self, index) -> Estimate:
        """The estimates of some records of a batch.

        Parameters
        ----------
        index : int, int array, slice or (batch,) bool mask

        Returns
        -------
        Estimate
            Unbatched for an int.
        """
        if not self.batched or self.records != 1:
            raise ValueError("take needs a batched estimate of one record per system")
        count = len(self.A)
        try:
            rows = np.atleast_1d(np.arange(count)[index])
        except (IndexError, TypeError, ValueError) as err:
            raise ValueError(f"index must select records of this batch of {count} records (an "
                             f"int, an int array, a slice or a ({count},) bool mask); got "
                             f"{index!r}: {err}") from None
        errors = None if self.errors is None else tuple(self.errors[i] for i in rows)
        return dataclasses.replace(
            self, A=self.A[index], b=self.b[index], c=self.c[index], d=self.d[index],
            elements={k: np.asarray(v)[index] for k, v in self.elements.items()},
            record=self.record.take(index), errors=errors)

    def to_control(self):
        """The model as python-control state space.

        Returns
        -------
        control.StateSpace, or a list of them
            A list for a batch (per batch row and record for several records).
        """
        return state_spaces(self)

    # -- helpers -------------------------------------------------------------------------------
    @property
    def _good(self) -> np.ndarray | None:
        """``(batch,)`` bool (``(1,)`` unbatched): the records identified, where
        ``errors="collect"`` set some aside; None when every record is good."""
        if self.errors is None or all(e is None for e in self.errors):
            return None
        return np.array([e is None for e in self.errors], dtype=bool)

    def _on_good(self, fn, *args, out):
        """``fn(*args)`` on the good records only, NaN of shape ``out`` for the others."""
        good = self._good
        if good is None:
            return fn(*args)
        result = np.full(out, np.nan)
        if not self.batched or not good.any():
            return result          # an unbatched estimate with errors is a bad record
        rows = np.flatnonzero(good)
        result[rows] = fn(*(None if a is None else np.asarray(a)[rows] for a in args))
        return result

    def _per_record(self, fn, shape, x0=None):
        """``fn(A, b, c, d, u, y, x0, dt)`` of each record on the good rows: one result, or a
        tuple of ``R`` for several records; ``shape(r)`` the result's shape."""
        if self.records == 1:
            return self._on_good(lambda A, b, c, d, u, y, x: fn(A, b, c, d, u, y, x, self.dt),
                                 self.A, self.b, self.c, self.d, self.u, self.y, x0,
                                 out=shape(0))
        return tuple(self._on_good(
            lambda A, b, c, d, u, y, x, r=r: fn(A, b, c, d, u, y, x, self.dt[r]),
            self.A[..., r, :, :], self.b[..., r, :], self.c[..., r, :], self.d[..., r],
            self.u[r], self.y[r], None if x0 is None else x0[r], out=shape(r))
            for r in range(self.records))

    def _groups(self):
        """Per record its output where the records are channels summed into outputs (the
        structure's ``groups``), else None."""
        return getattr(self.structure, "groups", None) if self.records > 1 else None

    def _x0(self):
        """The fitted initial state(s), or None for records from rest."""
        if self.initial != "fitted":
            return None
        if self._groups() is not None:
            return _summed(self)[1]
        if "_x0_fitted" not in self.__dict__:
            self.__dict__["_x0_fitted"] = self._per_record(
                lambda A, b, c, d, u, y, x, dt: _decoder()[1](A, b, c, d, u, y, dt),
                lambda r: np.shape(self.b if self.records == 1 else self.b[..., r, :]))
        return self.__dict__["_x0_fitted"]


def _summed(est: Estimate) -> tuple:
    """Per record its output's response and its own initial state (a tuple of ``R`` each) of
    an estimate whose records are channels summed into outputs: ``simulation.summed_response``
    row by row (the fitted free response of each output split over its channels, of
    minimum norm; zeros from rest); NaN for records set aside."""
    if "_summed_fitted" in est.__dict__:
        return est.__dict__["_summed_fitted"]
    from aeid_struct.simulation import output_groups, summed_response

    one = not est.batched
    A, b, c, d = (np.asarray(v)[None] if one else np.asarray(v)
                  for v in (est.A, est.b, est.c, est.d))
    ys = [np.atleast_2d(y) for y in est.y]
    us = [np.broadcast_to(u, y.shape) for u, y in zip(est.u, ys, strict=True)]
    initial = est.initial == "fitted"
    y_hat = [np.full(y.shape, np.nan) for y in ys]
    x0 = [np.full(b.shape[::2], np.nan if initial else 0.0) for _ in ys]
    good = np.ones(A.shape[0], dtype=bool) if est._good is None else est._good
    for i in np.flatnonzero(good):
        cache = []                # the row's channels share one discretisation (Eq. 10)
        for group in output_groups(est._groups(), est.records):
            h, states = summed_response(
                [(A[i, r][None], b[i, r][None], c[i, r][None], d[i, r][None])
                 for r in group], [us[r][i] for r in group], ys[group[0]][i],
                est.dt[group[0]], initial, x0=True, cache=cache)
            for j, r in enumerate(group):
                y_hat[r][i] = h[0]
                if states is not None:
                    x0[r][i] = states[j][0]
    out = tuple(tuple(v[0] if one else v for v in part) for part in (y_hat, x0))
    est.__dict__["_summed_fitted"] = out
    return out


def _provenance(provenance: Provenance | None, old: dict) -> Provenance:
    """``provenance`` (default: none known) with the old keywords' changes."""
    provenance = Provenance() if provenance is None else provenance
    changes = {("inverse" if k == "_inverse" else k): old[k]
               for k in ("structure", "initial", "training_range", "_inverse") if k in old}
    return dataclasses.replace(provenance, **changes) if changes else provenance
