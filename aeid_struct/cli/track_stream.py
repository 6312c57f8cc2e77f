"""``aeid-struct track --y FILE ..``: a measured stream tracked window by window
(``studies.wear.stream_study``) with any identifier the tracker takes (a mechanism's, one of
several channels): the drift of every parameter and the alarm printed, the window estimates
written as CSV and JSON, and a PNG."""

from __future__ import annotations

import argparse
import csv
import math
from pathlib import Path

import numpy as np

from aeid_struct.cli.errors import InputError
from aeid_struct.cli.output import plain, write_json
from aeid_struct.cli.records_io import RecordFile, check_dt, read_record

__all__ = ["run_track_stream"]


def run_track_stream(args: argparse.Namespace, ident, config) -> int:
    """``track`` of a measured stream: read ``--y`` (one file per output) and ``--u`` (one per
    input, or the u column of a one-input stream's --y file), track it, print and write.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct track`` (``args.y`` given).
    ident : Identifier
        From ``--model``.
    config : online.TrackerConfig
        From the tracker options.

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        An identifier the tracker refuses, files of the wrong number, layout, sample time or
        length, or samples the tracker refuses.
    """
    from aeid_struct import studies
    from aeid_struct.online import Tracker

    try:
        tracker = Tracker(ident, config, engine=args.engine)
    except ValueError as err:
        raise InputError(f"track --model {args.model}: {err}") from None
    p, m = tracker.width
    y, u = _stream(args, tracker, p, m)
    try:
        result = studies.wear.stream_study(tracker, y, u)
    except ValueError as err:
        raise InputError(f"track: {err}") from None
    used = result.config
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    names = list(result.estimate)
    failed = int(np.sum(~np.isfinite(np.stack([result.estimate[k] for k in names])).all(0)))
    print(f"{ident!r}")
    print(f"stream: {len(y)} samples at dt = {tracker.dt:g} s ({len(y) * tracker.dt:g} s), "
          f"{p} output{'s' if p > 1 else ''}, {m} input{'s' if m > 1 else ''}; one window of "
          f"{tracker.steps} samples every {used.hop}: {len(result.t)} windows"
          + (f", {failed} of them not identified (NaN in the CSV)" if failed else ""))
    rows = _drifts(result)
    limits = tracker.limits
    print(f"{'parameter':<10} {'reference':>12} {'last smoothed':>14} {'drift':>9} "
          f"{'limit':>9}")
    for k, (reference, last, drift) in rows.items():
        print(f"{k:<10} {reference:>12.6g} {last:>14.6g} {100 * drift:>8.2f} % "
              f"{100 * limits.get(k, math.nan):>7.2f} %")
    watched = list(used.watch) or names
    print(f"alarm ({', '.join(watched)} beyond their limits, {100 * used.threshold:g} % of the "
          f"reference or {used.sigmas:g} standard errors of a window where larger, for "
          f"{used.patience} windows): "
          + (f"raised at t = {result.alarm_time:.3f} s" if math.isfinite(result.alarm_time)
             else "not raised"))
    print(f"smoothing: running median of {used.median} windows, moving average weight "
          f"{used.smoothing:g}; head: {ident.head if ident.head is not None else 'none'}")
    print(f"update (one window identified, {result.engine} engine): "
          f"{result.latency_ms:.3f} ms median, {result.latency_p95_ms:.3f} ms p95")
    png, table, js = out / "track.png", out / "track.csv", out / "track.json"
    # the units of a user's mechanism are not known here (the leg's would mislabel them)
    studies.figures.wear_figure(result, png, config=used, units={},
                                title=f"{', '.join(args.y)}: {args.model}, {result.engine} "
                                      "engine")
    with table.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t", *names, *(f"{k}_smoothed" for k in names), "alarm"])
        for i, t in enumerate(result.t):
            w.writerow([repr(float(t)), *(repr(float(result.estimate[k][i])) for k in names),
                        *(repr(float(result.smoothed[k][i])) for k in names),
                        int(result.alarm[i])])
    write_json(js, plain({
        "model": args.model, "identifier": repr(ident), "dt": tracker.dt,
        "samples": len(y), "window": tracker.steps, "hop": used.hop,
        "median": used.median, "smoothing": used.smoothing, "threshold": used.threshold,
        "baseline": used.baseline, "patience": used.patience, "watch": watched,
        "iterations": used.iterations,
        "engine": result.engine, "latency_ms": result.latency_ms,
        "latency_p95_ms": result.latency_p95_ms,
        "alarm_time_s": None if not math.isfinite(result.alarm_time) else result.alarm_time,
        "not_identified": failed,
        "sigmas": used.sigmas,
        "parameters": {k: {"reference": r, "last_smoothed": last, "drift": d,
                           "limit": limits.get(k, math.nan)}
                       for k, (r, last, d) in rows.items()},
        "t": result.t, "estimate": result.estimate, "smoothed": result.smoothed,
        "alarm": result.alarm}))
    print(f"wrote {png}, {table}, {js}")
    return 0


def _stream(args, tracker, p: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``y (N,) or (N, p)`` and ``u (N,) or (N, m)`` of the stream files, checked."""
    if len(args.y) != p:
        raise InputError(f"--y: this identifier reads {p} output{'s' if p > 1 else ''} "
                         f"(one stream file each); got {len(args.y)} file(s)")
    ys = [_one(read_record(f, "--y", "y"), "--y", tracker.dt) for f in args.y]
    if args.u is not None:
        if len(args.u) != m:
            raise InputError(f"--u: this identifier reads {m} input{'s' if m > 1 else ''} "
                             f"(one stream file each); got {len(args.u)} file(s)")
        if any(rec.u is not None for rec in ys):
            raise InputError("--u and a u column in a --y file: give the input once")
        us = [_one(read_record(f, "--u", "u"), "--u", tracker.dt) for f in args.u]
        u = [rec.values for rec in us]
    elif m == 1 and ys[0].u is not None:
        differ = [rec.path for rec in ys[1:] if rec.u is None or not np.array_equal(
            rec.u, ys[0].u)]
        if differ:
            raise InputError(f"--y: the u column of {ys[0].path!r} is the stream's one input; "
                             f"{', '.join(map(repr, differ))} carry none or another (give "
                             "the input once, by --u)")
        u = [ys[0].u]
    else:
        raise InputError(f"--u: give the stream's input{'s' if m > 1 else ''} ({m} file"
                         f"{'s' if m > 1 else ''}), or a u column in the --y file")
    series = [rec.values for rec in ys] + u
    lengths = {len(v) for v in series}
    if len(lengths) != 1:
        raise InputError(f"--y and --u must hold streams of one length; got "
                         f"{[len(v) for v in series]} samples")
    y = ys[0].values if p == 1 else np.stack([rec.values for rec in ys], axis=1)
    return y, (u[0] if m == 1 else np.stack(u, axis=1))


def _one(rec: RecordFile, option: str, dt: float) -> RecordFile:
    """A stream file: one series, sampled at the identifier's ``dt`` where it says."""
    if rec.values.ndim != 1:
        raise InputError(f"{option} file {rec.path!r} holds {rec.values.shape[0]} rows of "
                         f"{rec.values.shape[1]} values; a stream is one series (one number "
                         "per line, or named columns such as 't,u,y')")
    check_dt(rec, option, dt, f"windows at dt = {dt:g} s")
    return rec


def _drifts(result) -> dict[str, tuple[float, float, float]]:
    """Per parameter: the tracker's reference, the last smoothed estimate and the tracker's
    drift from the reference after the last window (``Update.drift``; the reference is
    ``smoothed / (1 + drift)``, NaN where the baseline never filled)."""
    out = {}
    for k, smoothed in result.smoothed.items():
        last, drift = float(smoothed[-1]), float(result.drift[k][-1])
        out[k] = (last / (1.0 + drift), last, drift)
    return out
