"""Generic identifiers for any SISO system and any measured record (issue 14): trained once in
normalised time (dt = 1), applied to records of any length and sample time.

Layer: above ``identification`` (its :func:`identify` returns an ``Estimate``) and
``refinement``, below ``training``.

Modules: ``windows`` (candidates from windows at several time scales, the whole-record choice),
``delay`` (the input delay: ARX scan, projection re-scan), ``one_call`` (:func:`identify`),
``comparison`` (:func:`compare`, MATLAB's ``compare`` with the initial state fitted).
"""

from aeid_struct.generic.comparison import Comparison as Comparison
from aeid_struct.generic.comparison import compare as compare
from aeid_struct.generic.delay import arx_delay as arx_delay
from aeid_struct.generic.delay import rescan as rescan
from aeid_struct.generic.one_call import ORDER_TOLERANCE as ORDER_TOLERANCE
from aeid_struct.generic.one_call import Measured as Measured
from aeid_struct.generic.one_call import identify as identify
from aeid_struct.generic.one_call import measured as measured
from aeid_struct.generic.windows import Windows as Windows
from aeid_struct.generic.windows import candidates as candidates
from aeid_struct.generic.windows import scores as scores
from aeid_struct.generic.windows import solution as solution

__all__ = [
    "Comparison",
    "Measured",
    "ORDER_TOLERANCE",
    "Windows",
    "arx_delay",
    "candidates",
    "compare",
    "identify",
    "measured",
    "rescan",
    "scores",
    "solution",
]
