"""Excitation signals: the inputs ``u`` that simulated training records are driven by.

The grid is ``t_k = k dt``, ``k = 0..steps-1``, with the first-order hold between samples
(docs/architecture.md, "Conventions"); every random draw comes from an explicit generator.
"""

from __future__ import annotations

import numpy as np

from aeid_struct.records import unit_step
from aeid_struct.training.checks import generator

#: The excitation kinds ``excitation`` draws; ``"step"`` is the paper's.
EXCITATIONS = ("step", "ramp", "prbs", "multisine", "noise", "steps", "mix")


def excitation(kind: str, count: int, steps: int, dt: float,
               rng: np.random.Generator, *, first: int = 0) -> np.ndarray:
    """Input records of one kind on the grid ``t_k = k dt``, ``k = 0..steps-1``.

    - ``step``: unit step ``u_k = 1`` (the paper's excitation, ``records.unit_step``).
    - ``ramp``: ``u_k = t_k / t_end``.
    - ``prbs``: random +-1 levels held for 3-12 samples (a pseudo-random binary sequence).
    - ``multisine``: 4 random-phase sines between 0.2 and 10 Hz (below Nyquist), peak 1.
    - ``noise``: Gaussian noise low-pass filtered (first order, 5 Hz), peak 1.
    - ``steps``: a step of random height in [0.5, 2] at a random sample in the first quarter of
      the samples from ``first`` on (zero before it).
    - ``mix``: each record of a kind drawn at random among ``steps``, ``prbs``, ``multisine``
      and ``noise``.

    Parameters
    ----------
    kind : str
        One of ``EXCITATIONS``.
    count : int
        Records (0 gives an empty ``(0, steps)`` array).
    steps : int
        Samples per record.
    dt : float
        Sample time (s).
    rng : numpy.random.Generator
        Every random draw.
    first : int
        Where the record proper begins (``records(warmup=...)``). Why: a step in the first
        quarter of warmup + window has settled before a mid-motion window opens, and a flat
        window identifies nothing.

    Returns
    -------
    u : (count, steps) float64 array
    """
    if kind not in EXCITATIONS:
        raise ValueError(f"kind must be one of {EXCITATIONS}; got {kind!r}")
    generator(rng)
    t = np.arange(steps) * dt
    if kind == "step":
        return unit_step((count, steps))
    if kind == "ramp":
        return np.tile(t / max(t[-1], dt), (count, 1))
    if kind == "prbs":
        # Each record: levels +-1 held for 3-12 samples. Mark where each hold ends, and the
        # running count of marks is every sample's segment: no loop over the records.
        ends = np.cumsum(rng.integers(3, 13, size=(count, steps)), axis=1)
        marks = np.zeros((count, steps + 1), dtype=np.int64)
        rows, cols = np.nonzero(ends < steps)
        marks[rows, ends[rows, cols]] = 1
        segment = np.cumsum(marks[:, :steps], axis=1)
        levels = rng.choice([-1.0, 1.0], size=(count, steps))
        return np.take_along_axis(levels, segment, axis=1)
    if kind == "multisine":
        fmax = min(10.0, 0.4 / dt)
        f = rng.uniform(0.2, fmax, size=(count, 4, 1))
        phase = rng.uniform(0, 2 * np.pi, size=(count, 4, 1))
        u = np.sin(2 * np.pi * f * t[None, None, :] + phase).sum(axis=1)
        return u / np.max(np.abs(u), axis=1, keepdims=True)
    if kind == "steps":
        height = rng.uniform(0.5, 2.0, size=(count, 1))
        start = first + rng.integers(0, max((steps - first) // 4, 1), size=(count, 1))
        return height * (np.arange(steps)[None, :] >= start)
    if kind == "noise":
        from scipy.signal import lfilter

        alpha = np.exp(-2 * np.pi * 5.0 * dt)
        u = lfilter([1 - alpha], [1, -alpha], rng.normal(size=(count, steps)), axis=1)
        return u / np.max(np.abs(u), axis=1, keepdims=True)
    # mix
    kinds = ("step", "prbs", "multisine", "noise")
    pick = rng.integers(0, len(kinds), size=count)
    u = np.empty((count, steps))
    for j, sub in enumerate(kinds):
        idx = np.flatnonzero(pick == j)
        if idx.size == 0:
            continue
        u[idx] = excitation("steps" if sub == "step" else sub, idx.size, steps, dt, rng,
                            first=first)
    return u
