"""Benchmark of the generic identifiers (issue 14): any system, any record.

Unseen systems are drawn from :class:`~aeid_struct.training.GenericFamily` with seeds the
shipped identifiers were not trained on, at a random sample time ``dt`` (log-uniform in
``[1e-3, 1]`` s: the identifiers work in normalised time), with an input delay of 0-5 samples,
random input/output offsets, a mid-motion start and white output noise. Each simulated run of
``2 L`` samples is split: the first ``L`` samples are the estimation record, the last ``L`` the
validation record (a run whose validation half has a constant input -- a step early in the run
-- is redrawn: every model, the true one included, scores 0 on it). Methods, on the estimation
record:

* ``encoder``: ``ae.identify(record, order=n, refine=False, iterations=0, classical=False)``
  (the encoder's pass alone: its candidates, whole-record projection),
* ``one pass, no SM``: ``ae.identify(record, order=n, refine=False, classical=False)`` (the
  encoder's candidates alone, projection, the one pass's few Levenberg-Marquardt iterations: what
  amortization gives without the classical estimator),
* ``one pass``: ``ae.identify(record, order=n, refine=False)`` (the encoder's and the
  Steiglitz-McBride candidates, projection, a fixed few Levenberg-Marquardt iterations),
* ``refined``: ``ae.identify(record, order=n)`` (output error on the whole record, iterated to
  convergence from two starts, the delay searched),
* ``refined, D given``: the same with the true input delay given (``record.delay``),
* ``n4sid``: ``baselines.n4sid(record, order=n)`` (no zero padding, free initial state),
* ``least squares``: ``baselines.least_squares(record, order=n)`` (CCF, variable projection),
* ``true``: the system that generated the record (scored on the input it saw: the measured one
  less its offset, which matters for an integrating plant only),

The classical baselines are given the TRUE input delay (they have no delay estimate of their own),
which favours them; the identifiers estimate it (``refined``) or are given it too (``refined, D
given``: the same information as the baselines). Every model is scored on the validation record by
the NRMSE fit with its initial state and output offset fitted (MATLAB's ``compare``), against the
measured (noisy) output -- the true model's fit is the reference there -- and against the
noise-free output (``*_clean``: the true model scores 100).

Also three stand-ins for measured data sets (no data can be downloaded here; all are simulated
with the structure of the public ones): a thermal process sampled at 0.08 s, a lightly damped
mechanical system, and CONTSID's Rao-Garnier benchmark under a zero-order hold (a PRBS held 7
samples through a DAC, SNR 10 dB, ``Record(..., intersample="zoh")``), 1,000 samples each,
estimation on the first half, validation on the second.
"""

from __future__ import annotations

import dataclasses
import json
import time
import warnings
from pathlib import Path

import numpy as np

from aeid_struct.records import Record
from aeid_struct.simulation import fit_initial
from aeid_struct.structures import ccf_matrices
from aeid_struct.studies.generic_tables import METHODS as METHODS
from aeid_struct.studies.generic_tables import PLANTS as PLANTS
from aeid_struct.studies.generic_tables import Row as Row
from aeid_struct.studies.generic_tables import format_tables as format_tables

__all__ = ["METHODS", "PLANTS", "Row", "bench_generic", "format_tables", "measured_stand_ins",
           "write_json"]

#: An unstable plant's growth over its whole simulated run (pre-roll, estimation and validation
#: record): ``e^{0.5}`` to ``e^{4}``, a record of bounded length as an open-loop run must be.
GROWTH = (0.5, 4.0)
#: The methods that estimate the delay (the others are given the true one).
_DELAY_ESTIMATED = ("encoder", "one pass, no SM", "one pass", "refined")


def _score(A, b, c, d, delay: int, validation: Record, clean: np.ndarray) -> tuple[float, float]:
    """Validation fits (x0 and offset fitted) against the measured and the noise-free output."""
    A, b, c = (np.asarray(v, dtype=np.float64) for v in (A, b, c))
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(c))):
        return float("nan"), float("nan")
    with np.errstate(all="ignore"):
        measured = fit_initial(A, b, c, float(d), validation.y, validation.u, validation.dt,
                               delay=delay, intersample=validation.intersample).fit
        truth = fit_initial(A, b, c, float(d), clean, validation.u, validation.dt,
                            delay=delay, intersample=validation.intersample).fit
    return float(measured), float(truth)


def _number(value) -> float:
    """``value`` as a float, NaN for None (an ``info`` entry that did not run)."""
    return float("nan") if value is None else float(value)


def _methods(order: int, identifiers=None):
    """Method name -> callable(record) -> (A, b, c, d, delay) for one order."""
    import aeid_struct as ae
    from aeid_struct import baselines

    def ident(**kwargs):
        def run(record):
            with warnings.catch_warnings():     # counted in the table instead
                warnings.simplefilter("ignore", ae.UnexcitedModeWarning)
                warnings.simplefilter("ignore", ae.UndeterminedModelWarning)
                est = ae.identify(record, order=order, identifier=identifiers, **kwargs)
            return (est.A, est.b, est.c, est.d, int(est.delay), est.info.get("start", ""),
                    len(est.info["unexcited"]), _number(est.info.get("holdout_fit")),
                    _number(est.info.get("holdout_ratio")))
        return run

    def classical(fn):
        def run(record):
            est = fn(record, order=order)
            return est.A, est.b, est.c, est.d, int(record.delay or 0), "", 0, np.nan, np.nan
        return run

    return {"encoder": ident(refine=False, iterations=0, classical=False),
            "one pass, no SM": ident(refine=False, classical=False),
            "one pass": ident(refine=False), "refined": ident(refine=True),
            "refined, D given": ident(refine=True),
            "n4sid": classical(baselines.n4sid),
            "least squares": classical(baselines.least_squares)}


def _case_records(order: int, noise: float, steps: int, count: int, seed: int,
                  plant: str = "stable"):
    """``count`` (estimation, validation, clean validation output, true model) of one cell."""
    from aeid_struct.training import GenericFamily

    family = GenericFamily(order=order, max_delay=5, noise=(noise, noise), offset=0.5)
    if plant != "stable":
        run = 2 * steps + family.preroll[1]
        family = dataclasses.replace(family, **{plant: 1.0},
                                     growth=(GROWTH[0] / run, GROWTH[1] / run))
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < count:
        dt = float(10 ** rng.uniform(-3, 0))
        recs = family.records(1, 2 * steps, rng).at(dt)
        if not np.ptp(recs.u[0, steps:]) > 0:
            continue        # a step early in the run leaves nothing to validate: redrawn
        sy = recs.systems
        D = int(sy.delay[0])
        whole = Record(recs.y[0], recs.u[0], dt)     # delay unknown to the identifiers
        estimation, validation = whole.split(at=steps)
        clean = recs.y_clean[0, steps:]
        # the true model is scored on the input the plant saw (the measured one less its
        # offset): an integrator turns a constant input offset into a ramp that no initial
        # state absorbs, so the measured input would score the generating system far off
        true = (sy.A[0], sy.b[0], sy.c[0], float(sy.d[0]), D, float(recs.offsets[0, 0]))
        out.append((estimation, validation, clean, true))
    return out


def _run_record(methods, estimation, validation, clean, true, label, order, noise, steps,
                plant="stable"):
    rows = []
    for name, run in methods.items():
        # The baselines get the true delay; the identifiers estimate it (and once are given it).
        record = (estimation if name in _DELAY_ESTIMATED
                  else estimation.with_delay(true[4]))
        t0 = time.perf_counter()
        try:
            A, b, c, d, D, start, flagged, holdout, ratio = run(record)
        except (ValueError, np.linalg.LinAlgError, RuntimeError):
            A = b = c = np.full((order,), np.nan)
            A, d, D, start, flagged = np.full((order, order), np.nan), np.nan, 0, "", 0
            holdout = ratio = np.nan
        seconds = time.perf_counter() - t0
        fit, fit_clean = _score(A, b, c, d, D, validation, clean)
        rows.append(Row(label, order, noise, steps, name, fit, fit_clean, seconds, D, start,
                        plant, flagged, holdout, ratio))
    plant_input = validation
    if len(true) > 5:
        plant_input = Record(validation.y, validation.u - true[5], validation.dt,
                             intersample=validation.intersample)
    fit, fit_clean = _score(*true[:5], plant_input, clean)
    rows.append(Row(label, order, noise, steps, "true", fit, fit_clean, 0.0, true[4], "",
                    plant))
    return rows


def bench_generic(*, orders=(1, 2, 3, 4), noises=(0.01, 0.05), lengths=(400, 1000, 5000),
                  count: int = 10, seed: int = 20_261_123, identifiers=None,
                  progress=print, plants=("stable",)) -> list[Row]:
    """Every method on ``count`` unseen records per (plant, order, noise, length) cell.

    Parameters
    ----------
    orders, noises, lengths : sequences
        The cells: model order, noise std relative to the clean output's std, estimation
        record length in samples.
    plants : sequence of str
        Kinds of plant (:data:`PLANTS`); an unstable plant grows by ``e^{0.5}`` to ``e^4``
        over its run (:data:`GROWTH`), the validation half included.
    count : int
        Records per cell.
    seed : int
        Of the systems and records (not one the shipped identifiers were trained with).
    identifiers : dict order -> GenericIdentifier, optional
        Default: the shipped ``generic-n``.
    progress : callable or None
        Called with a line per finished cell.

    Returns
    -------
    list of Row
    """
    unknown = [p for p in plants if p not in PLANTS]
    if unknown or not plants:
        raise ValueError(f"plants must be a non-empty sequence of {PLANTS}; got {plants!r}")
    rows: list[Row] = []
    for plant in plants:
        for order in orders:
            methods = _methods(order, identifiers)
            for noise in noises:
                for steps in lengths:
                    # the stable cells keep the seeds they always had
                    cell = _case_records(order, noise, steps, count,
                                         seed + 1000 * order + int(1e4 * noise) + steps
                                         + 100_000 * PLANTS.index(plant), plant)
                    for i, (est, val, clean, true) in enumerate(cell):
                        rows += _run_record(methods, est, val, clean, true, f"{order}/{i}",
                                            order, noise, steps, plant)
                    if progress is not None:
                        progress(f"{plant}, order {order}, noise {noise:.0%}, {steps} "
                                 f"samples: done")
    rows += measured_stand_ins(identifiers=identifiers)
    return rows


def _thermal(rng) -> tuple[Record, Record, np.ndarray, tuple]:
    """A heater: time constants 12 s and 2.5 s, 0.4 s transport delay, 21 degC ambient."""
    dt, steps, delay = 0.08, 1000, 5
    tau1, tau2, gain = 12.0, 2.5, 40.0
    a = np.array([1 / (tau1 * tau2), (tau1 + tau2) / (tau1 * tau2)])       # s^2 + a1 s + a0
    return _stand_in(rng, dt, steps, delay, a, np.array([gain * a[0], 0.0]), 21.0, 0.01,
                     "staircase")


def _mechanical(rng) -> tuple[Record, Record, np.ndarray, tuple]:
    """A flexible arm: modes at 1.5 Hz (damping 0.01) and 6 Hz (0.03), force to position."""
    dt, steps = 0.01, 1000
    w1, w2, z1, z2 = 2 * np.pi * 1.5, 2 * np.pi * 6.0, 0.01, 0.03
    p1, p2 = np.array([1, 2 * z1 * w1, w1 ** 2]), np.array([1, 2 * z2 * w2, w2 ** 2])
    den = np.polymul(p1, p2)
    num = np.polyadd(0.6 * w1 ** 2 * p2, 0.4 * w2 ** 2 * p1)               # two modes, zeros
    c = np.zeros(4)
    c[: len(num)] = num[::-1]                                              # ascending
    return _stand_in(rng, dt, steps, 0, den[1:][::-1], c, 0.0, 0.02, "prbs")


def _stand_in(rng, dt, steps, delay, a, c, y_offset, noise, kind):
    """Simulate ``1 / (s^n + a_{n-1} s^{n-1} + ... + a_0)`` in CCF with numerator ``c`` under a
    ``kind`` excitation, from a mid-motion start, and split the run in halves."""
    from aeid_struct.simulation import simulate
    from aeid_struct.training import generic_excitation

    A, b, _ = ccf_matrices(np.asarray(a, float)[None], None)
    A, b = A[0], b[0]
    preroll = 300
    u_all = generic_excitation(kind, 1, 2 * steps + preroll + delay, rng,
                               band=(0.01, 1.0))[0]
    u_plant = u_all[: 2 * steps + preroll]
    u = u_all[delay : delay + 2 * steps + preroll][preroll:]
    y_all = np.asarray(simulate(A, b, np.asarray(c, float), 0.0, u_plant, dt))
    clean = y_all[preroll:] + y_offset
    y = clean + noise * np.std(clean) * rng.standard_normal(clean.shape)
    whole_y, whole_u = y[: 2 * steps], u[: 2 * steps]
    estimation = Record(whole_y[:steps], whole_u[:steps], dt)
    validation = Record(whole_y[steps:], whole_u[steps:], dt)
    return estimation, validation, clean[steps : 2 * steps], (A, b, np.asarray(c, float), 0.0,
                                                              delay)


def _held(rng) -> tuple[Record, Record, np.ndarray, tuple]:
    """CONTSID's Rao-Garnier system, ``(-6400 s + 1600) / (s^4 + 5 s^3 + 408 s^2 + 416 s +
    1600)`` (two resonances a decade apart, a non-minimum-phase zero), driven through a DAC:
    a PRBS held 7 samples, the output sampled at 0.01 s (scipy's zero-order-hold oracle), white
    noise at SNR 10 dB."""
    import scipy.signal

    dt, steps = 0.01, 1000
    num, den = [-6400.0, 1600.0], [1.0, 5.0, 408.0, 416.0, 1600.0]
    u = np.repeat(rng.integers(0, 2, 2 * steps // 7 + 2) * 2.0 - 1.0, 7)[: 2 * steps]
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete(scipy.signal.tf2ss(num, den), dt,
                                                   method="zoh")
    clean = scipy.signal.dlsim((Ad, Bd, Cd, Dd, dt), u)[1][:, 0]
    y = clean + np.std(clean) / 10 ** 0.5 * rng.standard_normal(clean.shape)
    estimation = Record(y[:steps], u[:steps], dt, intersample="zoh")
    validation = Record(y[steps:], u[steps:], dt, intersample="zoh")
    A, b, _ = ccf_matrices(np.asarray(den[1:][::-1])[None], None)
    return estimation, validation, clean[steps:], (A[0], b[0], np.array([1600.0, -6400.0, 0, 0]),
                                                   0.0, 0)


def measured_stand_ins(seed: int = 7, identifiers=None) -> list[Row]:
    """The three stand-ins for measured data sets, every method.

    Parameters
    ----------
    seed : int
        Of the excitations and the noise.
    identifiers : dict order -> GenericIdentifier, optional
        Default: the shipped ``generic-n``.

    Returns
    -------
    list of Row
    """
    rng = np.random.default_rng(seed)
    rows = []
    for label, make, order in (("thermal", _thermal, 2), ("mechanical", _mechanical, 4),
                               ("held input", _held, 4)):
        est, val, clean, true = make(rng)
        rows += _run_record(_methods(order, identifiers), est, val, clean, true, label, order, -1.0,
                            est.steps)
    return rows


def write_json(rows: list[Row], path) -> Path:
    """Every row as JSON (``path``'s folder is created).

    Parameters
    ----------
    rows : list of Row
    path : str or Path

    Returns
    -------
    Path
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps([r.__dict__ for r in rows], indent=1))
    return path
