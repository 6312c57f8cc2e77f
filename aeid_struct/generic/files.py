"""Generic identifier files: safetensors tensors plus a JSON header, data only.

The header is ``{"format": FORMAT, "kind": "generic", "config": GenericConfig fields, "meta":
{...}}`` (the one container, ``identification.container``; the older ``FORMAT_1`` without
``kind`` still reads); the tensors are
the encoder's weights (``encoder.<name>``). Loading parses JSON and raw tensors only (no pickle, no
CasADi Function), and checks every header entry, every weight's name, shape and values before
anything is built from them (docs/architecture.md, "Model files").
"""

from __future__ import annotations

import json
from pathlib import Path

import torch

from aeid_struct.encoder import Encoder
from aeid_struct.generic.config import GenericConfig
from aeid_struct.identification import (
    FORMAT,
    kind_of,
    read_safetensors,
    refuse_other,
    stamp,
    writable_file,
)

__all__ = ["FORMAT", "FORMAT_1", "read", "write"]

#: The format before the container (``FORMAT``, kind ``"generic"``): still read.
FORMAT_1 = "aeid-struct/generic/1"
_HEADER = ("format", "config", "meta")


def write(ident, path) -> Path:
    """:func:`~aeid_struct.generic.save_generic`'s file (its parameters, returns and errors;
    ``ident`` checked by it)."""
    from safetensors.torch import save_file

    path = writable_file(path)
    head = stamp("generic", {"config": ident.config.to_dict(), "meta": ident.meta})
    try:
        text = json.dumps(head)
    except (TypeError, ValueError) as err:
        raise ValueError(f"ident.meta must be JSON-ready data: {err}") from None
    tensors = {f"encoder.{k}": v.detach().contiguous()
               for k, v in ident.encoder.state_dict().items()}
    save_file(tensors, str(path), metadata={"aeid": text})
    return path


def _config(head, source: str) -> GenericConfig:
    """The header's checked entries -> the configuration (one ValueError naming ``source``)."""
    refuse_other(kind_of(head, source), "generic", source)
    entries = _HEADER if head["format"] == FORMAT_1 else ("format", "kind", *_HEADER[1:])
    if set(head) != set(entries):
        raise ValueError(f"{source}: the header must have exactly the entries {list(entries)}; "
                         f"got {sorted(head)}")
    if not isinstance(head["meta"], dict):
        raise ValueError(f"{source}: header entry 'meta' must be a dict; got "
                         f"{type(head['meta']).__name__}")
    config = head["config"]
    if not isinstance(config, dict):
        raise ValueError(f"{source}: header entry 'config' must be a dict; got "
                         f"{type(config).__name__}")
    fields = set(GenericConfig.__dataclass_fields__)
    if set(config) != fields:
        raise ValueError(f"{source}: header entry 'config' must have exactly the entries "
                         f"{sorted(fields)}; got {sorted(config)}")
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in config.items()}
    try:
        return GenericConfig(**values)
    except ValueError as err:
        raise ValueError(f"{source}: header entry 'config' is not valid: {err}") from None


def _encoder(config: GenericConfig, tensors: dict, source: str) -> Encoder:
    """The encoder of ``config`` with the file's weights, every one checked first."""
    enc = config.encoder_config()
    with torch.device("meta"):      # shapes without allocating what a header may describe
        expected = {f"encoder.{k}": tuple(v.shape) for k, v in Encoder(enc).state_dict().items()}
    missing = sorted(set(expected) - set(tensors))
    unknown = sorted(set(tensors) - set(expected))
    if missing or unknown:
        raise ValueError(f"{source}: the weights do not match the header's 'config' (missing "
                         f"{missing}, unknown {unknown})")
    for key, shape in expected.items():
        t = tensors[key]
        if tuple(t.shape) != shape:
            raise ValueError(f"{source}: weight {key!r} has shape {tuple(t.shape)}; the header's "
                             f"'config' needs {shape}")
        if t.dtype != torch.float32 or not bool(torch.isfinite(t).all()):
            raise ValueError(f"{source}: weight {key!r} must hold finite float32 numbers; got "
                             f"dtype {t.dtype}")
    encoder = Encoder(enc)
    encoder.load_state_dict({k[len("encoder."):]: v for k, v in tensors.items()})
    encoder.eval()
    return encoder


def read(cls, path):
    """:func:`~aeid_struct.generic.read_generic`'s reading (its parameters, returns and
    errors), the identifier built as ``cls(config, encoder, meta=...)``: the class is handed in
    (``generic.model`` imports this module, not the other way round)."""
    head, tensors, source = read_safetensors(path, "generic identifier")
    config = _config(head, source)
    return cls(config, _encoder(config, tensors, source), meta=head["meta"])
