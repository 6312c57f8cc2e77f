"""Benchmark rows for several inputs and outputs and several experiments (issue 24):
``aeid-struct bench-generic --channels``.

Unseen random systems (a real block-diagonal form of random poles, lightly damped pairs and
real poles, in a random basis; an integrator or an unstable real pole where the row says so),
``dt = 0.05`` s, a PRBS-like input (random levels held 4 samples, plus white noise) per input,
an input delay of 0-3 samples (one for all inputs), output offsets, a mid-motion start and white
output noise of 1-5 % of each output's standard deviation (uniform per record); the
``coloured`` row reads a low-pass input instead (white noise through a second-order
Butterworth filter at a tenth of the Nyquist frequency) and output noise coloured by an AR(1)
filter of pole 0.95, what measured records look like more often than PRBS and white noise
(the subspace method's noise model is wrong for it, the output-error fit's is not). Each run
is split into an estimation part and a validation part (a further experiment for the
several-experiment rows). Methods, on the estimation data:

* ``one pass``: ``ae.identify(records, order=n, refine=False)`` (delays estimated),
* ``refined``: ``ae.identify(records, order=n)`` (delays estimated),
* ``n4sid``: ``baselines.n4sid(record, order=n)`` with the true delays (one record only),
* ``least squares``: ``baselines.least_squares(records, order=n)`` with the true delays,
* ``true``: the system that generated the data.

Every model is scored on the validation record by ``ae.compare`` (initial state and offsets
fitted): the mean of the outputs' NRMSE fits against the measured (noisy) output.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import control
import numpy as np
import scipy.signal

from aeid_struct.baselines import least_squares, n4sid
from aeid_struct.generic import compare, identify
from aeid_struct.records import Record

__all__ = ["CASES", "ChannelRow", "bench_channels", "format_channels", "write_channels"]

#: Rows: name -> (order, outputs, inputs, experiments, kind, estimation samples[, record]);
#: ``record`` is "prbs" (the default) or "coloured" (module docstring).
CASES = {
    "2x2": (4, 2, 2, 1, "stable", 1000),
    "3x3": (4, 3, 3, 1, "stable", 1000),
    "2x2, 200 samples": (3, 2, 2, 1, "stable", 200),
    "1x1, 3 experiments": (3, 1, 1, 3, "stable", 300),
    "2x2, 2 experiments": (4, 2, 2, 2, "stable", 500),
    "2x2 integrating": (3, 2, 2, 1, "integrating", 600),
    "2x1 unstable": (3, 2, 1, 1, "unstable", 400),
    "1x1 order 6": (6, 1, 1, 1, "stable", 1000),
    "2x2 coloured, low-pass": (4, 2, 2, 1, "stable", 1000, "coloured"),
}
#: Methods in table order.
METHODS = ("one pass", "refined", "n4sid", "least squares", "true")
DT = 0.05


@dataclass(frozen=True)
class ChannelRow:
    """One record set, one method.

    Attributes
    ----------
    case : str
        The row's name (:data:`CASES`).
    index : int
        The record set within the row.
    noise : float
        Noise std over each output's std.
    method : str
    fit : float
        Validation fit % (mean over outputs); NaN where the method failed.
    seconds : float
    """

    case: str
    index: int
    noise: float
    method: str
    fit: float
    seconds: float


def _system(n, p, m, kind, rng):
    poles = []
    if kind == "integrating":
        poles.append(0.0)
    elif kind == "unstable":
        poles.append(rng.uniform(0.1, 0.3))
    while len(poles) < n:
        if n - len(poles) >= 2:
            w, z = rng.uniform(0.5, 4.0), rng.uniform(0.1, 0.7)
            poles += [complex(-z * w, w * np.sqrt(1 - z * z))] * 2
        else:
            poles.append(-rng.uniform(0.3, 3.0))
    A = np.zeros((n, n))
    k = 0
    while k < n:
        pole = poles[k]
        if isinstance(pole, complex):
            A[k: k + 2, k: k + 2] = [[pole.real, pole.imag], [-pole.imag, pole.real]]
            k += 2
        else:
            A[k, k] = pole
            k += 1
    T = rng.normal(size=(n, n))
    A = T @ A @ np.linalg.inv(T)
    return A, rng.normal(size=(n, m)), rng.normal(size=(p, n)), 0.2 * rng.normal(size=(p, m))


def _run(system, delays, steps, noise, rng, record="prbs"):
    """One experiment's Record (``record``: :data:`CASES`)."""
    A, B, C, D = system
    m, p = B.shape[1], C.shape[0]
    if record == "coloured":
        b, a = scipy.signal.butter(2, 0.1)
        U = scipy.signal.lfilter(b, a, rng.normal(size=(steps + 200, m)), axis=0)[200:]
        U = U / U.std(axis=0)
    else:
        U = np.repeat(rng.choice([-1.0, 1.0], size=(steps // 4 + 1, m)), 4, axis=0)[:steps]
        U = U + 0.2 * rng.normal(size=U.shape)
    Ud = np.stack([np.concatenate([np.zeros(d), U[: steps - d, j]])
                   for j, d in enumerate(delays)], axis=1)
    _, Y, _ = scipy.signal.lsim((A, B, C, D), Ud, np.arange(steps) * DT,
                                X0=0.5 * rng.normal(size=A.shape[0]), interp=True)
    Y = Y.reshape(steps, p) + rng.normal(size=p)
    e = rng.normal(size=Y.shape)
    if record == "coloured":
        e = scipy.signal.lfilter([1.0], [1.0, -0.95], e, axis=0)
        e = e / e.std(axis=0)
    Y = Y + noise * Y.std(axis=0) * e
    return Record(Y if p > 1 else Y[:, 0], U if m > 1 else U[:, 0], DT)


def _score(model, validation, delays) -> float:
    try:
        # one input: the one-channel compare, which takes an int delay
        out = compare(model, validation, delay=delays if len(delays) > 1 else int(delays[0]))
    except (ValueError, np.linalg.LinAlgError):
        return float("nan")
    return float(np.mean(out.fit))


def _case(name, order, p, m, count, kind, steps, seed, record="prbs"):
    rng = np.random.default_rng(seed)
    rows = []
    for index in range(count):
        system = _system(order, p, m, kind, rng)
        # one delay for every input: a Record carries one, and the baselines are given it
        delays = np.full(m, int(rng.integers(0, 4)))
        noise = float(rng.uniform(0.01, 0.05))
        experiments = CASES[name][3]
        records = [_run(system, delays, steps, noise, rng, record) for _ in range(experiments)]
        validation = _run(system, delays, steps, noise, rng, record)
        given = records[0] if experiments == 1 else records
        known = [r.with_delay(int(delays[0])) for r in records]
        known = known[0] if experiments == 1 else known
        methods = {
            "one pass": lambda g=given: identify(g, order=order, refine=False),
            "refined": lambda g=given: identify(g, order=order),
            # nfoursid reads one record: no n4sid row for several experiments
            "n4sid": (lambda k=known: n4sid(k, order=order)) if experiments == 1 else None,
            "least squares": lambda k=known: least_squares(k, order=order),
        }
        for method, run in methods.items():
            if run is None:
                continue
            began = time.perf_counter()
            try:
                est = run()
                seconds = time.perf_counter() - began
                fit = _score(est, validation, np.ravel(est.delay) if method in
                             ("one pass", "refined") else delays)
            except (ValueError, np.linalg.LinAlgError):     # a failed method scores NaN
                seconds, fit = time.perf_counter() - began, float("nan")
            rows.append(ChannelRow(name, index, noise, method, fit, seconds))
        rows.append(ChannelRow(name, index, noise, "true",
                               _score(control.ss(*system), validation, delays), 0.0))
    return rows


def bench_channels(*, cases=tuple(CASES), count: int = 20, seed: int = 20_261_127,
                   progress=print) -> list[ChannelRow]:
    """Every method on ``count`` unseen record sets per row (module docstring).

    Parameters
    ----------
    cases : sequence of str
        Rows of :data:`CASES`.
    count : int
    seed : int
    progress : callable or None

    Returns
    -------
    list of ChannelRow
    """
    rows = []
    for k, name in enumerate(cases):
        if name not in CASES:
            raise ValueError(f"cases must be among {list(CASES)}; got {name!r}")
        order, p, m, _, kind, steps, *record = CASES[name]
        rows += _case(name, order, p, m, count, kind, steps, seed + 1000 * k, *record)
        if progress is not None:
            progress(f"{name}: done")
    return rows


def format_channels(rows: list[ChannelRow]) -> str:
    """The table: median validation fit per row and method, the issue's three shares and the
    median times.

    Parameters
    ----------
    rows : list of ChannelRow

    Returns
    -------
    str
    """
    lines = ["Median validation fit % (mean over outputs); 'ref-true': median refined minus median "
             "true; then the shares of records where refined >= true - 1, refined >= n4sid - 1 "
             "(where n4sid returned a model), one pass >= refined - 1; median times.",
             f"{'row':22s} " + " ".join(f"{m:>13s}" for m in METHODS)
             + "  ref-true  ref>=true-1  ref>=n4sid-1  pass>=ref-1  t pass/refined/n4sid [ms]"]
    for name in dict.fromkeys(r.case for r in rows):
        by = {m: {r.index: r for r in rows if r.case == name and r.method == m}
              for m in METHODS}
        med = {m: np.nanmedian([r.fit for r in by[m].values()]) if by[m] else np.nan
               for m in METHODS}
        ref = by["refined"]
        near_true = np.mean([r.fit >= by["true"][i].fit - 1 for i, r in ref.items()])
        n4 = [(ref[i].fit, r.fit) for i, r in by["n4sid"].items() if np.isfinite(r.fit)]
        beats = np.mean([a >= b - 1 for a, b in n4]) if n4 else np.nan
        passes = np.mean([by["one pass"][i].fit >= r.fit - 1 for i, r in ref.items()])
        times = [np.median([r.seconds for r in by[m].values()]) * 1e3 if by[m] else np.nan
                 for m in ("one pass", "refined", "n4sid")]
        lines.append(f"{name:22s} " + " ".join(f"{med[m]:13.2f}" for m in METHODS)
                     + f"  {med['refined'] - med['true']:8.2f}  {near_true:11.0%}  "
                     + ("         n/a" if not n4 else f"{beats:12.0%}") + f"  {passes:11.0%}  "
                     + "/".join(f"{t:.0f}" for t in times))
    return "\n".join(lines)


def write_channels(rows: list[ChannelRow], path) -> Path:
    """Write the rows as JSON.

    Parameters
    ----------
    rows : list of ChannelRow
    path : str or path-like

    Returns
    -------
    Path
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"rows": [asdict(r) for r in rows]}, indent=1))
    return path
