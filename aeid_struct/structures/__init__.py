"""Structures: raw encoder output ``theta (batch, p)`` -> ``(A, b, c, d)`` with constraints by
construction (CCF, MCF, fixed elements, physical parameters through a CasADi map).

Modules: ``system`` (the assembled model), ``constraints`` (elementwise maps), ``elements``
(``theta`` <-> elements), ``config`` (a structure as data), ``base`` (``Structure``),
``canonical`` (``CCF``, ``MCF``), ``physical`` (``Physical``), ``realisation`` (a model in any
realisation -> CCF coefficients), ``casadi_torch`` (a CasADi Function as a torch operation),
``maps`` (named CasADi maps in model files), ``numeric`` (a CasADi Function evaluated on numpy
arrays).

``maps``, ``numeric`` and ``config`` need CasADi alone and are imported with the package; the
structures themselves (torch) on first use of their names, so that what reads a model file and
evaluates its maps (the ONNX runner, an Estimate's physical parameters) runs without torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from aeid_struct.lazy import attach
from aeid_struct.structures.config import Described as Described
from aeid_struct.structures.config import type_of as type_of
from aeid_struct.structures.maps import check_maps as check_maps
from aeid_struct.structures.maps import factory as factory
from aeid_struct.structures.maps import from_entry as from_entry
from aeid_struct.structures.maps import reference as reference
from aeid_struct.structures.maps import resolve as resolve
from aeid_struct.structures.maps import sha256 as sha256
from aeid_struct.structures.maps import to_entry as to_entry
from aeid_struct.structures.numeric import Numeric as Numeric
from aeid_struct.structures.numeric import expanded as expanded

if TYPE_CHECKING:
    from aeid_struct.structures.base import Structure as Structure
    from aeid_struct.structures.canonical import CCF as CCF
    from aeid_struct.structures.canonical import MCF as MCF
    from aeid_struct.structures.casadi_torch import CasadiOp as CasadiOp
    from aeid_struct.structures.physical import Physical as Physical
    from aeid_struct.structures.realisation import ccf_coefficients as ccf_coefficients
    from aeid_struct.structures.realisation import ccf_matrices as ccf_matrices
    from aeid_struct.structures.system import System as System

#: name -> the module (of this package, needing torch) that defines it
_LAZY = {
    "Structure": "base",
    "CCF": "canonical",
    "MCF": "canonical",
    "CasadiOp": "casadi_torch",
    "Physical": "physical",
    "ccf_coefficients": "realisation",
    "ccf_matrices": "realisation",
    "System": "system",
}

__all__ = [
    "CCF",
    "CasadiOp",
    "Described",
    "MCF",
    "Numeric",
    "Physical",
    "Structure",
    "System",
    "ccf_coefficients",
    "ccf_matrices",
    "check_maps",
    "expanded",
    "factory",
    "from_entry",
    "reference",
    "resolve",
    "sha256",
    "to_entry",
    "type_of",
]


#: The modules that define structure types: imported together, so that the registry a config
#: is read with (``Structure.from_config``) knows every type whichever name came first.
_TYPES = ("base", "canonical", "physical")

__getattr__, __dir__ = attach(__name__, _LAZY, together=_TYPES)
