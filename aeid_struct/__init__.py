"""aeid-struct: structured, amortized identification of continuous-time LTI systems.

A trained encoder maps a measured input/output record to a state-space model in a structure the
user chose (controllable or modal canonical form, partly known, or physical parameters) in one
forward pass; an optional CasADi NLP polishes the estimate. Implements and extends Nagel & Huber,
"Autoencoder-Inspired Identification of LTI Systems".
"""

from .data import LegFamily as LegFamily
from .data import PoleFamily as PoleFamily
from .decoder import discretise as discretise
from .decoder import initial_state as initial_state
from .decoder import simulate as simulate
from .decoder import stationary_value as stationary_value
from .encoder import EncoderConfig as EncoderConfig
from .identify import Estimate as Estimate
from .identify import Identifier as Identifier
from .identify import load_pretrained as load_pretrained
from .refine import RefineConfig as RefineConfig
from .structures import CCF as CCF
from .structures import MCF as MCF
from .structures import Physical as Physical
from .structures import Structure as Structure
from .structures import System as System
from .training import TrainConfig as TrainConfig
from .training import train as train

__all__ = [
    "CCF",
    "MCF",
    "EncoderConfig",
    "Estimate",
    "Identifier",
    "LegFamily",
    "Physical",
    "PoleFamily",
    "RefineConfig",
    "Structure",
    "System",
    "TrainConfig",
    "discretise",
    "initial_state",
    "load_pretrained",
    "simulate",
    "stationary_value",
    "train",
]
__version__ = "0.1.0"
