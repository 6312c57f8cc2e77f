"""``aeid-struct train-generic``: train a generic identifier of one order on the generic family and
write it as an ``.aeid`` file, with a JSON file of the run (its recipe and history).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from aeid_struct.cli.errors import InputError


def run_train_generic(args: argparse.Namespace) -> int:
    """The ``train-generic`` subcommand.

    The run checkpoints to ``OUT.ckpt`` every epoch; ``--resume`` continues from it (without it an
    existing checkpoint is an error, so that a finished or foreign run is not silently extended).
    Launched by ``torchrun`` the run is data-parallel (``--batch`` is the global batch) and rank 0
    alone writes the files and reports.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct train-generic``.

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        A wrong setting, output path or checkpoint.
    """
    out = Path(args.out or f"generic-{args.order}.aeid")
    if out.is_dir():
        raise InputError(f"train-generic: --out {str(out)!r} is a folder; expected the "
                         "identifier file to write (e.g. generic-2.aeid)")
    ckpt = out.with_name(out.name + ".ckpt")
    if ckpt.exists() and not args.resume:
        raise InputError(f"train-generic: checkpoint {str(ckpt)!r} exists; pass --resume to "
                         "continue that run, or delete it to start over")
    from aeid_struct.generic import GenericConfig, load_generic
    from aeid_struct.training import (
        GenericFamily,
        GenericTrainConfig,
        GrowthFamily,
        process_rank,
        train_generic,
    )

    try:
        shape = {k: v for k, v in (("width", args.width), ("depth", args.depth),
                                   ("dense", args.dense)) if v is not None}
        config = GenericConfig(order=args.order, window=args.window, **shape)
        # an unstable plant grows by e^0.5 to e^3 over one window (GrowthFamily reads it
        # under a weight of up to e^-4 over the window, which leaves it stable)
        family = GenericFamily(order=config.order, band=config.band,
                               integrating=args.integrating, unstable=args.unstable,
                               **({"growth": (0.5 / config.window, 3.0 / config.window)}
                                  if args.unstable else {}))
        if args.growth_weights:
            family = GrowthFamily(base=family)
    except ValueError as err:
        raise InputError(f"train-generic: {err}") from None
    init = None
    if args.init is not None:
        try:
            init = load_generic(args.init)
        except ValueError as err:
            raise InputError(f"train-generic: --init {args.init!r}: {err}") from None
        if init.config != config:
            raise InputError(f"train-generic: --init {args.init!r} is an identifier of order "
                             f"{init.config.order}, window {init.config.window}, width "
                             f"{init.config.width}, depth {init.config.depth}, dense "
                             f"{list(init.config.dense)}; --order {config.order} --window "
                             f"{config.window} --width {config.width} --depth {config.depth} "
                             f"--dense {' '.join(map(str, config.dense))} needs one of that "
                             "shape")
    try:
        train = GenericTrainConfig(
            epochs=args.epochs, seconds=None if args.minutes is None else 60.0 * args.minutes,
            count=args.count, holdout=args.holdout, batch=args.batch, lr=args.lr,
            seed=args.seed, loss=args.loss, checkpoint=str(ckpt), progress=not args.quiet,
            threads=args.threads, device=args.device, workers=args.workers)
    except ValueError as err:
        raise InputError(f"train-generic: {err}") from None
    meta = {"name": out.stem, "command": "aeid-struct " + " ".join(args.argv)}
    try:
        ident = train_generic(config, train, meta=meta, family=family, init=init)
    except ValueError as err:
        raise InputError(f"train-generic: {err}") from None
    if process_rank() != 0:
        return 0                   # under torchrun, rank 0 writes the identifier and reports
    try:
        path = ident.save(out)
        report = out.with_suffix(".json")
        report.write_text(json.dumps({"file": str(path), "meta": ident.meta}, indent=1))
    except (OSError, ValueError) as err:
        raise InputError(f"train-generic: --out {str(out)!r}: cannot write the identifier "
                         f"({getattr(err, 'strerror', None) or err})") from None
    info = ident.meta["train"]
    print(f"trained {ident!r}: {info['epochs']} epochs in {info['seconds']:.1f} s, best "
          f"held-out loss {info['best_holdout_loss']:.3f} (median fit "
          f"{info['holdout_fit_median']:.1f} %); wrote {path} and {report}")
    return 0
