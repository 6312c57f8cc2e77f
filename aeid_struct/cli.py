"""The ``aeid-struct`` command.

Subcommands wrap the public API; nothing here is imported by the library itself.

- ``aeid-struct demo``: derive the robot-leg model with CasADi, simulate both subsystems with the
  exact FOH decoder, print their matrices and write a step-response PNG.
- ``aeid-struct leg``: the robot-leg study (train or ``--pretrained``, Table I, Fig. 3, Fig. 4).
- ``aeid-struct train``: train an identifier for a structure and a system family.
- ``aeid-struct identify``: identify a system from a record file with a trained identifier.
- ``aeid-struct bench``: measured timings, side by side in one run, printed and written as JSON.
- ``aeid-struct track``: follow a wearing robot leg window by window (PNG and JSON).
- ``aeid-struct bench-online``: the online targets (tracker, export latency, arbitrary inputs,
  out-of-range flags) in one run, printed and written as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def _demo(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import aeid_struct as ae
    from symbolic import leg

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    params = {"k": args.k, "d": args.d, "m": args.m}
    np.set_printoptions(precision=4, suppress=True)

    t0 = time.perf_counter()
    lin = leg.linearisation()(**params, l0=leg.L0, g=leg.G)
    A, B = np.array(lin["A"]), np.array(lin["B"])
    print(f"Robot leg (spring-loaded inverted pendulum), k={args.k} N/m, d={args.d} kg/s, "
          f"m={args.m} kg, l0={leg.L0} m, g={leg.G} m/s^2")
    print(f"Linearisation at the upright equilibrium by CasADi Jacobians (paper Eq. 16), "
          f"derived in {time.perf_counter() - t0:.2f} s:")
    print("A =\n", A)
    print("B =\n", B)

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    systems = [
        ("stable (translational, G1)", leg.stable_map(), args.dt_stable, args.steps_stable),
        ("unstable (rotational, G2)", leg.unstable_map(), args.dt_unstable, args.steps_unstable),
    ]
    for ax, (name, f, dt, steps) in zip(axes, systems, strict=True):
        ccf = f(**params)
        Ac, bc = np.array(ccf["A"]), np.array(ccf["B"])[:, 0]
        cc, dc = np.array(ccf["C"])[0], float(np.array(ccf["D"])[0, 0])
        u = np.ones(steps)
        y = ae.simulate(Ac, bc, cc, dc, u, dt)
        print(f"\n{name} subsystem in controllable canonical form (paper Eq. 5):")
        print("A =\n", Ac)
        print("b =", bc, " c =", cc, " d =", dc)
        print(f"poles: {np.linalg.eigvals(Ac)}")
        print(f"unit-step response: {steps} samples, dt = {dt} s, y[-1] = {y[-1]:.6g}")
        t = np.arange(steps) * dt
        ax.plot(t, y)
        ax.set_title(f"{name}: unit step")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("l - L [m]" if "stable (" in name else "theta - pi/2 [rad]")
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    png = out / "leg_step_responses.png"
    fig.savefig(png, dpi=120)
    print(f"\nwrote {png}")
    return 0


def _leg(args: argparse.Namespace) -> int:
    from . import study

    command = "aeid-struct " + " ".join(args.argv)
    seconds = args.seconds
    print("Robot-leg study (paper Sec. IV): "
          + ("shipped identifiers" if args.pretrained else
             (f"training both identifiers, {args.epochs} epochs each" if args.epochs else
              f"training both identifiers, {seconds:.0f} s budget in total (at least "
              f"{study.MIN_EPOCHS['stable']} / {study.MIN_EPOCHS['unstable']} epochs)"))
          + f", {args.validation} validation systems, seed {args.seed}", flush=True)
    import warnings

    from .training import UndertrainedWarning

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


def _structure(spec: str):
    """Parse a structure spec: ccf:N[:descartes][:feedthrough], mcf:REAL,PAIRS, leg-stable."""
    from . import structures

    parts = spec.split(":")
    try:
        if parts[0] == "ccf":
            flags = set(parts[2:])
            unknown = flags - {"descartes", "feedthrough"}
            if unknown:
                raise ValueError(f"unknown flags {sorted(unknown)}")
            return structures.CCF(int(parts[1]), descartes="descartes" in flags,
                                  feedthrough="feedthrough" in flags)
        if parts[0] == "mcf":
            real, pairs = (int(v) for v in parts[1].split(","))
            return structures.MCF(real=real, pairs=pairs)
        if parts[0] in ("leg-stable", "leg-unstable"):
            from .data import LegFamily

            family = LegFamily(subsystem=parts[0].split("-")[1])
            return structures.Physical(family.map(), bounds=dict(family.ranges),
                                       inverse=family.inverse())
    except (IndexError, ValueError) as err:
        raise SystemExit(f"aeid-struct: --structure {spec!r} is malformed ({err}); expected "
                         "ccf:N[:descartes][:feedthrough], mcf:REAL,PAIRS, leg-stable or "
                         "leg-unstable") from None
    raise SystemExit(f"aeid-struct: --structure must be ccf:..., mcf:... or leg-stable/"
                     f"leg-unstable; got {spec!r}")


def _family(spec: str):
    """Parse a family spec: leg-stable, leg-unstable, poles:REAL,PAIRS."""
    from .data import LegFamily, PoleFamily

    if spec in ("leg-stable", "leg-unstable"):
        return LegFamily(subsystem=spec.split("-")[1])
    if spec.startswith("poles:"):
        try:
            real, pairs = (int(v) for v in spec[6:].split(","))
        except ValueError:
            raise SystemExit(f"aeid-struct: --family {spec!r} is malformed; expected "
                             "poles:REAL,PAIRS") from None
        return PoleFamily(real=real, pairs=pairs)
    raise SystemExit(f"aeid-struct: --family must be leg-stable, leg-unstable or "
                     f"poles:REAL,PAIRS; got {spec!r}")


def _train(args: argparse.Namespace) -> int:
    from .encoder import EncoderConfig
    from .training import TrainConfig, train

    structure = _structure(args.structure)
    family = _family(args.family)
    noise = args.noise[0] if len(args.noise) == 1 else tuple(args.noise)
    config = TrainConfig(dt=args.dt, steps=args.steps, count=args.count, epochs=args.epochs,
                         seconds=args.seconds, batch=args.batch, lr=args.lr, gamma=args.gamma,
                         noise=noise, excitation=args.excitation, seed=args.seed,
                         checkpoint=args.checkpoint, progress=not args.quiet)
    encoder = EncoderConfig(width=args.width, kernel=args.kernel, dense=tuple(args.dense),
                            pool=args.pool)
    from .data import LegFamily
    from .structures import CCF

    # A CCF identifier of a leg subsystem reports k, d, m through the CasADi inverse.
    inverse = family.inverse() if isinstance(family, LegFamily) and isinstance(
        structure, CCF) and structure.n == 2 else None
    ident = train(structure, family, config, encoder=encoder, inverse=inverse,
                  meta={"command": "aeid-struct " + " ".join(args.argv), "seed": args.seed})
    path = ident.save(args.out)
    info = ident.meta["train"]
    print(f"trained {ident!r}: {info['epochs']} epochs in {info['seconds']:.1f} s, "
          f"best held-out loss {info['best_holdout_loss']:.3e}; wrote {path}")
    return 0


def _load_records(path: str, name: str) -> np.ndarray:
    p = Path(path)
    if not p.is_file():
        raise SystemExit(f"aeid-struct: --{name} must be an existing .npy or .csv file; "
                         f"got {path!r}")
    if p.suffix == ".npy":
        return np.load(p, allow_pickle=False)
    return np.loadtxt(p, delimiter=",", ndmin=1)


def _identify(args: argparse.Namespace) -> int:
    from .identify import Identifier, load_pretrained

    # One file per record: a joint identifier (several records) takes one per subsystem.
    ys = [_load_records(p, "y") for p in args.y]
    us = [_load_records(p, "u") for p in args.u] if args.u else None
    y = ys[0] if len(ys) == 1 else ys
    u = None if us is None else (us[0] if len(us) == 1 else us)
    try:
        ident = (Identifier.load(args.model) if Path(args.model).exists()
                 else load_pretrained(args.model))
    except ValueError as err:
        raise SystemExit(f"aeid-struct: model {args.model!r}: {err}") from None
    try:
        est = ident.identify(y, u, refine=args.refine)
    except ValueError as err:
        raise SystemExit(f"aeid-struct: {err}") from None
    np.set_printoptions(precision=6, suppress=False)
    result = {"A": est.A.tolist(), "b": est.b.tolist(), "c": est.c.tolist(),
              "d": np.asarray(est.d).tolist(), "fit_percent": np.asarray(est.fit).tolist(),
              "records": est.records,
              "physical": {k: np.asarray(v).tolist() for k, v in est.physical.items()},
              "seconds": est.seconds}
    print(f"{ident!r}")
    print("A =\n", est.A)
    print("b =", est.b, " c =", est.c, " d =", est.d)
    print("fit (NRMSE %) =", est.fit)
    if est.physical:
        print("physical:", {k: np.round(v, 6).tolist() for k, v in est.physical.items()})
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2))
        print(f"wrote {args.json}")
    return 0


def _track(args: argparse.Namespace) -> int:
    from .identify import Identifier, load_pretrained
    from .online import TrackerConfig, wear_study
    from .plots import wear

    try:
        ident = (Identifier.load(args.model) if Path(args.model).exists()
                 else load_pretrained(args.model))
        config = TrackerConfig(hop=args.hop, smoothing=args.smoothing, median=args.median,
                               threshold=args.threshold,
                               baseline=args.baseline, patience=args.patience,
                               watch=tuple(args.watch))
        result = wear_study(ident, seconds=args.seconds, noise=args.noise, seed=args.seed,
                            config=config, engine=args.engine)
    except ValueError as err:
        raise SystemExit(f"aeid-struct: {err}") from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    png = out / "wear_tracking.png"
    wear(result, png)
    print(f"{ident!r}")
    print(f"wear scenario: {args.seconds:g} s, k 25 -> 20 N/m, d 2.5 -> 3.5 kg/s, m 1 kg, "
          f"{100 * args.noise:g} % noise, one window of {ident.steps} samples every {args.hop}")
    print("tracking error (RMS of the smoothed estimate, after the baseline windows): "
          + ", ".join(f"{p} {v:.2f} %" for p, v in result.rms.items()))
    print(f"true k left its start by {100 * args.threshold:g} % at {result.drift_time:.2f} s; "
          f"alarm at {result.alarm_time:.2f} s (delay {result.delay:.2f} s)")
    print(f"update (one window identified, {result.engine} engine): "
          f"{result.latency_ms:.3f} ms median, one call each")
    js = out / "wear_tracking.json"
    js.write_text(json.dumps({"rms_percent": result.rms, "drift_time_s": result.drift_time,
                              "alarm_time_s": result.alarm_time, "delay_s": result.delay,
                              "latency_ms": result.latency_ms, "engine": result.engine,
                              "windows": len(result.t)},
                             indent=2))
    print(f"wrote {png}, {js}")
    return 0


def _bench_online(args: argparse.Namespace) -> int:
    from .bench_online import bench_online, format_tables

    print("Online identification (issue 6's targets), measured in one run on the shipped "
          "identifiers; errors against the noise-free truth:", flush=True)
    result = bench_online(quick=args.quick, seconds=args.seconds, noise=args.noise,
                          progress=not args.quiet)
    print()
    print(format_tables(result))
    t = result["targets"]
    print("Targets: update <= 0.5 ms | k within 2 % RMS at 1 % noise | alarm delay stated | "
          ">= 90 % flagged 30 % beyond the range with <= 5 % false flags")
    print(f"Measured: update {t['update_ms_median']:.3f} ms | k {t['k_rms_percent_mean']:.2f} % "
          f"RMS | alarm delay " + ", ".join(f"{d:+.1f} s" for d in t["alarm_delay_s"])
          + f" | flagged {100 * t['flagged_30_percent_beyond_min']:.1f} % with "
          f"{100 * t['false_flags_max']:.1f} % false")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float))
    print(f"wrote {out}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    import torch

    from .bench import (
        bench_decoder,
        bench_identification,
        format_decoder_table,
        format_identification_table,
    )

    result = {}
    if not args.decoder_only:
        count = args.count or (20 if args.quick else 500)
        print(f"Identification of the robot-leg subsystems: {count} systems per subsystem and "
              f"noise level, one call per record, all methods on the same records "
              f"(noise-free truth as reference), {torch.get_num_threads()} torch thread(s):",
              flush=True)
        ident = bench_identification(count=count, noises=tuple(args.noise),
                                     progress=not args.quiet)
        print()
        print(format_identification_table(ident))
        result["identification"] = ident
    steps = (100, 300) if args.quick else tuple(args.steps)
    rows = []
    for dtype in (torch.float32, torch.float64):
        rows += bench_decoder(batch=args.batch, steps=steps, dtype=dtype, threads=args.threads)
    print(f"\nDecoder forward+backward, batch {args.batch}, {args.threads} thread(s):")
    print(format_decoder_table(rows))
    result["decoder"] = [_row_dict(r) for r in rows]
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float))
    print(f"wrote {out}")
    return 0


def _row_dict(row) -> dict:
    from dataclasses import asdict

    d = asdict(row)
    return {k: (str(v) if not isinstance(v, (int, float, str)) else v) for k, v in d.items()}


def build_parser() -> argparse.ArgumentParser:
    # light (numpy only): the tracker's defaults are the CLI's
    from .online import TrackerConfig

    parser = argparse.ArgumentParser(
        prog="aeid-struct",
        description="Structured, amortized identification of continuous-time LTI systems.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser(
        "demo",
        help="derive the robot-leg model, simulate both subsystems, write a step-response PNG",
    )
    demo.add_argument("--k", type=float, default=24.23, help="spring stiffness [N/m]")
    demo.add_argument("--d", type=float, default=2.24, help="damping [kg/s]")
    demo.add_argument("--m", type=float, default=1.01, help="mass [kg]")
    demo.add_argument("--dt-stable", type=float, default=0.01)
    demo.add_argument("--steps-stable", type=int, default=300)
    demo.add_argument("--dt-unstable", type=float, default=0.005)
    demo.add_argument("--steps-unstable", type=int, default=100)
    demo.add_argument("--out", default="out", help="folder for the PNG (default: out)")
    demo.set_defaults(func=_demo)

    legp = sub.add_parser(
        "leg", help="the robot-leg study: train, evaluate, Table I, Fig. 3 (and Fig. 4)")
    legp.add_argument("--pretrained", action="store_true",
                      help="evaluate the shipped identifiers instead of training (seconds)")
    legp.add_argument("--seconds", type=float, default=300.0,
                      help="training budget for both identifiers together (default 300)")
    legp.add_argument("--epochs", type=int, default=None,
                      help="train each identifier for this many epochs instead of a time "
                           "budget (reproducible on a busy machine)")
    legp.add_argument("--seed", type=int, default=0)
    legp.add_argument("--validation", type=int, default=500,
                      help="fresh validation systems (default 500)")
    legp.add_argument("--fig4", action="store_true",
                      help="also train at several data sizes for Fig. 4 (takes longer)")
    legp.add_argument("--fig4-sizes", type=int, nargs="+",
                      default=[100, 300, 1000, 3000, 10000, 30000, 100000])
    legp.add_argument("--fig4-seconds", type=float, default=30.0,
                      help="training budget per size and subsystem for Fig. 4")
    legp.add_argument("--out", default="out/leg",
                      help="parent folder: a run writes JSON, PNGs and identifiers to "
                           "OUT/trained or OUT/pretrained (default out/leg)")
    legp.add_argument("--quiet", action="store_true", help="no progress lines")
    legp.set_defaults(func=_leg)

    tr = sub.add_parser("train", help="train an identifier for a structure and a family")
    tr.add_argument("--structure", required=True,
                    help="ccf:N[:descartes][:feedthrough], mcf:REAL,PAIRS, leg-stable")
    tr.add_argument("--family", required=True, help="leg-stable, leg-unstable, poles:REAL,PAIRS")
    tr.add_argument("--dt", type=float, required=True)
    tr.add_argument("--steps", type=int, required=True)
    tr.add_argument("--count", type=int, default=10_000)
    tr.add_argument("--epochs", type=int, default=200)
    tr.add_argument("--seconds", type=float, default=None)
    tr.add_argument("--batch", type=int, default=128)
    tr.add_argument("--lr", type=float, default=3e-3)
    tr.add_argument("--gamma", type=float, default=None,
                    help="weight of Eq. 14's stationary-value term (default: 1 for steps, else 0)")
    tr.add_argument("--noise", type=float, nargs="+", default=[0.0],
                    help="a level, or LO HI drawn per record (std relative to max|y|)")
    tr.add_argument("--excitation", default="step")
    tr.add_argument("--width", type=int, default=12)
    tr.add_argument("--kernel", type=int, default=5)
    tr.add_argument("--dense", type=int, nargs="+", default=[48, 48])
    tr.add_argument("--pool", type=int, default=1)
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--checkpoint", default=None, help="checkpoint file to resume from")
    tr.add_argument("--out", required=True, help="identifier file to write (.aeid)")
    tr.add_argument("--quiet", action="store_true")
    tr.set_defaults(func=_train)

    trk = sub.add_parser(
        "track", help="follow a wearing robot leg window by window (online identification): "
                      "prints tracking error, alarm delay, update time; writes a PNG")
    trk.add_argument("--model", default="leg-stable-window",
                     help="an identifier of mid-motion windows reading u (.aeid file or a "
                          "shipped name)")
    trk.add_argument("--seconds", type=float, default=120.0, help="length of the scenario")
    trk.add_argument("--noise", type=float, default=0.01, help="measurement noise, of max|y|")
    tracker = TrackerConfig()          # the tracker's own defaults, not copies of them
    for name, kind, text in (
            ("hop", int, "samples between identifications"),
            ("smoothing", float, "moving-average weight"),
            ("median", int, "window estimates in the running median before the moving average"),
            ("threshold", float, "relative drift that alarms"),
            ("baseline", int, "windows in the reference"),
            ("patience", int, "windows over the threshold")):
        trk.add_argument(f"--{name}", type=kind, default=getattr(tracker, name), help=text)
    trk.add_argument("--watch", nargs="*", default=["k"],
                     help="parameters whose drift raises the alarm (default: k, the spring)")
    trk.add_argument("--seed", type=int, default=0)
    trk.add_argument("--engine", choices=("auto", "onnx", "identifier"), default="auto",
                     help="onnx: the exported encoder under onnxruntime (auto: when installed)")
    trk.add_argument("--out", default="out/track", help="folder for the PNG and JSON")
    trk.set_defaults(func=_track)

    idp = sub.add_parser("identify", help="identify a system from a record file")
    idp.add_argument("model", help="an .aeid file or a shipped name (leg-stable, leg-unstable)")
    idp.add_argument("--y", required=True, nargs="+",
                     help="output record(s): .npy or .csv, one per row; one file per record "
                          "(subsystem) for a joint identifier")
    idp.add_argument("--u", default=None, nargs="+",
                     help="input record(s), files like --y; default: a unit step")
    idp.add_argument("--refine", action="store_true", help="polish with the CasADi NLP")
    idp.add_argument("--json", default=None, help="write the estimate as JSON")
    idp.set_defaults(func=_identify)

    bench = sub.add_parser(
        "bench", help="accuracy and speed of the encoder, refinement and classical baselines, "
                      "and decoder timings, measured side by side; prints and writes JSON")
    bench.add_argument("--quick", action="store_true", help="20 systems, short decoder table")
    bench.add_argument("--count", type=int, default=None,
                       help="systems per subsystem and noise level (default 500)")
    bench.add_argument("--noise", type=float, nargs="+", default=[0.0, 0.01, 0.05],
                       help="noise levels, std relative to max|y| (default 0 0.01 0.05)")
    bench.add_argument("--decoder-only", action="store_true", help="only the decoder timings")
    bench.add_argument("--batch", type=int, default=256)
    bench.add_argument("--steps", type=int, nargs="+", default=[100, 300, 1000])
    bench.add_argument("--threads", type=int, default=1,
                       help="torch threads for the decoder timings (default 1: steady on a "
                            "busy box)")
    bench.add_argument("--json", default="out/bench.json")
    bench.add_argument("--quiet", action="store_true")
    bench.set_defaults(func=_bench)

    bon = sub.add_parser(
        "bench-online", help="online identification: tracker error, alarm delay and update "
                             "time, export latency, arbitrary inputs, out-of-range flags")
    bon.add_argument("--quick", action="store_true",
                     help="a 30 s scenario, one seed, 20 records per row (for tests)")
    bon.add_argument("--seconds", type=float, default=120.0, help="wear scenario length")
    bon.add_argument("--noise", type=float, default=0.01, help="tracker measurement noise")
    bon.add_argument("--json", default="out/bench_online.json")
    bon.add_argument("--quiet", action="store_true", help="no progress lines")
    bon.set_defaults(func=_bench_online)
    return parser


def main(argv: list[str] | None = None) -> int:
    import matplotlib

    matplotlib.use("Agg")   # the CLI only writes PNG files
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
