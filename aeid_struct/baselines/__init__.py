"""Classical baselines behind the library's ``Estimate`` type: n4sid, least squares, CasADi
cold start.
"""

from aeid_struct.baselines.classical import Classical as Classical
from aeid_struct.baselines.classical import Continuous as Continuous
from aeid_struct.baselines.classical import NoRealLogarithm as NoRealLogarithm
from aeid_struct.baselines.classical import casadi_cold as casadi_cold
from aeid_struct.baselines.classical import failed as failed
from aeid_struct.baselines.classical import failure as failure
from aeid_struct.baselines.classical import generic_start as generic_start
from aeid_struct.baselines.classical import least_squares as least_squares
from aeid_struct.baselines.classical import n4sid as n4sid
from aeid_struct.baselines.classical import to_continuous as to_continuous

__all__ = [
    "Classical",
    "Continuous",
    "NoRealLogarithm",
    "casadi_cold",
    "failed",
    "failure",
    "generic_start",
    "least_squares",
    "n4sid",
    "to_continuous",
]
