"""Table I of the robot-leg study (paper Sec. IV): the record grids, the paper's scenario and
numbers, and the evaluation of an identifier on fresh systems.

Record settings (the paper gives none; ours):

- stable, translational subsystem ``G1``: ``dt = 0.01 s``, 300 samples (3 s: the slowest decay,
  ``d/(2m) >= 0.67 /s``, has brought the step response within 15 % of its final value and the
  oscillation of 3.7-7 rad/s shows 2-3 periods);
- unstable, rotational subsystem ``G2``: ``dt = 0.005 s``, 100 samples (0.5 s: the response grows
  like ``e^{p t}`` with ``p = sqrt(g/L)`` in 4-12.4 /s, i.e. by up to ``e^{6.2} = 490``; longer
  records would only show the exponential, shorter ones hide the slow poles).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from aeid_struct.metrics import FREQUENCIES, bode_errors, parameter_errors, step_error
from aeid_struct.records import unit_step
from aeid_struct.simulation import simulate
from aeid_struct.training import LegFamily, records

#: Record grid per subsystem: (dt, steps).
RECORDS = {"stable": (0.01, 300), "unstable": (0.005, 100)}
SCENARIO = {"k": 24.23, "d": 2.24, "m": 1.01}

#: Paper Table I: subsystem -> metric -> (scenario, overall). Phase in rad (paper: 10^-3 rad).
PAPER = {
    "stable": {"step": (9.01e-3, 14.82e-3), "magnitude_db": (0.73, 0.89),
               "phase_rad": (39.72e-3, 28.46e-3), "k": (1.97, 11.68), "d": (3.49, 8.67),
               "m": (3.89, 14.77)},
    "unstable": {"step": (15.70e-3, 31.50e-3), "magnitude_db": (4.03, 3.37),
                 "phase_rad": (0.0, 0.0), "k": (24.19, 26.36), "m": (50.13, 48.32)},
}
PAPER_SECONDS = {"encoder_400mhz": 1.194, "n4sid_matlab": 3.682}


@dataclass(frozen=True)
class Evaluation:
    """Table I metrics of one identifier, scenario and overall (mean over the validation set).

    Attributes
    ----------
    subsystem : str
        ``"stable"`` or ``"unstable"``.
    scenario : dict of str to float
        Metric name -> value on the paper's scenario (step, magnitude_db, phase_rad, and
        k, d, m in %).
    overall : dict of str to float
        Metric name -> mean over the validation set.
    per_system : dict of str to (count,) ndarray
        Metric name -> its values over the validation set.
    latency_ms : float
        Median batch-1 identification time [ms].
    throughput : float
        Identifications per second, batched.
    """

    subsystem: str
    scenario: dict
    overall: dict
    per_system: dict = field(repr=False)
    latency_ms: float
    throughput: float



def _timing(ident, y: np.ndarray) -> tuple[float, float]:
    """Median batch-1 latency (ms) and batched throughput (identifications/s)."""
    single = y[0]
    for _ in range(50):
        ident.identify(single)
    times = []
    for i in range(1000):
        t0 = time.perf_counter()
        ident.identify(y[i % len(y)])
        times.append(time.perf_counter() - t0)
    batch = np.tile(y, (max(1, 4096 // len(y)), 1))[:4096]
    ident.identify(batch)
    t0 = time.perf_counter()
    reps = 3
    for _ in range(reps):
        ident.identify(batch)
    throughput = reps * len(batch) / (time.perf_counter() - t0)
    return 1e3 * float(np.median(times)), float(throughput)


def evaluate(ident, subsystem: str, *, count: int = 500, seed: int = 12345,
             noise: float = 0.0, timing: bool = True) -> Evaluation:
    """Table I metrics of ``ident`` on ``count`` fresh systems and on the paper's scenario.

    Parameters
    ----------
    ident : Identifier
        A leg identifier of the subsystem's record grid (``RECORDS``).
    subsystem : str
        ``"stable"`` or ``"unstable"``.
    count : int
        Fresh validation systems.
    seed : int
        Their seed.
    noise : float
        Measurement noise of their records.
    timing : bool
        Also measure the latency and throughput (else nan).

    Returns
    -------
    Evaluation
    """
    dt, steps = RECORDS[subsystem]
    family = LegFamily(subsystem=subsystem)
    val = records(family, count, steps=steps, dt=dt, noise=noise, seed=seed)
    scen_sys = family.systems(**{k: [v] for k, v in SCENARIO.items()})
    u = unit_step(steps)
    y_scen = simulate(scen_sys.A, scen_sys.b, scen_sys.c, scen_sys.d, u, dt)
    y_all = np.concatenate([y_scen, val.y])
    y_true = np.concatenate([y_scen, val.y_clean])
    est = ident.identify(y_all)
    y_hat = simulate(est.A, est.b, est.c, est.d, u, dt)
    metrics = {"step": step_error(y_true, y_hat)}
    true = (np.concatenate([scen_sys.A, val.systems.A]), np.concatenate([scen_sys.b,
            val.systems.b]), np.concatenate([scen_sys.c, val.systems.c]),
            np.concatenate([scen_sys.d, val.systems.d]))
    metrics["magnitude_db"], metrics["phase_rad"] = bode_errors(
        true, (est.A, est.b, est.c, est.d), FREQUENCIES)
    params = {k: np.concatenate([[SCENARIO[k]], val.systems.params[k]]) for k in SCENARIO}
    metrics.update(parameter_errors(params, est.physical))
    latency, throughput = _timing(ident, val.y) if timing else (float("nan"), float("nan"))
    return Evaluation(
        subsystem,
        {k: float(v[0]) for k, v in metrics.items()},
        {k: float(np.mean(v[1:])) for k, v in metrics.items()},
        {k: v[1:] for k, v in metrics.items()},
        latency, throughput,
    )


def table(evals: list[Evaluation]) -> str:
    """Table I, ours beside the paper's, as markdown.

    Parameters
    ----------
    evals : list of Evaluation
        One per subsystem.

    Returns
    -------
    str
    """
    rows = [("step", "Step error", "{:.2e}"), ("magnitude_db", "Magnitude (dB)", "{:.3f}"),
            ("phase_rad", "Phase (rad)", "{:.2e}"), ("k", "Δk (%)", "{:.3f}"),
            ("d", "Δd (%)", "{:.3f}"), ("m", "Δm (%)", "{:.3f}")]
    head = "| metric |"
    sep = "|---|"
    for ev in evals:
        for part in ("scenario", "overall"):
            head += f" {ev.subsystem} {part}: ours | paper |"
            sep += "---:|---:|"
    lines = [head, sep]
    for key, label, fmt in rows:
        line = f"| {label} |"
        for ev in evals:
            paper = PAPER[ev.subsystem].get(key)
            for i, part in enumerate((ev.scenario, ev.overall)):
                ours = part.get(key)
                line += f" {fmt.format(ours) if ours is not None else '-'} |"
                line += f" {fmt.format(paper[i]) if paper is not None else '-'} |"
        lines.append(line)
    return "\n".join(lines)
