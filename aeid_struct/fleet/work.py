"""What one worker does with one chunk: read its records, identify them as one batch with a
trained identifier, and write the chunk's rows as one Parquet file, atomically (a part exists
whole or not at all, which is what makes a run resumable).

The table, one row per record (the long schema: every model a row, any ``n, m, p``):

========== ============ ====================================================================
column     type         meaning
========== ============ ====================================================================
record     string       ``FILE#INDEX``: the file (relative to the source) and its row
status     string       ``"ok"``, or ``"refused"`` (the record, or its file, could not be
                        identified)
reason     string       why it was refused (null where ok)
n, m, p    int32        order, inputs, outputs of the model
A          list<double> ``A (n, n)`` row-major, in the record's time unit
B          list<double> ``B (n, m)`` row-major
C          list<double> ``C (p, n)`` row-major
D          list<double> ``D (p, m)`` row-major
fit        double       the identifier's self-check: NRMSE fit in % on the record
outside    bool         flagged outside the identifier's training range
excess     double       how far beyond the training range (0 inside)
elements   list<double> the structure's elements (names in the file's metadata)
physical   list<double> physical parameters where the identifier has an inverse map (names
                        in the metadata), else empty
========== ============ ====================================================================

A refused record's model columns are empty lists and its numbers NaN. The file metadata
(``aeid``, JSON) holds the identifier, the element and physical names, the chunk and the
schema's version.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from aeid_struct.fleet.sources import Chunk, read_chunk

__all__ = ["SCHEMA", "identify_chunk", "part_path"]

#: The table's version, in every part's metadata.
SCHEMA = 1


#: A worker's identifiers, read once each: by name and the SHA-256 of the maps given with it.
_LOADED: dict = {}


def _identifier(name: str, maps: dict | None):
    """A worker reads each identifier once (a shipped name or a file: data only)."""
    from aeid_struct.loading import load
    from aeid_struct.structures import sha256

    key = (name, tuple(sorted((k, sha256(f)) for k, f in (maps or {}).items())))
    if key not in _LOADED:
        _LOADED[key] = load(name, maps=maps)
    return _LOADED[key]


def _arrow_schema():
    """The module docstring's table as a pyarrow schema: every part has the same (a part whose
    records are all fine would otherwise get a null ``reason`` column)."""
    import pyarrow as pa

    floats = pa.list_(pa.float64())
    return pa.schema([("record", pa.string()), ("status", pa.string()),
                      ("reason", pa.string()), ("n", pa.int32()), ("m", pa.int32()),
                      ("p", pa.int32()), ("A", floats), ("B", floats), ("C", floats),
                      ("D", floats), ("fit", pa.float64()), ("outside", pa.bool_()),
                      ("excess", pa.float64()), ("elements", floats), ("physical", floats)])


def part_path(out: Path, c: Chunk) -> Path:
    """The part file of a chunk in the output directory (a name from the chunk's key)."""
    safe = c.key.replace(os.sep, "__").replace("/", "__")
    return Path(out) / f"part-{safe}.parquet"


def _lists(x: np.ndarray, ok: np.ndarray):
    """A ``list<double>`` column of ``x (records, ...)``, each row flattened where ``ok``, empty
    where not: one offsets array over the flat values (a per-row Python list cost a third of a
    chunk's time)."""
    import pyarrow as pa

    width = int(np.prod(x.shape[1:]))
    offsets = np.concatenate([[0], np.cumsum(np.where(ok, width, 0))]).astype(np.int32)
    values = np.ascontiguousarray(x[ok], dtype=np.float64).reshape(-1)
    return pa.ListArray.from_arrays(pa.array(offsets), pa.array(values))


def _rows(est, names: list) -> dict:
    """The table's columns of a batched estimate (model columns empty, numbers NaN where
    refused)."""
    A = np.asarray(est.A, dtype=np.float64)
    count, n = A.shape[0], A.shape[1]
    b = np.asarray(est.b, dtype=np.float64).reshape(count, n, -1)
    c = np.asarray(est.c, dtype=np.float64).reshape(count, -1, n)
    m, p = b.shape[2], c.shape[1]
    d = np.asarray(est.d, dtype=np.float64).reshape(count, p, m)
    errors = est.errors if est.errors is not None else (None,) * count
    ok = np.array([e is None for e in errors])
    elements = np.stack([np.asarray(v, dtype=np.float64).reshape(count)
                         for v in est.elements.values()], 1)
    physical = est.physical
    phys = (np.stack([np.asarray(v, dtype=np.float64).reshape(count)
                      for v in physical.values()], 1) if physical else np.zeros((count, 0)))
    return {
        "record": names, "status": np.where(ok, "ok", "refused"),
        "reason": [None if e is None else str(e) for e in errors],
        "n": np.full(count, n, dtype=np.int32), "m": np.full(count, m, dtype=np.int32),
        "p": np.full(count, p, dtype=np.int32),
        "A": _lists(A, ok), "B": _lists(b, ok), "C": _lists(c, ok), "D": _lists(d, ok),
        "fit": np.where(ok, np.asarray(est.fit, dtype=np.float64), np.nan),
        "outside": np.asarray(est.outside, dtype=bool),
        "excess": np.asarray(est.excess, dtype=np.float64),
        "elements": _lists(elements, ok), "physical": _lists(phys, ok),
    }


def _refused_rows(names: list, reason: str) -> dict:
    count = len(names)
    zero = np.zeros(count, dtype=np.int32)
    empty = _lists(np.zeros((count, 0)), np.zeros(count, dtype=bool))
    return {"record": names, "status": np.full(count, "refused"), "reason": [reason] * count,
            "n": zero, "m": zero, "p": zero,
            "A": empty, "B": empty, "C": empty, "D": empty, "fit": np.full(count, np.nan),
            "outside": np.ones(count, dtype=bool), "excess": np.full(count, np.inf),
            "elements": empty, "physical": empty}


def identify_chunk(identifier: str, c: Chunk, out, source_root: str,
                   maps: dict | None = None) -> dict:
    """Identify one chunk's records and write its part (the module docstring's table).

    Parameters
    ----------
    identifier : str
        A shipped identifier's name or an identifier file (``aeid_struct.load``).
    c : Chunk
    out : str or PathLike
        The output directory.
    source_root : str
        The source the chunks came from (records are named relative to it).
    maps : dict str -> casadi.Function, optional
        The user maps the identifier file names (``aeid_struct.load``).

    Returns
    -------
    dict
        ``{"key", "records", "ok"}``.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    ident = _identifier(identifier, maps)
    root = Path(source_root)
    rel = str(Path(c.path).relative_to(root)) if root.is_dir() else Path(c.path).name
    meta = {"schema": SCHEMA, "identifier": identifier, "chunk": c.key,
            "elements": list(ident.structure.element_names),
            "physical": []}        # the estimate's names, where it has physical parameters
    names = None
    try:
        y, u, dt = read_chunk(c)
        names = [f"{rel}#{c.start + i}" for i in range(y.shape[0])]
        est = ident.identify(y, u, dt=dt, errors="collect")
        columns = _rows(est, names)
        if est.physical:
            meta["physical"] = list(est.physical)
    except ValueError as err:
        # the whole chunk's file is unreadable, or a malformed batch: every record says why
        # (as many rows as were read; a file that could not be read or sized is one row)
        if names is None:
            names = [f"{rel}#{c.start + i}" for i in range(max((c.stop or 1) - c.start, 1))]
        columns = _refused_rows(names, str(err))
    table = pa.table(columns, schema=_arrow_schema()).replace_schema_metadata(
        {"aeid": json.dumps(meta)})
    path = part_path(out, c)
    # a hidden name: a worker killed while writing leaves it behind, and readers of the
    # directory (pyarrow, pandas, Dask) skip names that start with "." instead of failing on it
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    pq.write_table(table, tmp)
    os.replace(tmp, path)          # atomic: a part is whole or absent
    return {"key": c.key, "records": len(columns["record"]),
            "ok": int(np.sum(np.asarray(columns["status"]) == "ok"))}
