"""Online identification: a sliding-window tracker over a stream of (u, y) samples.

The paper's purpose is to identify a system during use, e.g. to follow the wear of a robot leg.
:class:`Tracker` keeps the last ``steps`` samples of a stream (the identifier's record format),
identifies every ``hop`` samples the window that just ended in one encoder pass, smooths the
physical-parameter estimates and raises a change alarm when they drift.

Initial state. A window cut from a running system does not start from rest. The identifier must
therefore be one trained on such windows: ``TrainConfig(warmup=..., initial="fitted")``, whose
decoder fits the window's initial state by linear least squares (``decoder.initial_state``), so
that the encoder only has to output the structure's parameters. The tracker never needs the
state itself (its estimates' ``x0`` is there when asked for).

Smoothing and alarm. Each parameter ``p`` is first taken as the running median of its last
``TrackerConfig.median`` window estimates, ``q_j = median(p_{j-M+1}, .., p_j)`` (M = 1: the
estimate itself), then smoothed by an exponential moving average,
``s_j = s_{j-1} + alpha (q_j - s_{j-1})`` (``alpha = TrackerConfig.smoothing``). Why the median:
the window estimates have heavy tails (a stretch of weakly exciting input puts several windows
off together), which an average passes on and a median does not. The reference
is the median of the first ``baseline`` window estimates (not of the smoothed values, which
are still settling from the first estimate then); the alarm is raised once
``|s_j / reference - 1| > threshold`` holds for ``patience`` consecutive windows for any
parameter, and stays raised (a change alarm, not a level indicator) until :meth:`Tracker.reset`.

Bad stretches of a stream. A window that the identifier cannot identify -- the checks of
``records.check_records``, the same for both engines: an input that is zero over the whole window
(a leg at rest), a varying input to a step identifier, ... -- or whose estimate is not finite
gives an :class:`Update` with ``error`` set (its reason) and NaN estimates; it leaves the
smoothing, the reference and the alarm as they were, and the stream goes on: every sample of a
chunk is consumed. Samples that are not finite (or not real) are refused by ``push`` before it
consumes any of its chunk. Anything else that fails while a window is identified (the engine
itself) raises a :class:`PushError` that says how many samples of the chunk were consumed
(``consumed``) and carries the updates produced before it (``updates``): push the rest,
``u[consumed:]``, to go on.

Engine. ``Tracker(engine="onnx")`` exports the identifier once to ONNX (``export.onnx_bytes``)
and identifies each window with onnxruntime on one thread, then maps the model to physical
parameters with the identifier's CasADi inverse; ``engine="identifier"`` calls
``Identifier.identify`` (numpy encoder, a full ``Estimate``); ``"auto"`` (default) takes onnx
when onnxruntime is installed. Same numbers to float32 precision; the update times of both
are in ``pretrained/README.md``.
"""

from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass, field

import numpy as np

from aeid_struct.records import RecordError, as_array


@dataclass(frozen=True, kw_only=True)
class TrackerConfig:
    """How the tracker windows, smooths and alarms; validates itself.

    Attributes:
        hop: samples between two identifications (window starts), >= 1.
        smoothing: the moving-average weight ``alpha`` in (0, 1] (1 = no smoothing).
        median: window estimates in the running median taken before the moving average
            (1 = none).
        threshold: relative drift of a smoothed parameter from its reference that alarms.
        baseline: windows whose estimates' median is the reference.
        patience: consecutive windows over the threshold before the alarm is raised.
        parameters: the physical parameters to track (empty: all the estimate has).
        watch: those of them whose drift raises the alarm (empty: all tracked ones).
    """

    hop: int = 50
    smoothing: float = 0.3
    median: int = 9
    threshold: float = 0.05
    baseline: int = 10
    patience: int = 3
    parameters: tuple[str, ...] = ()
    watch: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in ("hop", "median", "baseline", "patience"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name} must be a positive integer; got {v!r}")
        def number(v) -> bool:
            return isinstance(v, (int, float)) and not isinstance(v, bool)

        if not (number(self.smoothing) and 0 < self.smoothing <= 1):
            raise ValueError(f"smoothing must be in (0, 1]; got {self.smoothing!r}")
        if not (number(self.threshold) and math.isfinite(self.threshold)
                and self.threshold > 0):
            raise ValueError(f"threshold must be a finite number > 0; got {self.threshold!r}")
        for name in ("parameters", "watch"):
            v = getattr(self, name)
            # a string is a sequence of letters: parameters="kd" would track 'k' and 'd'
            if isinstance(v, str) or not isinstance(v, (tuple, list)) \
                    or not all(isinstance(p, str) and p for p in v):
                raise ValueError(f"{name} must be a tuple of parameter names; got {v!r}")
            object.__setattr__(self, name, tuple(v))
        stray = [p for p in self.watch if self.parameters and p not in self.parameters]
        if stray:
            raise ValueError(f"watch must name tracked parameters {self.parameters}; got {stray}")


@dataclass(frozen=True)
class Update:
    """One identified window.

    Attributes:
        t: time of the window's last sample, s (stream time, ``k dt``).
        estimate: the physical parameters of this window alone, name -> value.
        smoothed: their moving averages.
        drift: ``smoothed / reference - 1`` per parameter (nan until the reference exists).
        alarm: whether the change alarm is raised (it stays raised).
        seconds: wall time of the identification.
        error: None for an identified window; else why it could not be identified (the
            message of the identifier's check, or a non-finite estimate): then ``estimate``
            holds NaN for each tracked parameter known so far, and ``smoothed``, ``drift``,
            ``alarm`` are the tracker's state, unchanged by this window.
    """

    t: float
    estimate: dict[str, float]
    smoothed: dict[str, float]
    drift: dict[str, float]
    alarm: bool
    seconds: float
    error: str | None = None


class PushError(ValueError):
    """A failure of the engine while ``Tracker.push`` identified a window (module docstring).

    Attributes:
        consumed: samples of the chunk taken into the stream, the failed window's last one
            included; the stream goes on with ``u[consumed:], y[consumed:]``.
        updates: the updates of the windows completed before the failure.
    """

    def __init__(self, message: str, consumed: int, updates: list) -> None:
        super().__init__(message)
        self.consumed = consumed
        self.updates = updates


@dataclass
class _State:
    u: np.ndarray
    y: np.ndarray
    filled: int = 0
    since: int = 0
    samples: int = 0
    smoothed: dict = field(default_factory=dict)
    history: list = field(default_factory=list)
    reference: dict | None = None
    over: int = 0
    alarm: bool = False


class Tracker:
    """Sliding-window identification of a stream (module docstring).

    Args:
        identifier: an ``Identifier`` whose estimates have physical parameters (a physical
            structure, or a canonical one with a CasADi inverse), trained on windows that start
            mid-motion (``initial="fitted"``) and, for arbitrary inputs, reading ``u``.
            An ``export.OnnxIdentifier`` works too (then the engine is that file).
        config: a :class:`TrackerConfig`.
        engine: ``"auto"``, ``"onnx"`` or ``"identifier"`` (module docstring).
    """

    def __init__(self, identifier, config: TrackerConfig = TrackerConfig(),  # noqa: B008
                 *, engine: str = "auto") -> None:
        from aeid_struct.identification import Identifier
        from aeid_struct.online.export import OnnxIdentifier

        if not isinstance(config, TrackerConfig):
            raise ValueError(f"config must be a TrackerConfig; got {type(config).__name__}")
        if not isinstance(identifier, OnnxIdentifier):
            for attr in ("identify", "steps", "dt", "initial", "records"):
                if not hasattr(identifier, attr):
                    raise ValueError(f"identifier must be an Identifier or an OnnxIdentifier; "
                                     f"got {type(identifier).__name__}")
        if engine not in ("auto", "onnx", "identifier"):
            raise ValueError(f"engine must be 'auto', 'onnx' or 'identifier'; got {engine!r}")
        if identifier.records != 1:
            raise ValueError("identifier must read one record per window; got one of "
                             f"{identifier.records} records")
        if identifier.initial != "fitted":
            raise ValueError("identifier must be trained on windows that start mid-motion "
                             "(TrainConfig(warmup=..., initial='fitted')); this one assumes "
                             "records from rest")
        _check_names(identifier, config)
        self.identifier, self.config = identifier, config
        self.steps, self.dt = identifier.steps, identifier.dt
        self.runner = identifier if isinstance(identifier, OnnxIdentifier) else None
        if self.runner is None and engine != "identifier":
            if isinstance(identifier, Identifier):
                self.runner = _onnx_runner(identifier, required=engine == "onnx")
            elif engine == "onnx":
                raise ValueError("engine='onnx' needs an Identifier to export; got "
                                 f"{type(identifier).__name__}")
        self.engine = "identifier" if self.runner is None else "onnx"
        self.reset()

    def reset(self) -> None:
        """Forget the stream, the smoothing, the reference and the alarm."""
        self._s = _State(np.zeros(self.steps), np.zeros(self.steps))

    def push(self, u, y) -> list[Update]:
        """Feed samples ``u, y (k,)`` (any number, in stream order); returns the updates of the
        windows completed by them (one per ``hop`` samples once the first window is full),
        including windows that could not be identified (``Update.error``).

        Raises:
            ValueError: ``u, y`` not 1-D real arrays of one length, or not finite; nothing of
                the chunk is consumed.
            PushError: the engine failed on a window; ``consumed`` and ``updates`` say how far
                the chunk went (module docstring).
        """
        u = np.atleast_1d(as_array("u", u))
        y = np.atleast_1d(as_array("y", y))
        if u.ndim != 1 or u.shape != y.shape:
            raise ValueError(f"u and y must be 1-D sample arrays of one length; got shapes "
                             f"{u.shape} and {y.shape}")
        for name, v in (("u", u), ("y", y)):
            if not np.all(np.isfinite(v)):
                k = int(np.flatnonzero(~np.isfinite(v))[0])
                raise ValueError(f"u and y must be finite; got {v[k]} in {name} at sample {k} "
                                 "of the chunk (no sample of it was consumed)")
        s, steps, hop = self._s, self.steps, self.config.hop
        updates = []
        i = 0
        while i < len(u):
            # copy up to the next identification point into the ring (kept in order: shift)
            need = steps - s.filled if s.filled < steps else hop - s.since
            take = min(need, len(u) - i)
            s.u = np.concatenate([s.u[take:], u[i: i + take]])
            s.y = np.concatenate([s.y[take:], y[i: i + take]])
            s.samples += take
            i += take
            if s.filled < steps:
                s.filled += take
                due = s.filled == steps
            else:
                s.since += take
                due = s.since == hop
                if due:
                    s.since = 0
            if due:
                try:
                    updates.append(self._identify())
                except Exception as err:
                    raise PushError(f"{err} (the window ending at sample {i - 1} of this chunk "
                                    f"failed: {i} of its {len(u)} samples were consumed, "
                                    f"{len(updates)} update(s) before it; see "
                                    "PushError.consumed and .updates)", i, updates) from err
        return updates

    def _physical(self) -> tuple[dict, float]:
        """The physical parameters of the current window and the wall time it took."""
        s = self._s
        if self.runner is not None:
            t0 = time.perf_counter()
            out = self.runner.physical(self.runner(s.y, s.u))
            return out, time.perf_counter() - t0
        est = self.identifier.identify(s.y, s.u)
        t0 = time.perf_counter()
        out = est.physical
        return out, est.seconds + time.perf_counter() - t0

    def _identify(self) -> Update:
        s, cfg = self._s, self.config
        t0 = time.perf_counter()
        try:
            physical, seconds = self._physical()
        except RecordError as err:   # the identifier's own check refused the window
            return self._skipped(str(err), time.perf_counter() - t0)
        values = {k: float(v) for k, v in physical.items()
                  if not cfg.parameters or k in cfg.parameters}
        if not values:
            raise ValueError("identifier must give physical parameters (a physical structure, or "
                             "an inverse map); its estimates have none"
                             + (f" named {cfg.parameters}" if cfg.parameters else ""))
        bad = [k for k, v in values.items() if not math.isfinite(v)]
        if bad:
            return self._skipped("the window's estimate is not finite: "
                                 + ", ".join(f"{k} = {values[k]}" for k in bad), seconds)
        s.history.append(dict(values))
        recent = s.history[-cfg.median:]
        for k in values:
            # statistics.median: 2 us on 9 numbers against 22 us for np.median (a tenth of
            # an update, per parameter)
            v = statistics.median([h[k] for h in recent]) if cfg.median > 1 else values[k]
            prev = s.smoothed.get(k)
            s.smoothed[k] = v if prev is None or not math.isfinite(prev) \
                else prev + cfg.smoothing * (v - prev)
        drift = {k: math.nan for k in values}
        if s.reference is None and len(s.history) >= cfg.baseline:
            s.reference = {k: float(np.median([h[k] for h in s.history[: cfg.baseline]]))
                           for k in values}
        if s.reference is not None and len(s.history) > cfg.median:
            del s.history[: -cfg.median]       # a stream may run for days: keep what is used
        if s.reference is not None:
            drift = {k: s.smoothed[k] / s.reference[k] - 1.0 for k in values}
            watched = [v for k, v in drift.items() if not cfg.watch or k in cfg.watch]
            s.over = s.over + 1 if any(abs(v) > cfg.threshold for v in watched) else 0
            s.alarm = s.alarm or s.over >= cfg.patience
        return Update(s.samples * self.dt - self.dt, values, dict(s.smoothed), drift, s.alarm,
                      seconds)

    def _skipped(self, reason: str, seconds: float) -> Update:
        """The update of a window that could not be identified: NaN estimates, the state as it
        was (module docstring)."""
        s, cfg = self._s, self.config
        names = list(s.smoothed) or list(cfg.parameters)
        drift = {k: (s.smoothed[k] / s.reference[k] - 1.0 if s.reference is not None
                     else math.nan) for k in s.smoothed}
        return Update(s.samples * self.dt - self.dt, {k: math.nan for k in names},
                      dict(s.smoothed), drift, s.alarm, seconds, error=reason)


def _physical_names(identifier) -> tuple[str, ...] | None:
    """The physical parameters the identifier's estimates carry (an inverse map's outputs, or a
    Physical structure's elements), or None where that cannot be told without identifying."""
    from aeid_struct.online.export import OnnxIdentifier

    if isinstance(identifier, OnnxIdentifier):
        if identifier._physical_elements:
            return tuple(identifier._physical_elements)
        inverse = identifier._inverse
    else:
        source = identifier._physical_source() if hasattr(identifier, "_physical_source") \
            else None
        if isinstance(source, tuple):
            return tuple(source[1])
        inverse = source
    if inverse is None:
        return ()
    try:
        return tuple(inverse.name_out())
    except AttributeError:
        return None


def _check_names(identifier, config: TrackerConfig) -> None:
    """``config.parameters`` and ``config.watch`` must name parameters the identifier gives:
    a watched name it never gives would never raise the alarm, silently."""
    names = _physical_names(identifier)
    if not names:
        return      # none at all: the first window says so (Tracker._identify)
    for field_name in ("parameters", "watch"):
        stray = [p for p in getattr(config, field_name) if p not in names]
        if stray:
            raise ValueError(f"config.{field_name} must name physical parameters of the "
                             f"identifier ({', '.join(names)}); got {stray}")


def _onnx_runner(identifier, required: bool):
    """An ``OnnxIdentifier`` of ``identifier`` (None where onnxruntime is missing and not
    ``required``, or the identifier cannot be exported: a Physical structure)."""
    try:
        import onnxruntime  # noqa: F401
    except ImportError:
        if required:
            raise ValueError("engine='onnx' needs onnxruntime: pip install "
                             "\"aeid-struct[onnx]\"") from None
        return None
    from aeid_struct.online.export import OnnxIdentifier, onnx_bytes

    inverse = identifier.inverse       # the caller's own map, passed again (aeid_struct.maps)
    try:
        return OnnxIdentifier(onnx_bytes(identifier),
                              maps=None if inverse is None else {inverse.name(): inverse})
    except ValueError:
        if required:
            raise
        return None


def wearing_leg(k, d, m, u, dt: float) -> np.ndarray:
    """The translational leg subsystem with slowly varying parameters: the response ``y (N,)``
    to ``u (N,)`` from rest, for ``k, d, m (N,)`` given per sample.

    Simulated in the physical state (position, velocity) ``m x'' + d x' + k x = u``, ``y = x``,
    which stays continuous when the parameters change (a CCF state would not: its output row is
    ``1/m``). On each sample interval the parameters are held at their value at its start and
    the input is first-order-hold, discretised exactly (Eq. 10). For constant parameters this
    is ``G1 = (1/m) / (s^2 + (d/m) s + k/m)`` from rest, as ``simulate`` gives it.
    """
    import torch

    from aeid_struct.simulation.foh import _discretise

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
    Phi, g1, g2 = (t.numpy() for t in _discretise(torch.from_numpy(A), torch.from_numpy(b), dt))
    # A loop over the samples: the parameters change every sample, and the decoder's log-depth
    # scan needs one transition matrix for the whole record. 12,000 samples take ~40 ms.
    x = np.zeros(2)
    y = np.empty(N)
    du = np.diff(u, append=u[-1])
    for i in range(N):
        y[i] = x[0]
        x = Phi[i] @ x + g1[i] * u[i] + g2[i] * du[i]
    return y


@dataclass(frozen=True)
class WearResult:
    """A tracked wear scenario (:func:`wear_study`).

    Attributes:
        t: ``(W,)`` time of each window's last sample, s.
        true: name -> ``(W,)`` true parameter at the middle of each window.
        estimate, smoothed: name -> ``(W,)`` the tracker's raw and smoothed estimates.
        alarm: ``(W,)`` bool, the tracker's alarm after each window.
        drift_time: when the true k first left its start value by more than the tracker's
            threshold, s; alarm_time: when the alarm was first raised (nan if never).
        rms: name -> RMS relative error (%) of the smoothed estimate after the baseline windows.
        latency_ms: median wall time of one tracker update (one window identified, smoothed
            and checked), as ``Tracker.push`` takes it.
        engine: the tracker's engine (``"onnx"`` or ``"identifier"``).
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

    @property
    def delay(self) -> float:
        """Alarm delay after the true drift crossed the threshold, s (nan without an alarm)."""
        return self.alarm_time - self.drift_time


def wear_study(identifier, *, seconds: float = 120.0, noise: float = 0.01, seed: int = 0,
               config: TrackerConfig = TrackerConfig(),  # noqa: B008
               engine: str = "auto") -> WearResult:
    """A running leg that wears, tracked window by window.

    Scenario: the translational subsystem driven by a random binary force (levels +-1 held
    3-12 samples) for ``seconds``, already running when tracking starts (the force has acted for
    one window length before ``t = 0``: a running leg is not at rest); k stays at 25 N/m for
    the first quarter, falls linearly to 20 N/m until three quarters of the time and stays
    there; d rises from 2.5 to 3.5 kg/s over the same span; m = 1 kg. White measurement noise
    of ``noise * max|y|``. The samples are pushed to a :class:`Tracker` in chunks of one hop,
    as a controller would.
    """
    import time as _time

    import torch

    if not seconds > 0:
        raise ValueError(f"seconds must be positive; got {seconds!r}")
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
    tracker = Tracker(identifier, config, engine=engine)
    updates, times = [], []
    # One core, as on a robot's processor: torch's other threads (idle-spinning after the
    # simulation above) would otherwise compete with the tracker for the second core of a
    # two-core machine (measured: 0.24-0.52 ms per update against 0.16-0.34 ms).
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for i in range(0, N, config.hop):
            t0 = _time.perf_counter()
            got = tracker.push(u[i: i + config.hop], y[i: i + config.hop])
            if got:
                times.append((_time.perf_counter() - t0) / len(got))
            updates += got
    finally:
        torch.set_num_threads(threads)
    if not updates:
        raise ValueError(f"seconds must cover at least one window of {identifier.steps} samples")
    ts = np.array([up.t for up in updates])
    mid = np.clip(np.round((ts - (identifier.steps - 1) * dt / 2) / dt).astype(int), 0, N - 1)
    names = list(updates[0].estimate)
    truth = {"k": k, "d": d, "m": m}
    true = {p: truth[p][mid] for p in names if p in truth}
    est = {p: np.array([up.estimate[p] for up in updates]) for p in names}
    smooth = {p: np.array([up.smoothed[p] for up in updates]) for p in names}
    alarm = np.array([up.alarm for up in updates])
    crossed = np.flatnonzero(np.abs(k / k[0] - 1) > config.threshold)
    drift_time = float(t[crossed[0]]) if crossed.size else math.nan
    alarm_time = float(ts[np.argmax(alarm)]) if alarm.any() else math.nan
    after = slice(config.baseline, None)
    rms = {p: float(100 * np.sqrt(np.mean((smooth[p][after] / true[p][after] - 1) ** 2)))
           for p in true}
    return WearResult(ts, true, est, smooth, alarm, drift_time, alarm_time, rms,
                      1e3 * float(np.median(times)), tracker.engine)
