"""Figures: step responses and Bode plots, true vs identified (paper Fig. 3); step error vs
training-set size (paper Fig. 4); training curves, pole maps, error distributions and parameter
errors for comparing structures (``training_curves``, ``pole_map``, ``error_cdf``,
``knowledge_bars``). Each returns a matplotlib Figure and writes a PNG when a path is given; no
display is needed (the CLI uses the Agg backend).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .metrics import FREQUENCIES, frequency_response


@dataclass(frozen=True)
class Comparison:
    """One subsystem of Fig. 3: a true and an identified model of the same record.

    Attributes:
        name: panel title. true, est: ``(A, b, c, d)`` of one system each.
        dt, steps: the record grid of the step response.
        extra: further identified models to draw (label -> (A, b, c, d)), e.g. "refined".
    """

    name: str
    true: tuple
    est: tuple
    dt: float
    steps: int
    extra: dict | None = None


def _pyplot():
    # No backend is forced here, so figures show inline in notebooks; without a display
    # matplotlib falls back to Agg by itself, and the CLI selects Agg explicitly.
    import matplotlib.pyplot as plt

    return plt


def fig3(comparisons: list[Comparison], path=None, omega=FREQUENCIES):
    """Paper Fig. 3: per subsystem a row with the unit-step response, Bode magnitude and phase."""
    from .decoder import simulate

    plt = _pyplot()
    fig, axes = plt.subplots(len(comparisons), 3, figsize=(13, 3.6 * len(comparisons)),
                             squeeze=False)
    for row, cmp in zip(axes, comparisons, strict=True):
        t = np.arange(cmp.steps) * cmp.dt
        u = np.ones(cmp.steps)
        models = {"true": cmp.true, "identified": cmp.est, **(cmp.extra or {})}
        styles = {"true": dict(color="k", lw=2.2, alpha=0.6),
                  "identified": dict(color="C1", lw=1.4, ls="--")}
        reference = None
        for i, (label, model) in enumerate(models.items()):
            style = styles.get(label, dict(lw=1.0, ls=":", color=f"C{i + 1}"))
            y = simulate(*model, u, cmp.dt)
            G = frequency_response(*model, omega=omega)
            # Unwrap along frequency and put every model on the true model's 2 pi branch, so a
            # phase of -pi and one of +pi (the same angle) are drawn as the same curve.
            phase = np.unwrap(np.angle(G))
            if reference is None:
                reference = phase[0]
            phase = phase - 2 * np.pi * np.round((phase[0] - reference) / (2 * np.pi))
            row[0].plot(t, y, label=label, **style)
            row[1].semilogx(omega, 20 * np.log10(np.abs(G)), label=label, **style)
            row[2].semilogx(omega, phase, label=label, **style)
        row[0].set(title=f"{cmp.name}: unit step", xlabel="t [s]", ylabel="y")
        row[1].set(title="Bode magnitude", xlabel="omega [rad/s]", ylabel="|G| [dB]")
        row[2].set(title="Bode phase", xlabel="omega [rad/s]", ylabel="arg G [rad]")
        for ax in row:
            ax.grid(True, which="both", alpha=0.3)
        row[0].legend()
    fig.tight_layout()
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)
    return fig


def fig4(sizes, errors: dict[str, np.ndarray], path=None, paper: dict | None = None):
    """Paper Fig. 4: mean step error over the training-set size, one line per subsystem.

    Args:
        sizes: ``(s,)`` training-set sizes. errors: label -> ``(s,)`` mean step errors.
        paper: optional label -> value reference lines (the paper's overall errors).
    """
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for i, (label, err) in enumerate(errors.items()):
        ax.loglog(sizes, err, "o-", label=label, color=f"C{i}")
    for i, (label, value) in enumerate((paper or {}).items()):
        ax.axhline(value, ls="--", lw=1, color=f"C{i}", label=f"paper, {label}")
    ax.set(xlabel="training systems", ylabel="mean step error", title="Step error vs data size")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)
    return fig


def _save(fig, path) -> None:
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)


def _runs(value) -> list:
    """A history dict, or a list of them (e.g. one per seed), as a list."""
    return [value] if isinstance(value, dict) else list(value)


def training_curves(histories: dict, path=None):
    """Held-out loss and largest gradient norm (before clipping) per epoch, log scale.

    Args:
        histories: label -> ``train()``'s history (``ident.meta["history"]``) or a list of them
            (one line per run, e.g. per seed, in the label's colour). Epochs with batches
            skipped for a non-finite loss or gradient are marked with an ``x``.
    """
    if not histories:
        raise ValueError("histories must map at least one label to a training history")
    plt = _pyplot()
    fig, (ax_loss, ax_grad) = plt.subplots(1, 2, figsize=(12, 4.2))
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
    ax_loss.set(xlabel="epoch", ylabel="held-out loss (Eq. 14)", title="Held-out loss")
    ax_grad.set(xlabel="epoch", ylabel="max gradient norm (before clipping)",
                title="Largest gradient norm per epoch")
    for ax in (ax_loss, ax_grad):
        ax.grid(True, which="both", alpha=0.3)
    ax_loss.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    return fig


def pole_map(scores, path=None, reference=None, max_records: int = 1000):
    """The estimated poles of each score in the complex plane, one panel per score; the poles
    of estimates that are not stable (``per_record["stable"]`` False) are drawn as red crosses.

    Args:
        scores: ``scorecard.Score`` objects.
        reference: optional ``(N, n)`` complex poles (e.g. of the true systems), drawn in grey.
        max_records: at most this many records per panel (the first ones), to keep it legible.
    """
    scores = list(scores)
    if not scores:
        raise ValueError("scores must hold at least one Score")
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(scores), figsize=(4.2 * len(scores), 4.0), squeeze=False,
                             sharex=True, sharey=True)
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
    fig.tight_layout()
    _save(fig, path)
    return fig


def error_cdf(scores, metric: str = "step", path=None, ax=None):
    """Empirical distribution of a per-record error of each score (share of records with an
    error below x), log x. Infinite errors (overflowing estimates) never reach the curve's top;
    their count is given in the legend.

    Args:
        scores: ``scorecard.Score`` objects. metric: a key of ``per_record`` (e.g. ``"step"``,
            ``"magnitude_db"``, ``"k"``). ax: draw into this axes instead of a new figure.
    """
    scores = list(scores)
    if not scores:
        raise ValueError("scores must hold at least one Score")
    missing = [s.name for s in scores if metric not in s.per_record]
    if missing:
        raise ValueError(f"metric must be a per-record measure of every score; {metric!r} is "
                         f"missing from {missing}")
    plt = _pyplot()
    if ax is None:
        fig, ax = plt.subplots(figsize=(6.5, 4.2))
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
    ax.set(xlabel=f"{metric} error", ylabel="share of records", ylim=(0, 1.02),
           title=f"Distribution of the {metric} error")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    return fig


def knowledge_bars(groups: dict, parameters=("k", "d", "m"), path=None):
    """Mean physical-parameter errors of several identifiers as grouped bars, one panel per
    group (e.g. noise level), log scale; the share of invalid estimates (parameters that are
    not finite and positive, left out of the mean) is written above each identifier's bars.

    Args:
        groups: panel title -> ``scorecard.Score`` objects (one bar cluster each).
        parameters: the parameters to draw (a score without one leaves its bar out).
    """
    if not groups or not all(list(g) for g in groups.values()):
        raise ValueError("groups must map at least one title to a non-empty list of Scores")
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(groups), figsize=(6.5 * len(groups), 4.6), squeeze=False,
                             sharey=True)
    width = 0.8 / len(parameters)
    for ax, (title, scores) in zip(axes[0], groups.items(), strict=True):
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
        ax.set(title=title, ylabel="mean absolute error (%)")
        ax.grid(True, axis="y", which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)
    return fig


def wear(result, path=None):
    """True against tracked physical parameters of a wear scenario (``online.wear_study``), one
    panel per parameter, with the alarm time marked."""
    names = list(result.true)
    if not names:
        raise ValueError("result must hold at least one tracked parameter with a true value")
    plt = _pyplot()
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 2.4 * len(names)), sharex=True,
                             squeeze=False)
    for ax, p in zip(axes[:, 0], names, strict=True):
        ax.plot(result.t, result.true[p], "k-", lw=1.5, label="true")
        ax.plot(result.t, result.estimate[p], ".", color="C0", ms=3, alpha=0.5,
                label="window estimate")
        ax.plot(result.t, result.smoothed[p], "-", color="C3", lw=1.2, label="smoothed")
        if np.isfinite(result.alarm_time):
            ax.axvline(result.alarm_time, color="C1", ls="--", lw=1, label="alarm")
        if np.isfinite(result.drift_time):
            ax.axvline(result.drift_time, color="0.5", ls=":", lw=1, label="true drift > threshold")
        ax.set_ylabel(p)
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.tight_layout()
    _save(fig, path)
    return fig
