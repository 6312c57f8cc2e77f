"""The options of the benchmark subcommands, ``aeid-struct bench``, ``bench-online``,
``bench-generic`` and ``bench-mechanism``: one function per subcommand adds its parser.

The seam: the benchmarks measure the library rather than use it (``studies.bench``,
``studies.onepass_bench``, ``studies.bench_online``, ``studies.generic_bench``), and their
options are the studies' sizes and switches; ``parser`` builds the whole command from them.
Adding the options imports neither torch nor CasADi.
"""

from __future__ import annotations

from aeid_struct.cli.arguments import FRACTION, POSITIVE, POSITIVE_INT, number
from aeid_struct.cli.benchmarks import (
    run_bench,
    run_bench_generic,
    run_bench_mechanism,
    run_bench_online,
)


def add_bench(sub) -> None:
    """Add the ``bench`` subcommand and its options to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subcommands of the ``aeid-struct`` parser (``parser.build_parser``).
    """
    bench = sub.add_parser(
        "bench", help="accuracy and speed of the encoder, the one pass, refinement and classical "
                      "baselines, and decoder timings, measured side by side; prints and writes "
                      "JSON")
    bench.add_argument("--quick", action="store_true",
                       help="20 systems, 8 records per one-pass row, short decoder table")
    bench.add_argument("--count", type=POSITIVE_INT, default=None,
                       help="systems per subsystem and noise level (default 500)")
    bench.add_argument("--noise", type=FRACTION, nargs="+", default=None,
                       help="noise levels, std relative to max|y| (default 0 0.01 0.05; the "
                            "one-pass study with --quick: 0 0.01)")
    bench.add_argument("--decoder-only", action="store_true", help="only the decoder timings")
    bench.add_argument("--onepass-only", action="store_true",
                       help="only the one-pass study (encoder alone, one pass, refined, cold "
                            "least squares, cold CasADi, n4sid under four inputs)")
    bench.add_argument("--records", type=POSITIVE_INT, default=None,
                       help="records per one-pass row (default 60; --quick 8)")
    bench.add_argument("--timed", type=POSITIVE_INT, default=None,
                       help="records per one-pass row timed at batch 1 and fitted by the cold "
                            "baselines (default 30; --quick 4)")
    bench.add_argument("--identifiers", nargs="+", default=None,
                       choices=["leg-stable-any", "leg-unstable-any", "leg-stable-window"],
                       help="identifiers of the one-pass study (default all three)")
    bench.add_argument("--kinds", nargs="+", default=None,
                       choices=["steps", "prbs", "multisine", "noise"],
                       help="input kinds of the one-pass study (default all four)")
    bench.add_argument("--batch", type=POSITIVE_INT, default=256,
                       help="records per decoder call in the decoder timings (default 256)")
    bench.add_argument("--steps", type=POSITIVE_INT, nargs="+", default=[100, 300, 1000],
                       help="record lengths of the decoder timings (default 100 300 1000)")
    bench.add_argument("--threads", type=POSITIVE_INT, default=1,
                       help="torch threads for the decoder timings (default 1: steady on a "
                            "busy box)")
    bench.add_argument("--json", default="out/bench.json",
                       help="JSON file to write (default out/bench.json)")
    bench.add_argument("--quiet", action="store_true", help="no progress lines")
    bench.set_defaults(func=run_bench)


def add_bench_online(sub) -> None:
    """Add the ``bench-online`` subcommand and its options to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subcommands of the ``aeid-struct`` parser (``parser.build_parser``).
    """
    bon = sub.add_parser(
        "bench-online", help="online identification: tracker error, alarm delay and update "
                             "time, export latency, arbitrary inputs, out-of-range flags")
    bon.add_argument("--quick", action="store_true",
                     help="a 30 s scenario, one seed, 20 records per row (for tests)")
    bon.add_argument("--seconds", type=POSITIVE, default=120.0, help="wear scenario length")
    bon.add_argument("--noise", type=FRACTION, default=0.01, help="tracker measurement noise")
    bon.add_argument("--json", default="out/bench_online.json",
                     help="JSON file to write (default out/bench_online.json)")
    bon.add_argument("--quiet", action="store_true", help="no progress lines")
    bon.set_defaults(func=run_bench_online)


def add_bench_generic(sub) -> None:
    """Add the ``bench-generic`` subcommand and its options to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subcommands of the ``aeid-struct`` parser (``parser.build_parser``).
    """
    gen = sub.add_parser(
        "bench-generic", help="the generic identifiers on unseen systems: encoder alone, one "
                              "pass, refined, n4sid, least squares and the true model, fits and "
                              "times",
        description="Identify unseen simulated systems of orders 1-4 by default, up to 8 with "
                    "--orders (random dt, delay, offsets, "
                    "mid-motion start, noise) with the shipped generic identifiers and the "
                    "classical baselines, all on the same records; print the validation fits "
                    "(median per order, noise and record length), the one pass's gap to the "
                    "refined model, the worst gap to n4sid, two stand-ins for measured data "
                    "sets and the time per call; write JSON.")
    gen.add_argument("--quick", action="store_true",
                     help="3 records per cell, record lengths 400 and 1000 (default: 10, and "
                          "400, 1000, 5000)")
    gen.add_argument("--count", type=POSITIVE_INT, default=None, help="records per cell")
    gen.add_argument("--orders", type=POSITIVE_INT, nargs="+", default=[1, 2, 3, 4],
                     choices=range(1, 9), metavar="N",      # generic.MAX_ORDER (no torch here)
                     help="model orders 1-8 (default 1 2 3 4; above 4 the classical start "
                          "alone, no encoder)")
    gen.add_argument("--noise", type=FRACTION, nargs="+", default=[0.01, 0.05],
                     help="noise std / output std (default 0.01 0.05)")
    gen.add_argument("--lengths", type=POSITIVE_INT, nargs="+", default=None,
                     help="estimation record lengths in samples (each at least twice the "
                          "highest order's parameters after a 5-sample delay: 33 for order 4)")
    gen.add_argument("--seed", type=number(int, 0, strict=False), default=20_261_123,
                     help="seed of the systems and records (default 20261123)")
    gen.add_argument("--plants", nargs="+", default=["stable"],
                     choices=("stable", "integrating", "unstable"),   # generic_bench.PLANTS
                     help="kinds of plant, each its own cells (default stable; integrating: a "
                          "pole at 0; unstable: one in the right half plane, growing e^0.5 to "
                          "e^4 over the run)")
    gen.add_argument("--json", default="out/bench_generic.json",
                     help="JSON file to write (default out/bench_generic.json)")
    gen.add_argument("--channels", action="store_true",
                     help="the rows of several inputs and outputs, several experiments, "
                          "integrating and unstable plants instead (studies.channels_bench; "
                          "--count records per row, default 20, 5 with --quick; JSON to "
                          "out/bench_channels.json unless --json is given)")
    gen.add_argument("--quiet", action="store_true", help="no progress lines")
    gen.set_defaults(func=run_bench_generic)


def add_bench_mechanism(sub) -> None:
    """Add the ``bench-mechanism`` subcommand and its options to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subcommands of the ``aeid-struct`` parser (``parser.build_parser``).
    """
    mech = sub.add_parser(
        "bench-mechanism", help="mechanisms from their Lagrangians: identifiability, trained "
                                "physical identifiers, one pass and refinement against a cold "
                                "grey-box fit and n4sid",
        description="For mechanisms written as Lagrangians (symbolic.mechanisms): print the "
                    "identifiability report of the measured channel, train an identifier of "
                    "the physical parameters through Physical(mechanism) and ParameterFamily, "
                    "and measure its parameters' errors (encoder, one pass, refined, a 4-start "
                    "cold grey-box fit, n4sid) and batch-1 times on unseen PRBS records; write "
                    "JSON.")
    mech.add_argument("--quick", action="store_true",
                      help="20 s of training, 8 records per level (default 120 s, 40)")
    mech.add_argument("--seconds", type=POSITIVE, default=None,
                      help="training budget per identifier in seconds")
    mech.add_argument("--records", type=POSITIVE_INT, default=None,
                      help="test records per noise level")
    mech.add_argument("--noise", type=FRACTION, nargs="+", default=[0.0, 0.02, 0.05],
                      help="noise std / max|y| of the test records (default 0 0.02 0.05)")
    mech.add_argument("--cases", nargs="+", default=None,
                      help="mechanisms by name, as the report prints them (default all: 'lever "
                           "(r known)', 'leg, translation', 'two-mass', 'leg, rotation', "
                           "'cart-pole, both outputs', 'drive train, both angles', 'leg, both "
                           "subsystems', 'quarter car', 'coupled masses, one experiment per "
                           "force', 'coupled masses, both forces at once', 'lever (r "
                           "unknown)')")
    mech.add_argument("--json", default="out/bench_mechanism.json",
                      help="JSON file to write (default out/bench_mechanism.json)")
    mech.add_argument("--quiet", action="store_true", help="no progress lines")
    mech.set_defaults(func=run_bench_mechanism)

