"""The models of :func:`~aeid_struct.generic.identify` in normalised time and their
refinement: the separable output-error refinement of the free canonical forms from several
starts (the encoder's best candidate and a classical Steiglitz-McBride estimate), the CasADi one
for every other structure, the delay re-scanned after refinement, and the conversion to the
user's structure and time unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from aeid_struct.generic.classical import steiglitz_mcbride
from aeid_struct.generic.scoring import ccf, select
from aeid_struct.identification import Estimate, Provenance
from aeid_struct.refinement import BUCKETS, refine_record, refine_separable
from aeid_struct.simulation import fit_initial
from aeid_struct.structures import CCF, MCF, Structure

__all__ = ["COST_TOL", "Model", "better_of", "classical_start", "common_cost", "controllability",
           "denominator_of", "in_structure", "refine_casadi", "refine_free", "refine_starts"]

#: ``refine_separable``'s ``cost_tol`` (default 1e-10): a fifth fewer iterations, same median
#: fit (measured from the encoder's starts at orders 2 and 4).
COST_TOL = 1e-8


def common_cost(m: Model, y: np.ndarray, first: int) -> float:
    """Mean squared residual of ``m`` on the samples from ``first`` on.

    Models at different delays fit different samples (``y[D:]``); per fitted sample, a longer
    delay wins by dropping the record's first samples, the hardest to fit mid-motion. Compared
    on common samples (``first`` >= every delay compared), they are compared fairly.

    Parameters
    ----------
    m : Model
    y : (steps,) array
    first : int

    Returns
    -------
    float
    """
    return float(np.mean((y[first:] - m.y_hat[first:]) ** 2))


def denominator_of(A: np.ndarray) -> np.ndarray:
    """The monic denominator of a bottom-row CCF ``A``.

    Parameters
    ----------
    A : (n, n) array

    Returns
    -------
    (n + 1,) array
        Highest power first.
    """
    return np.concatenate([[1.0], -A[-1, ::-1]])


@dataclass(frozen=True)
class Model:
    """A model of a record in NORMALISED time (dt = 1): ``A, b, c, d`` in some realisation,
    its state at sample ``delay``, offset, output and mean squared residual."""

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: float
    x0: np.ndarray
    y_offset: float
    delay: int
    y_hat: np.ndarray
    fit: float
    cost: float

    @classmethod
    def of_ccf(cls, den, p) -> Model:
        A, b = ccf(den)
        return cls(A, b, p.c, p.d, p.x0, p.y_offset, p.delay, p.y_hat, p.fit, p.cost)

    def estimate(self, structure: Structure, data, seconds: float, refined: bool,
                 info: dict) -> Estimate:
        """The Estimate in physical time: ``A / dt, b / dt``, the same ``c, d, x0``."""
        dt = data.dt
        A, b, c, d, x0, elements = in_structure(structure, self, dt)
        y_offset, fit, y_hat, cost = self.y_offset, self.fit, self.y_hat, self.cost
        if not _free_ccf(structure):
            # elements_of gives the closest model the structure admits, not this one (a fixed
            # element the data contradict moves it): the initial state, offset, output and
            # fit are the returned model's own
            with np.errstate(all="ignore"):
                p = fit_initial(A, b, c, d, data.y, data.u, dt, delay=self.delay, offset=True)
            x0, y_offset, fit, y_hat, cost = p.x0, p.y_offset, p.fit, p.y_hat, p.cost
        info = {**info, "delay": self.delay, "x0": x0, "y_offset": y_offset,
                "fit": fit, "y_hat": y_hat, "cost": cost}
        return Estimate(A=A, b=b, c=c, d=d, elements=elements, record=data,
                        provenance=Provenance(structure=structure, initial="fitted"),
                        seconds=seconds, refined=refined, info=info)


def _free_ccf(structure: Structure) -> bool:
    """The structure :func:`in_structure` converts exactly: the free CCF with a feedthrough."""
    return isinstance(structure, CCF) and not structure.fixed_values and structure.feedthrough


def in_structure(structure: Structure, m: Model, dt: float):
    """``A, b, c, d, x0, elements`` of the physical-time model ``(A_n / dt, b_n / dt, c, d)``
    in ``structure``'s realisation (the state transformed with it, ``x = T x_n``: for the free
    CCF the exact diagonal ``T = diag(dt^(n-i))``, else ``T = C_s C_n^-1`` from the
    controllability matrices)."""
    A, b = m.A / dt, m.b / dt
    n = A.shape[0]
    if _free_ccf(structure):
        # m.A is a CCF in normalised time (the projection's, or refined in CCF): its
        # coefficients in physical time are a_i / dt^(n-i), no torch needed
        den = np.concatenate([[1.0], -m.A[-1, ::-1]]) / dt ** np.arange(n + 1)
        As, bs = ccf(den)
        # the state in physical time is z_i = dt^(n-i) x_i (i = 0..n-1): z_(i+1) = dz_i/dt
        # and b = e_n hold exactly. Diagonal, so exact where the controllability matrices of a
        # stiff model (a pole at -1e5 per sample) are singular to working precision: their
        # T = C_s C_n^-1 gave a c whose fit was -1e6 % for a model that fits 90 %.
        T = dt ** (n - np.arange(n, dtype=np.float64))
        cs = m.c / T
        values = np.concatenate([den[:0:-1], cs, [m.d]])
        names = [f"a{i}" for i in range(n)] + [f"c{i}" for i in range(n)] + ["d"]
        return As, bs, cs, m.d, T * m.x0, dict(zip(names, values.tolist(), strict=True))
    x = structure.elements_of(A, b, m.c, m.d, strict=False).to(torch.float64)
    s = structure.assemble(x)
    As, bs, cs = (t.numpy() for t in (s.A, s.b, s.c))
    T = controllability(As, bs) @ np.linalg.inv(controllability(A, b))
    elements = dict(zip(structure.element_names, x.tolist(), strict=True))
    return As, bs, cs, float(s.d), T @ m.x0, elements


def controllability(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    cols = [b]
    for _ in range(A.shape[0] - 1):
        cols.append(A @ cols[-1])
    return np.stack(cols, axis=1)


def refine_casadi(structure: Structure, m: Model, data, max_delay: int):
    """``(Model, info)`` of ``refinement.refine_record`` from ``m``; the model is None where
    the refinement did not run (a record longer than its largest bucket) or failed.

    A structure with fixed elements (or one that is not canonical) holds its elements in the
    user's time unit, so it is refined in physical time; the canonical forms are refined in
    normalised time (better scaled: a_k ~ (|p| dt)^(n-k) instead of |p|^(n-k))."""
    physical = bool(structure.fixed_values) or not isinstance(structure, (CCF, MCF))
    dt = data.dt if physical else 1.0
    scale = data.dt if physical else 1.0
    start = structure.elements_of(m.A / scale, m.b / scale, m.c, m.d, strict=False)
    D = m.delay
    delays = (D,) if data.delay is not None else tuple(
        k for k in (D - 1, D, D + 1) if 0 <= k <= max_delay)
    if data.steps - min(delays) > BUCKETS[-1]:
        return None, {"refinement": f"skipped: more than {BUCKETS[-1]} samples"}
    r = refine_record(structure, start.to(torch.float64).numpy(), data.y, data.u, dt,
                      delay=D, delays=delays, offset=True)
    if not np.isfinite(r.cost):
        return None, {"refinement": "failed: no finite cost"}
    y_hat = np.asarray(r.y_hat, dtype=np.float64)
    used = ~np.isnan(y_hat)
    cost = float(np.mean((data.y[used] - y_hat[used]) ** 2))
    A, b = np.asarray(r.A, float) * scale, np.asarray(r.b, float) * scale
    model = Model(A, b, np.asarray(r.c, float), float(r.d), np.asarray(r.x0, float),
                   float(r.y_offset), int(r.delay), y_hat, float(r.fit), cost)
    return model, {"iterations": r.iterations, "converged": r.converged,
                   "refine_seconds": r.seconds}


def refine_free(structure: Structure, m: Model, data, max_delay: int, *,
                split: bool = False, search: bool = True, max_iter: int = 100):
    """``(Model, info)`` of ``refinement.refine_separable`` from ``m`` (normalised time) at its
    delay; then every delay of ``0..max_delay`` re-scanned by projection with the refined poles
    and the best other one refined too where it is better (a wrong delay is partly absorbed by
    the poles, so the delay found before refinement can be several samples off). None for an
    MCF whose optimum is not stable in its form (the caller falls back to CasADi, which keeps
    ``Re < 0``): not stable, or (``split``: the user's MCF) with other real poles and pairs
    than the structure's.

    Parameters
    ----------
    structure : CCF or MCF
        Free (no fixed elements).
    m : Model
        The start, a CCF in normalised time.
    data : Record
        The record (``y, u, delay``: the known delay or None).
    max_delay : int
    split : bool
    search : bool
        Search the delay (else refine at ``m.delay`` only).
    max_iter : int, >= 1
        Levenberg-Marquardt iterations per refinement, at most (the one pass of ``identify``
        runs a fixed few).

    Returns
    -------
    model : Model or None
    info : dict
    """
    feedthrough = "d" in structure.element_names and "d" not in structure.fixed_values
    seconds, iterations = 0.0, 0

    def run(den, D):
        nonlocal seconds, iterations
        r = refine_separable(den, data.y, data.u, 1.0, delay=D, feedthrough=feedthrough,
                             cost_tol=COST_TOL, max_iter=max_iter)
        seconds, iterations = seconds + r.seconds, iterations + r.iterations
        y_hat = np.asarray(r.y_hat, dtype=np.float64)
        cost = float(np.mean((data.y[D:] - y_hat[D:]) ** 2))
        return Model(r.A, r.b, r.c, r.d, r.x0, r.y_offset, D, y_hat, r.fit, cost), r.converged

    best, converged = run(denominator_of(m.A), m.delay)
    if search and data.delay is None and max_delay > 0:
        top = min(max_delay, data.y.shape[0] - 4 * m.A.shape[0] - 4)
        best, converged = _delay_search(run, best, converged, data.y, top)
    poles = np.linalg.eigvals(best.A)
    real = int(np.sum(np.abs(poles.imag) <= 1e-9 * np.abs(poles).max()))
    if isinstance(structure, MCF) and not (np.all(poles.real < 0) and (
            not split or real == structure.real)):
        return None, {"refinement": "separable optimum not a stable MCF: CasADi"}
    return best, {"iterations": iterations, "converged": converged, "refine_seconds": seconds,
                  "method": "separable"}


def _delay_search(run, best: Model, converged: bool, y: np.ndarray, top: int):
    """A local search over the delay by refinement: from the refined model at its delay, step
    the delay up and then down, each refinement warm-started from its neighbour's poles, until
    two steps in a row do not improve the cost on the common samples (from ``top`` on); then
    the shortest delay within ``2 / N`` of the best (:func:`better_of`).

    Why refine at each delay rather than re-scan by projection with the refined poles: the
    poles adapt to a wrong delay (a one-sample error is partly absorbed by a faster or slower
    pole), so at the other delays those poles look worse than they are; measured, the re-scan
    kept delays one or two samples off with validation fits 5 points below the true model's.
    """
    tried = {best.delay: (best, converged)}
    for step in (1, -1):
        prev, D, worse = best, best.delay + step, 0
        while 0 <= D <= top and worse < 2:
            if D not in tried:
                tried[D] = run(denominator_of(prev.A), D)
            model = tried[D][0]
            if common_cost(model, y, top) < common_cost(best, y, top):
                best, worse = model, 0
            else:
                worse += 1
            prev, D = model, D + step
    chosen = better_of([t[0] for t in tried.values()], y)
    return chosen, next(t[1] for t in tried.values() if t[0] is chosen)


def classical_start(data, order: int, delay: int, max_delay: int,
                    feedthrough: bool) -> Model | None:
    """The Steiglitz-McBride start (``generic.classical``) at the delay that fits it best.

    Parameters
    ----------
    data : Record
    order : int
    delay : int
        The delay the candidates were found at (the ARX estimate, or the known delay).
    max_delay : int
    feedthrough : bool

    Returns
    -------
    Model or None
        None where the estimate is not finite.
    """
    den = steiglitz_mcbride(data.y, data.u, order, delay)
    if den is None:
        return None
    top = min(max_delay, data.y.shape[0] - 4 * order - 4)
    delays = [delay] if data.delay is not None else range(max(top, 0) + 1)
    chosen = select(den[None], data.y, data.u, delays, feedthrough=feedthrough)
    if not np.isfinite(chosen.projection.cost):
        return None
    return Model.of_ccf(den, chosen.projection)


def better_of(models, y: np.ndarray) -> Model | None:
    """The model with the least mean squared residual, with two preferences: a stable model
    (an unstable one wins only where its cost is below 0.99 times every stable one's: a
    slightly unstable pole fits an estimation record about as well and ruins any longer
    prediction) and, among those within ``2 / N`` of the least cost, the shortest delay (the
    parsimony of the delay's selection, ``generic.scoring.select``); costs on the samples every
    model fits (:func:`common_cost`).

    Parameters
    ----------
    models : iterable of Model or None
    y : (steps,) array
        The record's output.

    Returns
    -------
    Model or None
    """
    models = [m for m in models if m is not None and np.isfinite(m.cost)]
    if not models:
        return None
    first = max(m.delay for m in models)
    cost = {id(m): common_cost(m, y, first) for m in models}
    samples = y.shape[0] - first
    stable = [m for m in models if np.all(np.linalg.eigvals(m.A).real < 0)]
    best = min(models, key=lambda m: cost[id(m)])
    if stable and not any(m is best for m in stable):
        best_stable = min(stable, key=lambda m: cost[id(m)])
        if cost[id(best)] >= 0.99 * cost[id(best_stable)]:
            best = best_stable
    pool = stable if any(m is best for m in stable) else models
    close = [m for m in pool if cost[id(m)] <= cost[id(best)] * (1.0 + 2.0 / samples)]
    return min(close, key=lambda m: (m.delay, cost[id(m)]))


def refine_starts(structure: Structure, m: Model, data, max_delay: int, *,
                  split: bool = False, classical: bool = True):
    """:func:`refine_free` from the encoder's start ``m`` and from the classical start
    (:func:`classical_start`), the better kept (:func:`better_of`); ``info["start"]`` says
    which. Measured on the benchmark's stand-in for a flexible arm: from the encoder's start
    alone the refinement stopped in a local minimum (validation fit 87 % against 98 %).

    Parameters
    ----------
    structure : CCF or MCF
    m : Model
    data : Record
    max_delay : int
    split : bool
        As in :func:`refine_free`.
    classical : bool
        Refine from the classical start too (else from ``m`` alone).

    Returns
    -------
    model : Model or None
    info : dict
    """
    order = m.A.shape[0]
    feedthrough = "d" in structure.element_names and "d" not in structure.fixed_values
    # both starts refined at their own delay, the delay searched from the better one only
    results = [refine_free(structure, m, data, max_delay, split=split, search=False)]
    alt = classical_start(data, order, m.delay, max_delay, feedthrough) if classical else None
    if alt is not None:
        results.append(refine_free(structure, alt, data, max_delay, split=split, search=False))
    chosen = better_of((r[0] for r in results), data.y)
    if chosen is None:
        return None, results[0][1]
    k = next(i for i, r in enumerate(results) if r[0] is chosen)
    final, info = refine_free(structure, chosen, data, max_delay, split=split)
    if final is None:
        final, info = chosen, dict(results[k][1])
    info = dict(info)
    info["start"] = ("encoder", "classical")[k]
    info["iterations"] = (sum(r[1].get("iterations", 0) for r in results)
                          + info.get("iterations", 0))
    info["refine_seconds"] = (sum(r[1].get("refine_seconds", 0.0) for r in results)
                              + info.get("refine_seconds", 0.0))
    return final, info
