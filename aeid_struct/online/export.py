"""Deployment files of an identifier (ONNX, torch.export; TorchScript deprecated): the writers
live with the identifier (``identification.export``); this module keeps the names where they
were."""

from aeid_struct.identification import onnx_bytes as onnx_bytes
from aeid_struct.identification import to_exported as to_exported
from aeid_struct.identification import to_onnx as to_onnx
from aeid_struct.identification import to_torchscript as to_torchscript
from aeid_struct.online.onnx import ONNX_FORMAT as ONNX_FORMAT
from aeid_struct.online.onnx import ONNX_FORMAT_1 as ONNX_FORMAT_1
from aeid_struct.online.onnx import OnnxIdentifier as OnnxIdentifier

__all__ = ["ONNX_FORMAT", "ONNX_FORMAT_1", "OnnxIdentifier", "onnx_bytes", "to_exported",
           "to_onnx", "to_torchscript"]
