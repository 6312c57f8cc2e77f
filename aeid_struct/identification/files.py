"""Identifier files (``.aeid``): safetensors, tensors plus a JSON header.

A model file holds data, never code: loading parses JSON and raw tensors only (no pickle), and
CasADi maps are stored as references to named factories (``aeid_struct.structures.maps``), never
as serialised Functions, which can run shell commands when read. A user's own map is passed
again at load time (``Identifier.load(path, maps={name: f})``) or read from the file only behind
``trust=True``. Every header entry and tensor is checked before anything is built from it.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from pathlib import Path

import torch

from aeid_struct.encoder import Encoder, EncoderConfig
from aeid_struct.identification import container
from aeid_struct.identification.fast_path import warm
from aeid_struct.identification.forward import CHUNK
from aeid_struct.identification.head import Head
from aeid_struct.structures import Structure, check_maps, from_entry, to_entry

__all__ = ["FORMAT", "FORMAT_1", "FORMAT_2", "from_parts", "header", "load", "save",
           "writable_file"]

#: The file format written: the one container (``identification.container``), kind
#: ``"identifier"``; maps are references (``aeid_struct.structures.maps``), never code.
FORMAT = container.FORMAT
#: The format before the container (the same entries under ``format`` alone): still read.
FORMAT_2 = "aeid-struct/identifier/2"
#: The format before named maps (CasADi Functions serialised inline): read with ``trust=True``
#: where it holds a Function.
FORMAT_1 = "aeid-struct/identifier/1"


def writable_file(path) -> Path:
    """``path`` as a Path to a file that can be written, its folder created.

    Parameters
    ----------
    path : str or PathLike

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        Naming ``path`` for anything else (not a path, a directory, a file where its folder
        should be).
    """
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ValueError(f"path must be a file name (str or Path); got {path!r}")
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"path must be a file to write; {str(path)!r} is a directory")
    folder = next((p for p in path.parents if p.exists()), None)
    if folder is not None and not folder.is_dir():
        raise ValueError(f"path must be a file to write; {str(path)!r} lies below "
                         f"{str(folder)!r}, which is a file")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


#: Header entries: required ones, and optional ones with the JSON types they may have.
_HEADER_REQUIRED = ("format", "encoder", "structure", "dt", "scale", "feature_mean",
                    "feature_scale")
_HEADER_OPTIONAL = ("kind", "initial", "inverse", "meta", "head")


def _numbers(value, finite: bool = True) -> bool:
    """A JSON number, or a non-empty list of them (finite when ``finite``)."""
    values = value if isinstance(value, list) and value else [value]
    return all(isinstance(v, (int, float)) and not isinstance(v, bool)
               and (not finite or math.isfinite(v)) for v in values)


def _check_header(header: dict, source: str) -> None:
    """Entries and JSON types of an identifier header (one ValueError naming ``source``)."""
    unknown = sorted(set(header) - set(_HEADER_REQUIRED) - set(_HEADER_OPTIONAL))
    if unknown:
        raise ValueError(f"{source}: the header has unknown entries {unknown}; an identifier "
                         f"header has {', '.join(_HEADER_REQUIRED + _HEADER_OPTIONAL)}")
    missing = [k for k in _HEADER_REQUIRED if k not in header]
    if missing:
        raise ValueError(f"{source}: the header is missing {', '.join(map(repr, missing))}")
    checks = {
        "encoder": (isinstance(header["encoder"], dict), "a dict"),
        "structure": (isinstance(header["structure"], dict), "a dict"),
        "dt": (_numbers(header["dt"]), "a finite number or a list of them"),
        "scale": (isinstance(header["scale"], str), "a string"),
        "initial": (isinstance(header.get("initial", "rest"), str), "a string"),
        "feature_mean": (_numbers(header["feature_mean"]), "a finite number or a list of them"),
        "feature_scale": (_numbers(header["feature_scale"]),
                          "a finite number or a list of them"),
        "meta": (isinstance(header.get("meta", {}), dict), "a dict"),
        "head": (header.get("head") is None or isinstance(header["head"], dict),
                 "a dict {'iterations': int, 'fixed': {name: value}} or null"),
        "inverse": (header.get("inverse") is None
                    or isinstance(header["inverse"], (dict, str)), "a map reference or null"),
    }
    for key, (ok, expected) in checks.items():
        if not ok:
            got = header[key]
            text = repr(got) if len(repr(got)) <= 80 else f"{repr(got)[:60]}..."
            raise ValueError(f"{source}: header entry {key!r} must be {expected}; got {text}")
    rng = header.get("meta", {}).get("training_range")
    if rng:   # read by Estimate.outside: {"elements"/"physical": {name: [lo, hi, err]}, ...}
        ok = isinstance(rng, dict) and set(rng) <= {"elements", "physical", "fit", "excess"}
        for group in ("elements", "physical"):
            part = rng.get(group, {}) if ok else None
            ok = ok and isinstance(part, dict) and all(
                isinstance(v, list) and len(v) == 3 and _numbers(v) for v in part.values())
        ok = ok and all(_numbers(rng[k]) and not isinstance(rng[k], list)
                        for k in ("fit", "excess") if k in rng)
        if not ok:
            text = repr(rng) if len(repr(rng)) <= 80 else f"{repr(rng)[:60]}..."
            raise ValueError(f"{source}: 'meta' entry 'training_range' must be "
                             "{'elements': {name: [lo, hi, err]}, 'physical': {...}, 'fit': "
                             f"number, 'excess': number}}; got {text}")
    fields = {f.name for f in dataclasses.fields(EncoderConfig)}
    unknown = sorted(set(header["encoder"]) - fields)
    if unknown:
        raise ValueError(f"{source}: 'encoder' has unknown entries {unknown}; an encoder "
                         f"configuration has {', '.join(sorted(fields))}")
    if not isinstance(header["encoder"].get("inputs", False), bool):
        raise ValueError(f"{source}: 'encoder' entry 'inputs' must be true or false; got "
                         f"{header['encoder']['inputs']!r}")


def _check_structure_size(config, outputs: int, source: str) -> None:
    """A canonical structure's size against the encoder's outputs, before it is built: a header
    with ``{"type": "CCF", "n": 100000000}`` would otherwise spend minutes and gigabytes on its
    element maps before any later check refused it. Every element is a raw parameter
    (``outputs`` of them) or fixed (listed in the config)."""
    kind = config.get("type")
    if kind not in ("CCF", "MCF"):
        return            # Physical: one element per input of a map from the allow-list
    sizes = [config.get(k, 0) for k in (("n",) if kind == "CCF" else ("real", "pairs"))]
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in sizes):
        return            # from_config names the bad entry
    n = sizes[0] if kind == "CCF" else sizes[0] + 2 * sizes[1]
    fixed = config.get("fixed") or {}
    elements = 2 * n + (1 if config.get("feedthrough") else 0)
    if elements > outputs + (len(fixed) if isinstance(fixed, dict) else 0):
        raise ValueError(f"{source}: 'structure' {kind} of order {n} has {elements} elements, "
                         f"more than the encoder's {outputs} outputs and "
                         f"{len(fixed) if isinstance(fixed, dict) else 0} fixed elements")


def _check_weights(expected: dict, tensors: dict, source: str) -> None:
    """The file's tensors against ``expected`` (name -> shape of the encoder the header
    describes): every one there, none more, each of its shape."""
    missing = [k for k in (*expected, "theta_mean", "theta_scale") if k not in tensors]
    if missing:
        raise ValueError(f"{source}: weights {missing} are missing (the header's 'encoder' "
                         "describes them)")
    unknown = sorted(set(tensors) - set(expected) - {"theta_mean", "theta_scale"})
    if unknown:
        raise ValueError(f"{source}: unknown weights {unknown} (not in the encoder the header "
                         "describes)")
    for key, shape in expected.items():
        if tuple(tensors[key].shape) != shape:
            raise ValueError(f"{source}: weight {key!r} has shape {tuple(tensors[key].shape)}; "
                             f"the header's 'encoder' needs {shape}")


def _load_weights(encoder: Encoder, tensors: dict, source: str) -> None:
    """Load the file's tensors, whose names and shapes ``_check_weights`` has checked, after
    checking that they are finite floats; one ValueError naming ``source`` and the tensor."""
    for key in (*encoder.state_dict(), "theta_mean", "theta_scale"):   # the layer order
        key = key if key.startswith("theta_") else f"encoder.{key}"
        tensor = tensors[key]
        if not tensor.is_floating_point() or not bool(torch.isfinite(tensor).all()):
            raise ValueError(f"{source}: weight {key!r} must hold finite floating-point "
                             f"numbers; got dtype {tensor.dtype}"
                             + ("" if not tensor.is_floating_point() else " with non-finite "
                                "values"))
    encoder.load_state_dict({k[len("encoder."):]: v for k, v in tensors.items()
                             if k.startswith("encoder.")})
    encoder.eval()


def header(ident) -> dict:
    """The JSON header of an identifier: everything but the weights.

    Data only: the inverse map (and a Physical structure's maps) as references to named
    factories, a user's own map as its name and SHA-256 (with its serialisation, read only under
    ``trust=True``).

    Parameters
    ----------
    ident : Identifier

    Returns
    -------
    dict
    """
    return container.stamp("identifier", {
        "encoder": ident.encoder.config.to_dict(),
        "structure": ident.structure.config(),
        "dt": ident.dt,
        "scale": ident.scale,
        "initial": ident.initial,
        "feature_mean": ident.feature_mean,
        "feature_scale": ident.feature_scale,
        "inverse": None if ident.inverse is None else to_entry(ident.inverse),
        "meta": ident.meta,
        **({} if ident.head is None else {"head": ident.head.to_dict()}),
    })


def save(ident, path) -> Path:
    """Write an identifier to ``path`` (safetensors: weights + JSON header).

    Parameters
    ----------
    ident : Identifier
    path : str or PathLike

    Returns
    -------
    Path
    """
    from safetensors.torch import save_file

    path = writable_file(path)
    tensors = {f"encoder.{k}": v.detach().contiguous()
               for k, v in ident.encoder.state_dict().items()}
    tensors["theta_mean"] = ident.theta_mean.contiguous()
    tensors["theta_scale"] = ident.theta_scale.contiguous()
    save_file(tensors, str(path), metadata={"aeid": json.dumps(header(ident))})
    return path


def load(cls, path, *, maps: dict | None = None, trust: bool = False):
    """Read an identifier written by :func:`save`; parses JSON and raw tensors only.

    Parameters
    ----------
    cls : type
        The identifier class to build (``Identifier``).
    path : str or PathLike
    maps : dict name -> casadi.Function, optional
        The user maps the file names, passed again; each must have the recorded SHA-256.
    trust : bool
        Deserialise user maps (and ``FORMAT_1`` Functions) from the file itself.

    Returns
    -------
    Identifier

    Raises
    ------
    ValueError
        Naming the file and what is wrong.
    """
    head, tensors, source = container.read_safetensors(path, "identifier")
    container.refuse_other(container.kind_of(head, source), "identifier", source)
    check_maps(maps, trust)
    if head["format"] == FORMAT_1:
        source += f" (format {FORMAT_1!r}, which stored CasADi maps as code)"
    ident = from_parts(cls, head, tensors, source=source, maps=maps, trust=trust)
    warm(ident, CHUNK)     # the first identification as fast as the next (fast_path.warm)
    return ident


def _encoder(head: dict, tensors: dict, source: str) -> Encoder:
    """The encoder the header describes, with the file's weights, all checked first."""
    try:
        config = EncoderConfig.from_dict(head["encoder"])
    except (TypeError, ValueError) as err:
        raise ValueError(f"{source}: 'encoder' is not a valid encoder configuration: "
                         f"{err}") from None
    try:
        # First on the meta device, which allocates nothing: a header that describes a huge
        # network (width 1e8) is refused by the shapes of the weights the file really holds,
        # before any memory is taken for it.
        with torch.device("meta"):
            expected = {f"encoder.{k}": tuple(v.shape)
                        for k, v in Encoder(config).state_dict().items()}
    except ValueError as err:
        raise ValueError(f"{source}: 'encoder': {err}") from None
    _check_weights(expected, tensors, source)
    encoder = Encoder(config)
    _load_weights(encoder, tensors, source)
    return encoder


def from_parts(cls, head: dict, tensors: dict, *, source: str = "header",
               maps: dict | None = None, trust: bool = False):
    """The identifier of a parsed header and its tensors.

    Parameters
    ----------
    cls : type
        The identifier class to build.
    head : dict
        The JSON header.
    tensors : dict name -> torch.Tensor
    source : str
        Named in messages.
    maps, trust
        As for :func:`load`.

    Returns
    -------
    Identifier

    Raises
    ------
    ValueError
        Naming ``source`` and what is wrong, for anything malformed.
    """
    _check_header(head, source)
    encoder = _encoder(head, tensors, source)
    _check_structure_size(head["structure"], encoder.config.outputs, source)
    try:
        structure = Structure.from_config(head["structure"], maps=maps, trust=trust)
        inverse = head.get("inverse")
        if inverse is not None:
            inverse = from_entry(inverse, "'inverse'", maps=maps, trust=trust)
        dt = head["dt"]
        return cls(
            encoder, structure,
            dt=tuple(dt) if isinstance(dt, list) else dt,
            theta_mean=tensors["theta_mean"],
            theta_scale=tensors["theta_scale"],
            scale=head["scale"],
            initial=head.get("initial", "rest"),
            feature_mean=head["feature_mean"],
            feature_scale=head["feature_scale"],
            inverse=inverse,
            meta=head.get("meta", {}),
            head=None if head.get("head") is None else Head.from_dict(head["head"]),
        )
    except ValueError as err:
        raise ValueError(f"{source}: {err}") from None
