"""Figures for comparing identifiers: training curves, pole maps, error distributions and
parameter errors (``training_curves``, ``pole_map``, ``error_cdf``, ``knowledge_bars``). Each
returns a matplotlib Figure and writes a PNG when a path is given; no display is needed (the CLI
uses the Agg backend). Every axis names a quantity and its unit, and every function takes a
``title`` that says what produced the figure.

The paper's figures (``fig3``, ``fig4``, ``Comparison``, ``LEG_SIGNALS``) live in
``evaluation.comparison`` and the shared units and helpers in ``evaluation.style``; both are
importable from here too (the module's old names).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from aeid_struct.evaluation.comparison import LEG_SIGNALS as LEG_SIGNALS
from aeid_struct.evaluation.comparison import Comparison as Comparison
from aeid_struct.evaluation.comparison import fig3 as fig3
from aeid_struct.evaluation.comparison import fig4 as fig4
from aeid_struct.evaluation.style import METRIC_UNITS as METRIC_UNITS
from aeid_struct.evaluation.style import PARAMETER_UNITS as PARAMETER_UNITS
from aeid_struct.evaluation.style import check_title as check_title
from aeid_struct.evaluation.style import finish_figure as finish_figure
from aeid_struct.evaluation.style import pyplot
from aeid_struct.evaluation.style import unit_label as unit_label


def _runs(value) -> list:
    """A history dict, or a list of them (e.g. one per seed), as a list."""
    return [value] if isinstance(value, dict) else list(value)


def training_curves(histories: dict, path=None, *, title=None):
    """Held-out loss and largest gradient norm (before clipping) per epoch, log scale.

    Parameters
    ----------
    histories : dict
        Label -> ``train()``'s history (``ident.meta["history"]``) or a list of them (one line
        per run, e.g. per seed, in the label's colour). Epochs with batches skipped for a
        non-finite loss or gradient are marked with an ``x``.
    path : str or Path, optional
        Where to write the PNG (None: only return the Figure).
    title : str, optional
        What produced the figure (family, structures, budget).

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        No history, or one without ``holdout_loss`` and ``grad_norm_max``.
    """
    if not histories:
        raise ValueError("histories must map at least one label to a training history")
    check_title(title)
    plt = pyplot()
    fig, (ax_loss, ax_grad) = plt.subplots(1, 2, figsize=(12, 4.4), layout="constrained")
    for i, (label, runs) in enumerate(histories.items()):
        for j, h in enumerate(_runs(runs)):
            if "holdout_loss" not in h or "grad_norm_max" not in h:
                raise ValueError(f"histories[{label!r}] must be train() histories with "
                                 "holdout_loss and grad_norm_max")
            epochs = np.arange(1, len(h["holdout_loss"]) + 1)
            style = dict(color=f"C{i}", lw=1.2, alpha=0.85, label=label if j == 0 else None)
            ax_loss.semilogy(epochs, h["holdout_loss"], **style)
            ax_grad.semilogy(epochs, h["grad_norm_max"], **style)
            skipped = np.asarray(h.get("skipped", [0] * len(epochs))) > 0
            if skipped.any():
                ax_grad.semilogy(epochs[skipped], np.asarray(h["grad_norm_max"])[skipped],
                                 "x", color=f"C{i}", ms=7)
    # The loss of Eq. 14 compares responses scaled by Eq. 15, so it has no unit; so has the
    # gradient norm of the raw parameters theta.
    ax_loss.set(xlabel="epoch [count]", ylabel="held-out loss, Eq. 14 [dimensionless]",
                title="Held-out loss")
    ax_grad.set(xlabel="epoch [count]",
                ylabel="max gradient norm, before clipping [dimensionless]",
                title="Largest gradient norm per epoch")
    for ax in (ax_loss, ax_grad):
        ax.grid(True, which="both", alpha=0.3)
    ax_loss.legend(fontsize=8)
    finish_figure(fig, title, path)
    return fig


def pole_map(scores, path=None, reference=None, max_records: int = 1000, *, title=None):
    """The estimated poles of each score in the complex plane, one panel per score; the poles
    of estimates that are not stable (``per_record["stable"]`` False) are drawn as red crosses.

    Parameters
    ----------
    scores : list of Score
        One panel each.
    path : str or Path, optional
        Where to write the PNG (None: only return the Figure).
    reference : (N, n) complex array_like, optional
        Poles drawn in grey (e.g. of the true systems).
    max_records : int
        At most this many records per panel (the first ones), to keep it legible.
    title : str, optional
        What produced the figure (family, identifiers, noise).

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        No score.
    """
    scores = list(scores)
    if not scores:
        raise ValueError("scores must hold at least one Score")
    check_title(title)
    plt = pyplot()
    fig, axes = plt.subplots(1, len(scores), figsize=(4.2 * len(scores), 4.2), squeeze=False,
                             sharex=True, sharey=True, layout="constrained")
    for ax, s in zip(axes[0], scores, strict=True):
        poles = s.poles[:max_records]
        stable = np.asarray(s.per_record["stable"], dtype=bool)[:max_records]
        if reference is not None:
            ref = np.asarray(reference)[:max_records].ravel()
            ax.plot(ref.real, ref.imag, ".", color="0.7", ms=3, label="true")
        good, bad = poles[stable].ravel(), poles[~stable].ravel()
        ax.plot(good.real, good.imag, ".", color="C0", ms=3, alpha=0.6, label="stable estimate")
        if bad.size:
            ax.plot(bad.real, bad.imag, "x", color="C3", ms=6,
                    label=f"unstable estimate ({int((~stable).sum())})")
        ax.axvline(0.0, color="k", lw=0.8, ls="--")
        ax.set(title=f"{s.name}: {stable.mean():.1%} stable", xlabel="Re(pole) [1/s]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")
    axes[0, 0].set_ylabel("Im(pole) [rad/s]")
    finish_figure(fig, title, path)
    return fig


def error_cdf(scores, metric: str = "step", path=None, ax=None, *, title=None):
    """Empirical distribution of a per-record error of each score (share of records with an
    error below x), log x. Infinite errors (overflowing estimates) never reach the curve's top;
    their count is given in the legend.

    Parameters
    ----------
    scores : list of Score
        One curve each.
    metric : str
        A key of ``Score.per_record`` (e.g. ``"step"``, ``"magnitude_db"``, ``"k"``; its unit
        from ``METRIC_UNITS``).
    path : str or Path, optional
        Where to write the PNG (None: only return the Figure).
    ax : matplotlib.axes.Axes, optional
        Draw into these axes instead of a new figure (then the figure is neither laid out nor
        titled: the caller owns it).
    title : str, optional
        What produced the figure.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        No score, or a metric some score lacks.
    """
    scores = list(scores)
    if not scores:
        raise ValueError("scores must hold at least one Score")
    missing = [s.name for s in scores if metric not in s.per_record]
    if missing:
        raise ValueError(f"metric must be a per-record measure of every score; {metric!r} is "
                         f"missing from {missing}")
    check_title(title)
    plt = pyplot()
    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(6.5, 4.4), layout="constrained")
    else:
        fig = ax.figure
    for i, s in enumerate(scores):
        v = np.asarray(s.per_record[metric], dtype=np.float64)
        finite = np.sort(v[np.isfinite(v)])
        share = np.arange(1, finite.size + 1) / v.size
        overflow = v.size - finite.size
        label = s.name + (f" ({overflow} inf)" if overflow else "")
        ax.step(finite, share, where="post", color=f"C{i}", label=label)
    ax.set_xscale("log")
    ax.set(xlabel=f"{metric} error {unit_label(METRIC_UNITS.get(metric, ''))}",
           ylabel="share of records [fraction]", ylim=(0, 1.02),
           title=f"Distribution of the {metric} error")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if own:
        finish_figure(fig, title, path)
    else:
        if title:
            ax.set_title(title, fontsize=9)
        if path is not None:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            fig.savefig(path, dpi=120)
    return fig


def knowledge_bars(groups: dict, parameters=("k", "d", "m"), path=None, *, title=None):
    """Mean physical-parameter errors of several identifiers as grouped bars, one panel per
    group (e.g. noise level), log scale; the share of invalid estimates (parameters that are
    not finite and positive, left out of the mean) is written above each identifier's bars.

    Parameters
    ----------
    groups : dict of str to list of Score
        Panel title -> the scores drawn in it (one bar cluster each).
    parameters : tuple of str
        The parameters to draw (a score without one leaves its bar out).
    path : str or Path, optional
        Where to write the PNG (None: only return the Figure).
    title : str, optional
        What produced the figure (family, validation set, budget).

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        No group, or an empty one.
    """
    if not groups or not all(list(g) for g in groups.values()):
        raise ValueError("groups must map at least one title to a non-empty list of Scores")
    check_title(title)
    plt = pyplot()
    fig, axes = plt.subplots(1, len(groups), figsize=(6.5 * len(groups), 4.8), squeeze=False,
                             sharey=True, layout="constrained")
    width = 0.8 / len(parameters)
    for ax, (panel, scores) in zip(axes[0], groups.items(), strict=True):
        scores = list(scores)
        x = np.arange(len(scores))
        top = 0.0
        for j, p in enumerate(parameters):
            values = [s.summary().get(f"{p}_mean", np.nan) for s in scores]
            ax.bar(x + (j - (len(parameters) - 1) / 2) * width, values, width, label=f"Δ{p}",
                   color=f"C{j}")
            top = max([top] + [v for v in values if np.isfinite(v)])
        for i, s in enumerate(scores):
            invalid = 1.0 - s.summary().get("valid_share", 1.0)
            if invalid > 0:
                ax.annotate(f"{invalid:.0%} invalid", (x[i], top), ha="center",
                            va="bottom", fontsize=7, color="C3", rotation=90)
        ax.set_yscale("log")
        ax.set_xticks(x, [s.name for s in scores], rotation=60, ha="right", fontsize=8)
        ax.set(title=panel, ylabel="mean absolute parameter error [% of the true value]")
        ax.grid(True, axis="y", which="both", alpha=0.3)
        ax.legend(fontsize=8)
    finish_figure(fig, title, path)
    return fig
