"""Online identification: a sliding-window tracker over a stream of (u, y) samples.

The paper's purpose is to identify a system during use, e.g. to follow the wear of a robot leg.
:class:`Tracker` keeps the last ``steps`` samples of a stream (the identifier's record format),
identifies every ``hop`` samples the window that just ended in one encoder pass, smooths the
physical-parameter estimates and raises a change alarm when they drift (the rules are in its
docstring).
"""

from __future__ import annotations

import copy
import dataclasses
import math
import statistics
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from aeid_struct.online.settings import DEFAULT_SMOOTHING as DEFAULT_SMOOTHING
from aeid_struct.online.settings import PushError as PushError
from aeid_struct.online.settings import TrackerConfig as TrackerConfig
from aeid_struct.online.settings import Update as Update
from aeid_struct.records import RecordError, as_array


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
    errors: list = field(default_factory=list)     # the baseline windows' standard errors
    limit: dict = field(default_factory=dict)      # each parameter's alarm limit
    over: int = 0
    alarm: bool = False


class Tracker:
    """Sliding-window identification of a stream.

    Parameters
    ----------
    identifier : identification.Identifies
        Any identifier of the protocol (``identify(record) -> Estimate``) with a record format
        (``steps``, ``dt``, ``initial``, ``records``) whose estimates have physical parameters
        (a physical structure, or a canonical one with a CasADi inverse), trained on windows
        that start mid-motion (``initial="fitted"``) and, for arbitrary inputs, reading ``u``:
        an ``Identifier`` on any back end (one read from an export runs its ONNX graph), or
        any other identifier of the protocol.
    config : TrackerConfig
        How the tracker windows, smooths and alarms; ``median`` and ``smoothing`` left None
        are set by the identifier's structure and head (:data:`DEFAULT_SMOOTHING`, at
        construction), and ``Tracker.config`` holds the values used.
    engine : str
        ``"auto"`` (default: the identifier's ONNX back end when onnxruntime is installed and
        it can be exported, else the identifier as given), ``"onnx"`` (its ONNX back end,
        ``Identifier.with_backend("onnx")``) or ``"identifier"`` (the identifier as given).

    Raises
    ------
    ValueError
        An identifier of the wrong kind (several records that are not channels of one,
        records from rest, parameters that ``config`` names and it never gives), or an
        unknown engine.

    Notes
    -----
    *Initial state.* A window cut from a running system does not start from rest. The
    identifier must therefore be one trained on such windows: ``TrainConfig(warmup=...,
    initial="fitted")``, whose decoder fits the window's initial state by linear least squares
    (``simulation.initial_state``), so that the encoder only has to output the structure's
    parameters.

    *Smoothing and alarm.* Each parameter ``p`` is first taken as the running median of its
    last ``TrackerConfig.median`` window estimates, ``q_j = median(p_{j-M+1}, .., p_j)``, then
    smoothed by an exponential moving average, ``s_j = s_{j-1} + alpha (q_j - s_{j-1})``
    (``alpha = TrackerConfig.smoothing``). The median because window estimates have heavy
    tails (a stretch of weakly exciting input puts several windows off together), which an
    average passes on and a median does not. The reference is the median of the first
    ``baseline`` window estimates (not of the smoothed values, still settling then); the alarm
    is raised once ``|s_j / reference - 1|`` exceeds the parameter's limit for ``patience``
    consecutive windows for any watched parameter, and stays raised (a change alarm, not a
    level indicator) until :meth:`reset`. The limit is ``threshold``, or for a physical
    structure ``sigmas`` standard errors of a baseline window where larger: a parameter the
    windows determine poorly (the drive train's shaft damping at 1 % noise) scatters more
    than any threshold that catches a drift of the well-determined ones.

    *Bad stretches of a stream.* A window that the identifier cannot identify (the checks of
    ``records.check_records``, the same for both engines: an input that is zero over the whole
    window, a varying input to a step identifier, ...) or whose estimate is not finite gives an
    :class:`Update` with ``error`` set and NaN estimates; it leaves the smoothing, the
    reference and the alarm as they were, and the stream goes on. Samples that are not finite
    (or not real) are refused by :meth:`push` before it consumes any of its chunk. Anything
    else that fails while a window is identified (the engine itself) raises a
    :class:`PushError` that says how many samples of the chunk were consumed.

    *Engine.* Every window walks one path, ``identify(window) -> Estimate`` and its
    ``physical`` parameters; the engine is the back end the identifier runs the encoder on.
    ``"onnx"`` is the identifier's ONNX back end on one thread (exported once, in memory, where
    the identifier holds its torch weights): onnxruntime's fused kernels run one window's
    encoder several times faster than the numpy pass (``aeid-struct bench-online``);
    ``"identifier"`` runs the identifier's own back end. Both give the same numbers to float32
    precision.

    *Head.* An identifier with a separable head (``Identifier.head``: Gauss-Newton iterations
    in its structure after the encoder, ``identification.head``) has it run on every window by
    both engines, after the encoder pass (the head the identifier had when the tracker was
    built); the update's time includes it.
    """

    def __init__(self, identifier, config: TrackerConfig = TrackerConfig(),  # noqa: B008
                 *, engine: str = "auto") -> None:
        if not isinstance(config, TrackerConfig):
            raise ValueError(f"config must be a TrackerConfig; got {type(config).__name__}")
        #: ``(output, input)`` per record of an identifier of several channels of one
        #: record (``Physical(mechanism, channels=...)``): the stream has several outputs and
        #: inputs, and each window is split by them; None for one output and one input.
        self.channels = _check_identifier(identifier, engine)
        _check_names(identifier, config)
        self.identifier, self.config = identifier, config
        self.steps = identifier.steps if self.channels is None else identifier.steps[0]
        self.dt = identifier.dt if self.channels is None else identifier.dt[0]
        #: ``(p, m)``: the stream's outputs and inputs.
        self.width = (1, 1) if self.channels is None else (
            1 + max(o for o, _ in self.channels), 1 + max(i for _, i in self.channels))
        runner = identifier if engine == "identifier" else _onnx_engine(
            identifier, required=engine == "onnx")
        #: ``"onnx"`` where the windows run an ONNX back end, else ``"identifier"``.
        self.engine = "onnx" if _backend_name(runner) == "onnx" else "identifier"
        cap = _cap(config.iterations, identifier)
        if cap is not None:
            runner = _capped(runner, cap)
        #: Whether the baseline windows' standard errors set the alarm's limits (a physical
        #: structure, ``TrackerConfig.sigmas > 0``).
        self._uses_errors = config.sigmas > 0 and _physical(identifier)
        #: The identifier every window goes through (``identifier`` on the engine's back end).
        self.runner = runner
        self.config = _resolved(config, runner)
        self.reset()

    @property
    def limits(self) -> dict[str, float]:
        """Each parameter's alarm limit, the relative drift beyond which it counts toward the
        alarm (``Update.limit``; empty until the baseline is complete)."""
        return dict(self._s.limit)

    def reset(self) -> None:
        """Forget the stream, the smoothing, the reference and the alarm."""
        if self.channels is None:
            self._s = _State(np.zeros(self.steps), np.zeros(self.steps))
        else:
            p, m = self.width
            self._s = _State(np.zeros((self.steps, m)), np.zeros((self.steps, p)))

    def push(self, u, y) -> list[Update]:
        """Deprecated: :meth:`feed` ``(y, u)``, the order every other call of the library uses.

        Parameters
        ----------
        u, y : (k,) array_like

        Returns
        -------
        list of Update
        """
        warnings.warn("Tracker.push(u, y) is deprecated: call Tracker.feed(y, u) (outputs first, "
                      "as everywhere else in aeid_struct)", DeprecationWarning, stacklevel=2)
        return self.feed(y, u)

    def feed(self, y, u) -> list[Update]:
        """Feed samples of the stream, in order.

        Parameters
        ----------
        y, u : (k,) array_like
            Any number of output and input samples; ``(k, p)`` and ``(k, m)`` for an
            identifier of several channels (:attr:`width`).

        Returns
        -------
        list of Update
            The updates of the windows completed by these samples (one per ``hop`` samples once
            the first window is full), windows that could not be identified included
            (``Update.error``).

        Raises
        ------
        ValueError
            ``u, y`` not 1-D real arrays of one length, or not finite; nothing of the chunk is
            consumed.
        PushError
            The engine failed on a window; ``consumed`` and ``updates`` say how far the chunk
            went.
        """
        u = np.atleast_1d(as_array("u", u))
        y = np.atleast_1d(as_array("y", y))
        if self.channels is not None:
            u, y = _columns(u, y, self.width, self.channels)
        elif u.ndim != 1 or u.shape != y.shape:
            raise ValueError(f"u and y must be 1-D sample arrays of one length; got shapes "
                             f"{u.shape} and {y.shape}")
        for name, v in (("u", u), ("y", y)):
            if not np.all(np.isfinite(v)):
                rows = v.reshape(len(v), -1)
                bad = ~np.isfinite(rows)
                k = int(np.flatnonzero(bad.any(axis=1))[0])
                raise ValueError(f"u and y must be finite; got {rows[k][bad[k]][0]} in {name} "
                                 f"at sample {k} of the chunk (no sample of it was consumed)")
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

    def _estimate(self) -> tuple:
        """The estimate of the current window and the wall time it took."""
        s = self._s
        t0 = time.perf_counter()
        if self.channels is None:
            out = self.runner.identify(s.y, s.u)
        else:
            out = self.runner.identify(tuple(s.y[:, o] for o, _ in self.channels),
                                       tuple(s.u[:, i] for _, i in self.channels))
        return out, time.perf_counter() - t0

    def _identify(self) -> Update:
        s, cfg = self._s, self.config
        t0 = time.perf_counter()
        try:
            est, seconds = self._estimate()
        except RecordError as err:   # the identifier's own check refused the window
            return self._skipped(str(err), time.perf_counter() - t0)
        physical = est.physical or {}
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
        errors = _errors(est, values) if self._uses_errors and s.reference is None else None
        drift = _advance(s, cfg, values, errors)
        return Update(s.samples * self.dt - self.dt, values, dict(s.smoothed), drift, s.alarm,
                      seconds, limit=dict(s.limit))

    def _skipped(self, reason: str, seconds: float) -> Update:
        """The update of a window that could not be identified: NaN estimates, the state as it
        was (module docstring)."""
        s, cfg = self._s, self.config
        names = list(s.smoothed) or list(cfg.parameters)
        drift = {k: (s.smoothed[k] / s.reference[k] - 1.0 if s.reference is not None
                     else math.nan) for k in s.smoothed}
        return Update(s.samples * self.dt - self.dt, {k: math.nan for k in names},
                      dict(s.smoothed), drift, s.alarm, seconds, error=reason,
                      limit=dict(s.limit))


def _check_identifier(identifier, engine: str):
    """``Tracker``'s identifier and engine checked; the identifier's channels (or None)."""
    for attr in ("identify", "steps", "dt", "initial", "records"):
        if not hasattr(identifier, attr):
            raise ValueError(f"identifier must answer identify(record) -> Estimate with a "
                             f"record format (steps, dt, initial, records), as an Identifier "
                             f"does; got {type(identifier).__name__} (no {attr!r})")
    if engine not in ("auto", "onnx", "identifier"):
        raise ValueError(f"engine must be 'auto', 'onnx' or 'identifier'; got {engine!r}")
    channels = getattr(getattr(identifier, "structure", None), "channels", None)
    if identifier.records != 1 and channels is None:
        raise ValueError("identifier must read one record per window (or several channels of "
                         f"one, Physical(..., channels=...)); got one of {identifier.records} "
                         "records")
    if identifier.initial != "fitted":
        raise ValueError("identifier must be trained on windows that start mid-motion "
                         "(TrainConfig(warmup=..., initial='fitted')); this one assumes "
                         "records from rest")
    return channels


def _columns(u: np.ndarray, y: np.ndarray, width: tuple, channels) -> tuple:
    """``u (k, m)`` and ``y (k, p)`` of a chunk of a several-channel stream, checked
    (``width = (p, m)``)."""
    p, m = width
    u = u.reshape(-1, 1) if u.ndim == 1 and m == 1 else u
    y = y.reshape(-1, 1) if y.ndim == 1 and p == 1 else y
    if u.ndim != 2 or y.ndim != 2 or u.shape != (len(y), m) or y.shape[1] != p:
        raise ValueError(f"y and u must be (k, {p}) and (k, {m}) sample arrays of one length "
                         f"(the channels {list(channels)}); got shapes {y.shape} and {u.shape}")
    return u, y


def _errors(est, values: dict) -> dict:
    """The standard errors of a window's parameters ``values`` (NaN where they cannot be had:
    a rank-deficient Jacobian, or a failure, which must not stop the stream)."""
    from aeid_struct.identification import with_standard_errors

    try:
        std = with_standard_errors(est).info.get("std", {})
    except (ValueError, RuntimeError, np.linalg.LinAlgError):
        std = {}                 # no errors from this window: the limit is the others'
    return {k: abs(float(std.get(k, math.nan))) for k in values}


def _advance(s: _State, cfg: TrackerConfig, values: dict, errors: dict | None) -> dict:
    """The stream's state after one window's estimate ``values`` (and, in the baseline, its
    standard errors ``errors``): the running median and moving average, the reference and
    the limits once the baseline is full, the alarm (``Tracker``'s rule); the drift per
    parameter (NaN before the reference)."""
    s.history.append(dict(values))
    if errors is not None:
        s.errors.append(errors)
    recent = s.history[-cfg.median:]
    for k in values:
        # statistics.median: 2 us on 9 numbers against 22 us for np.median (a tenth of an
        # update, per parameter)
        v = statistics.median([h[k] for h in recent]) if cfg.median > 1 else values[k]
        prev = s.smoothed.get(k)
        s.smoothed[k] = v if prev is None or not math.isfinite(prev) \
            else prev + cfg.smoothing * (v - prev)
    if s.reference is None and len(s.history) >= cfg.baseline:
        s.reference = {k: float(np.median([h[k] for h in s.history[: cfg.baseline]]))
                       for k in values}
        s.limit = {k: _limit(cfg, s.reference[k], [e[k] for e in s.errors]) for k in values}
    if s.reference is None:
        return {k: math.nan for k in values}
    if len(s.history) > cfg.median:
        del s.history[: -cfg.median]           # a stream may run for days: keep what is used
    drift = {k: s.smoothed[k] / s.reference[k] - 1.0 for k in values}
    watched = [k for k in drift if not cfg.watch or k in cfg.watch]
    s.over = s.over + 1 if any(abs(drift[k]) > s.limit[k] for k in watched) else 0
    s.alarm = s.alarm or s.over >= cfg.patience
    return drift


def _physical(identifier) -> bool:
    """Whether ``identifier``'s structure is physical (its head iterates in the parameters,
    its estimates carry standard errors); read by the structure's type name, so that an
    identifier known by its description answers too."""
    from aeid_struct.structures import type_of

    return type_of(getattr(identifier, "structure", None)) == "Physical"


def _cap(iterations, identifier) -> int | None:
    """``TrackerConfig.iterations`` resolved for ``identifier``: ``"auto"`` by its structure
    (its docstring), else as given."""
    if iterations == "auto":
        return None if _physical(identifier) else 1
    return iterations


def _limit(config: TrackerConfig, reference: float, errors: list) -> float:
    """A parameter's alarm limit: ``max(threshold, sigmas * e / |reference|)``, ``e`` the
    median of its finite standard errors over the baseline windows (the threshold alone
    where there are none)."""
    finite = [e for e in errors if math.isfinite(e)]
    if not finite or reference == 0:
        return config.threshold
    return max(config.threshold, config.sigmas * statistics.median(finite) / abs(reference))


def _capped(engine, iterations: int):
    """``engine`` (an identifier), or a shallow copy of it whose separable head iterates at
    most ``iterations`` times: the caller's object is not changed."""
    head = getattr(engine, "head", None)
    if head is None or head.iterations <= iterations:
        return engine
    from aeid_struct.identification import Head

    capped = copy.copy(engine)
    capped.head = Head(iterations=iterations, fixed=head.fixed)
    return capped


def _resolved(config: TrackerConfig, engine) -> TrackerConfig:
    """``config`` with ``median`` and ``smoothing`` set where None, by whether ``engine`` (the
    identifier on the tracker's back end) has a physical structure, or a separable head that
    iterates (:data:`DEFAULT_SMOOTHING`)."""
    head = getattr(engine, "head", None)
    median, smoothing = DEFAULT_SMOOTHING[
        "physical" if _physical(engine) else
        "head" if head is not None and head.iterations >= 1 else "encoder"]
    return dataclasses.replace(
        config, median=median if config.median is None else config.median,
        smoothing=smoothing if config.smoothing is None else config.smoothing)


def _physical_names(identifier) -> tuple[str, ...] | None:
    """The physical parameters the identifier's estimates carry (an inverse map's outputs, or a
    Physical structure's elements), or None where that cannot be told without identifying."""
    from aeid_struct.identification import inverse_names

    source = identifier.provenance.inverse if hasattr(identifier, "provenance") else None
    if isinstance(source, tuple):
        return tuple(source[1])
    return inverse_names(source)


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


def _backend_name(identifier) -> str | None:
    """The name of an identifier's back end (``Identifier.backend``), or None for one
    without back ends."""
    return getattr(getattr(identifier, "backend", None), "name", None)


def _onnx_engine(identifier, required: bool):
    """``identifier`` on its ONNX back end (``Identifier.with_backend``), or ``identifier``
    itself where it runs one already, or (unless ``required``) where onnxruntime is missing or
    it cannot be exported (a Physical structure, an identifier without back ends)."""
    name = _backend_name(identifier)
    if name == "onnx":
        return identifier
    if name is None:
        if required:
            raise ValueError("engine='onnx' needs an Identifier to export; got "
                             f"{type(identifier).__name__}")
        return identifier
    try:
        return identifier.with_backend("onnx")
    except ValueError:
        if required:
            raise
        return identifier
