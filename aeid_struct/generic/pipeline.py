r"""The steps of one call (:func:`run`, the body of ``ae.identify``): a measured record with a
generic identifier.

The model of a record (docs/architecture.md, "Any system, any record"):

    y_k = yhat_k(A, b, c, d; u delayed by D samples) + c^T e^{A k dt} x_0 + y_offset,

identified in normalised time (dt = 1, time in samples) and de-normalised at the end
(``A = A_n / dt``, ``b = b_n / dt``, the same ``c, d`` and state). The steps:

1. the record is validated once (a :class:`~aeid_struct.records.Record` or arrays); it is not
   detrended (the offset is a parameter of the model);
2. the input delay by an ARX scan (:func:`~aeid_struct.generic.delay.arx_delay`) unless known;
3. candidate denominators from windows at several time scales, each read unweighted and under
   the growth weights, one batched identifier call
   (:func:`~aeid_struct.generic.windows.candidates`);
4. the best candidate and delay by whole-record projection: every candidate at the ARX delay,
   the :data:`SHORTLIST` best of them also at ``D_arx - 1`` and ``D_arx + 1``
   (:func:`~aeid_struct.generic.scoring.select`; only the known delay where it is known);
5. unless ``refine=False``, output-error refinement over the whole record, kept if its mean
   squared residual is lower. The free CCF (the default) and MCF: separable least squares
   (``refinement.refine_separable``: only the denominator iterated, ``c, d, x_0`` and the
   offset projected) at the chosen delay; then ``D - 1`` and ``D + 1`` are re-checked by
   projection with the refined poles and refined again only where one is better. An MCF whose
   separable optimum is not stable, and every other structure (fixed elements, physical):
   CasADi (``refinement.refine_record``) with delays ``D - 1, D, D + 1``;
6. for a refined model, the closed-loop test of its residuals (``generic.feedback``): where it
   finds the input correlated with earlier residuals, a warning, and the default structure
   identified again without its feedthrough ``d`` (steps 2-5 once more);
7. for every model, refined or not, the lightly damped pairs the record does not determine
   (``multi.excitation``: the measured output holds only noise near their frequency, and
   their resonance is far above the model's gain where the input is): ``info["unexcited"]``
   and an :class:`UnexcitedModeWarning`. The model is returned as fitted (it is the
   least-squares optimum of its order); what to do is the user's choice (a lower order, or
   an input that reaches those frequencies).

*The one pass* (``refine=False``): steps 2-4 with classical candidates beside the encoder's,
the Steiglitz-McBride estimate at the ARX delay after five refits and at its fixed point
(``generic.classical.classical_candidates``; ``classical=False`` leaves them out), then a
fixed number of separable Levenberg-Marquardt iterations (``iterations``, default
:data:`ITERATIONS`; ``refinement.refine_separable`` with ``max_iter``) from the chosen candidate
at the chosen delay, for the free CCF and MCF (a structure with fixed elements: the
iterations run in the free CCF, and the closest model in the structure is returned, its initial
state, offset and fit its own); where the delay is unknown, it is re-scanned by projection with
the iterated poles, and at a better delay as many iterations again. A bounded cost: at most
twice ``iterations`` iterations and one re-scan; no search by refinement, no second start.
``iterations=0, classical=False`` is the encoder's pass alone (candidates and projection), as
before the iterations were added. Why: the iterations close the gap from a good start to the
output-error optimum (the encoder's poles are near it, not at it, and the projected ``c, d,
x_0`` inherit their error); the classical candidate is a good start where no window of the
encoder's gives one; the re-scan undoes a delay chosen to absorb the start's error in the
poles. ``aeid-struct bench-generic`` measures the pass, the encoder's pass alone and the
refined model on the same records.

*Order selection* (``order=None``): each available order (``ae.identify``: 1-8, those the
record has samples for), from the lowest until three orders in a row improve on none before them
(``multi.order_search_done``), is identified (refined where
``refine``: an encoder's error in the poles would otherwise favour a higher order that absorbs
it) on the first 70 % of the record and validated on the last 30 % (NRMSE fit with the initial
state and offset fitted, MATLAB's ``compare``); the smallest order whose validation fit is
within :data:`ORDER_TOLERANCE` points of the best is chosen and identified on the whole
record. Where 70 % of the record is shorter than the identifier's window, or holds no
variation of the input or output (a step late in the record), or the last 30 % none of the
output, each order is identified on the whole record and the one of least Bayesian information
criterion ``N log V + 3 n log N`` is chosen (``V`` the mean squared residual over the ``N``
fitted samples, at least ``(EXACT std(y))^2``, so that exact fits count as equal; ``3 n`` the
parameters that grow with the order: denominator, numerator and initial state). Why not the
fit rule there: on the record it was fitted to, a higher order always fits better, and within
half a point of the best was order 5-8 for records of 80 samples of orders 1-3 (their
validation fits 60-500000 points below the true order's on 3 of 18); the criterion chose the
true order on 11 of them. Either rule chooses among the orders whose model has no mode the
record does not determine (step 7; all orders where every one has): such an order is one the
record cannot fill, and on short records its model, whose fit the rule would otherwise reward,
validated far below a smaller order's.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from aeid_struct.generic.boundary import METHODS as METHODS
from aeid_struct.generic.boundary import checked, shortest, warn_caller
from aeid_struct.generic.boundary import measured as measured
from aeid_struct.generic.classical import classical_candidates
from aeid_struct.generic.delay import arx_delay
from aeid_struct.generic.feedback import feedback_test, warn_feedback
from aeid_struct.generic.holdout import residual_ratio, warn_holdout
from aeid_struct.generic.normalised import Model, held_stable, structure_of
from aeid_struct.generic.polish import (
    better_of,
    iterate,
    one_pass,
    refine_casadi,
    refine_model,
    refine_starts,
)
from aeid_struct.generic.result import estimate_of, restore
from aeid_struct.generic.scoring import select
from aeid_struct.generic.windows import candidates
from aeid_struct.identification import Estimate
from aeid_struct.multi import (
    ESTIMATION_SHARE,
    EXACT,
    MAX_DELAY,
    ORDER_TOLERANCE,
    chosen_order,
    order_search_done,
    stabilised,
    unexcited_modes,
)
from aeid_struct.records import Record
from aeid_struct.simulation import fit_initial
from aeid_struct.structures import CCF

__all__ = ["ESTIMATION_SHARE", "ITERATIONS", "MAX_DELAY", "METHODS", "ORDER_TOLERANCE",
           "StableOnlyWarning", "UnexcitedModeWarning", "run", "warn_stable_only",
           "warn_unexcited"]

#: Candidates re-scanned at the neighbouring delays (the others are scored at the ARX delay).
SHORTLIST = 2
#: Levenberg-Marquardt iterations of the one pass (``refine=False``) of one channel; chosen by
#: ``aeid-struct bench-generic``: from 3 to 10 (1,203 records, orders 1-4, stable, integrating
#: and unstable plants: from the encoder's candidates alone within a point of refined on 86 % of
#: records against 79 %, for 7 % more time), then to 30 (its 64-200-sample rows, orders 1-8:
#: the one pass within a point of refined on 89 % of records against 87 %, from the encoder's
#: candidates alone 84 % against 80 %, for about 1 ms; on 400-1,000 samples the same fits and
#: times: the iterations stop where they converge).
ITERATIONS = 30


@dataclass(frozen=True)
class _Fit:
    """A normalised-time fit: the denominator, its projection, and how it was found
    (``start``: the winning candidate is the encoder's or the classical one)."""

    den: np.ndarray
    projection: object
    candidates: int
    start: str = "encoder"


def _encoder_fit(identifier, y, u, order, known, max_delay, feedthrough,
                 classical=False, intersample="foh", fallback=False, stable=False) -> _Fit:
    """Steps 2-4 of the module docstring, in normalised time (``classical``: the
    Steiglitz-McBride candidates too, as in the one pass; ``fallback``: them where the
    identifier proposes none, an order without an encoder; ``intersample``: the record's
    hold; ``stable``: a structure held to stable models, every candidate's unstable poles
    mirrored into the left half-plane, ``multi.stabilised``, before they are scored)."""
    N = y.shape[0]
    room = N - shortest(order)
    D0 = known if known is not None else arx_delay(y, u, order, min(max_delay, room))
    dens = candidates(identifier, y[D0:], u[: N - D0])
    if dens.shape[1] != order + 1:
        raise ValueError(f"identifier must give denominators of order {order} ((K, "
                         f"{order + 1}) arrays); got shape {dens.shape}")
    if len(dens) == 0:
        Record(y, u).require_informative()     # the one message for a constant y or u
    sm = (classical_candidates(y, u, order, D0) if classical or (fallback and len(dens) == 0)
          else np.zeros((0, order + 1)))
    if len(dens) == 0 and len(sm) == 0:
        raise ValueError(f"the generic identifier of order {order} found no usable model in "
                         f"any window of this record ({N} samples)"
                         + ("" if fallback else "; classical=False leaves out the classical "
                            "start"))
    if len(dens) >= 3:
        # the coefficient-wise median as one more candidate: measured on 300 random systems
        # (orders 1-4, 5 perturbed candidates and an outlier), choosing among candidates plus
        # their median beat both the median alone and the candidates alone
        dens = np.vstack([dens, np.median(dens, axis=0)])
    encoder = len(dens)
    dens = np.vstack([dens, sm])
    if stable:
        # the modal form cannot take an unstable start: a start kept unstable was returned
        # clamped to the axis (a 3rd-order record of 200 samples: fit -5 % against 80 % from
        # the mirrored start), or, beside a refined stable model, kept as the estimate
        dens = np.array([np.real(np.poly(stabilised(np.roots(den)))) for den in dens])
    top = min(max_delay, room)
    delays = [D0] if known is not None else range(top + 1)
    chosen = select(dens, y, u, delays, feedthrough=feedthrough, shortlist=SHORTLIST,
                    around=D0, intersample=intersample)
    return _Fit(dens[chosen.index], chosen.projection, len(dens),
                "encoder" if chosen.index < encoder else "classical")


def _select_order(identifiers: dict, data: Record, max_delay: int, feedthrough,
                  refine: bool, method: str, iterations: int, classical: bool) -> tuple:
    """Validation fit per order (see the module docstring), each order's model found as the
    chosen order's is (the one pass, or refined); returns ``(fits, criterion, flagged,
    ratios)``: order -> fit, order -> Bayesian information criterion where there is no holdout
    (else None), the orders whose model has a mode the record does not determine (step 7), and
    order -> the hold-out's residual ratio (``generic.holdout.holdout_flagged``; empty without a
    hold-out)."""
    N = data.steps
    cut = int(round(ESTIMATION_SHARE * N))
    # a part that says nothing (the input's step after the cut, an output at rest before it)
    # cannot be fitted, and a validation part at rest scores nothing: the whole record then
    holdout = (cut >= max(int(i.config.window) for i in identifiers.values())
               and np.ptp(data.u[:cut]) > 0 and np.ptp(data.y[:cut]) > 0
               and np.ptp(data.y[cut:]) > 0)
    part = Record(data.y[:cut], data.u[:cut], data.dt, delay=data.delay,
                  intersample=data.intersample) if holdout else data
    fits, criterion, flagged, ratios = {}, ({} if not holdout else None), set(), {}
    for n, ident in sorted(identifiers.items()):
        fit = _encoder_fit(ident, part.y, part.u, n, data.delay, max_delay, feedthrough,
                           classical and not refine, data.intersample, classical)
        model = Model.of_ccf(fit.den, fit.projection)
        ccf_n = CCF(n, feedthrough=feedthrough)
        if refine:
            better, _ = (refine_casadi(ccf_n, model, part, max_delay) if method == "casadi" else
                         refine_starts(ccf_n, model, part, max_delay, classical=classical,
                                       origin=fit.start))
            model = better_of([model, better], part.y) if better is not None else model
        else:
            model = iterate(None, ccf_n, model, part, iterations, max_delay)[0]
        if _undetermined(model, part):
            flagged.add(n)
        if not holdout:
            fits[n] = model.fit
            used = N - model.delay
            # fits within round-off of exact count as equal (EXACT), or the criterion of a
            # noise-free record would prefer the order whose round-off is smallest
            floor = (EXACT * np.std(data.y)) ** 2
            criterion[n] = used * np.log(max(model.cost, floor)) + 3 * n * np.log(used)
            if order_search_done(list(criterion.values()), lower=True):
                break
            continue
        rest = fit_initial(model.A, model.b, model.c, model.d, data.y[cut:], data.u[cut:],
                           1.0, delay=min(model.delay, N - cut - 2),
                           intersample=data.intersample)
        fits[n], ratios[n] = rest.fit, residual_ratio(rest.cost, model.cost)
        if order_search_done(list(fits.values()), lower=False):
            break
    return fits, criterion, flagged, ratios


def run(resolve, record, order=None, *, structure=None, refine=True, delay=None,
        max_delay=None, method="auto", iterations=ITERATIONS, classical=True,
        what: str = "ae.identify") -> Estimate:
    """The steps of the module docstring for the generic identifiers ``resolve`` gives: the
    body of ``ae.identify`` (``generic.one_call.identify``, whose docstring describes the
    arguments) and of ``GenericIdentifier.identify``.

    Parameters
    ----------
    resolve : callable
        ``resolve(order) -> dict order -> generic identifier`` (``order`` None: every order
        to select among), called once the arguments are checked; it raises a ValueError for
        an order it cannot serve. The entry points pass their own, so that this module knows
        no loader (no import cycle with the identifier's class).
    record, order, structure, refine, delay, max_delay, method, iterations, classical
        As ``ae.identify``.
    what : str
        The entry point, named in the message that refuses a record of several channels.

    Returns
    -------
    Estimate
    """
    start = time.perf_counter()
    call = checked(resolve, record, order, structure=structure, refine=refine, delay=delay,
                   max_delay=max_delay, method=method, iterations=iterations,
                   classical=classical, what=what, default_max_delay=MAX_DELAY)
    order, order_fits, criterion, ratios = call.order, None, None, None
    fitting = (refine, method, int(iterations), bool(classical))
    if order is None:
        order_fits, criterion, flagged, ratios = _select_order(
            call.identifiers, call.work, call.max_delay, call.feedthrough, *fitting)
        order = chosen_order(order_fits, criterion, flagged)
    model, chosen, refined, info = _fit(call, order, structure, *fitting)
    # refined models only: the one pass's residual carries model error that the test reads as
    # feedback (measured: 2 false alarms in 59 open-loop records at 0-2 % noise, none refined)
    found = feedback_test(call.work.y, model.y_hat, call.work.u) if refine else None
    strict = structure is None            # the default structure: CCF with a free d
    if found is not None and found["detected"] and strict:
        # a free d takes up the noise a controller acting on the sample it measures feeds back
        # through u_k: measured on a PI loop (white noise, 10 % of the output), the poles'
        # mean error 0.043 with d and 0.002 without
        model, chosen, refined, info = _fit(replace(call, feedthrough=False), order,
                                            CCF(order, feedthrough=False), *fitting)
        found = found | {"refit": "no feedthrough"}
    if found is not None and found["detected"]:
        warn_feedback(found, strict)
    holdout, ratio = None, None
    if refine:
        used = replace(call, feedthrough=False) if found and "refit" in found else call
        holdout, ratio = _holdout(used, order, model, order_fits, ratios, criterion, fitting)
        warn_holdout(holdout, model.fit, ratio)
    info |= {"order_fits": order_fits, "feedback": found, "holdout_fit": holdout,
             "holdout_ratio": ratio,
             "unexcited": _unexcited(model, call.work)}
    est = estimate_of(model, chosen, call.work, time.perf_counter() - start, refined, info)
    return restore(call.units, est, call.data)


def _holdout(call, order: int, model: Model, order_fits, ratios, criterion,
             fitting: tuple) -> tuple[float | None, float | None]:
    """The validation fit of a model of ``order`` fitted on the first :data:`ESTIMATION_SHARE`
    of the record at the estimate's delay and run on the rest (initial state and offset
    fitted), and the ratio of its RMS residual there to its own on the first part
    (``generic.holdout.holdout_flagged``): read from ``order=None``'s ``order_fits`` and
    ``ratios`` where its hold-out ran (:func:`_select_order`), else the one pass's fit
    (``iterations`` of ``fitting``) here, records shorter than the identifier's window included
    (they are read at a finer grid). ``(None, None)`` where the record leaves no such split (a
    part too short for the order, or without variation).

    Why a hold-out and not the parameters' covariance: on the benchmark's short records the
    poles' standard errors were no smaller on the fits that validated well than on those that
    failed, while a model that cannot predict the record's own last part failed. Why the one
    pass and not a second refinement: it flagged nearly the same records at a third of the
    cost."""
    if criterion is None and order_fits and order in order_fits:
        return float(order_fits[order]), (ratios or {}).get(order)
    work, D = call.work, int(model.delay)
    cut = int(round(ESTIMATION_SHARE * work.steps))
    # the part must leave the samples a fit of this order needs after the delay, and the rest
    # at least half as many: more than the n states and the offset fitted to it
    if cut - D < shortest(order) or work.steps - cut - D < shortest(order) // 2 or not (
            np.ptp(work.u[:cut]) > 0 and np.ptp(work.y[cut:]) > 0):
        return None, None
    part = Record(work.y[:cut], work.u[:cut], work.dt, delay=D, intersample=work.intersample)
    try:
        fitted = _fit(replace(call, work=part), order, None, False, *fitting[1:])[0]
    except ValueError:       # the part refused (a record the identifiers cannot read)
        return None, None
    rest = fit_initial(fitted.A, fitted.b, fitted.c, fitted.d, work.y[cut:], work.u[cut:], 1.0,
                       delay=D, intersample=work.intersample)
    fit = float(rest.fit) if np.isfinite(rest.fit) else None
    return fit, (residual_ratio(rest.cost, fitted.cost) if fit is not None else None)


def _fit(call, order: int, structure, refine: bool, method: str, iterations: int,
         classical: bool):
    """Steps 2-5 of the module docstring at one order: ``(model, structure, refined, info)``
    in normalised time."""
    work, max_delay, feedthrough = call.work, call.max_delay, call.feedthrough
    fit = _encoder_fit(call.identifiers[order], work.y, work.u, order, work.delay, max_delay,
                       feedthrough, classical and not refine, work.intersample, classical,
                       held_stable(structure))
    model = Model.of_ccf(fit.den, fit.projection)
    spec, structure = structure, structure_of(structure, order, fit.den)
    refined = False
    info = {"candidates": fit.candidates, "start": fit.start, "max_delay": max_delay}
    if not refine:
        model, structure, about = one_pass(spec, structure, model, work, order, feedthrough,
                                           iterations, max_delay)
    else:
        model, structure, refined, about = refine_model(spec, structure, model, work, order,
                                                        feedthrough, max_delay, method,
                                                        classical, fit.start)
    info |= about
    info |= _stable_only(info.pop("unstable", None), model, work.dt)
    return model, structure, refined, info


def _undetermined(model: Model, work: Record) -> list[dict]:
    """The lightly damped pairs of the model (normalised time) that the record does not
    determine (``multi.excitation``), their poles in the record's time unit."""
    D, N = model.delay, work.steps
    used = np.isfinite(model.y_hat)
    residual = float(np.sum((work.y[used] - model.y_hat[used]) ** 2))
    found = unexcited_modes(model.A, model.b[:, None], model.c[None], np.array([[model.d]]),
                            [work.y[D:]], [work.u[: N - D]], residual, 1.0)
    return [m | {"pole": m["pole"] / work.dt} for m in found]


def _unexcited(model: Model, work: Record) -> list[dict]:
    """Step 7 of the module docstring: :func:`_undetermined`, and the
    :class:`UnexcitedModeWarning` where there are any."""
    found = _undetermined(model, work)
    warn_unexcited(found)
    return found


class UnexcitedModeWarning(UserWarning):
    """The model has a lightly damped mode that its record does not determine: the measured
    output holds only noise near its frequency, and its gain there, far above the model's gain
    where the input is, is a guess (``multi.excitation``)."""


def warn_unexcited(found: list[dict]) -> None:
    """The :class:`UnexcitedModeWarning` of ``multi.excitation.unexcited_modes``' pairs (poles
    in the record's time unit), attributed to the caller; nothing where there are none.

    Parameters
    ----------
    found : list of dict
    """
    if not found:
        return
    modes = ", ".join(f"{m['pole'].imag:.4g} rad per time unit (damping {m['damping']:.3f}, "
                      f"gain {m['gain']:.3g} times the model's where the input is)"
                      for m in found)
    warn_caller(f"the model has lightly damped modes the record does not determine: {modes}; "
                f"the measured output holds only noise near them, so the model's response to "
                f"an input that reaches them is a guess (info['unexcited']). Identify with a "
                f"lower order (order=None selects one by validation) or from an input that "
                f"excites those frequencies", UnexcitedModeWarning)


class StableOnlyWarning(UserWarning):
    """A record whose best model is unstable, identified in a structure that is stable by
    construction (the modal form): the estimate is the best stable model, not the system."""


def _stable_only(unstable: dict | None, model: Model, dt: float) -> dict:
    """``{"unstable": ...}`` (and a :class:`StableOnlyWarning`) where the free CCF's fit of the
    record, which the modal form could not take, is unstable and fits clearly better (a mean
    squared residual below 0.99 times the returned model's, ``polish.better_of``'s margin): the
    stable-only structure's estimate would otherwise pass for the system. Its poles in the
    record's time unit; empty where there is nothing to say."""
    if unstable is None or not unstable["cost"] < 0.99 * model.cost:
        return {}
    poles = np.sort_complex(np.asarray(unstable["poles"]) / dt)
    fit = 100.0 * (1.0 - np.sqrt(unstable["cost"] / model.cost) * (1.0 - model.fit / 100.0))
    warn_stable_only(poles, fit, model.fit, "identify it with structure='ccf' (the default) "
                     "and without stable=True")
    return {"unstable": {"poles": poles, "fit": float(fit)}}


def warn_stable_only(poles, fit, stable_fit, instead: str) -> None:
    """The :class:`StableOnlyWarning` of an estimate held to stable models whose records' best
    model is unstable (one channel's modal form, or ``stable=True``).

    Parameters
    ----------
    poles : (n,) complex array
        The unstable model's, in the record's time unit.
    fit, stable_fit : float or (p,) array
        Its fit % and the returned estimate's (per output for several).
    instead : str
        What to do instead, as the message's last words.
    """
    poles = np.sort_complex(np.asarray(poles))
    fits = ", ".join(f"{float(v):.1f}" for v in np.ravel(fit))
    ours = ", ".join(f"{float(v):.1f}" for v in np.ravel(stable_fit))
    warn_caller(f"the record's best model is unstable (poles {np.round(poles, 4).tolist()}, "
                f"fit {fits} % against {ours} %): the estimate is held to stable models and is "
                f"the best stable one, not the system; {instead}", StableOnlyWarning)

