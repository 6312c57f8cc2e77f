"""Online use: the sliding-window tracker and deployment files (TorchScript, ONNX).

The deployment names (``to_onnx``, ``OnnxIdentifier``, ...) are imported on first use (PEP 562):
their modules need torch or onnxruntime, and the tracker's configuration must stay cheap to
import (the command line reads its defaults while building ``--help``). The wear scenario that
exercises the tracker is a study: ``aeid_struct.studies.wear``.
"""

from importlib import import_module
from typing import TYPE_CHECKING

from aeid_struct.online.tracker import DEFAULT_SMOOTHING as DEFAULT_SMOOTHING
from aeid_struct.online.tracker import PushError as PushError
from aeid_struct.online.tracker import Tracker as Tracker
from aeid_struct.online.tracker import TrackerConfig as TrackerConfig
from aeid_struct.online.tracker import Update as Update

if TYPE_CHECKING:  # static analysers and the documentation see the lazy names
    from aeid_struct.online.export import onnx_bytes as onnx_bytes
    from aeid_struct.online.export import to_exported as to_exported
    from aeid_struct.online.export import to_onnx as to_onnx
    from aeid_struct.online.export import to_torchscript as to_torchscript
    from aeid_struct.online.onnx import ONNX_FORMAT as ONNX_FORMAT
    from aeid_struct.online.onnx import ONNX_FORMAT_1 as ONNX_FORMAT_1
    from aeid_struct.online.onnx import ONNX_FORMAT_2 as ONNX_FORMAT_2
    from aeid_struct.online.onnx import ONNX_FORMAT_3 as ONNX_FORMAT_3
    from aeid_struct.online.onnx import OnnxIdentifier as OnnxIdentifier

__all__ = [
    "DEFAULT_SMOOTHING",
    "ONNX_FORMAT",
    "ONNX_FORMAT_1",
    "ONNX_FORMAT_2",
    "ONNX_FORMAT_3",
    "OnnxIdentifier",
    "PushError",
    "Tracker",
    "TrackerConfig",
    "Update",
    "onnx_bytes",
    "to_exported",
    "to_onnx",
    "to_torchscript",
]

#: deployment names -> the module that defines them, imported when first used
_LAZY = {"ONNX_FORMAT": "onnx", "ONNX_FORMAT_1": "onnx", "ONNX_FORMAT_2": "onnx",
         "ONNX_FORMAT_3": "onnx",
         "OnnxIdentifier": "onnx",
         "onnx_bytes": "export", "to_exported": "export", "to_onnx": "export",
         "to_torchscript": "export"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(f"aeid_struct.online.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
