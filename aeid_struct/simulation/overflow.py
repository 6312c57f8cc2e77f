"""The overflow rule of the decoder's public functions.

A response that leaves the floating range (an unstable system over a long record) is returned as
+inf from its first overflowing sample on, with an :class:`OverflowWarning` (a
``RuntimeWarning``); never NaN. The overflowing records are recomputed by the per-step recursion
(:func:`~aeid_struct.simulation.kernels.simulate_loop`): the log-depth kernels raise ``Phi`` to
powers up to the record's length, which can overflow while every sample is still finite. The batch
kernels do not apply this rule; they return whatever the arithmetic gives.
"""

from __future__ import annotations

import math
import warnings

import torch

__all__ = ["OverflowWarning", "nonfinite_records", "overflow_from", "replace_overflow",
           "warn_overflow"]


class OverflowWarning(RuntimeWarning):
    """A simulated response exceeded the dtype's range; the record is +inf from that sample on."""


def nonfinite_records(t: torch.Tensor) -> torch.Tensor:
    """The records (axis 0) of ``t`` that hold a non-finite entry.

    Parameters
    ----------
    t : (batch, ...) tensor

    Returns
    -------
    index : (count,) int64 tensor
    """
    return torch.nonzero(~torch.isfinite(t).flatten(1).all(1))[:, 0]


def overflow_from(t: torch.Tensor) -> torch.Tensor:
    """Where each record has overflowed: True from its first sample with a non-finite entry on.

    Parameters
    ----------
    t : (records, steps) or (records, steps, n) tensor

    Returns
    -------
    (records, steps) bool tensor
    """
    bad = ~torch.isfinite(t)
    if bad.ndim == 3:
        bad = bad.any(-1)
    return bad.cumsum(dim=1) > 0


def replace_overflow(out: torch.Tensor, index: torch.Tensor, exact: torch.Tensor, caller: str, A,
                     dt: float, is_batched: bool) -> torch.Tensor:
    """``out`` with the records ``index`` replaced by their per-step values, +inf from the first
    sample that overflows on; warns if any does.

    Parameters
    ----------
    out : (batch, steps) or (batch, steps, n) tensor
        A log-depth kernel's result.
    index : (count,) int64 tensor
        The records of ``out`` that are not finite (:func:`nonfinite_records`).
    exact : (count, steps) or (count, steps, n) tensor
        The same records by the per-step recursion.
    caller : str
        The public function, for the warning.
    A : (batch, n, n) tensor
        The systems, for the warning's pole.
    dt : float
    is_batched : bool
        Whether the caller's arguments had a batch axis (the warning names records then).

    Returns
    -------
    tensor shaped like ``out``

    Warns
    -----
    OverflowWarning
        When a record of ``exact`` overflows.
    """
    over = overflow_from(exact)
    mask = over if exact.ndim == 2 else over[..., None].expand_as(exact)
    out = out.index_put((index,), exact.masked_fill(mask, math.inf))
    hit = torch.nonzero(over.any(1))[:, 0]
    if len(hit):
        first = int(torch.nonzero(over[hit[0]])[0, 0])
        warn_overflow(caller, index[hit], first, A, dt, out.shape[1], out.dtype, is_batched,
                      "those samples are +inf", stacklevel=4)
    return out


def warn_overflow(caller: str, records: torch.Tensor, first: int, A, dt: float, steps: int,
                  dtype: torch.dtype, is_batched: bool, returned: str, stacklevel: int) -> None:
    """Issue the overflow rule's warning: which records, from which sample, and why.

    Parameters
    ----------
    caller : str
        The public function.
    records : (count,) int64 tensor
        The overflowing records (the first is named).
    first : int
        Its first overflowing sample.
    A : (batch, n, n) tensor
        The systems: the first record's largest real pole part goes into the message.
    dt : float
    steps : int
    dtype : torch.dtype
    is_batched : bool
        Name the records (True) or "the record".
    returned : str
        What the caller returns for them.
    stacklevel : int
        For ``warnings.warn``: the user's frame.

    Warns
    -----
    OverflowWarning
        Always.
    """
    r = int(records[0])
    pole = float(torch.linalg.eigvals(A[r].detach()).real.max())
    name = str(dtype).removeprefix("torch.")
    where = (f"{len(records)} of {A.shape[0]} records (the first: record {r}, "
             if is_batched else "the record (")
    growth = pole * dt * steps
    why = (f"its largest pole Re(p) = {pole:.3g} rad/s grows by e^(Re(p) dt steps) = "
           f"e^{growth:.3g} over the record" if growth > 0 else
           f"a stable system (largest Re(p) = {pole:.3g} rad/s): the input or the model's size")
    warnings.warn(
        f"{caller}: the response overflows {name} (largest finite {torch.finfo(dtype).max:.3g}) "
        f"in {where}from sample {first} of {steps}; {why}); {returned}",
        OverflowWarning,
        stacklevel=stacklevel,
    )
