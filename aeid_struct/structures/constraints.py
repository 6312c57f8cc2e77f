"""Elementwise constraint maps: one unconstrained column of ``theta`` -> one element.

Each element of a structure (``a0``, ``c1``, ``lambda0``, ``k``, ...) has a map that acts on its
own column of ``theta`` only, so the map is cheap, invertible and its Jacobian diagonal:

==========  ===================================  ===============================
kind        element = map(theta)                 set (closure of the range)
==========  ===================================  ===============================
real        ``theta``                            ``(-inf, inf)``
nonneg      ``softplus(theta)``                  ``[0, inf)``
pos         ``softplus(theta) + eps``            ``[eps, inf)``
neg         ``-(softplus(theta) + eps)``         ``(-inf, -eps]``
interval    ``lo + (hi - lo) sigmoid(theta)``    ``[lo, hi]``
==========  ===================================  ===============================

``eps`` = :data:`MARGIN` keeps an MCF real part strictly negative (and ``omega`` strictly
positive) also where softplus underflows to 0. The checks below are what a structure applies to
elements and given models: tolerances per row, fixed columns, constraint violations, with errors
that name the element, the rule and the offending row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi
import numpy as np
import torch
import torch.nn.functional as F

__all__ = [
    "MARGIN",
    "ElementMap",
    "as_batch",
    "check_constraints",
    "check_fixed_columns",
    "offending_rows",
    "row_tolerance",
    "switch",
]

#: Margin that keeps MCF real parts strictly negative (and omega strictly positive) when softplus
#: underflows to 0 for very negative theta.
MARGIN = 1e-8

_KINDS = ("real", "nonneg", "pos", "neg", "interval")


def _inv_softplus(y: torch.Tensor) -> torch.Tensor:
    # softplus(t) = log(1 + e^t)  =>  t = log(e^y - 1) = y + log(1 - e^-y); expm1 keeps it exact
    # for small y, and for large y log(1 - e^-y) -> 0 without overflow.
    return y + torch.log(-torch.expm1(-y))


@dataclass(frozen=True)
class ElementMap:
    """The constraint map of one element (module docstring).

    Attributes
    ----------
    kind : {"real", "nonneg", "pos", "neg", "interval"}
        The set the element lies in.
    lo : float
        The lower bound of an ``"interval"`` (finite, ``< hi``); unused otherwise.
    hi : float
        The upper bound of an ``"interval"``; unused otherwise.
    note : str
        Why the constraint holds, for error messages (e.g. ``"Descartes"``).
    """

    kind: str
    lo: float = -math.inf
    hi: float = math.inf
    note: str = ""

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ValueError(f"kind must be one of {', '.join(_KINDS)}; got {self.kind!r}")

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        """The element of raw ``t``.

        Parameters
        ----------
        t : (batch,) tensor
            One column of ``theta``.

        Returns
        -------
        (batch,) tensor
            The element, in the set.
        """
        if self.kind == "real":
            return t
        if self.kind == "nonneg":
            return F.softplus(t)
        if self.kind == "pos":
            return F.softplus(t) + MARGIN
        if self.kind == "neg":
            return -(F.softplus(t) + MARGIN)
        # interval: clamp only removes a rounding ulp outside [lo, hi]
        return torch.clamp(self.lo + (self.hi - self.lo) * torch.sigmoid(t), self.lo, self.hi)

    def casadi(self, t):
        """:meth:`forward` written with CasADi operations (torch's softplus: ``t`` itself above
        20, where ``log(1 + e^t)`` equals it in float64).

        Parameters
        ----------
        t : casadi SX or MX scalar
            One entry of ``theta``.

        Returns
        -------
        casadi SX or MX scalar
        """
        if self.kind == "real":
            return t
        if self.kind == "interval":
            return casadi.fmin(casadi.fmax(self.lo + (self.hi - self.lo) / (1 + casadi.exp(-t)),
                                           self.lo), self.hi)
        softplus = casadi.if_else(t > 20, t, casadi.log1p(casadi.exp(t)))
        return {"nonneg": softplus, "pos": softplus + MARGIN,
                "neg": -(softplus + MARGIN)}[self.kind]

    def inverse(self, x: torch.Tensor) -> torch.Tensor:
        """Raw ``theta`` of element values ``x`` in the closure of the set.

        Parameters
        ----------
        x : (batch,) tensor
            Element values; on the boundary of an open set they are clamped to the nearest
            value the map reaches, ``eps`` of the dtype inside.

        Returns
        -------
        (batch,) tensor
            ``theta`` with ``forward(theta) = x`` (up to that clamping).
        """
        tiny = torch.finfo(x.dtype).eps
        if self.kind == "real":
            return x
        if self.kind == "nonneg":
            return _inv_softplus(torch.clamp(x, min=tiny))
        if self.kind == "pos":
            return _inv_softplus(torch.clamp(x - MARGIN, min=tiny))
        if self.kind == "neg":
            return _inv_softplus(torch.clamp(-x - MARGIN, min=tiny))
        u = (x - self.lo) / (self.hi - self.lo)
        return torch.logit(torch.clamp(u, tiny, 1.0 - tiny))

    def admits(self, x: torch.Tensor, atol: torch.Tensor | float, *,
               open_: bool = False) -> torch.Tensor:
        """Whether ``x`` lies in the closure of the set, up to ``atol``.

        Parameters
        ----------
        x : (batch,) tensor
            Element values.
        atol : (batch,) tensor or float
            Tolerance per row.
        open_ : bool
            Check the open sets (``pos``, ``neg``) as open, without tolerance: a given model's
            pole at 0 is not in the open left half-plane.

        Returns
        -------
        (batch,) bool tensor
        """
        ok = torch.isfinite(x)
        if self.kind == "pos" and open_:
            ok = ok & (x > 0)
        elif self.kind == "neg" and open_:
            ok = ok & (x < 0)
        elif self.kind in ("nonneg", "pos"):
            ok = ok & (x >= -atol)
        elif self.kind == "neg":
            ok = ok & (x <= atol)
        elif self.kind == "interval":
            ok = ok & (x >= self.lo - atol) & (x <= self.hi + atol)
        return ok

    def project(self, x: torch.Tensor) -> torch.Tensor:
        """The closest point of the closure of the set.

        Parameters
        ----------
        x : (batch,) tensor

        Returns
        -------
        (batch,) tensor
        """
        if self.kind in ("nonneg", "pos"):
            return torch.clamp(x, min=0.0)
        if self.kind == "neg":
            return torch.clamp(x, max=0.0)
        if self.kind == "interval":
            return torch.clamp(x, self.lo, self.hi)
        return x

    def holds(self, v: float) -> bool:
        """Whether a value to be fixed satisfies the constraint exactly (open sets stay open).

        Parameters
        ----------
        v : float

        Returns
        -------
        bool
        """
        if not math.isfinite(v):
            return False
        return {
            "real": True,
            "nonneg": v >= 0.0,
            "pos": v > 0.0,
            "neg": v < 0.0,
            "interval": self.lo <= v <= self.hi,
        }[self.kind]

    def bounds(self) -> tuple[float, float]:
        """The closure of the map's range: what the refinement imposes as bounds.

        Returns
        -------
        (lo, hi) : tuple of float
        """
        return {
            "real": (-math.inf, math.inf),
            "nonneg": (0.0, math.inf),
            "pos": (MARGIN, math.inf),
            "neg": (-math.inf, -MARGIN),
            "interval": (self.lo, self.hi),
        }[self.kind]

    def describe(self, name: str) -> str:
        """The constraint as a rule for error messages, e.g. ``"a0 >= 0 (Descartes)"``.

        Parameters
        ----------
        name : str
            The element's name.

        Returns
        -------
        str
        """
        rule = {
            "real": f"{name} finite",
            "nonneg": f"{name} >= 0",
            "pos": f"{name} > 0",
            "neg": f"{name} < 0",
            "interval": f"{self.lo:g} <= {name} <= {self.hi:g}",
        }[self.kind]
        return f"{rule} ({self.note})" if self.note else rule


# ---------------------------------------------------------------------------------------------
# Checks that a structure applies to its elements
# ---------------------------------------------------------------------------------------------
def switch(name: str, value) -> bool:
    """A constructor's switch: True or False only.

    ``bool("no")`` is True, so a string or None would otherwise silently turn a constraint on
    or off.

    Parameters
    ----------
    name : str
        The argument's name, for the error message.
    value : bool

    Returns
    -------
    bool

    Raises
    ------
    ValueError
        If ``value`` is not a bool.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False; got {value!r}")
    return bool(value)


def row_tolerance(x: torch.Tensor, factor: float) -> torch.Tensor:
    """Per-row tolerance ``factor * (1 + max|x|)`` (non-finite entries count as 0).

    Parameters
    ----------
    x : (batch, q) tensor
    factor : float

    Returns
    -------
    (batch,) tensor
    """
    return factor * (1.0 + torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0).abs().amax(1))


def offending_rows(mask: torch.Tensor) -> list[int]:
    """The first (at most five) rows where ``mask`` is True, for error messages.

    Parameters
    ----------
    mask : (batch,) bool tensor

    Returns
    -------
    list of int
    """
    return torch.nonzero(mask).flatten()[:5].tolist()


def as_batch(x, width: int, what: str, who: str) -> tuple[torch.Tensor, bool]:
    """``x`` as a finite float tensor ``(batch, width)``, and whether it came unbatched.

    Parameters
    ----------
    x : (batch, width) or (width,) array-like
    width : int
    what : str
        The argument's name (``"theta"``, ``"elements"``).
    who : str
        The structure, for the error message.

    Returns
    -------
    t : (batch, width) tensor
        A float32 or float64 tensor (an unbatched ``x`` gets a batch axis of 1).
    squeeze : bool
        Whether ``x`` was unbatched.

    Raises
    ------
    ValueError
        For a value that is not a float tensor of that shape, or not finite.
    """
    try:
        t = torch.as_tensor(x)
    except (TypeError, ValueError, RuntimeError):   # strings, ragged lists, objects
        raise ValueError(f"{what} must be a float32 or float64 tensor of shape (batch, "
                         f"{width}) for {who}; got {type(x).__name__}") from None
    if not t.is_floating_point():
        raise ValueError(f"{what} must be a float32 or float64 tensor; got {t.dtype}")
    if t.ndim not in (1, 2) or t.shape[-1] != width:
        raise ValueError(f"{what} must have shape (batch, {width}) for {who}; "
                         f"got {tuple(t.shape)}")
    squeeze = t.ndim == 1
    t = t.unsqueeze(0) if squeeze else t
    bad = ~torch.isfinite(t).all(1)
    # not in an exported graph (torch.export): the file's reader checks what it reads
    if not torch.compiler.is_exporting() and bool(bad.any()):
        raise ValueError(f"{what} must be finite; got nan or inf in row(s) {offending_rows(bad)}")
    return t, squeeze


def check_fixed_columns(x: torch.Tensor, names, fixed: dict[str, float], atol, what: str,
                        who: str) -> None:
    """Check that the fixed elements' columns hold their values.

    Parameters
    ----------
    x : (batch, q) tensor
        Elements, columns in ``names`` order.
    names : sequence of str
        The element names.
    fixed : dict str -> float
        The fixed elements and their values.
    atol : (batch,) tensor or float
        Tolerance per row.
    what, who : str
        What ``x`` is and the structure, for the error message.

    Raises
    ------
    ValueError
        Naming the first element and row off its fixed value.
    """
    for i, name in enumerate(names):
        if name in fixed:
            v = fixed[name]
            bad = (x[:, i] - v).abs() > atol
            if not torch.compiler.is_exporting() and bool(bad.any()):
                r = offending_rows(bad)[0]
                raise ValueError(f"{what}: element {name} is fixed at {v!r} in {who}; "
                                 f"got {x[r, i].item():.6g} (row {r})")


def check_constraints(x: torch.Tensor, maps: dict[str, ElementMap], fixed: dict[str, float],
                      atol, what: str, who: str, open_: bool = False) -> None:
    """Check that every free element lies in its set (:meth:`ElementMap.admits`).

    Parameters
    ----------
    x : (batch, q) tensor
        Elements, columns in ``maps`` order.
    maps : dict str -> ElementMap
        Every element's map.
    fixed : dict str -> float
        The fixed elements (not checked here).
    atol : (batch,) tensor or float
        Tolerance per row.
    what, who : str
        What ``x`` is and the structure, for the error message.
    open_ : bool
        Check open sets as open (given models).

    Raises
    ------
    ValueError
        Naming the first element, its rule and the row that violates it.
    """
    for i, (name, m) in enumerate(maps.items()):
        if name not in fixed:
            bad = ~m.admits(x[:, i], atol, open_=open_)
            if not torch.compiler.is_exporting() and bool(bad.any()):
                r = offending_rows(bad)[0]
                raise ValueError(f"{what} violates the constraint {m.describe(name)} of "
                                 f"{who}: {name} = {x[r, i].item():.6g} (row {r})")
