"""Record files read as data: ``.npy`` arrays (``allow_pickle=False``) and CSV layouts (named
columns ``t, u, y``, numbered ``u1, u2, y1, ...``, one number or one record per line), one reading
for the command line (``aeid-struct identify``, ``track``) and the fleet's CSV sources
(``fleet.sources``). Errors are ValueErrors that name the file and what was expected, prefixed
by the caller's label (the option or the source that named the file); the command line prints
them on one line (``cli.errors.one_line``)."""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["RECORD_LAYOUTS", "RecordFile", "load_numpy", "read_record"]

#: The record layouts ``identify`` reads (its --help and its hints show this text).
RECORD_LAYOUTS = (
    "Record files: .npy (a (steps,) array, or (batch, steps) for a batch of records) or CSV "
    "(comma-separated numbers): one number per line (one record), one record per line (a "
    "batch), or named columns under a header row, e.g. 't,y' or 't,u,y' (names t/time, "
    "u/input, y/output, units after the name allowed: 't [s]'; several inputs or outputs "
    "numbered from 1: 't,u1,u2,y1,y2', for the generic identifiers). A --y file needs a y "
    "column and may carry u (the input) and t (its sample time is checked against the "
    "identifier's). A header over a single column is skipped. Lines starting with # are "
    "comments."
)

#: CSV header names -> the channel they name.
_COLUMN_NAMES = {"t": "t", "time": "t", "u": "u", "input": "u", "y": "y", "output": "y"}


@dataclass(frozen=True)
class RecordFile:
    """What one record file holds.

    Attributes
    ----------
    path : str
        The file as it was named (on the command line, or in a fleet's source).
    values : (steps,) or (batch, steps) array, or (steps, p) for numbered columns
        The record(s) of the channel asked for; numbered columns (``y1, y2, ...``): one record
        of ``p`` channels (:attr:`several`).
    u : (steps,) or (steps, m) array, or None
        The input, from named u columns of a --y file (one record per file).
    dt : float or None
        The sample time of a named t column [s].
    columns : bool
        Whether the file was read from named columns (one record per file).
    t0 : float or None
        The time of the first sample, from a named t column [s].
    several : bool
        Whether numbered columns gave several outputs or inputs (``values`` then one record of
        shape (steps, p), ``u`` (steps, m)).
    """

    path: str
    values: np.ndarray
    u: np.ndarray | None = None
    dt: float | None = None
    columns: bool = False
    t0: float | None = None
    several: bool = False


def load_numpy(path, *, mmap_mode: str | None = None):
    """``numpy.load`` of a record file as data: pickles and object arrays are refused, never
    loaded (``allow_pickle=False``), and where numpy's own message for a file it takes for a
    pickle suggests loading it unsafely, the reason says instead what the file is not.

    Parameters
    ----------
    path : str or Path
        An ``.npy`` or ``.npz`` file.
    mmap_mode : {None, "r"}
        As ``numpy.load``'s.

    Returns
    -------
    ndarray or NpzFile

    Raises
    ------
    ValueError
        The file is not an array of numbers (the reason in the message).
    """
    try:
        return np.load(path, mmap_mode=mmap_mode, allow_pickle=False)
    except (ValueError, OSError, EOFError) as err:
        reason = str(err)
        if "unsafely" in reason:
            # numpy takes any file without the .npy or .zip magic for a pickle and advises
            # loading it unsafely: a record file is data, never code
            reason = ("neither an .npy array nor an .npz archive: not loaded, as a pickle "
                      "never is")
        raise ValueError(reason) from None


def _read_npy(path: Path, option: str) -> np.ndarray:
    try:
        arr = load_numpy(path)
    except ValueError as err:
        raise ValueError(f"{option} file {str(path)!r} is not a numeric .npy array "
                         f"({err})") from None
    if not isinstance(arr, np.ndarray):
        raise ValueError(f"{option} file {str(path)!r} is an .npz archive; expected one .npy "
                         "array")
    if arr.dtype.kind == "c":
        raise ValueError(f"{option} file {str(path)!r} holds complex values ({arr.dtype}); "
                         "expected real numbers")
    if arr.dtype.kind not in "iuf":
        raise ValueError(f"{option} file {str(path)!r} holds {arr.dtype} values; expected a "
                         "numeric (float or integer) array")
    if arr.ndim not in (1, 2) or arr.size == 0:
        raise ValueError(f"{option} file {str(path)!r} holds an array of shape {arr.shape}; "
                         "expected (steps,) or (batch, steps)")
    return arr.astype(np.float64)


def _column_name(cell: str) -> tuple[str, int] | None:
    """A header cell's channel and its number: ``'y [m]'`` is ``("y", 0)``, ``'u2'`` and
    ``'u_2 [V]'`` are ``("u", 2)`` (numbers from 1; 0 for an unnumbered column); None when
    unknown."""
    word = re.match(r"([a-z]+)(?:_?([0-9]+))?(?![a-z0-9_])", cell.strip().lower())
    if not word or word.group(1) not in _COLUMN_NAMES:
        return None
    number = int(word.group(2)) if word.group(2) else 0
    if word.group(2) and (number < 1 or _COLUMN_NAMES[word.group(1)] == "t"):
        return None
    return _COLUMN_NAMES[word.group(1)], number


def _read_csv(path: Path, option: str) -> tuple[np.ndarray, list[str] | None]:
    """The numbers of a CSV as ``(rows, columns)``, and its header cells (None without one)."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            lines = [(i, row) for i, row in enumerate(csv.reader(fh), 1)
                     if row and "".join(row).strip() and not row[0].lstrip().startswith("#")]
    except UnicodeDecodeError:
        raise ValueError(f"{option} file {str(path)!r} is not a text CSV file (nor .npy)") \
            from None
    except (OSError, csv.Error) as err:
        raise ValueError(f"{option} file {str(path)!r} cannot be read ({err})") \
            from None
    if not lines:
        raise ValueError(f"{option} file {str(path)!r} holds no numbers")
    header = None
    if not all(_is_number(c) for c in lines[0][1]):
        header = [c.strip() for c in lines[0][1]]
        lines = lines[1:]
        if not lines:
            raise ValueError(f"{option} file {str(path)!r} holds a header row and no numbers")
    width = len(header) if header is not None else len(lines[0][1])
    rows = []
    for i, row in lines:
        if len(row) != width:
            raise ValueError(f"{option} file {str(path)!r}: line {i} holds {len(row)} values; "
                             f"expected {width} like the {'header' if header else 'first line'}")
        for j, cell in enumerate(row, 1):
            if not _is_number(cell):
                raise ValueError(f"{option} file {str(path)!r}: line {i}, column {j} is "
                                 f"{cell.strip()!r}; expected a number")
        rows.append([float(c) for c in row])
    return np.array(rows, dtype=np.float64), header


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def read_record(file: str, option: str, channel: str) -> RecordFile:
    """Read one record file given to ``option`` for ``channel`` (layouts: ``RECORD_LAYOUTS``).

    Parameters
    ----------
    file : str
        A ``.npy`` or CSV file.
    option : str
        What named it, the errors' prefix (the command line's ``"--y"``, a fleet's
        ``"source"``).
    channel : str
        ``"y"`` or ``"u"``: the named column to read from a CSV file with a header.

    Returns
    -------
    RecordFile

    Raises
    ------
    ValueError
        The file is missing, a folder, unreadable, or not one of the layouts.
    """
    path = Path(file)
    if path.is_dir():
        raise ValueError(f"{option}: {file!r} is a folder; expected a .npy or .csv record file")
    if not path.is_file():
        raise ValueError(f"{option}: file not found: {file!r}; expected a .npy or .csv record "
                         "file")
    if path.suffix.lower() == ".npy":
        return RecordFile(file, _read_npy(path, option))
    table, header = _read_csv(path, option)
    if header is None:
        # one column is one record; one row too; several rows of several values are a batch
        values = table[:, 0] if table.shape[1] == 1 else (table[0] if len(table) == 1
                                                            else table)
        return RecordFile(file, values)
    names = [_column_name(c) for c in header]
    if len(header) == 1:
        if names[0] is not None and names[0][0] != channel:
            raise ValueError(f"{option} file {file!r} holds one column named {header[0]!r}; "
                             f"expected {channel} (or an unnamed column)")
        return RecordFile(file, table[:, 0])
    unknown = [h for h, n in zip(header, names, strict=True) if n is None]
    twice = sorted({f"{n[0]}{n[1] or ''}" for n in names if n is not None
                    and names.count(n) > 1})
    if unknown or twice:
        raise ValueError(f"{option} file {file!r} has the header {','.join(header)!r}; "
                         f"expected columns named t, u, y (each once, or u1, u2, ... and y1, "
                         f"y2, ... for several), e.g. 't,u,y'"
                         + (f"; {', '.join(map(repr, unknown))} is not one of them"
                             if unknown else f"; {', '.join(twice)} named twice"))
    column = {kind: _channels(table, names, kind, file, option) for kind in ("t", "u", "y")}
    if column[channel] is None:
        raise ValueError(f"{option} file {file!r} has the columns {','.join(header)!r} but no "
                         f"{channel} column")
    t = column["t"]
    several = any(v is not None and v.ndim == 2 for v in column.values())
    return RecordFile(file, column[channel], u=column["u"] if channel == "y" else None,
                      dt=_sample_time(t, file, option) if t is not None else None,
                      columns=True, t0=float(t[0]) if t is not None else None,
                      several=several)


def _channels(table: np.ndarray, names: list, kind: str, file: str,
              option: str) -> np.ndarray | None:
    """The columns of one channel kind: None, one (steps,) column, or (steps, k) for numbered
    columns ``1..k`` (each number once, none missing, not mixed with an unnumbered one)."""
    found = {n[1]: j for j, n in enumerate(names) if n is not None and n[0] == kind}
    if not found:
        return None
    if set(found) == {0}:
        return table[:, found[0]]
    if 0 in found or sorted(found) != list(range(1, len(found) + 1)):
        raise ValueError(f"{option} file {file!r}: the {kind} columns are numbered "
                         f"{sorted(found)}; expected one unnumbered {kind} column, or {kind}1.."
                         f"{kind}k numbered from 1 without gaps")
    return table[:, [found[k] for k in range(1, len(found) + 1)]]


def _sample_time(t: np.ndarray, file: str, option: str) -> float | None:
    """The sample time of a t column, which must be evenly spaced."""
    if len(t) < 2:
        return None
    steps = np.diff(t)
    dt = (t[-1] - t[0]) / (len(t) - 1)
    # 1e-3 relative: a t column printed with a few digits is still read as even
    if not dt > 0 or np.max(np.abs(steps - dt)) > 1e-3 * dt:
        raise ValueError(f"{option} file {file!r}: the t column must increase in equal steps "
                         f"(one record sampled every dt); got steps from {steps.min():g} to "
                         f"{steps.max():g} s")
    return float(dt)
