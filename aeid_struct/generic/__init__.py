"""Generic identifiers for any SISO system and any measured record (issue 14): trained once in
normalised time (dt = 1), applied to records of any length and sample time.

Layer: above ``identification`` (its :func:`identify` returns an ``Estimate``) and
``refinement``, below ``training``.

Modules: ``poles`` (raw network outputs -> stable factors -> denominator), ``model``
(``GenericConfig``, ``GenericIdentifier``: a window -> its poles; the shipped names), ``files``
(the ``.aeid`` file: the one container, kind ``"generic"``), ``windows`` (candidates from
windows at several time scales, the whole-record choice), ``delay`` (the input delay: ARX scan,
projection re-scan), ``one_call`` (:func:`identify`; its steps in ``pipeline``),
``comparison`` (:func:`compare`, MATLAB's ``compare`` with the initial state fitted),
``feedback`` (is the record closed-loop? residuals against later inputs).
"""

from aeid_struct.generic.boundary import shortest as shortest
from aeid_struct.generic.classical import MAX_ORDER as MAX_ORDER
from aeid_struct.generic.classical import NoEncoder as NoEncoder
from aeid_struct.generic.classical import arx as arx
from aeid_struct.generic.comparison import Comparison as Comparison
from aeid_struct.generic.comparison import compare as compare
from aeid_struct.generic.delay import arx_delay as arx_delay
from aeid_struct.generic.delay import rescan as rescan
from aeid_struct.generic.feedback import FeedbackWarning as FeedbackWarning
from aeid_struct.generic.feedback import feedback_test as feedback_test
from aeid_struct.generic.files import FORMAT as FORMAT
from aeid_struct.generic.holdout import HOLDOUT_FLOOR as HOLDOUT_FLOOR
from aeid_struct.generic.holdout import HOLDOUT_RATIO as HOLDOUT_RATIO
from aeid_struct.generic.holdout import UndeterminedModelWarning as UndeterminedModelWarning
from aeid_struct.generic.holdout import holdout_flagged as holdout_flagged
from aeid_struct.generic.model import GENERIC as GENERIC
from aeid_struct.generic.model import ORDERS as ORDERS
from aeid_struct.generic.model import GenericConfig as GenericConfig
from aeid_struct.generic.model import GenericIdentifier as GenericIdentifier
from aeid_struct.generic.model import load_generic as load_generic
from aeid_struct.generic.model import normalise_windows as normalise_windows
from aeid_struct.generic.model import read_generic as read_generic
from aeid_struct.generic.model import save_generic as save_generic
from aeid_struct.generic.model import spectra as spectra
from aeid_struct.generic.one_call import ORDER_TOLERANCE as ORDER_TOLERANCE
from aeid_struct.generic.one_call import identify as identify
from aeid_struct.generic.one_call import measured as measured
from aeid_struct.generic.pipeline import StableOnlyWarning as StableOnlyWarning
from aeid_struct.generic.pipeline import UnexcitedModeWarning as UnexcitedModeWarning
from aeid_struct.generic.poles import denominator as denominator
from aeid_struct.generic.poles import factors as factors
from aeid_struct.generic.poles import poles_of as poles_of
from aeid_struct.generic.poles import raw_of as raw_of
from aeid_struct.generic.scoring import scores as scores
from aeid_struct.generic.scoring import solution as solution
from aeid_struct.generic.windows import GROWTH as GROWTH
from aeid_struct.generic.windows import Windows as Windows
from aeid_struct.generic.windows import candidates as candidates
from aeid_struct.generic.windows import unshift as unshift
from aeid_struct.generic.windows import weighted as weighted

__all__ = [
    "Comparison",
    "FORMAT",
    "FeedbackWarning",
    "GENERIC",
    "GROWTH",
    "GenericConfig",
    "GenericIdentifier",
    "HOLDOUT_FLOOR",
    "HOLDOUT_RATIO",
    "MAX_ORDER",
    "NoEncoder",
    "ORDERS",
    "ORDER_TOLERANCE",
    "StableOnlyWarning",
    "UndeterminedModelWarning",
    "UnexcitedModeWarning",
    "Windows",
    "arx",
    "arx_delay",
    "candidates",
    "compare",
    "denominator",
    "factors",
    "feedback_test",
    "holdout_flagged",
    "identify",
    "load_generic",
    "measured",
    "normalise_windows",
    "poles_of",
    "raw_of",
    "read_generic",
    "rescan",
    "save_generic",
    "scores",
    "shortest",
    "solution",
    "spectra",
    "unshift",
    "weighted",
]
