"""The parser of the ``aeid-struct`` command: one function per subcommand adds its options.

Building the parser and printing its help import neither torch nor CasADi (the subcommands import
what they need when they run), so ``--help`` is immediate.
"""

from __future__ import annotations

import argparse
import math
import textwrap

from aeid_struct.cli.commands import (
    run_bench,
    run_bench_generic,
    run_bench_online,
    run_leg,
    run_track,
    run_train,
)
from aeid_struct.cli.demo import run_demo
from aeid_struct.cli.errors import EXIT_INPUT, EXIT_OUTSIDE, InputError
from aeid_struct.cli.identify import generic_names, run_identify, shipped_names
from aeid_struct.cli.records_io import RECORD_LAYOUTS
from aeid_struct.cli.train_generic import run_train_generic

#: The training excitations, for --help only (TrainConfig checks the name; a test keeps this
#: equal to training.EXCITATIONS, which the parser cannot import without torch).
_EXCITATIONS = ("step", "ramp", "prbs", "multisine", "noise", "steps", "mix")


class _Formatter(argparse.HelpFormatter):
    """argparse's help layout, keeping blank-line paragraphs and names such as leg-stable-any
    whole (textwrap would break them at the hyphens)."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n\n".join(textwrap.fill(" ".join(p.split()), width, initial_indent=indent,
                                          subsequent_indent=indent, break_on_hyphens=False)
                            for p in text.split("\n\n"))


class _Parser(argparse.ArgumentParser):
    """argparse, with its errors as one line (no usage block) through ``main``."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _Formatter)   # subcommands inherit the class
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        where = self.prog.removeprefix("aeid-struct").strip()
        raise InputError(f"{where + ': ' if where else ''}{message} "
                         f"(see '{self.prog} --help')")


def _number(kind: type, low: float | None = None, *, strict: bool = True):
    """An argparse type: a finite ``kind`` (int or float), above ``low`` (or at least it)."""
    what = "an integer" if kind is int else "a finite number"
    if low is not None:
        what += f" {'>' if strict else '>='} {low:g}"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}") from None
        if not math.isfinite(value) or (low is not None
                                        and (value <= low if strict else value < low)):
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}")
        return value

    return parse


_POSITIVE = _number(float, 0)
_POSITIVE_INT = _number(int, 0)
_FRACTION = _number(float, 0, strict=False)


def build_parser() -> argparse.ArgumentParser:
    """The command's parser, with every option's help text (a test checks).

    Building it and printing its help import neither torch nor CasADi.

    Returns
    -------
    argparse.ArgumentParser
        Its errors raise ``InputError`` (``main`` prints them as one line).
    """
    names = ", ".join(shipped_names())
    parser = _Parser(
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
    _add_train(sub)
    _add_train_generic(sub)
    _add_track(sub, names)
    _add_identify(sub, names, ", ".join(generic_names()))
    _add_bench(sub)
    _add_bench_online(sub)
    _add_bench_generic(sub)
    return parser


def _add_demo(sub) -> None:
    demo = sub.add_parser(
        "demo",
        help="derive the robot-leg model, simulate both subsystems, write a step-response PNG",
        description="Derive the robot-leg model with CasADi (paper Eq. 16), print both "
                    "subsystems in controllable canonical form, and write their unit-step "
                    "responses (exact FOH simulation) to OUT/leg_step_responses.png.")
    demo.add_argument("--k", type=_POSITIVE, default=24.23, help="spring stiffness [N/m]")
    demo.add_argument("--d", type=_POSITIVE, default=2.24, help="damping [kg/s]")
    demo.add_argument("--m", type=_POSITIVE, default=1.01, help="mass [kg]")
    demo.add_argument("--dt-stable", type=_POSITIVE, default=0.01,
                      help="sample time of the translational (stable) response [s] "
                           "(default 0.01)")
    demo.add_argument("--steps-stable", type=_number(int, 2, strict=False), default=300,
                      help="samples of the translational response (default 300)")
    demo.add_argument("--dt-unstable", type=_POSITIVE, default=0.005,
                      help="sample time of the rotational (unstable) response [s] "
                           "(default 0.005)")
    demo.add_argument("--steps-unstable", type=_number(int, 2, strict=False), default=100,
                      help="samples of the rotational response (default 100)")
    demo.add_argument("--out", default="out", help="folder for the PNG (default: out)")
    demo.set_defaults(func=run_demo)


def _add_leg(sub) -> None:
    legp = sub.add_parser(
        "leg", help="the robot-leg study: train, evaluate, Table I, Fig. 3 (and Fig. 4)")
    legp.add_argument("--pretrained", action="store_true",
                      help="evaluate the shipped identifiers instead of training (seconds)")
    legp.add_argument("--seconds", type=_POSITIVE, default=300.0,
                      help="training budget for both identifiers together (default 300)")
    legp.add_argument("--epochs", type=_POSITIVE_INT, default=None,
                      help="train each identifier for this many epochs instead of a time "
                           "budget (reproducible on a busy machine)")
    legp.add_argument("--seed", type=_number(int, 0, strict=False), default=0,
                      help="seed of the training data and the validation systems (default 0)")
    legp.add_argument("--validation", type=_POSITIVE_INT, default=500,
                      help="fresh validation systems (default 500)")
    legp.add_argument("--fig4", action="store_true",
                      help="also train at several data sizes for Fig. 4 (takes longer)")
    legp.add_argument("--fig4-sizes", type=_POSITIVE_INT, nargs="+",
                      default=[100, 300, 1000, 3000, 10000, 30000, 100000],
                      help="training-set sizes (records) for Fig. 4 "
                           "(default 100 300 1000 3000 10000 30000 100000)")
    legp.add_argument("--fig4-seconds", type=_POSITIVE, default=30.0,
                      help="training budget per size and subsystem for Fig. 4")
    legp.add_argument("--out", default="out/leg",
                      help="parent folder: a run writes JSON, PNGs and identifiers to "
                           "OUT/trained or OUT/pretrained (default out/leg)")
    legp.add_argument("--quiet", action="store_true", help="no progress lines")
    legp.set_defaults(func=run_leg)


def _add_train(sub) -> None:
    tr = sub.add_parser("train", help="train an identifier for a structure and a family",
                        description="Train an identifier (encoder + structure) on simulated "
                                    "records of a system family and write it as an .aeid file. "
                                    "TrainConfig checks the values and names any it refuses.")
    tr.add_argument("--structure", required=True,
                    help="the model structure: ccf:N[:descartes][:feedthrough][:NAME=VALUE...] "
                         "(controllable canonical form of order N; NAME=VALUE fixes an element, "
                         "e.g. ccf:2:a1=0:c1=0), mcf:REAL,PAIRS (modal form), leg-stable or "
                         "leg-unstable (the leg's physical k, d, m)")
    tr.add_argument("--family", required=True,
                    help="the systems to train on: leg-stable, leg-unstable, or poles:REAL,PAIRS "
                         "(random stable poles: REAL real ones and PAIRS complex pairs)")
    tr.add_argument("--dt", type=float, required=True,
                    help="sample time of the records [s]")
    tr.add_argument("--steps", type=int, required=True, help="samples per record")
    tr.add_argument("--count", type=int, default=10_000,
                    help="simulated training records, a share held out (default 10000)")
    tr.add_argument("--epochs", type=int, default=200,
                    help="epochs to train (default 200; --seconds stops earlier)")
    tr.add_argument("--seconds", type=_POSITIVE, default=None,
                    help="wall-clock training budget [s] (default: none, --epochs decides)")
    tr.add_argument("--batch", type=int, default=128, help="records per gradient step "
                                                           "(default 128)")
    tr.add_argument("--lr", type=_POSITIVE, default=3e-3, help="Adam learning rate (default 3e-3)")
    tr.add_argument("--gamma", type=_number(float, 0, strict=False), default=None,
                    help="weight of Eq. 14's stationary-value term (default: 1 for steps, else 0)")
    tr.add_argument("--noise", type=float, nargs="+", default=[0.0],
                    help="a level, or LO HI drawn per record (std relative to max|y|)")
    tr.add_argument("--excitation", default="step",
                    help="input of the training records: " + ", ".join(_EXCITATIONS)
                         + " (default step)")
    tr.add_argument("--width", type=int, default=12,
                    help="channels of the encoder's convolutions (default 12)")
    tr.add_argument("--kernel", type=int, default=5,
                    help="kernel size of the encoder's convolutions (default 5)")
    tr.add_argument("--dense", type=int, nargs="+", default=[48, 48],
                    help="widths of the encoder's dense layers (default 48 48)")
    tr.add_argument("--pool", type=int, default=1,
                    help="average-pooling factor of the record before the encoder (default 1)")
    tr.add_argument("--seed", type=_number(int, 0, strict=False), default=0,
                    help="seed of the records, the initial weights and the batches (default 0)")
    tr.add_argument("--checkpoint", default=None, help="checkpoint file to resume from")
    tr.add_argument("--device", choices=("cpu", "cuda", "auto"), default="cpu",
                    help="where the encoder and decoder run: cpu (default), cuda, or auto (a GPU "
                         "when torch finds one). Launched by torchrun, the run is data-parallel "
                         "(--batch is the global batch) and rank 0 writes --out")
    tr.add_argument("--out", required=True, help="identifier file to write (.aeid)")
    tr.add_argument("--quiet", action="store_true", help="no progress lines")
    tr.set_defaults(func=run_train)


def _add_train_generic(sub) -> None:
    tg = sub.add_parser(
        "train-generic", help="train a generic identifier of one order (any system, any dt)",
        description="Train a generic identifier of order N on fresh records of the generic "
                    "family in normalised time (dt = 1) by variable projection, and write it as "
                    "an .aeid file with a JSON file of the run. It checkpoints to OUT.ckpt every "
                    "epoch.")
    tg.add_argument("--order", type=_number(int, 0), required=True,
                    help="the model order N, 1..4")
    tg.add_argument("--minutes", type=_POSITIVE, default=None,
                    help="wall-clock training budget [min] (default: none, --epochs decides)")
    tg.add_argument("--epochs", type=_POSITIVE_INT, default=100,
                    help="at most this many epochs (default 100)")
    tg.add_argument("--count", type=_POSITIVE_INT, default=4096,
                    help="fresh training windows per epoch (default 4096)")
    tg.add_argument("--holdout", type=_POSITIVE_INT, default=512,
                    help="held-out windows that pick the best weights (default 512)")
    tg.add_argument("--window", type=_POSITIVE_INT, default=256,
                    help="samples per window the encoder reads (default 256)")
    tg.add_argument("--batch", type=_POSITIVE_INT, default=128,
                    help="windows per gradient step (default 128)")
    tg.add_argument("--lr", type=_POSITIVE, default=3e-3,
                    help="peak Adam learning rate (default 3e-3)")
    tg.add_argument("--loss", default="log",
                    help="per-window loss: log (log of 1 - R^2, default) or nmse (1 - R^2)")
    tg.add_argument("--seed", type=_number(int, 0, strict=False), default=0,
                    help="seed of the weights and the records (default 0)")
    tg.add_argument("--threads", type=_POSITIVE_INT, default=None,
                    help="torch threads for the run (default: torch's setting)")
    tg.add_argument("--device", choices=("cpu", "cuda", "auto"), default="cpu",
                    help="where the encoder and the projection run: cpu (default), cuda, or auto "
                         "(a GPU when torch finds one). Launched by torchrun, the run is "
                         "data-parallel (--batch is the global batch) and rank 0 writes --out")
    tg.add_argument("--out", default=None,
                    help="identifier file to write (default generic-N.aeid); the run's JSON "
                         "goes next to it (.json)")
    tg.add_argument("--resume", action="store_true",
                    help="continue the run checkpointed in OUT.ckpt")
    tg.add_argument("--quiet", action="store_true", help="no progress lines")
    tg.set_defaults(func=run_train_generic)


def _add_track(sub, names: str) -> None:
    # light (numpy only): the tracker's defaults are the CLI's
    from aeid_struct.online import DEFAULT_SMOOTHING, TrackerConfig

    trk = sub.add_parser(
        "track", help="follow a wearing robot leg window by window (online identification): "
                      "prints tracking error, alarm delay, update time; writes a PNG")
    trk.add_argument("--model", default="leg-stable-window",
                     help="an identifier of mid-motion windows reading u: an .aeid file or a "
                          f"shipped name ({names}; default leg-stable-window)")
    trk.add_argument("--seconds", type=_POSITIVE, default=120.0, help="length of the scenario")
    trk.add_argument("--noise", type=_FRACTION, default=0.01,
                     help="measurement noise, of max|y|")
    tracker = TrackerConfig()          # the tracker's own defaults, not copies of them
    (m0, s0), (m1, s1) = DEFAULT_SMOOTHING["encoder"], DEFAULT_SMOOTHING["head"]
    by_head = {"median": f"{m1} for an identifier whose separable head iterates, {m0} "
                         "without", "smoothing": f"{s1} for an identifier whose separable head "
                                                 f"iterates, {s0} without"}
    for name, kind, text in (
            ("hop", int, "samples between identifications"),
            ("smoothing", float, "moving-average weight"),
            ("median", int, "window estimates in the running median before the moving average"),
            ("threshold", float, "relative drift that alarms"),
            ("baseline", int, "windows in the reference"),
            ("patience", int, "windows over the threshold"),
            ("iterations", int, "at most this many iterations of the identifier's separable "
                                "head per window")):
        trk.add_argument(f"--{name}", type=kind, default=getattr(tracker, name),
                         help=f"{text} (default {by_head.get(name, getattr(tracker, name))})")
    trk.add_argument("--watch", nargs="*", default=["k"],
                     help="parameters whose drift raises the alarm (default: k, the spring)")
    trk.add_argument("--seed", type=_number(int, 0, strict=False), default=0,
                     help="seed of the scenario (default 0)")
    trk.add_argument("--engine", choices=("auto", "onnx", "identifier"), default="auto",
                     help="onnx: the exported encoder under onnxruntime (auto: when installed)")
    trk.add_argument("--out", default="out/track", help="folder for the PNG and JSON")
    trk.set_defaults(func=run_track)


def _order(text: str):
    """An argparse type: ``auto`` or an order 1..4 (the generic identifiers' orders)."""
    if text == "auto":
        return text
    if text.strip().isdigit() and 1 <= int(text) <= 4:
        return int(text)
    raise argparse.ArgumentTypeError(f"expected an order 1, 2, 3, 4 or auto; got {text!r}")


def _add_identify(sub, names: str, generic: str) -> None:
    generic = generic or "none in this installation (aeid-struct train-generic trains them)"
    idp = sub.add_parser(
        "identify", help="identify a system from a record file: any SISO system with --order "
                         "(the generic identifiers), or with a trained identifier and its "
                         "self-check (fit, excess, inside or outside its training range)",
        usage="aeid-struct identify RECORD --order {1,2,3,4,auto} [--dt DT] [options]\n"
              "       aeid-struct identify MODEL --y FILE [FILE ...] [options]",
        description="Two uses. (1) Any SISO system, any sample time and record length: "
                    "'aeid-struct identify RECORD --order N' identifies a continuous-time model "
                    "of order N (or --order auto: the order selected by validation fit) with the "
                    f"shipped generic identifiers ({generic}) and refines it over the whole "
                    "record (output error with the initial state, an output offset and the input "
                    "delay), like aeid_struct.identify(record, order=N); it prints the model "
                    "(A, b, c, d and the transfer function), the delay, the initial state, the "
                    "offset, the fit and the time. (2) With a trained identifier MODEL (a file, "
                    f"or a shipped leg identifier: {names}) and --y: print the model, its "
                    "physical parameters and the self-check: each record's fit (NRMSE %), its "
                    "excess beyond the training range, and the verdict (inside or OUTSIDE the "
                    "training range).",
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
    idp.add_argument("--order", type=_order, default=None, metavar="{1,2,3,4,auto}",
                     help="identify RECORD with the generic identifiers: the model order 1-4, "
                          "or auto (each order identified on the first 70 %% of the record, the "
                          "smallest within 0.5 points of the best validation fit on the rest)")
    idp.add_argument("--dt", type=_POSITIVE, default=None,
                     help="with --order: the record's sample time [s] (default: from its t "
                          "column)")
    idp.add_argument("--no-refine", action="store_true",
                     help="with --order: the generic identifier's model alone, without the "
                          "output-error refinement over the whole record")
    idp.add_argument("--delay", type=_number(int, 0, strict=False), default=None, metavar="D",
                     help="with --order: the known input delay [samples] (default: estimated)")
    idp.add_argument("--max-delay", type=_number(int, 0, strict=False), default=None,
                     metavar="D",
                     help="with --order: the largest input delay considered when it is "
                          "estimated [samples] (default 10)")
    idp.add_argument("--structure", choices=("ccf", "mcf"), default=None,
                     help="with --order: ccf (controllable canonical form with feedthrough, "
                          "default) or mcf (modal form, stable by construction)")
    idp.add_argument("--figure", default=None,
                     help="with --order: write the measured and the model's output (MATLAB's "
                          "compare, initial state and offset fitted) as a PNG file")
    idp.add_argument("--y", default=None, nargs="+",
                     help="with MODEL: output record file(s), .npy or .csv (layouts below); one "
                          "file per record (subsystem) for a joint identifier")
    idp.add_argument("--u", default=None, nargs="+",
                     help="input record file(s), like --y; default: the u column of the --y "
                          "file (with --order: of RECORD), else a unit step")
    idp.add_argument("--refine", choices=("no", "yes", "auto"), nargs="?", const="yes",
                     default="no",
                     help="with MODEL: polish with the CasADi NLP: yes (also plain --refine), "
                          "auto (only the estimates flagged outside the training range), no "
                          "(default)")
    idp.add_argument("--allow-outside", action="store_true",
                     help=f"with MODEL: exit 0 even when an estimate is flagged outside the "
                          f"training range (default: exit {EXIT_OUTSIDE}); the WARNING is "
                          "printed either way")
    idp.add_argument("--json", default=None,
                     help="write the estimate as JSON (with MODEL: with fit_percent, excess, "
                          "outside and the thresholds; with --order: the model, delay, initial "
                          "state, offset, fit and time)")
    idp.set_defaults(func=run_identify)


def _add_bench(sub) -> None:
    bench = sub.add_parser(
        "bench", help="accuracy and speed of the encoder, the one pass, refinement and classical "
                      "baselines, and decoder timings, measured side by side; prints and writes "
                      "JSON")
    bench.add_argument("--quick", action="store_true",
                       help="20 systems, 8 records per one-pass row, short decoder table")
    bench.add_argument("--count", type=_POSITIVE_INT, default=None,
                       help="systems per subsystem and noise level (default 500)")
    bench.add_argument("--noise", type=_FRACTION, nargs="+", default=None,
                       help="noise levels, std relative to max|y| (default 0 0.01 0.05; the "
                            "one-pass study with --quick: 0 0.01)")
    bench.add_argument("--decoder-only", action="store_true", help="only the decoder timings")
    bench.add_argument("--onepass-only", action="store_true",
                       help="only the one-pass study (encoder alone, one pass, refined, cold "
                            "least squares, cold CasADi, n4sid under four inputs)")
    bench.add_argument("--records", type=_POSITIVE_INT, default=None,
                       help="records per one-pass row (default 60; --quick 8)")
    bench.add_argument("--timed", type=_POSITIVE_INT, default=None,
                       help="records per one-pass row timed at batch 1 and fitted by the cold "
                            "baselines (default 30; --quick 4)")
    bench.add_argument("--identifiers", nargs="+", default=None,
                       choices=["leg-stable-any", "leg-unstable-any", "leg-stable-window"],
                       help="identifiers of the one-pass study (default all three)")
    bench.add_argument("--kinds", nargs="+", default=None,
                       choices=["steps", "prbs", "multisine", "noise"],
                       help="input kinds of the one-pass study (default all four)")
    bench.add_argument("--batch", type=_POSITIVE_INT, default=256,
                       help="records per decoder call in the decoder timings (default 256)")
    bench.add_argument("--steps", type=_POSITIVE_INT, nargs="+", default=[100, 300, 1000],
                       help="record lengths of the decoder timings (default 100 300 1000)")
    bench.add_argument("--threads", type=_POSITIVE_INT, default=1,
                       help="torch threads for the decoder timings (default 1: steady on a "
                            "busy box)")
    bench.add_argument("--json", default="out/bench.json",
                       help="JSON file to write (default out/bench.json)")
    bench.add_argument("--quiet", action="store_true", help="no progress lines")
    bench.set_defaults(func=run_bench)


def _add_bench_online(sub) -> None:
    bon = sub.add_parser(
        "bench-online", help="online identification: tracker error, alarm delay and update "
                             "time, export latency, arbitrary inputs, out-of-range flags")
    bon.add_argument("--quick", action="store_true",
                     help="a 30 s scenario, one seed, 20 records per row (for tests)")
    bon.add_argument("--seconds", type=_POSITIVE, default=120.0, help="wear scenario length")
    bon.add_argument("--noise", type=_FRACTION, default=0.01, help="tracker measurement noise")
    bon.add_argument("--json", default="out/bench_online.json",
                     help="JSON file to write (default out/bench_online.json)")
    bon.add_argument("--quiet", action="store_true", help="no progress lines")
    bon.set_defaults(func=run_bench_online)


def _add_bench_generic(sub) -> None:
    gen = sub.add_parser(
        "bench-generic", help="the generic identifiers on unseen systems: encoder alone, one "
                              "pass, refined, n4sid, least squares and the true model, fits and "
                              "times",
        description="Identify unseen simulated systems of orders 1-4 (random dt, delay, offsets, "
                    "mid-motion start, noise) with the shipped generic identifiers and the "
                    "classical baselines, all on the same records; print the validation fits "
                    "(median per order, noise and record length), the one pass's gap to the "
                    "refined model, the worst gap to n4sid, two stand-ins for measured data "
                    "sets and the time per call; write JSON.")
    gen.add_argument("--quick", action="store_true",
                     help="3 records per cell, record lengths 400 and 1000 (default: 10, and "
                          "400, 1000, 5000)")
    gen.add_argument("--count", type=_POSITIVE_INT, default=None, help="records per cell")
    gen.add_argument("--orders", type=_POSITIVE_INT, nargs="+", default=[1, 2, 3, 4],
                     choices=[1, 2, 3, 4], help="model orders (default 1 2 3 4)")
    gen.add_argument("--noise", type=_FRACTION, nargs="+", default=[0.01, 0.05],
                     help="noise std / output std (default 0.01 0.05)")
    gen.add_argument("--lengths", type=_POSITIVE_INT, nargs="+", default=None,
                     help="estimation record lengths in samples (each >= 256, the window)")
    gen.add_argument("--seed", type=_number(int, 0, strict=False), default=20_261_123,
                     help="seed of the systems and records (default 20261123)")
    gen.add_argument("--json", default="out/bench_generic.json",
                     help="JSON file to write (default out/bench_generic.json)")
    gen.add_argument("--quiet", action="store_true", help="no progress lines")
    gen.set_defaults(func=run_bench_generic)

