"""The walk of checked records through an identifier, whatever its back end: the back end's
model of the good records (torch, numpy or ONNX: ``Identifier.backend``), the separable head, the
overflow check and the :class:`Estimate` (records that cannot be identified set aside with NaN
model rows). No torch here: an identifier read from an ONNX export walks it without torch."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from aeid_struct.estimates import Estimate
from aeid_struct.identification.head import apply_head, head_failure
from aeid_struct.records import RecordBatch, overflow_problem
from aeid_struct.structures import type_of

__all__ = ["estimate_of", "identify_record", "refine_with_head"]


def identify_record(ident, record: RecordBatch, start: float, errors: str,
                    head=None, provenance=None) -> Estimate:
    """The Estimate of a checked record (``Identifier.identify`` after its checks).

    Parameters
    ----------
    ident : Identifier
    record : RecordBatch
        From ``records.check_record``, with each system's problem.
    start : float
        ``time.perf_counter()`` when the identification began.
    errors : {"raise", "collect"}
    head : Head, optional
        In place of ``ident.head`` (``Head.converged()`` for the refinement).
    provenance : Provenance, optional
        ``ident.provenance``, read by the caller (the identifier hands it over, so that this
        module's walk never calls back into the identifier's module).

    Returns
    -------
    Estimate
    """
    # every record good (the common case, one per tracker window): no mask built, nothing to
    # raise; a Python count over the problems, a few microseconds less than numpy's
    every = record.problems.count(None) == len(record.problems)
    if errors == "raise" and not every:
        record.raise_first()
    good = _ALL_GOOD if every and record.count == 1 else record.good
    with np.errstate(over="ignore", invalid="ignore"):   # overflow: _overflowed says it
        model, missed = _on_rows(ident, record, good, every,
                                 ident.head if head is None else head)
    if missed is not None and missed.any():
        out = list(record.problems)
        used = ident.head if head is None else head
        for r in np.flatnonzero(missed):
            out[r] = head_failure(int(r), used)
        record = dataclasses.replace(record, problems=tuple(out))
        good = good & ~missed
        every = False
        if errors == "raise":
            record.raise_first()
    if record.records == 1:
        problems = _overflowed(record, good, every, model)
        if problems is not record.problems:
            record = dataclasses.replace(record, problems=problems)
            if errors == "raise":
                record.raise_first()
    return estimate_of(ident, record, model, start, None if errors == "raise"
                       else record.problems, provenance)


def refine_with_head(ident, record: RecordBatch, start: float, errors: str,
                     head, provenance=None) -> Estimate:
    """``identify(refine=True)`` of an identifier with a head: the head iterated to
    convergence (``Head.converged``), the least-squares optimum in its structure, batched
    (``refinement.fit_rows``) in place of the CasADi NLP.

    Parameters
    ----------
    ident : Identifier
        With ``ident.head`` set.
    record : RecordBatch
    start : float
    errors : {"raise", "collect"}
    head : Head
        ``ident.head.converged()``, made by the caller (the identifier's own step, so that
        this module's walk never goes back to it).
    provenance : Provenance, optional
        As :func:`identify_record`.

    Returns
    -------
    Estimate
        ``refined`` True, ``info["refine"] = "separable"``; a physical structure's records
        left on a bound are refined by the NLP (``polish.polish_at_bounds``), and
        ``info["std"]`` holds its parameters' standard errors
        (``polish.with_standard_errors``).
    """
    est = identify_record(ident, record, start, errors, head, provenance)
    est = dataclasses.replace(est, refined=True, info={**est.info, "refine": "separable"})
    if type_of(ident.structure) != "Physical":
        return est
    from aeid_struct.identification.physical_head import physical_head
    from aeid_struct.identification.polish import polish_at_bounds, with_standard_errors

    est = with_standard_errors(polish_at_bounds(est))
    if physical_head(ident.structure, ident.initial == "fitted").inverse.reached_from_anywhere:
        return est            # the one pass's nearest parameters are the same ones
    return no_worse_than_one_pass(ident, record, start, provenance, est)


def no_worse_than_one_pass(ident, record: RecordBatch, start: float, provenance,
                           est: Estimate) -> Estimate:
    """``est``, a physical structure's refinement that started over from the encoder's poles,
    no worse than the one pass of the same records (``multistart.no_worse_than``).

    Parameters
    ----------
    ident : Identifier
    record : RecordBatch
    start : float
    provenance : Provenance or None
        As :func:`identify_record`.
    est : Estimate
        The refinement.

    Returns
    -------
    Estimate
    """
    from aeid_struct.identification.multistart import no_worse_than

    t0 = time.perf_counter()
    # "collect": a record whose one pass fails is simply not compared, never an error here
    one = identify_record(ident, record, start, "collect", provenance=provenance)
    out = no_worse_than(est, one)
    return dataclasses.replace(out, seconds=est.seconds + time.perf_counter() - t0)


def _on_rows(ident, record: RecordBatch, good: np.ndarray, every: bool, head) -> tuple:
    """Float64 ``A, b, c, d, elements`` of every system, NaN rows where ``good`` is False
    (``every``: none is): the good records through the identifier's back end
    (``ident.backend``), then the ``head``, if any. Returns ``(model, missed)``: ``missed
    (count,)`` marks the records the head found no finite model for (NaN rows); None without
    a head."""
    ys, us = record.y, record.u
    missed = None if head is None else np.zeros(good.shape, dtype=bool)
    rows = slice(None) if every else np.flatnonzero(good)
    if not every:
        ys, us = [v[rows] for v in ys], [v[rows] for v in us]
    parts = None
    if every or rows.size:
        parts = ident.backend.model(ident, _encoded(ident, list(ys)), list(us))
        if head is not None:
            parts, missed[rows] = apply_head(ident, head, list(ys), list(us), parts)
    if every:
        return parts, missed
    R, count = record.records, record.count
    n, q = ident.structure.n, len(ident.structure.element_names)
    axis = () if R == 1 else (R,)
    model = tuple(np.full((count, *axis, *shape), math.nan)
                  for shape in ((n, n), (n,), (n,), ())) + (np.full((count, q), math.nan),)
    if parts is not None:
        for whole, part in zip(model, parts, strict=True):
            whole[rows] = part
    return model, missed


def _encoded(ident, ys: list) -> list:
    """The records as the encoder reads them (``physical_head.centred``: a physical
    structure's integrating records less their first sample)."""
    if type_of(ident.structure) != "Physical":
        return ys
    from aeid_struct.identification.physical_head import centred

    return centred(ident.structure, ident.initial == "fitted", ys)


def _overflowed(record: RecordBatch, good: np.ndarray, every: bool, model: tuple) -> tuple:
    """The record's problems with a reason added for each good record whose identified model
    is not finite, and its model rows set to NaN (in place); ``every``: all records are good.

    Why: the de-normalisation multiplies ``c, d`` by ``max|y| / max|u|`` (Eq. 15 and
    linearity); a record of 1e308 has a model whose ``c`` lies beyond float64 (inf), which
    must not come back as an estimate."""
    problems = record.problems
    if every and _finite(model):
        return problems       # the common case, in microseconds (a window of a stream)
    finite = np.ones(len(problems), dtype=bool)
    for part in model:
        finite &= np.isfinite(part.reshape(len(problems), -1)).all(axis=1)
    bad = good & ~finite
    if not bad.any():
        return problems
    out = list(problems)
    y2, u2 = record.y[0], record.u[0]
    u_bar = np.abs(u2).max(axis=1)
    for r in np.flatnonzero(bad):
        out[r] = overflow_problem(r, np.abs(y2[r]).max() / u_bar[r])
        for part in model:
            part[r] = math.nan
    return tuple(out)


#: The mask of one good record (read only).
_ALL_GOOD = np.ones(1, dtype=bool)
_ALL_GOOD.flags.writeable = False


def _finite(model: tuple) -> bool:
    """Whether every entry of the model is finite (False may be an overflow of a sum)."""
    if model[0].shape[0] == 1:
        # one record's few dozen numbers: Python floats, a third of five numpy reductions' time
        return all(map(math.isfinite, [x for part in model for x in part.ravel().tolist()]))
    # a sum of the parts' sums is finite only where every entry is (an overflow of the sum
    # itself goes on to the entries' own check)
    return math.isfinite(sum(float(np.add.reduce(part, axis=None)) for part in model))


def estimate_of(ident, record: RecordBatch, model: tuple, start: float, errors,
                provenance=None) -> Estimate:
    """Wrap float64 ``A (count, ...), b, c, d, elements (count, q)`` of ``record`` as the
    Estimate (unbatched where the record is).

    Parameters
    ----------
    ident : Identifier
    record : RecordBatch
    model : tuple of arrays
    start : float
    errors : tuple or None
    provenance : Provenance, optional
        Default: ``ident.provenance``.

    Returns
    -------
    Estimate
    """
    A, b, c, d, el = model
    names = ident.structure.element_names
    if record.batched:
        elements = {name: el[:, i] for i, name in enumerate(names)}
    else:
        elements = dict(zip(names, el[0].tolist(), strict=True))
        A, b, c, d = A[0], b[0], c[0], (float(d[0]) if record.records == 1 else d[0])
    return Estimate(A=A, b=b, c=c, d=d, elements=elements, record=record,
                    provenance=ident.provenance if provenance is None else provenance,
                    seconds=time.perf_counter() - start,
                    errors=errors)
