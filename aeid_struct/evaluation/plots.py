"""Figures: step responses and Bode plots, true vs identified (paper Fig. 3); step error vs
training-set size (paper Fig. 4); training curves, pole maps, error distributions and parameter
errors for comparing structures (``training_curves``, ``pole_map``, ``error_cdf``,
``knowledge_bars``); a tracked wear scenario (``wear``). Each returns a matplotlib Figure and
writes a PNG when a path is given; no display is needed (the CLI uses the Agg backend).

Every axis names a quantity and its unit, and every function takes a ``title`` that says what
produced the figure (scenario, trained in this run or shipped). Limits are fixed where automatic
ones mislead: the Bode phase is drawn in degrees between multiples of 45 deg that contain every
curve with a margin (a nearly constant phase, as the rotational leg's -180 deg, would otherwise
fill a window of a few hundredths of a degree with rounding noise), the magnitude in dB between
multiples of 10 dB spanning at least 20 dB.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aeid_struct.metrics import FREQUENCIES, frequency_response

#: Input and output of the robot-leg subsystems (``symbolic/leg.py``), as ``Comparison``
#: keywords: the translational leg is driven by the force F along the leg and its output is the
#: leg length's deviation from the equilibrium L; the rotational one by the hip torque tau, and
#: its output is the angle's deviation from upright (theta = pi/2).
LEG_SIGNALS = {
    "stable": {"u_name": "force F", "u_unit": "N", "y_name": "leg length l - L",
               "y_unit": "m"},
    "unstable": {"u_name": "hip torque tau", "u_unit": "N m",
                 "y_name": "angle theta - pi/2", "y_unit": "rad"},
}

#: Units of the leg's physical parameters (``wear``, ``knowledge`` tables).
PARAMETER_UNITS = {"k": "N/m", "d": "N s/m", "m": "kg"}

#: Unit of each per-record error of a ``scorecard.Score`` (``error_cdf``): the Table I step
#: error is a share of the true step response's range (dimensionless).
METRIC_UNITS = {"step": "share of the true step range", "magnitude_db": "dB",
                "phase_rad": "rad", "fit": "%", "k": "%", "d": "%", "m": "%"}


@dataclass(frozen=True)
class Comparison:
    """One subsystem of Fig. 3: a true and an identified model of the same record.

    Attributes:
        name: panel title. true, est: ``(A, b, c, d)`` of one system each.
        dt, steps: the record grid of the step response (dt in s).
        extra: further identified models to draw (label -> (A, b, c, d)), e.g. "refined".
        u_name, u_unit, y_name, y_unit: the input and output quantities and their units
            (e.g. ``**LEG_SIGNALS["stable"]``); they label the axes (the step is one unit of
            ``u_unit``, the Bode magnitude is in dB relative to 1 ``y_unit``/``u_unit``). Empty
            units say so on the axis rather than leaving it bare.
    """

    name: str
    true: tuple
    est: tuple
    dt: float
    steps: int
    extra: dict | None = None
    u_name: str = "u"
    u_unit: str = ""
    y_name: str = "y"
    y_unit: str = ""

    def __post_init__(self) -> None:
        for field_name in ("name", "u_name", "u_unit", "y_name", "y_unit"):
            value = getattr(self, field_name)
            if not isinstance(value, str):
                raise ValueError(f"{field_name} must be a string; got {value!r}")


def _pyplot():
    # No backend is forced here, so figures show inline in notebooks; without a display
    # matplotlib falls back to Agg by itself, and the CLI selects Agg explicitly.
    import matplotlib.pyplot as plt

    return plt


def _check_title(title) -> None:
    if title is not None and not isinstance(title, str):
        raise ValueError(f"title must be a string or None; got {title!r}")


def _finish(fig, title, path) -> None:
    """Put the figure's title (what produced it) above the panels' own titles (the figures use
    matplotlib's constrained layout, which makes room for it) and write the PNG when a path is
    given."""
    if title:
        fig.suptitle(title, fontsize=10)
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=120)


def _unit(unit: str) -> str:
    """``"[m]"``, or a note that the caller gave no unit."""
    return f"[{unit}]" if unit else "[unit not given]"


def _limits(values, *, step: float, margin: float, span: float) -> tuple[float, float]:
    """Axis limits on multiples of ``step`` that contain every finite value with ``margin`` to
    spare on both sides, at least ``span`` apart.

    Args:
        values: any array of data drawn on the axis (non-finite entries are ignored).
        step, margin, span: in the axis' unit, all > 0.

    Returns:
        ``(low, high)``; the margin around 0, rounded out, when no value is finite.
    """
    for name, v in (("step", step), ("margin", margin), ("span", span)):
        if not (isinstance(v, (int, float)) and v > 0):
            raise ValueError(f"{name} must be a positive number; got {v!r}")
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    v_lo, v_hi = (float(v.min()), float(v.max())) if v.size else (0.0, 0.0)
    lo = step * np.floor((v_lo - margin) / step)
    hi = step * np.ceil((v_hi + margin) / step)
    # Widen one step at a time on the side where the data lie closer to the edge, so the data
    # stay near the middle and both limits stay multiples of step.
    while hi - lo < span * (1 - 1e-12):
        if v_lo - lo <= hi - v_hi:
            lo -= step
        else:
            hi += step
    return float(lo) + 0.0, float(hi) + 0.0      # + 0.0: no -0.0 on an axis


def _phase_deg(G: np.ndarray, reference: float | None) -> tuple[np.ndarray, float]:
    """Unwrapped phase in degrees on one 360-degree branch: the first model's (the reference)
    starts in (-270, 90] deg, so a negative gain reads -180 (not +180) and a lag is negative;
    every later model is put on the branch nearest the reference at the lowest frequency, so a
    phase of -180 and one of +180 (the same angle) are drawn as the same curve."""
    phase = np.degrees(np.unwrap(np.angle(G)))
    if reference is None:
        reference = phase[0] - 360.0 * np.floor((phase[0] + 270.0) / 360.0)
        if reference <= -270.0:
            reference += 360.0
    phase = phase - 360.0 * np.round((phase[0] - reference) / 360.0)
    return phase, reference


def fig3(comparisons: list[Comparison], path=None, omega=FREQUENCIES, *, title=None):
    """Paper Fig. 3: per subsystem a row with the unit-step response, Bode magnitude (dB) and
    phase (deg, fixed limits: module docstring).

    Args:
        comparisons: one ``Comparison`` per row.
        path: where to write the PNG (None: only return the Figure).
        omega: ``(f,)`` frequencies in rad/s.
        title: what produced the figure, e.g. the scenario and whether the identifiers were
            trained in this run or shipped.
    """
    from aeid_struct.simulation import simulate

    comparisons = list(comparisons)
    if not comparisons or not all(isinstance(c, Comparison) for c in comparisons):
        raise ValueError("comparisons must be a non-empty list of plots.Comparison; got "
                         f"{[type(c).__name__ for c in comparisons]}")
    _check_title(title)
    plt = _pyplot()
    fig, axes = plt.subplots(len(comparisons), 3, figsize=(13, 3.8 * len(comparisons)),
                             squeeze=False, layout="constrained")
    for row, cmp in zip(axes, comparisons, strict=True):
        t = np.arange(cmp.steps) * cmp.dt
        u = np.ones(cmp.steps)
        models = {"true": cmp.true, "identified": cmp.est, **(cmp.extra or {})}
        styles = {"true": dict(color="k", lw=2.2, alpha=0.6),
                  "identified": dict(color="C1", lw=1.4, ls="--")}
        reference = None
        magnitudes, phases = [], []
        for i, (label, model) in enumerate(models.items()):
            style = styles.get(label, dict(lw=1.0, ls=":", color=f"C{i + 1}"))
            y = simulate(*model, u, cmp.dt)
            G = frequency_response(*model, omega=omega)
            with np.errstate(divide="ignore"):
                magnitude = 20 * np.log10(np.abs(G))
            phase, reference = _phase_deg(G, reference)
            magnitudes.append(magnitude)
            phases.append(phase)
            row[0].plot(t, y, label=label, **style)
            row[1].semilogx(omega, magnitude, label=label, **style)
            row[2].semilogx(omega, phase, label=label, **style)
        step = (f"1 {cmp.u_unit} step in {cmp.u_name}" if cmp.u_unit
                else f"unit step in {cmp.u_name}")
        per = f"({cmp.u_unit})" if " " in cmp.u_unit else cmp.u_unit
        gain = f"{cmp.y_unit}/{per}" if cmp.y_unit and cmp.u_unit else ""
        row[0].set(title=f"{cmp.name}\n{step}", xlabel="time t [s]",
                   ylabel=f"{cmp.y_name} {_unit(cmp.y_unit)}")
        row[1].set(title="Bode magnitude", xlabel="frequency omega [rad/s]",
                   ylabel=f"|G| [dB re 1 {gain}]" if gain else "|G| [dB]",
                   ylim=_limits(np.concatenate(magnitudes), step=10.0, margin=3.0, span=20.0))
        lo, hi = _limits(np.concatenate(phases), step=45.0, margin=10.0, span=90.0)
        tick = 45.0 if hi - lo <= 360 else 90.0 if hi - lo <= 720 else 180.0
        row[2].set(title="Bode phase", xlabel="frequency omega [rad/s]",
                   ylabel="arg G [deg]", ylim=(lo, hi),
                   yticks=np.arange(tick * np.ceil(lo / tick), hi + tick / 2, tick))
        for ax in row:
            ax.grid(True, which="both", alpha=0.3)
        row[0].legend()
    _finish(fig, title, path)
    return fig


def fig4(sizes, errors: dict[str, np.ndarray], path=None, paper: dict | None = None, *,
         title=None):
    """Paper Fig. 4: mean step error over the training-set size, one line per subsystem.

    Args:
        sizes: ``(s,)`` training-set sizes. errors: label -> ``(s,)`` mean step errors.
        paper: optional label -> value reference lines (the paper's overall errors).
        title: what produced the figure (budget per size, seed, validation set).
    """
    _check_title(title)
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.4), layout="constrained")
    for i, (label, err) in enumerate(errors.items()):
        ax.loglog(sizes, err, "o-", label=label, color=f"C{i}")
    for i, (label, value) in enumerate((paper or {}).items()):
        ax.axhline(value, ls="--", lw=1, color=f"C{i}", label=f"paper, {label}")
    ax.set(xlabel="training systems [count]",
           ylabel=f"mean step error [{METRIC_UNITS['step']}]",
           title="Step error vs training-set size")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    _finish(fig, title, path)
    return fig


def _runs(value) -> list:
    """A history dict, or a list of them (e.g. one per seed), as a list."""
    return [value] if isinstance(value, dict) else list(value)


def training_curves(histories: dict, path=None, *, title=None):
    """Held-out loss and largest gradient norm (before clipping) per epoch, log scale.

    Args:
        histories: label -> ``train()``'s history (``ident.meta["history"]``) or a list of them
            (one line per run, e.g. per seed, in the label's colour). Epochs with batches
            skipped for a non-finite loss or gradient are marked with an ``x``.
        title: what produced the figure (family, structures, budget).
    """
    if not histories:
        raise ValueError("histories must map at least one label to a training history")
    _check_title(title)
    plt = _pyplot()
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
    _finish(fig, title, path)
    return fig


def pole_map(scores, path=None, reference=None, max_records: int = 1000, *, title=None):
    """The estimated poles of each score in the complex plane, one panel per score; the poles
    of estimates that are not stable (``per_record["stable"]`` False) are drawn as red crosses.

    Args:
        scores: ``scorecard.Score`` objects.
        reference: optional ``(N, n)`` complex poles (e.g. of the true systems), drawn in grey.
        max_records: at most this many records per panel (the first ones), to keep it legible.
        title: what produced the figure (family, identifiers, noise).
    """
    scores = list(scores)
    if not scores:
        raise ValueError("scores must hold at least one Score")
    _check_title(title)
    plt = _pyplot()
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
    _finish(fig, title, path)
    return fig


def error_cdf(scores, metric: str = "step", path=None, ax=None, *, title=None):
    """Empirical distribution of a per-record error of each score (share of records with an
    error below x), log x. Infinite errors (overflowing estimates) never reach the curve's top;
    their count is given in the legend.

    Args:
        scores: ``scorecard.Score`` objects. metric: a key of ``per_record`` (e.g. ``"step"``,
            ``"magnitude_db"``, ``"k"``; its unit from ``METRIC_UNITS``). ax: draw into this
            axes instead of a new figure (then the figure is neither laid out nor titled: the
            caller owns it). title: what produced the figure.
    """
    scores = list(scores)
    if not scores:
        raise ValueError("scores must hold at least one Score")
    missing = [s.name for s in scores if metric not in s.per_record]
    if missing:
        raise ValueError(f"metric must be a per-record measure of every score; {metric!r} is "
                         f"missing from {missing}")
    _check_title(title)
    plt = _pyplot()
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
    ax.set(xlabel=f"{metric} error {_unit(METRIC_UNITS.get(metric, ''))}",
           ylabel="share of records [fraction]", ylim=(0, 1.02),
           title=f"Distribution of the {metric} error")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    if own:
        _finish(fig, title, path)
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

    Args:
        groups: panel title -> ``scorecard.Score`` objects (one bar cluster each).
        parameters: the parameters to draw (a score without one leaves its bar out).
        title: what produced the figure (family, validation set, budget).
    """
    if not groups or not all(list(g) for g in groups.values()):
        raise ValueError("groups must map at least one title to a non-empty list of Scores")
    _check_title(title)
    plt = _pyplot()
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
    _finish(fig, title, path)
    return fig


def wear(result, path=None, *, config=None, title=None):
    """True against tracked physical parameters of a wear scenario (``online.wear_study``), one
    panel per parameter (units from ``PARAMETER_UNITS``), with the alarm threshold and the alarm
    time drawn.

    The threshold band is the tracker's own rule (``online`` module docstring): the reference is
    the median of the first ``config.baseline`` window estimates, and the alarm is raised when a
    watched parameter's smoothed estimate stays beyond ``reference * (1 +- config.threshold)``
    for ``config.patience`` windows; the band is drawn on the watched parameters.

    Args:
        result: an ``online.WearResult``.
        config: the ``online.TrackerConfig`` the result was tracked with (None: the default
            one, as ``wear_study`` uses by default).
        title: what produced the figure (identifier, noise, seed, engine).
    """
    from aeid_struct.online import TrackerConfig

    names = list(result.true)
    if not names:
        raise ValueError("result must hold at least one tracked parameter with a true value")
    if config is None:
        config = TrackerConfig()
    if not isinstance(config, TrackerConfig):
        raise ValueError(f"config must be an online.TrackerConfig; got {type(config).__name__}")
    _check_title(title)
    watched = [p for p in names if not config.watch or p in config.watch]
    plt = _pyplot()
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 2.4 * len(names) + 1.0), sharex=True,
                             squeeze=False, layout="constrained")
    for ax, p in zip(axes[:, 0], names, strict=True):
        estimates = np.asarray(result.estimate[p], dtype=np.float64)
        drawn = [np.asarray(result.true[p], dtype=np.float64), estimates,
                 np.asarray(result.smoothed[p], dtype=np.float64)]
        ax.plot(result.t, drawn[0], "k-", lw=1.5, label="true")
        ax.plot(result.t, estimates, ".", color="C0", ms=3, alpha=0.5, label="window estimate")
        ax.plot(result.t, drawn[2], "-", color="C3", lw=1.2, label="smoothed")
        if p in watched and estimates.size >= config.baseline:
            reference = float(np.median(estimates[: config.baseline]))
            band = reference * (1 + config.threshold * np.array([1.0, -1.0]))
            drawn.append(band)
            for i, level in enumerate(band):
                ax.axhline(level, color="C1", ls="-.", lw=1,
                           label=(f"alarm threshold: reference ±{config.threshold:.0%}"
                                  if i == 0 else None))
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
        ax.set_ylabel(f"{p} {_unit(PARAMETER_UNITS.get(p, ''))}")
        ax.grid(True, alpha=0.3)
    # One legend for all panels, under them: inside a panel it hides the data.
    handles = {}
    for ax in axes[:, 0]:
        for h, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, h)
    fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncol=3,
               fontsize=8)
    axes[0, 0].set_title("True and tracked physical parameters")
    axes[-1, 0].set_xlabel("time t [s]")
    _finish(fig, title, path)
    return fig
