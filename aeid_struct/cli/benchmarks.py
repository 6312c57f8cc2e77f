"""The benchmark subcommands: ``bench`` (identification accuracy and speed, the one-pass study,
the decoder timings), ``bench-online`` and ``bench-generic``, each printed and written as JSON.

The seam: these subcommands measure the library (``studies.bench``, ``studies.onepass_bench``,
``studies.bench_online``, ``studies.generic_bench``) rather than use it, and write their results
alike (JSON, numpy numbers as floats).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from aeid_struct.cli.errors import InputError
from aeid_struct.threads import settings


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
          f"identifiers; errors against the noise-free truth; {settings()}:", flush=True)
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
              f"(noise-free truth as reference); {settings()}:", flush=True)
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
        A record length shorter than the highest order needs after the records' largest delay.
    """
    from aeid_struct import studies
    from aeid_struct.generic import shortest

    if args.channels:
        return _bench_channels(args)
    generic_bench = studies.generic_bench
    lengths = tuple(args.lengths or ((400, 1000) if args.quick else (400, 1000, 5000)))
    # the benchmark's records have input delays up to 5 samples (generic_bench)
    need = shortest(max(args.orders)) + 5
    if min(lengths) < need:
        raise InputError(f"bench-generic: --lengths must be >= {need} (twice the parameters of "
                         f"an order-{max(args.orders)} model after a delay of up to 5 samples); "
                         f"got {min(lengths)}")
    count = args.count or (3 if args.quick else 10)
    print(f"Generic identifiers on unseen systems: {', '.join(args.plants)} plants, orders "
          f"{args.orders}, noise {args.noise}, lengths {list(lengths)}, {count} records per "
          f"cell; validation on the record's second half; {settings()}", flush=True)
    rows = generic_bench.bench_generic(orders=tuple(args.orders), noises=tuple(args.noise),
                                       lengths=lengths, count=count, seed=args.seed,
                                       progress=None if args.quiet else print,
                                       plants=tuple(dict.fromkeys(args.plants)))
    print()
    print(generic_bench.format_tables(rows))
    out = generic_bench.write_json(rows, args.json)
    print(f"wrote {out}")
    return 0


def _bench_channels(args: argparse.Namespace) -> int:
    """``bench-generic --channels``: the several-channel rows (``studies.channels_bench``)."""
    from aeid_struct import studies

    bench = studies.channels_bench
    count = args.count or (5 if args.quick else 20)
    print(f"Several channels and experiments: {count} record sets per row, noise 1-5 %, "
          f"validation on a further run; {settings()}", flush=True)
    rows = bench.bench_channels(count=count, seed=args.seed,
                                progress=None if args.quiet else print)
    print()
    print(bench.format_channels(rows))
    path = args.json if args.json != "out/bench_generic.json" else "out/bench_channels.json"
    print(f"wrote {bench.write_channels(rows, path)}")
    return 0


def run_bench_mechanism(args: argparse.Namespace) -> int:
    """The ``bench-mechanism`` subcommand: mechanisms written as Lagrangians, their
    identifiability, identifiers trained through the user's API and their accuracy and speed
    against a cold grey-box fit and n4sid (``studies.mechanism_bench``), printed and written
    as JSON.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct bench-mechanism``.

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        A case name the benchmark does not have.
    """
    from aeid_struct import studies

    mechanism_bench = studies.mechanism_bench
    seconds = args.seconds or (20.0 if args.quick else 120.0)
    records = args.records or (8 if args.quick else 40)
    timed = min(records, 4 if args.quick else 10)
    print(f"Mechanisms from their Lagrangians: {seconds:g} s of training per identifier, "
          f"{records} PRBS records per noise level {list(args.noise)}, {timed} timed at "
          f"batch 1; {settings()}", flush=True)
    try:
        rows = mechanism_bench.bench_mechanism(seconds=seconds, noises=tuple(args.noise),
                                               records=records, timed=timed, cases=args.cases,
                                               progress=None if args.quiet else print)
    except ValueError as err:
        raise InputError(f"bench-mechanism: {err}") from None
    print(mechanism_bench.report(rows))
    _write_json(rows, args.json)
    return 0

