"""Deployment: an identifier as one ONNX or ``torch.export`` file that needs neither this
library nor Python's training code to identify a record.

:func:`to_onnx` writes the whole identification of one record (the normalisation of Eq. 15,
the encoder, the structure's constraint maps and assembly, the exact de-normalisation) as an
ONNX graph from the exporter built on ``torch.export``, with the record format and the inverse
map (a reference to a named map) in its metadata, which ``Identifier.from_onnx`` runs with
onnxruntime and numpy alone (the ONNX back end); :func:`to_exported` writes the same
computation as a ``torch.export`` program for a torch runtime (``torch.export.load``), graph
and weights only. :func:`to_torchscript` (TorchScript, deprecated in PyTorch) is deprecated.
Their latencies are measured by ``aeid-struct bench-online``.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import torch

from aeid_struct.identification.container import FORMAT, stamp

__all__ = ["onnx_bytes", "to_exported", "to_onnx", "to_torchscript"]


class _OneRecord(torch.nn.Module):
    """``Identifier.forward`` of one record, with tensors in and out (traceable)."""

    def __init__(self, ident) -> None:
        super().__init__()
        self.ident = ident
        self.encoder = ident.encoder   # registered, so that freezing inlines the weights

    def forward(self, y: torch.Tensor, u: torch.Tensor):
        sys, elements = self.ident.forward(y[None], u[None])
        return sys.A[0], sys.b[0], sys.c[0], sys.d[0], elements[0]


def _exportable(ident) -> None:
    from aeid_struct.structures import Physical

    # the back end's name, not isinstance(Identifier): the identifier module imports this one
    # (with_backend("onnx")), and an import back would make the two a cycle
    backend = getattr(getattr(ident, "backend", None), "name", None)
    if backend is None or not hasattr(ident, "structure"):
        raise ValueError(f"ident must be an Identifier; got {type(ident).__name__}")
    if backend == "onnx":
        raise ValueError("ident was read from an ONNX export (backend 'onnx'): it is an export "
                         "already; export the identifier it came from")
    if ident.records != 1:
        raise ValueError(f"ident must read one record to be exported; it reads {ident.records}")
    if isinstance(ident.structure, Physical):
        raise ValueError("ident's structure is Physical: its CasADi map runs as a Python "
                         "callback, which an exported graph cannot hold; export a canonical "
                         "identifier and the map's C code (symbolic.leg.generate_c) instead")


def _example(ident) -> tuple[torch.Tensor, torch.Tensor]:
    """A record to trace with: any finite record of the right length takes the same path."""
    g = torch.Generator().manual_seed(0)
    y = torch.cumsum(torch.rand(ident.steps, generator=g), 0)
    u = 0.5 + torch.rand(ident.steps, generator=g)
    return y, u


def _program(ident):
    """The ``torch.export`` program of ``ident``'s identification of one record: the one trace
    both exports are made from (:func:`to_exported` saves it, :func:`onnx_bytes` translates it).
    The structures' element checks stand aside while it traces (``torch.compiler.is_exporting``:
    they are data-dependent branches); each file's reader checks what the graph returns."""
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        return torch.export.export(_OneRecord(ident).eval(), _example(ident))


def _inverse_entry(ident):
    """The inverse map as the files name it: a reference (``structures.to_entry``), never a
    serialised Function; None without one or for a physical pair (its own header entry)."""
    from aeid_struct.structures import to_entry

    inverse = ident.provenance.inverse
    return None if inverse is None or isinstance(inverse, tuple) else to_entry(inverse)


def _file_to_write(path) -> Path:
    """``path`` as a Path to a file that can be written (``files.writable_file``; imported
    from its module, not through the package, whose lazy names include the identifier that
    imports this module)."""
    from aeid_struct.identification.files import writable_file

    return writable_file(path)


def to_torchscript(ident, path) -> Path:
    """Save ``ident`` as a frozen TorchScript module at ``path``.

    Loaded with ``torch.jit.load`` (in Python, or in C++ through libtorch), the module maps
    ``y (steps,)`` and ``u (steps,)`` (float32; ``u = torch.ones(steps)`` for a unit step) to
    ``A (n, n), b (n,), c (n,), d ()`` and the structure's elements ``(q,)``, the numbers of
    ``Identifier.identify`` to float32 precision. It identifies one record per call and does
    not compute the fitted initial state or the physical parameters (both are cheap functions
    of the returned model), nor the identifier's separable head (``Identifier.head``: the
    module gives the encoder pass; the ONNX file names the head and ``Identifier.from_onnx``
    runs it).

    Parameters
    ----------
    ident : Identifier
        An identifier of one record whose structure is assembled by torch operations (``CCF``,
        ``MCF``, fixed elements). A ``Physical`` structure evaluates its CasADi map through a
        Python callback, which TorchScript cannot hold: export the CasADi map itself (its C
        code, ``symbolic.leg.generate_c``) beside a canonical identifier instead.
    path : str or Path
        The file to write (conventionally ``.pt``).

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    ValueError
        An identifier that cannot be exported, or a path that cannot be written.

    Notes
    -----
    Deprecated: PyTorch deprecates TorchScript in favour of ``torch.export``; write
    :func:`to_exported` (a torch runtime) or :func:`to_onnx` (onnxruntime) instead. The file
    still loads and runs where libtorch reads TorchScript.
    """
    warnings.warn("to_torchscript is deprecated (PyTorch deprecates TorchScript): write "
                  "to_exported(ident, path) for a torch runtime (torch.export.load) or "
                  "to_onnx(ident, path) for onnxruntime", DeprecationWarning, stacklevel=2)
    _exportable(ident)
    path = _file_to_write(path)
    module = _OneRecord(ident).eval()
    y, u = _example(ident)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")       # tracer notes on Python scalars of the config
        traced = torch.jit.trace(module, (y, u), check_trace=False)
        frozen = torch.jit.freeze(traced)
    torch.jit.save(frozen, str(path))
    return path


def to_exported(ident, path) -> Path:
    """Save ``ident`` as a ``torch.export`` program (``.pt2``) at ``path``.

    ``torch.export.load(path).module()(y, u)`` (under ``torch.no_grad()``: the weights are
    the module's parameters) maps float32 ``y, u`` of shape ``(steps,)`` to
    ``A (n, n), b (n,), c (n,), d ()`` and the elements ``(q,)``, as :func:`to_onnx`'s graph;
    the record format (steps, dt, the elements' names, the inverse map's reference) is the
    archive's ``aeid.json``. The archive holds the graph (JSON) and the weights (raw bytes)
    only: the sample record ``torch.export`` keeps, a pickle, is left out (tested: no pickle
    in the file), and the graph names operators, not code.

    Parameters
    ----------
    ident : Identifier
        An identifier of one record with a torch-assembled structure.
    path : str or Path
        The file to write (parent folders created).

    Returns
    -------
    Path

    Raises
    ------
    ValueError
        An identifier that cannot be exported, or a path that cannot be written.
    """
    _exportable(ident)
    path = _file_to_write(path)
    program = _program(ident)
    program.example_inputs = None          # a pickle in the archive otherwise
    # the container's header, for a kind no reader of the library reads (container.KINDS)
    header = {"format": FORMAT, "kind": "exported",
              "steps": ident.steps, "dt": ident.dt, "inputs": ident.inputs,
              "elements": list(ident.structure.element_names),
              "inverse": _inverse_entry(ident), "structure": ident.structure.config()}
    torch.export.save(program, str(path), extra_files={"aeid.json": json.dumps(header)})
    return path


def onnx_bytes(ident) -> bytes:
    """The ONNX model of ``ident``'s identification of one record (:func:`to_onnx`), as bytes.

    Parameters
    ----------
    ident : Identifier
        An identifier of one record with a torch-assembled structure.

    Returns
    -------
    bytes
        The model (opset 18), with the record format, the inverse map (a reference,
        ``structures.to_entry``) and the identifier's separable head (``Head.to_dict``, or
        null) in its ``aeid`` metadata.

    Raises
    ------
    ValueError
        An identifier that cannot be exported.

    Notes
    -----
    The graph is the encoder pass (Eq. 15, the encoder, the structure, the de-normalisation);
    the head (``identification.head``: FFTs and small solves, iterated) is not in it but named
    in the metadata, and the ONNX back end applies it after onnxruntime in numpy, so the
    file gives ``Identifier.identify``'s estimate with the head.

    The exporter built on ``torch.export`` (``dynamo=True``; TorchScript, which the older
    exporter traced through, is deprecated), from the program :func:`to_exported` saves
    (``_program``); the ONNX back end checks the graph's outputs (non-finite rows are refused).
    Its dependencies (onnxscript beside onnx) are in the ``onnx`` extra.
    """
    import logging

    from aeid_struct.structures import CCF

    _exportable(ident)
    exported = _program(ident)
    # the exporter's notes (optional torchvision ops, initializer deduplication) are not the
    # caller's business
    quiet = [logging.getLogger(n) for n in ("torch.onnx", "torch.export", "onnxscript",
                                            "onnx_ir")]
    levels = [q.level for q in quiet]
    try:
        for q in quiet:
            q.setLevel(logging.ERROR)
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            model = torch.onnx.export(exported, input_names=["y", "u"],
                                      output_names=["A", "b", "c", "d", "elements"],
                                      opset_version=18, dynamo=True, verbose=False).model_proto
    finally:
        for q, level in zip(quiet, levels, strict=True):
            q.setLevel(level)
    inverse = ident.provenance.inverse
    header = stamp("onnx", {
        "steps": ident.steps, "dt": ident.dt, "inputs": ident.inputs,
        "initial": ident.initial, "elements": list(ident.structure.element_names),
        "inverse": _inverse_entry(ident),
        "physical_elements": list(inverse[1]) if isinstance(inverse, tuple) else None,
        "structure": ident.structure.config(),
        "ccf": isinstance(ident.structure, CCF),
        "scale": ident.scale,
        "head": None if ident.head is None else ident.head.to_dict(),
    })
    entry = model.metadata_props.add()
    entry.key, entry.value = "aeid", json.dumps(header)
    return model.SerializeToString()


def to_onnx(ident, path) -> Path:
    """Save ``ident`` as an ONNX model at ``path``.

    The graph's inputs are ``y, u``: float32 ``(steps,)``; its outputs ``A (n, n), b (n,),
    c (n,), d ()`` and ``elements (q,)``. The inverse map is stored as a reference to a named
    map (``structures.to_entry``), never as a serialised Function, which could run code when
    read. ``Identifier.from_onnx`` (or ``aeid_struct.load``) reads it; both need the optional
    ``onnx`` extra (``pip install "aeid-struct[onnx]"``).

    Parameters
    ----------
    ident : Identifier
        An identifier of one record with a torch-assembled structure.
    path : str or Path
        The file to write (conventionally ``.onnx``).

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    ValueError
        An identifier that cannot be exported, or a path that cannot be written.
    """
    path = _file_to_write(path)
    path.write_bytes(onnx_bytes(ident))
    return path
