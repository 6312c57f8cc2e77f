"""What a :class:`~aeid_struct.online.Tracker` is told and what it answers: its configuration
(:class:`TrackerConfig`, with the smoothing defaults by identifier), one identified window
(:class:`Update`) and a failure mid-chunk (:class:`PushError`). Cut from the tracker at this
seam: these are the values a user builds and reads; the tracker's module is the stream's
state machine.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["DEFAULT_SMOOTHING", "PushError", "TrackerConfig", "Update"]

#: ``(median, smoothing)`` where :class:`TrackerConfig` leaves them None, for an identifier
#: without and with a separable head that iterates (``Identifier.head``, ``iterations >= 1``):
#: the iterated head's window estimates scatter far less, so a shorter median and a lighter
#: average follow the parameter with less lag, while the encoder's estimates (and those of a
#: projection-only head) need the heavier smoothing; chosen on the wear scenario of
#: ``studies.wear`` and checked on other seeds. A physical structure's (``"physical"``) gets
#: the heavier smoothing although its head iterates: a mechanism's parameters can be
#: ill-conditioned in a window (the drive train's inertias and shaft damping), and then even
#: the least-squares optimum of each window scatters as the encoder's estimates do; with the
#: lighter smoothing a stationary drive-train stream at 1-5 % noise raised false alarms.
DEFAULT_SMOOTHING = {"encoder": (9, 0.3), "head": (3, 0.7), "physical": (9, 0.3)}


@dataclass(frozen=True, kw_only=True)
class TrackerConfig:
    """How the tracker windows, smooths and alarms; validates itself.

    Attributes
    ----------
    hop : int
        Samples between two identifications (window starts), >= 1.
    smoothing : float or None
        The moving-average weight ``alpha`` in (0, 1] (1 = no smoothing); None: by the
        identifier (:data:`DEFAULT_SMOOTHING`, resolved by ``Tracker``).
    median : int or None
        Window estimates in the running median taken before the moving average (1 = none);
        None: by the identifier, as ``smoothing``.
    threshold : float
        Relative drift of a smoothed parameter from its reference that alarms, > 0.
    baseline : int
        Windows whose estimates' median is the reference.
    patience : int
        Consecutive windows over the threshold before the alarm is raised.
    parameters : tuple of str
        The physical parameters to track (empty: all the estimate has).
    watch : tuple of str
        Those of them whose drift raises the alarm (empty: all tracked ones).
    iterations : int, None or "auto"
        At most this many Gauss-Newton iterations of the identifier's head per window (>= 0;
        the tracker runs a copy of the identifier with the head capped); None: the head as the
        identifier has it. ``"auto"`` (the default): 1 for a canonical structure's separable
        head, whose encoder starts close to the least-squares optimum on the identifier's own
        kind of record, so that the update keeps within its time budget (more iterations
        barely move the tracked estimates: ``aeid-struct bench-online``); the head as it is
        for a physical structure, whose encoder lands some tens of percent from the
        parameters and whose head (``identification.physical_head``) closes that gap only in
        all its iterations (capped at one, noise-free windows of the drive train scatter by
        tens of percent).
    sigmas : float
        A drift counts toward the alarm only beyond this many standard errors of a window's
        parameters (>= 0): each parameter's limit is ``max(threshold, sigmas * e / |r|)``
        with ``r`` its reference and ``e`` the median of its standard errors over the
        baseline windows (``sqrt(diag(s^2 (J^T J)^-1))`` at the window's estimate, as
        ``greyest`` gives them: ``identification.physical_errors``), so that a parameter a
        window determines poorly does not raise the alarm on its scatter. Six, not the three
        of a Gaussian rule: an ill-conditioned window's cost is far from quadratic, and its
        optimum moves between windows by several of its linearised standard errors (the
        drive train's inertias and shaft damping at 1-5 % noise). Only for a physical
        structure (a canonical one's estimates carry no standard errors); 0: the threshold
        alone.

    Raises
    ------
    ValueError
        A field of the wrong type or out of its range, named.
    """

    hop: int = 50
    smoothing: float | None = None
    median: int | None = None
    threshold: float = 0.05
    baseline: int = 10
    patience: int = 3
    parameters: tuple[str, ...] = ()
    watch: tuple[str, ...] = ()
    iterations: int | None | str = "auto"
    sigmas: float = 6.0

    def __post_init__(self) -> None:
        for name in ("hop", "median", "baseline", "patience"):
            v = getattr(self, name)
            if name == "median" and v is None:
                continue
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name} must be a positive integer; got {v!r}")
        if self.iterations is not None and self.iterations != "auto" and (
                not isinstance(self.iterations, int) or isinstance(self.iterations, bool)
                or self.iterations < 0):
            raise ValueError(f"iterations must be None, 'auto' or an integer >= 0; got "
                             f"{self.iterations!r}")

        def number(v) -> bool:
            return isinstance(v, (int, float)) and not isinstance(v, bool)

        if self.smoothing is not None and not (number(self.smoothing)
                                               and 0 < self.smoothing <= 1):
            raise ValueError(f"smoothing must be in (0, 1]; got {self.smoothing!r}")
        if not (number(self.threshold) and math.isfinite(self.threshold)
                and self.threshold > 0):
            raise ValueError(f"threshold must be a finite number > 0; got {self.threshold!r}")
        if not (number(self.sigmas) and math.isfinite(self.sigmas) and self.sigmas >= 0):
            raise ValueError(f"sigmas must be a finite number >= 0; got {self.sigmas!r}")
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

    Attributes
    ----------
    t : float
        Time of the window's last sample [s] (stream time, ``k dt``).
    estimate : dict of str to float
        The physical parameters of this window alone.
    smoothed : dict of str to float
        Their moving averages.
    drift : dict of str to float
        ``smoothed / reference - 1`` per parameter (nan until the reference exists).
    alarm : bool
        Whether the change alarm is raised (it stays raised).
    seconds : float
        Wall time of the identification [s].
    error : str or None
        None for an identified window; else why it could not be identified (the message of
        the identifier's check, or a non-finite estimate): then ``estimate`` holds NaN for each
        tracked parameter known so far, and ``smoothed``, ``drift``, ``alarm`` are the
        tracker's state, unchanged by this window.
    limit : dict of str to float
        The relative drift beyond which each parameter counts toward the alarm
        (``TrackerConfig.sigmas``); empty until the reference exists.
    """

    t: float
    estimate: dict[str, float]
    smoothed: dict[str, float]
    drift: dict[str, float]
    alarm: bool
    seconds: float
    error: str | None = None
    limit: dict[str, float] = field(default_factory=dict)


class PushError(ValueError):
    """A failure of the engine while ``Tracker.push`` identified a window.

    Parameters
    ----------
    message : str
        What failed.
    consumed : int
        Samples of the chunk taken into the stream, the failed window's last one included; the
        stream goes on with ``u[consumed:], y[consumed:]``.
    updates : list of Update
        The updates of the windows completed before the failure.
    """

    def __init__(self, message: str, consumed: int, updates: list) -> None:
        super().__init__(message)
        self.consumed = consumed
        self.updates = updates
