"""Figures of the studies that draw study results (the generic figures are in
``aeid_struct.evaluation``): the tracked wear scenario of ``studies.wear``."""

from __future__ import annotations

import numpy as np

from aeid_struct.evaluation import PARAMETER_UNITS, check_title, finish_figure, unit_label
from aeid_struct.online import TrackerConfig


def wear_figure(result, path=None, *, config=None, title=None, units=None):
    """True against tracked physical parameters of a wear scenario, one panel per parameter
    (units from ``evaluation.PARAMETER_UNITS``), with the alarm threshold (or a parameter's
    own limit, ``Tracker.limits``) and the alarm time.

    The threshold band is the tracker's own rule (``online.Tracker``): the reference is the
    median of the first ``config.baseline`` window estimates, and the alarm is raised when a
    watched parameter's smoothed estimate stays beyond ``reference * (1 +- config.threshold)``
    for ``config.patience`` windows; the band is drawn on the watched parameters.

    Parameters
    ----------
    result : WearResult
        A tracked scenario (``studies.wear.wear_study``).
    path : str or Path, optional
        Where to write the PNG (None: only return the Figure).
    config : online.TrackerConfig, optional
        The configuration the result was tracked with (None: the default one, as
        ``wear_study`` uses by default).
    title : str, optional
        What produced the figure (identifier, noise, seed, engine).
    units : dict name -> str, optional
        The parameters' units (default: the leg's, ``evaluation.PARAMETER_UNITS``); a
        parameter without one is labelled by its name alone.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        A result without parameters, a ``config`` that is not a ``TrackerConfig``, or a title
        that is not a string.
    """
    names = list(result.true)
    if not names:
        raise ValueError("result must hold at least one tracked parameter with a true value")
    if config is None:
        config = TrackerConfig()
    if not isinstance(config, TrackerConfig):
        raise ValueError(f"config must be an online.TrackerConfig; got {type(config).__name__}")
    check_title(title)
    import matplotlib.pyplot as plt  # no backend forced: inline in notebooks, Agg in the CLI

    fig, axes = plt.subplots(len(names), 1, figsize=(8, 2.4 * len(names) + 1.0), sharex=True,
                             squeeze=False, layout="constrained")
    watched = [p for p in names if not config.watch or p in config.watch]
    for ax, p in zip(axes[:, 0], names, strict=True):
        _panel(ax, result, p, config, p in watched,
               PARAMETER_UNITS if units is None else units)
    # One legend for all panels, under them: inside a panel it hides the data.
    handles = {}
    for ax in axes[:, 0]:
        for h, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, h)
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncol=3,
               fontsize=8)
    truth = any(np.isfinite(np.asarray(v, dtype=np.float64)).any() for v in result.true.values())
    axes[0, 0].set_title("True and tracked physical parameters" if truth
                         else "Tracked physical parameters")
    axes[-1, 0].set_xlabel("time t [s]")
    finish_figure(fig, title, path)
    return fig


def _panel(ax, result, p: str, config: TrackerConfig, watched: bool, units: dict) -> None:
    """One parameter's panel: truth, window estimates, smoothed estimates, the threshold band
    (``watched``), the alarm and the true drift."""
    estimates = np.asarray(result.estimate[p], dtype=np.float64)
    drawn = [np.asarray(result.true[p], dtype=np.float64), estimates,
             np.asarray(result.smoothed[p], dtype=np.float64)]
    if np.isfinite(drawn[0]).any():          # a measured stream has no truth
        ax.plot(result.t, drawn[0], "k-", lw=1.5, label="true")
    ax.plot(result.t, estimates, ".", color="C0", ms=3, alpha=0.5, label="window estimate")
    ax.plot(result.t, drawn[2], "-", color="C3", lw=1.2, label="smoothed")
    if watched and estimates.size >= config.baseline:
        reference = float(np.median(estimates[: config.baseline]))
        # the parameter's own limit where the tracker set one (TrackerConfig.sigmas)
        limit = (result.limit or {}).get(p, config.threshold)
        band = reference * (1 + limit * np.array([1.0, -1.0]))
        drawn.append(band)
        label = (f"alarm threshold: reference ±{config.threshold:.0%}"
                 if limit <= config.threshold else
                 f"alarm limit: {config.sigmas:g} standard errors of a window")
        for i, level in enumerate(band):
            ax.axhline(level, color="C1", ls="-.", lw=1, label=label if i == 0 else None)
        if limit > config.threshold:
            ax.text(0.995, 0.03, f"limit ±{limit:.0%}", transform=ax.transAxes, ha="right",
                    va="bottom", fontsize=7, color="C1")
    if np.isfinite(result.alarm_time):
        ax.axvline(result.alarm_time, color="C1", ls="--", lw=1, label="alarm raised")
    if np.isfinite(result.drift_time):
        ax.axvline(result.drift_time, color="0.5", ls=":", lw=1,
                   label=f"true k {config.threshold:.0%} from its start")
    # Every drawn value (the threshold band included) inside, with a margin of 8 %.
    values = np.concatenate([np.ravel(v) for v in drawn])
    values = values[np.isfinite(values)]
    if values.size:
        pad = 0.08 * max(float(np.ptp(values)), 1e-3 * float(np.abs(values).max()), 1e-12)
        ax.set_ylim(values.min() - pad, values.max() + pad)
    ax.set_ylabel(f"{p} {unit_label(units[p])}" if p in units else p)
    ax.grid(True, alpha=0.3)
