"""One ``load`` for every identifier the library writes or ships (:func:`load`).

It reads the kind from the file's header (the one container, ``identification.container``) and
hands the file to that kind's reader: a leg (structured) ``Identifier`` (from its weights, or
from an ONNX export on its ONNX back end) or a ``generic.GenericIdentifier``; every older format
still reads. A shipped name (``"leg-stable"``, ``"generic-2"``) loads the shipped file. Whatever
it returns answers the identifier protocol, ``identify(record) -> Estimate``.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["load"]


def load(source, *, maps: dict | None = None, trust: bool = False, threads: int = 1):
    """Read an identifier file of any kind, or a shipped identifier by name.

    Parameters
    ----------
    source : str or PathLike
        A shipped name (``identification.PRETRAINED``, ``generic.GENERIC``), an ``.aeid``
        file (a leg or a generic identifier) or an ``.onnx`` export.
    maps : dict name -> casadi.Function, optional
        User maps the file names, passed again (``Identifier.load``, ``Identifier.from_onnx``).
    trust : bool
        Deserialise user maps from the file itself: only for files you trust
        (``Identifier.load``).
    threads : int
        onnxruntime's intra-op threads, for an ONNX export.

    Returns
    -------
    Identifier or GenericIdentifier
        An export is an ``Identifier`` whose ``backend`` is ONNX. Each answers
        ``identify(record) -> Estimate`` (``identification.Identifies``).

    Raises
    ------
    ValueError
        Naming the file and what is wrong: not an existing file, not an aeid-struct file, a
        kind or format this version does not read, or what the kind's reader refuses.
    """
    from aeid_struct.generic import GENERIC, load_generic, read_generic
    from aeid_struct.identification import (
        PRETRAINED,
        Identifier,
        kind_of,
        load_pretrained,
        read_safetensors,
    )

    if isinstance(source, str) and source in PRETRAINED:
        return load_pretrained(source)
    if isinstance(source, str) and source in GENERIC:
        return load_generic(source)
    if not isinstance(source, (str, os.PathLike)) or not str(source):
        raise ValueError(f"source must be a shipped identifier's name ({', '.join(PRETRAINED)}, "
                         f"{', '.join(GENERIC)}) or the path of an identifier file; got "
                         f"{source!r}")
    path = Path(source)
    if not path.is_file():
        raise ValueError(f"source must be a shipped identifier's name or an existing "
                         f"identifier file; got {str(path)!r}"
                         + (" (a directory)" if path.is_dir() else ""))
    if not _safetensors(path):
        return Identifier.from_onnx(path, threads, maps=maps, trust=trust)
    header, _, where = read_safetensors(path, "identifier")
    kind = kind_of(header, where)
    if kind == "generic":
        return read_generic(path)
    if kind == "identifier":
        return Identifier.load(path, maps=maps, trust=trust)
    raise ValueError(f"{where} says kind {kind!r} but is a safetensors file; an ONNX export is "
                     f"an ONNX model")


def _safetensors(path: Path) -> bool:
    """Whether the file is laid out as safetensors: an 8-byte little-endian header length, then
    the JSON header's ``{`` (an ONNX model is a protobuf, whose first byte is a field tag)."""
    with path.open("rb") as f:
        start = f.read(9)
    return len(start) == 9 and start[8:9] == b"{"
