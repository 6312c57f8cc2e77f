"""The one file container of every identifier kind: a JSON header that says which kind it holds.

Every file the library writes carries the header ``{"format": FORMAT, "kind": KIND, ...}``
beside its data, with the kind's own entries after those two:

- ``"identifier"``: a leg (or any structured) :class:`~aeid_struct.identification.Identifier`,
  safetensors weights with the header in the ``aeid`` metadata entry (``.aeid``);
- ``"generic"``: a ``generic.GenericIdentifier``, the same layout (``.aeid``);
- ``"onnx"``: an exported identifier (``online.to_onnx``), the header in the ONNX model's
  ``aeid`` metadata entry (``.onnx``), read into an ``Identifier`` on its ONNX back end;
- ``"exported"``: a ``torch.export`` program (``online.to_exported``), the header the
  archive's ``aeid.json``; read by a torch runtime (``torch.export.load``), not by the library,
  so not one of :data:`KINDS`.

Files are data only: JSON and raw tensors (or an ONNX graph, which runs no Python), never a
pickle or a CasADi Function read without ``trust``. Every older format still reads: its
``format`` string names its kind (:data:`OLD_FORMATS`). :func:`kind_of` is the one place that
tells a header's kind; ``aeid_struct.load`` dispatches on it, and each kind's own reader refuses
another kind by that name.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

__all__ = ["FORMAT", "KINDS", "OLD_FORMATS", "kind_of", "read_safetensors", "refuse_other", "stamp"]

#: The container format written by every writer of the library.
FORMAT = "aeid-struct/3"
#: The kinds of identifier a container holds, and what reads each.
KINDS = {"identifier": "ae.Identifier.load", "generic": "ae.generic.load_generic",
         "onnx": "ae.Identifier.from_onnx"}
#: What each kind is, in messages.
NAMES = {"identifier": "a structured identifier (aeid_struct.Identifier)",
         "generic": "a generic identifier (any SISO record)",
         "onnx": "an ONNX export"}
#: The formats before the container, by the kind each held (all still read).
OLD_FORMATS = {
    "aeid-struct/identifier/2": "identifier",
    "aeid-struct/identifier/1": "identifier",
    "aeid-struct/generic/1": "generic",
    "aeid-struct-onnx-3": "onnx",
    "aeid-struct-onnx-2": "onnx",
    "aeid-struct-onnx-1": "onnx",
}


def stamp(kind: str, header: dict) -> dict:
    """``header`` in the container: ``format`` and ``kind`` first, then the kind's entries.

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    header : dict
        The kind's own entries (without ``format`` and ``kind``).

    Returns
    -------
    dict
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {sorted(KINDS)}; got {kind!r}")
    return {"format": FORMAT, "kind": kind,
            **{k: v for k, v in header.items() if k not in ("format", "kind")}}


def kind_of(header, source: str) -> str:
    """The kind of identifier a parsed header describes (the container's, or an older format's).

    Parameters
    ----------
    header : object
        The parsed JSON header.
    source : str
        Named in the message.

    Returns
    -------
    str
        One of :data:`KINDS`.

    Raises
    ------
    ValueError
        Not a JSON object, or a format or kind this version does not read.
    """
    if not isinstance(header, dict):
        raise ValueError(f"{source} is not an aeid-struct file: its header is not a JSON object "
                         f"(got {type(header).__name__})")
    fmt = header.get("format")
    if fmt == FORMAT:
        kind = header.get("kind")
        if kind not in KINDS:
            raise ValueError(f"{source}: header entry 'kind' must be one of {sorted(KINDS)}; "
                             f"got {kind!r}")
        return kind
    if fmt in OLD_FORMATS:
        return OLD_FORMATS[fmt]
    raise ValueError(f"{source} is not an aeid-struct file: its header format is {fmt!r}; this "
                     f"version reads {FORMAT!r} and the older {', '.join(map(repr, OLD_FORMATS))}")


def read_safetensors(path, what: str):
    """The parsed header and the tensors of a safetensors container.

    Parameters
    ----------
    path : str or PathLike
        An existing file.
    what : str
        What the caller reads (``"identifier"``, ``"generic identifier"``), in messages.

    Returns
    -------
    header : object
        The parsed ``aeid`` metadata entry (None where there is none).
    tensors : dict name -> torch.Tensor
    source : str
        ``"<what> file '<path>'"``, for the caller's messages.

    Raises
    ------
    ValueError
        Not a path of an existing file, or not safetensors with a JSON header.
    """
    from safetensors import safe_open

    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ValueError(f"path must be an existing {what} file (str or Path); got {path!r}")
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"path must be an existing {what} file; got {str(path)!r}")
    source = f"{what} file {str(path)!r}"
    try:
        with safe_open(str(path), framework="pt") as f:
            header = json.loads((f.metadata() or {}).get("aeid", "null"))
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as err:  # safetensors and json raise their own error types
        raise ValueError(f"path {str(path)!r} is not an aeid-struct {what} file (safetensors "
                         f"with a JSON header): {err}") from None
    return header, tensors, source


def refuse_other(kind: str, want: str, source: str) -> None:
    """Raise where a reader of ``want`` is given a file of another ``kind``, naming the
    reader of that kind (and ``aeid_struct.load``, which reads every kind).

    Parameters
    ----------
    kind, want : str
        The file's kind and the reader's.
    source : str
        Named in the message.

    Raises
    ------
    ValueError
    """
    if kind != want:
        raise ValueError(f"{source} holds {NAMES[kind]}, kind {kind!r}, not {NAMES[want]}: "
                         f"read it with {KINDS[kind]}, or with ae.load, which reads every kind")
