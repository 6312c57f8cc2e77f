"""Refinement: the CasADi NLP that polishes an estimate in its own structure.
"""

from aeid_struct.refinement.nlp import CacheInfo as CacheInfo
from aeid_struct.refinement.nlp import RefineConfig as RefineConfig
from aeid_struct.refinement.nlp import RefineResult as RefineResult
from aeid_struct.refinement.nlp import cache_info as cache_info
from aeid_struct.refinement.nlp import casadi_simulate as casadi_simulate
from aeid_struct.refinement.nlp import clear_cache as clear_cache
from aeid_struct.refinement.nlp import expm as expm
from aeid_struct.refinement.nlp import refine as refine
from aeid_struct.refinement.nlp import refine_elements as refine_elements

__all__ = [
    "CacheInfo",
    "RefineConfig",
    "RefineResult",
    "cache_info",
    "casadi_simulate",
    "clear_cache",
    "expm",
    "refine",
    "refine_elements",
]
