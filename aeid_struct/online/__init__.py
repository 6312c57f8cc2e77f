"""Online use: the sliding-window tracker and deployment files (TorchScript, ONNX).
"""

from aeid_struct.online.tracker import PushError as PushError
from aeid_struct.online.tracker import Tracker as Tracker
from aeid_struct.online.tracker import TrackerConfig as TrackerConfig
from aeid_struct.online.tracker import Update as Update
from aeid_struct.online.tracker import WearResult as WearResult
from aeid_struct.online.tracker import wear_study as wear_study
from aeid_struct.online.tracker import wearing_leg as wearing_leg

__all__ = [
    "PushError",
    "Tracker",
    "TrackerConfig",
    "Update",
    "WearResult",
    "wear_study",
    "wearing_leg",
]
