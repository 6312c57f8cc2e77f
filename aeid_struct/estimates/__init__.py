"""Estimates: the one result of every identification and every fit (:class:`Estimate`), where it
comes from (:class:`Provenance`), how far it lies beyond an identifier's training range
(``calibration``), and its model in other forms (python-control state spaces, physical
parameters through a CasADi inverse).

Layer: below ``refinement`` (a refinement returns an Estimate) and above the kernels it reads
(``records``, ``metrics``, ``simulation``, ``structures``).
"""

from aeid_struct.estimates.calibration import FLAG_FALSE_RATE as FLAG_FALSE_RATE
from aeid_struct.estimates.calibration import excess as excess
from aeid_struct.estimates.estimate import Estimate as Estimate
from aeid_struct.estimates.estimate import Provenance as Provenance
from aeid_struct.estimates.physical import inverse_of_models as inverse_of_models
from aeid_struct.estimates.physical import through_ccf as through_ccf

__all__ = [
    "Estimate",
    "FLAG_FALSE_RATE",
    "Provenance",
    "excess",
    "inverse_of_models",
    "through_ccf",
]
