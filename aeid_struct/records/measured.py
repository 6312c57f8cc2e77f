"""The user's measured record (:class:`Record`, MATLAB's ``iddata``): one output, one input, a
sample time, offsets and a known or unknown input delay, validated once when it is made.

Time axis: sample ``k`` is taken at ``t_k = t0 + k dt``; the input is linear between samples
(first-order hold, docs/architecture.md), or held from one sample to the next where the record
says so (``intersample="zoh"``, MATLAB's ``InterSample``: an input applied through a DAC). An
input delay of ``D`` samples means that ``y_k``
answers ``u_{k-D}``: :meth:`Record.shifted` pairs ``y[D:]`` with ``u[:steps - D]``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import KW_ONLY, dataclass

import numpy as np

from aeid_struct.records.checks import as_array, check_dt, require_finite, unit_step

__all__ = ["DETRENDS", "INTERSAMPLE", "Record", "exact_scale"]

#: What :meth:`Record.detrend` removes.
DETRENDS = ("mean", "initial", "linear")
#: The input between samples (:attr:`Record.intersample`): linear (first-order hold) or held
#: (zero-order hold).
INTERSAMPLE = ("foh", "zoh")
#: Peaks within ``2^-SAFE_EXPONENT .. 2^SAFE_EXPONENT`` are used as they are: their squares and
#: the products of the normal equations stay far inside float64 (1e-308 .. 1e308).
SAFE_EXPONENT = 64


def exact_scale(x: np.ndarray) -> float:
    """A power of two near ``max |x|`` where that peak is outside ``2^-64 .. 2^64`` (else 1).

    Dividing by a power of two is exact in binary floating point (only the exponent changes),
    so a record scaled by it carries the same digits; a tiny output (1e-200) would otherwise
    underflow in its squares (1e-400) and a huge one overflow.

    Parameters
    ----------
    x : array

    Returns
    -------
    float
        ``2^e``; 1.0 for a peak inside the safe range or an all-zero ``x``.
    """
    peak = float(np.max(np.abs(x))) if x.size else 0.0
    if peak == 0.0:
        return 1.0
    exponent = math.frexp(peak)[1]
    return math.ldexp(1.0, exponent) if abs(exponent) > SAFE_EXPONENT else 1.0


def _number(name: str, value) -> float:
    """``value`` as a finite float, or a ValueError naming ``name`` (no bool, no string)."""
    if isinstance(value, (bool, str)) or not isinstance(value, (int, float, np.number)):
        raise ValueError(f"{name} must be a finite number; got {value!r}")
    if not math.isfinite(float(value)):
        raise ValueError(f"{name} must be a finite number; got {value!r}")
    return float(value)


def _samples(name: str, value) -> np.ndarray:
    """A read-only float64 copy of ``value``: ``(steps,)`` for one channel (a column too),
    ``(steps, channels)`` for several; steps >= 2 and more samples than channels, finite, real."""
    arr = as_array(name, value)
    if arr.ndim == 2 and arr.shape[1] == 1:        # a column: one channel
        arr = arr[:, 0]
    what = "outputs" if name == "y" else "inputs"
    if arr.ndim == 2 and not arr.shape[0] > arr.shape[1] >= 2:
        raise ValueError(f"{name} must have shape (steps,) or (steps, {what}) with more samples "
                         f"than {what}; got shape {arr.shape} (a transposed record? pass "
                         f"{name}.T)")
    if arr.ndim not in (1, 2) or arr.shape[0] < 2:
        raise ValueError(f"{name} must have shape (steps,) or (steps, {what}) with steps >= 2 "
                         f"(one record); got shape {arr.shape}")
    # a record of several channels is (steps, channels): "at sample k, output i"
    require_finite(name, arr, ("sample", "output" if name == "y" else "input")[: arr.ndim])
    arr = np.array(arr, dtype=np.float64)          # our own copy: the caller's may change
    arr.flags.writeable = False
    return arr


def _offset(name: str, value, channels: int):
    """An offset: a finite float for one channel, a read-only ``(channels,)`` array for
    several (a scalar is broadcast)."""
    if channels == 1:
        return _number(name, value)
    if np.ndim(value) == 0:
        value = np.full(channels, _number(name, value))
    arr = as_array(name, value)
    if arr.shape != (channels,):
        raise ValueError(f"{name} must be a number or a ({channels},) array (one per channel); "
                         f"got shape {arr.shape}")
    require_finite(name, arr)
    arr = np.array(arr, dtype=np.float64)
    arr.flags.writeable = False
    return arr


class _Channels:
    """A record's channels: ``p`` outputs, ``m`` inputs, their two-dimensional views and one
    channel of them (:class:`Record`'s, cut from it at this seam)."""

    @property
    def outputs(self) -> int:
        """``p``, the number of outputs."""
        return _width(self.y)

    @property
    def inputs(self) -> int:
        """``m``, the number of inputs."""
        return _width(self.u)

    @property
    def Y(self) -> np.ndarray:
        """``(steps, p)`` outputs (a view of ``y``)."""
        return self.y.reshape(self.steps, -1)

    @property
    def U(self) -> np.ndarray:
        """``(steps, m)`` inputs (a view of ``u``)."""
        return self.u.reshape(self.steps, -1)

    def channel(self, output: int = 0, input: int = 0) -> Record:  # noqa: A002 (the maths' name)
        """The one-output, one-input record of output ``output`` and input ``input``.

        Parameters
        ----------
        output : int in [0, p)
        input : int in [0, m)

        Returns
        -------
        Record
            With that channel's offsets, the same ``dt``, ``delay``, ``t0`` and name.

        Raises
        ------
        ValueError
            For an index outside the record's channels.
        """
        for what, k, count in (("output", output, self.outputs), ("input", input, self.inputs)):
            if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not (
                    0 <= k < count):
                raise ValueError(f"{what} must be an integer in [0, {count}) (the record has "
                                 f"{count} {what}s); got {k!r}")
        return self._like(y=self.Y[:, output], u=self.U[:, input],
                          y_offset=float(np.ravel(self.y_offset)[output]),
                          u_offset=float(np.ravel(self.u_offset)[input]))

    def require_siso(self, what: str) -> None:
        """Refuse a record with several outputs or inputs where ``what`` identifies one output
        from one input.

        Parameters
        ----------
        what : str
            The entry point, named in the message.

        Raises
        ------
        ValueError
        """
        if self.outputs > 1 or self.inputs > 1:
            raise ValueError(f"{what} identifies one output from one input; the record has "
                             f"{self.outputs} outputs and {self.inputs} inputs (y "
                             f"{self.y.shape}, u {self.u.shape}): identify one channel at a "
                             f"time with record.channel(output, input)")


@dataclass(frozen=True, eq=False)
class Record(_Channels):
    """A measured record ``(y, u)`` on the grid ``t_k = t0 + k dt``, checked once.

    One output and one input are ``(steps,)`` arrays (a ``(steps, 1)`` column is the same);
    ``p`` outputs are ``(steps, p)`` and ``m`` inputs ``(steps, m)``. :attr:`Y` and :attr:`U`
    are always two-dimensional; :meth:`channel` picks one output and one input. Several
    experiments of one system are a list of records.

    Parameters
    ----------
    y : (steps,) or (steps, p) array_like, steps >= 2
        Measured output (real, finite); stored as a read-only float64 array.
    u : (steps,) or (steps, m) array_like, optional
        Input (real, finite), as long as ``y``; None is a unit step (``records.unit_step``).
    dt : float, > 0
        Sample time.
    delay : int, optional
        Input delay in samples, ``0 <= delay < steps``; None: unknown.
    name : str
        Shown in ``repr`` and carried by :meth:`split`.
    t0 : float
        Time of the first sample.
    y_offset, u_offset : float, or (p,) / (m,) array for several channels
        Offsets already removed from ``y`` and ``u`` (:meth:`detrend` adds to them): the
        measured signals are ``y + y_offset`` and ``u + u_offset``.
    intersample : {"foh", "zoh"}
        The input between samples (MATLAB's ``InterSample``): ``"foh"`` linear from one sample
        to the next (the paper's first-order hold, Eq. 10-13), ``"zoh"`` held at each sample's
        value until the next (an input applied through a DAC). ``ae.identify`` models the
        record under its own hold.

    Raises
    ------
    ValueError
        Naming the argument: not real numbers, a wrong shape, a non-finite sample, ``u`` of
        another length, a bad ``dt``, ``delay``, ``name``, ``t0``, offset or ``intersample``.
    """

    y: np.ndarray
    u: np.ndarray | None = None
    dt: float = 1.0
    _: KW_ONLY
    delay: int | None = None
    name: str = ""
    t0: float = 0.0
    y_offset: float = 0.0
    u_offset: float = 0.0
    intersample: str = "foh"

    def __post_init__(self) -> None:
        y = _samples("y", self.y)
        u = _samples("u", unit_step(y.shape[0]) if self.u is None else self.u)
        if u.shape[0] != y.shape[0]:
            raise ValueError(f"u must have as many samples as y ({y.shape[0]}); got "
                             f"{u.shape[0]}")
        delay = self.delay
        if delay is not None:
            if isinstance(delay, bool) or not isinstance(delay, (int, np.integer)):
                raise ValueError(f"delay must be None (unknown) or an integer number of "
                                 f"samples; got {delay!r}")
            if not 0 <= delay < y.shape[0]:
                raise ValueError(f"delay must be >= 0 and < steps = {y.shape[0]}; got {delay}")
            delay = int(delay)
        if not isinstance(self.name, str):
            raise ValueError(f"name must be a str; got {type(self.name).__name__}")
        if not isinstance(self.intersample, str) or self.intersample not in INTERSAMPLE:
            raise ValueError(f"intersample must be one of {', '.join(map(repr, INTERSAMPLE))} "
                             f"(the input between samples: linear, or held); got "
                             f"{self.intersample!r}")
        values = {"y": y, "u": u, "dt": check_dt(self.dt), "delay": delay,
                  "t0": _number("t0", self.t0),
                  "y_offset": _offset("y_offset", self.y_offset, _width(y)),
                  "u_offset": _offset("u_offset", self.u_offset, _width(u))}
        for key, value in values.items():
            object.__setattr__(self, key, value)

    @property
    def steps(self) -> int:
        """Samples in the record."""
        return self.y.shape[0]

    @property
    def t(self) -> np.ndarray:
        """``(steps,)`` sample times ``t0 + k dt``."""
        return self.t0 + self.dt * np.arange(self.steps)

    def __len__(self) -> int:
        return self.steps

    def __repr__(self) -> str:
        channels = "" if self.outputs == self.inputs == 1 else \
            f"outputs={self.outputs}, inputs={self.inputs}, "
        offsets = ", ".join(f"{k}={np.array2string(np.asarray(v), precision=6)}"
                            if np.ndim(v) else f"{k}={v:g}"
                            for k, v in (("y_offset", self.y_offset), ("u_offset", self.u_offset)))
        hold = "" if self.intersample == "foh" else f", intersample={self.intersample!r}"
        return (f"Record(name={self.name!r}, steps={self.steps}, {channels}dt={self.dt:g}, "
                f"delay={self.delay}, {offsets}{hold})")

    def _like(self, **changes) -> Record:
        """A Record with ``changes``, the rest kept (checked again: a split part may be short)."""
        return dataclasses.replace(self, **changes)

    def detrend(self, kind: str = "mean") -> Record:
        """The record without its offsets; the removed offsets are added to ``y_offset`` and
        ``u_offset``.

        Parameters
        ----------
        kind : {"mean", "initial", "linear"}
            ``"mean"``: subtract the means of ``y`` and ``u``; ``"initial"``: their first
            samples; ``"linear"``: from ``y`` the least-squares line ``alpha + beta k`` and from
            ``u`` its mean. For ``"linear"`` ``y_offset`` grows by the line's value at the first
            sample (``alpha``); the slope is not kept.

        Returns
        -------
        Record

        Raises
        ------
        ValueError
            For an unknown ``kind``.
        """
        if kind not in DETRENDS:
            raise ValueError(f"kind must be one of {DETRENDS}; got {kind!r}")
        if kind == "initial":
            y_trend, u_level = np.broadcast_to(self.y[0], self.y.shape), self.u[0]
        elif kind == "mean":
            y_trend, u_level = np.broadcast_to(self.y.mean(0), self.y.shape), self.u.mean(0)
        else:                  # per output channel (lstsq solves every column at once)
            k = np.arange(self.steps, dtype=np.float64)
            line = np.linalg.lstsq(np.stack([np.ones_like(k), k], 1), self.y, rcond=None)[0]
            y_trend, u_level = line[0] + np.multiply.outer(k, line[1]), self.u.mean(0)
        return self._like(y=self.y - y_trend, u=self.u - u_level,
                          y_offset=self.y_offset + y_trend[0], u_offset=self.u_offset + u_level)

    def split(self, fraction: float = 0.5, *, at: int | None = None) -> tuple[Record, Record]:
        """An estimation part and a validation part (the validation part's ``t0`` continues
        the time axis); both keep ``dt``, ``delay`` and the offsets.

        Parameters
        ----------
        fraction : float in (0, 1)
            The estimation part's share of the samples (rounded); ignored when ``at`` is given.
        at : int, optional
            The first sample of the validation part.

        Returns
        -------
        estimation, validation : Record
            Named ``name + " (estimation)"`` and ``name + " (validation)"``.

        Raises
        ------
        ValueError
            For a bad ``fraction`` or ``at``, or a part with fewer than 2 samples (or not more
            samples than the known ``delay``).
        """
        if at is None:
            fraction = _number("fraction", fraction)
            if not 0.0 < fraction < 1.0:
                raise ValueError(f"fraction must be in (0, 1); got {fraction}")
            at = int(round(fraction * self.steps))
        elif isinstance(at, bool) or not isinstance(at, (int, np.integer)):
            raise ValueError(f"at must be an integer sample index; got {at!r}")
        least = max(2, (self.delay or 0) + 1)
        if not least <= at <= self.steps - least:
            raise ValueError(f"the split must leave each part at least {least} samples (steps = "
                             f"{self.steps}, delay = {self.delay}): at must be in [{least}, "
                             f"{self.steps - least}]; got {at}")
        return (self._like(y=self.y[:at], u=self.u[:at], name=f"{self.name} (estimation)"),
                self._like(y=self.y[at:], u=self.u[at:], name=f"{self.name} (validation)",
                           t0=self.t0 + at * self.dt))

    def shifted(self, delay: int | None = None) -> Record:
        """The record aligned for an input delay of ``D`` samples: ``y[D:]`` with
        ``u[:steps - D]`` (delay 0, ``t0`` of the sample ``y[D]``).

        Parameters
        ----------
        delay : int, optional
            ``D``, ``0 <= D <= steps - 2``; default: the record's known ``delay``.

        Returns
        -------
        Record

        Raises
        ------
        ValueError
            When no delay is given or known, or for a bad one.
        """
        D = self.delay if delay is None else delay
        if D is None:
            raise ValueError("delay must be given: the record's delay is unknown (None)")
        if isinstance(D, bool) or not isinstance(D, (int, np.integer)) or not (
                0 <= D <= self.steps - 2):
            raise ValueError(f"delay must be an integer in [0, {self.steps - 2}] (2 samples "
                             f"left); got {D!r}")
        D = int(D)
        return self._like(y=self.y[D:], u=self.u[: self.steps - D], delay=0,
                          t0=self.t0 + D * self.dt)

    def with_delay(self, delay: int | None) -> Record:
        """A copy with the known input delay set (None: unknown).

        Parameters
        ----------
        delay : int or None
            ``0 <= delay < steps``.

        Returns
        -------
        Record

        Raises
        ------
        ValueError
            For a bad ``delay``.
        """
        return self._like(delay=delay)

    def require_informative(self) -> None:
        """Refuse a record that says nothing about the system's input-output behaviour: a
        constant output, or a constant input (with a free initial state and offset, the
        response to a constant input is indistinguishable from a free response).

        Raises
        ------
        ValueError
            Naming ``y`` or ``u``.
        """
        flat = np.flatnonzero(~(np.ptp(self.Y, axis=0) > 0))
        if flat.size:
            which = "" if self.outputs == 1 else f" (output {flat[0]})"
            raise ValueError(f"y is constant{which} (every sample is {self.Y[0, flat[0]]:g}): "
                             f"a constant output says nothing about the system; give a record "
                             f"whose output responds to the input")
        flat = np.flatnonzero(~(np.ptp(self.U, axis=0) > 0))
        if flat.size:
            which = "" if self.inputs == 1 else f" (input {flat[0]})"
            raise ValueError(f"u is constant{which} over the whole record: with a free initial "
                             "state and offset, a constant input says nothing about the system (a "
                             "step response from rest is the leg identifiers' case, "
                             "ae.load_pretrained); give a record whose input varies")


def _width(x: np.ndarray) -> int:
    """Channels of a ``(steps,)`` or ``(steps, channels)`` array."""
    return 1 if x.ndim == 1 else x.shape[1]
