"""Where a fleet's records come from: a directory of record files, cut into chunks of at most
``chunk`` records that a worker reads and identifies alone.

Files (read as data only: ``allow_pickle=False``, Parquet's own columns):

- ``.npy``: ``y``, a ``(steps,)`` array (one record) or ``(batch, steps)``; read by memory map,
  so a chunk reads its own rows only;
- ``.npz``: arrays ``y`` and, optionally, ``u`` of the same shape (read whole by each of its
  chunks: an archive's members cannot be mapped; a large data set is better as ``.npy``);
- ``.parquet``: a table of records, a row each: a list column ``y``, optionally ``u`` (each
  chunk reads only the row groups that hold its rows);
- ``.csv``: the layouts ``aeid-struct identify`` reads (``records.files``): named columns
  ``t, u, y`` (one record, its ``t`` column's sample time checked against the identifier's),
  one number per line (one record) or one record per line (a batch); a file is one chunk,
  parsed by its worker alone (a CSV is a record or a few, not a data set's bulk).

Records are named ``FILE#INDEX`` (``INDEX`` the row within the file, from 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aeid_struct.records.files import load_numpy

__all__ = ["FORMATS", "Chunk", "chunks", "read_chunk"]

#: File suffixes read as records.
FORMATS = (".npy", ".npz", ".parquet", ".csv")


@dataclass(frozen=True)
class Chunk:
    """Records ``start .. stop - 1`` of one file.

    Attributes
    ----------
    path : str
        The file.
    start : int
    stop : int or None
        None: a file read whole by the worker (a CSV, or a file that could not be sized, whose
        worker reports why).
    key : str
        ``RELPATH@START``: the chunk's name, and its part's.
    """

    path: str
    start: int
    stop: int | None
    key: str


def _count(path: Path) -> int | None:
    """Records in a file, from its header or metadata alone where the format allows; None for
    a CSV, which only parsing would size: it is one chunk, parsed once, by its worker (a fleet
    of many small CSV files is cut into chunks without reading one)."""
    if path.suffix == ".csv":
        return None
    if path.suffix == ".npy":
        shape = load_numpy(path, mmap_mode="r").shape
        return 1 if len(shape) == 1 else shape[0]
    if path.suffix == ".npz":
        with load_numpy(path) as archive:
            shape = archive["y"].shape
        return 1 if len(shape) == 1 else shape[0]
    import pyarrow.parquet as pq

    return pq.ParquetFile(path).metadata.num_rows


def chunks(source, chunk: int = 10_000) -> list[Chunk]:
    """The chunks of every record file under ``source`` (a directory, searched recursively, or
    one file), in a stable order: files by path, records in order.

    Parameters
    ----------
    source : str or PathLike
    chunk : int, >= 1
        Records per chunk at most.

    Returns
    -------
    list of Chunk
        A file that cannot be sized (unreadable, no ``y``) is one chunk of unknown length: its
        worker reports the reason as the file's one row.

    Raises
    ------
    ValueError
        ``source`` is neither a directory nor a record file, or holds none; ``chunk`` < 1.
    """
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"chunk must be an integer >= 1 (records per task); got {chunk!r}")
    root = Path(source)
    if root.is_file():
        files = [root]
    elif root.is_dir():
        files = sorted(p for p in root.rglob("*") if p.is_file() and p.suffix in FORMATS)
    else:
        raise ValueError(f"source {str(source)!r} is neither a directory nor a file")
    if not files:
        raise ValueError(f"source {str(source)!r} holds no record files ({', '.join(FORMATS)})")
    out = []
    for path in files:
        rel = str(path.relative_to(root)) if root.is_dir() else path.name
        try:
            count = _count(path)
        except Exception:           # any unreadable file: its worker says why
            count = None
        if count is None:
            out.append(Chunk(str(path), 0, None, f"{rel}@0"))
            continue
        out += [Chunk(str(path), s, min(s + chunk, count), f"{rel}@{s}")
                for s in range(0, count, chunk)]
    return out


def read_chunk(c: Chunk) -> tuple[np.ndarray, np.ndarray | None, float | None]:
    """The records of a chunk: ``y (records, steps)``, ``u`` alike or None, and the sample time
    a CSV's ``t`` column gives (None for the other formats and a CSV without one).

    Raises
    ------
    ValueError
        The file cannot be read as records (named in the message).
    """
    path = Path(c.path)
    stop = c.stop
    dt = None
    try:
        if path.suffix == ".npy":
            y = load_numpy(path, mmap_mode="r")
            y, u = np.atleast_2d(y)[c.start:stop], None
        elif path.suffix == ".npz":
            with load_numpy(path) as archive:
                y = np.atleast_2d(archive["y"])[c.start:stop]
                u = np.atleast_2d(archive["u"])[c.start:stop] if "u" in archive else None
        elif path.suffix == ".csv":
            y, u, dt = _read_csv(path)
            y, u = y[c.start:stop], None if u is None else u[c.start:stop]
        else:
            y, u = _read_parquet(path, c.start, stop)
    except Exception as err:        # the reason becomes the file's row
        raise ValueError(f"{path.name} cannot be read as records ({type(err).__name__}: "
                         f"{err})") from None
    y = np.asarray(y, dtype=np.float64)
    if y.ndim != 2 or (u is not None and np.shape(u) != y.shape):
        raise ValueError(f"{path.name} holds y of shape {y.shape}"
                         + ("" if u is None else f" and u of shape {np.shape(u)}")
                         + "; expected y (records, steps) and u alike")
    return y, None if u is None else np.asarray(u, dtype=np.float64), dt


def _read_parquet(path: Path, start: int, stop: int | None):
    """Rows ``start .. stop - 1`` of a Parquet table of records: only the row groups that hold
    them, only the ``y`` and ``u`` columns (each chunk of a large file reads its own part)."""
    import pyarrow.parquet as pq

    file = pq.ParquetFile(path)
    meta = file.metadata
    stop = meta.num_rows if stop is None else stop
    ends = np.cumsum([meta.row_group(i).num_rows for i in range(meta.num_row_groups)])
    groups = [i for i, end in enumerate(ends) if end > start and end - meta.row_group(i).num_rows
              < stop]
    first = int(ends[groups[0]] - meta.row_group(groups[0]).num_rows) if groups else 0
    columns = [n for n in ("y", "u") if n in file.schema_arrow.names]
    rows = file.read_row_groups(groups, columns=columns).slice(start - first, stop - start)
    y = np.array(rows.column("y").to_pylist(), dtype=np.float64)
    u = (np.array(rows.column("u").to_pylist(), dtype=np.float64)
         if "u" in rows.column_names else None)
    return y, u


def _read_csv(path: Path) -> tuple[np.ndarray, np.ndarray | None, float | None]:
    """A CSV of records (``records.files``): ``y (records, steps)``, ``u`` alike or None, and
    its ``t`` column's sample time; a file of several outputs or inputs is refused (the
    fleet's identifiers read one channel)."""
    from aeid_struct.records.files import read_record

    rec = read_record(str(path), "source", "y")
    if rec.several:
        raise ValueError("it holds several outputs or inputs (numbered columns); identify-many "
                         "runs trained identifiers of one output and one input")
    y = np.atleast_2d(rec.values)
    return y, None if rec.u is None else np.atleast_2d(rec.u), rec.dt
