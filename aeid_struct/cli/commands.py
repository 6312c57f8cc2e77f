"""The subcommands that run the library's studies on the robot leg: ``leg`` (the paper's study)
and ``track`` (the wear scenario of online identification; a measured stream goes to
``track_stream``).

The seam: each of these runs one study of ``aeid_struct.studies`` and prints what it found; the
training subcommands are in ``train`` and ``train_generic``, the benchmarks in ``benchmarks``, and
``demo`` and ``identify`` have modules of their own.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

# The training and benchmark subcommands lived here before they got modules of their own: they
# stay importable from here (the ``as`` imports)
from aeid_struct.cli.benchmarks import run_bench as run_bench
from aeid_struct.cli.benchmarks import run_bench_generic as run_bench_generic
from aeid_struct.cli.benchmarks import run_bench_online as run_bench_online
from aeid_struct.cli.errors import InputError
from aeid_struct.cli.identify import load_identifier
from aeid_struct.cli.train import parse_family as parse_family
from aeid_struct.cli.train import parse_structure as parse_structure
from aeid_struct.cli.train import run_train as run_train


def run_leg(args: argparse.Namespace) -> int:
    """The ``leg`` subcommand: the robot-leg study (paper Sec. IV), Table I printed.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct leg``.

    Returns
    -------
    int
        0.
    """
    from aeid_struct import studies

    study = studies.leg_paper
    command = "aeid-struct " + " ".join(args.argv)
    seconds = args.seconds
    print("Robot-leg study (paper Sec. IV): "
          + ("shipped identifiers" if args.pretrained else
             (f"training both identifiers, {args.epochs} epochs each" if args.epochs else
              f"training both identifiers, {seconds:.0f} s budget in total (at least "
              f"{study.MIN_EPOCHS['stable']} / {study.MIN_EPOCHS['unstable']} epochs)"))
          + f", {args.validation} validation systems, seed {args.seed}", flush=True)
    import warnings

    from aeid_struct.training import UndertrainedWarning

    with warnings.catch_warnings():   # printed below, beside the table they qualify
        warnings.simplefilter("ignore", UndertrainedWarning)
        result = study.run(pretrained=args.pretrained, seconds=seconds, seed=args.seed,
                           out=args.out, fig4_sizes=args.fig4_sizes if args.fig4 else None,
                           fig4_seconds=args.fig4_seconds, validation=args.validation,
                           progress=not args.quiet, command=command, epochs=args.epochs)
    print()
    print("Table I, ours beside the paper's (noise-free; Bode over "
          f"{result['frequency_grid_rad_s'][0]:g}-{result['frequency_grid_rad_s'][1]:g} rad/s, "
          f"{result['frequency_grid_rad_s'][2]} log-spaced points):")
    print(result["markdown"])
    print()
    for name, row in result["table"].items():
        trained = ("shipped identifier" if args.pretrained else
                   f"training {result['train_seconds'][name]:.1f} s, "
                   f"{result['train_epochs'][name]} epochs")
        print(f"{name}: {trained}, identification "
              f"{row['latency_ms']:.3f} ms per call (batch 1), "
              f"{row['throughput_per_s']:,.0f} identifications/s batched "
              f"(paper: {study.PAPER_SECONDS['encoder_400mhz']} s on a 400 MHz core)")
    for note in result["warnings"]:
        print(f"\nWARNING (under-trained): {note}")
    print("\nwrote " + ", ".join(result["run"]["files"]))
    return 0


def run_track(args: argparse.Namespace) -> int:
    """The ``track`` subcommand: follow a wearing robot leg window by window
    (``studies.wear``), print the tracking error, alarm delay and update time, write a PNG and a
    JSON file; with ``--y``, a measured stream (``track_stream.run_track_stream``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct track``.

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        A wrong identifier or tracker setting.
    """
    ident = load_identifier(args.model, "--model", args.maps)
    from aeid_struct import studies
    from aeid_struct.online import TrackerConfig

    stream = args.y is not None
    watch = args.watch if args.watch is not None else ([] if stream else ["k"])
    # a measured stream runs the identifier's own head (None); the leg's scenario the
    # tracker's default cap
    iterations = args.iterations if args.iterations is not None else (
        None if stream else TrackerConfig().iterations)
    try:
        config = TrackerConfig(hop=args.hop, smoothing=args.smoothing, median=args.median,
                               threshold=args.threshold,
                               baseline=args.baseline, patience=args.patience,
                               sigmas=args.sigmas, watch=tuple(watch), iterations=iterations)
    except ValueError as err:
        raise InputError(f"track: {err}") from None
    if stream:
        from aeid_struct.cli.track_stream import run_track_stream

        return run_track_stream(args, ident, config)
    if args.u is not None:
        raise InputError("track: --u belongs to a measured stream; give its outputs by --y")
    try:
        result = studies.wear.wear_study(ident, seconds=args.seconds, noise=args.noise,
                                         seed=args.seed, config=config, engine=args.engine)
    except ValueError as err:
        raise InputError(f"track: {err}") from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    png = out / "wear_tracking.png"
    source = (f"identifier file {args.model}" if Path(args.model).exists()
              else f"shipped identifier {args.model}")
    studies.figures.wear_figure(
        result, png, config=config,
        title=f"Wear scenario, {args.seconds:g} s, {100 * args.noise:g} % noise, seed "
              f"{args.seed}: {source}, {result.engine} engine")
    print(f"{ident!r}")
    print(f"wear scenario: {args.seconds:g} s, k 25 -> 20 N/m, d 2.5 -> 3.5 kg/s, m 1 kg, "
          f"{100 * args.noise:g} % noise, one window of {ident.steps} samples every {args.hop}")
    print("tracking error (RMS of the smoothed estimate, after the baseline windows): "
          + ", ".join(f"{p} {v:.2f} %" for p, v in result.rms.items()))
    print(f"true k left its start by {100 * args.threshold:g} % at {result.drift_time:.2f} s; "
          f"alarm at {result.alarm_time:.2f} s (delay {result.delay:.2f} s)")
    used = result.config
    print(f"smoothing: running median of {used.median} windows, moving average weight "
          f"{used.smoothing:g}; head: {ident.head if ident.head is not None else 'none'}")
    print(f"update (one window identified, {result.engine} engine): "
          f"{result.latency_ms:.3f} ms median, {result.latency_p95_ms:.3f} ms p95")
    js = out / "wear_tracking.json"
    js.write_text(json.dumps({"rms_percent": result.rms, "drift_time_s": result.drift_time,
                              "alarm_time_s": result.alarm_time, "delay_s": result.delay,
                              "latency_ms": result.latency_ms,
                              "latency_p95_ms": result.latency_p95_ms, "engine": result.engine,
                              "median": used.median, "smoothing": used.smoothing,
                              "windows": len(result.t)},
                             indent=2))
    print(f"wrote {png}, {js}")
    return 0
