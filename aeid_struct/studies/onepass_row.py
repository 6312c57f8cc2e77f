"""One row of the one-pass study (``studies.onepass_bench``): every method on the same records of
one input kind and noise level, scored and timed.

Errors are the median over records of ``|p_hat / p - 1|`` in % for the physical parameters the
record holds, from every model through the CCF of its transfer function
(``identification.physical.through_ccf``); a failed or non-finite estimate counts as an infinite
error. Times are on one thread: the median of batch-1 calls (back to back, after an untimed
warm-up call), and records per second of one batched call.

The seam: ``studies.onepass_methods`` says which methods are compared, this module measures them on
one set of records, and ``studies.onepass_bench`` repeats that over the whole study.
"""

from __future__ import annotations

import math
import time

import numpy as np

from aeid_struct.studies.onepass_methods import (
    ORDER,
    baseline_calls,
    encoder_alone,
    leg_family,
    with_head,
)

__all__ = ["bench_row"]


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
    n = ORDER
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
        Input kind (``onepass_bench.KINDS``).
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
