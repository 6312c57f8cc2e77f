"""What ``train()``'s history says about a run, and a table of several runs' stability."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

#: Held-out loss above this multiple of its best counts as diverged.
DIVERGED_FACTOR = 10.0


def training_summary(ident) -> dict:
    """What ``train()``'s history says about the run.

    Parameters
    ----------
    ident : Identifier or dict
        A trained identifier (its ``meta["history"]``), or a history dict itself.

    Returns
    -------
    dict
        ``epochs``; ``seconds`` (wall time); ``final_holdout`` (held-out loss of the
        last epoch) and ``best_holdout`` (lowest finite one, whose weights ``train`` returned);
        ``grad_norm_max`` (largest gradient norm before clipping, over all epochs) and
        ``grad_norm_median`` (median of the per-epoch medians); ``skipped`` (batches skipped for a
        non-finite loss or gradient, in total); ``diverged``: the final held-out loss is not finite
        or exceeds ``DIVERGED_FACTOR`` times the best.

    Raises
    ------
    ValueError
        Neither a trained identifier nor a history, or a history without epochs.
    """
    history = ident if isinstance(ident, Mapping) else getattr(ident, "meta", {}).get("history")
    needed = ("holdout_loss", "grad_norm_max", "grad_norm_median", "skipped", "seconds")
    if not isinstance(history, Mapping) or any(k not in history for k in needed):
        raise ValueError("ident must be a trained Identifier (meta['history'] from train()) or "
                         f"a history dict with {', '.join(needed)}")
    held = np.asarray(history["holdout_loss"], dtype=np.float64)
    if held.size == 0:
        raise ValueError("ident's history must cover at least one epoch; got none")
    finite = held[np.isfinite(held)]
    best = float(finite.min()) if finite.size else math.inf
    final = float(held[-1])
    gmax = np.asarray(history["grad_norm_max"], dtype=np.float64)
    gmed = np.asarray(history["grad_norm_median"], dtype=np.float64)
    with np.errstate(all="ignore"):
        grad_max = float(np.nanmax(gmax)) if np.any(~np.isnan(gmax)) else math.nan
        grad_med = float(np.nanmedian(gmed)) if np.any(~np.isnan(gmed)) else math.nan
    return {
        "epochs": int(held.size),
        "seconds": float(history["seconds"][-1]),
        "final_holdout": final,
        "best_holdout": best,
        "grad_norm_max": grad_max,
        "grad_norm_median": grad_med,
        "skipped": int(np.sum(history["skipped"])),
        "diverged": bool(not math.isfinite(final) or final > DIVERGED_FACTOR * best),
    }


def training_table(runs: Mapping[str, Sequence[dict]]) -> str:
    """A markdown table of training stability, one row per label.

    Parameters
    ----------
    runs : mapping of str to sequence of dict
        Label -> the :func:`training_summary` dicts of its runs (e.g. seeds).

    Returns
    -------
    str
        Columns: runs, diverged runs, skipped batches (total), the largest gradient norm (max
        over runs), the median per-epoch median gradient norm (median over runs), best held-out
        loss (median and worst over runs) and seconds per run (mean).

    Raises
    ------
    ValueError
        No label, or a label without runs.
    """
    if not isinstance(runs, Mapping) or not runs:
        raise ValueError("runs must be a non-empty mapping label -> list of training_summary")
    lines = ["| run | runs | diverged | skipped batches | max grad norm | median grad norm | "
             "best held-out loss (median) | (worst) | s / run |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for label, summaries in runs.items():
        summaries = list(summaries)
        if not summaries:
            raise ValueError(f"runs[{label!r}] must hold at least one training summary")
        col = {k: np.array([s[k] for s in summaries], dtype=np.float64)
               for k in ("grad_norm_max", "grad_norm_median", "best_holdout", "seconds")}
        with np.errstate(all="ignore"):
            cells = [
                str(len(summaries)),
                str(sum(bool(s["diverged"]) for s in summaries)),
                str(sum(int(s["skipped"]) for s in summaries)),
                f"{np.nanmax(col['grad_norm_max']):.3g}",
                f"{np.nanmedian(col['grad_norm_median']):.3g}",
                f"{np.median(col['best_holdout']):.2e}",
                f"{np.max(col['best_holdout']):.2e}",
                f"{np.mean(col['seconds']):.1f}",
            ]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
