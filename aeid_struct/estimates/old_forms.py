"""Reading the old forms of ``Estimate(...)``: the positional order and the keywords ``y, u, dt``
of the code written before an Estimate referred to a :class:`~aeid_struct.records.RecordBatch`
and a ``Provenance``. The seam: the deprecated ways in, kept apart from the class they feed
(``estimate.py``), so that dropping them one day touches this module and one call each.

The old provenance keywords (``structure, initial, training_range, _inverse``) are applied next
to ``Provenance`` itself, in ``estimate.py``.
"""

from __future__ import annotations

import warnings

from aeid_struct.records import Record, RecordBatch

__all__ = ["OLD", "POSITIONAL", "arguments", "record_of"]

#: The old positional order of ``Estimate(...)`` (kept for code written before Provenance).
POSITIONAL = ("A", "b", "c", "d", "elements", "y", "u", "dt", "seconds", "refined", "info",
              "_inverse")
#: The old keywords: the record's and the provenance's fields, which an Estimate now refers to.
OLD = {"y", "u", "dt", "structure", "initial", "training_range", "_inverse"}


def arguments(legacy: tuple, values: dict, old: dict) -> dict:
    """The Estimate's own fields from the old positional form ``legacy`` and the keywords
    ``values``; the old positional ``y, u, dt, _inverse`` go to ``old`` (in place)."""
    if legacy:
        # stacklevel 3: the line that called Estimate(...), through Estimate.__init__
        warnings.warn("Estimate(A, b, c, d, elements, y, u, dt, ...) positionally is deprecated: "
                      "construct it with keywords, Estimate(A=..., b=..., c=..., d=..., "
                      "elements=..., record=..., provenance=Provenance(...))",
                      DeprecationWarning, stacklevel=3)
    if len(legacy) > len(POSITIONAL):
        raise TypeError(f"Estimate takes at most {len(POSITIONAL)} positional arguments (the "
                        f"old form); got {len(legacy)}")
    given = dict(zip(POSITIONAL, legacy, strict=False))   # a prefix of the old order
    values = {k: given.get(k, v) for k, v in values.items()}
    old.update({k: given[k] for k in ("y", "u", "dt", "_inverse") if k in given})
    unknown = sorted(set(old) - OLD)
    if unknown:
        raise TypeError(f"Estimate got unexpected keyword arguments {unknown}")
    if any(values[k] is None for k in ("A", "b", "c", "d", "elements")):
        raise TypeError("Estimate needs A, b, c, d and elements")
    return values


def record_of(record: RecordBatch | None, old: dict, ndim: int) -> RecordBatch:
    """The estimate's record: ``record``, or one of the old keywords ``y, u, dt`` (over
    ``record``'s where both are given)."""
    if isinstance(record, Record):
        record = RecordBatch.of(record.y, record.u, record.dt, batched=False)
    if record is not None and not {"y", "u", "dt"} & set(old):
        return record
    if record is None and "y" not in old:
        raise TypeError("Estimate needs a record (or the old y, u, dt)")
    y = old["y"] if "y" in old else record.given(record.y)
    u = old["u"] if "u" in old else (None if record is None else record.given(record.u))
    dt = old["dt"] if "dt" in old else (None if record is None else record.times)
    return RecordBatch.of(y, u, dt, batched=ndim == (4 if isinstance(y, tuple) else 3))
