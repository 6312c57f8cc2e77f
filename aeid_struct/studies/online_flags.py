"""The out-of-range flags of the online benchmark (``studies.bench_online``): how often
``Estimate.outside`` flags legs inside the identifier's training range (false flags) and legs with
one parameter beyond it, and what ``identify(refine="auto")`` makes of the flagged ones.

The seam: the other parts of the benchmark run legs drawn from a family; this one builds legs
outside every family on purpose (one parameter at ``hi (1 + f)`` or ``lo (1 - f)``) and simulates
them as given systems. Errors are measured against the noise-free truth; noise is white,
``noise * max|y_clean|``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeid_struct.training import LegFamily, Systems, records


def _percent(est: dict, truth: dict, names=("k", "d", "m")) -> dict[str, np.ndarray]:
    return {p: 100.0 * np.abs(np.asarray(est[p]) / truth[p] - 1.0) for p in names
            if p in est and p in truth}


def _outside_family(ranges: dict, name: str, f: float, count: int,
                    rng: np.random.Generator, side: str | None = None) -> dict[str, np.ndarray]:
    """Legs inside ``ranges`` but for ``name``, which lies ``f`` beyond one of its bounds (either,
    at random, or the ``side`` given: ``"above"`` or ``"below"``)."""
    params = {p: rng.uniform(lo, hi, count) for p, (lo, hi) in ranges.items()}
    lo, hi = ranges[name]
    above = rng.random(count) < 0.5 if side is None else np.full(count, side == "above")
    params[name] = np.where(above, hi * (1 + f), lo * (1 - f))
    return params


@dataclass(frozen=True)
class _Given:
    """A family of given systems, so that ``training.records`` simulates them like any family."""

    systems: Systems
    records: int = 1

    def sample(self, count: int, rng: np.random.Generator) -> Systems:
        return self.systems


def bench_flags(ident, ranges: dict, *, noises=(0.0, 0.01), beyond=(0.1, 0.2, 0.3),
                count: int = 300, seed: int = 2000, refine: bool = True,
                subsystem: str = "stable", sides: dict | None = None) -> list[dict]:
    """How often ``Estimate.outside`` flags legs inside and beyond the training range.

    Parameters
    ----------
    ident : Identifier
        A leg identifier with a calibrated training range.
    ranges : dict of str to (float, float)
        The parameter ranges of its training family.
    noises : tuple of float
        Noise levels, a share of ``max|y|``.
    beyond : tuple of float
        Departures beyond a bound, a share of it (``hi (1 + f)`` or ``lo (1 - f)``).
    count : int
        Legs per row.
    seed : int
        Seed of the legs and records.
    refine : bool
        Also compare the errors before and after ``refine="auto"``.
    subsystem : str
        ``"stable"`` or ``"unstable"``.
    sides : dict of str to str or None, optional
        The parameters pushed out and on which side (name -> ``"above"``, ``"below"`` or None
        for either); default every parameter, either side. For the unstable subsystem only k
        above and m below keep a leg (``L = l0 - m g / k > 0``), and d is not in its record.

    Returns
    -------
    list of dict
        One row per noise level and departure (0 = inside the range): the share flagged and,
        with ``refine``, the mean k, d, m errors (%) before and after ``refine="auto"``.
    """
    cfg = ident.meta.get("train", {}).get("config", {})
    kind, warmup = cfg.get("excitation", "step"), int(cfg.get("warmup", 0))
    fam = LegFamily(subsystem=subsystem, ranges=ranges)
    sides = sides or {p: None for p in ranges}
    rows = []
    for i, noise in enumerate(noises):
        for j, f in enumerate((0.0, *beyond)):
            rng = np.random.default_rng(seed + 100 * i + j)
            if f == 0.0:
                params = {p: rng.uniform(lo, hi, count) for p, (lo, hi) in ranges.items()}
            else:
                names = rng.choice(sorted(sides), size=count)
                params = {p: np.empty(count) for p in ranges}
                for name in sorted(sides):
                    rows_ = names == name
                    part = _outside_family(ranges, name, f, int(rows_.sum()), rng, sides[name])
                    for p in ranges:
                        params[p][rows_] = part[p]
            # the identifier's own kind of record: its excitation, mid-motion after warmup
            rec = records(_Given(fam.systems(params["k"], params["d"], params["m"])), count,
                          steps=ident.steps, dt=ident.dt, excitation_kind=kind, noise=noise,
                          seed=seed + 100 * i + j, warmup=warmup)
            y, u = rec.y, rec.u
            est = ident.identify(y, u)
            row = {"noise": noise, "beyond": f, "count": count,
                   "flagged": float(np.mean(est.outside))}
            if refine:
                auto = ident.identify(y, u, refine="auto")
                before, after = _percent(est.physical, params), _percent(auto.physical, params)
                row["before"] = {p: float(np.mean(v)) for p, v in before.items()}
                row["after"] = {p: float(np.mean(v)) for p, v in after.items()}
            rows.append(row)
    return rows
