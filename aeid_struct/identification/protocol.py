"""The identifier protocol: whatever identifies answers ``identify(record) -> Estimate``.

The leg identifiers (:class:`~aeid_struct.identification.Identifier`, one class on its back ends:
torch, its numpy pass for one record, or an export's ONNX graph), the generic identifiers
(``generic.GenericIdentifier``) and the classical methods behind an identifier's interface
(``baselines.Classical``) all take a measured ``records.Record`` (or the arrays each has always
taken, converted once at its boundary by ``records.arrays_of``) and return one
:class:`~aeid_struct.estimates.Estimate`; code that identifies (the tracker, scorecards,
benchmarks) is written against this protocol and takes any of them.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from aeid_struct.estimates import Estimate

__all__ = ["Identifies"]


@runtime_checkable
class Identifies(Protocol):
    """Anything with ``identify(record, ...) -> Estimate`` (``isinstance`` checks the method).

    Methods
    -------
    identify(record, /, *args, **options) -> Estimate
        ``record``: a ``records.Record`` (one output, one input), or the identifier's own
        array form (``y`` with ``u``); ``options`` are the identifier's own (``refine`` and
        the like).
    """

    def identify(self, record, /, *args, **options) -> Estimate:
        """Identify ``record``.

        Parameters
        ----------
        record : Record or arrays
        *args, **options
            The identifier's own.

        Returns
        -------
        Estimate
        """
        ...
