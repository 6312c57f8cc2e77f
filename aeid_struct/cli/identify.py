"""``aeid-struct identify``: a record file through a trained identifier, with its self-check
(fit, excess, inside or outside the training range), printed and written as JSON."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from aeid_struct.cli.errors import EXIT_OUTSIDE, InputError
from aeid_struct.cli.output import plain, write_json
from aeid_struct.cli.records_io import on_grid, read_record
from aeid_struct.cli.user_maps import maps_hint, read_maps

#: How the shipped generic identifiers' names begin (``generic-1`` .. ``generic-4``): the file
#: name tells a shipped file's kind (``identification.load_pretrained`` reads the others).
GENERIC_PREFIX = "generic-"


#: The options of ``identify RECORD --order N`` (the generic identifiers) alone.
GENERIC_OPTIONS = ("dt", "no_refine", "delay", "max_delay", "structure", "stable",
                   "intersample", "figure")


def _shipped() -> list[str]:
    from importlib.resources import files

    return sorted(p.name[: -len(".aeid")] for p in files("aeid_struct.pretrained").iterdir()
                  if p.name.endswith(".aeid"))


def shipped_names() -> list[str]:
    """The shipped leg identifiers' names, listed without importing torch.

    Returns
    -------
    list of str
        The ``.aeid`` files of ``aeid_struct/pretrained`` that ``identification.load_pretrained``
        reads (all but the generic identifiers, :func:`generic_names`), without the suffix,
        sorted.
    """
    return [n for n in _shipped() if not n.startswith(GENERIC_PREFIX)]


def generic_names() -> list[str]:
    """The shipped generic identifiers' names (``generic-1`` .. ``generic-4``, those this
    installation has), listed without importing torch.

    Returns
    -------
    list of str
        The ``generic-*.aeid`` files of ``aeid_struct/pretrained`` (read by
        ``generic.load_generic``; ``identify RECORD --order N`` uses them), sorted.
    """
    return [n for n in _shipped() if n.startswith(GENERIC_PREFIX)]


def load_identifier(model: str, option: str, maps: str | None = None):
    """An identifier from an ``.aeid`` file, or a shipped one by name (a file wins).

    Parameters
    ----------
    model : str
        A file name or a shipped name (:func:`shipped_names`).
    option : str
        The option or argument that named it, for the errors.
    maps : str, optional
        ``--maps``: a Python file that builds the user maps the identifier file names
        (``cli.user_maps``).

    Returns
    -------
    Identifier

    Raises
    ------
    InputError
        Neither a readable identifier file nor a shipped name.
    """
    names = ", ".join(shipped_names())
    path = Path(model)
    if path.is_file():
        from aeid_struct.identification import Identifier

        functions = read_maps(maps)
        try:
            return Identifier.load(path, maps=functions)
        except ValueError as err:
            raise InputError(f"{option} {model!r}: {err}{maps_hint(err, maps)}") from None
    if path.is_dir():
        raise InputError(f"{option}: {model!r} is a folder; expected an identifier file (.aeid) "
                         f"or a shipped name: {names}")
    if model.startswith(GENERIC_PREFIX):
        order = model[len(GENERIC_PREFIX):]
        raise InputError(f"{option} {model!r} is a generic identifier (any system, any sample "
                         f"time), not an identifier of one record grid: identify a record with "
                         f"it by 'aeid-struct identify RECORD --order "
                         f"{order if order.isdigit() else 'N'} --dt DT'")
    if model in names.split(", "):
        if maps is not None:
            raise InputError(f"--maps: the shipped identifier {model!r} needs no maps (its "
                             f"maps are the library's own); --maps belongs to an identifier "
                             f"file of your own mechanism")
        from aeid_struct.identification import load_pretrained

        return load_pretrained(model)
    raise InputError(f"{option}: file not found: {model!r} (and it is not a shipped name: "
                     f"{names})")



def _check_model_use(args: argparse.Namespace) -> None:
    """``identify MODEL --y FILE``: no option of the generic identifiers, and a --y file."""
    given = [f"--{k.replace('_', '-')}" for k in GENERIC_OPTIONS if getattr(args, k)
             not in (None, False)]
    if given:
        raise InputError(f"identify: {', '.join(given)} "
                         f"{'applies' if len(given) == 1 else 'apply'} to the generic "
                         f"identifiers: give "
                         f"--order N (or auto) and the record as the argument ('aeid-struct "
                         f"identify RECORD --order N --dt DT'); got the identifier "
                         f"{args.model!r}")
    if args.y is None:
        if Path(args.model).suffix.lower() in (".csv", ".npy", ".txt") and \
                Path(args.model).is_file():
            raise InputError(f"identify: {args.model!r} is a record file: identify it with the "
                             "generic identifiers by --order N (or --order auto), or name an "
                             "identifier and give the record by --y (see 'aeid-struct identify "
                             "--help')")
        raise InputError("identify: the following arguments are required: --y (see "
                         "'aeid-struct identify --help')")


def _print_refinement(est) -> None:
    """How a refined estimate was refined, its standard errors and the start that won."""
    how = {"separable": "refined by the head iterated to convergence (the least-squares "
                        "optimum in its structure)",
           "joint": "refined by the joint output-error fit of the parameters over every "
                    "record"}.get(est.info.get("refine"), "refined by the CasADi NLP")
    print(how + ("" if "refined_rows" not in est.info or not est.batched
                 else f" (records {np.flatnonzero(est.info['refined_rows']).tolist()})"))
    if "std" in est.info:
        print("standard errors:", {k: np.round(v, 6).tolist()
                                   for k, v in est.info["std"].items()})
    if "starts" in est.info:
        print(f"from {est.info['starts']} more starts in the box: the lowest cost from "
              "start (0: the refinement's own optimum)", np.asarray(est.info["start"]).tolist())


def run_identify(args: argparse.Namespace) -> int:
    """The ``identify`` subcommand: read the records, identify, print the model and the
    self-check, write the JSON.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct identify``.

    Returns
    -------
    int
        0, or ``EXIT_OUTSIDE`` when an estimate is flagged outside the training range and
        ``--allow-outside`` is not given.

    Raises
    ------
    InputError
        A wrong model, record file or record.
    """
    if args.order is not None:
        from aeid_struct.cli.identify_any import run_identify_any

        return run_identify_any(args)
    _check_model_use(args)
    ident = load_identifier(args.model, "model", args.maps)
    R = ident.records
    channels = getattr(ident.structure, "channels", None)
    if channels is not None and len(args.y) == 1:
        return _report(args, ident, _identify(args, ident, *_channel_record(args, ident)))
    steps = ident.steps if R > 1 else (ident.steps,)
    dts = ident.dt if R > 1 else (ident.dt,)
    grids = ", ".join(f"{s} samples at dt = {t:g} s" for s, t in zip(steps, dts, strict=True))
    if len(args.y) != R:
        raise InputError(f"--y: this identifier reads {R} record{'s' if R > 1 else ''} "
                         f"(one file per record: {grids}); got {len(args.y)} file(s)")
    if args.u is not None and len(args.u) != R:
        raise InputError(f"--u: give one input file per --y file ({R}); got {len(args.u)}")
    ys = [read_record(f, "--y", "y") for f in args.y]
    us = [read_record(f, "--u", "u") for f in args.u] if args.u else [None] * R
    for r in range(R):
        for rec, option in ((ys[r], "--y"), (us[r], "--u")):
            if rec is not None and rec.several:
                raise InputError(f"{option} file {rec.path!r} holds several outputs or inputs "
                                 f"(numbered columns); {args.model} reads one of each: "
                                 f"identify it with --order N (the generic identifiers)")
        on_grid(ys[r], "--y", steps[r], dts[r])
        if us[r] is not None:
            if ys[r].u is not None:
                raise InputError(f"--u {us[r].path!r} and the u column of --y "
                                 f"{ys[r].path!r}: give the input once")
            on_grid(us[r], "--u", steps[r], dts[r])
    inputs = [ys[r].u if us[r] is None else us[r].values for r in range(R)]
    y = ys[0].values if R == 1 else [rec.values for rec in ys]
    u = inputs[0] if R == 1 else (None if all(v is None for v in inputs) else inputs)
    return _report(args, ident, _identify(args, ident, y, u))


def _identify(args, ident, y, u):
    """``ident.identify`` of the read record(s) with the command's refinement options."""
    refine = {"no": False, "yes": True, "auto": "auto"}[args.refine]
    try:
        return ident.identify(y, u, refine=refine, starts=args.starts)
    except ValueError as err:   # the record's content (all zero, non-finite, a varying u, ...)
        raise InputError(f"identify {', '.join(args.y)} with {args.model}: {err}") from None


def _channel_record(args, ident) -> tuple:
    """One record file of several outputs (and inputs) for an identifier of the channels of one
    record (``Physical(mechanism, channels=...)`` or ``outputs=..., inputs=...``): numbered
    columns ``u1, .., y1, ..`` (or ``--u`` for the inputs), read as one ``Record`` that the
    identifier splits by its channels."""
    from aeid_struct.records import Record

    steps, dt = ident.steps[0], ident.dt[0]
    if args.u is not None and len(args.u) != 1:
        raise InputError(f"--u: give one input file beside the one --y file; got {len(args.u)}")
    rec = read_record(args.y[0], "--y", "y")
    if not rec.several:
        raise InputError(
            f"--y: this identifier reads the channels {list(ident.structure.channels)} (output, "
            f"input) of one record: give one file of numbered columns (y1, y2, .., u1, ..) or "
            f"one --y file per channel ({ident.records}); {rec.path!r} holds one output")
    on_grid(rec, "--y", steps, dt)
    u = rec.u
    if args.u is not None:
        if u is not None:
            raise InputError(f"--u {args.u[0]!r} and the u columns of --y {rec.path!r}: give "
                             "the inputs once")
        inputs = read_record(args.u[0], "--u", "u")
        on_grid(inputs, "--u", steps, dt)
        u = inputs.values
    if u is None:
        raise InputError(f"--y {rec.path!r}: this identifier reads the channels "
                         f"{list(ident.structure.channels)} (output, input) of one record; "
                         "give its inputs as u columns (u1, u2, ..) or with --u")
    try:
        return Record(y=rec.values, u=u, dt=dt), None
    except ValueError as err:
        raise InputError(f"--y {rec.path!r}: {err}") from None


def _report(args, ident, est) -> int:
    """Print the estimate, its refinement and self-check; write JSON; the exit status."""
    np.set_printoptions(precision=6, suppress=False)
    print(f"{ident!r}")
    print("A =\n", est.A)
    print("b =", est.b, " c =", est.c, " d =", est.d)
    if est.physical:
        print("physical:", {k: np.round(v, 6).tolist() for k, v in est.physical.items()})
    if est.refined:
        _print_refinement(est)
    flagged = _self_check(est)
    if args.json:
        write_json(args.json, _estimate_json(est, args.model, repr(ident)))
        print(f"wrote {args.json}")
    if flagged:
        rng = est.training_range
        which = (f"this estimate (fit {_percent(est.fit)}, excess {est.excess:.3g}) is"
                 if not est.batched else
                 f"{len(flagged)} of {len(est.A)} estimates (records "
                 f"{', '.join(map(str, flagged))}) are")
        print(f"aeid-struct: WARNING: {which} OUTSIDE the identifier's training range (fit at "
              f"least {rng['fit']:.2f} %, excess at most {rng['excess']:.3g}): the "
              "record is unlike those it was trained on (another sample time, input or system?) "
              "and the parameters cannot be trusted. "
              + ("Check the record's sample time and input (refined, the model fits the record "
                 "with parameters beyond the range). " if est.refined else
                 "Check the record, or try --refine. ")
              + ("Accepted by --allow-outside." if args.allow_outside else
                 f"Exit status {EXIT_OUTSIDE}; --allow-outside accepts "
                 f"{'it' if not est.batched else 'them'}."), file=sys.stderr)
        if not args.allow_outside:
            return EXIT_OUTSIDE
    return 0




def _self_check(est) -> list[int]:
    """Print each record's fit, excess and verdict; return the flagged rows (``[0]`` for an
    unbatched flagged estimate)."""
    rng = est.training_range
    fits = np.asarray(est.fit, dtype=np.float64)
    rows = len(est.A) if est.batched else 1
    fits = fits.reshape(rows, -1)
    if est.outside is None:
        for i in range(rows):
            print(f"self-check{f' record {i}' if est.batched else ''}: fit "
                  f"{_percent(fits[i])} (NRMSE); this identifier carries no calibrated training "
                  "range, so no inside/outside verdict (training.recalibrate adds one)")
        return []
    excess = np.asarray(est.excess, dtype=np.float64).reshape(rows)
    outside = np.asarray(est.outside, dtype=bool).reshape(rows)
    print(f"self-check against the training range (flagged OUTSIDE when the fit falls below "
          f"{rng['fit']:.2f} % or the excess exceeds {rng['excess']:.3g}):")
    for i in range(rows):
        print(f"  {f'record {i}: ' if est.batched else ''}fit {_percent(fits[i])}, excess "
              f"{excess[i]:.3g}: "
              + ("OUTSIDE the training range" if outside[i] else "inside the training range"))
    return np.flatnonzero(outside).tolist()


def _percent(fit: np.ndarray) -> str:
    return ", ".join(f"{v:.2f} %" for v in np.atleast_1d(fit))


def _estimate_json(est, model: str, identifier: str) -> dict:
    rng = est.training_range
    refined_rows = est.info.get("refined_rows")
    return plain({
        "model": model, "identifier": identifier, "dt": est.dt,
        "A": est.A, "b": est.b, "c": est.c, "d": np.asarray(est.d),
        "fit_percent": np.asarray(est.fit), "excess": est.excess, "outside": est.outside,
        "thresholds": (None if not rng or "excess" not in rng
                       else {"fit_percent": rng["fit"], "excess": rng["excess"]}),
        "refined": est.refined,
        "refined_rows": None if refined_rows is None else np.asarray(refined_rows),
        "records": est.records,
        "physical": {k: np.asarray(v) for k, v in est.physical.items()},
        "seconds": est.seconds,
    })

