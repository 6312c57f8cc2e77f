"""Identification: ``Identifier`` (encoder + structure + normalisation) on its back ends
(``TorchBackend``: torch, and the numpy pass for one record; ``OnnxBackend``: an export run by
onnxruntime), ``Estimate`` and its ``Provenance``, the separable ``Head`` after the encoder,
identifier files and exports, the shipped identifiers.

Layer: above ``refinement`` (``identify(refine=True)`` calls down into it), below ``training``.

The file container (``kind_of``, ``refuse_other``, ``read_safetensors``, ``stamp``), the
protocol and the estimate's names need no torch and are imported with the package; the
identifier, its files and its back ends on first use of their names. The ``Identifier`` class
itself imports no torch, so that an identifier read from an ONNX export runs without it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from aeid_struct.estimates import FLAG_FALSE_RATE as FLAG_FALSE_RATE
from aeid_struct.estimates import Estimate as Estimate
from aeid_struct.estimates import Provenance as Provenance
from aeid_struct.estimates import excess as excess
from aeid_struct.estimates import inverse_of_models as inverse_of_models
from aeid_struct.estimates import through_ccf as through_ccf
from aeid_struct.identification.container import KINDS as KINDS
from aeid_struct.identification.container import kind_of as kind_of
from aeid_struct.identification.container import read_safetensors as read_safetensors
from aeid_struct.identification.container import refuse_other as refuse_other
from aeid_struct.identification.container import stamp as stamp
from aeid_struct.identification.protocol import Identifies as Identifies
from aeid_struct.lazy import attach
from aeid_struct.records import RecordBatch as RecordBatch

if TYPE_CHECKING:
    from aeid_struct.identification.export import onnx_bytes as onnx_bytes
    from aeid_struct.identification.export import to_exported as to_exported
    from aeid_struct.identification.export import to_onnx as to_onnx
    from aeid_struct.identification.export import to_torchscript as to_torchscript
    from aeid_struct.identification.files import FORMAT as FORMAT
    from aeid_struct.identification.files import FORMAT_1 as FORMAT_1
    from aeid_struct.identification.files import FORMAT_2 as FORMAT_2
    from aeid_struct.identification.files import writable_file as writable_file
    from aeid_struct.identification.forward import TorchBackend as TorchBackend
    from aeid_struct.identification.head import Head as Head
    from aeid_struct.identification.head import apply_head as apply_head
    from aeid_struct.identification.head import head_failure as head_failure
    from aeid_struct.identification.head import pattern_of as pattern_of
    from aeid_struct.identification.identifier import ERROR_MODES as ERROR_MODES
    from aeid_struct.identification.identifier import INITIAL_STATES as INITIAL_STATES
    from aeid_struct.identification.identifier import SCALE_MODES as SCALE_MODES
    from aeid_struct.identification.identifier import Identifier as Identifier
    from aeid_struct.identification.onnx_backend import ONNX_FORMAT as ONNX_FORMAT
    from aeid_struct.identification.onnx_backend import ONNX_FORMAT_1 as ONNX_FORMAT_1
    from aeid_struct.identification.onnx_backend import ONNX_FORMAT_2 as ONNX_FORMAT_2
    from aeid_struct.identification.onnx_backend import ONNX_FORMAT_3 as ONNX_FORMAT_3
    from aeid_struct.identification.onnx_backend import OnnxBackend as OnnxBackend
    from aeid_struct.identification.onnx_backend import inverse_names as inverse_names
    from aeid_struct.identification.onnx_backend import read_onnx as read_onnx
    from aeid_struct.identification.physical_head import PhysicalHead as PhysicalHead
    from aeid_struct.identification.polish import with_standard_errors as with_standard_errors
    from aeid_struct.identification.pretrained import PRETRAINED as PRETRAINED
    from aeid_struct.identification.pretrained import load_pretrained as load_pretrained

#: name -> the module (of this package, needing torch) that defines it
_LAZY = {
    "FORMAT": "files",
    "FORMAT_1": "files",
    "FORMAT_2": "files",
    "writable_file": "files",
    "onnx_bytes": "export",
    "to_exported": "export",
    "to_onnx": "export",
    "to_torchscript": "export",
    "TorchBackend": "forward",
    "OnnxBackend": "onnx_backend",
    "ONNX_FORMAT": "onnx_backend",
    "ONNX_FORMAT_1": "onnx_backend",
    "ONNX_FORMAT_2": "onnx_backend",
    "ONNX_FORMAT_3": "onnx_backend",
    "inverse_names": "onnx_backend",
    "read_onnx": "onnx_backend",
    "Head": "head",
    "apply_head": "head",
    "head_failure": "head",
    "pattern_of": "head",
    "PhysicalHead": "physical_head",
    "with_standard_errors": "polish",
    "ERROR_MODES": "identifier",
    "INITIAL_STATES": "identifier",
    "SCALE_MODES": "identifier",
    "Identifier": "identifier",
    "PRETRAINED": "pretrained",
    "load_pretrained": "pretrained",
}

__all__ = [
    "ERROR_MODES",
    "Estimate",
    "FLAG_FALSE_RATE",
    "FORMAT",
    "FORMAT_1",
    "FORMAT_2",
    "Head",
    "INITIAL_STATES",
    "Identifier",
    "Identifies",
    "KINDS",
    "ONNX_FORMAT",
    "ONNX_FORMAT_1",
    "ONNX_FORMAT_2",
    "ONNX_FORMAT_3",
    "OnnxBackend",
    "PRETRAINED",
    "PhysicalHead",
    "Provenance",
    "RecordBatch",
    "SCALE_MODES",
    "TorchBackend",
    "apply_head",
    "excess",
    "head_failure",
    "inverse_names",
    "inverse_of_models",
    "kind_of",
    "load_pretrained",
    "onnx_bytes",
    "pattern_of",
    "read_onnx",
    "read_safetensors",
    "refuse_other",
    "stamp",
    "through_ccf",
    "to_exported",
    "to_onnx",
    "to_torchscript",
    "with_standard_errors",
    "writable_file",
]


__getattr__, __dir__ = attach(__name__, _LAZY)
