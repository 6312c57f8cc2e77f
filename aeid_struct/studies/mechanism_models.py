"""The shipped mechanism identifiers and their recipe: ``drive-train`` (motor and load angle
from the motor torque: a rigid-body mode, so integrating) and ``cart-pole`` (cart position and
pole angle from the force, linearised upright: unstable), each trained through exactly the
user's API on both outputs of one record, in the structure of a named factory
(``symbolic.mechanisms.drive_train_channels``, ``cart_pole_channels``) so that the file refers
to its map by name (data, never code).

Recipe (the README of ``aeid_struct/pretrained`` gives the commands and what they measured)::

    python -m aeid_struct.studies.mechanism_models drive-train --out drive-train.aeid
    python -m aeid_struct.studies.mechanism_models drive-train --table drive-train.aeid

the second prints the README's accuracy rows of a file (:func:`accuracy_table`).
"""

from __future__ import annotations

import argparse
import time

__all__ = ["SHIPPED", "accuracy_table", "shipped_structure", "train_shipped"]

#: name -> (the ``mechanism_bench`` case, the ``symbolic.mechanisms`` factory, its constants,
#: samples the records run before their window starts: windows cut mid-motion, or 0: records
#: from rest). The cart-pole's records start from rest: upright it is unstable, and a window cut
#: from a running (growing) record is dominated by its free response, so that even the
#: least-squares optimum of a mid-motion window misses M, m and b by tens of percent at 2 %
#: noise, where a one-second record from rest gives M, m, l to a few percent.
SHIPPED = {
    "drive-train": ("drive train, both angles", "drive_train_channels", {}, 100),
    "cart-pole": ("cart-pole, both outputs", "cart_pole_channels", {"g": 9.81}, 0),
}


def _case(name: str):
    from aeid_struct.studies.mechanism_bench import CASES

    if name not in SHIPPED:
        raise ValueError(f"name must be one of {list(SHIPPED)}; got {name!r}")
    return next(c for c in CASES if c.name == SHIPPED[name][0])


def shipped_structure(name: str):
    """The structure of a shipped mechanism identifier: its named factory's map of both
    channels, in the bench case's box.

    Parameters
    ----------
    name : {"drive-train", "cart-pole"}

    Returns
    -------
    Physical
    """
    from aeid_struct.structures import Physical
    from symbolic import mechanisms

    case = _case(name)
    factory, constants = getattr(mechanisms, SHIPPED[name][1]), SHIPPED[name][2]
    return Physical(factory(**constants), bounds=case.bounds,
                    channels=[spec[:2] for spec in case.specs])


def train_shipped(name: str, *, seconds: float = 240.0, seed: int = 0,
                  progress: bool = True, checkpoint=None):
    """Train a shipped mechanism identifier (module docstring): PRBS records (windows that
    start mid-motion, their initial state fitted, where :data:`SHIPPED` says so), 0-3 % noise,
    fresh records each epoch, within ``seconds``, with a five-iteration head.

    Parameters
    ----------
    name : {"drive-train", "cart-pole"}
    seconds : float
        The training budget.
    seed : int
    progress : bool
    checkpoint : str or Path, optional
        Where training checkpoints (a killed run resumes from it).

    Returns
    -------
    Identifier
        With its head, and the training range calibrated with that head.
    """
    from aeid_struct.training import ParameterFamily, TrainConfig, train

    case, warmup = _case(name), SHIPPED[name][3]
    structure = shipped_structure(name)
    family = ParameterFamily(structure)
    config = TrainConfig(**case.grid, epochs=100_000, seconds=seconds, count=10_000,
                         excitation="prbs", noise=(0.0, 0.03), warmup=warmup,
                         initial="fitted" if warmup else "rest", fresh=True, seed=seed,
                         progress=progress, checkpoint=checkpoint)
    return train(structure, family, config)      # with train()'s physical head


def accuracy_table(name: str, ident, *, records: int = 30, seed: int = 1) -> list[str]:
    """The README's accuracy rows of a shipped mechanism identifier: on ``records`` unseen PRBS
    records per noise level (0, 2 and 5 % of ``max|y|``, cut as the recipe cuts them), the
    median relative error (%) of each parameter for the encoder alone, the one pass and
    ``refine=True``, one batch per row.

    Parameters
    ----------
    name : {"drive-train", "cart-pole"}
    ident : Identifier
        The file's identifier.
    records : int
    seed : int
        Seeds the records (the training used ``seed`` 0's streams).

    Returns
    -------
    list of str
        Markdown table rows ``| name, noise | encoder | one pass | refined |``.
    """
    import numpy as np

    from aeid_struct.training import ParameterFamily
    from aeid_struct.training import records as simulated

    case, warmup = _case(name), SHIPPED[name][3]
    names = ident.structure.element_names
    rows = []
    for noise in (0.0, 0.02, 0.05):
        rec = simulated(ParameterFamily(ident.structure), records, **case.grid,
                        excitation_kind="prbs", seed=seed, noise=noise, warmup=warmup)
        truth = np.stack([rec.systems.params[k] for k in names], 1)
        head, ident.head = ident.head, None
        try:
            found = [ident.identify(rec.y, rec.u)]
        finally:
            ident.head = head
        found += [ident.identify(rec.y, rec.u), ident.identify(rec.y, rec.u, refine=True)]
        cells = []
        for est in found:
            err = 100 * np.median(np.abs(np.stack([est.physical[k] for k in names], 1)
                                         / truth - 1), axis=0)
            cells.append("0.000 all" if np.all(err < 5e-4) else
                         " / ".join(f"{e:.2g}" if e < 10 else f"{e:.0f}" for e in err))
        rows.append(f"| `{name}`, {100 * noise:g} % | " + " | ".join(cells) + " |")
    return rows


def main(argv=None) -> None:
    """``python -m aeid_struct.studies.mechanism_models NAME --out PATH [--seconds S]``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("name", choices=sorted(SHIPPED))
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument("--out", help="train, and write the identifier here")
    what.add_argument("--table", help="print the README's accuracy rows of this file")
    parser.add_argument("--seconds", type=float, default=240.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--checkpoint")
    args = parser.parse_args(argv)
    if args.table:
        from aeid_struct.identification import Identifier

        print("\n".join(accuracy_table(args.name, Identifier.load(args.table))))
        return
    t0 = time.perf_counter()
    ident = train_shipped(args.name, seconds=args.seconds, seed=args.seed,
                          checkpoint=args.checkpoint)
    ident.save(args.out)
    print(f"{args.name}: trained in {time.perf_counter() - t0:.0f} s, written to {args.out}")


if __name__ == "__main__":
    main()
