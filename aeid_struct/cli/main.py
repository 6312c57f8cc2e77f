"""The ``aeid-struct`` command.

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

Nothing heavy is imported before the arguments are parsed (the package ``__init__`` is lazy, and
torch, CasADi and matplotlib are imported inside the subcommands), so ``--help`` is immediate.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import sys
import textwrap
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Exit status of a usage or input error (argparse's own convention).
EXIT_INPUT = 2
#: Exit status of ``identify`` when an estimate is flagged outside the training range.
EXIT_OUTSIDE = 3

#: The record layouts ``identify`` reads (its --help and its hints show this text).
RECORD_LAYOUTS = (
    "Record files: .npy (a (steps,) array, or (batch, steps) for a batch of records) or CSV "
    "(comma-separated numbers): one number per line (one record), one record per line (a "
    "batch), or named columns under a header row, e.g. 't,y' or 't,u,y' (names t/time, "
    "u/input, y/output, units after the name allowed: 't [s]'). A --y file needs a y column and "
    "may carry u (the input) and t (its sample time is checked against the identifier's). A "
    "header over a single column is skipped. Lines starting with # are comments."
)

#: CSV header names -> the channel they name.
_COLUMN_NAMES = {"t": "t", "time": "t", "u": "u", "input": "u", "y": "y", "output": "y"}
#: The training excitations, for --help only (TrainConfig checks the name; a test keeps this
#: equal to data.EXCITATIONS, which the parser cannot import without torch).
_EXCITATIONS = ("step", "ramp", "prbs", "multisine", "noise", "steps", "mix")


class _InputError(Exception):
    """A user's mistake (an argument, a file, a record): ``main`` prints it as one line and
    returns ``EXIT_INPUT``. Anything else that escapes a subcommand is a bug and keeps its
    traceback."""


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
        raise _InputError(f"{where + ': ' if where else ''}{message} "
                          f"(see '{self.prog} --help')")


class UsageExit(SystemExit):
    """How ``main`` ends on a usage or input error, after printing it as one line on stderr:
    ``SystemExit`` with status ``EXIT_INPUT`` (what the interpreter exits with, printing
    nothing more) whose ``str()`` is the message, so that callers and tests can read it."""

    def __init__(self, message: str):
        super().__init__(EXIT_INPUT)
        self.message = message

    def __str__(self) -> str:
        return self.message


def _one_line(err: object) -> str:
    return " ".join(str(err).split())


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


# -- demo ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Response:
    """One subsystem's unit-step response for the demo figure: ``t, y (steps,)``."""

    title: str
    step: str       # the input that steps, with its unit
    output: str     # the output's quantity and unit (the axis label)
    t: np.ndarray
    y: np.ndarray


def _demo_figure(responses: list[_Response], params: dict[str, float]):
    """The demo's figure: one panel per subsystem, quantities with units, a title that says
    what produced it. A ``matplotlib.figure.Figure`` (no pyplot state)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.4))
    axes = fig.subplots(1, len(responses))
    for ax, r in zip(np.atleast_1d(axes), responses, strict=True):
        ax.plot(r.t, r.y)
        ax.set_title(f"{r.title}\nresponse to a unit step of {r.step}", fontsize=10)
        ax.set_xlabel("time t [s]")
        ax.set_ylabel(r.output)
        ax.set_xlim(r.t[0], r.t[-1])
        ax.grid(True, alpha=0.3)
    fig.suptitle("aeid-struct demo: robot leg linearised by CasADi (paper Eq. 16), exact FOH "
                 f"simulation (Eq. 10-13); k = {params['k']:g} N/m, d = {params['d']:g} kg/s, "
                 f"m = {params['m']:g} kg", fontsize=10)
    fig.tight_layout()
    return fig


def _demo(args: argparse.Namespace) -> int:
    import aeid_struct as ae
    from symbolic import leg

    out = Path(args.out)
    params = {"k": args.k, "d": args.d, "m": args.m}
    # The rotational subsystem is linearised about the upright leg at the length where the
    # spring carries the weight, L = l0 - m g / k (symbolic.leg): it must be a positive length.
    if not leg.L0 - args.m * leg.G / args.k > 0:
        raise _InputError(
            f"demo: --k and --m must let the spring carry the weight (l0 - m g / k > 0 with "
            f"l0 = {leg.L0} m, g = {leg.G} m/s^2, i.e. k > {args.m * leg.G / leg.L0:.4g} N/m "
            f"for m = {args.m:g} kg); got k = {args.k:g} N/m")
    np.set_printoptions(precision=4, suppress=True)

    t0 = time.perf_counter()
    lin = leg.linearisation()(**params, l0=leg.L0, g=leg.G)
    A, B = np.array(lin["A"]), np.array(lin["B"])
    print(f"Robot leg (spring-loaded inverted pendulum), k={args.k} N/m, d={args.d} kg/s, "
          f"m={args.m} kg, l0={leg.L0} m, g={leg.G} m/s^2")
    print(f"Linearisation at the upright equilibrium by CasADi Jacobians (paper Eq. 16), "
          f"derived in {time.perf_counter() - t0:.2f} s:")
    print("A =\n", A)
    print("B =\n", B)

    # (title, map, dt, steps, the input that steps, the output with its unit)
    systems = [
        ("translational subsystem G1 (stable)", leg.stable_map(), args.dt_stable,
         args.steps_stable, "the leg force F [N]", "leg length deflection l - L [m]"),
        ("rotational subsystem G2 (unstable)", leg.unstable_map(), args.dt_unstable,
         args.steps_unstable, "the hip torque tau [N m]",
         "leg angle deflection theta - pi/2 [rad]"),
    ]
    responses = []
    for title, f, dt, steps, step, output in systems:
        ccf = f(**params)
        Ac, bc = np.array(ccf["A"]), np.array(ccf["B"])[:, 0]
        cc, dc = np.array(ccf["C"])[0], float(np.array(ccf["D"])[0, 0])
        y = ae.simulate(Ac, bc, cc, dc, np.ones(steps), dt)
        print(f"\n{title} in controllable canonical form (paper Eq. 5):")
        print("A =\n", Ac)
        print("b =", bc, " c =", cc, " d =", dc)
        print(f"poles: {np.linalg.eigvals(Ac)}")
        print(f"unit-step response: {steps} samples, dt = {dt} s, y[-1] = {y[-1]:.6g}")
        responses.append(_Response(title, step, output, np.arange(steps) * dt, y))
    fig = _demo_figure(responses, params)
    png = out / "leg_step_responses.png"
    try:
        out.mkdir(parents=True, exist_ok=True)
        fig.savefig(png, dpi=120, metadata={"Title": fig.get_suptitle()})
    except OSError as err:
        raise _InputError(f"demo: --out {args.out!r}: cannot write {png} "
                          f"({err.strerror or err})") from None
    print(f"\nwrote {png}")
    return 0


def _leg(args: argparse.Namespace) -> int:
    from aeid_struct.studies import leg_paper as study

    command = "aeid-struct " + " ".join(args.argv)
    seconds = args.seconds
    print("Robot-leg study (paper Sec. IV): "
          + ("shipped identifiers" if args.pretrained else
             (f"training both identifiers, {args.epochs} epochs each" if args.epochs else
              f"training both identifiers, {seconds:.0f} s budget in total (at least "
              f"{study.MIN_EPOCHS['stable']} / {study.MIN_EPOCHS['unstable']} epochs)"))
          + f", {args.validation} validation systems, seed {args.seed}", flush=True)
    import warnings

    from aeid_struct.training import UndertrainedWarning

    with warnings.catch_warnings():   # printed below, beside the table they qualify
        warnings.simplefilter("ignore", UndertrainedWarning)
        result = study.run(pretrained=args.pretrained, seconds=seconds, seed=args.seed,
                           out=args.out, fig4_sizes=args.fig4_sizes if args.fig4 else None,
                           fig4_seconds=args.fig4_seconds, validation=args.validation,
                           progress=not args.quiet, command=command, epochs=args.epochs)
    print()
    print("Table I, ours beside the paper's (noise-free; Bode over "
          f"{result['frequency_grid_rad_s'][0]:g}-{result['frequency_grid_rad_s'][1]:g} rad/s, "
          f"{result['frequency_grid_rad_s'][2]} log-spaced points):")
    print(result["markdown"])
    print()
    for name, row in result["table"].items():
        trained = ("shipped identifier" if args.pretrained else
                   f"training {result['train_seconds'][name]:.1f} s, "
                   f"{result['train_epochs'][name]} epochs")
        print(f"{name}: {trained}, identification "
              f"{row['latency_ms']:.3f} ms per call (batch 1), "
              f"{row['throughput_per_s']:,.0f} identifications/s batched "
              f"(paper: {study.PAPER_SECONDS['encoder_400mhz']} s on a 400 MHz core)")
    for note in result["warnings"]:
        print(f"\nWARNING (under-trained): {note}")
    print("\nwrote " + ", ".join(result["run"]["files"]))
    return 0


def _structure(spec: str):
    """Parse a structure spec: ccf:N[:descartes][:feedthrough], mcf:REAL,PAIRS, leg-stable."""
    from aeid_struct.structures import base as structures

    parts = spec.split(":")
    try:
        if parts[0] == "ccf":
            flags = set(parts[2:])
            unknown = flags - {"descartes", "feedthrough"}
            if unknown:
                raise ValueError(f"unknown flags {sorted(unknown)}")
            return structures.CCF(int(parts[1]), descartes="descartes" in flags,
                                  feedthrough="feedthrough" in flags)
        if parts[0] == "mcf":
            real, pairs = (int(v) for v in parts[1].split(","))
            return structures.MCF(real=real, pairs=pairs)
        if parts[0] in ("leg-stable", "leg-unstable"):
            from aeid_struct.training import LegFamily

            family = LegFamily(subsystem=parts[0].split("-")[1])
            return structures.Physical(family.map(), bounds=dict(family.ranges),
                                       inverse=family.inverse())
    except (IndexError, ValueError) as err:
        raise _InputError(f"train: --structure {spec!r} is malformed ({_one_line(err)}); "
                          "expected ccf:N[:descartes][:feedthrough], mcf:REAL,PAIRS, "
                          "leg-stable or leg-unstable") from None
    raise _InputError(f"train: --structure must be ccf:..., mcf:... or leg-stable/leg-unstable; "
                      f"got {spec!r}")


def _family(spec: str):
    """Parse a family spec: leg-stable, leg-unstable, poles:REAL,PAIRS."""
    from aeid_struct.training import LegFamily, PoleFamily

    if spec in ("leg-stable", "leg-unstable"):
        return LegFamily(subsystem=spec.split("-")[1])
    if spec.startswith("poles:"):
        try:
            real, pairs = (int(v) for v in spec[6:].split(","))
            return PoleFamily(real=real, pairs=pairs)
        except ValueError as err:
            raise _InputError(f"train: --family {spec!r} is malformed ({_one_line(err)}); "
                              "expected poles:REAL,PAIRS") from None
    raise _InputError(f"train: --family must be leg-stable, leg-unstable or poles:REAL,PAIRS; "
                      f"got {spec!r}")


def _train(args: argparse.Namespace) -> int:
    if Path(args.out).is_dir():
        raise _InputError(f"train: --out {args.out!r} is a folder; expected the identifier file "
                          "to write (e.g. model.aeid)")
    structure = _structure(args.structure)
    family = _family(args.family)
    order = getattr(family, "n", 2)          # a leg subsystem is of order 2
    if structure.n != order:
        raise _InputError(f"train: --structure {args.structure!r} has order {structure.n} but "
                          f"--family {args.family!r} has systems of order {order}; they must "
                          "agree")
    from aeid_struct.encoder import EncoderConfig
    from aeid_struct.structures import CCF
    from aeid_struct.training import LegFamily, TrainConfig, train

    if len(args.noise) > 2:
        raise _InputError(f"train: --noise takes one level or LO HI; got {len(args.noise)} "
                          f"values {args.noise}")
    noise = args.noise[0] if len(args.noise) == 1 else tuple(args.noise)
    try:
        config = TrainConfig(dt=args.dt, steps=args.steps, count=args.count, epochs=args.epochs,
                             seconds=args.seconds, batch=args.batch, lr=args.lr,
                             gamma=args.gamma, noise=noise, excitation=args.excitation,
                             seed=args.seed, checkpoint=args.checkpoint,
                             progress=not args.quiet)
        encoder = EncoderConfig(width=args.width, kernel=args.kernel, dense=tuple(args.dense),
                                pool=args.pool)
    except ValueError as err:
        raise _InputError(f"train: {err}") from None
    # A CCF identifier of a leg subsystem reports k, d, m through the CasADi inverse.
    inverse = family.inverse() if isinstance(family, LegFamily) and isinstance(
        structure, CCF) and structure.n == 2 else None
    try:
        # train() checks the structure against the family and the checkpoint against the run
        ident = train(structure, family, config, encoder=encoder, inverse=inverse,
                      meta={"command": "aeid-struct " + " ".join(args.argv), "seed": args.seed})
    except ValueError as err:
        raise _InputError(f"train: {err}") from None
    try:
        path = ident.save(args.out)
    except OSError as err:
        raise _InputError(f"train: --out {args.out!r}: cannot write the identifier "
                          f"({err.strerror or err})") from None
    info = ident.meta["train"]
    print(f"trained {ident!r}: {info['epochs']} epochs in {info['seconds']:.1f} s, "
          f"best held-out loss {info['best_holdout_loss']:.3e}; wrote {path}")
    return 0


# -- identify: models and record files -----------------------------------------------------------
def shipped_names() -> list[str]:
    """The shipped identifiers' names: the ``.aeid`` files of ``aeid_struct/pretrained``, the
    folder ``identify.load_pretrained`` reads (listed without importing torch)."""
    from importlib.resources import files

    return sorted(p.name[: -len(".aeid")] for p in files("aeid_struct.pretrained").iterdir()
                  if p.name.endswith(".aeid"))


def _load_identifier(model: str, option: str):
    """An identifier from an ``.aeid`` file, or a shipped one by name (a file wins)."""
    names = ", ".join(shipped_names())
    path = Path(model)
    if path.is_file():
        from aeid_struct.identification import Identifier

        try:
            return Identifier.load(path)
        except ValueError as err:
            raise _InputError(f"{option} {model!r}: {err}") from None
    if path.is_dir():
        raise _InputError(f"{option}: {model!r} is a folder; expected an identifier file (.aeid) "
                          f"or a shipped name: {names}")
    if model in names.split(", "):
        from aeid_struct.identification import load_pretrained

        return load_pretrained(model)
    raise _InputError(f"{option}: file not found: {model!r} (and it is not a shipped name: "
                      f"{names})")


@dataclass(frozen=True)
class _Record:
    """What one record file holds: ``values`` ``(steps,)`` or ``(batch, steps)``, and from
    named CSV columns the input ``u (steps,)`` and the sample time ``dt`` of a t column."""

    path: str
    values: np.ndarray
    u: np.ndarray | None = None
    dt: float | None = None
    columns: bool = False      # read from named columns (one record per file)


def _read_npy(path: Path, option: str) -> np.ndarray:
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as err:
        # allow_pickle=False: object arrays and pickles are refused, never unpickled
        raise _InputError(f"{option} file {str(path)!r} is not a numeric .npy array "
                          f"({_one_line(err)})") from None
    if not isinstance(arr, np.ndarray):
        raise _InputError(f"{option} file {str(path)!r} is an .npz archive; expected one .npy "
                          "array")
    if arr.dtype.kind == "c":
        raise _InputError(f"{option} file {str(path)!r} holds complex values ({arr.dtype}); "
                          "expected real numbers")
    if arr.dtype.kind not in "iuf":
        raise _InputError(f"{option} file {str(path)!r} holds {arr.dtype} values; expected a "
                          "numeric (float or integer) array")
    if arr.ndim not in (1, 2) or arr.size == 0:
        raise _InputError(f"{option} file {str(path)!r} holds an array of shape {arr.shape}; "
                          "expected (steps,) or (batch, steps)")
    return arr.astype(np.float64)


def _column_name(cell: str) -> str | None:
    """A header cell's channel (t, u, y), reading ``'y [m]'`` as y; None when unknown."""
    word = re.match(r"[a-z_]+", cell.strip().lower())
    return _COLUMN_NAMES.get(word.group(0)) if word else None


def _read_csv(path: Path, option: str) -> tuple[np.ndarray, list[str] | None]:
    """The numbers of a CSV as ``(rows, columns)``, and its header cells (None without one)."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            lines = [(i, row) for i, row in enumerate(csv.reader(fh), 1)
                     if row and "".join(row).strip() and not row[0].lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise _InputError(f"{option} file {str(path)!r} is not a text CSV file (nor .npy)") \
            from None
    except (OSError, csv.Error) as err:
        raise _InputError(f"{option} file {str(path)!r} cannot be read ({_one_line(err)})") \
            from None
    if not lines:
        raise _InputError(f"{option} file {str(path)!r} holds no numbers")
    header = None
    if not all(_is_number(c) for c in lines[0][1]):
        header = [c.strip() for c in lines[0][1]]
        lines = lines[1:]
        if not lines:
            raise _InputError(f"{option} file {str(path)!r} holds a header row and no numbers")
    width = len(header) if header is not None else len(lines[0][1])
    rows = []
    for i, row in lines:
        if len(row) != width:
            raise _InputError(f"{option} file {str(path)!r}: line {i} holds {len(row)} values; "
                              f"expected {width} like the {'header' if header else 'first line'}")
        for j, cell in enumerate(row, 1):
            if not _is_number(cell):
                raise _InputError(f"{option} file {str(path)!r}: line {i}, column {j} is "
                                  f"{cell.strip()!r}; expected a number")
        rows.append([float(c) for c in row])
    return np.array(rows, dtype=np.float64), header


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _read_record(file: str, option: str, channel: str) -> _Record:
    """Read one record file given to ``option`` (--y or --u) for ``channel`` (y or u)."""
    path = Path(file)
    if path.is_dir():
        raise _InputError(f"{option}: {file!r} is a folder; expected a .npy or .csv record file")
    if not path.is_file():
        raise _InputError(f"{option}: file not found: {file!r}; expected a .npy or .csv record "
                          "file")
    if path.suffix.lower() == ".npy":
        return _Record(file, _read_npy(path, option))
    table, header = _read_csv(path, option)
    if header is None:
        # one column is one record; one row too; several rows of several values are a batch
        values = table[:, 0] if table.shape[1] == 1 else (table[0] if len(table) == 1
                                                            else table)
        return _Record(file, values)
    names = [_column_name(c) for c in header]
    if len(header) == 1:
        if names[0] not in (None, channel):
            raise _InputError(f"{option} file {file!r} holds one column named {header[0]!r}; "
                              f"expected {channel} (or an unnamed column)")
        return _Record(file, table[:, 0])
    unknown = [h for h, n in zip(header, names, strict=True) if n is None]
    twice = sorted({n for n in names if n is not None and names.count(n) > 1})
    if unknown or twice:
        raise _InputError(f"{option} file {file!r} has the header {','.join(header)!r}; "
                          f"expected columns named t, u, y (each once), e.g. 't,u,y'"
                          + (f"; {', '.join(map(repr, unknown))} is not one of them"
                             if unknown else f"; {', '.join(twice)} named twice"))
    if channel not in names:
        raise _InputError(f"{option} file {file!r} has the columns {','.join(header)!r} but no "
                          f"{channel} column")
    column = {n: table[:, k] for k, n in enumerate(names)}
    return _Record(file, column[channel], u=column.get("u") if channel == "y" else None,
                   dt=_sample_time(column["t"], file, option) if "t" in column else None,
                   columns=True)


def _sample_time(t: np.ndarray, file: str, option: str) -> float | None:
    """The sample time of a t column, which must be evenly spaced."""
    if len(t) < 2:
        return None
    steps = np.diff(t)
    dt = (t[-1] - t[0]) / (len(t) - 1)
    # 1e-3 relative: a t column printed with a few digits is still read as even
    if not dt > 0 or np.max(np.abs(steps - dt)) > 1e-3 * dt:
        raise _InputError(f"{option} file {file!r}: the t column must increase in equal steps "
                          f"(one record sampled every dt); got steps from {steps.min():g} to "
                          f"{steps.max():g} s")
    return float(dt)


def _on_grid(rec: _Record, option: str, steps: int, dt: float) -> None:
    """Check a record against the identifier's grid (``steps`` samples every ``dt`` s), with a
    hint on the layouts where the file's shape suggests a misread."""
    grid = f"records of {steps} samples at dt = {dt:g} s"
    if rec.dt is not None and not math.isclose(rec.dt, dt, rel_tol=1e-4):
        raise _InputError(f"{option} file {rec.path!r}: its t column is sampled every "
                          f"{rec.dt:g} s; this identifier reads {grid}: resample the record, "
                          f"or use an identifier trained at dt = {rec.dt:g} s")
    v = rec.values
    if v.shape[-1] == steps:
        return
    if rec.columns or v.ndim == 1:
        raise _InputError(f"{option} file {rec.path!r} holds a record of {v.shape[-1]} samples; "
                          f"this identifier reads {grid}")
    raise _InputError(
        f"{option} file {rec.path!r} holds {v.shape[0]} rows of {v.shape[1]} values, read as "
        f"{v.shape[0]} records of {v.shape[1]} samples; this identifier reads {grid}. "
        "If its columns are t, u, y, name them in a header row (e.g. 't,y' or 't,u,y'); "
        "otherwise give one record per line or one number per line")


def _identify(args: argparse.Namespace) -> int:
    ident = _load_identifier(args.model, "model")
    R = ident.records
    steps = ident.steps if R > 1 else (ident.steps,)
    dts = ident.dt if R > 1 else (ident.dt,)
    grids = ", ".join(f"{s} samples at dt = {t:g} s" for s, t in zip(steps, dts, strict=True))
    if len(args.y) != R:
        raise _InputError(f"--y: this identifier reads {R} record{'s' if R > 1 else ''} "
                          f"(one file per record: {grids}); got {len(args.y)} file(s)")
    if args.u is not None and len(args.u) != R:
        raise _InputError(f"--u: give one input file per --y file ({R}); got {len(args.u)}")
    ys = [_read_record(f, "--y", "y") for f in args.y]
    us = [_read_record(f, "--u", "u") for f in args.u] if args.u else [None] * R
    for r in range(R):
        _on_grid(ys[r], "--y", steps[r], dts[r])
        if us[r] is not None:
            if ys[r].u is not None:
                raise _InputError(f"--u {us[r].path!r} and the u column of --y "
                                  f"{ys[r].path!r}: give the input once")
            _on_grid(us[r], "--u", steps[r], dts[r])
    inputs = [ys[r].u if us[r] is None else us[r].values for r in range(R)]
    y = ys[0].values if R == 1 else [rec.values for rec in ys]
    u = inputs[0] if R == 1 else (None if all(v is None for v in inputs) else inputs)
    refine = {"no": False, "yes": True, "auto": "auto"}[args.refine]
    try:
        est = ident.identify(y, u, refine=refine)
    except ValueError as err:   # the record's content (all zero, non-finite, a varying u, ...)
        raise _InputError(f"identify {', '.join(args.y)} with {args.model}: {err}") from None

    np.set_printoptions(precision=6, suppress=False)
    print(f"{ident!r}")
    print("A =\n", est.A)
    print("b =", est.b, " c =", est.c, " d =", est.d)
    if est.physical:
        print("physical:", {k: np.round(v, 6).tolist() for k, v in est.physical.items()})
    if est.refined:
        print("refined by the CasADi NLP" + (
            "" if "refined_rows" not in est.info or not est.batched
            else f" (records {np.flatnonzero(est.info['refined_rows']).tolist()})"))
    flagged = _self_check(est)
    if args.json:
        _write_json(args.json, _estimate_json(est, args.model, repr(ident)))
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
    return _plain({
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


def _plain(value):
    """``value`` as strict JSON: arrays as lists, non-finite numbers as null."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def _write_json(file: str, data: dict) -> None:
    path = Path(file)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(data, indent=2, allow_nan=False))
    except OSError as err:
        raise _InputError(f"--json {file!r}: cannot write ({err.strerror or err})") from None


def _track(args: argparse.Namespace) -> int:
    ident = _load_identifier(args.model, "--model")
    from aeid_struct.evaluation import wear
    from aeid_struct.online import TrackerConfig, wear_study

    try:
        config = TrackerConfig(hop=args.hop, smoothing=args.smoothing, median=args.median,
                               threshold=args.threshold,
                               baseline=args.baseline, patience=args.patience,
                               watch=tuple(args.watch))
        result = wear_study(ident, seconds=args.seconds, noise=args.noise, seed=args.seed,
                            config=config, engine=args.engine)
    except ValueError as err:
        raise _InputError(f"track: {err}") from None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    png = out / "wear_tracking.png"
    source = (f"identifier file {args.model}" if Path(args.model).exists()
              else f"shipped identifier {args.model}")
    wear(result, png, config=config,
         title=f"Wear scenario, {args.seconds:g} s, {100 * args.noise:g} % noise, seed "
               f"{args.seed}: {source}, {result.engine} engine")
    print(f"{ident!r}")
    print(f"wear scenario: {args.seconds:g} s, k 25 -> 20 N/m, d 2.5 -> 3.5 kg/s, m 1 kg, "
          f"{100 * args.noise:g} % noise, one window of {ident.steps} samples every {args.hop}")
    print("tracking error (RMS of the smoothed estimate, after the baseline windows): "
          + ", ".join(f"{p} {v:.2f} %" for p, v in result.rms.items()))
    print(f"true k left its start by {100 * args.threshold:g} % at {result.drift_time:.2f} s; "
          f"alarm at {result.alarm_time:.2f} s (delay {result.delay:.2f} s)")
    print(f"update (one window identified, {result.engine} engine): "
          f"{result.latency_ms:.3f} ms median, one call each")
    js = out / "wear_tracking.json"
    js.write_text(json.dumps({"rms_percent": result.rms, "drift_time_s": result.drift_time,
                              "alarm_time_s": result.alarm_time, "delay_s": result.delay,
                              "latency_ms": result.latency_ms, "engine": result.engine,
                              "windows": len(result.t)},
                             indent=2))
    print(f"wrote {png}, {js}")
    return 0


def _bench_online(args: argparse.Namespace) -> int:
    from aeid_struct.studies.bench_online import bench_online, format_tables

    print("Online identification (issue 6's targets), measured in one run on the shipped "
          "identifiers; errors against the noise-free truth:", flush=True)
    result = bench_online(quick=args.quick, seconds=args.seconds, noise=args.noise,
                          progress=not args.quiet)
    print()
    print(format_tables(result))
    t = result["targets"]
    print("Targets: update <= 0.5 ms | k within 2 % RMS at 1 % noise | alarm delay stated | "
          ">= 90 % flagged 30 % beyond the range with <= 5 % false flags")
    print(f"Measured: update {t['update_ms_median']:.3f} ms | k {t['k_rms_percent_mean']:.2f} % "
          f"RMS | alarm delay " + ", ".join(f"{d:+.1f} s" for d in t["alarm_delay_s"])
          + f" | flagged {100 * t['flagged_30_percent_beyond_min']:.1f} % with "
          f"{100 * t['false_flags_max']:.1f} % false")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float))
    print(f"wrote {out}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    import torch

    from aeid_struct.studies.bench import (
        bench_decoder,
        bench_identification,
        format_decoder_table,
        format_identification_table,
    )

    result = {}
    if not args.decoder_only:
        count = args.count or (20 if args.quick else 500)
        print(f"Identification of the robot-leg subsystems: {count} systems per subsystem and "
              f"noise level, one call per record, all methods on the same records "
              f"(noise-free truth as reference), {torch.get_num_threads()} torch thread(s):",
              flush=True)
        ident = bench_identification(count=count, noises=tuple(args.noise),
                                     progress=not args.quiet)
        print()
        print(format_identification_table(ident))
        result["identification"] = ident
    steps = (100, 300) if args.quick else tuple(args.steps)
    rows = []
    for dtype in (torch.float32, torch.float64):
        rows += bench_decoder(batch=args.batch, steps=steps, dtype=dtype, threads=args.threads)
    print(f"\nDecoder forward+backward, batch {args.batch}, {args.threads} thread(s):")
    print(format_decoder_table(rows))
    result["decoder"] = [_row_dict(r) for r in rows]
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2, default=float))
    print(f"wrote {out}")
    return 0


def _row_dict(row) -> dict:
    from dataclasses import asdict

    d = asdict(row)
    return {k: (str(v) if not isinstance(v, (int, float, str)) else v) for k, v in d.items()}


def build_parser() -> argparse.ArgumentParser:
    """The command's parser; building it and printing its help import neither torch nor CasADi.
    Every option carries help text (a test checks)."""
    # light (numpy only): the tracker's defaults are the CLI's
    from aeid_struct.online import TrackerConfig

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
    demo.set_defaults(func=_demo)

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
    legp.set_defaults(func=_leg)

    tr = sub.add_parser("train", help="train an identifier for a structure and a family",
                        description="Train an identifier (encoder + structure) on simulated "
                                    "records of a system family and write it as an .aeid file. "
                                    "TrainConfig checks the values and names any it refuses.")
    tr.add_argument("--structure", required=True,
                    help="the model structure: ccf:N[:descartes][:feedthrough] (controllable "
                         "canonical form of order N), mcf:REAL,PAIRS (modal form), leg-stable or "
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
    tr.add_argument("--out", required=True, help="identifier file to write (.aeid)")
    tr.add_argument("--quiet", action="store_true", help="no progress lines")
    tr.set_defaults(func=_train)

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
    for name, kind, text in (
            ("hop", int, "samples between identifications"),
            ("smoothing", float, "moving-average weight"),
            ("median", int, "window estimates in the running median before the moving average"),
            ("threshold", float, "relative drift that alarms"),
            ("baseline", int, "windows in the reference"),
            ("patience", int, "windows over the threshold")):
        trk.add_argument(f"--{name}", type=kind, default=getattr(tracker, name),
                         help=f"{text} (default {getattr(tracker, name)})")
    trk.add_argument("--watch", nargs="*", default=["k"],
                     help="parameters whose drift raises the alarm (default: k, the spring)")
    trk.add_argument("--seed", type=_number(int, 0, strict=False), default=0,
                     help="seed of the scenario (default 0)")
    trk.add_argument("--engine", choices=("auto", "onnx", "identifier"), default="auto",
                     help="onnx: the exported encoder under onnxruntime (auto: when installed)")
    trk.add_argument("--out", default="out/track", help="folder for the PNG and JSON")
    trk.set_defaults(func=_track)

    idp = sub.add_parser(
        "identify", help="identify a system from a record file, with the identifier's "
                         "self-check (fit, excess, inside or outside its training range)",
        description="Identify a system from a record file with a trained identifier and print "
                    "the model, its physical parameters and the self-check: each record's fit "
                    "(NRMSE %), its excess beyond the training range, and the verdict (inside "
                    "or OUTSIDE the training range).",
        epilog=RECORD_LAYOUTS + "\n\n"
        f"Exit status: 0 done; {EXIT_INPUT} a usage or input error; {EXIT_OUTSIDE} an estimate "
        "is flagged OUTSIDE the training range (a WARNING line on stderr; the estimate is still "
        "printed and written): the record is unlike the identifier's training records, e.g. "
        "sampled at another dt, and its parameters cannot be trusted. --allow-outside accepts "
        "it (status 0, the WARNING stays).")
    idp.add_argument("model", help=f"an identifier file (.aeid) or a shipped name: {names}")
    idp.add_argument("--y", required=True, nargs="+",
                     help="output record file(s), .npy or .csv (layouts below); one file per "
                          "record (subsystem) for a joint identifier")
    idp.add_argument("--u", default=None, nargs="+",
                     help="input record file(s), like --y; default: the u column of the --y "
                          "file, else a unit step")
    idp.add_argument("--refine", choices=("no", "yes", "auto"), nargs="?", const="yes",
                     default="no",
                     help="polish with the CasADi NLP: yes (also plain --refine), auto (only the "
                          "estimates flagged outside the training range), no (default)")
    idp.add_argument("--allow-outside", action="store_true",
                     help=f"exit 0 even when an estimate is flagged outside the training range "
                          f"(default: exit {EXIT_OUTSIDE}); the WARNING is printed either way")
    idp.add_argument("--json", default=None,
                     help="write the estimate as JSON, with fit_percent, excess, outside and the "
                          "thresholds")
    idp.set_defaults(func=_identify)

    bench = sub.add_parser(
        "bench", help="accuracy and speed of the encoder, refinement and classical baselines, "
                      "and decoder timings, measured side by side; prints and writes JSON")
    bench.add_argument("--quick", action="store_true", help="20 systems, short decoder table")
    bench.add_argument("--count", type=_POSITIVE_INT, default=None,
                       help="systems per subsystem and noise level (default 500)")
    bench.add_argument("--noise", type=_FRACTION, nargs="+", default=[0.0, 0.01, 0.05],
                       help="noise levels, std relative to max|y| (default 0 0.01 0.05)")
    bench.add_argument("--decoder-only", action="store_true", help="only the decoder timings")
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
    bench.set_defaults(func=_bench)

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
    bon.set_defaults(func=_bench_online)
    return parser


#: Subcommands that write figures (matplotlib is imported, with the file-only Agg backend).
_PLOTTING = ("demo", "leg", "track", "bench", "bench-online")


def _check_outputs(args: argparse.Namespace) -> None:
    """Refuse an output path of the wrong kind before any work: --out of demo, leg and track is
    a folder, a --json file is not one."""
    if args.command in ("demo", "leg", "track") and Path(args.out).exists() \
            and not Path(args.out).is_dir():
        raise _InputError(f"{args.command}: --out {args.out!r} is a file; expected a folder for "
                          "the figures and JSON")
    if getattr(args, "json", None) and Path(args.json).is_dir():
        raise _InputError(f"{args.command}: --json {args.json!r} is a folder; expected the JSON "
                          "file to write")


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the exit status (0, or ``EXIT_OUTSIDE``). A usage or input
    error is printed as one line on stderr and raises ``UsageExit`` (status ``EXIT_INPUT``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
        args.argv = argv
        _check_outputs(args)
        if args.command in _PLOTTING:
            import matplotlib

            matplotlib.use("Agg")   # the CLI only writes PNG files
        return args.func(args)
    except _InputError as err:
        message = _one_line(err)
        print(f"aeid-struct: error: {message}", file=sys.stderr)
        raise UsageExit(message) from None


if __name__ == "__main__":
    sys.exit(main())
