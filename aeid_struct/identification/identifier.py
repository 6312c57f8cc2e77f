"""Identifier = encoder + structure + normalisation; one forward pass identifies a system.

The scale question the paper leaves open (Eq. 15 removes ``y_bar = max|y|`` before the encoder
sees the record), and how we settle it:

- The encoder reads ``y_tilde = 2 y / y_bar - 1`` (Eq. 15) and, for identifiers trained on
  arbitrary excitation, ``u / u_bar`` with ``u_bar = max|u|``.
- ``scale="denormalise"`` (canonical structures): the structure's output describes the
  *normalised* system ``u / u_bar -> y / y_bar``. By linearity the measured system is the same
  ``A, b`` with ``c = c' * y_bar / u_bar`` and ``d = d' * y_bar / u_bar``: exact, no information
  lost, and the encoder never has to learn magnitudes.
- ``scale="feature"`` (physical structures, or fixed non-zero ``c``/``d`` elements, where ``c``
  cannot be rescaled freely): the structure describes the measured system itself, and the
  encoder receives ``log(y_bar / u_bar)`` (standardised) as an extra scalar feature, because the
  magnitude carries information (the stable leg's static gain is ``1/k``).

Either way the decoded response is normalised with the *measured* ``y_bar`` before it is
compared with the record (Eq. 14-15), as the paper prescribes.

Several records, one parameter set. An identifier of a :class:`~aeid_struct.structures.Physical`
structure with ``records = R > 1`` (the leg's two subsystems, ``symbolic.leg.joint_map``) reads
one record per subsystem, each on its own grid (``dt`` and ``steps`` are tuples), normalises each
by its own ``y_bar`` (Eq. 15), feeds all of them to one encoder (``EncoderConfig`` with tuple
``steps`` and ``pool``) together with the ``R`` scale features, and outputs one parameter vector;
``identify`` takes sequences of ``R`` records and its ``Estimate`` carries a record axis.

The raw encoder output is mapped affinely, ``theta = theta_mean + theta_scale * net(...)``, with
statistics of the training family's raw parameters, so that the network works in O(1) units
whatever the physical magnitudes; the structure then imposes its constraints.

Files (``.aeid``) are safetensors: tensors plus a JSON header. A model file holds data, never
code: loading parses JSON and raw tensors only (no pickle), and CasADi maps are stored as
references to named factories (``aeid_struct.maps``), never as serialised Functions, which can
run shell commands when read. A user's own map is passed again at load time
(``Identifier.load(path, maps={name: f})``) or read from the file only behind ``trust=True``.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from aeid_struct.encoder import Encoder, EncoderConfig
from aeid_struct.records import (
    Checked,
    as_array,
    check_records,
    normalise,
    overflow_problem,
    require_finite,
)
from aeid_struct.structures import Structure, System

#: The file format written: maps are references (``aeid_struct.maps``), never code.
FORMAT = "aeid-struct/identifier/2"
#: The format before named maps (CasADi Functions serialised inline): read with ``trust=True``
#: where it holds a Function.
FORMAT_1 = "aeid-struct/identifier/1"
SCALE_MODES = ("denormalise", "feature")
#: The calibrated rule's false-flag budget per criterion (excess and fit) on held-out records
#: inside the training range: each threshold is that quantile of its statistic there.
FLAG_FALSE_RATE = 0.015
#: How the decoder treats a record's initial state: from rest (the paper), or fitted by least
#: squares (records that start mid-motion; ``decoder.initial_state``).
INITIAL_STATES = ("rest", "fitted")
#: What ``Identifier.identify`` does with a record it cannot identify (non-finite, all zero,
#: ...): raise (the default), or collect a reason per record and identify the good ones.
ERROR_MODES = ("raise", "collect")


@dataclass(frozen=True, eq=False)
class Estimate:
    """An identified continuous-time model (batched or single).

    Attributes:
        A: ``(batch, n, n)`` or ``(n, n)``; b, c: ``(batch, n)`` or ``(n,)``; d: ``(batch,)`` or
            scalar -- float64 numpy. A several-record estimate (``records = R > 1``) has a record
            axis after the batch axis (``A (batch, R, n, n)`` or ``(R, n, n)``, ...), and its
            ``y``, ``u`` (and ``y_hat``) are tuples of ``R`` records, ``dt`` a tuple.
        elements: the structure's named elements (e.g. ``a0``, ``c1``, ``k``), each ``(batch,)``.
        y, u: the records the estimate was made from, ``(batch, steps)`` or ``(steps,)``.
        dt: sample time.
        seconds: wall time of the identification.
        refined: whether a CasADi refinement polished the estimate.
        info: extra diagnostics (refinement iterations, loss, ...).
        structure: the structure the model is in, where known (set by ``Identifier``), so that
            ``refine(estimate, y, u, dt)`` needs no further argument.
        initial: ``"rest"`` (the record starts from rest) or ``"fitted"`` (it starts
            mid-motion: ``x0`` is the least-squares initial state and ``y_hat`` starts there).
        training_range: the identifier's training range (``Identifier.training_range``), or
            None where unknown; see ``outside``.
        errors: set by ``Identifier.identify(errors="collect")``: per record of ``y`` (one entry
            for an unbatched ``y``), why it could not be identified, or None for a good record;
            a bad record's model rows are NaN and its ``y_hat``, ``fit`` NaN. None when the
            records were checked with ``errors="raise"`` (all of them were good).

    ``fit``, ``y_hat`` and ``physical`` are computed on first access, so that a plain
    identification costs one encoder pass.
    """

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    elements: dict[str, np.ndarray]
    y: np.ndarray
    u: np.ndarray
    dt: float
    seconds: float = 0.0
    refined: bool = False
    info: dict = field(default_factory=dict)
    _inverse: object = field(default=None, repr=False)
    structure: object = field(default=None, repr=False)
    initial: str = "rest"
    training_range: dict | None = field(default=None, repr=False)
    errors: tuple[str | None, ...] | None = None

    @property
    def records(self) -> int:
        """Records the estimate was made from jointly (1, or ``R`` for a tuple of records)."""
        return len(self.y) if isinstance(self.y, tuple) else 1

    @property
    def batched(self) -> bool:
        return self.A.ndim == (3 if self.records == 1 else 4)

    @cached_property
    def y_hat(self):
        """The decoded response of the estimate to ``u`` (Eq. 10-13), shaped like ``y`` (a
        tuple of ``R`` responses for a several-record estimate)."""
        from aeid_struct.simulation import simulate

        x0 = self._x0()
        if self.records == 1:
            return self._on_good(
                lambda A, b, c, d, u, x: simulate(A, b, c, d, u, self.dt, x0=x),
                self.A, self.b, self.c, self.d, self.u, x0, out=np.shape(self.y))
        return tuple(self._on_good(
            lambda A, b, c, d, u, x, r=r: simulate(A, b, c, d, u, self.dt[r], x0=x),
            self.A[..., r, :, :], self.b[..., r, :], self.c[..., r, :], self.d[..., r],
            self.u[r], None if x0 is None else x0[r], out=np.shape(self.y[r]))
            for r in range(self.records))

    @property
    def _good(self) -> np.ndarray | None:
        """``(batch,)`` bool (``(1,)`` unbatched): the records identified, where
        ``errors="collect"`` set some aside; None when every record is good."""
        if self.errors is None or all(e is None for e in self.errors):
            return None
        return np.array([e is None for e in self.errors], dtype=bool)

    def _on_good(self, fn, *args, out):
        """``fn(*args)`` on the good records only (``_good``), NaN of shape ``out`` for the
        others; ``args`` are batched like the estimate (None passes through)."""
        good = self._good
        if good is None:
            return fn(*args)
        result = np.full(out, np.nan)
        if not self.batched or not good.any():
            return result          # an unbatched estimate with errors is a bad record
        rows = np.flatnonzero(good)
        result[rows] = fn(*(None if a is None else np.asarray(a)[rows] for a in args))
        return result

    def take(self, index) -> Estimate:
        """The estimates of the records ``index`` (an int array, slice or mask) of a batch."""
        if not self.batched or self.records != 1:
            raise ValueError("take needs a batched estimate of one record per system")
        count = len(self.A)
        try:
            rows = np.atleast_1d(np.arange(count)[index])
        except (IndexError, TypeError, ValueError) as err:
            raise ValueError(f"index must select records of this batch of {count} records (an "
                             f"int, an int array, a slice or a ({count},) bool mask); got "
                             f"{index!r}: {err}") from None
        errors = self.errors
        if errors is not None:
            errors = tuple(errors[i] for i in rows)
        return dataclasses.replace(
            self, A=self.A[index], b=self.b[index], c=self.c[index], d=self.d[index],
            elements={k: np.asarray(v)[index] for k, v in self.elements.items()},
            y=self.y[index], u=self.u[index], errors=errors)

    @cached_property
    def outside(self):
        """Whether the estimate lies outside the identifier's training range. A bool, or
        ``(batch,)``; None when the identifier carries no calibrated training range (a file
        trained before the calibration: ``training.recalibrate`` adds it).

        Flagged when
        ``excess`` (how far some free element or physical parameter lies beyond its range over
        the training family, in units of the identifier's 90th-percentile held-out error on it)
        exceeds a threshold, or when the fit (``fit``, NRMSE %) falls below one. Both thresholds
        are quantiles of the same statistics on the identifier's held-out records at its largest
        training noise, set at the end of training so that each flags ``FLAG_FALSE_RATE`` of
        them: the false-flag rate inside the range is known by construction (at most twice
        that, less on cleaner records). Quantities the family holds constant (the leg's c1 = 0)
        are not compared.

        A record with an undefined fit (a constant ``y``: ``fit`` is NaN) and a record set aside
        by ``errors="collect"`` are flagged.

        Why both: an encoder that extrapolates decodes a record from beyond the range well (its
        residual says nothing) while its parameters land outside the range; one that saturates
        keeps the parameters inside and misfits. Physical parameters (through an inverse map)
        are compared too: the bounding box of the elements is much larger than the image of the
        parameter box. Why errors as the unit: a quantity the records determine poorly (k and m
        of the leg's unstable subsystem) needs a large departure to flag.
        """
        rng = self.training_range
        if not rng or "excess" not in rng:
            return None
        excess = np.asarray(self.excess)
        fit = np.asarray(self.fit)
        # An undefined fit (NaN: a constant record, or one set aside by errors="collect") is
        # no evidence that the estimate is inside the range: flagged.
        low = (fit < rng["fit"]) | ~np.isfinite(fit)
        if self.records > 1:                   # (batch, R) or (R,): any record of the system
            low = np.any(low, axis=-1)
        flags = (excess > rng["excess"]) | ~np.isfinite(excess) | low
        if self._good is not None:
            flags = flags | ~(self._good if self.batched else self._good[0])
        return flags if self.batched else bool(flags)

    @cached_property
    def excess(self):
        """How far the estimate lies beyond the identifier's training range, in units of its
        own held-out error: ``max_q max(lo_q - v_q, v_q - hi_q, 0) / err_q`` over the free
        elements and physical parameters ``q`` (``err_q`` the 90th-percentile held-out error);
        0 inside the range, inf for a non-finite value. A float or ``(batch,)``; None without a
        training range."""
        rng = self.training_range
        if not rng:
            return None
        out = _excess({**self.elements, **(self.physical or {})}, rng)
        return out if self.batched else float(out)

    @cached_property
    def x0(self):
        """The state at the first sample: zeros for a record from rest, else the least-squares
        initial state of the estimate (``decoder.initial_state``); ``(n,)`` / ``(batch, n)``, a
        tuple of them for several records."""
        x0 = self._x0()
        if x0 is not None:
            return x0
        if self.records == 1:
            return np.zeros(np.shape(self.b))                 # (n,) or (batch, n)
        return tuple(np.zeros(np.shape(self.b[..., r, :])) for r in range(self.records))

    def _x0(self):
        """The fitted initial state(s), or None for records from rest."""
        if self.initial != "fitted":
            return None
        if "_x0_fitted" not in self.__dict__:
            from aeid_struct.simulation import initial_state

            if self.records == 1:
                value = self._on_good(
                    lambda A, b, c, d, u, y: initial_state(A, b, c, d, u, y, self.dt),
                    self.A, self.b, self.c, self.d, self.u, self.y, out=np.shape(self.b))
            else:
                value = tuple(self._on_good(
                    lambda A, b, c, d, u, y, r=r: initial_state(A, b, c, d, u, y, self.dt[r]),
                    self.A[..., r, :, :], self.b[..., r, :], self.c[..., r, :],
                    self.d[..., r], self.u[r], self.y[r], out=np.shape(self.b[..., r, :]))
                    for r in range(self.records))
            self.__dict__["_x0_fitted"] = value
        return self.__dict__["_x0_fitted"]

    @cached_property
    def fit(self):
        """NRMSE fit in %: ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` per record (a float,
        ``(batch,)``, or with several records ``(R,)`` / ``(batch, R)``); NaN where it is
        undefined: a constant record (``||y - mean(y)|| = 0``), or one set aside by
        ``errors="collect"``. Such records are flagged ``outside``."""
        from aeid_struct.metrics import nrmse_fit

        if self.records == 1:
            fit = nrmse_fit(self.y, self.y_hat)
            return fit if self.batched else float(fit[0])
        fit = np.stack([nrmse_fit(y, h) for y, h in zip(self.y, self.y_hat, strict=True)], 1)
        return fit if self.batched else fit[0]

    @cached_property
    def physical(self) -> dict[str, np.ndarray]:
        """Physical parameters by name, where the identifier has a physical map or inverse.

        From a ``Physical`` structure they are the elements themselves; for a canonical structure
        with a CasADi inverse map (e.g. the leg's CCF -> k, d, m) they are that map's outputs.
        Empty otherwise.
        """
        from aeid_struct.structures import CCF

        inverse = self._inverse
        if inverse is None:
            return {}
        if isinstance(inverse, tuple) and inverse[0] == "elements":
            return {name: self.elements[name] for name in inverse[1]}
        A = np.asarray(self.A, dtype=np.float64)
        A = A[None] if A.ndim == 2 else A
        count, n = A.shape[0], A.shape[-1]
        b = np.asarray(self.b, dtype=np.float64).reshape(count, n)
        c = np.asarray(self.c, dtype=np.float64).reshape(count, n)
        d = np.asarray(self.d, dtype=np.float64).reshape(count)
        result = _inverse_of_models(inverse, A, b, c, d, isinstance(self.structure, CCF))
        if not self.batched:
            result = {k: float(v[0]) for k, v in result.items()}
        return result

    def to_control(self):
        """``control.StateSpace`` (a list for a batch)."""
        import control

        def one(A, b, c, d):
            n = A.shape[0]
            return control.ss(A, b.reshape(n, 1), c.reshape(1, n), np.reshape(d, (1, 1)))

        if self.records > 1:   # a list per record (per batch row and record when batched)
            A, b, c, d = (np.asarray(x) for x in (self.A, self.b, self.c, self.d))
            rows = [(A, b, c, d)] if not self.batched else list(zip(A, b, c, d, strict=True))
            out = [[one(*m) for m in zip(*row, strict=True)] for row in rows]
            return out if self.batched else out[0]
        if not self.batched:
            return one(self.A, self.b, self.c, self.d)
        return [one(*m) for m in zip(self.A, self.b, self.c, self.d, strict=True)]


def _excess(values: dict, rng: dict) -> np.ndarray:
    """``Estimate.excess`` of element and parameter ``values`` (name -> array) against a
    training range (``training._training_range``)."""
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


def _inverse_of_models(inverse, A: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray,
                       ccf: bool) -> dict[str, np.ndarray]:
    """A CCF -> parameters casadi.Function on models ``A (N, n, n), b, c (N, n), d (N,)``:
    ``name -> (N,)``. ``ccf``: the models are bottom-row CCFs already; otherwise (an MCF or
    n4sid model, another realisation of the same transfer function) they are converted first."""
    if ccf:
        return _apply_inverse(inverse, A, b, c, d)
    return _through_ccf(A, b, c, d, inverse)


#: casadi.Function -> its buffer evaluation (``refine._Numeric``), by identity; a few entries.
_NUMERIC: dict[int, tuple] = {}


def _apply_inverse(inverse, A: np.ndarray, b: np.ndarray, c: np.ndarray,
                   d: np.ndarray) -> dict[str, np.ndarray]:
    """A CCF -> parameters casadi.Function on bottom-row CCF models ``A (N, n, n), b, c (N, n),
    d (N,)``: ``name -> (N,)``. One model goes through the Function's buffer (0.016 ms, against
    0.11 ms for its Python call and 0.4 ms for a map: the tracker's hot path); a batch, one map
    over all."""
    from aeid_struct.refinement.nlp import _Numeric

    count, n = A.shape[0], A.shape[-1]
    if count == 1 and list(inverse.name_in()) == ["A", "B", "C", "D"]:
        hit = _NUMERIC.get(id(inverse))
        if hit is None or hit[0] is not inverse:
            if len(_NUMERIC) >= 16:
                _NUMERIC.clear()
            hit = _NUMERIC[id(inverse)] = (inverse, _Numeric(inverse))
        # the buffer reads CasADi's column-major order: A transposed, then row by row
        out = hit[1](np.ascontiguousarray(A[0].T).ravel(), np.ascontiguousarray(b[0]),
                     np.ascontiguousarray(c[0]), np.asarray(d[:1], dtype=np.float64))
        return dict(zip(inverse.name_out(), out, strict=True))
    # Mapped casadi inputs are concatenated horizontally: A (n, n*N), B (n, N), C (1, n*N).
    out = inverse.map(count)(A=np.concatenate(list(A), axis=1), B=b.T,
                             C=c.reshape(1, count * n), D=d.reshape(1, count))
    return {name: np.array(out[name]).reshape(count) for name in inverse.name_out()}


def _through_ccf(A: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray,
                 inverse) -> dict[str, np.ndarray]:
    """Apply a CCF -> parameters casadi.Function to models in any realisation.

    Each finite model ``A (N, n, n), b, c (N, n), d (N,)`` is converted to the bottom-row CCF of
    its transfer function (characteristic polynomial and Markov parameters, as
    ``Structure.elements_of`` does), then mapped; NaN for non-finite models. Returns
    ``name -> (N,)``.
    """
    from aeid_struct.structures.base import _ccf_coefficients, _ccf_matrices

    finite = (np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(b), axis=1)
              & np.all(np.isfinite(c), axis=1) & np.isfinite(d))
    out = {name: np.full(A.shape[0], math.nan) for name in inverse.name_out()}
    rows = np.flatnonzero(finite)
    if rows.size:
        Ac, bc, cc = _ccf_matrices(*_ccf_coefficients(A[rows], b[rows], c[rows]))
        for name, value in _apply_inverse(inverse, Ac, bc, cc, d[rows]).items():
            out[name][rows] = value
    return out


# The record checks live in records.py; these names stay for modules that imported them.
_as_array, _require_finite = as_array, require_finite


def _features(name: str, value, records: int) -> np.ndarray:
    """``(records,)`` float64 from a number or one finite number per record."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.array([np.nan])
    if arr.ndim > 1 or arr.size not in (1, records) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite number or {records} of them (one per "
                         f"record); got {value!r}")
    return np.broadcast_to(arr.reshape(-1), (records,)).copy()


def _overflowed(problems: tuple, good: np.ndarray, model: tuple, y2: np.ndarray,
                u2: np.ndarray | None) -> tuple:
    """``problems`` with a reason added for each good record whose identified model is not
    finite, and its model rows set to NaN (in place).

    Why: the de-normalisation multiplies ``c, d`` by ``max|y| / max|u|`` (Eq. 15 and
    linearity); a record of 1e308 has a model whose ``c`` lies beyond float64 (inf), which
    must not come back as an estimate."""
    finite = np.ones(len(problems), dtype=bool)
    for part in model:
        finite &= np.isfinite(part.reshape(len(problems), -1)).all(axis=1)
    bad = good & ~finite
    if not bad.any():
        return problems
    out = list(problems)
    u_bar = np.ones(len(y2)) if u2 is None else np.abs(u2).max(axis=1)
    for r in np.flatnonzero(bad):
        gain = np.abs(y2[r]).max() / u_bar[r]
        out[r] = overflow_problem(r, gain)
        for part in model:
            part[r] = math.nan
    return tuple(out)


def _same_dt(dt, dts: tuple[float, ...]) -> bool:
    """Whether a user's ``dt`` (a number, or a sequence for several records) is ``dts``."""
    given = tuple(dt) if isinstance(dt, (tuple, list)) else (dt,)
    return len(given) == len(dts) and all(
        isinstance(g, (int, float)) and math.isclose(g, t, rel_tol=1e-9)
        for g, t in zip(given, dts, strict=True))


class Identifier:
    """A trained encoder with its structure, record format and normalisation.

    Args:
        encoder: the network (its config fixes ``steps`` and the input channels).
        structure: maps raw parameters to ``(A, b, c, d)`` with its constraints.
        dt: sample time the identifier was trained for (a tuple, one per record, for a
            several-record structure).
        theta_mean, theta_scale: ``(p,)`` affine map of the network output to raw parameters.
        scale: ``"denormalise"`` or ``"feature"`` (see the module docstring).
        feature_mean, feature_scale: standardisation of ``log(y_bar/u_bar)`` (``"feature"``);
            one per record (tuples) for several records.
        inverse: optional casadi.Function from the CCF model to physical parameters.
        meta: provenance (training command, seed, metrics), stored in the file.
        initial: ``"rest"`` (records start from rest, the paper) or ``"fitted"`` (records may
            start mid-motion; the estimate's initial state is fitted by least squares).
    """

    def __init__(self, encoder: Encoder, structure: Structure, *, dt,
                 theta_mean: torch.Tensor, theta_scale: torch.Tensor,
                 scale: str = "denormalise", feature_mean=0.0,
                 feature_scale=1.0, inverse=None, meta: dict | None = None,
                 initial: str = "rest"):
        if scale not in SCALE_MODES:
            raise ValueError(f"scale must be one of {SCALE_MODES}; got {scale!r}")
        if initial not in INITIAL_STATES:
            raise ValueError(f"initial must be one of {INITIAL_STATES}; got {initial!r}")
        if not isinstance(encoder, Encoder):
            raise ValueError(f"encoder must be an Encoder; got {type(encoder).__name__}")
        if not isinstance(structure, Structure):
            raise ValueError(f"structure must be a Structure (CCF, MCF, Physical, ...); got "
                             f"{type(structure).__name__}")
        R = encoder.config.records
        if structure.records != R:
            raise ValueError(f"the encoder reads {R} record(s) but {structure!r} describes "
                             f"{structure.records}: encoder.config.steps must have one entry "
                             "per record")
        dts = tuple(dt) if isinstance(dt, (tuple, list)) else (dt,)
        if len(dts) != R or not all(isinstance(t, (int, float)) and math.isfinite(t) and t > 0
                                    for t in dts):
            raise ValueError(f"dt must be {'a positive finite number' if R == 1 else f'{R} '}"
                             f"{'' if R == 1 else 'positive finite numbers, one per record'}; "
                             f"got {dt!r}")
        if R > 1 and scale != "feature":
            raise ValueError("several records need scale='feature' (one physical parameter "
                             f"set cannot be de-normalised per record); got {scale!r}")
        if encoder.config.outputs != structure.p:
            raise ValueError(
                f"encoder.config.outputs must equal structure.p = {structure.p}; "
                f"got {encoder.config.outputs}"
            )
        if scale == "feature" and encoder.config.features != R:
            raise ValueError(f"scale='feature' needs an encoder with features={R} (one scale "
                             f"per record); got features={encoder.config.features}")
        self.encoder = encoder
        self.structure = structure
        self._dts = tuple(float(t) for t in dts)
        #: Sample time (a tuple, one per record, for several records).
        self.dt = self._dts[0] if R == 1 else self._dts
        self.theta_mean = torch.as_tensor(theta_mean, dtype=torch.float32).reshape(-1)
        self.theta_scale = torch.as_tensor(theta_scale, dtype=torch.float32).reshape(-1)
        if self.theta_mean.shape != (structure.p,) or self.theta_scale.shape != (structure.p,):
            raise ValueError(f"theta_mean and theta_scale must have shape ({structure.p},); "
                             f"got {tuple(self.theta_mean.shape)}, "
                             f"{tuple(self.theta_scale.shape)}")
        if not bool(torch.isfinite(self.theta_mean).all() & torch.isfinite(self.theta_scale)
                    .all()):
            raise ValueError("theta_mean and theta_scale must be finite: every estimate would be "
                             "NaN")
        self.scale = scale
        self.initial = initial
        fm, fs = (_features(name, v, R) for name, v in (("feature_mean", feature_mean),
                                                        ("feature_scale", feature_scale)))
        if not np.all(fs > 0):
            # the scale feature is divided by it: 0 gives inf features and NaN estimates
            raise ValueError(f"feature_scale must be positive (one per record); got "
                             f"{feature_scale!r}")
        self.feature_mean = float(fm[0]) if R == 1 else tuple(fm.tolist())
        self.feature_scale = float(fs[0]) if R == 1 else tuple(fs.tolist())
        self._features = (torch.from_numpy(fm), torch.from_numpy(fs))   # (R,) each
        self.inverse = inverse
        self.meta = dict(meta or {})
        self._fast_path = None                      # (weight versions, _Batch1 or None)
        self._params = list(encoder.parameters())   # cached: walking the modules costs ~0.5 ms
        # 1 for the elements that scale with the output (c_i, d), 0 elsewhere
        self._output_mask = torch.tensor([[
            1.0 if (k == "d" or (k[0] == "c" and k[1:].isdigit())) else 0.0
            for k in structure.element_names]])

    # -- the record format ---------------------------------------------------------------------
    @property
    def steps(self):
        """Samples per record (a tuple, one per record, for several records)."""
        return self.encoder.config.steps

    @property
    def records(self) -> int:
        """Records read together (1, or ``R`` for a several-record structure)."""
        return self.encoder.config.records

    @property
    def training_range(self) -> dict | None:
        """``{"elements": {name: (lo, hi, err)}, "physical": {name: (lo, hi, err)}, "fit": f}``:
        each free element's and physical parameter's range over the training family and the
        identifier's 90th-percentile held-out error on it, and the 1st percentile of its
        held-out fits (recorded by ``train``; see ``Estimate.outside``), or None for an
        identifier without it."""
        rng = self.meta.get("training_range")
        if not rng:
            return None
        return {g: ({k: tuple(v) for k, v in rng[g].items()} if isinstance(rng[g], dict)
                    else rng[g]) for g in rng}

    @property
    def inputs(self) -> bool:
        """Whether the encoder reads the input record (arbitrary excitation)."""
        return self.encoder.config.inputs

    def time(self):
        """Sample instants ``t_k = k*dt``, ``(steps,)`` (a tuple of them for several records)."""
        grids = tuple(np.arange(s) * t for s, t in zip(self.encoder.config.record_steps,
                                                       self._dts, strict=True))
        return grids[0] if self.records == 1 else grids

    def __repr__(self) -> str:
        return (f"Identifier({self.structure!r}, dt={self.dt}, steps={self.steps}, "
                f"inputs={self.inputs}, scale={self.scale!r})")

    # -- the differentiable path (training uses it) --------------------------------------------
    def system(self, y, u) -> System:
        """Encode records into the identified system, in measured units.

        Args:
            y, u: ``(batch, steps)`` tensors (checked by the caller); sequences of ``R`` such
                tensors ``(batch, steps_r)`` for several records.

        Returns:
            ``System`` with ``A (batch, n, n)``, ``b, c (batch, n)``, ``d (batch,)`` (with a
            record axis after the batch axis for several records).
        """
        return self._forward(y, u)[0]

    def _forward(self, y, u, *, raw: bool = False):
        """``(System, elements (batch, q))`` of the records, both in measured units; with
        ``raw``, also the encoder's standardised outputs ``(batch, p)``."""
        ys, us = (tuple(y), tuple(u)) if self.records > 1 else ((y,), (u,))
        y_bar = torch.stack([r.abs().amax(dim=1) for r in ys], 1)     # (batch, R)
        u_bar = torch.stack([r.abs().amax(dim=1) for r in us], 1)
        x = []
        for r, (y_r, u_r) in enumerate(zip(ys, us, strict=True)):
            channels = [2.0 * y_r / y_bar[:, r, None] - 1.0]         # Eq. 15
            if self.inputs:
                channels.append(u_r / u_bar[:, r, None])
            x.append(torch.stack(channels, dim=1))
        features = None
        gain = y_bar / u_bar                                          # (batch, R)
        if self.scale == "feature":
            mean, spread = (f.to(gain.dtype) for f in self._features)
            features = (torch.log(gain) - mean) / spread
        sys, elements, z = self._decode(x, features)
        if self.scale == "denormalise":
            gain = gain[:, 0]
            # Exact de-normalisation: the structure described u/u_bar -> y/y_bar (linearity).
            sys = System(sys.A, sys.b, sys.c * gain[:, None].to(sys.c.dtype),
                         sys.d * gain.to(sys.d.dtype))
            mask = self._output_mask.to(elements.dtype)
            elements = elements * (1.0 + mask * (gain[:, None].to(elements.dtype) - 1.0))
        return (sys, elements, z) if raw else (sys, elements)

    def _decode(self, x: list, features):
        """Normalised records ``x`` (one ``(batch, channels, steps_r)`` tensor per record) and
        scale ``features`` -> ``(System, elements, z)`` as the structure outputs them (before
        any de-normalisation), with the encoder's standardised output ``z (batch, p)``."""
        z = self.encoder(x[0] if self.records == 1 else x, features)
        theta = self.theta_mean.to(z.dtype) + self.theta_scale.to(z.dtype) * z
        elements = self.structure.elements(theta)
        return self.structure.assemble(elements), elements, z

    def _fast(self):
        """The batch-1 path: a ``_Batch1`` (numpy encoder + traced structure), or None.

        Why: one record costs ~100 small tensor operations, and at batch 1 PyTorch spends far
        more time dispatching them (2-10 us each) than computing. The encoder runs in numpy on
        float64 copies of the weights (76 us against 170 us for a frozen TorchScript trace of
        the same network) and the structure as a frozen trace (37 us against 83 us eager). It is
        rebuilt when the weights change (parameter version counters), compared with the eager
        path when it is built, and skipped (None) where it does not apply or does not agree.
        """
        if self.records > 1:
            return None
        version = tuple(p._version for p in self._params)
        if self._fast_path is not None and self._fast_path[0] == version:
            return self._fast_path[1]
        try:
            fast = _Batch1(self)
            g = torch.Generator().manual_seed(0)
            y = torch.cumsum(torch.rand(1, self.steps, generator=g), dim=1)
            u = 0.5 + torch.rand(1, self.steps, generator=g)
            was_training = self.encoder.training
            self.encoder.eval()
            try:
                with torch.no_grad():
                    sys, el = self._forward(y, u)
            finally:
                self.encoder.train(was_training)
            ref = [t.double().numpy() for t in (sys.A, sys.b, sys.c, sys.d, el)]
            got = fast(y.numpy()[0].astype(np.float64), u.numpy()[0].astype(np.float64))
            ok = all(np.allclose(a, b, rtol=1e-4, atol=1e-6 * (1 + np.abs(a).max()))
                     for a, b in zip(ref, got, strict=True))
        except Exception:  # any structure or layer the fast path does not cover: eager path
            fast, ok = None, False
        self._fast_path = (version, fast if ok else None)
        return self._fast_path[1]

    # -- public identification -----------------------------------------------------------------
    def identify(self, y, u=None, *, dt: float | None = None,
                 refine: bool | str = False, errors: str = "raise") -> Estimate:
        """Identify the system behind a record in one encoder pass.

        Args:
            y: measured output, ``(steps,)`` or ``(batch, steps)`` with ``batch >= 1``, sampled
                at ``t_k = k*dt`` from rest (zero initial state); real numbers (a complex
                array is refused). For a several-record identifier a sequence of ``R``
                records, one per subsystem, each on its own grid.
            u: input, same shape (or ``(steps,)`` for a whole batch); ``None`` means a unit
                step, which is what step-trained identifiers expect. A sequence of ``R`` (or
                None) for several records.
            dt: the record's sample time, if you want it checked against the identifier's
                (an identifier only knows records on the grid it was trained for).
            refine: polish the estimate with a CasADi NLP in the same structure (refine.py):
                True for every record, ``"auto"`` for exactly the records whose estimate is
                flagged ``outside`` the training range (``info["refined_rows"]`` says which).
            errors: what a record that cannot be identified does (non-finite samples, an
                all-zero ``y`` or ``u``, a varying ``u`` for an identifier that does not read
                it, ``max|y| / max|u|`` beyond float64; ``records.record_problems``):
                ``"raise"`` (default) raises a ``records.RecordError`` (a ValueError) for the
                first such record, so that nothing is identified from bad data unnoticed;
                ``"collect"`` identifies the good records as a batch of only them would be
                (no record's estimate depends on another's), gives the bad ones NaN model
                rows, and puts each record's reason (None for a good one) in
                ``Estimate.errors``; the bad ones are flagged ``outside`` where the identifier
                knows its range. A malformed argument (wrong shape, complex, no records)
                raises in both modes.

        Returns:
            An ``Estimate``; batched when ``y`` is.

        Records are normalised (Eq. 15) per record in float64 before the encoder's float32,
        and the model is de-normalised in float64, so a record's estimate does not depend on
        the other records of its batch, whatever their magnitudes.
        """
        start = time.perf_counter()
        if refine not in (True, False, "auto"):
            raise ValueError(f"refine must be True, False or 'auto'; got {refine!r}")
        if errors not in ERROR_MODES:
            raise ValueError(f"errors must be one of {ERROR_MODES}; got {errors!r}")
        if dt is not None and not _same_dt(dt, self._dts):
            raise ValueError(f"dt must be {self.dt} s for this identifier (trained on records of "
                             f"{self.steps} samples at dt={self.dt}); got dt={dt!r}")
        if self.records > 1:
            return self._identify_several(y, u, start, refine, errors)
        checked = check_records(y, u, steps=self.steps, dt=self.dt, reads_u=self.inputs)
        if errors == "raise":
            checked.raise_first()
        good = checked.good
        y2, u2 = checked.y, checked.u
        with np.errstate(over="ignore", invalid="ignore"):   # overflow: _overflowed says it
            if good.all():
                A, b, c, d, el = self._encode(y2, u2)
            else:
                rows = np.flatnonzero(good)
                n, q = self.structure.n, len(self.structure.element_names)
                A, b, c, d, el = (np.full((checked.count, *shape), math.nan)
                                  for shape in ((n, n), (n,), (n,), (), (q,)))
                if rows.size:
                    parts = self._encode(y2[rows], None if u2 is None else u2[rows])
                    for whole, part in zip((A, b, c, d, el), parts, strict=True):
                        whole[rows] = part
        problems = _overflowed(checked.problems, good, (A, b, c, d, el), y2, u2)
        if errors == "raise":
            Checked(y2, u2, checked.batched, problems).raise_first()
        return self._estimate(A, b, c, d, el, y2, u2, checked.batched, start, refine,
                              None if errors == "raise" else problems)

    def _encode(self, y2: np.ndarray, u2: np.ndarray | None):
        """Float64 ``A (count, n, n), b, c (count, n), d (count,), elements (count, q)`` of
        good records ``y2 (count, steps)``, ``u2`` (or None): the batch-1 path for one record,
        the batched one otherwise."""
        fast = self._fast() if y2.shape[0] == 1 else None
        if fast is not None:
            return fast(y2[0], None if u2 is None else u2[0])
        return self._batched([y2], [u2])

    def _batched(self, ys: list[np.ndarray], us: list[np.ndarray | None]):
        """Float64 ``A, b, c, d, elements`` of good records ``ys, us`` (one float64
        ``(count, steps_r)`` array per record; None for a unit step) through the encoder, in
        chunks, without gradients.

        Eq. 15 runs per record in float64 (``records.normalise``) and only the normalised
        records, in ``[-1, 1]``, and the standardised scale features are cast to the encoder's
        float32; the model is de-normalised in float64. So one record of 1e40 (beyond float32)
        or 1e-44 (below its normal range) among others gives what it gives alone."""
        count = ys[0].shape[0]
        x, gains = [], []
        for y2, u2 in zip(ys, us, strict=True):
            y_tilde, u_tilde, y_bar, u_bar = normalise(y2, u2)
            channels = [y_tilde, u_tilde] if self.inputs else [y_tilde]
            x.append(torch.from_numpy(np.stack(channels, axis=1).astype(np.float32)))
            gains.append(y_bar / u_bar)
        gain = np.stack(gains, axis=1)                                   # (count, R)
        features = None
        if self.scale == "feature":
            mean, spread = (f.numpy() for f in self._features)
            features = torch.from_numpy(((np.log(gain) - mean) / spread).astype(np.float32))
        # Small batches are dominated by per-operation overhead, which a second thread only
        # adds to (thread wake-ups); large ones gain from both cores.
        threads = torch.get_num_threads()
        if count <= 16 and threads > 1:
            torch.set_num_threads(1)
        try:
            with torch.no_grad():
                # Chunks of 1024 records keep the activations in cache: measured, batches
                # of 16k in one pass ran at half the throughput of chunks of 1k.
                parts = []
                for i in range(0, count, 1024):
                    sys, el, _ = self._decode([v[i: i + 1024] for v in x],
                                              None if features is None
                                              else features[i: i + 1024])
                    parts.append((sys.A, sys.b, sys.c, sys.d, el))
                A, b, c, d, el = (torch.cat(t).numpy().astype(np.float64)
                                  for t in zip(*parts, strict=True))
        finally:
            if torch.get_num_threads() != threads:
                torch.set_num_threads(threads)
        if self.scale == "denormalise":
            # Exact de-normalisation (linearity), in float64: the structure described
            # u/u_bar -> y/y_bar. A product, not el * (1 + mask (g - 1)), which is 0 for g=1e-44.
            g = gain[:, 0]
            c, d = c * g[:, None], d * g
            el = np.where(self._output_mask.numpy()[0] > 0, el * g[:, None], el)
        return A, b, c, d, el

    def _identify_several(self, y, u, start: float, refine: bool, errors: str) -> Estimate:
        """``identify`` for a several-record identifier: ``y``, ``u`` sequences of R records."""
        R, grids = self.records, list(zip(self.encoder.config.record_steps, self._dts,
                                          strict=True))
        if isinstance(y, (np.ndarray, torch.Tensor)) or not hasattr(y, "__len__") \
                or len(y) != R:
            raise ValueError(f"y must be a sequence of {R} records (one per subsystem: "
                             f"{', '.join(f'{s} samples at dt={t}' for s, t in grids)}); "
                             f"got {type(y).__name__}")
        if u is not None and (isinstance(u, (np.ndarray, torch.Tensor))
                              or not hasattr(u, "__len__") or len(u) != R):
            raise ValueError(f"u must be None (unit steps) or a sequence of {R} inputs, one per "
                             f"record; got {type(u).__name__}")
        if refine:
            raise ValueError("refine=True is not available for a several-record identifier: "
                             "the refinement fits one record; refine each subsystem's estimate "
                             "in its own structure")
        checks = []
        for r, (steps, dt) in enumerate(grids):
            checked = check_records(y[r], None if u is None else u[r], steps=steps, dt=dt,
                                    reads_u=self.inputs, names=(f"y[{r}]", f"u[{r}]"))
            if checks and (checked.batched != checks[0].batched
                           or checked.count != checks[0].count):
                raise ValueError(f"y[{r}] must be batched like y[0] ({checks[0].count} "
                                 f"record(s), batch axis {checks[0].batched}); got shape "
                                 f"{np.shape(y[r])}")
            checks.append(checked)
        # A system's row is good when each of its R records is; its reason is the first one's.
        problems = tuple(next((c.problems[i] for c in checks if c.problems[i] is not None),
                              None) for i in range(checks[0].count))
        if errors == "raise":
            for c in checks:
                c.raise_first()
        ys = [c.y for c in checks]
        us = [np.ones_like(c.y) if c.u is None else np.asarray(c.u) for c in checks]
        good = np.array([p is None for p in problems])
        count, n, q = len(problems), self.structure.n, len(self.structure.element_names)
        A, b, c, d = (np.full((count, R, *shape), math.nan)
                      for shape in ((n, n), (n,), (n,), ()))
        el = np.full((count, q), math.nan)
        rows = np.flatnonzero(good)
        if rows.size:
            parts = self._batched([v[rows] for v in ys], [v[rows] for v in us])
            for whole, part in zip((A, b, c, d, el), parts, strict=True):
                whole[rows] = part
        names = self.structure.element_names
        batched = checks[0].batched
        collected = None if errors == "raise" else problems
        if batched:
            elements = {name: el[:, i] for i, name in enumerate(names)}
            y_out, u_out = tuple(ys), tuple(us)
        else:
            elements = dict(zip(names, el[0].tolist(), strict=True))
            A, b, c, d = A[0], b[0], c[0], d[0]
            y_out, u_out = tuple(v[0] for v in ys), tuple(v[0] for v in us)
        return Estimate(A, b, c, d, elements, y_out, u_out, self._dts,
                        time.perf_counter() - start, False, {}, self._physical_source(),
                        structure=self.structure, initial=self.initial,
                        training_range=self.training_range, errors=collected)

    def _estimate(self, A, b, c, d, el, y2, u2, batched, start, refine,
                  errors=None) -> Estimate:
        """Wrap float64 arrays ``A (count, n, n)``, ..., ``el (count, q)`` as an Estimate."""
        if u2 is None:
            u2 = np.ones_like(y2)
        if batched:
            elements = {name: el[:, i] for i, name in enumerate(self.structure.element_names)}
            est = Estimate(A, b, c, d, elements, y2, np.asarray(u2), self.dt,
                           time.perf_counter() - start, False, {}, self._physical_source(),
                           structure=self.structure, initial=self.initial,
                           training_range=self.training_range, errors=errors)
        else:
            elements = dict(zip(self.structure.element_names, el[0].tolist(), strict=True))
            est = Estimate(A[0], b[0], c[0], float(d[0]), elements, y2[0], np.asarray(u2)[0],
                           self.dt, time.perf_counter() - start, False, {},
                           self._physical_source(), structure=self.structure,
                           initial=self.initial, training_range=self.training_range,
                           errors=errors)
        if refine:
            from aeid_struct.refinement import refine as _refine

            if refine == "auto":
                return self._refine_flagged(est, _refine)
            if est._good is not None:      # errors="collect" set records aside: refine the rest
                return self._refine_rows(est, est._good, _refine)
            est = _refine(est, est.y, est.u, self.dt, structure=self.structure)
        return est

    def _refine_flagged(self, est: Estimate, _refine) -> Estimate:
        """``refine="auto"``: refine exactly the records flagged ``outside`` (and identified:
        a record set aside by ``errors="collect"`` has nothing to start from)."""
        flags = est.outside
        if flags is None:
            raise ValueError("refine='auto' needs an identifier that knows its calibrated "
                             "training range (trained by this version of train(), a shipped "
                             "one, or one passed through training.recalibrate)")
        good = est._good
        if not est.batched:
            if not flags or (good is not None and not good[0]):
                return dataclasses.replace(est, info={**est.info, "refined_rows": False})
            est = _refine(est, est.y, est.u, self.dt, structure=self.structure)
            return dataclasses.replace(est, info={**est.info, "refined_rows": True})
        return self._refine_rows(est, flags if good is None else flags & good, _refine)

    def _refine_rows(self, est: Estimate, mask: np.ndarray, _refine) -> Estimate:
        """Refine the records ``mask (batch,)`` of a batched estimate, keep the others;
        ``info["refined_rows"]`` is ``mask``, ``info["refine"]`` the refinement's info."""
        rows = np.flatnonzero(mask)
        if rows.size == 0:
            return dataclasses.replace(est, info={**est.info, "refined_rows": mask})
        sub = _refine(est.take(rows), est.y[rows], est.u[rows], self.dt,
                      structure=self.structure)
        A, b, c, d = (np.array(x, copy=True) for x in (est.A, est.b, est.c, est.d))
        A[rows], b[rows], c[rows], d[rows] = sub.A, sub.b, sub.c, sub.d
        elements = {k: np.array(v, copy=True) for k, v in est.elements.items()}
        for k in elements:
            elements[k][rows] = sub.elements[k]
        return dataclasses.replace(
            est, A=A, b=b, c=c, d=d, elements=elements, refined=True,
            seconds=est.seconds + sub.info["seconds"].sum(),
            info={**est.info, "refined_rows": mask, "refine": sub.info})

    def _physical_source(self):
        from aeid_struct.structures import Physical

        if isinstance(self.structure, Physical):
            return ("elements", tuple(self.structure.element_names))
        return self.inverse

    # -- files ---------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The JSON header: everything but the weights. Data only: the inverse map (and a
        Physical structure's maps) as references to named factories (``aeid_struct.maps``), a
        user's own map as its name and SHA-256 (with its serialisation, read only under
        ``trust=True``)."""
        from aeid_struct.structures import maps as maps

        return {
            "format": FORMAT,
            "encoder": self.encoder.config.to_dict(),
            "structure": self.structure.config(),
            "dt": self.dt,
            "scale": self.scale,
            "initial": self.initial,
            "feature_mean": self.feature_mean,
            "feature_scale": self.feature_scale,
            "inverse": None if self.inverse is None else maps.to_entry(self.inverse),
            "meta": self.meta,
        }

    def save(self, path) -> Path:
        """Write the identifier to ``path`` (safetensors: weights + JSON header)."""
        from safetensors.torch import save_file

        path = writable_file(path)
        tensors = {f"encoder.{k}": v.detach().contiguous()
                   for k, v in self.encoder.state_dict().items()}
        tensors["theta_mean"] = self.theta_mean.contiguous()
        tensors["theta_scale"] = self.theta_scale.contiguous()
        save_file(tensors, str(path), metadata={"aeid": json.dumps(self.to_dict())})
        return path

    @classmethod
    def load(cls, path, *, maps: dict | None = None, trust: bool = False) -> Identifier:
        """Read an identifier written by ``save``. Parses JSON and raw tensors only.

        Args:
            path: the ``.aeid`` file.
            maps: name -> casadi.Function: the user maps the file names (a ``Physical``
                structure's map or an inverse that is not a named map of ``aeid_struct.maps``),
                passed again; each must have the SHA-256 the file recorded.
            trust: deserialise the user maps, and the CasADi Functions of files in the format
                before named maps (``FORMAT_1``), from the file itself. A serialised CasADi
                Function can run shell commands when it is read: only for files you trust.

        Raises:
            ValueError: naming the file and what is wrong: not an identifier file, a corrupted
                header or weights, or a map the file cannot name without ``maps``/``trust``.
        """
        from safetensors import safe_open

        from aeid_struct.structures import maps as _maps

        if not isinstance(path, (str, os.PathLike)) or not str(path):
            raise ValueError(f"path must be an existing identifier file (str or Path); got "
                             f"{path!r}")
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"path must be an existing identifier file; got {str(path)!r}")
        try:
            with safe_open(str(path), framework="pt") as f:
                header = json.loads((f.metadata() or {}).get("aeid", "null"))
                tensors = {k: f.get_tensor(k) for k in f.keys()}
        except Exception as err:  # safetensors raises its own error types
            raise ValueError(f"path {str(path)!r} is not an aeid-struct identifier file "
                             f"(safetensors + JSON header): {err}") from None
        if not isinstance(header, dict) or header.get("format") not in (FORMAT, FORMAT_1):
            raise ValueError(f"path {str(path)!r} is not an aeid-struct identifier file: "
                             f"its header format is not {FORMAT!r}")
        _maps.check_maps(maps, trust)
        source = f"identifier file {str(path)!r}"
        if header["format"] == FORMAT_1:
            source += f" (format {FORMAT_1!r}, which stored CasADi maps as code)"
        return cls._from_parts(header, tensors, source=source, maps=maps, trust=trust)

    @classmethod
    def _from_parts(cls, header: dict, tensors: dict, *, source: str = "header",
                    maps: dict | None = None, trust: bool = False) -> Identifier:
        """The identifier of a parsed header and its tensors; one ValueError naming ``source``
        and what is wrong for anything malformed."""
        from aeid_struct.structures import maps as _maps

        _check_header(header, source)
        try:
            config = EncoderConfig.from_dict(header["encoder"])
        except (TypeError, ValueError) as err:
            raise ValueError(f"{source}: 'encoder' is not a valid encoder configuration: "
                             f"{err}") from None
        try:
            # First on the meta device, which allocates nothing: a header that describes a huge
            # network (width 1e8) is refused by the shapes of the weights the file really holds,
            # before any memory is taken for it.
            with torch.device("meta"):
                expected = {f"encoder.{k}": tuple(v.shape)
                            for k, v in Encoder(config).state_dict().items()}
        except ValueError as err:
            raise ValueError(f"{source}: 'encoder': {err}") from None
        _check_weights(expected, tensors, source)
        encoder = Encoder(config)
        _load_weights(encoder, tensors, source)
        _check_structure_size(header["structure"], config.outputs, source)
        try:
            structure = Structure.from_config(header["structure"], maps=maps, trust=trust)
            inverse = header.get("inverse")
            if inverse is not None:
                inverse = _maps.from_entry(inverse, "'inverse'", maps=maps, trust=trust)
            dt = header["dt"]
            ident = cls(
                encoder, structure,
                dt=tuple(dt) if isinstance(dt, list) else dt,
                theta_mean=tensors["theta_mean"],
                theta_scale=tensors["theta_scale"],
                scale=header["scale"],
                initial=header.get("initial", "rest"),
                feature_mean=header["feature_mean"],
                feature_scale=header["feature_scale"],
                inverse=inverse,
                meta=header.get("meta", {}),
            )
        except ValueError as err:
            raise ValueError(f"{source}: {err}") from None
        return ident


def writable_file(path) -> Path:
    """``path`` (str or PathLike) as a Path to a file that can be written, its folder created;
    a ValueError naming ``path`` for anything else (not a path, a directory, a file where its
    folder should be)."""
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ValueError(f"path must be a file name (str or Path); got {path!r}")
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"path must be a file to write; {str(path)!r} is a directory")
    folder = next((p for p in path.parents if p.exists()), None)
    if folder is not None and not folder.is_dir():
        raise ValueError(f"path must be a file to write; {str(path)!r} lies below "
                         f"{str(folder)!r}, which is a file")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


#: Header entries: required ones, and optional ones with the JSON types they may have.
_HEADER_REQUIRED = ("format", "encoder", "structure", "dt", "scale", "feature_mean",
                    "feature_scale")
_HEADER_OPTIONAL = ("initial", "inverse", "meta")


def _numbers(value, finite: bool = True) -> bool:
    """A JSON number, or a non-empty list of them (finite when ``finite``)."""
    values = value if isinstance(value, list) and value else [value]
    return all(isinstance(v, (int, float)) and not isinstance(v, bool)
               and (not finite or math.isfinite(v)) for v in values)


def _check_header(header: dict, source: str) -> None:
    """Entries and JSON types of an identifier header (one ValueError naming ``source``)."""
    from aeid_struct.encoder import EncoderConfig as _Config

    unknown = sorted(set(header) - set(_HEADER_REQUIRED) - set(_HEADER_OPTIONAL))
    if unknown:
        raise ValueError(f"{source}: the header has unknown entries {unknown}; an identifier "
                         f"header has {', '.join(_HEADER_REQUIRED + _HEADER_OPTIONAL)}")
    missing = [k for k in _HEADER_REQUIRED if k not in header]
    if missing:
        raise ValueError(f"{source}: the header is missing {', '.join(map(repr, missing))}")
    checks = {
        "encoder": (isinstance(header["encoder"], dict), "a dict"),
        "structure": (isinstance(header["structure"], dict), "a dict"),
        "dt": (_numbers(header["dt"]), "a finite number or a list of them"),
        "scale": (isinstance(header["scale"], str), "a string"),
        "initial": (isinstance(header.get("initial", "rest"), str), "a string"),
        "feature_mean": (_numbers(header["feature_mean"]), "a finite number or a list of them"),
        "feature_scale": (_numbers(header["feature_scale"]),
                          "a finite number or a list of them"),
        "meta": (isinstance(header.get("meta", {}), dict), "a dict"),
        "inverse": (header.get("inverse") is None
                    or isinstance(header["inverse"], (dict, str)), "a map reference or null"),
    }
    for key, (ok, expected) in checks.items():
        if not ok:
            got = header[key]
            text = repr(got) if len(repr(got)) <= 80 else f"{repr(got)[:60]}..."
            raise ValueError(f"{source}: header entry {key!r} must be {expected}; got {text}")
    rng = header.get("meta", {}).get("training_range")
    if rng:   # read by Estimate.outside: {"elements"/"physical": {name: [lo, hi, err]}, ...}
        ok = isinstance(rng, dict) and set(rng) <= {"elements", "physical", "fit", "excess"}
        for group in ("elements", "physical"):
            part = rng.get(group, {}) if ok else None
            ok = ok and isinstance(part, dict) and all(
                isinstance(v, list) and len(v) == 3 and _numbers(v) for v in part.values())
        ok = ok and all(_numbers(rng[k]) and not isinstance(rng[k], list)
                        for k in ("fit", "excess") if k in rng)
        if not ok:
            text = repr(rng) if len(repr(rng)) <= 80 else f"{repr(rng)[:60]}..."
            raise ValueError(f"{source}: 'meta' entry 'training_range' must be "
                             "{'elements': {name: [lo, hi, err]}, 'physical': {...}, 'fit': "
                             f"number, 'excess': number}}; got {text}")
    fields = {f.name for f in dataclasses.fields(_Config)}
    unknown = sorted(set(header["encoder"]) - fields)
    if unknown:
        raise ValueError(f"{source}: 'encoder' has unknown entries {unknown}; an encoder "
                         f"configuration has {', '.join(sorted(fields))}")
    if not isinstance(header["encoder"].get("inputs", False), bool):
        raise ValueError(f"{source}: 'encoder' entry 'inputs' must be true or false; got "
                         f"{header['encoder']['inputs']!r}")


def _check_structure_size(config, outputs: int, source: str) -> None:
    """A canonical structure's size against the encoder's outputs, before it is built: a header
    with ``{"type": "CCF", "n": 100000000}`` would otherwise spend minutes and gigabytes on its
    element maps before any later check refused it. Every element is a raw parameter
    (``outputs`` of them) or fixed (listed in the config)."""
    kind = config.get("type")
    if kind not in ("CCF", "MCF"):
        return            # Physical: one element per input of a map from the allow-list
    sizes = [config.get(k, 0) for k in (("n",) if kind == "CCF" else ("real", "pairs"))]
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in sizes):
        return            # from_config names the bad entry
    n = sizes[0] if kind == "CCF" else sizes[0] + 2 * sizes[1]
    fixed = config.get("fixed") or {}
    elements = 2 * n + (1 if config.get("feedthrough") else 0)
    if elements > outputs + (len(fixed) if isinstance(fixed, dict) else 0):
        raise ValueError(f"{source}: 'structure' {kind} of order {n} has {elements} elements, "
                         f"more than the encoder's {outputs} outputs and "
                         f"{len(fixed) if isinstance(fixed, dict) else 0} fixed elements")


def _check_weights(expected: dict, tensors: dict, source: str) -> None:
    """The file's tensors against ``expected`` (name -> shape of the encoder the header
    describes): every one there, none more, each of its shape."""
    missing = [k for k in (*expected, "theta_mean", "theta_scale") if k not in tensors]
    if missing:
        raise ValueError(f"{source}: weights {missing} are missing (the header's 'encoder' "
                         "describes them)")
    unknown = sorted(set(tensors) - set(expected) - {"theta_mean", "theta_scale"})
    if unknown:
        raise ValueError(f"{source}: unknown weights {unknown} (not in the encoder the header "
                         "describes)")
    for key, shape in expected.items():
        if tuple(tensors[key].shape) != shape:
            raise ValueError(f"{source}: weight {key!r} has shape {tuple(tensors[key].shape)}; "
                             f"the header's 'encoder' needs {shape}")


def _load_weights(encoder: Encoder, tensors: dict, source: str) -> None:
    """Check the file's tensors against the encoder the header describes (names, shapes,
    finite floats) and load them; one ValueError naming ``source`` and the tensor."""
    expected = {f"encoder.{k}": tuple(v.shape) for k, v in encoder.state_dict().items()}
    missing = [k for k in (*expected, "theta_mean", "theta_scale") if k not in tensors]
    if missing:
        raise ValueError(f"{source}: weights {missing} are missing (the header's 'encoder' "
                         "describes them)")
    unknown = sorted(set(tensors) - set(expected) - {"theta_mean", "theta_scale"})
    if unknown:
        raise ValueError(f"{source}: unknown weights {unknown} (not in the encoder the header "
                         "describes)")
    for key in (*expected, "theta_mean", "theta_scale"):      # the encoder's layer order
        tensor = tensors[key]
        if key in expected and tuple(tensor.shape) != expected[key]:
            raise ValueError(f"{source}: weight {key!r} has shape {tuple(tensor.shape)}; the "
                             f"header's 'encoder' needs {expected[key]}")
        if not tensor.is_floating_point() or not bool(torch.isfinite(tensor).all()):
            raise ValueError(f"{source}: weight {key!r} must hold finite floating-point "
                             f"numbers; got dtype {tensor.dtype}"
                             + ("" if not tensor.is_floating_point() else " with non-finite "
                                "values"))
    encoder.load_state_dict({k[len("encoder."):]: v for k, v in tensors.items()
                             if k.startswith("encoder.")})
    encoder.eval()


_NUMPY_ACTIVATIONS = {"tanh": np.tanh, "relu": lambda x: np.maximum(x, 0.0)}


class _Batch1:
    """One record through the identifier without per-operation torch overhead.

    The encoder is evaluated in numpy (float64 copies of the weights): average pooling by a
    reshape, each "same" convolution as one matmul over a strided im2col view, then the dense
    layers; the structure (theta -> elements -> A, b, c, d) runs as a frozen TorchScript trace
    (or eagerly for CasADi-backed structures). Returns float64 ``A (1, n, n), b, c (1, n),
    d (1,), elements (1, q)``, in measured units like ``Identifier._forward``.
    """

    def __init__(self, ident: Identifier):
        import warnings

        from aeid_struct.structures import Physical

        enc = ident.encoder
        cfg = enc.config
        if cfg.activation not in _NUMPY_ACTIVATIONS:
            raise ValueError(f"no numpy path for activation {cfg.activation!r}")
        self.act = _NUMPY_ACTIVATIONS[cfg.activation]
        sd = {k: v.detach().double().numpy() for k, v in enc.state_dict().items()}
        self.cfg = cfg
        self.pad = cfg.kernel // 2
        self.length = cfg.steps // cfg.pool
        self.window = np.arange(cfg.kernel)[:, None] + np.arange(self.length)[None, :]
        self.convs = [(sd[f"main.{2 * i}.weight"].reshape(cfg.width, -1),
                       sd[f"main.{2 * i}.bias"][:, None]) for i in range(cfg.depth)]
        self.shortcut = (sd["shortcut.0.weight"].reshape(cfg.width, -1),
                         sd["shortcut.0.bias"][:, None])
        self.dense = [(sd[f"head.{2 * i}.weight"], sd[f"head.{2 * i}.bias"])
                      for i in range(len(cfg.dense) + 1)]
        self.mean = ident.theta_mean.double().numpy()
        self.scale = ident.theta_scale.double().numpy()
        self.ident = ident
        self.mask = ident._output_mask.double().numpy()[0]
        structure = ident.structure

        class _Structure(torch.nn.Module):
            def forward(self, theta):
                el = structure.elements(theta)
                sys = structure.assemble(el)
                return sys.A, sys.b, sys.c, sys.d, el

        self.structure = _Structure().eval()
        if not isinstance(structure, Physical):
            with warnings.catch_warnings(), torch.no_grad():
                warnings.simplefilter("ignore")
                self.structure = torch.jit.freeze(torch.jit.trace(
                    self.structure, (torch.zeros(1, structure.p, dtype=torch.float64),),
                    check_trace=False))

    def _conv(self, h: np.ndarray, W: np.ndarray, b: np.ndarray) -> np.ndarray:
        """'Same' 1-D convolution (Eq. 8) + activation: ``h (C, L) -> (O, L)``."""
        C, L, p = h.shape[0], self.length, self.pad
        hp = np.zeros((C, L + 2 * p))
        hp[:, p: p + L] = h
        # im2col by one gather: cols[c, k, l] = hp[c, l + k], laid out as torch's (O, C, K)
        return self.act(W @ hp[:, self.window].reshape(C * self.cfg.kernel, L) + b)

    def __call__(self, y: np.ndarray, u: np.ndarray | None):
        cfg = self.cfg
        y_tilde, u_tilde, y_bar, u_bar = normalise(y[None], None if u is None else u[None])
        gain = float(y_bar[0] / u_bar[0])
        x = np.concatenate([y_tilde, u_tilde]) if cfg.inputs else y_tilde     # Eq. 15
        if cfg.pool > 1:
            x = x[:, : self.length * cfg.pool].reshape(x.shape[0], self.length,
                                                       cfg.pool).mean(axis=2)
        h = x
        for W, b in self.convs:
            h = self._conv(h, W, b)
        z = np.concatenate([h, self._conv(x, *self.shortcut)]).ravel()
        if cfg.features:
            ident = self.ident
            z = np.append(z, (np.log(gain) - ident.feature_mean) / ident.feature_scale)
        for i, (W, b) in enumerate(self.dense):
            z = W @ z + b
            if i < len(self.dense) - 1:
                z = self.act(z)
        theta = torch.from_numpy((self.mean + self.scale * z)[None])
        with torch.no_grad():
            A, b, c, d, el = (t.numpy() for t in self.structure(theta))
        if self.ident.scale == "denormalise":
            c, d = c * gain, d * gain
            # a product, not el * (1 + mask (gain - 1)), which is 0 for gain = 1e-44
            el = np.where(self.mask > 0, el * gain, el)
        return A, b, c, d, el


PRETRAINED = ("leg-stable", "leg-unstable", "leg-stable-noisy", "leg-unstable-noisy",
              "leg-stable-window", "leg-stable-any", "leg-unstable-any")


def load_pretrained(name: str) -> Identifier:
    """An identifier shipped in the package (``PRETRAINED``): ``"leg-stable"``,
    ``"leg-unstable"``, and their noise-trained variants ``"leg-stable-noisy"``,
    ``"leg-unstable-noisy"`` for measured (noisy) records; ``"leg-stable-window"`` reads the
    input too and identifies windows of a running leg under a random binary force (records
    that start mid-motion; the tracker's identifier, ``aeid-struct track``);
    ``"leg-stable-any"`` (windows mid-motion) and ``"leg-unstable-any"`` (records from rest)
    read any reasonably exciting input: steps of random height and timing, binary sequences,
    multisines, filtered noise (their encoder alone is a start for ``refine=True``; accuracy
    in ``pretrained/README.md``)."""
    from importlib.resources import files

    root = files("aeid_struct.pretrained")
    available = sorted(p.name[: -len(".aeid")] for p in root.iterdir()
                       if p.name.endswith(".aeid"))
    if name not in available:
        raise ValueError(f"name must be one of {available}; got {name!r}")
    return Identifier.load(root / f"{name}.aeid")
