"""Your own mechanism, measured: for mechanisms written as Lagrangians (``symbolic.mechanisms``),
the identifiability report, an identifier trained through exactly the user's API
(``Physical(mechanism)``, ``ParameterFamily``, ``train`` and its physical head) within a time
budget, and its accuracy and speed against a cold grey-box fit and n4sid, side by side in one run
(``aeid-struct bench-mechanism``).

Per case and noise level, on records the training never saw (PRBS from rest), the median
relative error of every parameter for: the encoder alone, the one pass (encoder + five head
iterations), ``refine=True``, ``refine=True, starts=3`` ("refined x4": the refinement beside
the fits from three fixed points of the box, ``identification.multistart``), the cold grey-box
fit (scipy's output-error least squares in the same structure from 4 starts drawn in the box,
the best cost kept: what ``greyest`` does from guesses), and n4sid's model taken to the nearest
parameters (the head's coefficient inverse); batch-1 medians of the one pass, the
refinements and the cold fit. Per record, the output-error cost of each method at its
parameters: the one pass's excess over refined's (median, 90th percentile), and how often
refined, refined x4 and the cold fit reach the lowest of their optima (a record's own
optimum, which medians of parameter errors over a few dozen noisy records read only roughly).
And the iterations (Jacobians) each spends: refined's after the one pass, the cold fit's over
its four starts; at the same cost per iteration their ratio bounds refined's speed-up.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

__all__ = ["CASES", "Case", "bench_mechanism", "report"]


@dataclass(frozen=True)
class Case:
    """One mechanism of the benchmark.

    Attributes
    ----------
    name : str
    mechanism : str
        The ``symbolic.mechanisms`` function.
    bounds : dict name -> (lo, hi)
    known : dict name -> float
    channel : tuple or None
        ``(output, input[, states])``; None where ``channels`` are given.
    operating : dict
        ``q`` / ``u`` of the rest point.
    dt : float
    steps : int
    train : bool
        Whether an identifier is trained (else the report alone: a channel that cannot
        determine every parameter).
    channels : tuple, optional
        Several channels of one record (``Physical(..., channels=...)``).
    experiments : bool
        The channels are records of separate experiments, one input moving in each
        (``Physical(..., experiments=True)``: a coupled mechanism of several inputs).
    together : bool
        The channels are every output of every input of one record in which the inputs move
        at once (``Physical(..., outputs=..., inputs=...)``: each output their sum).
    """

    name: str
    mechanism: str
    bounds: dict
    known: dict
    channel: tuple
    operating: dict
    dt: float
    steps: int
    train: bool = True
    channels: tuple | None = None
    experiments: bool = False
    together: bool = False

    @property
    def specs(self) -> tuple:
        """The channels, one ``(output, input[, states])`` per record."""
        return self.channels if self.channels is not None else (self.channel,)

    @property
    def grid(self) -> dict:
        """``steps`` and ``dt`` of a record set (tuples for several channels)."""
        R = len(self.specs)
        return ({"steps": self.steps, "dt": self.dt} if R == 1 else
                {"steps": (self.steps,) * R, "dt": (self.dt,) * R})

    def structure(self):
        """The case's ``Physical`` structure, built through the user's API."""
        from aeid_struct.structures import Physical

        mech, operating = _mechanism(self)
        if self.together:
            where = {"outputs": list(dict.fromkeys(s[0] for s in self.specs)),
                     "inputs": list(dict.fromkeys(s[1] for s in self.specs))}
        else:
            where = ({"channel": self.channel} if self.channels is None
                     else {"channels": self.channels}) | {"experiments": self.experiments}
        return Physical(mech, bounds=self.bounds, known=self.known or None, **where,
                        **operating)


#: The benchmark's mechanisms.
CASES = (
    Case("lever (r known)", "lever", {"m": (0.5, 2.0), "k": (10.0, 50.0), "d": (0.5, 3.0)},
         {"r": 1.5}, (0, 0), {}, 0.02, 300),
    Case("leg, translation", "leg", {"k": (20.0, 25.0), "d": (2.0, 5.0), "m": (0.5, 1.5)},
         {"l0": 0.8, "g": 9.81}, (0, 0, (0, 2)), {"upright": True}, 0.01, 300),
    Case("two-mass", "two_mass", {n: (0.5, 2.0) for n in ("m1", "m2", "k1", "k2", "c1", "c2")},
         {}, (0, 0), {}, 0.05, 400),
    Case("leg, rotation", "leg", {"k": (20.0, 25.0), "d": (2.0, 5.0), "m": (0.5, 1.5)},
         {"l0": 0.8, "g": 9.81}, (1, 1, (1, 3)), {"upright": True}, 0.005, 300, train=False),
    Case("cart-pole, both outputs", "cart_pole",
         {"M": (0.5, 2.0), "m": (0.05, 0.5), "l": (0.3, 1.0), "b": (0.05, 1.0)},
         {"g": 9.81}, None, {"q": [0, 0]}, 0.01, 100, channels=((0, 0), (1, 0))),
    Case("drive train, both angles", "drive_train",
         {"J1": (0.01, 0.05), "J2": (0.02, 0.2), "k": (50.0, 200.0), "c": (0.05, 0.5),
          "b": (0.01, 0.1)}, {}, None, {"q": [0, 0]}, 0.005, 300,
         channels=((0, 0), (1, 0))),
    Case("leg, both subsystems", "leg", {"k": (20.0, 25.0), "d": (2.0, 5.0), "m": (0.5, 1.5)},
         {"l0": 0.8, "g": 9.81}, None, {"upright": True}, 0.005, 300,
         channels=((0, 0, (0, 2)), (1, 1, (1, 3)))),
    Case("quarter car", "quarter_car",
         {"ms": (200.0, 400.0), "mu": (25.0, 50.0), "ks": (1.5e4, 3e4), "cs": (800.0, 2000.0),
          "kt": (1.5e5, 2.5e5)}, {}, (0, 0), {}, 0.002, 400),
    Case("coupled masses, one experiment per force", "coupled_masses",
         {n: (0.5, 2.0) for n in ("m1", "m2", "k1", "k2", "c1", "c2")}, {}, None, {}, 0.05,
         400, channels=((0, 0), (1, 0), (0, 1), (1, 1)), experiments=True),
    Case("coupled masses, both forces at once", "coupled_masses",
         {n: (0.5, 2.0) for n in ("m1", "m2", "k1", "k2", "c1", "c2")}, {}, None, {}, 0.05,
         400, channels=((0, 0), (0, 1), (1, 0), (1, 1)), together=True),
    Case("lever (r unknown)", "lever", {"m": (0.5, 2.0), "k": (10.0, 50.0), "d": (0.5, 3.0),
                                        "r": (0.5, 2.0)}, {}, (0, 0), {}, 0.02, 300,
         train=False),
)


def _mechanism(case: Case):
    """The case's mechanism and its operating keywords."""
    from symbolic import mechanisms

    mech = getattr(mechanisms, case.mechanism)()
    operating = dict(case.operating)
    if operating.pop("upright", False):
        operating["q"] = mechanisms.upright(mech)["q"]
    return mech, operating


def _report(case: Case) -> dict:
    from symbolic.identifiability import identifiability

    mech, operating = _mechanism(case)
    channels = ({"pairs": [s[:2] for s in case.specs]} if case.experiments else
                {"inputs": sorted({s[1] for s in case.specs}),
                 "outputs": list(dict.fromkeys(s[0] for s in case.specs))})
    rep = identifiability(mech, case.bounds, known=case.known or None, **channels, **operating)
    return {"rank": rep.rank, "parameters": list(rep.parameters),
            "inputs": list(rep.inputs), "outputs": list(rep.outputs),
            "identifiable": list(rep.identifiable), "unidentifiable": list(rep.unidentifiable),
            "fix": list(rep.fix), "condition": rep.condition, "text": str(rep)}


def _median_error(values: np.ndarray, truth: np.ndarray) -> list[float]:
    errors = np.abs(values / truth - 1.0)
    if np.isnan(errors).all(axis=0).any():        # a method with no estimate (n4sid, 2 outputs)
        return [float(np.nanmedian(e)) * 100 if np.isfinite(e).any() else math.nan
                for e in errors.T]
    return [float(v) for v in np.nanmedian(errors, axis=0) * 100]


def _cold(structure, y, u, dt, names, rng) -> tuple[np.ndarray, float, int]:
    """The cold grey-box fit: 4 starts in the box, the best cost; its parameters, seconds and
    the iterations of all starts."""
    from aeid_struct import baselines

    best, iterations, t0 = None, 0, time.perf_counter()
    for _ in range(4):
        start = {k: float(rng.uniform(*structure.bounds[k])) for k in names}
        try:
            fit = baselines.least_squares(y, u, dt, structure=structure, start=start)
        except (ValueError, RuntimeError, np.linalg.LinAlgError):
            continue
        iterations += int(fit.info.get("njev") or 0)     # scipy's iterations: its Jacobians
        if best is None or fit.info["cost"] < best.info["cost"]:
            best = fit
    seconds = time.perf_counter() - t0
    values = np.full(len(names), np.nan) if best is None else np.array(
        [best.elements[k] for k in names])
    return values, seconds, iterations


def _cold_joint(ph, ys, us, dts, rng) -> tuple[np.ndarray, float, int]:
    """The cold grey-box fit of several channels: the joint output-error fit
    (``refinement.fit_joint``) from 4 starts drawn in the box, the best cost (``ph``: the
    structure's ``PhysicalHead``, its systems and box); its parameters, seconds and the
    iterations of all starts."""
    from aeid_struct.refinement import fit_joint

    t0 = time.perf_counter()
    starts = rng.uniform(ph.lo, ph.hi, (4, ph.q))
    fit = fit_joint(ph.at, starts, [np.repeat(y[None], 4, 0) for y in ys],
                    [np.repeat(u[None], 4, 0) for u in us], dts, lower=ph.lo, upper=ph.hi,
                    initial=False, groups=ph.groups)
    seconds = time.perf_counter() - t0
    cost = np.where(np.isfinite(fit.cost), fit.cost, np.inf)
    best = int(np.argmin(cost))
    return ((fit.p[best] if np.isfinite(cost[best]) else np.full(ph.q, np.nan)), seconds,
            int(fit.iterations.sum()))


def _n4sid(ident, y, u, head) -> np.ndarray:
    """n4sid's model of order n, taken to the nearest parameters (the head's inverse)."""
    from aeid_struct import baselines
    from aeid_struct.structures import ccf_coefficients

    try:
        est = baselines.n4sid(y, u, ident.dt, order=ident.structure.n)
        a, c = ccf_coefficients(np.asarray(est.A)[None], np.asarray(est.b)[None],
                                np.asarray(est.c)[None])
    except (ValueError, RuntimeError, np.linalg.LinAlgError):
        return np.full(len(ident.structure.element_names), np.nan)
    coefficients = np.concatenate([a[0], c[0], [float(est.d)]])[head.free]
    if not np.isfinite(coefficients).all():
        return np.full(len(ident.structure.element_names), np.nan)
    centre = 0.5 * (head.lo + head.hi)
    return head.inverse.parameters(coefficients, centre)


def _evaluate(ident, family, case: Case, noise: float, records: int, timed: int,
              seed: int) -> dict:
    """One noise level of a trained case (module docstring)."""
    from aeid_struct.identification import PhysicalHead
    from aeid_struct.training import records as simulated

    names = ident.structure.element_names
    rec = simulated(family, records, **case.grid, excitation_kind="prbs", seed=seed,
                    noise=noise)
    several = ident.structure.records > 1
    truth = np.stack([rec.systems.params[k] for k in names], 1)
    head = ident.head
    ident.head = None
    encoder = ident.identify(rec.y, rec.u)
    ident.head = head
    one = ident.identify(rec.y, rec.u)
    refined = ident.identify(rec.y, rec.u, refine=True)
    several_starts = ident.identify(rec.y, rec.u, refine=True, starts=STARTS)
    rng = np.random.default_rng(seed)
    ph = PhysicalHead(ident.structure, initial=False)
    rows = {"encoder": np.stack([encoder.physical[k] for k in names], 1),
            "one pass": np.stack([one.physical[k] for k in names], 1),
            "refined": np.stack([refined.physical[k] for k in names], 1),
            "refined x4": np.stack([several_starts.physical[k] for k in names], 1),
            "cold grey-box x4": np.full((records, len(names)), np.nan),
            # several channels: n4sid's models per channel do not share the poles (no row)
            "n4sid": np.full((records, len(names)), np.nan) if several else np.stack(
                [_n4sid(ident, rec.y[i], rec.u[i], ph) for i in range(records)])}
    seconds = {"one pass": [], "refined": [], "refined x4": [], "cold grey-box x4": []}
    cold_iterations = np.zeros(records, dtype=int)
    for i in range(records):
        if several:
            y, u = tuple(v[i] for v in rec.y), tuple(v[i] for v in rec.u)
            rows["cold grey-box x4"][i], cold_s, cold_iterations[i] = _cold_joint(
                ph, y, u, rec.dt, rng)
        else:
            y, u = rec.y[i], rec.u[i]
            rows["cold grey-box x4"][i], cold_s, cold_iterations[i] = _cold(
                ident.structure, y, u, case.dt, names, rng)
        if i < timed:
            seconds["cold grey-box x4"].append(cold_s)
            for label, refine, starts in (("one pass", False, 0), ("refined", True, 0),
                                          ("refined x4", True, STARTS)):
                t0 = time.perf_counter()
                ident.identify(y, u, refine=refine, starts=starts)
                seconds[label].append(time.perf_counter() - t0)
    costs = {k: _costs(ph, rows[k], rec, several) for k in ("one pass", "refined",
                                                             "refined x4", "cold grey-box x4")}
    out = {"noise": noise, "errors": {k: _median_error(v, truth) for k, v in rows.items()},
           "cost": _cost_summary(costs),
           "ms": {k: float(np.median(v) * 1e3) for k, v in seconds.items()},
           # records a method gave no finite parameters for (left out of its medians)
           "failed": {k: int((~np.isfinite(v).all(axis=1)).sum()) for k, v in rows.items()}}
    # the bound on the speed-up: refine iterates from the one pass, the cold fit from four
    # starts; each iteration costs both about the same simulations
    # (one record whose head converged inside the box: refine=True checks and runs no fit)
    out["iterations"] = {
        "refined": float(np.median(np.asarray(refined.info.get("iterations", 0)))),
        "cold grey-box x4": float(np.median(cold_iterations))}
    out["speedup refined vs cold"] = out["ms"]["cold grey-box x4"] / out["ms"]["refined"]
    out["speedup refined x4 vs cold"] = (out["ms"]["cold grey-box x4"]
                                         / out["ms"]["refined x4"])
    return out


#: The extra starts of the multi-start refinement (``identify(refine=True, starts=...)``):
#: with the one pass, as many starts as the cold fit's.
STARTS = 3


#: Costs below this count as equal: an rms residual of 5e-5 of ``max|y|`` (the cost is 4 times
#: the mean square of the residual over ``max|y|``), a thousandth of the cost of 1 % noise;
#: relative excesses of noise-free records' costs (round-off over round-off) mean nothing.
FLOOR = 1e-8


def _costs(ph, P: np.ndarray, rec, several: bool) -> np.ndarray:
    """Each record's output-error cost (``refinement.fit_joint``'s, records from rest) at the
    parameters ``P (records, q)``; NaN where a method gave none."""
    from aeid_struct.refinement import fit_joint

    ys, us = (list(rec.y), list(rec.u)) if several else ([rec.y], [rec.u])
    dts = tuple(rec.dt) if several else (rec.dt,)
    ok = np.isfinite(P).all(axis=1)
    out = np.full(P.shape[0], math.nan)
    if ok.any():
        out[ok] = fit_joint(ph.at, P[ok], [y[ok] for y in ys], [u[ok] for u in us], dts,
                            lower=ph.lo, upper=ph.hi, initial=False, max_iter=0,
                            groups=ph.groups).cost
    return out


def _cost_summary(costs: dict) -> dict:
    """The one pass's cost over refined's (median and 90th percentile of the relative excess),
    and the shares of records where refined, the multi-start refinement and the cold fit reach
    the lowest of their optima (to ``1e-6``): a record's own optimum, which medians of
    parameter errors over a few dozen noisy records read only roughly. A cost is a normalised
    mean square (Eq. 14, 15): below :data:`FLOOR` costs count as equal."""
    fits = ("refined", "refined x4", "cold grey-box x4")
    with np.errstate(invalid="ignore", divide="ignore"):
        excess = (costs["one pass"] - costs["refined"]) / np.maximum(costs["refined"], FLOOR)
        best = np.nanmin(np.stack([costs[k] for k in fits]), axis=0)
        at = {k: float(np.mean(costs[k] <= best * (1 + 1e-6) + FLOOR)) for k in fits}
    finite = excess[np.isfinite(excess)]
    return {"one pass excess median": float(np.median(finite)) if finite.size else math.nan,
            "one pass excess p90": float(np.quantile(finite, 0.9)) if finite.size else math.nan,
            "refined at the best": at["refined"], "refined x4 at the best": at["refined x4"],
            "cold at the best": at["cold grey-box x4"]}


def bench_mechanism(*, seconds: float = 120.0, noises=(0.0, 0.02, 0.05), records: int = 40,
                    timed: int = 10, cases=None, seed: int = 0, progress=print) -> list[dict]:
    """Train and measure each case (module docstring).

    Parameters
    ----------
    seconds : float
        Training budget per trained case.
    noises : tuple of float
        Noise levels (std relative to ``max|y|``) of the test records.
    records : int
        Test records per noise level.
    timed : int
        Of them, those timed at batch 1.
    cases : sequence of str, optional
        Case names (default all of :data:`CASES`).
    seed : int
    progress : callable or None
        Called with a line per stage.

    Returns
    -------
    list of dict
        Per case: ``name``, ``identifiability``, and for trained ones ``training``
        (seconds, epochs) and ``levels`` (per noise level: errors per method, batch-1 ms).

    Raises
    ------
    ValueError
        A case name not in :data:`CASES`.
    """
    from aeid_struct.training import ParameterFamily, TrainConfig, train

    unknown = sorted(set(cases or ()) - {c.name for c in CASES})
    if unknown:
        raise ValueError(f"cases must be among {[c.name for c in CASES]}; got {unknown}")
    chosen = [c for c in CASES if cases is None or c.name in cases]
    say = progress or (lambda line: None)
    out = []
    for case in chosen:
        row = {"name": case.name, "identifiability": _report(case)}
        say(f"{case.name}: {row['identifiability']['text'].splitlines()[1].strip()}, "
            f"identifiable: {', '.join(row['identifiability']['identifiable']) or 'none'}")
        if case.train:
            structure = case.structure()
            family = ParameterFamily(structure)
            config = TrainConfig(**case.grid, epochs=100_000, seconds=seconds, count=20_000,
                                 excitation="prbs", noise=(0.0, 0.03), seed=seed,
                                 progress=False)
            t0 = time.perf_counter()
            ident = train(structure, family, config)      # with train()'s physical head
            row["training"] = {"seconds": time.perf_counter() - t0,
                               "epochs": ident.meta["train"]["epochs"]}
            row["parameters"] = list(structure.element_names)
            row["levels"] = []
            for noise in noises:
                level = _evaluate(ident, family, case, noise, records, timed, seed + 1)
                row["levels"].append(level)
                say(f"  noise {noise:g}: one pass "
                    f"{max(level['errors']['one pass']):.3g} %, refined "
                    f"{max(level['errors']['refined']):.3g} %, cold "
                    f"{max(level['errors']['cold grey-box x4']):.3g} % (worst parameter's "
                    f"median); refine {level['ms']['refined']:.2f} ms vs cold "
                    f"{level['ms']['cold grey-box x4']:.1f} ms")
        out.append(row)
    return out


def report(rows: list[dict]) -> str:
    """The benchmark as text tables: per case, the report and a row per method and noise.

    Parameters
    ----------
    rows : list of dict
        From :func:`bench_mechanism`.

    Returns
    -------
    str
    """
    lines = []
    for row in rows:
        lines.append(f"\n{row['name']}")
        lines.append("  " + row["identifiability"]["text"].replace("\n", "\n  "))
        if "levels" not in row:
            continue
        lines.append(f"  trained {row['training']['seconds']:.0f} s, "
                     f"{row['training']['epochs']} epochs; median |error| % per "
                     f"{', '.join(row['parameters'])}")
        for level in row["levels"]:
            lines.append(f"  noise {level['noise']:g}:")
            several = len(row["identifiability"].get("outputs", [0])) > 1
            for method, errors in level["errors"].items():
                if method == "n4sid" and several:
                    lines.append(f"    {method:<18} (several channels: n4sid's models per "
                                 "channel share no poles; no row)")
                    continue
                ms = level["ms"].get(method)
                timing = "" if ms is None else f"   {ms:.2f} ms batch-1"
                lines.append(f"    {method:<18}" + " ".join(f"{e:8.3g}" for e in errors)
                             + timing)
            failed = {k: v for k, v in level.get("failed", {}).items()
                      if v and not (k == "n4sid" and several)}
            if failed:
                lines.append("    no finite parameters for " + ", ".join(
                    f"{v} record(s) of {k}" for k, v in failed.items()))
            cost = level.get("cost")          # runs recorded before it was measured lack it
            if cost:
                median, p90 = cost["one pass excess median"], cost["one pass excess p90"]
                lines.append(f"    cost over refined's: one pass +{100 * median:.3g} % median, "
                             f"+{100 * p90:.3g} % p90")
                # runs recorded before the multi-start refinement compared two fits only
                x4 = cost.get("refined x4 at the best")
                lines.append("    at the lowest optimum of the fits: refined "
                             f"{cost['refined at the best']:.0%}"
                             + ("" if x4 is None else f", refined x4 {x4:.0%}")
                             + f", cold x4 {cost['cold at the best']:.0%} of records")
            its = level.get("iterations")         # runs recorded before it was measured lack it
            if its:
                lines.append(f"    iterations (median): refined {its['refined']:.3g} after the "
                             f"one pass, cold x4 {its['cold grey-box x4']:.3g} over its starts")
            lines.append(f"    refined is {level['speedup refined vs cold']:.0f}x faster than "
                         "the cold grey-box fit"
                         + ("" if "speedup refined x4 vs cold" not in level else
                            f", refined x4 {level['speedup refined x4 vs cold']:.1f}x"))
    return "\n".join(lines)
