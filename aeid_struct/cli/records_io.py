"""Record files of ``aeid-struct identify``: ``.npy`` arrays and CSV layouts, read and checked
against an identifier's record grid (``RECORD_LAYOUTS`` describes them)."""

from __future__ import annotations

import math

from aeid_struct.cli.errors import InputError, one_line
from aeid_struct.records.files import RECORD_LAYOUTS as RECORD_LAYOUTS
from aeid_struct.records.files import RecordFile as RecordFile
from aeid_struct.records.files import read_record as read_file


def check_dt(rec: RecordFile, option: str, dt: float, reads: str) -> None:
    """Check a record file's t column (where it has one) against an identifier's sample time.

    Parameters
    ----------
    rec : RecordFile
    option : str
        The option that named the file, for the errors.
    dt : float
        The identifier's sample time [s].
    reads : str
        What the identifier reads (``"records of 300 samples at dt = 0.01 s"``), for the errors.

    Raises
    ------
    InputError
        The t column is sampled at another ``dt`` (relative ``1e-4``).
    """
    if rec.dt is not None and not math.isclose(rec.dt, dt, rel_tol=1e-4):
        raise InputError(f"{option} file {rec.path!r}: its t column is sampled every "
                         f"{rec.dt:g} s; this identifier reads {reads}: resample the record, "
                         f"or use an identifier trained at dt = {rec.dt:g} s")


def on_grid(rec: RecordFile, option: str, steps: int, dt: float) -> None:
    """Check a record file against an identifier's grid, with a hint on the layouts where the
    file's shape suggests a misread.

    Parameters
    ----------
    rec : RecordFile
        What :func:`read_record` read.
    option : str
        The option that named the file, for the errors.
    steps : int
        Samples per record the identifier reads.
    dt : float
        Its sample time [s].

    Raises
    ------
    InputError
        The record's length, or its t column's sample time, is not the identifier's.
    """
    grid = f"records of {steps} samples at dt = {dt:g} s"
    check_dt(rec, option, dt, grid)
    v = rec.values
    if rec.several:
        # numbered columns: one record of several channels, (steps, p)
        if v.shape[0] != steps:
            raise InputError(f"{option} file {rec.path!r} holds a record of {v.shape[0]} "
                             f"samples; this identifier reads {grid}")
        return
    if v.shape[-1] == steps:
        return
    if rec.columns or v.ndim == 1:
        raise InputError(f"{option} file {rec.path!r} holds a record of {v.shape[-1]} samples; "
                         f"this identifier reads {grid}")
    raise InputError(
        f"{option} file {rec.path!r} holds {v.shape[0]} rows of {v.shape[1]} values, read as "
        f"{v.shape[0]} records of {v.shape[1]} samples; this identifier reads {grid}. "
        "If its columns are t, u, y, name them in a header row (e.g. 't,y' or 't,u,y'); "
        "otherwise give one record per line or one number per line")


def read_record(file: str, option: str, channel: str) -> RecordFile:
    """Read one record file given to ``option`` for ``channel`` (``records.files.read_record``;
    layouts: ``RECORD_LAYOUTS``).

    Parameters
    ----------
    file : str
    option : str
        The option that named it (``"--y"`` or ``"--u"``), for the errors.
    channel : str
        ``"y"`` or ``"u"``.

    Returns
    -------
    RecordFile

    Raises
    ------
    InputError
        The file is missing, a folder, unreadable, or not one of the layouts.
    """
    try:
        return read_file(file, option, channel)
    except ValueError as err:
        raise InputError(one_line(err)) from None
