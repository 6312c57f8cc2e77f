"""``aeid-struct identify RECORD --order N``: any system's record through the generic
identifiers (``aeid_struct.identify``), the model printed and written as JSON, the compare
figure written as PNG (a record of several inputs and outputs: ``cli.identify_channels``).

The model of the record (docs/architecture.md, "Any system, any record"): the continuous-time
``(A, b, c, d)`` in the record's time unit, the input delay ``D`` in samples, the state ``x0``
at sample ``D`` and a constant output offset; the fit is the NRMSE fit in % on ``y[D:]``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from aeid_struct.cli.errors import InputError
from aeid_struct.cli.identify_channels import (
    order_and_hold,
    print_channels,
    refinement_line,
    summary_channels,
    unexcited_line,
    unexcited_of,
    unstable_line,
    unstable_of,
)
from aeid_struct.cli.output import plain, write_json
from aeid_struct.cli.records_io import read_record


def transfer_function(A, b, c, d) -> tuple[np.ndarray, np.ndarray]:
    """Numerator and denominator of ``G(s) = c^T (sI - A)^-1 b + d`` (descending powers of s).

    Faddeev-LeVerrier: ``adj(sI - A) = sum_k N_k s^(n-1-k)`` with ``N_0 = I`` and ``N_k = A
    N_(k-1) + a_k I`` (``a`` the characteristic polynomial's coefficients), so the numerator's
    coefficients are ``d a_k + c^T N_(k-1) b``: linear in ``c`` and ``d``. (The determinant
    lemma's ``det(sI - A + b c^T) + (d - 1) det(sI - A)`` cancels to nothing where ``c`` is
    small beside ``A``, a gain of 1e-200 printed as a zero numerator.)

    Parameters
    ----------
    A : (n, n) array
    b, c : (n,) arrays
    d : float

    Returns
    -------
    num, den : (n + 1,) arrays
        ``den`` monic.
    """
    A = np.asarray(A, dtype=np.float64)
    b, c = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (b, c))
    den = np.poly(A)
    n = A.shape[0]
    num, N = float(d) * den, np.eye(n)
    for k in range(1, n + 1):
        num[k] += c @ N @ b
        N = A @ N + den[k] * np.eye(n)
    return num, den


def _record(args: argparse.Namespace):
    """The ``aeid_struct.Record`` of RECORD (and ``--u``, ``--dt``), checked."""
    from aeid_struct import Record

    rec = read_record(args.model, "RECORD", "y")
    if rec.values.ndim != 1 and not rec.several:
        raise InputError(f"RECORD file {args.model!r} holds {rec.values.shape[0]} rows of "
                         f"{rec.values.shape[1]} values; expected one record: name its "
                         "columns in a header row (e.g. 't,u,y', or 't,u1,u2,y1,y2' for "
                         "several inputs and outputs), or give y alone (one number per line, "
                         "or a (steps,) .npy) and its input by --u")
    u = rec.u
    source = "the u column" if u is None or u.ndim == 1 else f"the u1..u{u.shape[1]} columns"
    if args.u is not None and rec.several:
        raise InputError(f"--u and RECORD {args.model!r} of several outputs or inputs: give "
                         "the inputs as its numbered columns u1, u2, ...")
    if args.u is not None:
        if len(args.u) != 1:
            raise InputError(f"--u: give one input file for RECORD; got {len(args.u)} files")
        if rec.u is not None:
            raise InputError(f"--u {args.u[0]!r} and the u column of RECORD {args.model!r}: "
                             "give the input once")
        u_file = read_record(args.u[0], "--u", "u")
        if u_file.values.ndim != 1 or u_file.values.shape != rec.values.shape:
            raise InputError(f"--u file {args.u[0]!r} holds {u_file.values.shape} values; "
                             f"expected one input of {rec.values.shape[0]} samples like RECORD")
        u, source = u_file.values, f"--u {args.u[0]}"
    if u is None:
        source = "a unit step (RECORD has no u column and no --u was given)"
    if rec.dt is None and args.dt is None:
        raise InputError(f"--dt: RECORD {args.model!r} has no t column; give its sample time "
                         "by --dt DT (seconds)")
    if rec.dt is not None and args.dt is not None and not math.isclose(rec.dt, args.dt,
                                                                       rel_tol=1e-4):
        raise InputError(f"--dt {args.dt:g} s disagrees with the t column of RECORD "
                         f"{args.model!r} (sampled every {rec.dt:g} s); give one of them")
    steps = rec.values.shape[0]
    if args.delay is not None and args.delay > steps - 2:
        raise InputError(f"--delay must be at most {steps - 2} samples for RECORD "
                         f"{args.model!r} ({steps} samples); got {args.delay}")
    try:
        record = Record(rec.values, u, args.dt if rec.dt is None else rec.dt,
                        t0=rec.t0 or 0.0, name=Path(args.model).name,
                        intersample=args.intersample or "foh")
    except ValueError as err:
        raise InputError(f"RECORD {args.model!r}: {err}") from None
    return record, source


def _refuse_model_options(args: argparse.Namespace) -> None:
    """The options of an identifier (MODEL) have no meaning for the generic identifiers."""
    given = [opt for opt, on in (("--y", args.y is not None),
                                 ("--refine", args.refine != "no"),
                                 ("--starts", args.starts != 0),
                                 ("--allow-outside", args.allow_outside),
                                 ("--maps", args.maps is not None)) if on]
    if given:
        raise InputError(f"identify: {', '.join(given)} "
                         f"{'applies' if len(given) == 1 else 'apply'} to an identifier "
                         "MODEL, not to "
                         "--order (the generic identifiers read RECORD, the argument; "
                         "--no-refine skips their refinement)")
    if args.figure is not None and Path(args.figure).is_dir():
        raise InputError(f"--figure {args.figure!r} is a folder; expected the PNG file to write")


def run_identify_any(args: argparse.Namespace) -> int:
    """``identify RECORD --order N``: identify, print the model, write the JSON and figure.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct identify`` with ``--order``.

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        A wrong option, record file or record (one that the generic identifiers refuse, e.g.
        shorter than their window).
    """
    _refuse_model_options(args)
    record, source = _record(args)
    import aeid_struct as ae

    order = None if args.order == "auto" else int(args.order)
    try:
        est = ae.identify(record, order=order, structure=args.structure, refine=not args.no_refine,
                          delay=args.delay, max_delay=args.max_delay, stable=args.stable)
    except ValueError as err:   # the record's content, its length, a missing generic file
        raise InputError(f"identify {args.model} --order {args.order}: {err}") from None
    figure = None
    if args.figure is not None:
        cmp = ae.compare(est, record)
        try:
            Path(args.figure).parent.mkdir(parents=True, exist_ok=True)
            cmp.figure(args.figure, title=f"{record.name}: order {est.A.shape[0]}")
        except OSError as err:
            raise InputError(f"--figure {args.figure!r}: cannot write "
                             f"({err.strerror or err})") from None
        figure = {"path": args.figure, "fit_percent": cmp.fit}
    if record.outputs > 1 or record.inputs > 1:
        summary = summary_channels(est, record, args, source, figure)
        print_channels(summary, est)
    else:
        summary = _summary(est, record, args, source, est.info["max_delay"], figure)
        _print(summary, est)
    if args.json:
        write_json(args.json, plain(summary))
        print(f"wrote {args.json}")
    return 0


def _summary(est, record, args, source: str, max_delay: int, figure) -> dict:
    """The estimate as the JSON and the printout carry it."""
    num, den = transfer_function(est.A, est.b, est.c, est.d)
    fits = est.info.get("order_fits")
    return {
        "record": args.model, "steps": record.steps, "dt": record.dt, "input": source,
        "intersample": record.intersample,
        "order": int(est.A.shape[0]),
        "order_fits": None if fits is None else {str(n): f for n, f in sorted(fits.items())},
        "identifier": f"generic-{est.A.shape[0]}", "structure": repr(est.structure),
        "A": est.A, "b": est.b, "c": est.c, "d": float(est.d),
        "elements": {k: float(v) for k, v in est.elements.items()},
        "numerator": num, "denominator": den,
        "delay_samples": est.delay, "delay_seconds": est.delay * record.dt,
        "delay_estimated": args.delay is None, "max_delay": max_delay,
        "x0": est.x0, "offset": est.offset, "fit_percent": float(est.fit),
        "refined": bool(est.refined), "refine": not args.no_refine,
        "seconds": float(est.seconds), "figure": figure,
        "feedback": est.info.get("feedback"), "unexcited": unexcited_of(est),
        "stable": bool(args.stable), "unstable": unstable_of(est),
        "holdout_fit_percent": est.info.get("holdout_fit"),
        "holdout_residual_ratio": est.info.get("holdout_ratio"),
    }


def _print(s: dict, est) -> None:
    np.set_printoptions(precision=6, suppress=False)
    chosen, held = order_and_hold(s)
    print(f"{s['record']}: {s['steps']} samples at dt = {s['dt']:g} s; input: "
          f"{s['input']}{held}")
    print(f"{s['identifier']}: order {s['order']}{chosen}, structure {s['structure']}")
    print("A =\n", est.A)
    print("b =", est.b, " c =", est.c, " d =", est.d)
    print("transfer function (descending powers of s):\n  num =", s["numerator"],
          "\n  den =", s["denominator"])
    print(f"delay: {s['delay_samples']} samples = {s['delay_seconds']:g} s ("
          + (f"estimated, 0..{s['max_delay']} considered)" if s["delay_estimated"]
             else "given)"))
    print(f"initial state x0 (at sample {s['delay_samples']}) =", est.x0)
    print(f"output offset = {s['offset']:.6g}")
    print(f"fit: {s['fit_percent']:.2f} % (NRMSE on samples {s['delay_samples']}.."
          f"{s['steps'] - 1}, initial state and offset fitted)")
    print(refinement_line(s))
    found = s["feedback"]
    if found is not None and found["detected"]:
        print(f"closed loop: the residuals are correlated with later inputs (z = "
              f"{found['statistic']:.1f} at lag {found['lag']} > {found['bound']:.2f})"
              + ("; identified without a feedthrough" if "refit" in found else ""))
    for line in (unexcited_line(s), unstable_line(s)):
        if line is not None:
            print(line)
    holdout, ratio = s["holdout_fit_percent"], s["holdout_residual_ratio"]
    if holdout is not None:
        from aeid_struct.generic import holdout_flagged

        print(f"hold-out: fitted on the first 70 %, the model predicts the rest with a fit of "
              f"{holdout:.2f} %" + ("" if ratio is None else f", its residual {ratio:.2f} "
                                    f"times its own on the first 70 %")
              + (" -- the record does not determine a model of this order"
                 if holdout_flagged(holdout, ratio) else ""))
    print(f"time: {1e3 * s['seconds']:.1f} ms")
    if s["figure"] is not None:
        print(f"wrote {s['figure']['path']} (compare: fit {s['figure']['fit_percent']:.2f} %)")
