"""Argument handling of the decoder's public functions: array-likes in, validated tensors of one
dtype with one batch size out, and the results back in the caller's type.

Conventions (docs/architecture.md, "Conventions"): numpy in -> numpy float64 out; any torch tensor
in -> torch out in the promoted floating dtype of the torch inputs (float64 when none is floating);
half precision is refused (``matrix_exp`` and the scan need at least float32). Shapes are batch
first; each argument may drop its batch axis (shared by the batch) or have batch 1. Every error is
a ``ValueError`` that names the argument, what was expected and what came.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

from aeid_struct.records import check_dt  # the one dt rule (the boundary's)

__all__ = [
    "AXES",
    "Array",
    "CORE",
    "batched",
    "check_dt",
    "check_finite",
    "check_record",
    "check_system",
    "output",
    "prepare",
    "shape",
]

#: What the public functions accept and return: numpy arrays (and array-likes) or torch tensors.
Array = np.ndarray | torch.Tensor

#: Arguments that may be None (absent); every other one must be given.
OPTIONAL = frozenset({"x0", "yinf_hat", "yinf"})

#: How the entries of each argument are named in an error ("nan at record 0, sample 12").
AXES = {
    "A": ("record", "row", "column"),
    "b": ("record", "entry"),
    "c": ("record", "entry"),
    "x0": ("record", "entry"),
    "d": ("record",),
    "u": ("record", "sample"),
    "y": ("record", "sample"),
}

#: Dimensions of one (unbatched) argument: more means a leading batch axis.
CORE = {"A": 2, "b": 1, "c": 1, "x0": 1, "d": 0, "u": 1, "y": 1}


def prepare(named: dict[str, object]) -> tuple[dict[str, torch.Tensor | None], bool]:
    """Array-likes -> tensors of one floating dtype on one device.

    Parameters
    ----------
    named : dict
        Argument name -> array-like, torch tensor, or None (allowed only for ``x0``, ``yinf_hat``,
        ``yinf``).

    Returns
    -------
    tensors : dict
        Argument name -> tensor (float32 or float64) or None.
    torch_out : bool
        True when any argument was a torch tensor (the result is then returned as torch).

    Raises
    ------
    ValueError
        For a missing argument, tensors on several devices, a half-precision, complex or boolean
        tensor, or an array that is not real.
    """
    for name, v in named.items():
        if v is None and name not in OPTIONAL:
            raise ValueError(f"{name} must be a real array; got None")
    tensors = [v for v in named.values() if isinstance(v, torch.Tensor)]
    dtype, device = torch.float64, torch.device("cpu")
    if tensors:
        devices = sorted({str(t.device) for t in tensors})
        if len(devices) > 1:
            raise ValueError(f"all tensors must be on one device; got {', '.join(devices)}")
        device = tensors[0].device
        floats = [t.dtype for t in tensors if t.is_floating_point()]
        if floats:
            dtype = functools.reduce(torch.promote_types, floats)
        if dtype not in (torch.float32, torch.float64):
            raise ValueError(f"tensors must be float32 or float64; got {dtype}")
    out: dict[str, torch.Tensor | None] = {}
    for name, v in named.items():
        if v is None:
            out[name] = None
        elif isinstance(v, torch.Tensor):
            if v.is_complex() or v.dtype == torch.bool:
                raise ValueError(f"{name} must be real; got {v.dtype}")
            out[name] = v.to(dtype=dtype)
        else:
            try:
                arr = np.asarray(v)
            except ValueError as err:  # ragged nested sequences
                raise ValueError(f"{name} must be a real array; got {type(v).__name__}") from err
            if arr.dtype.kind not in "iuf":
                raise ValueError(f"{name} must be a real array; got dtype {arr.dtype}")
            # A Record's arrays are read-only (torch warns on such memory) and a reversed view
            # has negative strides (torch refuses it): both are copied.
            if not arr.flags.writeable or any(s < 0 for s in arr.strides):
                arr = arr.copy()
            out[name] = torch.as_tensor(arr, dtype=dtype, device=device)
    return out, bool(tensors)


def shape(t: torch.Tensor) -> str:
    """``t``'s shape as an error message writes it, e.g. ``(2, 300)``.

    Parameters
    ----------
    t : tensor of any shape

    Returns
    -------
    str
    """
    return str(tuple(t.shape))


def check_finite(name: str, t: torch.Tensor, axes: tuple[str, ...]) -> None:
    """Raise naming the first non-finite entry, e.g. ``"nan at record 0, sample 12"``.

    Parameters
    ----------
    name : str
        The argument's name in the message.
    t : tensor of any shape
    axes : tuple of str
        The names of ``t``'s axes for a batched argument; an unbatched one uses the trailing ones.

    Raises
    ------
    ValueError
        When ``t`` holds a NaN or an infinity.
    """
    bad = ~torch.isfinite(t)
    if not bool(bad.any()):
        return
    index = tuple(int(i) for i in torch.nonzero(bad)[0])
    value = float(t[index])
    # A record without its batch axis names only the trailing axes ("sample 12", "row 1, ...").
    labels = axes[len(axes) - len(index) :]
    where = ", ".join(f"{axis} {i}" for axis, i in zip(labels, index, strict=True))
    raise ValueError(f"{name} must be finite; got {value}" + (f" at {where}" if where else ""))


def check_record(name: str, y: torch.Tensor, *, allow_scalar: bool = False) -> None:
    """Check a record's shape ``(batch, steps)`` or ``(steps,)``, ``steps >= 1``, and finiteness.

    Parameters
    ----------
    name : str
        The argument's name in the message.
    y : tensor
    allow_scalar : bool
        Also accept a 0-d tensor.

    Raises
    ------
    ValueError
        For another shape or a non-finite sample.
    """
    lowest = 0 if allow_scalar else 1
    if not lowest <= y.ndim <= 2 or (y.ndim > 0 and y.shape[-1] == 0):
        raise ValueError(
            f"{name} must have shape (batch, steps) or (steps,) with steps >= 1; got {shape(y)}"
        )
    check_finite(name, y, ("record", "sample"))


def check_system(t: dict[str, torch.Tensor | None]) -> tuple[int, int, bool]:
    """Check the shapes and finiteness of ``A, b`` and, where present, ``c, d, u, y, x0``.

    Parameters
    ----------
    t : dict
        From :func:`prepare`: ``A (batch, n, n)`` or ``(n, n)``; ``b, c, x0 (batch, n)`` or
        ``(n,)``; ``d (batch,)`` or scalar; ``u, y (batch, steps)`` or ``(steps,)``.

    Returns
    -------
    n : int
        The order.
    batch : int
        The common batch size (1 when no argument has a batch axis).
    batched : bool
        Whether any argument has a batch axis (the result keeps one then).

    Raises
    ------
    ValueError
        Naming the argument whose shape disagrees, the disagreeing batch sizes, or the first
        non-finite entry.
    """
    A = t["A"]
    if A.ndim not in (2, 3) or A.shape[-1] != A.shape[-2] or A.shape[-1] == 0:
        raise ValueError(f"A must be square with shape (batch, n, n) or (n, n); got {shape(A)}")
    n = A.shape[-1]
    for name in ("b", "c", "x0"):
        v = t.get(name)
        if v is not None and (v.ndim not in (1, 2) or v.shape[-1] != n):
            raise ValueError(
                f"{name} must have shape (batch, n) or (n,) with n = {n} from A; got {shape(v)}"
            )
    d = t.get("d")
    if d is not None and d.ndim > 1:
        raise ValueError(f"d must be a scalar or have shape (batch,); got {shape(d)}")
    for name in ("u", "y"):
        v = t.get(name)
        if v is not None and (v.ndim not in (1, 2) or v.shape[-1] == 0):
            raise ValueError(
                f"{name} must have shape (batch, steps) or (steps,) with steps >= 1; "
                f"got {shape(v)}"
            )
    sizes = {k: v.shape[0] for k, v in t.items() if v is not None and v.ndim > CORE[k]}
    batch, is_batched = _common_batch(sizes)
    for name, v in t.items():
        if v is not None:
            check_finite(name, v, AXES[name])
    return n, batch, is_batched


def _common_batch(sizes: dict[str, int]) -> tuple[int, bool]:
    distinct = sorted({s for s in sizes.values() if s != 1})
    if len(distinct) > 1:
        have = ", ".join(f"{k} has {s}" for k, s in sizes.items())
        raise ValueError(
            f"batch sizes disagree: {have} (batched arguments must share one batch size, or have 1)"
        )
    return (distinct[0] if distinct else 1), bool(sizes)


def batched(t: dict[str, torch.Tensor | None], batch: int) -> dict[str, torch.Tensor | None]:
    """Give every argument the common leading batch axis (views, no copies).

    Parameters
    ----------
    t : dict
        From :func:`prepare`, checked by :func:`check_system`.
    batch : int
        The common batch size.

    Returns
    -------
    dict
        The same arguments, each with a leading axis of ``batch``.
    """
    out = {}
    for k, v in t.items():
        if v is not None:
            v = v if v.ndim > CORE[k] else v[None]
            v = v.expand(batch, *v.shape[1:])
        out[k] = v
    return out


def output(t: torch.Tensor, torch_out: bool, is_batched: bool = True):
    """A result in the caller's type: the batch axis dropped for an unbatched call, numpy float64
    for numpy input.

    Parameters
    ----------
    t : (batch, ...) tensor
    torch_out : bool
        Return torch (True) or numpy.
    is_batched : bool
        Keep the batch axis (False: return ``t[0]``).

    Returns
    -------
    torch tensor, numpy array, or numpy scalar for a 0-d result.
    """
    if not is_batched:
        t = t[0]
    if torch_out:
        return t
    arr = t.detach().cpu().numpy()
    return arr[()] if arr.ndim == 0 else arr
