"""The encoder: the residual 1-D convolutional network of paper Sec. III-A.
"""

from aeid_struct.encoder.network import Encoder as Encoder
from aeid_struct.encoder.network import EncoderConfig as EncoderConfig
from aeid_struct.encoder.numpy_forward import NumpyEncoder as NumpyEncoder

__all__ = [
    "Encoder",
    "EncoderConfig",
    "NumpyEncoder",
]
