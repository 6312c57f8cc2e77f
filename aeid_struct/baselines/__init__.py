"""Classical baselines behind the library's ``Estimate`` type: n4sid, least squares, CasADi
cold start, and the benchmark's failure rule.

All return the library's :class:`~aeid_struct.estimates.Estimate`, so that the benchmark
treats them like the encoder. A failure that depends on the data does not raise: the estimate
comes back with ``info["failed"] = True`` and a ``info["reason"]``; bad arguments raise
``ValueError`` naming the argument.

Modules: ``continuous`` (discrete -> continuous time), ``subspace`` (:func:`n4sid`),
``output_error`` (:func:`least_squares`), ``free_initial`` (both on a ``Record`` not at rest:
free initial state, offset, known delay), ``cold_nlp`` (:func:`casadi_cold`), ``start`` (the
generic start), ``models`` (a structure's model in numpy), ``checks``, ``failures``
(:func:`failure`), ``classical`` (:class:`Classical`). No module shares a name with a function
the package exports, so ``from aeid_struct.baselines import failure`` is the function to every
tool.
"""

from aeid_struct.baselines.classical import Classical as Classical
from aeid_struct.baselines.cold_nlp import casadi_cold as casadi_cold
from aeid_struct.baselines.continuous import Continuous as Continuous
from aeid_struct.baselines.continuous import NoRealLogarithm as NoRealLogarithm
from aeid_struct.baselines.continuous import to_continuous as to_continuous
from aeid_struct.baselines.failures import failed as failed
from aeid_struct.baselines.failures import failure as failure
from aeid_struct.baselines.output_error import least_squares as least_squares
from aeid_struct.baselines.start import generic_start as generic_start
from aeid_struct.baselines.subspace import n4sid as n4sid

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
