"""Classical baselines behind the library's ``Estimate`` type: n4sid, least squares, CasADi
cold start, and the benchmark's failure rule.

All return the library's :class:`~aeid_struct.identification.Estimate`, so that the benchmark
treats them like the encoder. A failure that depends on the data does not raise: the estimate
comes back with ``info["failed"] = True`` and a ``info["reason"]``; bad arguments raise
``ValueError`` naming the argument.

Modules: ``continuous`` (discrete -> continuous time), ``n4sid``, ``least_squares``,
``casadi_cold``, ``start`` (the generic start), ``models`` (a structure's model in numpy),
``checks``, ``failure``, ``classical`` (:class:`Classical`).
"""

from aeid_struct.baselines.casadi_cold import casadi_cold as casadi_cold
from aeid_struct.baselines.classical import Classical as Classical
from aeid_struct.baselines.continuous import Continuous as Continuous
from aeid_struct.baselines.continuous import NoRealLogarithm as NoRealLogarithm
from aeid_struct.baselines.continuous import to_continuous as to_continuous
from aeid_struct.baselines.failure import failed as failed
from aeid_struct.baselines.failure import failure as failure
from aeid_struct.baselines.least_squares import least_squares as least_squares
from aeid_struct.baselines.n4sid import n4sid as n4sid
from aeid_struct.baselines.start import generic_start as generic_start

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
