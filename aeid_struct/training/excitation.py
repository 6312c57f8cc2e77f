"""Excitation signals: the inputs ``u`` that simulated training records are driven by.

The grid is ``t_k = k dt``, ``k = 0..steps-1``, with the first-order hold between samples
(docs/architecture.md, "Conventions"); every random draw comes from an explicit generator.
"""

from __future__ import annotations

import numpy as np

from aeid_struct.records import unit_step
from aeid_struct.training.checks import count as positive_int
from aeid_struct.training.checks import generator, value_range

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


# ---------------------------------------------------------------------------------------------
# Normalised time (dt = 1): the excitations of the generic families
# ---------------------------------------------------------------------------------------------
#: The kinds ``generic_excitation`` draws, in normalised time (time in samples).
GENERIC_EXCITATIONS = ("staircase", "prbs", "multisine", "chirp", "filtered", "step")


def _log_uniform(rng: np.random.Generator, lo: float, hi: float, size) -> np.ndarray:
    """Draws log-uniform in ``[lo, hi]`` (``lo > 0``)."""
    return np.exp(rng.uniform(np.log(lo), np.log(hi), size=size))


def _held(levels: np.ndarray, holds: np.ndarray, steps: int) -> np.ndarray:
    """``levels[:, j]`` held for ``holds[:, j]`` samples each, cut to ``steps`` samples.

    Mark where each hold ends, and the running count of marks is every sample's segment: no loop
    over the records. ``holds`` must cover ``steps`` (every hold >= 1, ``steps`` of them).
    """
    ends = np.cumsum(holds, axis=1)
    marks = np.zeros((holds.shape[0], steps + 1), dtype=np.int64)
    rows, cols = np.nonzero(ends < steps)
    marks[rows, ends[rows, cols]] = 1
    return np.take_along_axis(levels, np.cumsum(marks[:, :steps], axis=1), axis=1)


def _staircase(count, steps, rng):
    # Mean hold log-uniform between 1 sample and an eighth of the record, each hold within
    # +-50 % of it: slow and fast staircases alike, never fewer than ~8 levels in a record.
    mean = _log_uniform(rng, 1.0, max(2.0, steps / 8), (count, 1))
    holds = np.maximum(1, np.rint(mean * rng.uniform(0.5, 1.5, (count, steps)))).astype(np.int64)
    return _held(rng.uniform(-1.0, 1.0, (count, steps)), holds, steps)


def _prbs(count, steps, rng):
    # A clock of period h (the minimum hold, log-uniform in 1..steps/16, so >= 16 clock periods)
    # with a random phase; at each tick a fresh +-1, so the level switches with probability 1/2.
    h = np.floor(_log_uniform(rng, 1.0, max(1.0, steps / 16) + 0.999, (count, 1))).astype(np.int64)
    phase = rng.integers(0, h)
    ticks = (np.arange(steps)[None, :] + phase) // h
    levels = rng.choice([-1.0, 1.0], size=(count, steps + 1))
    return np.take_along_axis(levels, ticks, axis=1)


def _sub_band(rng, band, count):
    """A random band ``lo <= hi`` per record, both ends log-uniform in ``band``."""
    w = np.sort(_log_uniform(rng, band[0], band[1], (count, 2)), axis=1)
    return w[:, :1], w[:, 1:]


def _multisine(count, steps, rng, band):
    # 16 sines of one amplitude at frequencies log-uniform in the record's band, random phases
    # (a flat amplitude spectrum over the band with a crest factor like Schroeder's), peak 1.
    lo, hi = _sub_band(rng, band, count)
    w = lo[:, :, None] * (hi / lo)[:, :, None] ** rng.uniform(0, 1, (count, 16, 1))
    phase = rng.uniform(0, 2 * np.pi, (count, 16, 1))
    u = np.sin(w * np.arange(steps)[None, None, :] + phase).sum(axis=1)
    return u / np.max(np.abs(u), axis=1, keepdims=True)


def _chirp(count, steps, rng, band, first):
    # Log sweep w(t) = w0 (w1/w0)^(tau/T) over the samples from `first` on (tau = t - first),
    # the start frequency held before (phase continuous), amplitude 1.
    w0, w1 = _sub_band(rng, band, count)
    t = np.arange(steps)[None, :]
    tau = np.maximum(t - first, 0).astype(float)
    span = max(steps - 1 - first, 1)
    log_ratio = np.log(w1 / w0)
    flat = log_ratio < 1e-9
    safe = np.where(flat, 1.0, log_ratio)
    sweep = np.where(flat, w0 * tau, w0 * span / safe * np.expm1(safe * tau / span))
    phase = rng.uniform(0, 2 * np.pi, (count, 1)) + w0 * np.minimum(t, first) + sweep
    return np.sin(phase)


def _filtered(count, steps, rng, band):
    # White noise through a unit-DC-gain discrete low-pass (first order, or second order with
    # damping 0.3-1), cut-off log-uniform in the band but above 4 periods per record (a slower
    # one leaves a constant). Filtered in the frequency domain: the periodic steady state of the
    # filter, a stationary record with no start-up transient. Peak 1.
    wc = _log_uniform(rng, min(max(band[0], 8 * np.pi / steps), band[1]), band[1], (count, 1))
    second = rng.random((count, 1)) < 0.5
    zeta = rng.uniform(0.3, 1.0, (count, 1))
    z1 = np.exp(-1j * np.linspace(0, np.pi, steps // 2 + 1))[None, :]   # z^-1 on the rfft grid
    a = np.exp(-wc)
    first_order = (1 - a) / (1 - a * z1)
    r, theta = np.exp(-zeta * wc), wc * np.sqrt(1 - zeta**2)
    den = 1 - 2 * r * np.cos(theta) * z1 + r**2 * z1**2
    second_order = (1 - 2 * r * np.cos(theta) + r**2) / den
    H = np.where(second, second_order, first_order)
    u = np.fft.irfft(np.fft.rfft(rng.normal(size=(count, steps)), axis=1) * H, n=steps, axis=1)
    return u / np.max(np.abs(u), axis=1, keepdims=True)


def _step(count, steps, rng, first):
    # A step from a level uniform in [-1, 1] (held since the start, so a pre-roll leaves the
    # system moving) by +-(0.5..1), at a sample in the first half of the samples from `first` on.
    before = rng.uniform(-1.0, 1.0, (count, 1))
    jump = rng.choice([-1.0, 1.0], size=(count, 1)) * rng.uniform(0.5, 1.0, (count, 1))
    at = first + rng.integers(0, max((steps - first) // 2, 1), size=(count, 1))
    return before + jump * (np.arange(steps)[None, :] >= at)


def generic_excitation(kind: str, count: int, steps: int, rng: np.random.Generator, *,
                       first: int = 0, band: tuple = (0.005, 2.5)) -> np.ndarray:
    """Input records of one kind in normalised time (``dt = 1``, time in samples), for the
    generic families (every parameter drawn per record from ``rng``).

    - ``staircase``: uniform levels in ``[-1, 1]`` held for random times (mean hold log-uniform
      in ``1..steps/8`` samples, each hold within +-50 % of it).
    - ``prbs``: +-1 on a clock of random period ``h`` (the minimum hold, log-uniform in
      ``1..steps/16``) with a random phase, a fresh random sign at each tick.
    - ``multisine``: 16 random-phase sines of one amplitude, frequencies log-uniform in a random
      band ``[lo, hi]`` inside ``band``; peak 1.
    - ``chirp``: log sweep from ``w0`` up to ``w1`` (a random band inside ``band``) over the
      samples from ``first`` on, ``w0`` held before; amplitude 1.
    - ``filtered``: white noise through a unit-DC-gain first- or second-order discrete low-pass,
      cut-off log-uniform in ``band`` (at least 4 periods per record); peak 1.
    - ``step``: a step by ``+-(0.5..1)`` from a level uniform in ``[-1, 1]``, at a random
      sample in the first half of the samples from ``first`` on.

    ``excitation`` keeps its own ``prbs``, ``multisine`` and ``step`` (in seconds, for the
    robot-leg families); these are the normalised-time kinds of the same names.

    Parameters
    ----------
    kind : str
        One of ``GENERIC_EXCITATIONS``.
    count : int
        Records (0 gives an empty ``(0, steps)`` array).
    steps : int
        Samples per record, >= 1.
    rng : numpy.random.Generator
        Every random draw.
    first : int
        Where the record proper begins (after a pre-roll): the chirp sweeps and the step lands
        from there on; ``0 <= first < steps``.
    band : (lo, hi)
        Frequencies (rad/sample) the random bands of ``multisine``, ``chirp`` and ``filtered``
        are drawn in; ``0 < lo <= hi <= pi``.

    Returns
    -------
    u : (count, steps) float64 array

    Raises
    ------
    ValueError
        If an argument is out of its range (the message names it).
    """
    if kind not in GENERIC_EXCITATIONS:
        raise ValueError(f"kind must be one of {GENERIC_EXCITATIONS}; got {kind!r}")
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
        raise ValueError(f"count must be an integer >= 0; got {count!r}")
    steps = positive_int("steps", steps)
    if isinstance(first, bool) or not isinstance(first, (int, np.integer)) \
            or not 0 <= first < steps:
        raise ValueError(f"first must be an integer in [0, steps = {steps}); got {first!r}")
    lo, hi = value_range("band", band)
    if not 0 < lo <= hi <= np.pi:
        raise ValueError(f"band must satisfy 0 < lo <= hi <= pi (rad/sample); got {band!r}")
    generator(rng)
    if count == 0:
        return np.zeros((0, steps))
    if kind == "staircase":
        return _staircase(count, steps, rng)
    if kind == "prbs":
        return _prbs(count, steps, rng)
    if kind == "multisine":
        return _multisine(count, steps, rng, (lo, hi))
    if kind == "chirp":
        return _chirp(count, steps, rng, (lo, hi), int(first))
    if kind == "filtered":
        return _filtered(count, steps, rng, (lo, hi))
    return _step(count, steps, rng, int(first))
