"""The robot-leg study of paper Sec. IV: train, evaluate, Table I, Fig. 3 and Fig. 4.

Record settings (the paper gives none; ours):

- stable, translational subsystem ``G1``: ``dt = 0.01 s``, 300 samples (3 s: the slowest decay,
  ``d/(2m) >= 0.67 /s``, has brought the step response within 15 % of its final value and the
  oscillation of 3.7-7 rad/s shows 2-3 periods);
- unstable, rotational subsystem ``G2``: ``dt = 0.005 s``, 100 samples (0.5 s: the response grows
  like ``e^{p t}`` with ``p = sqrt(g/L)`` in 4-12.4 /s, i.e. by up to ``e^{6.2} = 490``; longer
  records would only show the exponential, shorter ones hide the slow poles).

Training uses 10^4 simulated step responses per subsystem with (k, d, m) uniform in the paper's
ranges, 20 % held out; evaluation uses 500 fresh systems from another seed and the paper's
scenario k = 24.23, d = 2.24, m = 1.01, all noise-free unless asked.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .data import LegFamily, records
from .decoder import simulate
from .metrics import FREQUENCIES, bode_errors, parameter_errors, step_error

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

    Attributes:
        subsystem: "stable" or "unstable".
        scenario, overall: metric name -> value (step, magnitude_db, phase_rad, k, d, m in %).
        per_system: metric name -> ``(count,)`` values over the validation set.
        latency_ms: median batch-1 identification time; throughput: identifications/s batched.
    """

    subsystem: str
    scenario: dict
    overall: dict
    per_system: dict = field(repr=False)
    latency_ms: float
    throughput: float


def training_config(subsystem: str, *, seconds: float | None, seed: int = 0,
                    count: int = 10_000, noise=0.0, checkpoint=None, progress: bool = True,
                    epochs: int | None = None):
    """The study's training settings for one subsystem: a wall-time budget, or an epoch budget
    (reproducible whatever else the machine is doing) when ``epochs`` is given."""
    from .training import TrainConfig

    dt, steps = _grid(subsystem)
    if epochs is not None:
        seconds = None
    # With a wall-time budget the epoch limit must not bind: 100,000 epochs are weeks here.
    return TrainConfig(dt=dt, steps=steps, count=count, epochs=epochs or 100_000,
                       seconds=seconds,
                       batch=128, lr=3e-3, gamma=1.0, noise=noise, seed=seed,
                       checkpoint=checkpoint, progress=progress)


def _grid(subsystem: str):
    """``(dt, steps)`` of a subsystem's record; tuples (stable, unstable) for the joint leg."""
    if subsystem == "joint":
        return tuple(RECORDS[s][0] for s in RECORDS), tuple(RECORDS[s][1] for s in RECORDS)
    return RECORDS[subsystem]


def leg_structure(subsystem: str):
    """The paper's structure: CCF of order 2 (Descartes' constraint for the stable subsystem;
    the unstable one has a0 = -g/L < 0, so the constraint would exclude the truth)."""
    from .structures import CCF

    return CCF(2, descartes=(subsystem == "stable"))


def leg_encoder(subsystem: str):
    """The encoder of the shipped leg identifiers: the paper's architecture (three convolutions
    and a shortcut, then two dense layers), 12 convolution and 48 dense neurons instead of 8 and
    10, on the record average-pooled to 50 samples (pool 6 for 300 samples, 2 for 100): the
    responses are smooth, and pooling divides the convolution cost for batch throughput."""
    from .encoder import EncoderConfig

    pool = tuple(s // 50 for s in _grid(subsystem)[1]) if subsystem == "joint" \
        else RECORDS[subsystem][1] // 50
    return EncoderConfig(width=8, kernel=5, depth=3, dense=(48, 48), pool=pool,
                         activation="tanh")


def train_leg(subsystem: str, *, seconds: float | None, seed: int = 0, count: int = 10_000,
              noise=0.0, checkpoint=None, progress: bool = True, command: str = "",
              epochs: int | None = None):
    """Train one leg identifier with the study's settings."""
    from .training import train

    inverse = LegFamily(subsystem=subsystem).inverse()
    config = training_config(subsystem, seconds=seconds, seed=seed, count=count, noise=noise,
                             checkpoint=checkpoint, progress=progress, epochs=epochs)
    return train(leg_structure(subsystem), LegFamily(subsystem=subsystem), config,
                 encoder=leg_encoder(subsystem), inverse=inverse,
                 meta={"name": f"leg-{subsystem}", "command": command, "seed": seed})


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
    """Table I metrics of ``ident`` on ``count`` fresh systems and on the paper's scenario."""
    dt, steps = RECORDS[subsystem]
    family = LegFamily(subsystem=subsystem)
    val = records(family, count, steps=steps, dt=dt, noise=noise, seed=seed)
    scen_sys = family.systems(**{k: [v] for k, v in SCENARIO.items()})
    u = np.ones(steps)
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
    """Table I, ours beside the paper's, as markdown."""
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


def figure3(idents: dict, path, source: str = "identifiers given") -> None:
    """Paper Fig. 3 for the scenario: step and Bode, true vs identified, both subsystems;
    ``source`` says where the identifiers came from (trained in this run, or shipped) and goes
    into the figure's title with the scenario."""
    from .plots import LEG_SIGNALS, Comparison, fig3

    comparisons = []
    for subsystem, ident in idents.items():
        dt, steps = RECORDS[subsystem]
        family = LegFamily(subsystem=subsystem)
        s = family.systems(**{k: [v] for k, v in SCENARIO.items()})
        true = (s.A[0], s.b[0], s.c[0], float(s.d[0]))
        y = simulate(*true, np.ones(steps), dt)
        est = ident.identify(y)
        kind = "translational" if subsystem == "stable" else "rotational"
        comparisons.append(Comparison(f"{subsystem} subsystem ({kind})", true,
                                      (est.A, est.b, est.c, est.d), dt, steps,
                                      **LEG_SIGNALS[subsystem]))
    fig3(comparisons, path,
         title=f"Robot leg, paper scenario k = {SCENARIO['k']} N/m, d = {SCENARIO['d']} N s/m, "
               f"m = {SCENARIO['m']} kg, noise-free step records\n{source}")


def figure4(sizes, *, seconds_each: float, seed: int, path, progress: bool,
            validation: int = 200):
    """Paper Fig. 4: step error vs training-set size; each size trains for ``seconds_each``."""
    from .plots import fig4

    errors = {}
    for subsystem in ("stable", "unstable"):
        errs = []
        for size in sizes:
            ident = train_leg(subsystem, seconds=seconds_each, seed=seed,
                              count=int(size / 0.8) + 1, progress=progress)
            errs.append(evaluate(ident, subsystem, count=validation, timing=False)
                        .overall["step"])
        errors[subsystem] = np.array(errs)
    fig4(np.asarray(sizes), errors, path,
         paper={k: v["step"][1] for k, v in PAPER.items()},
         title=f"Robot leg, identifiers trained in this run: {seconds_each:g} s per size, "
               f"seed {seed}, {validation} validation systems")
    return errors


def run(*, pretrained: bool, seconds: float, seed: int, out, fig4_sizes=None,
        fig4_seconds: float = 30.0, validation: int = 500, progress: bool = True,
        save: bool = True, command: str = "", epochs: int | None = None) -> dict:
    """The whole study; returns the JSON-able result and writes figures and JSON to ``out``."""
    from .identify import load_pretrained

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    idents, train_seconds = {}, {}
    for subsystem in ("stable", "unstable"):
        if pretrained:
            idents[subsystem] = load_pretrained(f"leg-{subsystem}")
            train_seconds[subsystem] = 0.0
        else:
            t0 = time.perf_counter()
            idents[subsystem] = train_leg(subsystem, seconds=seconds / 2, seed=seed,
                                          progress=progress, command=command, epochs=epochs)
            train_seconds[subsystem] = time.perf_counter() - t0
            if save:
                idents[subsystem].save(out / f"leg-{subsystem}.aeid")
    evals = [evaluate(idents[s], s, count=validation) for s in ("stable", "unstable")]
    done = " / ".join(str(len(idents[s].meta.get("history", {}).get("holdout_loss", [])))
                      for s in ("stable", "unstable"))
    budget = (f"{epochs} epochs each" if epochs is not None
              else f"{seconds / 2:g} s budget each ({done} epochs)")
    figure3(idents, out / "fig3_leg_scenario.png",
            source="shipped identifiers leg-stable, leg-unstable" if pretrained else
            f"identifiers trained in this run: {budget}, seed {seed}")
    result = {
        "records": {k: {"dt": v[0], "steps": v[1]} for k, v in RECORDS.items()},
        "frequency_grid_rad_s": [float(FREQUENCIES[0]), float(FREQUENCIES[-1]),
                                 len(FREQUENCIES)],
        "pretrained": pretrained,
        "train_seconds": train_seconds,
        "table": {ev.subsystem: {"scenario": ev.scenario, "overall": ev.overall,
                                 "latency_ms": ev.latency_ms,
                                 "throughput_per_s": ev.throughput} for ev in evals},
        "paper": {"table": PAPER, "seconds": PAPER_SECONDS},
        "markdown": table(evals),
    }
    if fig4_sizes:
        errors = figure4(fig4_sizes, seconds_each=fig4_seconds, seed=seed,
                         path=out / "fig4_error_vs_size.png", progress=progress,
                         validation=min(validation, 200))
        result["fig4"] = {"sizes": list(fig4_sizes),
                          "step_error": {k: v.tolist() for k, v in errors.items()}}
    (out / "leg_study.json").write_text(json.dumps(result, indent=2))
    return result
