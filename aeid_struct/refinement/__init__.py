"""Refinement: the CasADi NLP that polishes an estimate in its own structure.

Layer: below ``identification`` (an estimate is taken duck-typed and returned through
``dataclasses.replace``).
"""

from aeid_struct.refinement.config import SOLVERS as SOLVERS
from aeid_struct.refinement.config import CacheInfo as CacheInfo
from aeid_struct.refinement.config import RefineConfig as RefineConfig
from aeid_struct.refinement.config import RefineResult as RefineResult
from aeid_struct.refinement.nlp import Numeric as Numeric
from aeid_struct.refinement.nlp import cache_info as cache_info
from aeid_struct.refinement.nlp import casadi_simulate as casadi_simulate
from aeid_struct.refinement.nlp import clear_cache as clear_cache
from aeid_struct.refinement.nlp import expm as expm
from aeid_struct.refinement.record import BUCKETS as BUCKETS
from aeid_struct.refinement.record import RecordFit as RecordFit
from aeid_struct.refinement.record import refine_record as refine_record
from aeid_struct.refinement.solve import refine as refine
from aeid_struct.refinement.solve import refine_elements as refine_elements

__all__ = [
    "BUCKETS",
    "CacheInfo",
    "Numeric",
    "RecordFit",
    "RefineConfig",
    "RefineResult",
    "SOLVERS",
    "cache_info",
    "casadi_simulate",
    "clear_cache",
    "expm",
    "refine",
    "refine_elements",
    "refine_record",
]
