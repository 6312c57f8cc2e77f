"""Structures: raw encoder output ``theta (batch, p)`` -> ``(A, b, c, d)`` with constraints by
construction (CCF, MCF, fixed elements, physical parameters through a CasADi map).
"""

from aeid_struct.structures.base import CCF as CCF
from aeid_struct.structures.base import MCF as MCF
from aeid_struct.structures.base import Physical as Physical
from aeid_struct.structures.base import Structure as Structure
from aeid_struct.structures.base import System as System

__all__ = [
    "CCF",
    "MCF",
    "Physical",
    "Structure",
    "System",
]
