"""aeid-struct: structured, amortized identification of continuous-time LTI systems.

A trained encoder maps a measured input/output record to a state-space model in a structure the
user chose (controllable or modal canonical form, partly known, or physical parameters) in one
forward pass; an optional CasADi NLP polishes the estimate. Implements and extends Nagel & Huber,
"Autoencoder-Inspired Identification of LTI Systems".

The public names are imported on first use (PEP 562 ``__getattr__``): ``import aeid_struct``
costs nothing, so that ``aeid-struct --help`` (and any tool that imports one light submodule)
does not pay for torch and CasADi; ``ae.Identifier`` or ``from aeid_struct import Identifier``
imports the submodule that defines it, and ``ae.decoder`` (any submodule by name) imports that
submodule, as the eager package did for the modules it loaded.
"""

from __future__ import annotations

from importlib import import_module
from importlib.util import find_spec
from typing import TYPE_CHECKING

from aeid_struct import _compat

_compat.install()      # old module paths (aeid_struct.decoder, .refine, ...) keep working

if TYPE_CHECKING:  # static analysers and IDEs see the eager imports
    from aeid_struct.encoder import EncoderConfig as EncoderConfig
    from aeid_struct.generic import FeedbackWarning as FeedbackWarning
    from aeid_struct.generic import StableOnlyWarning as StableOnlyWarning
    from aeid_struct.generic import UndeterminedModelWarning as UndeterminedModelWarning
    from aeid_struct.generic import UnexcitedModeWarning as UnexcitedModeWarning
    from aeid_struct.generic import compare as compare
    from aeid_struct.generic import identify as identify
    from aeid_struct.identification import Estimate as Estimate
    from aeid_struct.identification import Head as Head
    from aeid_struct.identification import Identifier as Identifier
    from aeid_struct.identification import Identifies as Identifies
    from aeid_struct.identification import load_pretrained as load_pretrained
    from aeid_struct.loading import load as load
    from aeid_struct.records import Record as Record
    from aeid_struct.refinement import RefineConfig as RefineConfig
    from aeid_struct.simulation import discretise as discretise
    from aeid_struct.simulation import initial_state as initial_state
    from aeid_struct.simulation import simulate as simulate
    from aeid_struct.simulation import stationary_value as stationary_value
    from aeid_struct.structures import CCF as CCF
    from aeid_struct.structures import MCF as MCF
    from aeid_struct.structures import Physical as Physical
    from aeid_struct.structures import Structure as Structure
    from aeid_struct.structures import System as System
    from aeid_struct.training import LegFamily as LegFamily
    from aeid_struct.training import ParameterFamily as ParameterFamily
    from aeid_struct.training import PoleFamily as PoleFamily
    from aeid_struct.training import TrainConfig as TrainConfig
    from aeid_struct.training import UndertrainedWarning as UndertrainedWarning
    from aeid_struct.training import train as train

#: public name -> the sub-package that exports it
_SOURCES = {
    "LegFamily": "training",
    "ParameterFamily": "training",
    "PoleFamily": "training",
    "discretise": "simulation",
    "initial_state": "simulation",
    "simulate": "simulation",
    "stationary_value": "simulation",
    "EncoderConfig": "encoder",
    "compare": "generic",
    "identify": "generic",
    "Estimate": "estimates",
    "Head": "identification",
    "Identifier": "identification",
    "Identifies": "identification",
    "load_pretrained": "identification",
    "load": "loading",
    "Record": "records",
    "RefineConfig": "refinement",
    "CCF": "structures",
    "MCF": "structures",
    "Physical": "structures",
    "Structure": "structures",
    "System": "structures",
    "TrainConfig": "training",
    "UndertrainedWarning": "training",
    "StableOnlyWarning": "generic",
    "UndeterminedModelWarning": "generic",
    "UnexcitedModeWarning": "generic",
    "FeedbackWarning": "generic",
    "train": "training",
}

__all__ = [
    "CCF",
    "MCF",
    "EncoderConfig",
    "Estimate",
    "FeedbackWarning",
    "Head",
    "Identifier",
    "Identifies",
    "LegFamily",
    "ParameterFamily",
    "Physical",
    "PoleFamily",
    "Record",
    "RefineConfig",
    "Structure",
    "StableOnlyWarning",
    "System",
    "TrainConfig",
    "UndertrainedWarning",
    "UndeterminedModelWarning",
    "UnexcitedModeWarning",
    "compare",
    "discretise",
    "identify",
    "initial_state",
    "load",
    "load_pretrained",
    "simulate",
    "stationary_value",
    "train",
]
__version__ = "0.1.0"


def __getattr__(name: str):
    """Import a public name's submodule on first access and cache the name here; a submodule's
    own name imports it (importing sets it as an attribute, so this runs once per name)."""
    source = _SOURCES.get(name)
    if source is not None:
        value = getattr(import_module(f".{source}", __name__), name)
        globals()[name] = value          # later accesses skip __getattr__
        return value
    if not name.startswith("__") and find_spec(f"{__name__}.{name}") is not None:
        return import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
