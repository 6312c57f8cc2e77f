"""Scorecard: how an identifier does on a validation record set, and how its training went.

A :class:`Score` holds per-record measures of one identifier's estimates against the true
systems behind a ``training.Records`` set (:func:`score`); :meth:`Score.summary` condenses them,
:func:`table` lays several scores side by side as markdown, :func:`training_summary` and
:func:`training_table` do the same for the training histories that ``train()`` records.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from aeid_struct.evaluation.history import DIVERGED_FACTOR as DIVERGED_FACTOR
from aeid_struct.evaluation.history import training_summary as training_summary
from aeid_struct.evaluation.history import training_table as training_table
from aeid_struct.metrics import (
    FREQUENCIES,
    bode_errors,
    nrmse_fit,
    parameter_errors,
    step_error,
)
from aeid_struct.records import unit_step
from aeid_struct.simulation import simulate
from aeid_struct.training import Records

__all__ = ["Score", "pool", "score", "table", "training_summary", "training_table"]

#: How ``table`` labels and formats each summary key: key -> (header, format).
COLUMNS = {
    "count": ("records", "{:d}"),
    "step_mean": ("step error mean", "{:.2e}"),
    "step_median": ("step error median", "{:.2e}"),
    "step_p90": ("step error p90", "{:.2e}"),
    "fit_median": ("fit median (%)", "{:.2f}"),
    "stable_share": ("stable (%)", "{:.1%}"),
    "magnitude_db_mean": ("magnitude mean (dB)", "{:.3f}"),
    "pole_real_max": ("max Re(pole) (1/s)", "{:.3g}"),
    "valid_share": ("valid k,d,m (%)", "{:.1%}"),
    "k_mean": ("Δk mean (%)", "{:.2f}"),
    "d_mean": ("Δd mean (%)", "{:.2f}"),
    "m_mean": ("Δm mean (%)", "{:.2f}"),
    "k_median": ("Δk median (%)", "{:.2f}"),
    "d_median": ("Δd median (%)", "{:.2f}"),
    "m_median": ("Δm median (%)", "{:.2f}"),
    "ms_per_record": ("ms / record", "{:.3f}"),
}
#: The columns ``table`` shows by default.
DEFAULT_COLUMNS = ("count", "step_mean", "step_median", "fit_median", "stable_share",
                   "magnitude_db_mean")
#: Per-record keys that are not parameter errors.
_MEASURES = ("step", "fit", "stable", "magnitude_db", "phase_rad", "valid")


@dataclass(frozen=True)
class Score:
    """Per-record measures of one identifier on one record set.

    Attributes
    ----------
    name : str
        A label for tables and figures.
    per_record : dict of str to (N,) ndarray
        The measures below, one value per record.
    poles : (N, n) complex ndarray
        Poles of the estimates (nan for a non-finite ``A``).
    seconds : float
        Wall time of identifying the whole set (one batched call) [s].

    Notes
    -----
    The per-record measures:

    - ``step``: the paper's Table-I step error (``metrics.step_error``) of the estimate's
      unit-step response against the true system's, both simulated exactly (FOH) on the record
      grid ``t_k = k dt``. A response that overflows (an unstable estimate) counts as ``inf``:
      infinitely wrong, not missing.
    - ``fit``: NRMSE fit in % (``metrics.nrmse_fit``) of the estimate's response to the
      record's own input against the noise-free record ``y_clean`` (so noise does not cap it
      below 100 %); ``-inf`` where that response overflows.
    - ``stable``: ``max Re(eig A) < 0`` of the estimate (False for a non-finite ``A``).
    - ``magnitude_db``, ``phase_rad``: the Bode errors of ``metrics.bode_errors`` over
      ``metrics.FREQUENCIES``.
    - where the true systems carry physical parameters (``Systems.params``, e.g. the leg's
      k, d, m) and the estimate yields them: one ``100 |p_hat - p| / |p|`` column per
      parameter, and ``valid``: every recovered parameter finite and positive.
    """

    name: str
    per_record: dict[str, np.ndarray] = field(repr=False)
    poles: np.ndarray = field(repr=False)
    seconds: float

    def __len__(self) -> int:
        return len(self.per_record["step"])

    @property
    def parameters(self) -> tuple[str, ...]:
        """The physical parameters compared (empty for generic systems)."""
        return tuple(k for k in self.per_record if k not in _MEASURES)

    def summary(self) -> dict[str, float]:
        """Means, medians and shares over the records.

        Returns
        -------
        dict of str to float
            ``count``; ``step_mean``, ``step_median``, ``step_p90`` (90th
            percentile, the order statistic at or above that rank) of the step error, over all
            records (``inf`` counts: an overflowing estimate makes the mean ``inf``, the median
            shows the typical record);
            ``fit_mean``, ``fit_median``; ``stable_share`` (fraction of estimates with
            ``Re(eig A) < 0``); ``magnitude_db_mean``, ``phase_rad_mean`` over the records whose
            Bode error is finite; ``pole_real_max``, the largest real part of any estimated pole
            (the worst stability margin; > 0 for an unstable estimate); ``ms_per_record``; and,
            where parameters are compared, ``valid_share`` and per parameter ``<p>_mean``,
            ``<p>_median`` over the *valid* rows only (nan if none is valid).
        """
        r = self.per_record
        out: dict[str, float] = {"count": len(self)}
        step = r["step"]
        out["step_mean"] = float(np.mean(step))
        out["step_median"] = float(np.median(step))
        # "higher": an order statistic, never an interpolation (inf - inf would give nan)
        out["step_p90"] = float(np.quantile(step, 0.9, method="higher"))
        out["fit_mean"] = float(np.mean(r["fit"]))
        out["fit_median"] = float(np.median(r["fit"]))
        out["stable_share"] = float(np.mean(r["stable"]))
        for key in ("magnitude_db", "phase_rad"):
            v = r[key][np.isfinite(r[key])]
            out[f"{key}_mean"] = float(np.mean(v)) if v.size else math.nan
        real = self.poles.real
        out["pole_real_max"] = float(np.nanmax(real)) if np.any(np.isfinite(real)) else math.nan
        out["ms_per_record"] = 1e3 * self.seconds / max(len(self), 1)
        if "valid" in r:
            valid = r["valid"]
            out["valid_share"] = float(np.mean(valid))
            for p in self.parameters:
                v = r[p][valid]
                out[f"{p}_mean"] = float(np.mean(v)) if v.size else math.nan
                out[f"{p}_median"] = float(np.median(v)) if v.size else math.nan
        return out


# ---------------------------------------------------------------------------------------------
# Scoring
# ---------------------------------------------------------------------------------------------
def score(ident, records: Records, *, name: str, refine: bool = False,
          inverse=None, record: int | None = None) -> Score:
    """Identify every record of ``records`` with ``ident`` and score the estimates.

    Parameters
    ----------
    ident : Identifier
        Anything with ``dt``, ``steps`` and ``identify(y, u, refine=) -> Estimate``.
    records : training.Records
        The validation set (``training.records``); ``y`` is what the identifier sees (noisy
        where the set has noise), ``y_clean`` and ``systems`` are the truth.
    name : str
        The label of the score.
    refine : bool
        Polish every estimate with the CasADi refinement (``identify(refine=True)``).
    inverse : casadi.Function, optional
        A CCF ``A, B, C, D`` -> physical parameters map. Then every estimate is first converted
        to the bottom-row CCF of its transfer function (characteristic polynomial and Markov
        parameters) and the map applied to that: the parameters are functions of the transfer
        function only (for the stable leg ``m = 1/c_0``, ``k = a_0 m``, ``d = a_1 m``), so this
        recovers them from any realisation, e.g. a modal estimate. Without it
        ``Estimate.physical`` is used.
    record : int, optional
        For an identifier of several records (``ident.records = R > 1``, e.g. the joint leg),
        which record's decoded system to score (0 .. R-1); the identifier reads all of them,
        and the physical parameters (one set) are scored with every record.

    Returns
    -------
    Score
        Parameter columns where both the truth and the estimate have parameters.

    Raises
    ------
    ValueError
        An argument of the wrong kind, records off the identifier's grid, or an inverse map
        of another order.
    """
    R = getattr(ident, "records", 1)
    if R > 1:
        if not isinstance(record, int) or not 0 <= record < R:
            raise ValueError(f"record must name the record to score (0 .. {R - 1}) for an "
                             f"identifier of {R} records; got {record!r}")
        if inverse is not None:
            raise ValueError("inverse must be None for an identifier of several records: its "
                             "physical parameters are its elements")
        _check_arguments(ident, records, name, record)
        est, seconds = _identify(ident, records, refine)
        records = records.record(record)
        A, b, c, d = (np.asarray(x, dtype=np.float64)[:, record]
                      for x in (est.A, est.b, est.c, est.d))
    else:
        if record not in (None, 0):
            raise ValueError(f"record must be None for an identifier of one record; "
                             f"got {record!r}")
        _check_arguments(ident, records, name)
        est, seconds = _identify(ident, records, refine)
        A, b, c, d = (np.asarray(x, dtype=np.float64) for x in (est.A, est.b, est.c, est.d))
    _check_inverse(inverse, A.shape[-1])
    per_record = _accuracy((A, b, c, d), records)
    poles = _poles(A)
    per_record["stable"] = np.all(poles.real < 0, axis=1)
    physical = _physical(est, (A, b, c, d), inverse)
    truth = records.systems.params
    if truth and physical:
        shared = [p for p in physical if p in truth]
        if shared:
            found = {p: physical[p] for p in shared}
            per_record.update(parameter_errors(truth, found))
            per_record["valid"] = _valid(found)
    return Score(name, per_record, poles, seconds)


def _check_arguments(ident, records, name, record: int | None = None) -> None:
    """Validate the arguments of ``score``; ``record``: the record of a several-record
    identifier whose grid the records' record ``record`` must be on."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"name must be a non-empty string; got {name!r}")
    if not isinstance(records, Records):
        raise ValueError(f"records must be a data.Records set (data.records(...)); "
                         f"got {type(records).__name__}")
    for attr in ("identify", "dt", "steps"):
        if not hasattr(ident, attr):
            raise ValueError(f"ident must be an Identifier (with {attr!r}); "
                             f"got {type(ident).__name__}")
    dt, steps = ident.dt, ident.steps
    if record is not None:
        dt, steps, records = dt[record], steps[record], records.record(record)
    got = records.u.shape[1]
    if not math.isclose(records.dt, dt, rel_tol=1e-9) or got != steps:
        raise ValueError(
            f"records must be on the identifier's grid (dt={dt}, steps={steps}); "
            f"got dt={records.dt}, steps={got}")


def _check_inverse(inverse, n: int) -> None:
    if inverse is None:
        return
    if not all(hasattr(inverse, m) for m in ("name_in", "name_out", "size_in", "map")):
        raise ValueError(f"inverse must be a casadi.Function CCF (A, B, C, D) -> parameters; "
                         f"got {type(inverse).__name__}")
    names = list(inverse.name_in())
    if names[:4] != ["A", "B", "C", "D"] or tuple(inverse.size_in("A")) != (n, n):
        shapes = {k: tuple(inverse.size_in(k)) for k in names}
        raise ValueError(f"inverse must take A ({n}, {n}), B, C, D of the estimates' order "
                         f"n = {n}; got inputs {shapes}")


def _identify(ident, records: Records, refine: bool):
    """One batched identification of the whole set: ``(Estimate, seconds)``."""
    start = time.perf_counter()
    est = ident.identify(records.y, records.u, refine=refine)
    return est, time.perf_counter() - start


def _accuracy(model: tuple, records: Records) -> dict[str, np.ndarray]:
    """``step``, ``fit``, ``magnitude_db``, ``phase_rad`` of ``model = (A, b, c, d)`` (batched
    like ``records``) against the true systems."""
    sys = records.systems
    steps = records.u.shape[1]
    step_input = unit_step(steps)
    y_true = simulate(sys.A, sys.b, sys.c, sys.d, step_input, records.dt)
    # An unstable estimate may overflow: it is scored below, so the decoder's warning (its
    # OverflowWarning, a RuntimeWarning) is noise.
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        y_step = simulate(*model, step_input, records.dt)
        # step records (the usual case) need no second simulation
        y_hat = y_step if np.all(records.u == 1.0) else simulate(*model, records.u, records.dt)
        err = step_error(y_true, y_step)
        fit = nrmse_fit(records.y_clean, y_hat)
        magnitude, phase = bode_errors((sys.A, sys.b, sys.c, sys.d), model, FREQUENCIES)
    overflow = ~np.all(np.isfinite(y_step), axis=1) | ~np.isfinite(err)
    err[overflow] = math.inf
    fit[~np.all(np.isfinite(y_hat), axis=1) | ~np.isfinite(fit)] = -math.inf
    return {"step": err, "fit": fit, "magnitude_db": magnitude, "phase_rad": phase}


def _poles(A: np.ndarray) -> np.ndarray:
    """Eigenvalues ``(N, n)`` of ``A (N, n, n)``; nan rows where ``A`` is not finite."""
    poles = np.full(A.shape[:2], complex(math.nan, math.nan))
    finite = np.all(np.isfinite(A), axis=(1, 2))
    if finite.any():
        poles[finite] = np.linalg.eigvals(A[finite])
    return poles


def _physical(est, model: tuple, inverse) -> dict[str, np.ndarray]:
    """Physical parameters ``name -> (N,)`` of the estimates (module docstring), or {}."""
    if inverse is None:
        return {k: np.atleast_1d(np.asarray(v, dtype=np.float64))
                for k, v in (est.physical or {}).items()}
    from aeid_struct.identification import through_ccf

    return through_ccf(*model, inverse)


def _valid(params: Mapping[str, np.ndarray]) -> np.ndarray:
    """Rows where every physical parameter is finite and positive."""
    stacked = np.stack([np.asarray(v, dtype=np.float64) for v in params.values()])
    with np.errstate(invalid="ignore"):
        return np.all(np.isfinite(stacked) & (stacked > 0), axis=0)


def pool(scores: Sequence[Score], *, name: str) -> Score:
    """One score over the records of several, e.g. the identifiers of several training seeds on
    the same validation set.

    Parameters
    ----------
    scores : sequence of Score
        Scores with the same measures.
    name : str
        The label of the pooled score.

    Returns
    -------
    Score
        Per-record arrays and poles concatenated (poles padded with nan to the largest
        order), seconds added.

    Raises
    ------
    ValueError
        No score, or scores with different measures.
    """
    scores = list(scores)
    if not scores or not all(isinstance(s, Score) for s in scores):
        raise ValueError("scores must be a non-empty sequence of Score")
    keys = set(scores[0].per_record)
    for s in scores[1:]:
        if set(s.per_record) != keys:
            raise ValueError(f"scores must have the same measures to be pooled; "
                             f"{s.name!r} has {sorted(s.per_record)}, "
                             f"{scores[0].name!r} has {sorted(keys)}")
    n = max(s.poles.shape[1] for s in scores)
    poles = np.concatenate([np.pad(s.poles, ((0, 0), (0, n - s.poles.shape[1])),
                                   constant_values=complex(math.nan, math.nan))
                            for s in scores])
    per_record = {k: np.concatenate([s.per_record[k] for s in scores])
                  for k in scores[0].per_record}
    return Score(name, per_record, poles, float(sum(s.seconds for s in scores)))


def table(scores: Sequence[Score], columns: Sequence[str] = DEFAULT_COLUMNS) -> str:
    """A markdown table, one row per score, one column per summary key.

    Parameters
    ----------
    scores : sequence of Score
        One row each.
    columns : sequence of str
        Keys of ``COLUMNS`` (which names them with their headers); a key a score lacks shows
        as ``-``.

    Returns
    -------
    str

    Raises
    ------
    ValueError
        No score, or an unknown column.
    """
    scores = list(scores)
    if not scores or not all(isinstance(s, Score) for s in scores):
        raise ValueError("scores must be a non-empty sequence of Score")
    unknown = [c for c in columns if c not in COLUMNS]
    if unknown:
        raise ValueError(f"columns must be keys of scorecard.COLUMNS ({', '.join(COLUMNS)}); "
                         f"got {unknown}")
    lines = ["| identifier | " + " | ".join(COLUMNS[c][0] for c in columns) + " |",
             "|---|" + "---:|" * len(columns)]
    for s in scores:
        summary = s.summary()
        cells = [_format(summary.get(c), COLUMNS[c][1]) for c in columns]
        lines.append(f"| {s.name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _format(value, fmt: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return fmt.format(value)
