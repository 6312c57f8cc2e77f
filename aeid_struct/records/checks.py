"""The checks of measured records: a user's ``y`` and ``u`` become validated float64 arrays.

Two kinds of problem, kept apart because a batch treats them differently: **structural** ones,
about the argument as a whole (not real numbers -- a complex array is refused, never silently cut
to its real part --, a wrong shape, no records, an input with another record count), always
raise a ``ValueError``; **per record** ones (non-finite samples, an all-zero output or input, a
varying input to an identifier that reads only steps, a scale ratio ``max|y| / max|u|`` beyond
float64) are kept per record: raised as a :class:`RecordError` naming the record, or collected
(``Identifier.identify(errors="collect")``). :func:`normalise` is Eq. 15 in float64, per record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Checked", "RecordError", "as_array", "as_records", "check_dt", "check_records",
           "denormalise", "normalise", "overflow_problem", "record_problems", "require_finite",
           "unit_step"]


class RecordError(ValueError):
    """A record that cannot be identified (non-finite, all zero, ...), as opposed to a
    malformed argument.

    Parameters
    ----------
    message : str
        What is wrong, naming the argument and the record.
    record : int
        The record's index in its batch (0 for a single record); kept as ``self.record``.
    """

    def __init__(self, message: str, record: int) -> None:
        super().__init__(message)
        self.record = record


def as_array(name: str, value) -> np.ndarray:
    """``value`` as a float64 array of real numbers, or a ValueError naming ``name``.

    A complex array is refused, whatever its imaginary part: numpy's cast would drop it
    silently, and a model identified from half of the data looks like a good one. So are a
    boolean array (0/1 flags are not a measurement), a masked array with masked samples (numpy
    would read the values under the mask) and a missing sample (None, which numpy's cast
    turns into NaN).

    Parameters
    ----------
    name : str
        The argument's name in messages.
    value : array_like or tensor

    Returns
    -------
    float64 array, the shape of ``value``
    """
    if value is None:
        raise ValueError(f"{name} must be an array of real numbers; got None")
    if hasattr(value, "detach") and hasattr(value, "cpu"):   # a torch tensor, grad or GPU
        value = value.detach().cpu()
    if isinstance(value, np.ma.MaskedArray):
        masked = int(np.ma.count_masked(value))
        if masked:
            raise ValueError(f"{name} is a masked array with {masked} masked sample"
                             f"{'s' if masked > 1 else ''}: fill them ({name}.filled(value)) or "
                             f"cut them out; the values under a mask are not measurements")
        value = value.data
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError, RuntimeError):
        raise ValueError(f"{name} must be an array of real numbers; got "
                         f"{type(value).__name__}") from None
    if arr.dtype.kind == "c":
        raise ValueError(f"{name} must be real; got a complex array (dtype {arr.dtype}): pass "
                         f"{name}.real or abs({name}) explicitly if that is what you mean")
    if arr.dtype.kind in "mM":     # numpy casts dates and durations to numbers silently
        raise ValueError(f"{name} must be an array of real numbers; got an array of dtype "
                         f"{arr.dtype} (times, not measurements)")
    if arr.dtype.kind == "b":
        raise ValueError(f"{name} must be an array of real numbers; got an array of dtype bool "
                         f"(pass {name}.astype(float) if 0/1 is what you mean)")
    if arr.dtype.kind == "O" and any(v is None for v in arr.flat):
        raise ValueError(f"{name} must be an array of real numbers; got {type(value).__name__} "
                         "of dtype object with a missing value (None)")
    try:
        return arr.astype(np.float64, copy=False)
    except (TypeError, ValueError):   # strings, objects (a complex number among them, ...)
        raise ValueError(f"{name} must be an array of real numbers; got "
                         f"{type(value).__name__} of dtype {arr.dtype}") from None


def require_finite(name: str, arr: np.ndarray, labels: tuple[str, ...] = ("record",
                                                                          "sample")) -> None:
    """A ValueError naming the first non-finite entry of a record ("at sample k" or "at record
    r, sample k").

    Parameters
    ----------
    name : str
        The argument's name in messages.
    arr : (steps,) or (batch, steps) array
    labels : tuple of str
        The axes' names, the last ones used for an array of fewer axes (a measured record of
        several channels, ``(steps, channels)``, passes ``("sample", "output")``).
    """
    if not np.all(np.isfinite(arr)):
        where = np.argwhere(~np.isfinite(arr))[0]
        labels = labels[-arr.ndim:]
        at = ", ".join(f"{label} {i}" for label, i in zip(labels, where, strict=True))
        raise ValueError(f"{name} must be finite; got {arr[tuple(where)]} at {at}")


def as_records(name: str, value, steps: int, dt: float, *,
               batch: bool = True) -> tuple[np.ndarray, bool]:
    """The structural check of a record argument: real numbers, at least one record.

    Finiteness is a per-record matter (:func:`record_problems`).

    Parameters
    ----------
    name : str
        The argument's name in messages.
    value : (steps,) or (batch, steps) array_like
        Only ``(steps,)`` without ``batch``.
    steps : int
    dt : float
        Named in messages.
    batch : bool
        Whether a batch axis is allowed.

    Returns
    -------
    records : (count, steps) float64 array
    batched : bool
        Whether a batch axis was given.
    """
    arr = as_array(name, value)
    ndims = (1, 2) if batch else (1,)
    if arr.ndim not in ndims or arr.shape[-1] != steps:
        want = f"({steps},) or (batch, {steps})" if batch else f"({steps},)"
        raise ValueError(f"{name} must have shape {want} for this identifier (dt={dt}, "
                         f"steps={steps}); got {arr.shape}")
    if arr.ndim == 2 and arr.shape[0] == 0:
        raise ValueError(f"{name} must hold at least one record; got shape {arr.shape} (a "
                         "batch of no records)")
    return (arr[None] if arr.ndim == 1 else arr), arr.ndim == 2


@dataclass(frozen=True)
class Checked:
    """Records that passed the structural checks, with each one's problem.

    Attributes
    ----------
    y : (count, steps) float64 array
    u : (count, steps) float64 array or None
        A ``(steps,)`` input broadcast over the batch; None for a unit step.
    batched : bool
        Whether ``y`` came with a batch axis.
    problems : tuple of count (str or None)
        Per record, why it cannot be identified, or None for a good record.
    """

    y: np.ndarray
    u: np.ndarray | None
    batched: bool
    problems: tuple[str | None, ...]

    @property
    def count(self) -> int:
        return self.y.shape[0]

    @property
    def good(self) -> np.ndarray:
        """``(count,)`` bool: the records without a problem."""
        return np.array([p is None for p in self.problems], dtype=bool)

    def raise_first(self) -> None:
        """Raise the first record's problem as a :class:`RecordError`; nothing if all are
        good."""
        for i, problem in enumerate(self.problems):
            if problem is not None:
                raise RecordError(problem, i)


def check_records(y, u, *, steps: int, dt: float, reads_u: bool, batch: bool = True,
                  names: tuple[str, str] = ("y", "u")) -> Checked:
    """Check an output record set ``y`` and its input ``u`` for an identifier of ``steps``
    samples at ``dt`` (module docstring).

    Parameters
    ----------
    y : (steps,) or (batch, steps) array
        Only ``(steps,)`` without ``batch``.
    u : like ``y``, (steps,) for a whole batch, or None
        None is a unit step.
    steps, dt : int, float
        The record format of the identifier (named in messages).
    reads_u : bool
        Whether the identifier reads ``u`` (otherwise ``u`` must be a constant step).
    batch : bool
        Whether a batch axis is allowed.
    names : (str, str)
        The arguments' names in messages (``("y[1]", "u[1]")`` for a second record).

    Returns
    -------
    Checked
        Each record's problem; structural problems raise a ValueError.
    """
    yname, uname = names
    y2, batched = as_records(yname, y, steps, dt, batch=batch)
    u2 = None
    if u is not None:
        u2, _ = as_records(uname, u, steps, dt, batch=batch)
        count = y2.shape[0]
        if u2.shape[0] == 1 and count > 1:
            u2 = np.broadcast_to(u2, y2.shape)
        if u2.shape[0] != count:
            raise ValueError(f"{uname} must have {count} records like {yname}; "
                             f"got {u2.shape[0]}")
    return Checked(y2, u2, batched, record_problems(y2, u2, reads_u=reads_u, names=names))


def record_problems(y2: np.ndarray, u2: np.ndarray | None, *, reads_u: bool,
                    names: tuple[str, str] = ("y", "u")) -> tuple[str | None, ...]:
    """Why each record cannot be identified; None for a good one.

    The first problem of a record, in the order: ``y`` non-finite, ``y`` all zero, ``u``
    non-finite, ``u`` all zero, ``u`` varying for an identifier that does not read it,
    ``max|y| / max|u|`` beyond float64.

    Parameters
    ----------
    y2 : (count, steps) float64 array
    u2 : (count, steps) float64 array or None
        None is a unit step.
    reads_u : bool
    names : (str, str)
        The arguments' names in messages.

    Returns
    -------
    tuple of count (str or None)
    """
    yname, uname = names
    count = y2.shape[0]
    if count == 1 and _one_good(y2, u2, reads_u):
        return (None,)
    # One reduction per signal screens every rule (a record's check runs on each tracker
    # window): max|v| is NaN or inf exactly when v is not finite, and 0 when v is all zero.
    # The ratio rule reads the finite samples' maxima; only a non-finite record recomputes
    # them, and _problem says which rule a bad record breaks.
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        y_bar = np.abs(y2).max(axis=1)
        u_bar = unit_step(count) if u2 is None else np.abs(u2).max(axis=1)
        bad = ~(np.isfinite(y_bar) & np.isfinite(u_bar) & (y_bar > 0) & (u_bar > 0))
        if u2 is not None and not reads_u:
            bad |= np.any(u2 != u2[:, :1], axis=1)
        if bad.any():
            y_bar = np.abs(np.where(np.isfinite(y2), y2, 0.0)).max(axis=1)
            if u2 is not None:
                u_bar = np.abs(np.where(np.isfinite(u2), u2, 0.0)).max(axis=1)
        # The de-normalisation multiplies c, d by max|y| / max|u| (Eq. 15 and linearity): it
        # must be a positive float64 number (1e300 / 1e-300 is not).
        ratio = y_bar / u_bar
    bad = bad | ~(np.isfinite(ratio) & (ratio > 0))
    if not bad.any():
        return (None,) * count
    out: list[str | None] = [None] * count
    for r in np.flatnonzero(bad):
        out[r] = _problem(int(r), count, y2[r], None if u2 is None else u2[r], reads_u,
                          y_bar[r], u_bar[r], yname, uname)
    return tuple(out)


def _one_good(y2: np.ndarray, u2: np.ndarray | None, reads_u: bool) -> bool:
    """Whether ONE record ``y2, u2 (1, steps)`` breaks none of :func:`record_problems`' rules,
    in Python floats (the rules' screen below in numpy costs a tracker window's or a batch-1
    call's time several times over); False sends it through the rules themselves."""
    y_bar = float(np.abs(y2).max())           # NaN or inf exactly when y is not finite
    u_bar = 1.0 if u2 is None else float(np.abs(u2).max())
    if not (0.0 < y_bar < math.inf and 0.0 < u_bar < math.inf):
        return False
    if u2 is not None and not reads_u and (u2 != u2[0, 0]).any():
        return False
    return 0.0 < y_bar / u_bar < math.inf


def _problem(r: int, count: int, y: np.ndarray, u: np.ndarray | None, reads_u: bool,
             y_bar: float, u_bar: float, yname: str, uname: str) -> str:
    """The message of record ``r``'s first problem (``record_problems``)."""
    for name, v in ((yname, y), (uname, u)):
        if v is None:
            continue
        if not np.all(np.isfinite(v)):
            k = int(np.flatnonzero(~np.isfinite(v))[0])
            return f"{name} must be finite; got {v[k]} at record {r}, sample {k}"
        if not np.any(v):
            if name == yname:
                return (f"{yname} must not be all zero (record {r} of {count}): the "
                        "normalisation y_tilde = 2 y / max|y| - 1 (Eq. 15) needs max|y| > 0")
            return (f"{uname} must not be all zero (record {r}): a system at rest with zero "
                    "input reveals nothing")
    if u is not None and not reads_u and np.any(u != u[0]):
        # The encoder never sees u: only a step (of any height, which the exact
        # de-normalisation or the scale feature absorbs) is what it was trained on.
        return (f"{uname} must be a constant step for this identifier (record {r} varies): "
                "it was trained on step responses and does not read u; use an identifier "
                "trained with another excitation (TrainConfig(excitation='mix')) for "
                "arbitrary inputs")
    return (f"{yname} and {uname} must have a scale ratio max|{yname}| / max|{uname}| that "
            f"float64 holds (the model is de-normalised by it, Eq. 15); got {y_bar:.3g} / "
            f"{u_bar:.3g} at record {r}")


def overflow_problem(r: int, gain: float, yname: str = "y") -> str:
    """The reason of a good record whose identified model is not finite: the de-normalisation
    multiplies ``c, d`` by ``gain = max|y| / max|u|`` (Eq. 15 and linearity), and for a record
    of 1e308 the product lies beyond float64.

    Parameters
    ----------
    r : int
        The record's index.
    gain : float
    yname : str

    Returns
    -------
    str
    """
    return (f"{yname} must have a scale the identified model can hold in float64: de-normalised "
            f"by max|{yname}| / max|u| = {gain:.3g} (Eq. 15), its c or d at record {r} lies "
            f"beyond float64's range; rescale {yname} (e.g. to other units)")


def normalise(y2: np.ndarray, u2: np.ndarray | None, *, inputs: bool = True):
    """Eq. 15 per record, in float64: ``y_tilde = 2 y / y_bar - 1`` with ``y_bar = max|y|``,
    and ``u / u_bar`` with ``u_bar = max|u|`` (ones and ``u_bar = 1`` for a unit step).

    Parameters
    ----------
    y2 : (count, steps) float64 array
        Good records (:func:`record_problems`).
    u2 : (count, steps) float64 array or None
    inputs : bool
        Whether ``u_tilde`` is wanted (False: None, for a reader that reads ``u_bar`` only).

    Returns
    -------
    y_tilde, u_tilde : (count, steps) arrays in [-1, 1] (``u_tilde`` None without ``inputs``)
    y_bar, u_bar : (count,) arrays
    """
    y_bar = np.abs(y2).max(axis=1)
    # y / y_bar first: 2 y overflows for |y| near float64's largest number; then in place
    # (the same products, no further temporaries)
    y_tilde = y2 / y_bar[:, None]
    y_tilde *= 2.0
    y_tilde -= 1.0
    if u2 is None:
        return y_tilde, unit_step(y2.shape) if inputs else None, y_bar, unit_step(y_bar.shape)
    u_bar = np.abs(u2).max(axis=1)
    return y_tilde, u2 / u_bar[:, None] if inputs else None, y_bar, u_bar


def denormalise(c: np.ndarray, d: np.ndarray, elements: np.ndarray, gain: np.ndarray,
                output: np.ndarray):
    """The exact de-normalisation of a model identified on Eq. 15-normalised records: by
    linearity, ``y / y_bar`` answering ``u / u_bar`` means ``c``, ``d`` and the output elements
    (``c_i``, ``d``) scale with ``gain = y_bar / u_bar``. In float64, after the encoder's pass
    (the leg identifiers' batch-1 path and an ONNX export's runner alike).

    Parameters
    ----------
    c : (count, n) array
    d : (count,) array
    elements : (count, q) array
    gain : (count,) array
    output : (q,) bool array
        The elements that scale with the output.

    Returns
    -------
    c, d, elements : arrays
        Scaled; an overflow gives inf, for the caller's overflow check
        (:func:`overflow_problem`).
    """
    with np.errstate(over="ignore", invalid="ignore"):
        # a product, not el * (1 + mask (gain - 1)), which is 0 for gain = 1e-44
        return (c * gain[:, None], d * gain,
                np.where(output, elements * gain[:, None], elements))


def unit_step(shape: int | tuple[int, ...]) -> np.ndarray:
    """The input a record without ``u`` stands for: a unit step, ``u_k = 1`` for every sample.

    With the first-order hold between samples (docs/architecture.md, time grid) this is the
    step of the paper's experiments: the input is 1 from ``t_0 = 0`` on, the system at rest
    before it.

    Parameters
    ----------
    shape : int or tuple of int
        ``steps`` for one record, ``(count, steps)`` for a batch (e.g. ``y.shape``).

    Returns
    -------
    u : (steps,) or (count, steps) float64 array of ones
    """
    return np.ones(shape, dtype=np.float64)


def check_dt(dt) -> float:
    """``dt`` as a positive finite float, or a ValueError naming it.

    Parameters
    ----------
    dt : number
        A sample time; a bool or a string is refused (no silent casts).

    Returns
    -------
    float
    """
    try:
        value = float(dt) if not isinstance(dt, (bool, str)) else math.nan
    except (TypeError, ValueError, RuntimeError):
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"dt must be a positive finite number; got {dt!r}")
    return value
