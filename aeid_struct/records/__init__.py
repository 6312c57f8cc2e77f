"""Measured records: the one place where a user's ``y`` and ``u`` become validated float64 arrays.

Every entry point that reads a record -- ``Identifier.identify`` (every back end, ONNX
included), ``online.Tracker``, ``refine`` and the baselines -- checks it here, so that a bad
input gets the same answer (the same exception, the same message) whichever way it comes in.
:func:`check_record` checks a user's records once into a frozen :class:`RecordBatch` (``y, u,
dt`` per record, the batch flag, each system's problem); everything behind the boundary (the
encoder pass, the ``Estimate``, the refinement) takes that value and checks nothing again.

:class:`Record` is the user's measured record (MATLAB's ``iddata``): one output, one input, a
sample time, offsets, a known or unknown input delay, validated once when it is made.
"""

from aeid_struct.records.checks import Checked as Checked
from aeid_struct.records.checks import RecordError as RecordError
from aeid_struct.records.checks import as_array as as_array
from aeid_struct.records.checks import as_records as as_records
from aeid_struct.records.checks import check_dt as check_dt
from aeid_struct.records.checks import check_records as check_records
from aeid_struct.records.checks import denormalise as denormalise
from aeid_struct.records.checks import normalise as normalise
from aeid_struct.records.checks import overflow_problem as overflow_problem
from aeid_struct.records.checks import record_problems as record_problems
from aeid_struct.records.checks import require_finite as require_finite
from aeid_struct.records.checks import unit_step as unit_step
from aeid_struct.records.measured import INTERSAMPLE as INTERSAMPLE
from aeid_struct.records.measured import SAFE_EXPONENT as SAFE_EXPONENT
from aeid_struct.records.measured import Record as Record
from aeid_struct.records.measured import exact_scale as exact_scale
from aeid_struct.records.record import RecordBatch as RecordBatch
from aeid_struct.records.record import arrays_of as arrays_of
from aeid_struct.records.record import check_record as check_record
from aeid_struct.records.units import Units as Units

__all__ = [
    "INTERSAMPLE",
    "SAFE_EXPONENT",
    "Checked",
    "Record",
    "RecordBatch",
    "RecordError",
    "Units",
    "arrays_of",
    "as_array",
    "as_records",
    "check_dt",
    "check_record",
    "check_records",
    "denormalise",
    "exact_scale",
    "normalise",
    "overflow_problem",
    "record_problems",
    "require_finite",
    "unit_step",
]
