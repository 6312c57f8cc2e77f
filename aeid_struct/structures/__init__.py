"""Structures: raw encoder output ``theta (batch, p)`` -> ``(A, b, c, d)`` with constraints by
construction (CCF, MCF, fixed elements, physical parameters through a CasADi map).
"""

from aeid_struct.structures.base import CCF as CCF
from aeid_struct.structures.base import MCF as MCF
from aeid_struct.structures.base import Physical as Physical
from aeid_struct.structures.base import Structure as Structure
from aeid_struct.structures.base import System as System
from aeid_struct.structures.casadi_torch import CasadiOp as CasadiOp
from aeid_struct.structures.maps import check_maps as check_maps
from aeid_struct.structures.maps import factory as factory
from aeid_struct.structures.maps import from_entry as from_entry
from aeid_struct.structures.maps import reference as reference
from aeid_struct.structures.maps import resolve as resolve
from aeid_struct.structures.maps import sha256 as sha256
from aeid_struct.structures.maps import to_entry as to_entry

__all__ = [
    "CCF",
    "CasadiOp",
    "MCF",
    "Physical",
    "Structure",
    "System",
    "check_maps",
    "factory",
    "from_entry",
    "reference",
    "resolve",
    "sha256",
    "to_entry",
]
