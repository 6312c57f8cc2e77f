"""The wear scenario of online identification: a running robot leg whose spring weakens and
whose damping grows, tracked window by window by an ``online.Tracker``.

``wearing_leg`` simulates the translational leg subsystem with parameters that vary per sample
(exact FOH discretisation of each sample interval, paper Eq. 10-11), and ``drifting`` any
mechanism written as a Lagrangian (``symbolic.Mechanism``) whose parameters drift: "a parameter
drifts", in the physical state; ``wear_study`` runs the scenario through a tracker and measures
the tracking error, the alarm delay and the update time; ``stream_study`` tracks a measured
stream the same way, with any identifier the tracker takes (``aeid-struct track --y``).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from aeid_struct.online import Tracker, TrackerConfig
from aeid_struct.simulation import discretise


def wearing_leg(k, d, m, u, dt: float) -> np.ndarray:
    """The translational leg subsystem with slowly varying parameters, from rest.

    Simulated in the physical state (position, velocity) ``m x'' + d x' + k x = u``, ``y = x``,
    which stays continuous when the parameters change (a CCF state would not: its output row is
    ``1/m``). On each sample interval the parameters are held at their value at its start and
    the input is first-order-hold, discretised exactly (``simulation.discretise``, paper
    Eq. 10) and stepped by Eq. 11. For constant parameters this is
    ``G1 = (1/m) / (s^2 + (d/m) s + k/m)`` from rest, as ``simulation.simulate`` gives it.

    Parameters
    ----------
    k, d, m : (N,) array_like
        Spring stiffness [N/m], damping [kg/s] and mass [kg] per sample; ``k, m > 0``,
        ``d >= 0``.
    u : (N,) array_like
        The leg force [N] at ``t_i = i dt``, linear in between.
    dt : float
        The sample time [s], > 0.

    Returns
    -------
    y : (N,) ndarray
        The leg length's deviation from the equilibrium [m] at each sample.

    Raises
    ------
    ValueError
        ``k, d, m`` not one value per sample of ``u``, or outside their ranges.
    """
    k, d, m, u = (np.asarray(v, dtype=np.float64).reshape(-1) for v in (k, d, m, u))
    N = u.shape[0]
    if not (k.shape == d.shape == m.shape == (N,)):
        raise ValueError(f"k, d, m must have one value per sample of u ({N}); got "
                         f"{k.shape}, {d.shape}, {m.shape}")
    if np.any(k <= 0) or np.any(m <= 0) or np.any(d < 0):
        raise ValueError("k, m must be positive and d non-negative")
    A = np.zeros((N, 2, 2))
    A[:, 0, 1] = 1.0
    A[:, 1, 0] = -k / m
    A[:, 1, 1] = -d / m
    b = np.stack([np.zeros(N), 1.0 / m], axis=1)
    foh = discretise(A, b, dt)           # one (Phi, gamma1, gamma2) per sample interval
    Phi, g1, g2 = foh.Phi, foh.gamma1, foh.gamma2
    # A loop over the samples: the parameters change every sample, and the decoder's log-depth
    # scan needs one transition matrix for the whole record.
    x = np.zeros(2)
    y = np.empty(N)
    du = np.diff(u, append=u[-1])
    for i in range(N):
        y[i] = x[0]
        x = Phi[i] @ x + g1[i] * u[i] + g2[i] * du[i]
    return y


def drifting(mechanism, parameters: dict, u, dt: float, *, output: int = 0, input: int = 0,
             states=None, known: dict | None = None, **operating) -> np.ndarray:
    """A mechanism's channel with parameters that vary per sample, from rest at its
    equilibrium: the linearisation (``Mechanism.linearise``) in its physical state
    ``x = (q, dq)``, which stays continuous when the parameters change, held on each sample
    interval at the interval's start, the input first-order-hold, discretised exactly
    (``simulation.discretise``, paper Eq. 10) and stepped by Eq. 11, as :func:`wearing_leg`
    does for the leg.

    Parameters
    ----------
    mechanism : symbolic.Mechanism
    parameters : dict name -> (N,) array_like
        Every free parameter (those not in ``known``), one value per sample.
    u : (N,) array_like
        The input ``u[input]`` at the samples (deviation from the operating input).
    dt : float
    output, input : int
        The channel.
    states : sequence of int, optional
        The states of a decoupled subsystem to simulate alone (the leg's translation,
        ``(0, 2)``: leaving out an unstable mode the channel does not excite, which rounding
        would otherwise grow).
    known : dict, optional
    **operating
        ``q``, ``u`` (the operating input), ``guess`` of ``Mechanism.linearise``.

    Returns
    -------
    (N,) ndarray
        ``y[output]`` (deviation from the equilibrium) at each sample.

    Raises
    ------
    ValueError
        A parameter missing or not one value per sample.
    """
    lin = mechanism.linearise(known=known, **operating)
    names = list(lin.name_in())
    u = np.asarray(u, dtype=np.float64).reshape(-1)
    N = u.shape[0]
    values = {k: np.asarray(parameters.get(k, ()), dtype=np.float64).reshape(-1) for k in names}
    bad = [k for k, v in values.items() if v.shape != (N,)]
    if bad:
        raise ValueError(f"parameters must give {bad} one value per sample of u ({N})")
    out = lin.map(N)(**{k: v.reshape(1, N) for k, v in values.items()})
    n, m = np.array(out["A"]).shape[0], np.array(out["B"]).shape[1] // N
    s = list(range(n)) if states is None else [int(i) for i in states]
    # mapped outputs sit side by side: A (n, n N), B (n, m N), C (p, n N), D (p, m N)
    A = np.array(out["A"]).reshape(n, N, n).transpose(1, 0, 2)[:, s][:, :, s]
    B = np.array(out["B"]).reshape(n, N, m).transpose(1, 0, 2)[:, s, input]
    C = np.array(out["C"]).reshape(-1, N, n)[output][:, s]
    feed = np.array(out["D"]).reshape(-1, N, m)[output, :, input]
    foh = discretise(A, B, dt)
    x = np.zeros(len(s))
    y = np.empty(N)
    du = np.diff(u, append=u[-1])
    for i in range(N):
        y[i] = C[i] @ x + feed[i] * u[i]
        x = foh.Phi[i] @ x + foh.gamma1[i] * u[i] + foh.gamma2[i] * du[i]
    return y


@dataclass(frozen=True)
class WearResult:
    """A tracked wear scenario (:func:`wear_study`).

    Attributes
    ----------
    t : (W,) ndarray
        Time of each window's last sample [s].
    true : dict of str to (W,) ndarray
        The true parameter at the middle of each window.
    estimate : dict of str to (W,) ndarray
        The tracker's raw window estimates.
    smoothed : dict of str to (W,) ndarray
        Its smoothed estimates.
    alarm : (W,) bool ndarray
        The tracker's alarm after each window.
    drift_time : float
        When the true k first left its start value by more than the tracker's threshold [s].
    alarm_time : float
        When the alarm was first raised [s] (nan if never).
    rms : dict of str to float
        RMS relative error (%) of the smoothed estimate after the baseline windows.
    latency_ms : float
        Median wall time of one tracker update (one window identified, smoothed and checked),
        as ``Tracker.push`` takes it.
    engine : str
        The tracker's engine (``"onnx"`` or ``"identifier"``).
    latency_p95_ms : float
        The 95th percentile of the update's wall time.
    config : online.TrackerConfig or None
        The configuration the tracker used (``Tracker.config``: the smoothing resolved).
    drift : dict of str to (W,) ndarray, optional
        The tracker's own drift of each smoothed parameter from its reference after each
        window (``Update.drift``: NaN until the reference exists).
    limit : dict of str to float, optional
        Each parameter's alarm limit (``Tracker.limits``: the relative drift beyond which it
        counts toward the alarm; empty where the baseline never filled).
    """

    t: np.ndarray
    true: dict
    estimate: dict
    smoothed: dict
    alarm: np.ndarray
    drift_time: float
    alarm_time: float
    rms: dict
    latency_ms: float
    engine: str = "identifier"
    latency_p95_ms: float = math.nan
    config: TrackerConfig | None = None
    drift: dict | None = None
    limit: dict | None = None

    @property
    def delay(self) -> float:
        """Alarm delay after the true drift crossed the threshold [s] (nan without an alarm)."""
        return self.alarm_time - self.drift_time


def _scenario(identifier, seconds: float, noise: float, seed: int):
    """The scenario's truth and record: ``t, k, d, m, u, y (N,)`` (``wear_study``)."""
    dt = identifier.dt
    N, before = int(round(seconds / dt)), identifier.steps
    t = np.arange(N) * dt
    ramp = np.clip((t / seconds - 0.25) / 0.5, 0.0, 1.0)
    k, d, m = 25.0 - 5.0 * ramp, 2.5 + 1.0 * ramp, np.ones(N)
    rng = np.random.default_rng(seed)
    ends = np.cumsum(rng.integers(3, 13, size=N + before))
    level = rng.choice([-1.0, 1.0], size=N + before)
    u = level[np.searchsorted(ends, np.arange(N + before), side="right")]
    pad = np.ones(before)
    y = wearing_leg(np.concatenate([k[0] * pad, k]), np.concatenate([d[0] * pad, d]),
                    np.concatenate([m[0] * pad, m]), u, dt)[before:]
    u = u[before:]
    y = y + noise * np.abs(y).max() * rng.normal(size=N)
    return t, k, d, m, u, y


def _track(tracker: Tracker, u: np.ndarray, y: np.ndarray, hop: int):
    """Push the record in chunks of one hop: ``(updates, seconds per update of each chunk)``."""
    import torch

    updates, times = [], []
    # One core, as on a robot's processor: torch's other threads (idle-spinning after the
    # simulation) would otherwise compete with the tracker for the other cores.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for i in range(0, len(u), hop):
            t0 = time.perf_counter()
            got = tracker.feed(y[i: i + hop], u[i: i + hop])
            if got:
                times.append((time.perf_counter() - t0) / len(got))
            updates += got
    finally:
        torch.set_num_threads(threads)
    return updates, times


def _series(updates: list) -> tuple:
    """The tracker's updates as series: ``t (W,)``, the window estimates, smoothed values and
    drifts per parameter, the alarm ``(W,)`` and when it was first raised (NaN if never)."""
    ts = np.array([up.t for up in updates])
    names = list(updates[0].estimate)
    est, smooth, drift = ({p: np.array([getattr(up, field)[p] for up in updates])
                           for p in names} for field in ("estimate", "smoothed", "drift"))
    alarm = np.array([up.alarm for up in updates])
    return (ts, est, smooth, drift, alarm,
            float(ts[np.argmax(alarm)]) if alarm.any() else math.nan)


def wear_study(identifier, *, seconds: float = 120.0, noise: float = 0.01, seed: int = 0,
               config: TrackerConfig = TrackerConfig(),  # noqa: B008
               engine: str = "auto") -> WearResult:
    """A running leg that wears, tracked window by window.

    Scenario: the translational subsystem driven by a random binary force (levels +-1 held
    3-12 samples) for ``seconds``, already running when tracking starts (the force has acted for
    one window length before ``t = 0``: a running leg is not at rest); k stays at 25 N/m for
    the first quarter, falls linearly to 20 N/m until three quarters of the time and stays
    there; d rises from 2.5 to 3.5 kg/s over the same span; m = 1 kg. White measurement noise
    of ``noise * max|y|``. The samples are pushed to an ``online.Tracker`` in chunks of one hop,
    as a controller would.

    Parameters
    ----------
    identifier : Identifier
        On any back end (one read from an ONNX export runs its graph): an identifier of
        mid-motion windows of the translational leg (as ``online.Tracker``
        takes it); its ``dt`` is the scenario's sample time.
    seconds : float
        Length of the scenario [s], > 0; it must cover at least one window.
    noise : float
        Measurement noise, a share of ``max|y|``.
    seed : int
        Seed of the input and the noise.
    config : online.TrackerConfig
        How the tracker windows, smooths and alarms.
    engine : str
        The tracker's engine: ``"auto"``, ``"onnx"`` or ``"identifier"``.

    Returns
    -------
    WearResult

    Raises
    ------
    ValueError
        ``seconds`` not positive or shorter than one window, or a tracker setting refused by
        ``online.Tracker``.
    """
    if not seconds > 0:
        raise ValueError(f"seconds must be positive; got {seconds!r}")
    dt = identifier.dt
    t, k, d, m, u, y = _scenario(identifier, seconds, noise, seed)
    tracker = Tracker(identifier, config, engine=engine)
    updates, times = _track(tracker, u, y, config.hop)
    if not updates:
        raise ValueError(f"seconds must cover at least one window of {identifier.steps} samples")
    N = len(t)
    ts, est, smooth, drift, alarm, alarm_time = _series(updates)
    mid = np.clip(np.round((ts - (identifier.steps - 1) * dt / 2) / dt).astype(int), 0, N - 1)
    truth = {"k": k, "d": d, "m": m}
    true = {p: truth[p][mid] for p in est if p in truth}
    crossed = np.flatnonzero(np.abs(k / k[0] - 1) > config.threshold)
    drift_time = float(t[crossed[0]]) if crossed.size else math.nan
    after = slice(config.baseline, None)
    rms = {p: float(100 * np.sqrt(np.mean((smooth[p][after] / true[p][after] - 1) ** 2)))
           for p in true}
    return WearResult(ts, true, est, smooth, alarm, drift_time, alarm_time, rms,
                      1e3 * float(np.median(times)), tracker.engine,
                      1e3 * float(np.percentile(times, 95)), tracker.config, drift=drift,
                      limit=tracker.limits)


def stream_study(tracker: Tracker, y, u) -> WearResult:
    """A measured stream tracked window by window, as :func:`wear_study` tracks its scenario:
    the samples pushed to ``tracker`` in chunks of one hop, as a controller would, with any
    identifier the tracker takes (a mechanism's, one of several channels).

    Parameters
    ----------
    tracker : online.Tracker
        Fresh (or :meth:`~aeid_struct.online.Tracker.reset`); its identifier's ``dt`` is the
        stream's.
    y : (N,) or (N, p) array_like
        The outputs (``(N, p)`` for an identifier of several channels: ``Tracker.width``).
    u : (N,) or (N, m) array_like
        The inputs.

    Returns
    -------
    WearResult
        ``true`` NaN (a measured stream has no truth), ``drift_time`` NaN and ``rms`` empty.

    Raises
    ------
    ValueError
        A stream shorter than one window, or samples ``tracker`` refuses.
    """
    y, u = np.asarray(y, dtype=np.float64), np.asarray(u, dtype=np.float64)
    if len(y) < tracker.steps or len(u) != len(y):
        raise ValueError(f"y and u must be streams of one length of at least one window "
                         f"({tracker.steps} samples); got {len(y)} and {len(u)}")
    updates, times = _track(tracker, u, y, tracker.config.hop)
    ts, est, smooth, drift, alarm, alarm_time = _series(updates)
    return WearResult(ts, {p: np.full(ts.size, math.nan) for p in est}, est, smooth, alarm,
                      math.nan, alarm_time, {}, 1e3 * float(np.median(times)), tracker.engine,
                      1e3 * float(np.percentile(times, 95)), tracker.config, drift=drift,
                      limit=tracker.limits)
