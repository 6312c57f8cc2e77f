"""The parser of the ``aeid-struct`` command: one function per subcommand adds its options.

Building the parser and printing its help import neither torch nor CasADi (the subcommands import
what they need when they run), so ``--help`` is immediate. Here are the parser itself and the
options of the subcommands that use the library (``demo``, ``leg``, ``track``, ``identify``); the
training subcommands' options are in ``train_options``, the benchmarks' in ``bench_options``, and
the argument types and help layout they all share in ``arguments``.
"""

from __future__ import annotations

import argparse

from aeid_struct.cli.arguments import FRACTION, POSITIVE, POSITIVE_INT, Parser, number
from aeid_struct.cli.bench_options import (
    add_bench,
    add_bench_generic,
    add_bench_mechanism,
    add_bench_online,
)
from aeid_struct.cli.commands import run_leg, run_track
from aeid_struct.cli.demo import run_demo
from aeid_struct.cli.errors import EXIT_INPUT, EXIT_OUTSIDE
from aeid_struct.cli.identify import generic_names, run_identify, shipped_names
from aeid_struct.cli.identify_many import add_identify_many
from aeid_struct.cli.records_io import RECORD_LAYOUTS
from aeid_struct.cli.train_options import add_train, add_train_generic
from aeid_struct.cli.user_maps import MAPS_HELP


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, with every option's help text (a test checks).

    Building it and printing its help import neither torch nor CasADi.

    Returns
    -------
    argparse.ArgumentParser
        Its errors raise ``InputError`` (``main`` prints them as one line).
    """
    names = ", ".join(shipped_names())
    parser = Parser(
        prog="aeid-struct",
        description="Structured, amortized identification of continuous-time LTI systems.",
        epilog=f"Exit status: 0 done; {EXIT_INPUT} a usage or input error (one line on stderr); "
               f"{EXIT_OUTSIDE} identify made an estimate flagged outside its identifier's "
               "training range (unless --allow-outside).",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="command",
                                help="one of the subcommands below ('aeid-struct COMMAND --help' "
                                     "for its options)")
    _add_demo(sub)
    _add_leg(sub)
    add_train(sub)
    add_train_generic(sub)
    _add_track(sub, names)
    _add_identify(sub, names, ", ".join(generic_names()))
    add_identify_many(sub)
    add_bench(sub)
    add_bench_online(sub)
    add_bench_generic(sub)
    add_bench_mechanism(sub)
    return parser


def _add_demo(sub) -> None:
    demo = sub.add_parser(
        "demo",
        help="derive the robot-leg model, simulate both subsystems, write a step-response PNG",
        description="Derive the robot-leg model with CasADi (paper Eq. 16), print both "
                    "subsystems in controllable canonical form, and write their unit-step "
                    "responses (exact FOH simulation) to OUT/leg_step_responses.png.")
    demo.add_argument("--k", type=POSITIVE, default=24.23, help="spring stiffness [N/m]")
    demo.add_argument("--d", type=POSITIVE, default=2.24, help="damping [kg/s]")
    demo.add_argument("--m", type=POSITIVE, default=1.01, help="mass [kg]")
    demo.add_argument("--dt-stable", type=POSITIVE, default=0.01,
                      help="sample time of the translational (stable) response [s] "
                           "(default 0.01)")
    demo.add_argument("--steps-stable", type=number(int, 2, strict=False), default=300,
                      help="samples of the translational response (default 300)")
    demo.add_argument("--dt-unstable", type=POSITIVE, default=0.005,
                      help="sample time of the rotational (unstable) response [s] "
                           "(default 0.005)")
    demo.add_argument("--steps-unstable", type=number(int, 2, strict=False), default=100,
                      help="samples of the rotational response (default 100)")
    demo.add_argument("--out", default="out", help="folder for the PNG (default: out)")
    demo.set_defaults(func=run_demo)


def _add_leg(sub) -> None:
    legp = sub.add_parser(
        "leg", help="the robot-leg study: train, evaluate, Table I, Fig. 3 (and Fig. 4)")
    legp.add_argument("--pretrained", action="store_true",
                      help="evaluate the shipped identifiers instead of training (seconds)")
    legp.add_argument("--seconds", type=POSITIVE, default=300.0,
                      help="training budget for both identifiers together (default 300)")
    legp.add_argument("--epochs", type=POSITIVE_INT, default=None,
                      help="train each identifier for this many epochs instead of a time "
                           "budget (reproducible on a busy machine)")
    legp.add_argument("--seed", type=number(int, 0, strict=False), default=0,
                      help="seed of the training data and the validation systems (default 0)")
    legp.add_argument("--validation", type=POSITIVE_INT, default=500,
                      help="fresh validation systems (default 500)")
    legp.add_argument("--fig4", action="store_true",
                      help="also train at several data sizes for Fig. 4 (takes longer)")
    legp.add_argument("--fig4-sizes", type=POSITIVE_INT, nargs="+",
                      default=[100, 300, 1000, 3000, 10000, 30000, 100000],
                      help="training-set sizes (records) for Fig. 4 "
                           "(default 100 300 1000 3000 10000 30000 100000)")
    legp.add_argument("--fig4-seconds", type=POSITIVE, default=30.0,
                      help="training budget per size and subsystem for Fig. 4")
    legp.add_argument("--out", default="out/leg",
                      help="parent folder: a run writes JSON, PNGs and identifiers to "
                           "OUT/trained or OUT/pretrained (default out/leg)")
    legp.add_argument("--quiet", action="store_true", help="no progress lines")
    legp.set_defaults(func=run_leg)


def _add_track(sub, names: str) -> None:
    # light (numpy only): the tracker's defaults are the CLI's
    from aeid_struct.online import DEFAULT_SMOOTHING, TrackerConfig

    trk = sub.add_parser(
        "track", help="follow a stream window by window (online identification): a measured "
                      "one (--y, --u) with any identifier of mid-motion windows, or the "
                      "wearing robot leg; prints the drift, the alarm and the update time, "
                      "writes a PNG")
    trk.add_argument("--model", default="leg-stable-window",
                     help="an identifier of mid-motion windows reading u: an .aeid file or a "
                          f"shipped name ({names}; default leg-stable-window)")
    trk.add_argument("--maps", default=None, metavar="FILE.py", help=MAPS_HELP)
    trk.add_argument("--y", nargs="+", default=None, metavar="FILE",
                     help="a measured stream to track in place of the wear scenario: one "
                          "file per output the identifier reads (columns as 'identify' "
                          "reads them, any length of at least one window)")
    trk.add_argument("--u", nargs="+", default=None, metavar="FILE",
                     help="the stream's inputs, one file per input (or a u column in the "
                          "--y file of a one-input identifier)")
    trk.add_argument("--seconds", type=POSITIVE, default=120.0, help="length of the scenario")
    trk.add_argument("--noise", type=FRACTION, default=0.01,
                     help="measurement noise, of max|y|")
    tracker = TrackerConfig()          # the tracker's own defaults, not copies of them
    (m0, s0), (m1, s1) = DEFAULT_SMOOTHING["encoder"], DEFAULT_SMOOTHING["head"]
    m2, s2 = DEFAULT_SMOOTHING["physical"]
    by_head = {"median": f"{m1} for an identifier whose separable head iterates, {m0} "
                         f"without, {m2} for a physical structure's",
               "smoothing": f"{s1} for an identifier whose separable head iterates, {s0} "
                            f"without, {s2} for a physical structure's",
               "iterations": f"{tracker.iterations!r} in the wear scenario (1 for a "
                             "canonical structure's head, the whole head for a physical "
                             "structure's); the identifier's own head for a measured stream, "
                             "whose mechanism's encoder may be a poor start"}
    for name, kind, text in (
            ("hop", int, "samples between identifications"),
            ("smoothing", float, "moving-average weight"),
            ("median", int, "window estimates in the running median before the moving average"),
            ("threshold", float, "relative drift that alarms"),
            ("baseline", int, "windows in the reference"),
            ("patience", int, "windows over the threshold"),
            ("sigmas", float, "standard errors of a window's parameters that a drift must "
                              "exceed as well (a physical structure's; 0: the threshold "
                              "alone)"),
            ("iterations", int, "at most this many iterations of the identifier's separable "
                                "head per window")):
        trk.add_argument(f"--{name}", type=kind,
                         default=None if name == "iterations" else getattr(tracker, name),
                         help=f"{text} (default {by_head.get(name, getattr(tracker, name))})")
    trk.add_argument("--watch", nargs="*", default=None,
                     help="parameters whose drift raises the alarm (default: k, the spring, "
                          "in the wear scenario; every parameter of a measured stream)")
    trk.add_argument("--seed", type=number(int, 0, strict=False), default=0,
                     help="seed of the scenario (default 0)")
    trk.add_argument("--engine", choices=("auto", "onnx", "identifier"), default="auto",
                     help="onnx: the exported encoder under onnxruntime (auto: when installed)")
    trk.add_argument("--out", default="out/track", help="folder for the PNG and JSON")
    trk.set_defaults(func=run_track)


def _order(text: str):
    """An argparse type: ``auto`` or an order 1..8 (the generic identifiers' encoders for 1-4,
    the classical start alone above)."""
    if text == "auto":
        return text
    # 8 is generic.MAX_ORDER, written here: building the parser imports no torch
    if text.strip().isdigit() and 1 <= int(text) <= 8:
        return int(text)
    raise argparse.ArgumentTypeError(f"expected an order 1-8 or auto; got {text!r}")


def _add_model_options(idp) -> None:
    """The options of ``identify MODEL`` (a trained identifier) from ``--refine`` on."""
    idp.add_argument("--refine", choices=("no", "yes", "auto"), nargs="?", const="yes",
                     default="no",
                     help="with MODEL: polish with the CasADi NLP: yes (also plain --refine), "
                          "auto (only the estimates flagged outside the training range), no "
                          "(default)")
    idp.add_argument("--starts", type=int, default=0, metavar="K",
                     help="with MODEL --refine, a physical structure: also fit from K fixed "
                          "points of the parameters' box and keep the lowest cost (a "
                          "mechanism whose cost holds several optima at noise; default 0)")
    idp.add_argument("--maps", default=None, metavar="FILE.py", help=MAPS_HELP)
    idp.add_argument("--allow-outside", action="store_true",
                     help=f"with MODEL: exit 0 even when an estimate is flagged outside the "
                          f"training range (default: exit {EXIT_OUTSIDE}); the WARNING is "
                          "printed either way")
    idp.add_argument("--json", default=None,
                     help="write the estimate as JSON (with MODEL: with fit_percent, excess, "
                          "outside and the thresholds; with --order: the model, delay, initial "
                          "state, offset, fit and time)")


def _add_identify(sub, names: str, generic: str) -> None:
    generic = generic or "none in this installation (aeid-struct train-generic trains them)"
    idp = sub.add_parser(
        "identify", help="identify a system from a record file: any system with --order "
                         "(the generic identifiers), or with a trained identifier and its "
                         "self-check (fit, excess, inside or outside its training range)",
        usage="aeid-struct identify RECORD --order {1-8,auto} [--dt DT] [options]\n"
              "       aeid-struct identify MODEL --y FILE [FILE ...] [options]",
        description="Two uses. (1) Any system, any sample time and record length: "
                    "'aeid-struct identify RECORD --order N' identifies a continuous-time model "
                    "of order N (or --order auto: the order selected by validation fit) with the "
                    f"shipped generic identifiers ({generic}) and refines it over the whole "
                    "record (output error with the initial state, an output offset and the input "
                    "delay), like aeid_struct.identify(record, order=N); it prints the model "
                    "(A, b, c, d and the transfer function), the delay, the initial state, the "
                    "offset, the fit and the time; a record of several inputs and outputs "
                    "(columns u1, u2, ..., y1, y2, ...) gives A, B, C, D with a delay per "
                    "input and an offset and fit per output. (2) With a trained identifier "
                    f"MODEL (a file, or a shipped leg identifier: {names}) and --y: print the "
                    "model, its physical parameters and the self-check: each record's fit "
                    "(NRMSE %), its excess beyond the training range, and the verdict (inside "
                    "or OUTSIDE the training range).",
        epilog=RECORD_LAYOUTS + " With --order, RECORD is one record: a CSV with named columns "
        "(t,u,y: dt from t; without t give --dt), or a (steps,) .npy or one-column CSV of y "
        "with --u for its input (default a unit step) and --dt.\n\n"
        f"Exit status: 0 done; {EXIT_INPUT} a usage or input error; {EXIT_OUTSIDE} an estimate "
        "is flagged OUTSIDE the training range (a WARNING line on stderr; the estimate is still "
        "printed and written): the record is unlike the identifier's training records, e.g. "
        "sampled at another dt, and its parameters cannot be trusted. --allow-outside accepts "
        "it (status 0, the WARNING stays).")
    idp.add_argument("model", metavar="RECORD|MODEL",
                     help="with --order: the record file (.csv or .npy, layouts below); "
                          f"otherwise an identifier file (.aeid) or a shipped name: {names}")
    idp.add_argument("--order", type=_order, default=None, metavar="{1-8,auto}",
                     help="identify RECORD with the generic identifiers: the model order 1-8 "
                          "(encoders for 1-4, the classical start alone above), or auto (each "
                          "of orders 1-8 identified on the first 70 %% of the record, the "
                          "smallest within 0.5 points of the best validation fit on the rest)")
    idp.add_argument("--dt", type=POSITIVE, default=None,
                     help="with --order: the record's sample time [s] (default: from its t "
                          "column)")
    idp.add_argument("--no-refine", action="store_true",
                     help="with --order: the generic identifier's model alone, without the "
                          "output-error refinement over the whole record")
    idp.add_argument("--delay", type=number(int, 0, strict=False), default=None, metavar="D",
                     help="with --order: the known input delay [samples] (default: estimated)")
    idp.add_argument("--max-delay", type=number(int, 0, strict=False), default=None,
                     metavar="D",
                     help="with --order: the largest input delay considered when it is "
                          "estimated [samples] (default 10)")
    idp.add_argument("--intersample", choices=("foh", "zoh"), default=None,
                     help="with --order: the input between samples: foh (linear from one "
                          "sample to the next, default) or zoh (held: an input applied through "
                          "a DAC), as MATLAB's InterSample")
    idp.add_argument("--structure", choices=("ccf", "mcf"), default=None,
                     help="with --order: ccf (controllable canonical form with feedthrough, "
                          "default) or mcf (modal form, stable by construction)")
    idp.add_argument("--stable", action="store_true",
                     help="with --order: a stable model (a plant known to be stable): the modal "
                          "form for one channel, the fit held to stable models for several; "
                          "warns where the record's best model is unstable")
    idp.add_argument("--figure", default=None,
                     help="with --order: write the measured and the model's output (MATLAB's "
                          "compare, initial state and offset fitted) as a PNG file")
    idp.add_argument("--y", default=None, nargs="+",
                     help="with MODEL: output record file(s), .npy or .csv (layouts below); one "
                          "file per record (subsystem) for a joint identifier; for an "
                          "identifier of a record's channels, one file of numbered columns "
                          "(y1, y2, .., u1, ..) or one file per channel")
    idp.add_argument("--u", default=None, nargs="+",
                     help="input record file(s), like --y; default: the u column of the --y "
                          "file (with --order: of RECORD), else a unit step")
    _add_model_options(idp)
    idp.set_defaults(func=run_identify)
