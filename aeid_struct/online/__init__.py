"""Online use: the sliding-window tracker and deployment files (TorchScript, ONNX).
"""

from aeid_struct.online.export import ONNX_FORMAT as ONNX_FORMAT
from aeid_struct.online.export import ONNX_FORMAT_1 as ONNX_FORMAT_1
from aeid_struct.online.export import OnnxIdentifier as OnnxIdentifier
from aeid_struct.online.export import onnx_bytes as onnx_bytes
from aeid_struct.online.export import to_onnx as to_onnx
from aeid_struct.online.export import to_torchscript as to_torchscript
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
