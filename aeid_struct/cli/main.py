"""The ``aeid-struct`` command: ``main`` parses the arguments and runs a subcommand.

Subcommands wrap the public API; nothing here is imported by the library itself.

- ``aeid-struct demo``: derive the robot-leg model with CasADi, simulate both subsystems with the
  exact FOH decoder, print their matrices and write a step-response PNG.
- ``aeid-struct leg``: the robot-leg study (train or ``--pretrained``, Table I, Fig. 3, Fig. 4).
- ``aeid-struct train``: train an identifier for a structure and a system family.
- ``aeid-struct identify``: identify a system from a record file with a trained identifier, and
  print the identifier's self-check (fit, excess, inside or outside its training range).
- ``aeid-struct bench``: measured timings, side by side in one run, printed and written as JSON.
- ``aeid-struct track``: follow a wearing robot leg window by window (PNG and JSON).
- ``aeid-struct bench-online``: the online targets (tracker, export latency, arbitrary inputs,
  out-of-range flags) in one run, printed and written as JSON.

Exit status: 0 done; 2 (``EXIT_INPUT``) a usage or input error, reported as one line
``aeid-struct: error: ...`` on stderr that names the argument or file, what was expected and what
came (``main`` raises ``UsageExit``, a ``SystemExit`` carrying the message); 3 (``EXIT_OUTSIDE``)
``identify`` made an estimate that its identifier flags outside its training range
(``Estimate.outside``), unless ``--allow-outside``; a traceback (status 1) is a bug.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from aeid_struct.cli.errors import InputError, UsageExit, one_line
from aeid_struct.cli.parser import build_parser

#: Subcommands that write figures (matplotlib is imported, with the file-only Agg backend).
_PLOTTING = ("demo", "leg", "track", "bench", "bench-online")


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse an output path of the wrong kind before any work: --out of demo, leg and track is
    a folder, a --json file is not one."""
    if args.command in ("demo", "leg", "track") and Path(args.out).exists() \
            and not Path(args.out).is_dir():
        raise InputError(f"{args.command}: --out {args.out!r} is a file; expected a folder for "
                         "the figures and JSON")
    if getattr(args, "json", None) and Path(args.json).is_dir():
        raise InputError(f"{args.command}: --json {args.json!r} is a folder; expected the JSON "
                         "file to write")


def main(argv: list[str] | None = None) -> int:
    """Run the command.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        The exit status: 0, or ``EXIT_OUTSIDE`` (``identify``, an estimate flagged outside its
        identifier's training range).

    Raises
    ------
    UsageExit
        A usage or input error (status ``EXIT_INPUT``), after printing it as one line on stderr.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
        args.argv = argv
        _check_outputs(args)
        if args.command in _PLOTTING:
            import matplotlib

            matplotlib.use("Agg")   # the CLI only writes PNG files
        return args.func(args)
    except InputError as err:
        message = one_line(err)
        print(f"aeid-struct: error: {message}", file=sys.stderr)
        raise UsageExit(message) from None


if __name__ == "__main__":
    sys.exit(main())
