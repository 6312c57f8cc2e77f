"""True against identified models: step responses and Bode plots (paper Fig. 3) and the step error
over the training-set size (paper Fig. 4).

Limits are fixed where automatic ones mislead: the Bode phase is drawn in degrees between
multiples of 45 deg that contain every curve with a margin (a nearly constant phase, as the
rotational leg's -180 deg, would otherwise fill a window of a few hundredths of a degree with
rounding noise), the magnitude in dB between multiples of 10 dB spanning at least 20 dB.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aeid_struct.evaluation.style import (
    METRIC_UNITS,
    check_title,
    finish_figure,
    pyplot,
    unit_label,
)
from aeid_struct.metrics import FREQUENCIES, frequency_response
from aeid_struct.records import unit_step

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


@dataclass(frozen=True)
class Comparison:
    """One subsystem of Fig. 3: a true and an identified model of the same record.

    Attributes
    ----------
    name : str
        The panel title.
    true : tuple
        ``(A (n, n), b (n,), c (n,), d)`` of the true system.
    est : tuple
        ``(A, b, c, d)`` of the identified one.
    dt : float
        The sample time of the step response [s].
    steps : int
        Its samples.
    extra : dict of str to tuple, optional
        Further identified models to draw (label -> ``(A, b, c, d)``), e.g. "refined".
    u_name : str
        The input quantity, e.g. ``"force F"`` (``**LEG_SIGNALS["stable"]`` gives all four).
    u_unit : str
        Its unit: the step is one unit of it. Empty units say so on the axis rather than
        leaving it bare.
    y_name : str
        The output quantity.
    y_unit : str
        Its unit; the Bode magnitude is in dB relative to 1 ``y_unit``/``u_unit``.

    Raises
    ------
    ValueError
        A name or unit that is not a string.
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


def _limits(values, *, step: float, margin: float, span: float) -> tuple[float, float]:
    """Axis limits on multiples of ``step`` that contain every finite value with ``margin`` to
    spare on both sides, at least ``span`` apart.

    Parameters
    ----------
    values : array_like
        Any array of data drawn on the axis (non-finite entries are ignored).
    step, margin, span : float
        In the axis' unit, all > 0.

    Returns
    -------
    (low, high) : tuple of float
        The margin around 0, rounded out, when no value is finite.
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

    Parameters
    ----------
    comparisons : list of Comparison
        One per row.
    path : str or Path, optional
        Where to write the PNG (None: only return the Figure).
    omega : (f,) array_like
        Frequencies [rad/s] (default ``metrics.FREQUENCIES``).
    title : str, optional
        What produced the figure, e.g. the scenario and whether the identifiers were trained in
        this run or shipped.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValueError
        ``comparisons`` empty or not ``Comparison`` objects, or a title that is not a string.
    """
    from aeid_struct.simulation import simulate

    comparisons = list(comparisons)
    if not comparisons or not all(isinstance(c, Comparison) for c in comparisons):
        raise ValueError("comparisons must be a non-empty list of plots.Comparison; got "
                         f"{[type(c).__name__ for c in comparisons]}")
    check_title(title)
    plt = pyplot()
    fig, axes = plt.subplots(len(comparisons), 3, figsize=(13, 3.8 * len(comparisons)),
                             squeeze=False, layout="constrained")
    for row, cmp in zip(axes, comparisons, strict=True):
        t = np.arange(cmp.steps) * cmp.dt
        u = unit_step(cmp.steps)
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
                   ylabel=f"{cmp.y_name} {unit_label(cmp.y_unit)}")
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
    finish_figure(fig, title, path)
    return fig


def fig4(sizes, errors: dict[str, np.ndarray], path=None, paper: dict | None = None, *,
         title=None):
    """Paper Fig. 4: mean step error over the training-set size, one line per subsystem.

    Parameters
    ----------
    sizes : (s,) array_like
        Training-set sizes [records].
    errors : dict of str to (s,) array_like
        Label -> the mean step errors at those sizes.
    path : str or Path, optional
        Where to write the PNG (None: only return the Figure).
    paper : dict of str to float, optional
        Label -> a reference line (the paper's overall errors).
    title : str, optional
        What produced the figure (budget per size, seed, validation set).

    Returns
    -------
    matplotlib.figure.Figure
    """
    check_title(title)
    plt = pyplot()
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
    finish_figure(fig, title, path)
    return fig
