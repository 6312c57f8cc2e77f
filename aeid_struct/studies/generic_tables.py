"""The rows of ``aeid-struct bench-generic`` and their tables: one record's result by one method
(:class:`Row`), the methods in table order, and the text tables (the median validation fit per
cell and method, every method against the refined model, the flags, the timings). The run that
makes the rows is ``studies.generic_bench``, which re-exports these names.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass

import numpy as np

__all__ = ["METHODS", "PLANTS", "Row", "format_tables"]

#: Method names in table order.
METHODS = ("encoder", "one pass, no SM", "one pass", "refined", "refined, D given", "n4sid",
           "least squares", "true")
#: The kinds of plant a cell can draw: the generic family's stable systems, or every system with
#: a pole at 0, or with one in the right half plane (``GenericFamily``'s ``integrating`` and
#: ``unstable`` shares at 1).
PLANTS = ("stable", "integrating", "unstable")


@dataclass(frozen=True)
class Row:
    """One record, one method.

    Attributes
    ----------
    case : str
        ``"order/index"``, or the stand-in's name.
    order : int
    noise : float
        Noise std relative to the clean output's std; -1 for the stand-ins.
    steps : int
        Estimation record length.
    method : str
        One of :data:`METHODS`.
    fit : float
        Validation fit % against the measured output.
    fit_clean : float
        Validation fit % against the noise-free output.
    seconds : float
        Wall time of the identification.
    delay : int
        The delay the method used (samples).
    start : str
        The identifiers' winning candidate or start (``info["start"]``: ``"encoder"`` or
        ``"classical"``); empty for the other methods.
    plant : str
        One of :data:`PLANTS`.
    unexcited : int
        The identifiers' pairs the record does not determine (``len(info["unexcited"])``);
        0 for the other methods.
    holdout : float
        The refined one-channel estimate's hold-out fit % (``info["holdout_fit"]``: its order
        fitted on the first 70 % of the record, run on the rest); NaN where it did not run.
    holdout_ratio : float
        Its RMS residual over the same model's on the first 70 % (``info["holdout_ratio"]``);
        with the fit, whether ``ae.UndeterminedModelWarning`` flags the estimate
        (``generic.holdout_flagged``); NaN where it did not run.
    """

    case: str
    order: int
    noise: float
    steps: int
    method: str
    fit: float
    fit_clean: float
    seconds: float
    delay: int
    start: str = ""
    plant: str = "stable"
    unexcited: int = 0
    holdout: float = float("nan")
    holdout_ratio: float = float("nan")


def _median(values) -> float:
    values = [v for v in values if np.isfinite(v)]
    return statistics.median(values) if values else float("nan")


def _gap_lines(rows: list[Row], by_case: dict) -> list[str]:
    """The one pass and the encoder's pass alone against the refined model, per record: the
    median, the 10th percentile and the count within 1 point of the difference in validation
    fit; how often the classical candidate won the one pass."""
    lines = ["", "Per record: validation fit minus the refined model's (points; the records "
                 "where both gave a model)"]
    for name in ("encoder", "one pass, no SM", "one pass"):
        gaps = np.array([v[name] - v["refined"] for v in by_case.values()
                         if np.isfinite(v.get(name, np.nan))
                         and np.isfinite(v.get("refined", np.nan))])
        if gaps.size == 0:
            continue
        lines.append(f"  {name:15s} - refined: median {np.median(gaps):6.2f}, 10th percentile "
                     f"{np.percentile(gaps, 10):7.2f}, within 1 point {int(np.sum(gaps >= -1))} "
                     f"of {gaps.size} ({np.mean(gaps >= -1):.0%})")
    won = [r.start for r in rows if r.method == "one pass" and r.start]
    lines.append(f"  one pass: the classical (Steiglitz-McBride) candidate won on "
                 f"{won.count('classical')} of {len(won)} records")
    return lines


def _flag_lines(by_case: dict, flagged: dict, what: str, below: float) -> list[str]:
    """The refined model's validation fit against the true model's on the records a flag marked
    and on the others it was computed for (``flagged``: case key -> marked): how many, the
    median gap, and how many fell more than ``below`` points short."""
    lines = []
    for label, keep in (("flagged", True), ("not flagged", False)):
        gaps = [v["refined"] - v["true"] for k, v in by_case.items()
                if flagged.get(k) is keep and np.isfinite(v.get("refined", np.nan))
                and "true" in v]
        if gaps:
            lines.append(f"  refined, {label} {what}: {len(gaps)} records, refined - true "
                         f"median {_median(gaps):.2f}, more than {below:g} "
                         f"point{'s' if below != 1 else ''} below on "
                         f"{sum(g < -below for g in gaps)}")
    return lines


def _holdout_lines(rows: list[Row], by_case: dict) -> list[str]:
    """How often the refined model was flagged by its hold-out (``generic.holdout_flagged``:
    the record does not determine a model of its order), and how often it failed on the
    validation half (more than 10 points below the true model's fit), flagged and not (the
    records where the hold-out ran)."""
    from aeid_struct.generic import holdout_flagged

    flagged = {(r.plant, r.case, r.noise, r.steps): holdout_flagged(
        r.holdout, r.holdout_ratio if np.isfinite(r.holdout_ratio) else None)
        for r in rows if r.method == "refined" and np.isfinite(r.holdout)}
    return _flag_lines(by_case, flagged, "by its hold-out", 10.0)


def _unexcited_lines(rows: list[Row], by_case: dict) -> list[str]:
    """How often the refined model was flagged for lightly damped modes its record does not
    determine (``info["unexcited"]``), and its validation fit against the true model's on the
    flagged records and the others."""
    flagged = {(r.plant, r.case, r.noise, r.steps): bool(r.unexcited)
               for r in rows if r.method == "refined"}
    return _flag_lines(by_case, flagged, "for modes the record does not determine", 1.0)


def format_tables(rows: list[Row]) -> str:
    """The fit table (median validation fit per cell and method), the one pass against the
    refined model, the worst gap to n4sid and the timings, as text.

    Parameters
    ----------
    rows : list of Row

    Returns
    -------
    str
    """
    lines = []
    kinds = [p for p in PLANTS if any(r.plant == p for r in rows if r.noise >= 0)]
    cells = sorted({(PLANTS.index(r.plant), r.order, r.noise, r.steps) for r in rows
                    if r.noise >= 0})
    head = "plant        order noise steps | " + " | ".join(f"{m:>16}" for m in METHODS)
    lines += ["Validation fit % (median; measured output, x0 and offset fitted)", head]
    for kind, order, noise, steps in cells:
        sel = [r for r in rows if (PLANTS.index(r.plant), r.order, r.noise, r.steps)
               == (kind, order, noise, steps)]
        vals = [_median(r.fit for r in sel if r.method == m) for m in METHODS]
        lines.append(f"{PLANTS[kind]:12s} {order:5d} {noise:5.0%} {steps:5d} | "
                     + " | ".join(f"{v:16.2f}" for v in vals))
    by_case = {}
    for r in rows:
        by_case.setdefault((r.plant, r.case, r.noise, r.steps), {})[r.method] = r.fit
    lines += _gap_lines(rows, by_case)
    for kind in kinds if len(kinds) > 1 else ():
        lines += [f"  ({kind} plants only)"] + _gap_lines(
            [r for r in rows if r.plant == kind],
            {k: v for k, v in by_case.items() if k[0] == kind})[2:]
    lines += ["", "Per record: refined minus n4sid and least squares (points, worst and count > 1 "
              "below), refined minus true (median)"]
    for name in ("refined", "refined, D given"):
        for other in ("n4sid", "least squares"):
            gaps = [v[name] - v[other] for v in by_case.values()
                    if np.isfinite(v.get(name, np.nan)) and np.isfinite(v.get(other, np.nan))]
            lines.append(f"  {name} - {other}: worst {min(gaps):.2f}, records more than 1 point "
                         f"below: {sum(g < -1 for g in gaps)} of {len(gaps)}")
        gap = [v[name] - v["true"] for v in by_case.values() if np.isfinite(v.get(name, np.nan))]
        lines.append(f"  {name} - true: median {_median(gap):.2f}, within 1 point: "
                     f"{sum(g >= -1 for g in gap)} of {len(gap)}")
    lines += _unexcited_lines(rows, by_case)
    lines += _holdout_lines(rows, by_case)
    failed = {m: sum(not np.isfinite(r.fit) for r in rows if r.method == m) for m in METHODS}
    lines.append("  no model (failed): " + ", ".join(f"{m} {k}" for m, k in failed.items()))
    for name in ("encoder", "one pass, no SM", "one pass"):
        gaps = [v[name] - v["true"] for v in by_case.values() if name in v and "true" in v]
        lines.append(f"  {name} - true: median {_median(gaps):.2f}")
    lines += ["", "Measured-data stand-ins (validation fit %)"]
    for r in rows:
        if r.noise < 0:
            lines.append(f"  {r.case:10s} {r.method:13s} {r.fit:7.2f}   ({r.seconds * 1e3:.1f} ms)")
    lines += ["", "Time per call (median ms) by record length"]
    for steps in sorted({r.steps for r in rows if r.noise >= 0}):
        sel = [r for r in rows if r.steps == steps and r.noise >= 0]
        lines.append(f"  {steps:5d} samples: " + ", ".join(
            f"{m} {_median(r.seconds for r in sel if r.method == m) * 1e3:.2f}"
            for m in METHODS[:-1]))
    return "\n".join(lines)
