"""Solving the refinement NLP: one record from a start vector (:func:`refine_elements`) and an
estimate record by record (:func:`refine`), with the guarantee that no result is worse than its
start (docs/architecture.md)."""

from __future__ import annotations

import dataclasses
import math
import time
import warnings

import numpy as np

from aeid_struct.records import RecordBatch, as_array, check_dt, require_finite, unit_step
from aeid_struct.refinement import nlp
from aeid_struct.refinement.config import RefineConfig, RefineResult
from aeid_struct.structures import Structure

__all__ = ["refine", "refine_elements"]

#: Headroom of the squarings over the start's ``||M||_1`` (three spare doublings).
_NORM_MARGIN = 8.0
#: How many times the squarings may be raised and the problem re-solved.
_MAX_RESOLVES = 3
#: sqpmethod's status for a step below ``min_step_size`` (``RefineConfig.step_tol``): converged.
_SMALL_STEP = "Search_Direction_Becomes_Too_Small"
#: sqpmethod's status at the end of its ``max_iter``: a chunk of :func:`_iterate` ran out.
_MAX_ITERATIONS = "Maximum_Iterations_Exceeded"
#: Iterations of one call of ``sqpmethod`` (:func:`_iterate`).
CHUNK = 10
#: A chunk lowering the loss by less than this, relative, ends the solve (:func:`_iterate`).
STALL = 1e-9


# ---------------------------------------------------------------------------------------------
# One record from an element vector
# ---------------------------------------------------------------------------------------------
def _record(name: str, value, steps: int | None = None) -> np.ndarray:
    arr = as_array(name, value)
    want = "(steps,)" if steps is None else f"({steps},) like y"
    if arr.ndim != 1 or arr.shape[0] < 1 or (steps is not None and arr.shape[0] != steps):
        raise ValueError(f"{name} must have shape {want}; got {arr.shape}")
    require_finite(name, arr)
    return arr


def _start_vector(structure: Structure, x0) -> np.ndarray:
    names = structure.element_names
    if isinstance(x0, dict):
        missing = [nm for nm in names if nm not in x0]
        if missing:
            raise ValueError(f"x0 is missing the element(s) {', '.join(missing)} of "
                             f"{structure!r}; elements: {', '.join(names)}")
        x0 = [x0[nm] for nm in names]
    try:
        x = np.array(x0, dtype=np.float64).reshape(-1) if np.ndim(x0) <= 1 else None
    except (TypeError, ValueError):
        raise ValueError(f"x0 must be a sequence of {structure.q} numbers or a dict name -> "
                         f"value; got {type(x0).__name__}") from None
    if x is None or x.shape != (structure.q,):
        raise ValueError(f"x0 must have shape ({structure.q},) for {structure!r} (elements "
                         f"{', '.join(names)}); got {np.shape(x0)}")
    if not np.all(np.isfinite(x)):
        i = int(np.flatnonzero(~np.isfinite(x))[0])
        raise ValueError(f"x0 must be finite; got {x[i]} for element {names[i]}")
    return x


def _check_structure(structure) -> None:
    if not isinstance(structure, Structure):
        raise ValueError(f"structure must be a Structure (CCF, MCF, Physical, ...); "
                         f"got {type(structure).__name__}")


def _check_config(config) -> None:
    if not isinstance(config, RefineConfig):
        raise ValueError(f"config must be a RefineConfig; got {type(config).__name__}")


def _check_not_zero(Y: np.ndarray) -> None:
    """Eq. 15 divides by ``max|y|``: every record ``Y (count, steps)`` must have one."""
    zero = ~np.any(Y != 0, axis=1)
    if zero.any():
        raise ValueError(f"y must not be all zero (record {int(np.argmax(zero))} of "
                         f"{len(Y)}): the normalisation y_tilde = 2 y / max|y| - 1 (Eq. 15) "
                         "needs max|y| > 0")


def refine_elements(structure: Structure, x0, y, u, dt: float,
                    config: RefineConfig = RefineConfig(),  # noqa: B008
                    initial: str = "rest") -> RefineResult:
    """Refine one record from any start vector of elements (docs/architecture.md).

    Parameters
    ----------
    structure : Structure
        The structure whose elements are refined; its constraints hold for the result.
    x0 : (q,) numbers or dict name -> value
        Start, all elements in ``structure.element_names`` order. Fixed elements must hold their
        fixed values (to ``1e-6`` relative: a float32 start is fine) and are set exactly; free
        ones outside ``structure.element_bounds()`` are clipped into them.
    y : (steps,) array
        The measured output at ``t_k = k dt`` from rest; not all zero.
    u : (steps,) array or None
        The input (linear between samples); None means a unit step.
    dt : float > 0
    config : RefineConfig
    initial : {"rest", "fitted"}
        ``"fitted"``: the record may start mid-motion; its initial state is fitted by least
        squares for every candidate (projected out of the NLP).

    Returns
    -------
    RefineResult
    """
    start = time.perf_counter()
    _check_structure(structure)
    _check_config(config)
    if initial not in ("rest", "fitted"):
        raise ValueError(f"initial must be 'rest' or 'fitted'; got {initial!r}")
    dt = check_dt(dt)
    y = _record("y", y)
    u = unit_step(y.shape) if u is None else _record("u", u, y.shape[0])
    if not np.any(y):
        raise ValueError("y must not be all zero: the normalisation y_tilde = 2 y / max|y| - 1 "
                         "(Eq. 15) needs max|y| > 0")
    key = nlp.structure_key(structure)
    x = _start_vector(structure, x0)
    return _refine_one(structure, key, x, y, u, dt, config, start, initial)


def _solve(problem, z, p, lbz, ubz):
    """Run the solver from ``z``: ``(z*, iterations, status, converged)``."""
    z_new = problem.solver(z, p, lbz, ubz)[0]
    stats = problem.solver.stats()
    status = str(stats.get("return_status", ""))
    return (z_new, int(stats.get("iter_count", 0)), status,
            bool(stats.get("success")) or status == _SMALL_STEP)


def _start(asm, structure, x: np.ndarray, y: np.ndarray, u: np.ndarray):
    """The start in the NLP's relative units: ``(x, scale, p, lbz, ubz)`` (checked record)."""
    names = structure.element_names
    tol = 1e-6 * (1.0 + np.abs(x).max())
    off = asm.fixed & (np.abs(x - asm.values) > tol)
    if np.any(off):
        i = int(np.flatnonzero(off)[0])
        raise ValueError(f"x0: element {names[i]} is fixed at {float(asm.values[i])!r} in "
                         f"{structure!r}; got {x[i]:.6g}")
    x = np.where(asm.fixed, asm.values, np.clip(x, asm.lo, asm.hi))
    free = ~asm.fixed
    x_free = x[free]
    scale = np.maximum(np.abs(x_free), 1e-2 * np.abs(x_free).max(initial=0.0))
    scale = np.where(scale > 0.0, scale, 1.0)
    w = 2.0 / (float(np.abs(y).max()) * math.sqrt(y.shape[0] + 1))  # residual weight (nlp)
    p = np.concatenate([scale, w * y, w * u])
    return x, scale, p, asm.lo[free] / scale, asm.hi[free] / scale


def _iterate(problem, make, squarings: int, z, p, lbz, ubz, loss_start: float,
             max_iter: int):
    """Solve, chunk by chunk (:data:`CHUNK` iterations a call of ``sqpmethod``), re-building
    with more squarings while the iterates leave the exponential's accurate range: ``(z, loss,
    iterations, status, converged, squarings)``.

    Why chunks: the solver stops on a gradient (``tol_du``) or a step below its tolerances;
    where the loss's round-off floor lies above them (a companion form of widely spread
    coefficients: a quarter car's gradient stalled at 1e-6) it would run all ``max_iter``
    iterations at the optimum. A chunk that lowers the loss by less than :data:`STALL` of itself
    ends the solve as converged."""
    iterations, status, converged, resolves = 0, "", False, 0
    before = loss_start
    while True:
        try:
            z_new, its, status, converged = _solve(problem, z, p, lbz, ubz)
        except RuntimeError as err:  # an evaluation failing inside the solver
            status = f"solver error: {err}".splitlines()[0]
            return z, math.nan, iterations, status, False, squarings
        iterations += its
        if not np.all(np.isfinite(z_new)):
            return z, math.nan, iterations, status, converged, squarings
        z = np.clip(z_new, lbz, ubz)
        loss, norm = (float(v[0]) for v in problem.loss(z, p))
        if not math.isfinite(norm):  # overflow far from the start: a failure, keep the start
            return z, math.nan, iterations, status, converged, squarings
        if nlp.fewest_squarings(norm) > squarings:
            # The iterates left the exponential's accurate range: rebuild and go on from here.
            squarings = nlp.fewest_squarings(_NORM_MARGIN * norm)
            problem = make(squarings, max(max_iter - iterations, 1))
            if resolves == _MAX_RESOLVES or iterations >= max_iter:
                loss = problem.loss(z, p)[0][0]  # with enough squarings at z now
                status = (f"{status}; squarings still too few after re-solves"
                          if resolves == _MAX_RESOLVES else status)
                return z, float(loss), iterations, status, False, squarings
            resolves += 1
            continue
        if converged or iterations >= max_iter or status != _MAX_ITERATIONS:
            return z, loss, iterations, status, converged, squarings
        if not before - loss > STALL * abs(before):
            status = (f"Stalled: the loss fell by less than {STALL:g} of itself in {its} "
                      "iterations (its round-off floor)")
            return z, loss, iterations, status, True, squarings
        before = loss
        if max_iter - iterations < CHUNK:   # the last chunk: exactly the iterations left
            problem = make(squarings, max_iter - iterations)


def _refine_one(structure, key, x, y, u, dt, config, start,
                initial: str = "rest") -> RefineResult:
    """Refine one checked record ``y, u (steps,)`` (``max|y| > 0``) from elements ``x``."""
    asm = nlp.assembly(structure, key)
    x, scale, p, lbz, ubz = _start(asm, structure, x, y, u)
    free = ~asm.fixed
    steps, dt_ = y.shape[0], np.array([dt])

    def make(squarings, left=config.max_iter):
        # sqpmethod runs in chunks (_iterate); ipopt, whose barrier a restart would reset, at
        # once
        chunk = (dataclasses.replace(config, max_iter=min(left, CHUNK))
                 if config.solver == "sqpmethod" else config)
        return nlp.problem(structure, key, steps, dt, squarings, chunk, initial)

    start_squarings = nlp.fewest_squarings(_NORM_MARGIN * asm.system(x, dt_)[4][0])
    problem = make(start_squarings)
    z0 = x[free] / scale
    loss_start = float(problem.loss(z0, p)[0][0])
    z, loss, iterations, status, converged, squarings = _iterate(
        problem, make, start_squarings, z0, p, lbz, ubz, loss_start, config.max_iter)
    if math.isfinite(loss) and (loss <= loss_start or not math.isfinite(loss_start)):
        x[free] = scale * z
        x = np.clip(x, asm.lo, asm.hi)
        success = converged
    else:
        status = f"kept the start: the solver's result has loss {loss:.6g} > {loss_start:.6g}" \
                 f" ({status})"
        loss, success, squarings = loss_start, False, start_squarings
    return RefineResult(x, float(loss_start), loss, iterations, success,
                        time.perf_counter() - start, config.solver, status, squarings)


# ---------------------------------------------------------------------------------------------
# An estimate, record by record
# ---------------------------------------------------------------------------------------------
#: What ``refine`` reads of an estimate (an ``estimates.Estimate``, or anything that reads the
#: same: taken duck-typed).
_ESTIMATE = ("A", "elements", "record", "structure", "initial", "batched", "seconds")


def _check_estimate(estimate) -> None:
    ok = (dataclasses.is_dataclass(estimate) and not isinstance(estimate, type)
          and all(hasattr(estimate, name) for name in _ESTIMATE))
    if not ok:
        raise ValueError(f"estimate must be an Estimate; got {type(estimate).__name__}")


def _structure_of(estimate, structure):
    if structure is None:
        structure = estimate.structure
        if structure is None:
            raise ValueError("structure must be given: this estimate does not carry one (only "
                             "estimates from an Identifier do)")
    _check_structure(structure)
    if structure.records > 1:
        raise ValueError(f"structure must describe one record; {structure!r} describes "
                         f"{structure.records} (a joint estimate): refine each subsystem's "
                         "estimate in its own structure")
    return structure


def _records(name: str, value, count: int, batched: bool) -> np.ndarray:
    """``(count, steps)`` from ``(steps,)`` or ``(count, steps)``."""
    arr = as_array(name, value)
    want = f"(steps,) or ({count}, steps) like the estimate" if batched else "(steps,)"
    ok = arr.ndim == 1 or (batched and arr.ndim == 2 and arr.shape[0] in (1, count))
    if not ok or arr.shape[-1] < 1:
        raise ValueError(f"{name} must have shape {want}; got {arr.shape}")
    if arr.shape[-1] < 2:
        # one sample holds no dynamics: the FOH response needs two to interpolate between
        raise ValueError(f"{name} must have steps >= 2 samples; got {arr.shape}")
    arr = np.broadcast_to(np.atleast_2d(arr), (count, arr.shape[-1]))
    require_finite(name, arr)
    return arr


def _given_record(estimate, y, u, dt) -> RecordBatch:
    """The records ``y, u`` at ``dt`` checked for ``estimate`` (the deprecated form, and an
    estimate whose record was never checked: one built by hand)."""
    dt = check_dt(estimate.record.dt[0] if dt is None else dt)
    batched = estimate.batched
    count = estimate.A.shape[0] if batched else 1
    Y = _records("y", y, count, batched)
    U = unit_step(Y.shape) if u is None else _records("u", u, count, batched)
    if U.shape != Y.shape:
        raise ValueError(f"u must have {Y.shape[1]} samples like y; got {U.shape[1]}")
    _check_not_zero(Y)
    return RecordBatch((Y.copy(),), (U.copy(),), (dt,), batched, checked=True)


def _own_record(estimate) -> RecordBatch:
    """The estimate's record, checked once already where an Identifier made it."""
    record = estimate.record
    if not record.checked:
        return _given_record(estimate, record.given(record.y), record.given(record.u),
                             record.dt[0])
    record.raise_first()        # a record set aside by errors="collect" has nothing to fit
    return record


def _info(results: list[RefineResult], batched: bool, seconds: float,
          config: RefineConfig) -> dict:
    def field(name, dtype=None):
        values = np.array([getattr(r, name) for r in results], dtype=dtype)
        return values if batched else values[0].item()

    return {
        "iterations": field("iterations", np.int64),
        "loss_start": field("loss_start", np.float64),
        "loss": field("loss", np.float64),
        "success": field("success", bool),
        "seconds": seconds if not batched else field("seconds", np.float64),
        "solver": config.solver,
        "status": [r.status for r in results] if batched else results[0].status,
    }


def _assembled(structure: Structure, key: str, results: list[RefineResult], dt: float,
               batched: bool) -> dict:
    """The refined models as Estimate fields: ``A (count, n, n), b, c (count, n), d (count,)``
    and ``elements`` (unbatched: the first record's, ``d`` and elements as floats)."""
    asm = nlp.assembly(structure, key)
    parts = [asm.system(r.elements, np.array([dt])) for r in results]
    n = structure.n
    A = np.stack([pt[0].reshape(n, n, order="F") for pt in parts])  # CasADi is column-major
    b, c = (np.stack([pt[i] for pt in parts]) for i in (1, 2))
    d = np.array([pt[3][0] for pt in parts])
    X = np.stack([r.elements for r in results])
    names = structure.element_names
    if batched:
        return {"A": A, "b": b, "c": c, "d": d,
                "elements": {nm: X[:, i].copy() for i, nm in enumerate(names)}}
    return {"A": A[0], "b": b[0], "c": c[0], "d": float(d[0]),
            "elements": {nm: float(X[0, i]) for i, nm in enumerate(names)}}


def refine(estimate, y=None, u=None, dt=None, *, structure: Structure | None = None,
           config: RefineConfig = RefineConfig()):  # noqa: B008
    """Polish an estimate by a CasADi NLP in its structure, record by record.

    ``refine(estimate)`` or ``refine(estimate, config)``: the estimate holds its records, their
    sample time, its structure and whether its records start from rest; the output error of
    each record (Eq. 14 on the normalised record, Eq. 15) is minimised over the structure's free
    elements within their bounds (docs/architecture.md).

    Parameters
    ----------
    estimate : Estimate
        The start (``estimates.Estimate``, read duck-typed: ``A``, ``elements``,
        ``record``, ``structure``, ``initial``, ``batched``, ``seconds``); its ``elements``
        must hold every element of ``structure``.
    y, u, dt : deprecated
        The old form ``refine(estimate, y, u, dt)``: records to refine against instead of the
        estimate's own (``y (steps,)`` or ``(batch, steps)``, ``u`` like ``y`` or None for a
        unit step, ``dt > 0``). Still answered, with a DeprecationWarning. A
        :class:`RefineConfig` in place of ``y`` is the ``config``.
    structure : Structure, optional
        Refine in another structure of the same elements (a tighter one, e.g. with fixed
        elements); default: the estimate's.
    config : RefineConfig

    Returns
    -------
    Estimate
        ``dataclasses.replace(estimate, ...)`` with ``refined=True``; ``elements``, ``A, b, c,
        d`` assembled from the refined elements; ``seconds`` the estimate's plus the
        refinement's; ``info`` with ``iterations, loss_start, loss, success, seconds``
        (scalars, or ``(batch,)`` arrays for a batch), ``status`` (str or list) and
        ``solver``. Per record, ``loss <= loss_start``.

    Raises
    ------
    ValueError
        Naming the argument: not an estimate, no structure, a structure of several records or
        without the estimate's elements, a record that cannot be refined (all zero, non-finite,
        set aside by ``errors="collect"``).
    """
    start = time.perf_counter()
    if isinstance(y, RefineConfig) and u is None and dt is None:
        y, config = None, y                       # refine(estimate, config)
    _check_estimate(estimate)
    structure = _structure_of(estimate, structure)
    _check_config(config)
    if y is None:
        if u is not None or dt is not None:
            raise ValueError("y must be given with u and dt (the deprecated form refine("
                             "estimate, y, u, dt)); refine(estimate) refines against the "
                             "estimate's own records")
        record = _own_record(estimate)
    else:
        record = _given_record(estimate, y, u, dt)
        warnings.warn("refine(estimate, y, u, dt) is deprecated: the estimate holds its records, "
                      "sample time and structure; call refine(estimate) or refine(estimate, "
                      "config)", DeprecationWarning, stacklevel=2)
    return _refine_estimate(estimate, record, structure, config, start)


def _refine_estimate(estimate, record: RecordBatch, structure: Structure, config: RefineConfig,
                     start: float):
    """``refine`` of checked arguments: each record of ``record`` from the estimate's
    elements."""
    names = structure.element_names
    missing = [nm for nm in names if nm not in estimate.elements]
    if missing:
        raise ValueError(f"estimate.elements must hold every element of {structure!r}; missing "
                         f"{', '.join(missing)}")
    count = record.count
    X0 = np.stack([np.asarray(estimate.elements[nm], dtype=np.float64).reshape(count)
                   for nm in names], axis=1)
    key = nlp.structure_key(structure)
    Y, U, dt = record.y[0], record.u[0], record.dt[0]
    results = [_refine_one(structure, key, X0[i].copy(), Y[i], U[i], dt, config,
                           time.perf_counter(), estimate.initial) for i in range(count)]
    model = _assembled(structure, key, results, dt, record.batched)
    seconds = time.perf_counter() - start
    return dataclasses.replace(
        estimate, **model, record=record, seconds=estimate.seconds + seconds, refined=True,
        info=_info(results, record.batched, seconds, config))
