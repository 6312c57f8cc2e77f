"""The options of the training subcommands, ``aeid-struct train`` and ``aeid-struct
train-generic``: one function per subcommand adds its parser.

The seam: training is the one job with a recipe (structure, family, excitation, encoder,
optimiser), so these two subcommands carry most of the command's options; ``parser`` builds the
whole command from them. Adding the options imports neither torch nor CasADi.
"""

from __future__ import annotations

from aeid_struct.cli.arguments import FRACTION, POSITIVE, POSITIVE_INT, number
from aeid_struct.cli.train import run_train
from aeid_struct.cli.train_generic import run_train_generic

#: The training excitations, for --help only (TrainConfig checks the name; a test keeps this
#: equal to training.EXCITATIONS, which the parser cannot import without torch).
_EXCITATIONS = ("step", "ramp", "prbs", "multisine", "noise", "steps", "mix")


def add_train(sub) -> None:
    """Add the ``train`` subcommand and its options to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subcommands of the ``aeid-struct`` parser (``parser.build_parser``).
    """
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
    tr.add_argument("--seconds", type=POSITIVE, default=None,
                    help="wall-clock training budget [s] (default: none, --epochs decides)")
    tr.add_argument("--batch", type=int, default=128, help="records per gradient step "
                                                           "(default 128)")
    tr.add_argument("--lr", type=POSITIVE, default=3e-3, help="Adam learning rate (default 3e-3)")
    tr.add_argument("--gamma", type=number(float, 0, strict=False), default=None,
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
    tr.add_argument("--seed", type=number(int, 0, strict=False), default=0,
                    help="seed of the records, the initial weights and the batches (default 0)")
    tr.add_argument("--checkpoint", default=None, help="checkpoint file to resume from")
    tr.add_argument("--device", choices=("cpu", "cuda", "auto"), default="cpu",
                    help="where the encoder and decoder run: cpu (default), cuda, or auto (a GPU "
                         "when torch finds one). Launched by torchrun, the run is data-parallel "
                         "(--batch is the global batch) and rank 0 writes --out")
    tr.add_argument("--out", required=True, help="identifier file to write (.aeid)")
    tr.add_argument("--quiet", action="store_true", help="no progress lines")
    tr.set_defaults(func=run_train)


def add_train_generic(sub) -> None:
    """Add the ``train-generic`` subcommand and its options to ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The subcommands of the ``aeid-struct`` parser (``parser.build_parser``).
    """
    tg = sub.add_parser(
        "train-generic", help="train a generic identifier of one order (any system, any dt)",
        description="Train a generic identifier of order N on fresh records of the generic "
                    "family in normalised time (dt = 1) by variable projection, and write it as "
                    "an .aeid file with a JSON file of the run. It checkpoints to OUT.ckpt every "
                    "epoch.")
    tg.add_argument("--order", type=number(int, 0), required=True,
                    help="the model order N, 1..4")
    tg.add_argument("--minutes", type=POSITIVE, default=None,
                    help="wall-clock training budget [min] (default: none, --epochs decides)")
    tg.add_argument("--epochs", type=POSITIVE_INT, default=100,
                    help="at most this many epochs (default 100)")
    tg.add_argument("--count", type=POSITIVE_INT, default=4096,
                    help="fresh training windows per epoch (default 4096)")
    tg.add_argument("--holdout", type=POSITIVE_INT, default=512,
                    help="held-out windows that pick the best weights (default 512)")
    tg.add_argument("--window", type=POSITIVE_INT, default=256,
                    help="samples per window the encoder reads (default 256)")
    tg.add_argument("--batch", type=POSITIVE_INT, default=128,
                    help="windows per gradient step (default 128)")
    tg.add_argument("--lr", type=POSITIVE, default=3e-3,
                    help="peak Adam learning rate (default 3e-3)")
    tg.add_argument("--loss", default="log",
                    help="per-window loss: log (log of 1 - R^2, default) or nmse (1 - R^2)")
    tg.add_argument("--seed", type=number(int, 0, strict=False), default=0,
                    help="seed of the weights and the records (default 0)")
    tg.add_argument("--threads", type=POSITIVE_INT, default=None,
                    help="torch threads for the run (default: torch's setting)")
    tg.add_argument("--device", choices=("cpu", "cuda", "auto"), default="cpu",
                    help="where the encoder and the projection run: cpu (default), cuda, or auto "
                         "(a GPU when torch finds one). Launched by torchrun, the run is "
                         "data-parallel (--batch is the global batch) and rank 0 writes --out")
    tg.add_argument("--workers", type=POSITIVE_INT, default=1,
                    help="processes that simulate the fresh windows, the next epoch's while one "
                         "trains (default 1: the training process; the result does not depend "
                         "on it)")
    tg.add_argument("--width", type=POSITIVE_INT, default=None,
                    help="channels of the encoder's convolutions (default 12)")
    tg.add_argument("--depth", type=POSITIVE_INT, default=None,
                    help="residual blocks of the encoder (default 3)")
    tg.add_argument("--dense", type=POSITIVE_INT, nargs="+", default=None,
                    help="widths of the encoder's hidden dense layers (default 64 64)")
    tg.add_argument("--init", default=None, metavar="NAME_OR_FILE",
                    help="start from this generic identifier's weights (a shipped name such as "
                         "generic-2, or an .aeid file of the same order and shape): fine-tuning")
    tg.add_argument("--integrating", type=FRACTION, default=0.0,
                    help="share of the family's plants with a pole at 0 (default 0)")
    tg.add_argument("--unstable", type=FRACTION, default=0.0,
                    help="share of the family's plants with a pole in the right half plane, "
                         "growing e^0.5 to e^3 over a window (default 0)")
    tg.add_argument("--growth-weights", action="store_true",
                    help="read each training window as identification does: unweighted or "
                         "under a growth weight that leaves its shifted system stable "
                         "(training.GrowthFamily)")
    tg.add_argument("--out", default=None,
                    help="identifier file to write (default generic-N.aeid); the run's JSON "
                         "goes next to it (.json)")
    tg.add_argument("--resume", action="store_true",
                    help="continue the run checkpointed in OUT.ckpt")
    tg.add_argument("--quiet", action="store_true", help="no progress lines")
    tg.set_defaults(func=run_train_generic)
