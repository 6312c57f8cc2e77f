"""What the ``identify`` subcommands write: their results as strict JSON (``--json``)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from aeid_struct.cli.errors import InputError

__all__ = ["plain", "write_json"]


def plain(value):
    """``value`` as strict JSON: arrays as lists, non-finite numbers as null.

    Parameters
    ----------
    value : object
        Dicts, lists, tuples, numpy arrays and scalars, str, None.

    Returns
    -------
    object
        The same data in JSON's types.
    """
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def write_json(file: str, data: dict) -> None:
    """Write ``data`` (strict JSON, :func:`plain`) to ``file``, creating its folder.

    Parameters
    ----------
    file : str
        The ``--json`` file.
    data : dict

    Raises
    ------
    InputError
        The file cannot be written.
    """
    path = Path(file)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(data, indent=2, allow_nan=False))
    except OSError as err:
        raise InputError(f"--json {file!r}: cannot write ({err.strerror or err})") from None
