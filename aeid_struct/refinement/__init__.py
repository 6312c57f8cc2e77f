"""Refinement: fits of a model to the least-squares / output-error optimum, in its own
structure. One Levenberg-Marquardt (``core``) over four problems: the partly fixed CCFs of many
records at once (``batched``; compiled to C by ``compiled``), the variable projection of a free
CCF (``projected``, ``separable``), any structure over a CasADi graph with its delay, offset
and initial state (``record``), parameters shared by several records (``joint``) and the CCFs
of channels summed into outputs (``summed``); and the
CasADi NLP (``nlp``, ``solve``) for the constraints that loop does not know. A fit over a
record returns an :class:`~aeid_struct.estimates.Estimate`.

Layer: below ``identification``, above ``estimates`` (a refinement returns the one Estimate).

The separable pass of the partly fixed CCFs (``batched``, ``compiled``, ``levenberg``: the
identifiers' head) needs numpy and CasADi alone and is imported with the package; the NLP and
the fits over a record (torch through the structures) on first use of their names.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from aeid_struct.lazy import attach
from aeid_struct.refinement.batched import Pattern as Pattern
from aeid_struct.refinement.compiled import MAX_ITERATIONS as MAX_ITERATIONS
from aeid_struct.refinement.config import SOLVERS as SOLVERS
from aeid_struct.refinement.config import CacheInfo as CacheInfo
from aeid_struct.refinement.config import RefineConfig as RefineConfig
from aeid_struct.refinement.core import Rules as Rules
from aeid_struct.refinement.core import minimise as minimise
from aeid_struct.refinement.levenberg import fit_rows as fit_rows
from aeid_struct.structures import Numeric as Numeric

if TYPE_CHECKING:
    from aeid_struct.refinement.joint import JointFit as JointFit
    from aeid_struct.refinement.joint import fit_joint as fit_joint
    from aeid_struct.refinement.joint import joint_jacobian as joint_jacobian
    from aeid_struct.refinement.joint import joint_residual as joint_residual
    from aeid_struct.refinement.nlp import cache_info as cache_info
    from aeid_struct.refinement.nlp import casadi_simulate as casadi_simulate
    from aeid_struct.refinement.nlp import clear_cache as clear_cache
    from aeid_struct.refinement.nlp import expm as expm
    from aeid_struct.refinement.record import BUCKETS as BUCKETS
    from aeid_struct.refinement.record import refine_record as refine_record
    from aeid_struct.refinement.separable import projected_cost as projected_cost
    from aeid_struct.refinement.separable import refine_separable as refine_separable
    from aeid_struct.refinement.solve import refine as refine
    from aeid_struct.refinement.summed import SummedFit as SummedFit
    from aeid_struct.refinement.summed import fit_summed as fit_summed

#: name -> the module (of this package) that defines it, imported on first use
_LAZY = {
    "cache_info": "nlp",
    "casadi_simulate": "nlp",
    "clear_cache": "nlp",
    "expm": "nlp",
    "JointFit": "joint",
    "fit_joint": "joint",
    "joint_jacobian": "joint",
    "joint_residual": "joint",
    "BUCKETS": "record",
    "refine_record": "record",
    "projected_cost": "separable",
    "refine_separable": "separable",
    "refine": "solve",
    "SummedFit": "summed",
    "fit_summed": "summed",
}

__all__ = [
    "BUCKETS",
    "MAX_ITERATIONS",
    "CacheInfo",
    "JointFit",
    "Numeric",
    "Pattern",
    "RefineConfig",
    "Rules",
    "SOLVERS",
    "SummedFit",
    "cache_info",
    "casadi_simulate",
    "clear_cache",
    "expm",
    "fit_joint",
    "fit_rows",
    "fit_summed",
    "joint_jacobian",
    "joint_residual",
    "minimise",
    "projected_cost",
    "refine",
    "refine_record",
    "refine_separable",
]


#: Names that are gone, read with a DeprecationWarning naming what replaced them.
_DEPRECATED = {
    "RefineResult": ("aeid_struct.refinement.config", "RefineResult",
                     "refinement.RefineResult is private to refinement: refine(Estimate) returns "
                     "an Estimate (its info holds the solver's status, iterations, loss and "
                     "success)"),
    "refine_elements": ("aeid_struct.refinement.solve", "refine_elements",
                        "refinement.refine_elements (which returns the private RefineResult) is "
                        "deprecated: refine(Estimate) returns the refined Estimate"),
    "SeparableFit": ("aeid_struct.refinement.batched", "SeparableFit",
                     "refinement.SeparableFit is private to refinement: refine_separable and "
                     "Identifier.identify(refine=True) return an Estimate; refinement.fit_rows "
                     "gives a batch's CCF arrays"),
    "gauss_newton": ("aeid_struct.refinement.levenberg", "gauss_newton",
                     "refinement.gauss_newton (which returns the private SeparableFit) is "
                     "deprecated: refinement.fit_rows gives the same fit as the CCF's arrays, "
                     "refine_separable and Identifier.identify(refine=True) as an Estimate"),
    "RecordFit": ("aeid_struct.estimates", "Estimate",
                  "refinement.RecordFit is gone: refine_record and refine_separable return an "
                  "Estimate (its info holds cost, iterations and converged; Estimate.offset is "
                  "the former y_offset)"),
}

__getattr__, __dir__ = attach(__name__, _LAZY, deprecated=_DEPRECATED)
