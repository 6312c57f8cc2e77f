"""``aeid-struct train``: train an identifier for a structure and a system family, and write it
as an ``.aeid`` file.

The seam: the subcommand and the two specs it reads (``--structure``, ``--family``), the one
place that turns the command line's names of structures and families into the library's objects
(``train-generic``, whose family is fixed, is in ``train_generic``).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from aeid_struct.cli.errors import InputError, one_line


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
