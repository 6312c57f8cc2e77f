r"""The one-pass study of ``aeid-struct bench`` (docs/architecture.md, "One pass at the
optimum"): the encoder alone, the one pass (encoder + separable head), the least-squares optimum
and the classical cold fits, on the same records, in one run.

For each leg identifier that reads ``u`` (``leg-stable-any``, ``leg-unstable-any``,
``leg-stable-window``), each input kind (steps, PRBS, multisine, filtered noise) and each noise
level (white, a share of ``max|y_clean|``), ``count`` legs are drawn from the identifier's
training range and simulated exactly in its record format (mid-motion windows after its
``warmup``, or from rest); every method identifies them:

(a) ``encoder``: the encoder alone (``ident.head = None``, the paper's architecture, Sec. III-A);
(b) ``one pass``: encoder + head, a fixed number of Levenberg-Marquardt iterations on the
    variable-projection cost in the physics structure (``identification.head``);
(c) ``encoder + refine``: ``identify(refine=True)``, the head iterated to convergence: the
    least-squares optimum in the physics structure (``c1 = 0``; rotational leg also ``a1 = 0``);
(d) ``least squares (cold)``: ``baselines.least_squares`` from its generic start, in the physics
    structure on records from rest; on windows its ``Record`` form (a CCF with the initial
    state and an output offset, started from n4sid);
(e) ``CasADi (cold)``: ``baselines.casadi_cold`` in the physics structure on records from rest;
    on windows ``refinement.refine_record`` (the CasADi graph with the initial state projected)
    from ``baselines.generic_start``;
(f) ``n4sid``: ``baselines.n4sid`` of order 2 (``Record`` form on windows).

Errors are the median over records of ``|p_hat / p - 1|`` in % for the physical parameters the
record holds (the rotational leg has no ``d``), from every model through the CCF of its transfer
function (``identification.physical.through_ccf``); a failed or non-finite estimate counts as an
infinite error. Times are on one thread: the median of batch-1 calls over the first ``timed``
records (back to back, after an untimed warm-up call), and records per second of one batched
call of ``batch`` records. The cold baselines run on those ``timed`` records only (they are the
slow part of the run); (a)-(c) are scored on all ``count`` records.

An identifier file without a head gets :data:`HEAD_ITERATIONS` iterations in the physics
structure here (:func:`with_head`); one that has a head keeps its own.

The methods (a)-(f) are in ``studies.onepass_methods``, one row of the study (every method on the
same records, scored and timed) in ``studies.onepass_row``, and the tables in
``studies.onepass_tables``; the names of the methods and of the row are importable from here.
"""

from __future__ import annotations

import sys
import time

# The methods and the row have modules of their own; they stay importable from here
from aeid_struct.studies.onepass_methods import BASELINES as BASELINES
from aeid_struct.studies.onepass_methods import HEAD_ITERATIONS as HEAD_ITERATIONS
from aeid_struct.studies.onepass_methods import METHODS as METHODS
from aeid_struct.studies.onepass_methods import PHYSICS as PHYSICS
from aeid_struct.studies.onepass_methods import baseline_calls as baseline_calls
from aeid_struct.studies.onepass_methods import encoder_alone as encoder_alone
from aeid_struct.studies.onepass_methods import leg_family as leg_family
from aeid_struct.studies.onepass_methods import with_head as with_head
from aeid_struct.studies.onepass_row import bench_row as bench_row

__all__ = ["BASELINES", "HEAD_ITERATIONS", "IDENTIFIERS", "KINDS", "METHODS", "PHYSICS",
           "bench_onepass", "bench_row", "encoder_alone", "leg_family", "with_head"]

#: The identifiers of the study and their leg subsystem.
IDENTIFIERS = {"leg-stable-any": "stable", "leg-unstable-any": "unstable",
               "leg-stable-window": "stable"}
#: Input kinds (``training.excitation`` names; ``noise`` is filtered noise).
KINDS = ("steps", "prbs", "multisine", "noise")


def _say(progress: bool, text: str) -> None:
    if progress:
        sys.stderr.write(text + "\n")
        sys.stderr.flush()


def bench_onepass(*, quick: bool = False, names=tuple(IDENTIFIERS), kinds=KINDS,
                  noises=None, count: int | None = None, timed: int | None = None,
                  batch: int | None = None, seed: int = 1500, baselines: bool = True,
                  progress: bool = True) -> dict:
    """The one-pass study on the shipped identifiers (module docstring), on one thread.

    Parameters
    ----------
    quick : bool
        Defaults for a test: 8 records per row, 4 timed, noise 0 and 1 %, batch 64.
    names : tuple of str
        Identifiers (keys of :data:`IDENTIFIERS`).
    kinds : tuple of str
        Input kinds (:data:`KINDS`).
    noises : tuple of float, optional
        Noise levels; default 0, 1 and 5 % (quick: 0 and 1 %).
    count, timed, batch : int, optional
        Records per row (default 60), timed and fitted by the baselines (default 30), records
        of the batched call (default 1000).
    seed : int
        Seed of the first row (each row has its own).
    baselines : bool
        Run the cold baselines.
    progress : bool
        One line per row on stderr.

    Returns
    -------
    dict
        JSON-able: ``identifiers``: name -> ``subsystem``, ``head`` (the head used, and whether
        the file had it), ``rows`` (:func:`bench_row`); ``settings``; ``targets``
        (:func:`targets`); ``seconds`` (wall time of the study).

    Raises
    ------
    ValueError
        An unknown identifier or input kind, or counts that are not positive integers with
        ``timed <= count``.
    """
    import torch
    from threadpoolctl import threadpool_limits

    from aeid_struct.identification import load_pretrained

    count = (8 if quick else 60) if count is None else count
    timed = (4 if quick else 30) if timed is None else timed
    batch = (64 if quick else 1000) if batch is None else batch
    noises = tuple(noises if noises is not None else ((0.0, 0.01) if quick else
                                                      (0.0, 0.01, 0.05)))
    _check(names, kinds, count, timed, batch)
    t_start = time.perf_counter()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    result = {"identifiers": {}, "settings": {"count": count, "timed": timed, "batch": batch,
                                             "noises": list(noises), "kinds": list(kinds),
                                             "seed": seed, "threads": 1}}
    try:
        # one core for every method: torch and the BLAS under numpy/scipy (an idle BLAS pool
        # spinning on the other core slows small calls down)
        with threadpool_limits(limits=1):
            for i, name in enumerate(names):
                subsystem = IDENTIFIERS[name]
                ident = load_pretrained(name)
                head = with_head(ident, subsystem).head
                entry = {"subsystem": subsystem, "head": head.to_dict(),
                         "head_in_file": ident.head is not None, "rows": []}
                for j, kind in enumerate(kinds):
                    for k, noise in enumerate(noises):
                        t0 = time.perf_counter()
                        row = bench_row(ident, subsystem, kind, noise, count=count,
                                        timed=timed, batch=batch,
                                        seed=seed + 100 * i + 10 * j + k, baselines=baselines)
                        entry["rows"].append(row)
                        one = row["methods"]["one pass"]["median"]
                        _say(progress, f"  {name:18s} {kind:9s} noise {noise:4.0%}  one pass "
                             + " / ".join(f"{p} {v:.3g}" for p, v in one.items())
                             + f" %  ({time.perf_counter() - t0:.1f} s)")
                result["identifiers"][name] = entry
    finally:
        torch.set_num_threads(threads)
    result["targets"] = targets(result)
    result["seconds"] = time.perf_counter() - t_start
    return result


def _check(names, kinds, count, timed, batch) -> None:
    unknown = [n for n in names if n not in IDENTIFIERS]
    if unknown or not names:
        raise ValueError(f"names must be some of {tuple(IDENTIFIERS)}; got {tuple(names)!r}")
    if not kinds or any(k not in KINDS for k in kinds):
        raise ValueError(f"kinds must be some of {KINDS}; got {tuple(kinds)!r}")
    for label, value in (("count", count), ("timed", timed), ("batch", batch)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{label} must be a positive integer; got {value!r}")
    if timed > count:
        raise ValueError(f"timed must be <= count ({count}); got {timed}")


#: Issue 15's targets for the one pass (``targets`` reads them off a result).
TARGET_NOISE_FREE_PERCENT = 0.5
TARGET_VS_OPTIMUM = 1.2
TARGET_LS_OVER_ONE_PASS = 50.0


def targets(result: dict) -> dict:
    """Issue 15's targets read off a result, per identifier, over PRBS, multisine and filtered
    noise (steps are the paper's input, not one of the target's).

    Parameters
    ----------
    result : dict
        What :func:`bench_onepass` returned (without ``targets``).

    Returns
    -------
    dict
        Identifier -> ``noise_free_max_percent`` (the one pass's largest median parameter error
        on noise-free rows), ``vs_optimum_max`` (its largest ratio to the optimum on noisy
        rows), ``ls_over_one_pass_min`` (the smallest time ratio), each with ``*_met``.
    """
    out = {}
    for name, entry in result["identifiers"].items():
        rows = [r for r in entry["rows"] if r["kind"] != "steps"]
        free = [v for r in rows if r["noise"] == 0
                for v in r["methods"]["one pass"]["median"].values()]
        ratios = [v for r in rows if r["noise"] > 0
                  for v in r["vs_optimum"]["one pass"].values() if v is not None]
        times = [r["ls_over_one_pass"] for r in entry["rows"] if "ls_over_one_pass" in r]
        t = {"noise_free_max_percent": max(free) if free else None,
             "vs_optimum_max": max(ratios) if ratios else None,
             "ls_over_one_pass_min": min(times) if times else None}
        t["noise_free_met"] = None if not free else bool(
            t["noise_free_max_percent"] <= TARGET_NOISE_FREE_PERCENT)
        t["vs_optimum_met"] = None if not ratios else bool(
            t["vs_optimum_max"] <= TARGET_VS_OPTIMUM)
        t["time_met"] = None if not times else bool(
            t["ls_over_one_pass_min"] >= TARGET_LS_OVER_ONE_PASS)
        out[name] = t
    return out
