r"""One call: :func:`identify` a measured record with a generic identifier (the steps are in
``generic.pipeline``; this module chooses the identifiers: the shipped ``generic-n``, or the
caller's).

The split is at a seam: the pipeline runs any generic identifiers it is given, and
``GenericIdentifier.identify`` runs it with itself; only this module loads the shipped ones, so
the identifier's class, the loader and the pipeline import one another in one direction only.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import time

import numpy as np

from aeid_struct.generic.boundary import shortest
from aeid_struct.generic.classical import MAX_ORDER, NoEncoder
from aeid_struct.generic.config import ORDERS
from aeid_struct.generic.feedback import feedback_channels, warn_feedback
from aeid_struct.generic.model import load_generic
from aeid_struct.generic.pipeline import (
    ESTIMATION_SHARE as ESTIMATION_SHARE,
)
from aeid_struct.generic.pipeline import (
    ITERATIONS,
    MAX_DELAY,
    METHODS,
    ORDER_TOLERANCE,
    run,
    warn_stable_only,
    warn_unexcited,
)
from aeid_struct.generic.pipeline import measured as measured
from aeid_struct.generic.windows import candidates
from aeid_struct.identification import Estimate
from aeid_struct.multi import ITERATIONS as SEVERAL_ITERATIONS
from aeid_struct.multi import identify as identify_multi
from aeid_struct.multi import several, unexcited_modes
from aeid_struct.records import Record as measured_record
from aeid_struct.threads import one_thread

__all__ = ["ESTIMATION_SHARE", "ITERATIONS", "MAX_DELAY", "METHODS", "ORDERS", "ORDER_TOLERANCE",
           "identify", "measured"]

@one_thread
def identify(record, order=None, *, structure=None, refine=True, delay=None, max_delay=None,
             identifier=None, method="auto", iterations=None,
             classical=True, stable=False) -> Estimate:
    """Identify a continuous-time model of a measured record in one call (see the module
    docstring): generic identifier, whole-record projection, input delay, refinement.

    A record of several outputs or inputs, or a list of records (several experiments of one
    system), is identified as one model ``A (n, n), B (n, m), C (p, n), D (p, m)`` with a
    delay per input and each record's own initial state and offsets (``multi.identify``:
    the observer form, variable projection; the generic encoders propose poles from every
    output-input pair).

    Parameters
    ----------
    record : Record, list of Record, (y, u) or (y, u, dt) tuple, or (steps,) array
        See :func:`measured`; at least ``2 (3 order + 2)`` samples after the delay, twice the
        fitted parameters (``generic.boundary.shortest``): a record shorter than the
        identifier's window is read by it at a finer grid (``generic.windows.Windows``). Its
        ``intersample`` (the input linear or held between samples) is modelled exactly.
    order : int, optional
        Model order, 1 to ``MAX_ORDER`` (8): the shipped generic identifiers' encoders for
        1-4, the classical start alone above (``generic.classical.NoEncoder``); None selects
        it among 1-8 (those the record has samples for; module docstring). Taken from
        ``structure`` when that is a Structure.
    structure : None, "ccf", "mcf" or Structure
        The structure of the estimate: default ``CCF(order, feedthrough=True)``; ``"mcf"`` the
        modal form with the start's real poles and pairs (stable by construction); any
        Structure of that order (fixed elements included) gets the CCF start converted by its
        ``elements_of`` (closest admissible elements).
    refine : bool
        Refine over the whole record to convergence (output error, initial state, offset and
        delay); False: the one pass (module docstring).
    delay : int, optional
        A known input delay in samples (over the record's); None: the record's, else estimated.
    max_delay : int, >= 0, optional
        Largest delay considered when it is estimated; it must leave the samples the model
        needs after it. None: :data:`MAX_DELAY`, capped by what the record leaves.
    identifier : generic identifier or dict order -> identifier, optional
        Default: the shipped ``generic-n`` (``load_generic``).
    method : {"auto", "separable", "casadi"}
        The refinement (module docstring, step 5): ``"auto"`` separable for the free CCF and
        MCF, CasADi otherwise; ``"separable"`` refuses other structures; ``"casadi"`` always
        CasADi.
    iterations : int, >= 0, optional
        Levenberg-Marquardt iterations of the one pass (``refine=False``; the refinement
        iterates to convergence); 0: the chosen candidate's projection. None: the path's own
        budget, :data:`~aeid_struct.generic.pipeline.ITERATIONS` for one channel and
        :data:`~aeid_struct.multi.ITERATIONS` for several channels or experiments (whose
        iterations cost a residual of every channel each).
    classical : bool
        The Steiglitz-McBride estimate as a candidate of the one pass and as the refinement's
        second start; False: the encoder's candidates alone (``iterations=0, classical=False,
        refine=False`` is the encoder's pass with projection only).
    stable : bool
        A stable model (every pole in the open left half-plane: a plant known to be stable,
        MATLAB's ``EnforceStability``): for one channel the modal form (``structure`` None or
        ``"mcf"``); for several channels or experiments the observer form's fit held to stable
        models, each candidate's unstable poles mirrored into the left half-plane. Either way,
        where the records' best model is unstable and fits clearly better, it warns
        (:class:`~aeid_struct.generic.pipeline.StableOnlyWarning`) and ``info["unstable"]``
        holds that model's ``poles`` and ``fit`` (with ``refine``).

    Returns
    -------
    Estimate
        For several channels ``b, c, d`` are ``B, C, D`` (also as ``est.B, est.C, est.D``) in
        the observer form of ``info["reference"]``'s output, ``info["fit"]`` per output (and
        per record), ``delay`` per input. Otherwise ``A, b, c, d`` in physical time units,
        ``elements`` of the structure, ``delay``,
        ``x0`` (the state at sample ``delay``), ``offset``, ``fit``, ``y_hat``, ``seconds``,
        ``refined`` (False for the one pass); ``info`` holds ``delay, x0, y_offset, fit, y_hat,
        cost, intersample, candidates, order_fits, start`` (``"encoder"`` or ``"classical"``:
        the candidate or start that won) and, where they ran, the iterations' ``iterations,
        converged`` (and the one pass's ``delay_moved``: its re-scan moved the delay), and
        ``feedback``: the closed-loop test of ``generic.feedback`` on the refined model's
        residuals (None for the one pass and where the record is too short for it; for
        several channels or experiments every output against every input of every record,
        ``feedback_channels``). Where it finds an input correlated with earlier residuals it
        warns (:class:`~aeid_struct.generic.feedback.FeedbackWarning`) and, for the default
        structure, identifies the record again without a feedthrough (``feedback["refit"]``;
        a free ``d`` or ``D`` takes up the noise a controller feeds back in the same sample).
        ``unexcited``: every estimate's lightly damped pairs that the record does not
        determine (``multi.excitation.unexcited_modes``: ``pole`` in the record's time unit,
        ``damping``, ``snr``, ``gain``; empty where there are none); where there are any it
        warns (:class:`~aeid_struct.generic.pipeline.UnexcitedModeWarning`). ``holdout_fit``
        (one channel, refined): the validation fit % of the same fit on the first 70 % of the
        record run on the rest, and ``holdout_ratio`` its RMS residual there over its own on
        the first 70 % (None where the record cannot be split); below 0 % or above
        :data:`~aeid_struct.generic.holdout.HOLDOUT_RATIO` it warns
        (:class:`~aeid_struct.generic.holdout.UndeterminedModelWarning`): the record does not
        determine a model of that order.

    Raises
    ------
    ValueError
        For a bad record, order, structure, delay, max_delay, method, iterations or classical,
        or a record too short for the model.
    """
    if _tuple_of_channels(record):
        record = measured_record(*record)
    if not isinstance(stable, (bool, np.bool_)):
        raise ValueError(f"stable must be True or False; got {stable!r}")
    if several(record):
        return _several(record, order, structure=structure, refine=refine, delay=delay,
                        max_delay=max_delay, identifier=identifier, method=method,
                        iterations=iterations, classical=classical, stable=bool(stable))
    if stable:
        if structure not in (None, "mcf"):
            raise ValueError(f"structure must be None or 'mcf' with stable=True for one channel "
                             f"(the modal form is the stable one); got {structure!r}")
        structure = "mcf"
    return run(functools.partial(_identifiers, identifier=identifier), record, order,
               structure=structure, refine=refine, delay=delay, max_delay=max_delay,
               method=method, iterations=ITERATIONS if iterations is None else iterations,
               classical=classical)


def _tuple_of_channels(record) -> bool:
    """Whether ``record`` is a ``(y, u[, dt])`` tuple of several outputs or inputs."""
    return isinstance(record, tuple) and len(record) in (2, 3) and any(
        np.ndim(v) == 2 and np.shape(v)[1] > 1 for v in record[:2] if v is not None)


def _several(record, order, *, structure, refine, delay, max_delay, identifier, method,
             iterations, classical, stable) -> Estimate:
    """``identify`` of several channels or experiments (``multi.identify``), the generic
    encoders' candidates of every output-input pair passed in as its proposals."""
    if structure not in (None, "ccf"):
        raise ValueError(f"structure must be None for several channels or experiments (the "
                         f"observer form with a free feedthrough: docs/architecture.md); got "
                         f"{structure!r}")
    if method not in ("auto", "separable"):
        raise ValueError(f"method must be 'auto' or 'separable' for several channels or "
                         f"experiments (variable projection); got {method!r}")
    # the identifiers are resolved here, once (a bad one is refused before any numerics); the
    # other arguments are checked by multi.identify, at its own boundary
    if identifier is not None:
        chosen = _identifiers(order, identifier=identifier)
    else:       # the shipped encoders (1-4); above them the classical candidates alone
        chosen = {n: _shipped(n) for n in ORDERS if order is None or order == n}

    def proposals(n, y, u):
        ident = chosen.get(n)
        if ident is None or isinstance(ident, NoEncoder) or y.shape[0] < shortest(n):
            return np.zeros((0, n + 1))
        # unweighted windows only (no growth weights): every pair's candidates are ranked by a
        # projection over all channels, and the weights cost a 2x2 order-4 one pass 30 % more
        # (one thread, 77-80 -> 107-110 ms) where its rows, the integrating and unstable ones
        # included, already reach the refined fit from these and the classical candidates
        return candidates(ident, y, u, growth=())

    began = time.perf_counter()
    kw = {"refine": refine, "delay": delay, "max_delay": max_delay,
          "iterations": SEVERAL_ITERATIONS if iterations is None else iterations,
          "classical": classical, "proposals": proposals, "orders": range(1, MAX_ORDER + 1),
          "stable": stable}
    est = identify_multi(record, order, **kw)
    records = est.record
    outputs = [y[0].reshape(y.shape[1], -1) for y in records.y]
    inputs = [u[0].reshape(u.shape[1], -1) for u in records.u]
    found = None
    if refine:      # as for one channel: the one pass's residual carries model error
        found = feedback_channels(outputs, _per_record(est.info["y_hat"], records.records),
                                  inputs)
    if found is not None and found["detected"]:
        # a free D takes up the noise a controller acting on the samples it measures feeds
        # back through u_k, as d does for one channel (generic.pipeline): the order found
        # again without it
        order_fits = est.info["order_fits"]
        est = identify_multi(record, est.A.shape[-1], feedthrough=False, **kw)
        est.info["order_fits"] = order_fits
        found = found | {"refit": "no feedthrough"}
        warn_feedback(found, True)
    fitted = _per_record(est.info["y_hat"], records.records)
    residual = sum(float(np.nansum((y - y_hat) ** 2))
                   for y, y_hat in zip(outputs, fitted, strict=True))
    n, p = est.A.shape[0], outputs[0].shape[1]      # one channel of several experiments too
    B, C, D = np.reshape(est.b, (n, -1)), np.reshape(est.c, (p, n)), np.reshape(est.d, (p, -1))
    unexcited = unexcited_modes(est.A, B, C, D, outputs, inputs, residual, records.dt[0])
    warn_unexcited(unexcited)
    if "unstable" in est.info:
        warn_stable_only(est.info["unstable"]["poles"], est.info["unstable"]["fit"], est.fit,
                         "identify it without stable=True")
    info = {**est.info, "unexcited": unexcited} | ({"feedback": found} if refine else {})
    return dataclasses.replace(est, seconds=time.perf_counter() - began, info=info)


def _per_record(y_hat, count: int) -> list:
    """``info["y_hat"]`` of a several-channel estimate as R ``(steps, p)`` arrays."""
    parts = y_hat if count > 1 else (y_hat,)
    return [np.reshape(v, (np.shape(v)[0], -1)) for v in parts]


@functools.cache
def _shipped(order: int):
    """The shipped ``generic-n``, read once per process (reading it took two thirds of an
    unrefined call; ``identify`` never changes an identifier); above the shipped orders, up to
    ``MAX_ORDER``, the classical start alone (``generic.classical.NoEncoder``)."""
    if order in ORDERS:
        return load_generic(f"generic-{order}")
    if order > MAX_ORDER:
        raise ValueError(f"order must be at most {MAX_ORDER} (encoders for orders "
                         f"{ORDERS[0]}-{ORDERS[-1]}, the classical start alone above) or None; "
                         f"got {order} (pass identifier= for another order)")
    shipped = _shipped(ORDERS[-1]).config
    return NoEncoder(order, shipped.window, shipped.band)


def _generic(ident):
    """``ident`` if it has what a generic identifier offers, else a ValueError naming it."""
    config = getattr(ident, "config", None)
    if not (hasattr(ident, "denominators") and all(
            hasattr(config, k) for k in ("window", "order", "band"))):
        raise ValueError(f"identifier must be a generic identifier (ae.load_generic), its "
                         f"name or file, or a dict order -> identifier; got "
                         f"{type(ident).__name__}")
    return ident


def _identifiers(order, *, identifier) -> dict:
    """Order -> generic identifier: the given one(s) (an identifier, its shipped name or file,
    or a dict order -> identifier), or the shipped ``generic-n``."""
    if isinstance(identifier, (str, os.PathLike)):
        try:
            identifier = load_generic(identifier)
        except ValueError as err:
            raise ValueError(f"identifier: {err}") from None
    if identifier is None:
        chosen = {n: _shipped(n) for n in (range(1, MAX_ORDER + 1) if order is None
                                            else (order,))}
    elif isinstance(identifier, dict):
        chosen = {n: _generic(ident) for n, ident in identifier.items()}
    else:
        chosen = {int(_generic(identifier).config.order): identifier}
    if order is not None:
        if order not in chosen:
            raise ValueError(f"identifier must be a generic identifier of order {order} (or "
                             f"a dict order -> identifier that has it); got orders "
                             f"{sorted(chosen)}")
        return {order: chosen[order]}
    return chosen
