"""Online use: the sliding-window tracker and deployment files (TorchScript, ONNX).


The deployment names (``to_onnx``, ``OnnxIdentifier``, ...) are imported on first use (PEP 562):
their module needs torch, and the tracker's configuration must stay cheap to import (the
command line reads its defaults while building ``--help``).
"""

from importlib import import_module

from aeid_struct.online.tracker import PushError as PushError
from aeid_struct.online.tracker import Tracker as Tracker
from aeid_struct.online.tracker import TrackerConfig as TrackerConfig
from aeid_struct.online.tracker import Update as Update
from aeid_struct.online.tracker import WearResult as WearResult
from aeid_struct.online.tracker import wear_study as wear_study
from aeid_struct.online.tracker import wearing_leg as wearing_leg

__all__ = [
    "ONNX_FORMAT",
    "ONNX_FORMAT_1",
    "OnnxIdentifier",
    "PushError",
    "Tracker",
    "TrackerConfig",
    "Update",
    "WearResult",
    "onnx_bytes",
    "to_onnx",
    "to_torchscript",
    "wear_study",
    "wearing_leg",
]

#: names of :mod:`aeid_struct.online.export`, imported when first used
_EXPORT = frozenset({"ONNX_FORMAT", "ONNX_FORMAT_1", "OnnxIdentifier", "onnx_bytes", "to_onnx",
                     "to_torchscript"})


def __getattr__(name: str):
    if name in _EXPORT:
        value = getattr(import_module("aeid_struct.online.export"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
