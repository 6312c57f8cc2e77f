"""The identification pass of checked records: Eq. 15 per record in float64, the encoder, the
structure, the exact de-normalisation, and the :class:`Estimate` (records that cannot be
identified set aside with NaN model rows)."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import torch

from aeid_struct.estimates import Estimate
from aeid_struct.identification.fast_path import fast_path
from aeid_struct.identification.head import apply_head, head_failure
from aeid_struct.records import RecordBatch, normalise, overflow_problem
from aeid_struct.structures import System

__all__ = ["CHUNK", "differentiable", "encode", "estimate_of", "identify_record",
           "refine_with_head"]

#: Records through the encoder at once in a batched call.
CHUNK = 256


def differentiable(ident, y, u, *, raw: bool = False):
    """The differentiable pass of tensors (training uses it): Eq. 15, the encoder, the
    structure and the exact de-normalisation, in torch.

    Parameters
    ----------
    ident : Identifier
    y, u : (batch, steps) tensors, or sequences of R of them
    raw : bool
        Also return the encoder's standardised outputs.

    Returns
    -------
    System, elements (batch, q) tensor[, z (batch, p) tensor]
        In measured units.
    """
    ys, us = (tuple(y), tuple(u)) if ident.records > 1 else ((y,), (u,))
    y_bar = torch.stack([r.abs().amax(dim=1) for r in ys], 1)     # (batch, R)
    u_bar = torch.stack([r.abs().amax(dim=1) for r in us], 1)
    x = []
    for r, (y_r, u_r) in enumerate(zip(ys, us, strict=True)):
        channels = [2.0 * y_r / y_bar[:, r, None] - 1.0]         # Eq. 15
        if ident.inputs:
            channels.append(u_r / u_bar[:, r, None])
        x.append(torch.stack(channels, dim=1))
    features = None
    gain = y_bar / u_bar                                          # (batch, R)
    if ident.scale == "feature":
        mean, spread = (f.to(gain.device, gain.dtype) for f in ident._features)
        features = (torch.log(gain) - mean) / spread
    sys, elements, z = ident._decode(x, features)
    if ident.scale == "denormalise":
        gain = gain[:, 0]
        # Exact de-normalisation: the structure described u/u_bar -> y/y_bar (linearity).
        sys = System(sys.A, sys.b, sys.c * gain[:, None].to(sys.c.dtype),
                     sys.d * gain.to(sys.d.dtype))
        mask = ident._output_mask.to(elements.device, elements.dtype)
        elements = elements * (1.0 + mask * (gain[:, None].to(elements.dtype) - 1.0))
    return (sys, elements, z) if raw else (sys, elements)


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
    if errors == "raise":
        record.raise_first()
    good = record.good
    with np.errstate(over="ignore", invalid="ignore"):   # overflow: _overflowed says it
        model, missed = _on_rows(ident, record, good, ident.head if head is None else head)
    if missed.any():
        out = list(record.problems)
        used = ident.head if head is None else head
        for r in np.flatnonzero(missed):
            out[r] = head_failure(int(r), used)
        record = dataclasses.replace(record, problems=tuple(out))
        good = good & ~missed
        if errors == "raise":
            record.raise_first()
    if record.records == 1:
        record = dataclasses.replace(record, problems=_overflowed(record, good, model))
        if errors == "raise":
            record.raise_first()
    return estimate_of(ident, record, model, start, None if errors == "raise"
                       else record.problems, provenance)


def refine_with_head(ident, record: RecordBatch, start: float, errors: str,
                     head, provenance=None) -> Estimate:
    """``identify(refine=True)`` of an identifier with a head: the head iterated to
    convergence (``Head.converged``), the least-squares optimum in its structure, batched
    (``refinement.gauss_newton``) in place of the CasADi NLP.

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
        ``refined`` True, ``info["refine"] = "separable"``.
    """
    est = identify_record(ident, record, start, errors, head, provenance)
    return dataclasses.replace(est, refined=True, info={**est.info, "refine": "separable"})


def _on_rows(ident, record: RecordBatch, good: np.ndarray, head) -> tuple:
    """Float64 ``A, b, c, d, elements`` of every system, NaN rows where ``good`` is False; one
    single record through the batch-1 path (``fast_path``), the others batched; then the
    ``head``, if any. Returns ``(model, missed)``: ``missed (count,)`` marks the records the
    head found no finite model for (NaN rows)."""
    ys, us, rows = record.y, record.u, np.flatnonzero(good)
    missed = np.zeros(good.shape, dtype=bool)
    if not good.all():
        ys, us = [v[rows] for v in ys], [v[rows] for v in us]
    parts = None
    if rows.size:
        fast = fast_path(ident) if len(ys) == 1 and ys[0].shape[0] == 1 else None
        parts = fast(ys[0][0], us[0][0]) if fast is not None else encode(ident, list(ys),
                                                                             list(us))
        if head is not None:
            parts, missed[rows] = apply_head(ident, head, list(ys), list(us), parts)
    if good.all():
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


def encode(ident, ys: list, us: list) -> tuple:
    """Float64 ``A, b, c, d, elements`` of good records through the encoder, in chunks,
    without gradients.

    Eq. 15 runs per record in float64 (``records.normalise``) and only the normalised records,
    in ``[-1, 1]``, and the standardised scale features are cast to the encoder's float32; the
    model is de-normalised in float64. So one record of 1e40 (beyond float32) or 1e-44 (below
    its normal range) among others gives what it gives alone.

    Parameters
    ----------
    ident : Identifier
    ys, us : lists of R (count, steps_r) float64 arrays
        Good records (``us`` entries may be None: a unit step).

    Returns
    -------
    A : (count, n, n) or (count, R, n, n)
    b, c : (count, n) or (count, R, n)
    d : (count,) or (count, R)
    elements : (count, q)
    """
    count = ys[0].shape[0]
    x, gains = [], []
    for y2, u2 in zip(ys, us, strict=True):
        y_tilde, u_tilde, y_bar, u_bar = normalise(y2, u2)
        channels = [y_tilde, u_tilde] if ident.inputs else [y_tilde]
        x.append(torch.from_numpy(np.stack(channels, axis=1).astype(np.float32)))
        gains.append(y_bar / u_bar)
    gain = np.stack(gains, axis=1)                                   # (count, R)
    features = None
    if ident.scale == "feature":
        mean, spread = (f.numpy() for f in ident._features)
        features = torch.from_numpy(((np.log(gain) - mean) / spread).astype(np.float32))
    A, b, c, d, el = _decoded(ident, x, features, count)
    if ident.scale == "denormalise":
        # Exact de-normalisation (linearity), in float64: the structure described
        # u/u_bar -> y/y_bar. A product, not el * (1 + mask (g - 1)), which is 0 for g=1e-44.
        g = gain[:, 0]
        c, d = c * g[:, None], d * g
        el = np.where(ident._output_mask.numpy()[0] > 0, el * g[:, None], el)
    return A, b, c, d, el


def _decoded(ident, x: list, features, count: int) -> tuple:
    """The structure's float64 model of normalised records ``x``, before de-normalisation."""
    # Small batches are dominated by per-operation overhead, which a second thread only adds
    # to (thread wake-ups); large ones gain from both cores.
    threads = torch.get_num_threads()
    if count <= 16 and threads > 1:
        torch.set_num_threads(1)
    try:
        with torch.no_grad():
            # Chunks (CHUNK) keep the activations in cache and bound the memory a call takes,
            # which load (fast_path.warm) touches once.
            parts = []
            for i in range(0, count, CHUNK):
                sys, el, _ = ident._decode([v[i: i + CHUNK] for v in x],
                                           None if features is None else features[i: i + CHUNK])
                parts.append((sys.A, sys.b, sys.c, sys.d, el))
            return tuple(torch.cat(t).numpy().astype(np.float64)
                         for t in zip(*parts, strict=True))
    finally:
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)


def _overflowed(record: RecordBatch, good: np.ndarray, model: tuple) -> tuple:
    """The record's problems with a reason added for each good record whose identified model
    is not finite, and its model rows set to NaN (in place).

    Why: the de-normalisation multiplies ``c, d`` by ``max|y| / max|u|`` (Eq. 15 and
    linearity); a record of 1e308 has a model whose ``c`` lies beyond float64 (inf), which
    must not come back as an estimate."""
    problems = record.problems
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
