r"""``ae.identify`` for several inputs and outputs, and for several experiments of one system
(:func:`identify`): one model ``A (n, n), B (n, m), C (p, n), D (p, m)``, a delay per input,
and per record its own initial state and output offsets.

The steps (docs/architecture.md, "Several channels, several experiments"):

1. the records are checked once and taken to working units (``multi.experiments``);
2. the input delays by the common-denominator ARX unless known (``multi.start.arx_delays``);
3. candidate poles: the classical ones (common-denominator ARX, Steiglitz-McBride) and the
   caller's (``ae.identify``: the generic encoders on every output-input pair), ranked by the
   relaxed projection (``multi.start.relaxed``);
4. the start in the observer form from the best candidate (``multi.start.start_of``);
5. output error over every record by variable projection (``multi.fit``): the one pass
   (``refine=False``) runs a fixed number of residual evaluations from the best candidate; the
   refinement runs to convergence from the two best, and keeps the better; then each input's
   delay is walked one sample at a time by projection while that is better, and the fit runs
   again there (up to :data:`RESCANS` rounds).

*Order selection* (``order=None``): as for one channel (``generic.pipeline``): the orders the
records have samples for, from the lowest, fitted on the first 70 % of each record and validated
on the rest (initial state and offsets fitted), until :data:`PATIENCE` orders in a row improve
on none before them (:func:`order_search_done`); the smallest order within ``ORDER_TOLERANCE``
points of the best mean validation fit (over outputs and records). Where the first part holds
no variation of an input or the rest none of an output, or the rest of a record is shorter than
twice the initial state and offset fitted to it at the largest order, the order of least Bayesian
information criterion of the whole records' fits, searched the same way. Either rule runs among
the orders whose fit has no lightly damped mode its records do not determine
(``multi.excitation``; :func:`chosen_order`).
"""

from __future__ import annotations

import time

import numpy as np

from aeid_struct.identification import Estimate, Provenance
from aeid_struct.multi.excitation import unexcited_modes
from aeid_struct.multi.experiments import Experiments, experiments_of
from aeid_struct.multi.fit import (
    Fitted,
    beyond_stable,
    iterate,
    output_fits,
    physical,
    rescan,
    validation_fit,
    without_delay,
)
from aeid_struct.multi.start import arx_delays, classical_poles, relaxed, stabilised, start_of
from aeid_struct.records import RecordBatch
from aeid_struct.threads import one_thread

__all__ = ["ESTIMATION_SHARE", "EXACT", "ITERATIONS", "MAX_DELAY", "ORDER_TOLERANCE",
           "PATIENCE", "chosen_order", "fit_from_poles", "identify", "order_search_done", "packed",
           "parameters"]

#: Points of validation fit within which the smaller order is preferred (``order=None``; the
#: rule of one channel too: ``generic.pipeline`` reads it from here).
ORDER_TOLERANCE = 0.5
#: The estimation part of each record when the order is selected.
ESTIMATION_SHARE = 0.7
#: Levenberg-Marquardt iterations of the several-channel one pass (``refine=False``), each a
#: residual and Jacobian of every channel: on ``aeid-struct bench-generic --channels`` its rows
#: reach the refined fit at 10, and 30 (one channel's budget) cost up to half as much time again
#: for the same fits.
ITERATIONS = 10
#: ``order=None`` stops its search after this many orders in a row that improve on none before
#: them (:func:`order_search_done`): a lightly damped pair adds two orders at once, so an order
#: or two that improve nothing are no reason to stop, and the orders above the system's (the
#: dearest to fit, and never chosen) are not fitted.
PATIENCE = 3
#: The largest input delay considered by default (capped by what the records leave; the
#: one-channel pipeline's default too: ``generic.pipeline`` reads it from here).
MAX_DELAY = 10
#: Records whose output-input pairs the encoders read for candidates (the first ones): each pair
#: is one batched encoder call, and the candidates are ranked on every record anyway.
PROPOSING_RECORDS = 3
#: The order criterion's floor on the residual's rms, relative to the output's: fits below it
#: count as exact (the Bayesian information criterion of round-off would prefer the highest
#: order on a noise-free record; ``generic.pipeline`` reads it from here).
EXACT = 1e-6
#: Rounds of the delays' re-scan and the fit at the delays found, at most.
RESCANS = 3
#: Starts refined to convergence at most (the best candidates by the relaxed projection).
STARTS = 2
#: The second start is refined only where the first's optimum costs more than this times the
#: best candidate's relaxed cost: the relaxed model holds the minimal one of the same poles, so
#: an optimum near the relaxed cost leaves nothing for another start to find.
SETTLED = 1.05


def parameters(order: int, p: int, m: int, records: int) -> int:
    """Parameters fitted: ``theta`` (n p), ``B`` (n m), ``D`` (p m), per record ``x0`` and
    offsets (n + p).

    Parameters
    ----------
    order, p, m, records : int

    Returns
    -------
    int
    """
    return order * p + order * m + p * m + records * (order + p)


def _room(ex: Experiments, order: int) -> int:
    """The largest delay that leaves twice the parameters in the fitted samples."""
    need = 2 * parameters(order, ex.outputs, ex.inputs, ex.count)
    for top in range(min(ex.steps), -1, -1):
        if sum(max(s - top, 0) for s in ex.steps) * ex.outputs >= need:
            return top
    return -1


def _poles_of(dens) -> list[np.ndarray]:
    """Per-sample poles of monic denominators (highest power first), finite ones only."""
    out = []
    for den in np.atleast_2d(dens):
        if np.all(np.isfinite(den)) and den[0] != 0:
            s = np.roots(den)
            if len(s) == len(den) - 1 and np.all(np.isfinite(s)):
                out.append(s)
    return out


def _fit(ex: Experiments, order: int, *, refine: bool, top: int, iterations: int,
         classical: bool, proposals, feedthrough: bool, stable: bool) -> tuple[Fitted, int]:
    """Steps 2-5 of the module docstring for one order; the fit and the candidates scored
    (the one pass's bounded iterations, or the refinement's to convergence)."""
    budget = None if refine else iterations
    delays = ex.delay if ex.delay is not None else arx_delays(ex, order, top)
    parts = ex.aligned(delays)
    found = [(s, "classical") for s in classical_poles(parts, order)] if classical or \
        proposals is None else []
    if proposals is not None:
        for Y, U in parts[:PROPOSING_RECORDS]:
            for i in range(Y.shape[1]):
                for j in range(U.shape[1]):
                    found += [(s, "encoder") for s in _poles_of(proposals(order, Y[:, i],
                                                                          U[:, j]))]
    if not found:
        found = [(s, "classical") for s in classical_poles(parts, order)]
    if stable:
        found = [(stabilised(s), origin) for s, origin in found]
    with np.errstate(all="ignore"):
        fits = [relaxed(s, parts, ex.holds, feedthrough) for s, _ in found]
    ranked = sorted((k for k in range(len(found)) if np.isfinite(fits[k][0])),
                    key=lambda k: fits[k][0])
    if not ranked:
        raise ValueError(f"no candidate model of order {order} could be fitted to the records "
                         f"(every candidate's response overflows)")
    best = None
    for k in ranked[: STARTS if refine else 1]:
        if best is not None and best.cost < SETTLED * fits[ranked[0]][0]:
            break
        poles, origin = found[k]
        layout, theta, h = start_of(poles, parts, ex.holds, feedthrough, fits[k])
        fitted = iterate(layout, theta, h, ex, delays, feedthrough, budget, origin, stable)
        if best is None or fitted.cost < best.cost:
            best = fitted
    if refine and ex.delay is None:     # a delay against a slow pole: fit.without_delay
        best = without_delay(best, ex, feedthrough, top, stable)
    # the delays walked at the fit's poles and the fit run again there, until they stay (the
    # poles of a fit at a wrong delay move towards the right one's, where the walk goes on)
    for _ in range(RESCANS if ex.delay is None and top > 0 else 0):
        moved = rescan(best, ex, top, feedthrough)
        if np.array_equal(moved, best.delays):
            break
        again = iterate(best.layout, best.theta, best.h, ex, moved, feedthrough, budget,
                        best.start, stable)
        if not again.cost < best.cost:
            break
        best = again
    if stable and refine:    # the records' best model may be unstable: say so (fit.beyond_stable)
        best = beyond_stable(best, ex, feedthrough)
    return best, len(found)


def fit_from_poles(record, order: int, poles=None, *, origin: str = "arx",
                   info: dict | None = None) -> Estimate:
    """The output-error fit to convergence from given poles (the several-channel least
    squares baseline's: n4sid's), or from the common-denominator ARX's; known delays applied,
    none estimated.

    Parameters
    ----------
    record : Record or sequence of Record
    order : int
    poles : (order,) complex array, optional
        Per sample (``s dt``).
    origin : str
        Where ``poles`` come from (``info["start"]``).
    info : dict, optional
        Kept in the estimate's ``info``.

    Returns
    -------
    Estimate
    """
    began = time.perf_counter()
    ex = experiments_of(record, what="least_squares")
    delays = ex.delay if ex.delay is not None else np.zeros(ex.inputs, dtype=int)
    parts = ex.aligned(delays)
    if poles is None:
        poles, origin = classical_poles(parts, order)[0], "arx"
    layout, theta, h = start_of(np.asarray(poles), parts, ex.holds)
    fitted = iterate(layout, theta, h, ex, delays, True, None, origin)
    return _estimate(fitted, ex, False, dict(info or {}), time.perf_counter() - began)


@one_thread
def identify(record, order=None, *, refine=True, delay=None, max_delay=None,
             iterations=ITERATIONS, classical=True, proposals=None, orders=range(1, 9),
             feedthrough=True, stable=False, what="ae.identify") -> Estimate:
    """Identify one model of records with several channels, or of several experiments (module
    docstring); the body of ``ae.identify`` for them.

    Parameters
    ----------
    record : Record or sequence of Record
        ``multi.experiments.experiments_of``.
    order : int or None
        None: selected among ``orders``.
    refine : bool
    delay : int or sequence of m ints, optional
        Known input delays (samples).
    max_delay : int, optional
        The largest delay considered (default :data:`MAX_DELAY`, capped by what the records
        leave).
    iterations : int, >= 0
        Levenberg-Marquardt iterations of the one pass (:data:`ITERATIONS`, what
        ``ae.identify`` runs by default).
    classical : bool
        The classical candidates beside ``proposals``' (always where there are none).
    proposals : callable, optional
        ``proposals(order, y, u) -> (K, order + 1)`` monic denominators per sample of one
        output-input pair (``ae.identify``: the generic encoders' windows).
    orders : iterable of int
        Where ``order=None`` selects.
    feedthrough : bool
    stable : bool
        Hold the fit to stable models (every pole in the open left half-plane), each candidate's
        unstable poles mirrored into it (``multi.start.stabilised``); with ``refine``, where
        the unconstrained fit from there is unstable and clearly better, ``info["unstable"]``
        holds its ``poles`` (record time unit) and ``fit`` (per output).
    what : str

    Returns
    -------
    Estimate
        For several channels ``b, c, d`` hold ``B (n, m), C (p, n), D (p, m)``; for several
        experiments of one channel, ``b (n,), c (n,), d`` (module docstring of
        ``estimates.estimate``). ``info``: ``delay`` (an int, or ``(m,)``), ``x0``,
        ``y_offset``, ``fit`` (per output, and per record for several), ``y_hat`` (NaN before the
        largest delay), ``cost``, ``candidates``, ``start``, ``reference`` (the output whose
        row of ``C`` is ``e_1``), ``order_fits``, ``iterations``, ``converged``, ``form``.

    Raises
    ------
    ValueError
        Naming the argument: bad records, order, refine, iterations, classical, delay or
        max_delay, or records too short for the model.
    """
    began = time.perf_counter()
    orders = [int(n) for n in orders]
    _check(order, orders, refine, iterations, classical, max_delay, stable)
    ex = experiments_of(record, delay, what=what)
    wanted = [order] if order is not None else [n for n in orders if _room(ex, n) >= 0]
    least = wanted[0] if wanted else 1
    room, need = _room(ex, least), 2 * parameters(least, ex.outputs, ex.inputs, ex.count)
    if room < 0 or (ex.delay is not None and int(ex.delay.max()) > room):
        raise ValueError(f"the records ({', '.join(map(str, ex.steps))} samples, "
                         f"{ex.outputs} output(s)) are too short for a model of order {least}: "
                         f"it needs {need} output samples after the delay (twice its "
                         f"{need // 2} fitted parameters)")
    if max_delay is not None and max_delay > room and ex.delay is None:
        raise ValueError(f"max_delay must leave twice the parameters of an order-{least} model "
                         f"after the delay: at most {room} for these records; got {max_delay}")
    largest = MAX_DELAY if max_delay is None else int(max_delay)
    kw = {"refine": bool(refine), "iterations": int(iterations), "classical": bool(classical),
          "proposals": proposals, "feedthrough": feedthrough, "stable": stable}
    order_fits = None
    if order is None:
        order, order_fits = _select(ex, wanted, least, largest, kw)
    # a higher order selected leaves fewer samples: the delays it may take are capped there
    top = min(largest, _room(ex, order))
    fitted, count = _fit(ex, order, top=top, **kw)
    info = {"candidates": count, "order_fits": order_fits}
    return _estimate(fitted, ex, refine, info, time.perf_counter() - began)


def order_search_done(scores: list, lower: bool) -> bool:
    """Whether ``order=None`` may stop searching (the rule of one channel too): each of the
    last :data:`PATIENCE` orders improved on none of the orders before them, by more than
    :data:`ORDER_TOLERANCE` points of validation fit (``lower`` False), or by a lower
    information criterion (``lower`` True); a score that is not finite improves nothing.

    Parameters
    ----------
    scores : list of float
        The fitted orders' scores, in increasing order.
    lower : bool
        Whether lower is better (the criterion) or higher (the validation fit).

    Returns
    -------
    bool
    """
    before = [v for v in scores[:-PATIENCE] if np.isfinite(v)]
    if len(scores) <= PATIENCE or not before:
        return False
    last = np.asarray(scores[-PATIENCE:], dtype=np.float64)
    last = last[np.isfinite(last)]
    if lower:
        return not np.any(last < min(before))
    return not np.any(last > max(before) + ORDER_TOLERANCE)


def _select(ex: Experiments, wanted: list, least: int, largest: int, kw: dict) -> tuple:
    """``order=None``: ``(order, order_fits)`` by the hold-out rule (module docstring), or,
    where the estimation part holds no variation of an input or the validation part none of an
    output, by the least Bayesian information criterion of the whole records' fits
    (``generic.pipeline``'s rule for one channel; ``order_fits`` then the whole records'
    mean fits)."""
    estimation, validation = ex.cut(ESTIMATION_SHARE)
    # a validation part no longer than the initial state and offset fitted to it scores any
    # order alike (40-sample records in three experiments: 12 samples each, and every order
    # from 5 to 8 validated at 100.0 %), so it must hold twice them at the largest order
    holdout = (all(np.all(np.ptp(u, axis=0) > 0) for u in estimation.U)
               and all(np.all(np.ptp(y, axis=0) > 0) for y in validation.Y)
               and min(y.shape[0] for y in validation.Y) >= 2 * (max(wanted) + 1))
    fits, criterion, flagged = {}, {}, set()
    for n in wanted:
        part = estimation if holdout else ex
        room = _room(part, n)
        if room < 0:
            continue
        fitted, _ = _fit(part, n, top=min(largest, room), **kw)
        if _undetermined(fitted, part):
            flagged.add(n)
        if holdout:
            fits[n] = float(np.mean(validation_fit(fitted, validation, kw["feedthrough"])))
            if order_search_done(list(fits.values()), lower=False):
                break
            continue
        fits[n] = float(np.mean(validation_fit(fitted, ex, kw["feedthrough"])))
        # residuals of every output at every fitted sample; the parameters that grow with n:
        # the denominator, B, C and every record's initial state
        used = fitted.projection.residual.size
        floor = EXACT ** 2 * float(np.mean([np.var(y, axis=0).mean() for y in ex.Y]))
        criterion[n] = (used * np.log(max(fitted.cost, floor))
                        + n * (1 + ex.inputs + ex.outputs + ex.count) * np.log(used))
        if order_search_done(list(criterion.values()), lower=True):
            break
    if not any(np.isfinite(v) for v in (*criterion.values(), *fits.values())):
        return least, fits
    return chosen_order(fits, criterion, flagged), fits


def chosen_order(fits: dict, criterion: dict | None, flagged: set) -> int:
    """``order=None``'s choice (the module docstring's rule; one channel's too): the order of
    least ``criterion`` where there is one, else the smallest order within
    :data:`ORDER_TOLERANCE` points of the best validation fit, among the orders not
    ``flagged`` (among all of them where every one is): an order with a mode its record does
    not determine is one the record cannot fill, whatever its fit.

    Parameters
    ----------
    fits : dict order -> float
        Validation fits (%); not finite: not a candidate.
    criterion : dict order -> float or None
        Bayesian information criteria where there is no hold-out (None or empty: ``fits``).
    flagged : set of int

    Returns
    -------
    int
    """
    def kept(values: dict) -> dict:
        clear = {n: v for n, v in values.items() if np.isfinite(v) and n not in flagged}
        return clear or {n: v for n, v in values.items() if np.isfinite(v)}

    finite = kept(criterion or {})
    if finite:
        return min(finite, key=finite.get)
    finite = kept(fits)
    best = max(finite.values())
    return min(n for n, f in finite.items() if f >= best - ORDER_TOLERANCE)


def _undetermined(fitted: Fitted, ex: Experiments) -> bool:
    """Whether a fit has a lightly damped pair its records do not determine
    (``multi.excitation``), judged in the user's units as ``ae.identify``'s flag is."""
    model = physical(fitted, ex)
    outputs = [Y * ex.y_scale + ex.y_mean for Y in ex.Y]
    inputs = [U * ex.u_scale for U in ex.U]
    residual = sum(float(np.nansum((y - y_hat) ** 2))
                   for y, y_hat in zip(outputs, model["y_hat"], strict=True))
    return bool(unexcited_modes(model["A"], model["B"], model["C"], model["D"], outputs, inputs,
                                residual, ex.dt))


def _check(order, orders, refine, iterations, classical, max_delay, stable) -> None:
    """The arguments of :func:`identify` other than the records (``experiments_of``), each
    refused by name."""
    if order is not None and (isinstance(order, bool) or not isinstance(order, (int, np.integer))
                              or not 1 <= order <= max(orders)):
        raise ValueError(f"order must be None (selected) or an integer in [1, {max(orders)}]; "
                         f"got {order!r}")
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or (
            iterations < 0):
        raise ValueError(f"iterations must be an integer >= 0 (iterations of the one pass); got "
                         f"{iterations!r}")
    for name, value in (("refine", refine), ("classical", classical), ("stable", stable)):
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{name} must be True or False; got {value!r}")
    if max_delay is not None and (isinstance(max_delay, bool) or not isinstance(
            max_delay, (int, np.integer)) or max_delay < 0):
        raise ValueError(f"max_delay must be None or an integer >= 0; got {max_delay!r}")


def _estimate(fitted: Fitted, ex: Experiments, refine: bool, info: dict,
              seconds: float) -> Estimate:
    """The Estimate of a fit (``identify``'s Returns)."""
    model = physical(fitted, ex)
    info = info | ({} if fitted.unstable is None else {"unstable": fitted.unstable})
    info = {**info, "cost": fitted.cost, "start": fitted.start,
            "reference": fitted.layout.reference, "iterations": fitted.iterations,
            "converged": fitted.converged, "form": "observer"}
    return packed(model, ex.records, fitted.delays, refine, info, seconds)


def packed(model: dict, records, delays, refined: bool, info: dict,
           seconds: float) -> Estimate:
    """An Estimate of a model of several channels or experiments (``identify``'s Returns; the
    several-channel baselines' too).

    Parameters
    ----------
    model : dict
        ``A, B, C, D`` in the user's units, per record ``x0, offset, y_hat`` (tuples of R).
    records : tuple of R Record
    delays : (m,) ints
    refined : bool
    info : dict
        Kept, with the per-record fields added.
    seconds : float

    Returns
    -------
    Estimate
    """
    R = len(records)
    p, m = records[0].outputs, records[0].inputs
    delays = np.asarray(delays, dtype=int)
    top = int(delays.max())
    n = model["A"].shape[0]
    fits = np.array([output_fits(rec.Y[top:], np.reshape(Yh, rec.Y.shape)[top:])
                     for rec, Yh in zip(records, model["y_hat"], strict=True)])   # (R, p)

    def per_record(values, squeeze):
        values = [squeeze(v) for v in values]
        return values[0] if R == 1 else tuple(values)

    if p == m == 1:
        b, c, d = model["B"][:, 0], model["C"][0], float(model["D"][0, 0])
        fit = float(fits[0, 0]) if R == 1 else fits[:, 0]
    else:
        b, c, d = model["B"], model["C"], model["D"]
        fit = fits[0] if R == 1 else fits
    # a failed fit's NaN model (a baseline's, baselines.several) has NaN coefficients
    a = (np.real(np.poly(np.linalg.eigvals(model["A"])))[1:][::-1]
         if np.all(np.isfinite(model["A"])) else np.full(n, np.nan))
    elements = {f"a{k}": float(v) for k, v in enumerate(a)}
    elements |= {f"b{l}_{j}": float(model["B"][l, j]) for l in range(n) for j in range(m)}
    elements |= {f"c{i}_{l}": float(model["C"][i, l]) for i in range(p) for l in range(n)}
    elements |= {f"d{i}_{j}": float(model["D"][i, j]) for i in range(p) for j in range(m)}
    holds = tuple(r.intersample for r in records)
    info = {**info, "delay": int(delays[0]) if m == 1 else delays.copy(),
            "x0": per_record(model["x0"], lambda x: x),
            "y_offset": per_record(model["offset"], lambda o: float(o[0]) if p == 1 else o),
            "fit": fit,
            "y_hat": per_record(model["y_hat"], lambda y: y[:, 0] if p == 1 else y),
            "intersample": holds[0] if len(set(holds)) == 1 else holds}
    record = RecordBatch(tuple(r.y[None] for r in records), tuple(r.u[None] for r in records),
                         tuple(r.dt for r in records), False, checked=True)
    return Estimate(A=model["A"], b=b, c=c, d=d, elements=elements, record=record,
                    provenance=Provenance(initial="fitted"), seconds=seconds,
                    refined=bool(refined), info=info)
