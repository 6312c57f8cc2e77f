"""``aeid-struct identify-many SOURCE --identifier NAME --out DIR``: a fleet's records identified
on Dask (``aeid_struct.fleet.identify_many``), one row per record in a Parquet table."""

from __future__ import annotations

import argparse

from aeid_struct.cli.arguments import POSITIVE_INT, number
from aeid_struct.cli.errors import InputError
from aeid_struct.cli.user_maps import MAPS_HELP, maps_hint, read_maps

__all__ = ["add_identify_many", "run_identify_many"]


def add_identify_many(sub) -> None:
    """Add the ``identify-many`` subcommand to the subparsers ``sub``."""
    many = sub.add_parser(
        "identify-many",
        help="identify every record of a directory with a trained identifier on Dask, one row "
             "per record in a Parquet table (resumable)",
        usage="aeid-struct identify-many SOURCE --identifier NAME --out DIR [options]",
        description="Identify every record under SOURCE (a directory, searched recursively, "
                    "or one file: .npy y arrays (steps,) or (records, steps), .npz with y and "
                    "optionally u, .parquet tables with list columns y and optionally u, .csv in "
                    "the layouts of identify: t,u,y columns, its t checked against the "
                    "identifier's dt, or one record per line) with "
                    "a trained identifier (a shipped name or an identifier file), on a local "
                    "Dask cluster or the one at --scheduler. Each chunk of records is one task "
                    "and one Parquet part of DIR, written when it is done: run the same command "
                    "again to resume. Every record gets a row: its model (A, B, C, D row-major, "
                    "with n, m, p), the self-check (fit, outside, excess), its elements and "
                    "physical parameters, or the reason it was refused (the table's schema: "
                    "aeid_struct.fleet.work). Needs the fleet extra: pip install "
                    "\"aeid-struct[fleet]\".")
    many.add_argument("source", metavar="SOURCE", help="directory of record files, or one file")
    many.add_argument("--identifier", required=True, metavar="NAME",
                      help="a shipped identifier (e.g. leg-stable) or an identifier file")
    many.add_argument("--maps", default=None, metavar="FILE.py", help=MAPS_HELP)
    many.add_argument("--out", required=True, metavar="DIR",
                      help="output directory: the Parquet table (pandas.read_parquet(DIR))")
    many.add_argument("--scheduler", metavar="ADDRESS",
                      help="a Dask scheduler's address (tcp://host:8786); default: a local "
                           "cluster of --workers processes")
    many.add_argument("--workers", type=POSITIVE_INT, metavar="K",
                      help="local worker processes (default: one per core)")
    many.add_argument("--chunk", type=POSITIVE_INT, default=10_000, metavar="N",
                      help="records per task (default 10000)")
    many.add_argument("--retries", type=number(int, 0, strict=False), default=2, metavar="R",
                      help="times a failed task is run again (default 2)")
    many.add_argument("--quiet", action="store_true", help="no progress lines")
    many.set_defaults(func=run_identify_many)


def run_identify_many(args: argparse.Namespace) -> int:
    """Run ``identify-many``; print the run's summary.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        The fleet extra missing, or a source, identifier or option the library refuses.
    """
    try:
        import dask.distributed  # noqa: F401
        import pyarrow  # noqa: F401
    except ImportError as err:
        raise InputError(f"identify-many needs the fleet extra (Dask and pyarrow): pip install "
                         f"\"aeid-struct[fleet]\" ({err})") from None
    from aeid_struct.fleet import identify_many

    try:
        run = identify_many(args.source, args.identifier, args.out, scheduler=args.scheduler,
                            maps=read_maps(args.maps),
                            workers=args.workers, chunk=args.chunk, retries=args.retries,
                            progress=None if args.quiet else print)
    except ValueError as err:
        raise InputError(f"identify-many: {err}{maps_hint(err, args.maps)}") from None
    print(f"{run.records} records identified ({run.ok} with a model, {run.records - run.ok} "
          f"refused with their reason) in {run.seconds:.1f} s on {run.workers} workers: "
          f"{run.records_per_second:.0f} records/s; {run.skipped} of {run.chunks} chunks were "
          f"already done; table: {run.out}")
    return 0
