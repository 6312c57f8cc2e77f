r"""The one-pass study of ``aeid-struct bench`` (docs/architecture.md, "One pass at the
optimum"): the encoder alone, the one pass (encoder + separable head), the least-squares optimum
and the classical cold fits, on the same records, in one run.

For each leg identifier that reads ``u`` (``leg-stable-any``, ``leg-unstable-any``,
``leg-stable-window``), each input kind (steps, PRBS, multisine, filtered noise) and each noise
level (white, a share of ``max|y_clean|``), ``count`` legs are drawn from the identifier's
training range and simulated exactly in its record format (mid-motion windows after its
``warmup``, or from rest); every method identifies them:

(a) ``encoder``: the encoder alone (``ident.head = None``, the paper's architecture, Sec. III-A);
(b) ``one pass``: encoder + head, a fixed number of Levenberg-Marquardt iterations on the
    variable-projection cost in the physics structure (``identification.head``);
(c) ``encoder + refine``: ``identify(refine=True)``, the head iterated to convergence: the
    least-squares optimum in the physics structure (``c1 = 0``; rotational leg also ``a1 = 0``);
(d) ``least squares (cold)``: ``baselines.least_squares`` from its generic start, in the physics
    structure on records from rest; on windows its ``Record`` form (a CCF with the initial
    state and an output offset, started from n4sid);
(e) ``CasADi (cold)``: ``baselines.casadi_cold`` in the physics structure on records from rest;
    on windows ``refinement.refine_record`` (the CasADi graph with the initial state projected)
    from ``baselines.generic_start``;
(f) ``n4sid``: ``baselines.n4sid`` of order 2 (``Record`` form on windows).

Errors are the median over records of ``|p_hat / p - 1|`` in % for the physical parameters the
record holds (the rotational leg has no ``d``), from every model through the CCF of its transfer
function (``identification.physical.through_ccf``); a failed or non-finite estimate counts as an
infinite error. Times are on one thread: the median of batch-1 calls over the first ``timed``
records (back to back, after an untimed warm-up call), and records per second of one batched
call of ``batch`` records. The cold baselines run on those ``timed`` records only (they are the
slow part of the run); (a)-(c) are scored on all ``count`` records.

An identifier file without a head gets :data:`HEAD_ITERATIONS` iterations in the physics
structure here (:func:`with_head`); one that has a head keeps its own.
"""

from __future__ import annotations

import copy
import math
import sys
import time

import numpy as np

__all__ = ["BASELINES", "HEAD_ITERATIONS", "IDENTIFIERS", "KINDS", "METHODS", "PHYSICS",
           "bench_onepass", "bench_row", "encoder_alone", "leg_family", "with_head"]

#: The identifiers of the study and their leg subsystem.
IDENTIFIERS = {"leg-stable-any": "stable", "leg-unstable-any": "unstable",
               "leg-stable-window": "stable"}
#: The physics structure per subsystem: the elements that are zero in the true transfer function.
PHYSICS = {"stable": {"c1": 0.0}, "unstable": {"a1": 0.0, "c1": 0.0}}
#: Iterations of the head given to an identifier file that has none.
HEAD_ITERATIONS = 3
#: Input kinds (``training.excitation`` names; ``noise`` is filtered noise).
KINDS = ("steps", "prbs", "multisine", "noise")
#: The methods in table order; the last three are the cold classical baselines.
METHODS = ("encoder", "one pass", "encoder + refine", "least squares (cold)", "CasADi (cold)",
           "n4sid")
BASELINES = METHODS[3:]
#: Order of every leg subsystem.
_ORDER = 2


def with_head(ident, subsystem: str):
    """``ident`` with its own head, or a copy with the default head when its file has none.

    Parameters
    ----------
    ident : Identifier
    subsystem : {"stable", "unstable"}
        Picks the physics structure (:data:`PHYSICS`).

    Returns
    -------
    Identifier
        ``ident`` itself when ``ident.head`` is set; else a shallow copy (same encoder) with
        ``Head(iterations=HEAD_ITERATIONS, fixed=PHYSICS[subsystem])``.
    """
    from aeid_struct.identification import Head

    if ident.head is not None:
        return ident
    headed = copy.copy(ident)
    headed.head = Head(iterations=HEAD_ITERATIONS, fixed=PHYSICS[subsystem])
    return headed


def encoder_alone(ident):
    """A shallow copy of ``ident`` (same encoder) without a head: the paper's architecture.

    Parameters
    ----------
    ident : Identifier

    Returns
    -------
    Identifier
    """
    alone = copy.copy(ident)
    alone.head = None
    return alone


def leg_family(ident, subsystem: str):
    """The legs of ``ident``'s training range (its file's ``training_range``), the paper's
    ranges for a parameter the file does not name.

    Parameters
    ----------
    ident : Identifier
    subsystem : {"stable", "unstable"}

    Returns
    -------
    training.LegFamily
    """
    from aeid_struct.training import LegFamily

    ranges = dict(LegFamily(subsystem=subsystem).ranges)
    trained = ident.meta.get("training_range", {}).get("physical", {})
    ranges |= {p: (float(v[0]), float(v[1])) for p, v in trained.items() if p in ranges}
    return LegFamily(subsystem=subsystem, ranges=ranges)


def _errors(inverse, models, truth: dict, rows) -> dict:
    """Per parameter the absolute error in % of the true value, ``(len(rows),)``; inf where the
    model is not finite or the parameter not finite and positive."""
    from aeid_struct.identification import through_ccf

    A, b, c, d = (np.asarray(x, dtype=np.float64) for x in models)
    with np.errstate(all="ignore"):
        phys = through_ccf(A, b, c, d, inverse)
        out = {}
        for p, value in phys.items():
            if p in truth:
                err = 100.0 * np.abs(value / truth[p][rows] - 1.0)
                out[p] = np.where(np.isfinite(value) & (value > 0), err, np.inf)
    return out


def _stack(models: list) -> tuple:
    """``(A (N, n, n), b, c (N, n), d (N,))`` of one model per record (None: a failure)."""
    n = _ORDER
    nan = (np.full((n, n), np.nan), np.full(n, np.nan), np.full(n, np.nan), np.nan)
    parts = [nan if m is None else m for m in models]
    return tuple(np.array([np.asarray(p[i], dtype=np.float64).reshape(np.shape(nan[i]))
                           for p in parts]) for i in range(4))


def _one_model(est):
    """``(A, b, c, d)`` of one baseline estimate, None where it reports a failure."""
    info = getattr(est, "info", None) or {}
    if info.get("failed"):
        return None
    return tuple(np.asarray(x, dtype=np.float64) for x in (est.A, est.b, est.c, est.d))


def baseline_calls(ident, subsystem: str) -> dict:
    """The cold classical fits of one record in ``ident``'s record format (module docstring).

    Parameters
    ----------
    ident : Identifier
    subsystem : {"stable", "unstable"}

    Returns
    -------
    dict
        :data:`BASELINES` name -> ``call(y, u)`` with ``y, u (steps,)``, returning the
        baseline's estimate (an ``Estimate`` or ``refinement.RecordFit``).
    """
    from aeid_struct import baselines, refinement
    from aeid_struct.records import Record

    dt = ident.dt
    physics = ident.structure.fixed(**PHYSICS[subsystem])
    if ident.initial == "rest":
        kw = dict(structure=physics, inverse=ident.inverse)
        return {
            "least squares (cold)": lambda y, u: baselines.least_squares(y, u, dt, **kw),
            "CasADi (cold)": lambda y, u: baselines.casadi_cold(y, u, dt, **kw),
            "n4sid": lambda y, u: baselines.n4sid(y, u, dt, order=_ORDER),
        }

    def casadi(y, u):
        start = baselines.generic_start(physics, y, u, dt)
        return refinement.refine_record(physics, start, y, u, dt, offset=False)

    return {
        "least squares (cold)": lambda y, u: baselines.least_squares(
            Record(y, u, dt, delay=0), order=_ORDER),
        "CasADi (cold)": casadi,
        "n4sid": lambda y, u: baselines.n4sid(Record(y, u, dt, delay=0), order=_ORDER),
    }


def _batch1(call, rec, timed: int):
    """``call(y_i, u_i)`` on the first ``timed`` records back to back after one untimed call
    (what it builds on first use: a trace, a solver); the estimates (exceptions kept) and the
    wall times in ms."""
    try:
        call(rec.y[0], rec.u[0])
    except Exception:       # a failing record is scored below; the warm-up only warms up
        pass
    # Timed back to back, scored afterwards: checking an estimate between two calls evicts
    # caches and slows the next call down (studies.bench measured it).
    out, ms = [], []
    for i in range(timed):
        t0 = time.perf_counter()
        try:
            out.append(call(rec.y[i], rec.u[i]))
        except Exception as exc:     # a baseline that throws counts as a failure
            out.append(exc)
        ms.append(1e3 * (time.perf_counter() - t0))
    return out, ms


def _throughput(call, y: np.ndarray, u: np.ndarray, repeats: int) -> float:
    """Records per second of ``call(y, u)`` on the whole batch (best of ``repeats`` after a
    warm-up call on a slice)."""
    call(y[:8], u[:8])
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        call(y, u)
        best = min(best, time.perf_counter() - t0)
    return y.shape[0] / best


def _stage(errors: dict, ms=None, throughput=None) -> dict:
    """One method's entry of a row: medians (inf-safe), failures, times."""
    fail = np.zeros(len(next(iter(errors.values()))), dtype=bool)
    for v in errors.values():
        fail |= ~np.isfinite(v)
    entry = {"median": {p: float(np.median(v)) for p, v in errors.items()},
             "failures": float(np.mean(fail)), "records": int(fail.size)}
    if ms is not None:
        entry["ms"] = float(np.median(ms))
    if throughput is not None:
        entry["per_s"] = float(throughput)
    return entry


def _ratio(num: dict, den: dict) -> dict:
    """Per parameter ``num / den`` of the median errors; None where ``den`` is ~0 (noise-free:
    the optimum is exact) or a value is not finite."""
    out = {}
    for p in den:
        a, b = num.get(p, math.nan), den[p]
        out[p] = float(a / b) if (b > 1e-6 and math.isfinite(a) and math.isfinite(b)) else None
    return out


def bench_row(ident, subsystem: str, kind: str, noise: float, *, count: int, timed: int,
              batch: int, seed: int, baselines: bool = True) -> dict:
    """Every method on the same ``count`` records of one input kind and noise level.

    Parameters
    ----------
    ident : Identifier
        A leg identifier that reads ``u`` (with or without its own head).
    subsystem : {"stable", "unstable"}
    kind : str
        Input kind (:data:`KINDS`).
    noise : float
        Noise std as a share of ``max|y_clean|``.
    count : int
        Records scored for (a)-(c).
    timed : int, <= count
        Records timed at batch 1 (all methods) and fitted by the cold baselines.
    batch : int
        Records of the batched throughput call.
    seed : int
        Seed of the legs, inputs and noise.
    baselines : bool
        Also run the cold baselines (d)-(f).

    Returns
    -------
    dict
        ``kind, noise, count, timed, batch``; ``methods``: name -> ``median`` (k, d, m errors,
        %), ``failures``, ``records``, ``ms`` (batch-1 median), ``per_s`` (batched, for (a)-(c));
        ``vs_optimum``: for (a), (b) the per-parameter ratio of the median error to (c)'s;
        ``ls_over_one_pass``: the cold least squares' batch-1 time over the one pass's.
    """
    from aeid_struct.training import records

    headed, alone = with_head(ident, subsystem), encoder_alone(ident)
    warmup = int(ident.meta.get("train", {}).get("config", {}).get("warmup", 0))
    rec = records(leg_family(ident, subsystem), count, steps=ident.steps, dt=ident.dt,
                  excitation_kind=kind, noise=noise, seed=seed, warmup=warmup)
    truth, inverse = rec.systems.params, ident.inverse
    rows, sub = np.arange(count), np.arange(timed)
    ours = {"encoder": lambda y, u: alone.identify(y, u),
            "one pass": lambda y, u: headed.identify(y, u),
            "encoder + refine": lambda y, u: headed.identify(y, u, refine=True)}
    y_big = np.tile(rec.y, (-(-batch // count), 1))[:batch]
    u_big = np.tile(rec.u, (-(-batch // count), 1))[:batch]
    methods = {}
    for name, call in ours.items():
        est = call(rec.y, rec.u)
        models = (est.A, est.b, est.c, est.d)
        _, ms = _batch1(call, rec, timed)
        per_s = _throughput(call, y_big, u_big, 1 if name == "encoder + refine" else 2)
        methods[name] = _stage(_errors(inverse, models, truth, rows), ms, per_s)
    if baselines:
        for name, call in baseline_calls(ident, subsystem).items():
            out, ms = _batch1(call, rec, timed)
            models = _stack([None if isinstance(e, Exception) else _one_model(e) for e in out])
            methods[name] = _stage(_errors(inverse, models, truth, sub), ms)
    opt = methods["encoder + refine"]["median"]
    row = {"kind": kind, "noise": noise, "count": count, "timed": timed, "batch": batch,
           "methods": methods,
           "vs_optimum": {m: _ratio(methods[m]["median"], opt) for m in ("encoder", "one pass")}}
    if baselines:
        row["ls_over_one_pass"] = (methods["least squares (cold)"]["ms"]
                                   / methods["one pass"]["ms"])
    return row


def _say(progress: bool, text: str) -> None:
    if progress:
        sys.stderr.write(text + "\n")
        sys.stderr.flush()


def bench_onepass(*, quick: bool = False, names=tuple(IDENTIFIERS), kinds=KINDS,
                  noises=None, count: int | None = None, timed: int | None = None,
                  batch: int | None = None, seed: int = 1500, baselines: bool = True,
                  progress: bool = True) -> dict:
    """The one-pass study on the shipped identifiers (module docstring), on one thread.

    Parameters
    ----------
    quick : bool
        Defaults for a test: 8 records per row, 4 timed, noise 0 and 1 %, batch 64.
    names : tuple of str
        Identifiers (keys of :data:`IDENTIFIERS`).
    kinds : tuple of str
        Input kinds (:data:`KINDS`).
    noises : tuple of float, optional
        Noise levels; default 0, 1 and 5 % (quick: 0 and 1 %).
    count, timed, batch : int, optional
        Records per row (default 60), timed and fitted by the baselines (default 30), records
        of the batched call (default 1000).
    seed : int
        Seed of the first row (each row has its own).
    baselines : bool
        Run the cold baselines.
    progress : bool
        One line per row on stderr.

    Returns
    -------
    dict
        JSON-able: ``identifiers``: name -> ``subsystem``, ``head`` (the head used, and whether
        the file had it), ``rows`` (:func:`bench_row`); ``settings``; ``targets``
        (:func:`targets`); ``seconds`` (wall time of the study).

    Raises
    ------
    ValueError
        An unknown identifier or input kind, or counts that are not positive integers with
        ``timed <= count``.
    """
    import torch
    from threadpoolctl import threadpool_limits

    from aeid_struct.identification import load_pretrained

    count = (8 if quick else 60) if count is None else count
    timed = (4 if quick else 30) if timed is None else timed
    batch = (64 if quick else 1000) if batch is None else batch
    noises = tuple(noises if noises is not None else ((0.0, 0.01) if quick else
                                                      (0.0, 0.01, 0.05)))
    _check(names, kinds, count, timed, batch)
    t_start = time.perf_counter()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    result = {"identifiers": {}, "settings": {"count": count, "timed": timed, "batch": batch,
                                             "noises": list(noises), "kinds": list(kinds),
                                             "seed": seed, "threads": 1}}
    try:
        # one core for every method: torch and the BLAS under numpy/scipy (an idle BLAS pool
        # spinning on the other core slows small calls down)
        with threadpool_limits(limits=1):
            for i, name in enumerate(names):
                subsystem = IDENTIFIERS[name]
                ident = load_pretrained(name)
                head = with_head(ident, subsystem).head
                entry = {"subsystem": subsystem, "head": head.to_dict(),
                         "head_in_file": ident.head is not None, "rows": []}
                for j, kind in enumerate(kinds):
                    for k, noise in enumerate(noises):
                        t0 = time.perf_counter()
                        row = bench_row(ident, subsystem, kind, noise, count=count,
                                        timed=timed, batch=batch,
                                        seed=seed + 100 * i + 10 * j + k, baselines=baselines)
                        entry["rows"].append(row)
                        one = row["methods"]["one pass"]["median"]
                        _say(progress, f"  {name:18s} {kind:9s} noise {noise:4.0%}  one pass "
                             + " / ".join(f"{p} {v:.3g}" for p, v in one.items())
                             + f" %  ({time.perf_counter() - t0:.1f} s)")
                result["identifiers"][name] = entry
    finally:
        torch.set_num_threads(threads)
    result["targets"] = targets(result)
    result["seconds"] = time.perf_counter() - t_start
    return result


def _check(names, kinds, count, timed, batch) -> None:
    unknown = [n for n in names if n not in IDENTIFIERS]
    if unknown or not names:
        raise ValueError(f"names must be some of {tuple(IDENTIFIERS)}; got {tuple(names)!r}")
    if not kinds or any(k not in KINDS for k in kinds):
        raise ValueError(f"kinds must be some of {KINDS}; got {tuple(kinds)!r}")
    for label, value in (("count", count), ("timed", timed), ("batch", batch)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{label} must be a positive integer; got {value!r}")
    if timed > count:
        raise ValueError(f"timed must be <= count ({count}); got {timed}")


#: Issue 15's targets for the one pass (``targets`` reads them off a result).
TARGET_NOISE_FREE_PERCENT = 0.5
TARGET_VS_OPTIMUM = 1.2
TARGET_LS_OVER_ONE_PASS = 50.0


def targets(result: dict) -> dict:
    """Issue 15's targets read off a result, per identifier, over PRBS, multisine and filtered
    noise (steps are the paper's input, not one of the target's).

    Parameters
    ----------
    result : dict
        What :func:`bench_onepass` returned (without ``targets``).

    Returns
    -------
    dict
        Identifier -> ``noise_free_max_percent`` (the one pass's largest median parameter error
        on noise-free rows), ``vs_optimum_max`` (its largest ratio to the optimum on noisy
        rows), ``ls_over_one_pass_min`` (the smallest time ratio), each with ``*_met``.
    """
    out = {}
    for name, entry in result["identifiers"].items():
        rows = [r for r in entry["rows"] if r["kind"] != "steps"]
        free = [v for r in rows if r["noise"] == 0
                for v in r["methods"]["one pass"]["median"].values()]
        ratios = [v for r in rows if r["noise"] > 0
                  for v in r["vs_optimum"]["one pass"].values() if v is not None]
        times = [r["ls_over_one_pass"] for r in entry["rows"] if "ls_over_one_pass" in r]
        t = {"noise_free_max_percent": max(free) if free else None,
             "vs_optimum_max": max(ratios) if ratios else None,
             "ls_over_one_pass_min": min(times) if times else None}
        t["noise_free_met"] = None if not free else bool(
            t["noise_free_max_percent"] <= TARGET_NOISE_FREE_PERCENT)
        t["vs_optimum_met"] = None if not ratios else bool(
            t["vs_optimum_max"] <= TARGET_VS_OPTIMUM)
        t["time_met"] = None if not times else bool(
            t["ls_over_one_pass_min"] >= TARGET_LS_OVER_ONE_PASS)
        out[name] = t
    return out
