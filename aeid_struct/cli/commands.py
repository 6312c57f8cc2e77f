"""The subcommands that run the library's studies and benchmarks: ``leg``, ``train``, ``track``,
``bench`` and ``bench-online`` (``demo`` and ``identify`` have modules of their own)."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from aeid_struct.cli.errors import InputError, one_line
from aeid_struct.cli.identify import load_identifier


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


def _fixed_element(flag: str) -> tuple[str, float]:
    """``"c1=0"`` -> ``("c1", 0.0)``; a ValueError for a value that is not a finite number."""
    name, _, value = flag.partition("=")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"element {name!r} must be fixed to a finite number; got {value!r}")
    return name, number


def parse_structure(spec: str):
    """The structure a ``train --structure`` spec names.

    Parameters
    ----------
    spec : str
        ``ccf:N[:descartes][:feedthrough][:NAME=VALUE...]``, ``mcf:REAL,PAIRS``, ``leg-stable``
        or ``leg-unstable``. ``NAME=VALUE`` fixes an element (``ccf:2:a1=0:c1=0``: the rotational
        leg's physics structure, no damping and no s-term).

    Returns
    -------
    Structure

    Raises
    ------
    InputError
        A malformed or unknown spec.
    """
    from aeid_struct import structures

    parts = spec.split(":")
    try:
        if parts[0] == "ccf":
            fixed = dict(_fixed_element(f) for f in parts[2:] if "=" in f)
            flags = {f for f in parts[2:] if "=" not in f}
            unknown = flags - {"descartes", "feedthrough"}
            if unknown:
                raise ValueError(f"unknown flags {sorted(unknown)}")
            ccf = structures.CCF(int(parts[1]), descartes="descartes" in flags,
                                 feedthrough="feedthrough" in flags)
            return ccf.fixed(**fixed) if fixed else ccf
        if parts[0] == "mcf":
            real, pairs = (int(v) for v in parts[1].split(","))
            return structures.MCF(real=real, pairs=pairs)
        if parts[0] in ("leg-stable", "leg-unstable"):
            from aeid_struct.training import LegFamily

            family = LegFamily(subsystem=parts[0].split("-")[1])
            return structures.Physical(family.map(), bounds=dict(family.ranges),
                                       inverse=family.inverse())
    except (IndexError, ValueError) as err:
        raise InputError(f"train: --structure {spec!r} is malformed ({one_line(err)}); "
                         "expected ccf:N[:descartes][:feedthrough][:NAME=VALUE...], "
                         "mcf:REAL,PAIRS, leg-stable or leg-unstable") from None
    raise InputError(f"train: --structure must be ccf:..., mcf:... or leg-stable/leg-unstable; "
                     f"got {spec!r}")


def parse_family(spec: str):
    """The system family a ``train --family`` spec names.

    Parameters
    ----------
    spec : str
        ``leg-stable``, ``leg-unstable`` or ``poles:REAL,PAIRS``.

    Returns
    -------
    LegFamily or PoleFamily

    Raises
    ------
    InputError
        A malformed or unknown spec.
    """
    from aeid_struct.training import LegFamily, PoleFamily

    if spec in ("leg-stable", "leg-unstable"):
        return LegFamily(subsystem=spec.split("-")[1])
    if spec.startswith("poles:"):
        try:
            real, pairs = (int(v) for v in spec[6:].split(","))
            return PoleFamily(real=real, pairs=pairs)
        except ValueError as err:
            raise InputError(f"train: --family {spec!r} is malformed ({one_line(err)}); "
                             "expected poles:REAL,PAIRS") from None
    raise InputError(f"train: --family must be leg-stable, leg-unstable or poles:REAL,PAIRS; "
                     f"got {spec!r}")


def run_train(args: argparse.Namespace) -> int:
    """The ``train`` subcommand: train an identifier and write its ``.aeid`` file.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct train``.

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        A wrong structure, family, setting (``TrainConfig``) or output file.
    """
    if Path(args.out).is_dir():
        raise InputError(f"train: --out {args.out!r} is a folder; expected the identifier file "
                         "to write (e.g. model.aeid)")
    structure = parse_structure(args.structure)
    family = parse_family(args.family)
    order = getattr(family, "n", 2)          # a leg subsystem is of order 2
    if structure.n != order:
        raise InputError(f"train: --structure {args.structure!r} has order {structure.n} but "
                         f"--family {args.family!r} has systems of order {order}; they must "
                         "agree")
    from aeid_struct.encoder import EncoderConfig
    from aeid_struct.structures import CCF
    from aeid_struct.training import LegFamily, TrainConfig, process_rank, train

    if len(args.noise) > 2:
        raise InputError(f"train: --noise takes one level or LO HI; got {len(args.noise)} "
                         f"values {args.noise}")
    noise = args.noise[0] if len(args.noise) == 1 else tuple(args.noise)
    try:
        config = TrainConfig(dt=args.dt, steps=args.steps, count=args.count, epochs=args.epochs,
                             seconds=args.seconds, batch=args.batch, lr=args.lr,
                             gamma=args.gamma, noise=noise, excitation=args.excitation,
                             seed=args.seed, checkpoint=args.checkpoint,
                             progress=not args.quiet, device=args.device)
        encoder = EncoderConfig(width=args.width, kernel=args.kernel, dense=tuple(args.dense),
                                pool=args.pool)
    except ValueError as err:
        raise InputError(f"train: {err}") from None
    # A CCF identifier of a leg subsystem reports k, d, m through the CasADi inverse.
    inverse = family.inverse() if isinstance(family, LegFamily) and isinstance(
        structure, CCF) and structure.n == 2 else None
    try:
        # train() checks the structure against the family and the checkpoint against the run
        ident = train(structure, family, config, encoder=encoder, inverse=inverse,
                      meta={"command": "aeid-struct " + " ".join(args.argv), "seed": args.seed})
    except ValueError as err:
        raise InputError(f"train: {err}") from None
    if process_rank() != 0:
        return 0                   # under torchrun, rank 0 writes the identifier and reports
    try:
        path = ident.save(args.out)
    except OSError as err:
        raise InputError(f"train: --out {args.out!r}: cannot write the identifier "
                         f"({err.strerror or err})") from None
    info = ident.meta["train"]
    print(f"trained {ident!r}: {info['epochs']} epochs in {info['seconds']:.1f} s, "
          f"best held-out loss {info['best_holdout_loss']:.3e}; wrote {path}")
    return 0


def run_track(args: argparse.Namespace) -> int:
    """The ``track`` subcommand: follow a wearing robot leg window by window
    (``studies.wear``), print the tracking error, alarm delay and update time, write a PNG and a
    JSON file.

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
    ident = load_identifier(args.model, "--model")
    from aeid_struct import studies
    from aeid_struct.online import TrackerConfig

    try:
        config = TrackerConfig(hop=args.hop, smoothing=args.smoothing, median=args.median,
                               threshold=args.threshold,
                               baseline=args.baseline, patience=args.patience,
                               watch=tuple(args.watch), iterations=args.iterations)
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


def run_bench_online(args: argparse.Namespace) -> int:
    """The ``bench-online`` subcommand: the online benchmark (``studies.bench_online``), printed and
    written as JSON.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct bench-online``.

    Returns
    -------
    int
        0.
    """
    from aeid_struct import studies

    bench = studies.bench_online
    print("Online identification (issue 6's targets), measured in one run on the shipped "
          "identifiers; errors against the noise-free truth:", flush=True)
    result = bench.bench_online(quick=args.quick, seconds=args.seconds, noise=args.noise,
                                progress=not args.quiet)
    print()
    print(bench.format_tables(result))
    t = result["targets"]
    print("Targets: update <= 0.5 ms | k within 2 % RMS at 1 % noise | alarm delay stated | "
          ">= 90 % flagged 30 % beyond the range with <= 5 % false flags")
    print(f"Measured: update {t['update_ms_median']:.3f} ms | k {t['k_rms_percent_mean']:.2f} % "
          f"RMS | alarm delay " + ", ".join(f"{d:+.1f} s" for d in t["alarm_delay_s"])
          + f" | flagged {100 * t['flagged_30_percent_beyond_min']:.1f} % with "
          f"{100 * t['false_flags_max']:.1f} % false")
    _write_json(result, args.json)
    return 0


def _write_json(result: dict, path) -> None:
    """Write a benchmark's result as JSON (numpy numbers as floats) and say where."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float))
    print(f"wrote {out}")


def run_bench(args: argparse.Namespace) -> int:
    """The ``bench`` subcommand: identification accuracy and speed of every method
    (``studies.bench``), the one-pass study (``studies.onepass_bench``) and the decoder timings,
    printed and written as JSON (``identification``, ``onepass``, ``decoder``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct bench``.

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        ``--decoder-only`` with ``--onepass-only``, or ``--timed`` above ``--records``.
    """
    import torch

    from aeid_struct import studies

    bench = studies.bench
    if args.decoder_only and args.onepass_only:
        raise InputError("bench: --decoder-only and --onepass-only exclude each other")
    if args.records and args.timed and args.timed > args.records:
        raise InputError(f"bench: --timed must be <= --records ({args.records}); got "
                         f"{args.timed}")
    result = {}
    if not (args.decoder_only or args.onepass_only):
        count = args.count or (20 if args.quick else 500)
        print(f"Identification of the robot-leg subsystems: {count} systems per subsystem and "
              f"noise level, one call per record, all methods on the same records "
              f"(noise-free truth as reference), {torch.get_num_threads()} torch thread(s):",
              flush=True)
        ident = bench.bench_identification(count=count, noises=tuple(args.noise or
                                                                     (0.0, 0.01, 0.05)),
                                           progress=not args.quiet)
        print()
        print(bench.format_identification_table(ident))
        result["identification"] = ident
    if not args.decoder_only:
        result["onepass"] = _run_onepass(args)
    if not args.onepass_only:
        result["decoder"] = _run_decoder(args)
    _write_json(result, args.json)
    return 0


def _run_onepass(args: argparse.Namespace) -> dict:
    """The one-pass study of ``bench`` (``studies.onepass_bench``), printed; its result."""
    from aeid_struct import studies

    onepass_bench, onepass_tables = studies.onepass_bench, studies.onepass_tables
    kw = {"names": tuple(args.identifiers)} if args.identifiers else {}
    if args.kinds:
        kw["kinds"] = tuple(args.kinds)
    print("\nOne pass at the optimum (issue 15): the encoder alone, the one pass, the "
          "least-squares optimum and the cold classical fits on the same records, one thread "
          "(progress on stderr):", flush=True)
    result = onepass_bench.bench_onepass(
        quick=args.quick, noises=tuple(args.noise) if args.noise else None,
        count=args.records, timed=min(args.timed or (4 if args.quick else 30),
                                      args.records or (8 if args.quick else 60)),
        progress=not args.quiet, **kw)
    print()
    print(onepass_tables.format_onepass_tables(result))
    return result


def _run_decoder(args: argparse.Namespace) -> list:
    """The decoder timings of ``bench`` (``studies.bench.bench_decoder``), printed; the rows."""
    import torch

    from aeid_struct import studies

    bench = studies.bench
    steps = (100, 300) if args.quick else tuple(args.steps)
    rows = []
    for dtype in (torch.float32, torch.float64):
        rows += bench.bench_decoder(batch=args.batch, steps=steps, dtype=dtype,
                                    threads=args.threads)
    print(f"\nDecoder forward+backward, batch {args.batch}, {args.threads} thread(s):")
    print(bench.format_decoder_table(rows))
    return [_row_dict(r) for r in rows]


def _row_dict(row) -> dict:
    from dataclasses import asdict

    d = asdict(row)
    return {k: (str(v) if not isinstance(v, (int, float, str)) else v) for k, v in d.items()}


def run_bench_generic(args: argparse.Namespace) -> int:
    """The ``bench-generic`` subcommand: the generic identifiers against the classical
    baselines on unseen systems (``studies.generic_bench``), printed and written as JSON.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct bench-generic``.

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        A record length shorter than the identifiers' window.
    """
    from aeid_struct import studies

    generic_bench = studies.generic_bench
    lengths = tuple(args.lengths or ((400, 1000) if args.quick else (400, 1000, 5000)))
    if min(lengths) < 256:
        raise InputError(f"bench-generic: --lengths must be >= 256 (the generic identifiers' "
                         f"window); got {min(lengths)}")
    count = args.count or (3 if args.quick else 10)
    print(f"Generic identifiers on unseen systems: orders {args.orders}, noise {args.noise}, "
          f"lengths {list(lengths)}, {count} records per cell; validation on the record's "
          f"second half", flush=True)
    rows = generic_bench.bench_generic(orders=tuple(args.orders), noises=tuple(args.noise),
                                       lengths=lengths, count=count, seed=args.seed,
                                       progress=None if args.quiet else print)
    print()
    print(generic_bench.format_tables(rows))
    out = generic_bench.write_json(rows, args.json)
    print(f"wrote {out}")
    return 0

