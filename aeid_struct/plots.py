"""Figures: step responses and Bode plots, true vs identified (paper Fig. 3); step error vs
training-set size (paper Fig. 4). Each returns a matplotlib Figure and writes a PNG when a path
is given; no display is needed (the CLI uses the Agg backend).
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
