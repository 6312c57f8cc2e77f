r"""Model structures: the encoder's raw output ``theta`` -> a continuous-time SISO state space.

Data flow::

    theta (batch, p) --elementwise constraint map--> elements (batch, q) --assemble--> System

``theta`` is unconstrained (what a network's last linear layer emits). Each *element* is a named
scalar of the structure (``a0``, ``c1``, ``lambda0``, ``k``, ...); its constraint map is applied
to its own column of ``theta`` only, so the map is cheap, invertible (:meth:`Structure.raw`) and
its Jacobian is diagonal. Elements held fixed (:meth:`Structure.fixed`) take no column of
``theta``: ``p = q - (number of fixed elements)``.

Structures
----------
:class:`CCF`
    Bottom-row controllable canonical form (paper Eq. 5)::

        A = [[0, 1, ..., 0], ..., [0, ..., 0, 1], [-a_0, -a_1, ..., -a_{n-1}]],  b = e_n,
        c = (c_0, ..., c_{n-1}),  d (0 unless feedthrough=True),
        G(s) = (c_{n-1} s^{n-1} + ... + c_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0) + d.

    Elements ``a0..a{n-1}, c0..c{n-1}[, d]``; all free reals (identity map), or with
    ``descartes=True`` ``a_i = softplus(theta_i) >= 0``. Descartes' rule of signs: with no sign
    change in ``(a_0, ..., a_{n-1}, 1)`` the characteristic polynomial has no positive real root,
    so no pole lies on the positive real axis (``a_0 = 0``, reachable by fixing, puts a pole at
    the origin). Complex pairs with a positive real part are *not* excluded
    (``s^3 + s^2 + s + 10`` has poles ``0.68 +- 1.94j``); the paper (Sec. III-B) says the same.
:class:`MCF`
    Modal canonical form (paper Eq. 6), real modes first, then the complex pairs::

        A = blkdiag(lambda_0, ..., lambda_{r-1}, [[delta_0, omega_0], [-omega_0, delta_0]], ...),
        lambda_i = -(softplus(theta) + eps),  delta_j = -(softplus(theta) + eps),
        omega_j = softplus(theta) + eps,      eps = 1e-8,

    so every sampled ``A`` is Hurwitz by construction, also where softplus underflows to 0. The
    margin ``eps`` keeps ``Re(eig) < 0`` strictly; it is far below any pole that a record of
    finite length can resolve.

    *Scaling redundancy.* ``(T b, c T^-1)`` with any ``T`` commuting with ``A`` (a diagonal
    scaling of a real mode, ``[[x, y], [-y, x]]`` on a pair) gives the same transfer function, so
    the paper's ``3n`` numbers (poles, ``b~``, ``c~``) are not identifiable. We fix
    ``b = 1`` for each real mode and ``b = (0, 1)`` for each pair and estimate ``c`` only: ``2n``
    elements (+ ``d``). ``b = (0, 1)`` keeps a pair controllable (its controllability matrix is
    ``[[0, omega], [1, delta]]``, ``omega > 0``), and the only ``T`` of the commuting form with
    ``T b = b`` is the identity, so no redundancy remains but the order of the modes.

    *Permutation redundancy.* Reordering real modes (or pairs) among themselves reorders the
    elements without changing the model. The forward map leaves it alone (the training loss is
    invariant to it; forcing an order would need a non-elementwise map). ``elements_of`` returns
    the canonical order: real modes slowest first (``lambda_0 >= lambda_1 >= ...``), pairs by
    increasing ``omega``; with fixed elements it picks the first ordering consistent with them.

    Elements ``lambda0..``, then ``delta0, omega0, delta1, omega1, ..``, then ``c0..c{n-1}``
    (state order: ``c_i`` for real mode ``i``, ``c_{r+2j}, c_{r+2j+1}`` for pair ``j``), then
    ``d`` if ``feedthrough``. Pair ``j`` contributes
    ``(c_{r+2j+1} s + c_{r+2j} omega_j - c_{r+2j+1} delta_j) / ((s - delta_j)^2 + omega_j^2)``.
:class:`Physical`
    A CasADi map from named physical parameters to ``(A, B, C, D)``; elements are the parameters,
    ``element = lo + (hi - lo) * sigmoid(theta)`` within the given bounds.

    *Several records, one parameter set.* A map with outputs ``A1, B1, C1, D1, ..., AR, .., DR``
    describes ``R`` SISO systems (e.g. the leg's two subsystems, ``symbolic.leg.joint_map``) that
    share the parameters, each identified from its own record. Its models carry a record axis
    after the batch axis: ``A (batch, R, n, n), b, c (batch, R, n), d (batch, R)``
    (:attr:`Structure.records`).

Models given from outside (:meth:`Structure.elements_of`) may come in any realisation; they are
converted through the transfer function: the characteristic polynomial (from the eigenvalues)
and the numerator from the Markov parameters ``h_k = c A^{k-1} b`` (CCF), poles and residues
(MCF), and a user-supplied CasADi inverse of the CCF (Physical). That path is numpy float64 and
not differentiable; the forward path (``theta -> System``) is torch and differentiable.

CasADi view (for the refinement, ``refine.py``): :meth:`Structure.element_bounds` gives the
closure of every constraint map's range as ``(lo, hi)``, and :meth:`Structure.casadi_system` the
same assembly ``elements -> (A, b, c, d)`` with CasADi operations, so that an NLP over the
elements keeps the structure and its constraints exactly.

Tolerances: a model element counts as satisfying a closed constraint (Descartes ``a_i >= 0``,
bounds) or a fixed value if it does so within ``sqrt(eps) * (1 + max|element|)`` of its row
(``eps`` of the model's dtype), since it is computed through eigenvalues; it is then set to the
closest admissible value. Open constraints are strict for models: an MCF pole must have
``Re < 0`` (a pole at 0 is rejected). :meth:`Structure.raw` accepts the closure of every set
(``lambda = 0`` maps to the boundary of the softplus range).
"""

from __future__ import annotations

import abc
import copy
import inspect
import itertools
import json
import math
from dataclasses import dataclass
from typing import Any, ClassVar

import casadi
import control
import numpy as np
import torch
import torch.nn.functional as F

from aeid_struct.structures.casadi_torch import CasadiOp

__all__ = ["CCF", "MCF", "Physical", "Structure", "System"]

#: Margin that keeps MCF real parts strictly negative (and omega strictly positive) when softplus
#: underflows to 0 for very negative theta.
_MARGIN = 1e-8
#: Largest number of mode orderings MCF.elements_of tries when matching fixed elements.
_MAX_PERMUTATIONS = 5040


# ---------------------------------------------------------------------------------------------
# The assembled model
# ---------------------------------------------------------------------------------------------
def _tensor(name: str, value) -> None:
    if not isinstance(value, (torch.Tensor, np.ndarray)):
        raise ValueError(f"{name} must be a torch tensor (or a numpy array); got "
                         f"{type(value).__name__}")


@dataclass(frozen=True, eq=False)
class System:
    """A batch of continuous-time SISO models ``xdot = A x + b u``, ``y = c^T x + d u``.

    Attributes
    ----------
    A : torch.Tensor, (batch, n, n)
    b : torch.Tensor, (batch, n)
    c : torch.Tensor, (batch, n)
    d : torch.Tensor, (batch,)

    A single model (from an unbatched ``theta``) drops the batch axis: ``A (n, n)``, ``d ()``.
    The models of a several-record structure (:attr:`Structure.records` ``R > 1``) carry a record
    axis after the batch axis: ``A (batch, R, n, n)``, ``b, c (batch, R, n)``, ``d (batch, R)``.
    """

    A: torch.Tensor
    b: torch.Tensor
    c: torch.Tensor
    d: torch.Tensor

    def __post_init__(self) -> None:
        A, b, c, d = self.A, self.b, self.c, self.d
        _tensor("A", A)
        if A.ndim not in (2, 3, 4) or A.shape[-1] != A.shape[-2]:
            raise ValueError(f"A must have shape (batch, n, n) or (n, n) (or (batch, records, "
                             f"n, n)); got {tuple(A.shape)}")
        lead, n = tuple(A.shape[:-2]), A.shape[-1]
        for name, x, shape in (("b", b, (*lead, n)), ("c", c, (*lead, n)), ("d", d, lead)):
            _tensor(name, x)
            if tuple(x.shape) != shape:
                raise ValueError(
                    f"{name} must have shape {shape} to match A {tuple(A.shape)}; "
                    f"got {tuple(x.shape)}"
                )

    @property
    def n(self) -> int:
        """The order (number of states)."""
        return self.A.shape[-1]

    def to_control(self) -> list[control.StateSpace] | control.StateSpace:
        """python-control models (float64): a list for a batch, one StateSpace for one model."""
        A, b, c, d = (x.detach().cpu().to(torch.float64).numpy() for x in self)
        if A.ndim == 2:
            return control.ss(A, b[:, None], c[None, :], d.reshape(1, 1))
        if A.ndim == 4:   # (batch, records, n, n): a list per batch row
            return [System(*(torch.from_numpy(x[i]) for x in (A, b, c, d))).to_control()
                    for i in range(A.shape[0])]
        return [
            control.ss(A[i], b[i][:, None], c[i][None, :], d[i].reshape(1, 1))
            for i in range(A.shape[0])
        ]

    def __iter__(self):
        """Unpack as ``A, b, c, d = system``."""
        return iter((self.A, self.b, self.c, self.d))


# ---------------------------------------------------------------------------------------------
# Elementwise constraint maps
# ---------------------------------------------------------------------------------------------
def _inv_softplus(y: torch.Tensor) -> torch.Tensor:
    # softplus(t) = log(1 + e^t)  =>  t = log(e^y - 1) = y + log(1 - e^-y); expm1 keeps it exact
    # for small y, and for large y log(1 - e^-y) -> 0 without overflow.
    return y + torch.log(-torch.expm1(-y))


@dataclass(frozen=True)
class _Map:
    """The constraint map of one element: ``kind`` in real, nonneg, pos, neg, interval."""

    kind: str
    lo: float = -math.inf
    hi: float = math.inf
    note: str = ""

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        if self.kind == "real":
            return t
        if self.kind == "nonneg":
            return F.softplus(t)
        if self.kind == "pos":
            return F.softplus(t) + _MARGIN
        if self.kind == "neg":
            return -(F.softplus(t) + _MARGIN)
        # interval: clamp only removes a rounding ulp outside [lo, hi]
        return torch.clamp(self.lo + (self.hi - self.lo) * torch.sigmoid(t), self.lo, self.hi)

    def inverse(self, x: torch.Tensor) -> torch.Tensor:
        """theta for element values ``x`` in the closure of the set, clamped at its boundary."""
        tiny = torch.finfo(x.dtype).eps
        if self.kind == "real":
            return x
        if self.kind == "nonneg":
            return _inv_softplus(torch.clamp(x, min=tiny))
        if self.kind == "pos":
            return _inv_softplus(torch.clamp(x - _MARGIN, min=tiny))
        if self.kind == "neg":
            return _inv_softplus(torch.clamp(-x - _MARGIN, min=tiny))
        u = (x - self.lo) / (self.hi - self.lo)
        return torch.logit(torch.clamp(u, tiny, 1.0 - tiny))

    def admits(self, x: torch.Tensor, atol: torch.Tensor | float, *, open_: bool = False):
        """Whether ``x`` lies in the closure of the set, up to ``atol``.

        With ``open_``, the open sets (``pos``, ``neg``) are checked as open, without tolerance:
        a given model's pole at 0 is not in the open left half-plane.
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
        """The closest point of the closure of the set."""
        if self.kind in ("nonneg", "pos"):
            return torch.clamp(x, min=0.0)
        if self.kind == "neg":
            return torch.clamp(x, max=0.0)
        if self.kind == "interval":
            return torch.clamp(x, self.lo, self.hi)
        return x

    def holds(self, v: float) -> bool:
        """Whether a value to be fixed satisfies the constraint exactly (open sets stay open)."""
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
        """The closure of the map's range, ``(lo, hi)``: what the refinement imposes as bounds."""
        return {
            "real": (-math.inf, math.inf),
            "nonneg": (0.0, math.inf),
            "pos": (_MARGIN, math.inf),
            "neg": (-math.inf, -_MARGIN),
            "interval": (self.lo, self.hi),
        }[self.kind]

    def describe(self, name: str) -> str:
        rule = {
            "real": f"{name} finite",
            "nonneg": f"{name} >= 0",
            "pos": f"{name} > 0",
            "neg": f"{name} < 0",
            "interval": f"{self.lo:g} <= {name} <= {self.hi:g}",
        }[self.kind]
        return f"{rule} ({self.note})" if self.note else rule


# ---------------------------------------------------------------------------------------------
# Numeric helpers for models given in any realisation (numpy float64, batched)
# ---------------------------------------------------------------------------------------------
def _numpy(x: Any) -> np.ndarray:
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu()
        return x.numpy().astype(np.float64) if x.is_floating_point() else x.double().numpy()
    return np.asarray(x, dtype=np.float64)


def _flag(name: str, value) -> bool:
    """A constructor's switch: True or False only. Why: ``bool("no")`` is True, so a string or
    None would otherwise silently turn a constraint on or off."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False; got {value!r}")
    return bool(value)


def _model_dtype(A: Any) -> torch.dtype:
    if isinstance(A, torch.Tensor) and A.dtype in (torch.float32, torch.float64):
        return A.dtype
    if isinstance(A, np.ndarray) and A.dtype == np.float32:
        return torch.float32
    return torch.float64


def _model_arrays(A, b, c, d, n: int, who: str, records: int = 1):
    """Batched float64 arrays ``A (B, n, n), b (B, n), c (B, n), d (B,)`` and whether batched.

    With ``records = R > 1`` the models carry a record axis, ``A (batch, R, n, n)`` or
    ``(R, n, n)``, ...; they come back flattened, ``B = batch * R`` rows, record-minor."""
    if records > 1:
        A_ = _numpy(A)
        if A_.ndim not in (3, 4) or A_.shape[-3:] != (records, n, n):
            raise ValueError(f"A must have shape (batch, {records}, {n}, {n}) or ({records}, {n}, "
                             f"{n}) for {who}; got {A_.shape}")
        batched = A_.ndim == 4
        lead = A_.shape[:-2]
        parts = {}
        for name, x, shape in (("b", b, (*lead, n)), ("c", c, (*lead, n)), ("d", d, lead)):
            try:
                parts[name] = np.broadcast_to(_numpy(x), shape)
            except ValueError:
                raise ValueError(f"{name} must have shape {shape} to match A {A_.shape}; "
                                 f"got {_numpy(x).shape}") from None
        flat = _model_arrays(A_.reshape(-1, n, n), parts["b"].reshape(-1, n),
                             parts["c"].reshape(-1, n), parts["d"].reshape(-1), n, who)
        return (*flat[:4], batched)
    A_, b_, c_, d_ = _numpy(A), _numpy(b), _numpy(c), _numpy(d)
    if A_.ndim not in (2, 3) or A_.shape[-2:] != (n, n):
        raise ValueError(f"A must have shape (batch, {n}, {n}) or ({n}, {n}) for {who}; "
                         f"got {A_.shape}")
    batched = A_.ndim == 3
    B = A_.shape[0] if batched else 1
    lead = (B,) if batched else ()
    allowed = {
        "b": [(*lead, n), (*lead, n, 1)],
        "c": [(*lead, n), (*lead, 1, n)],
        "d": [lead, (*lead, 1), (*lead, 1, 1)] + ([()] if batched else []),
    }
    out = {}
    for name, x in (("b", b_), ("c", c_), ("d", d_)):
        if x.shape not in allowed[name]:
            raise ValueError(f"{name} must have shape {allowed[name][0]} to match A {A_.shape}; "
                             f"got {x.shape}")
        out[name] = np.broadcast_to(x, (B,)) if name == "d" and x.shape == () else x
    A_, b_ = A_.reshape(B, n, n), out["b"].reshape(B, n)
    c_, d_ = out["c"].reshape(B, n), np.asarray(out["d"]).reshape(B)
    for name, x in (("A", A_), ("b", b_), ("c", c_), ("d", d_)):
        if not np.all(np.isfinite(x)):
            raise ValueError(f"{name} must be finite; got nan or inf")
    return A_, b_, c_, d_.copy(), batched


def _ccf_coefficients(A: np.ndarray, b: np.ndarray, c: np.ndarray):
    """CCF ``a (B, n)``, ``c (B, n)`` of any realisation, ``G = sum c_j s^j / (s^n + sum a_i s^i)``.

    Denominator: the characteristic polynomial from the eigenvalues (as np.poly), batched.
    Numerator: expand ``N(s) = D(s) G(s)`` with ``G(s) = sum_k h_k s^-k``, ``h_k = c A^{k-1} b``
    (Markov parameters); matching the coefficient of ``s^{n-m}`` gives
    ``c_{n-m} = sum_{i=0}^{m-1} den_i h_{m-i}`` (``den_0 = 1``), which stays accurate relative
    to the size of ``c`` (unlike ``charpoly(A - b c^T) - charpoly(A)``).
    """
    B, n = b.shape
    roots = np.linalg.eigvals(A)
    den = np.ones((B, 1), dtype=complex)
    for k in range(n):
        pad = np.zeros((B, 1))
        den = np.concatenate([den, pad], 1) - roots[:, k : k + 1] * np.concatenate([pad, den], 1)
    den = den.real
    h = np.empty((B, n))
    v = b.copy()
    for k in range(n):
        h[:, k] = np.einsum("bi,bi->b", c, v)
        v = np.einsum("bij,bj->bi", A, v)
    num = np.empty((B, n))
    for m in range(1, n + 1):
        num[:, n - m] = sum(den[:, i] * h[:, m - i - 1] for i in range(m))
    return den[:, :0:-1].copy(), num


def _ccf_matrices(a: np.ndarray, c: np.ndarray):
    """Bottom-row CCF ``A (B, n, n)``, ``b (B, n)``, ``c (B, n)`` from its coefficients."""
    B, n = a.shape
    A = np.zeros((B, n, n))
    A[:, np.arange(n - 1), np.arange(1, n)] = 1.0
    A[:, -1, :] = -a
    b = np.zeros((B, n))
    b[:, -1] = 1.0
    return A, b, c


def _atol(x: torch.Tensor, factor: float) -> torch.Tensor:
    """Per-row tolerance ``factor * (1 + max|x|)``, shape (batch,) like a column of ``x``."""
    return factor * (1.0 + torch.nan_to_num(x, nan=0.0, posinf=0.0, neginf=0.0).abs().amax(1))


def _rows(mask: torch.Tensor) -> list[int]:
    return torch.nonzero(mask).flatten()[:5].tolist()


# ---------------------------------------------------------------------------------------------
# The base class
# ---------------------------------------------------------------------------------------------
class Structure(abc.ABC):
    """A parameterisation ``theta (batch, p) -> elements (batch, q) -> System``.

    Subclasses define the elements (names and constraint maps), :meth:`_assemble` and
    :meth:`_elements_of`; fixing elements, validation, ``raw``, configuration and the
    conversions live here.
    """

    _registry: ClassVar[dict[str, type[Structure]]] = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        Structure._registry[cls.__name__] = cls

    def __init__(self, n: int, maps: dict[str, _Map]) -> None:
        self._n = n
        self._maps = dict(maps)
        self._fixed: dict[str, float] = {}

    # -- names and sizes ------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Order of the models (number of states)."""
        return self._n

    @property
    def element_names(self) -> tuple[str, ...]:
        """All elements, in the column order of :meth:`elements`."""
        return tuple(self._maps)

    @property
    def free_names(self) -> tuple[str, ...]:
        """Elements that are estimated: one column of ``theta`` each, in this order."""
        return tuple(nm for nm in self._maps if nm not in self._fixed)

    @property
    def fixed_values(self) -> dict[str, float]:
        """The fixed elements and their values."""
        return dict(self._fixed)

    @property
    def records(self) -> int:
        """Records (SISO systems) each parameter vector describes: 1, or ``R`` for a
        :class:`Physical` map of several systems (module docstring)."""
        return 1

    @property
    def p(self) -> int:
        """Number of raw parameters (width of ``theta``)."""
        return len(self._maps) - len(self._fixed)

    @property
    def q(self) -> int:
        """Number of elements (width of :meth:`elements`)."""
        return len(self._maps)

    # -- fixing elements ------------------------------------------------------------------------
    def fixed(self, **values: float) -> Structure:
        """A new structure with the named elements held at exactly these values.

        Composable: ``CCF(2).fixed(a1=0.0).fixed(c1=0.0)``. Raises ValueError for an unknown or
        already fixed name and for a value that violates the element's constraint.
        """
        for name, v in values.items():
            if name not in self._maps:
                hint = (" (no feedthrough: construct with feedthrough=True)"
                        if name == "d" else "")
                raise ValueError(f"unknown element {name!r} for {self!r}{hint}; valid names: "
                                 f"{', '.join(self._maps)}")
            if name in self._fixed:
                raise ValueError(f"element {name!r} of {self!r} is already fixed at "
                                 f"{self._fixed[name]!r}")
            try:
                if isinstance(v, (bool, np.bool_, str, bytes)):
                    raise TypeError   # float(True) is 1.0 and float("2") is 2.0: not numbers
                v = float(v)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be a real number; got {v!r}") from None
            if not self._maps[name].holds(v):
                raise ValueError(f"cannot fix {name}={v!r} in {self!r}: the structure requires "
                                 f"{self._maps[name].describe(name)}")
        new = copy.copy(self)
        merged = {**self._fixed, **{k: float(v) for k, v in values.items()}}
        new._fixed = {nm: merged[nm] for nm in self._maps if nm in merged}
        return new

    # -- theta <-> elements ---------------------------------------------------------------------
    def _as_batch(self, x: Any, width: int, what: str) -> tuple[torch.Tensor, bool]:
        try:
            t = torch.as_tensor(x)
        except (TypeError, ValueError, RuntimeError):   # strings, ragged lists, objects
            raise ValueError(f"{what} must be a float32 or float64 tensor of shape (batch, "
                             f"{width}) for {self!r}; got {type(x).__name__}") from None
        if not t.is_floating_point():
            raise ValueError(f"{what} must be a float32 or float64 tensor; got {t.dtype}")
        if t.ndim not in (1, 2) or t.shape[-1] != width:
            raise ValueError(f"{what} must have shape (batch, {width}) for {self!r}; "
                             f"got {tuple(t.shape)}")
        squeeze = t.ndim == 1
        t = t.unsqueeze(0) if squeeze else t
        bad = ~torch.isfinite(t).all(1)
        if bool(bad.any()):
            raise ValueError(f"{what} must be finite; got nan or inf in row(s) {_rows(bad)}")
        return t, squeeze

    def elements(self, theta: torch.Tensor) -> torch.Tensor:
        """All elements ``(batch, q)`` (fixed ones included) from raw ``theta (batch, p)``.

        Each free element is its constraint map applied to its own column of ``theta``.
        An unbatched ``theta (p,)`` gives ``(q,)``.
        """
        t, squeeze = self._as_batch(theta, self.p, "theta")
        cols, j = [], 0
        for name, m in self._maps.items():
            if name in self._fixed:
                cols.append(t.new_full((t.shape[0],), self._fixed[name]))
            else:
                cols.append(m.forward(t[:, j]))
                j += 1
        x = torch.stack(cols, dim=1)
        return x[0] if squeeze else x

    def _check_fixed_columns(self, x: torch.Tensor, atol, what: str) -> None:
        for i, name in enumerate(self._maps):
            if name in self._fixed:
                v = self._fixed[name]
                bad = (x[:, i] - v).abs() > atol
                if bool(bad.any()):
                    r = _rows(bad)[0]
                    raise ValueError(f"{what}: element {name} is fixed at {v!r} in {self!r}; "
                                     f"got {x[r, i].item():.6g} (row {r})")

    def _check_constraints(self, x: torch.Tensor, atol, what: str, open_: bool = False) -> None:
        for i, (name, m) in enumerate(self._maps.items()):
            if name not in self._fixed:
                bad = ~m.admits(x[:, i], atol, open_=open_)
                if bool(bad.any()):
                    r = _rows(bad)[0]
                    raise ValueError(f"{what} violates the constraint {m.describe(name)} of "
                                     f"{self!r}: {name} = {x[r, i].item():.6g} (row {r})")

    def raw(self, elements: torch.Tensor) -> torch.Tensor:
        """Raw ``theta (batch, p)`` for ``elements (batch, q)``: the inverse constraint map.

        Elements on the boundary of an open set (``a_i = 0`` for Descartes, ``lambda = 0``,
        ``k = lo``) are clamped to the nearest value the map reaches, ``eps`` of the dtype
        inside (``raw(0) = log(expm1(eps))`` for softplus, ``logit(eps)`` for an interval).
        Elements outside the constraints, or fixed elements not at their values, raise
        ValueError.
        """
        x, squeeze = self._as_batch(elements, self.q, "elements")
        atol = _atol(x, 8 * torch.finfo(x.dtype).eps)
        self._check_fixed_columns(x, atol, "elements")
        self._check_constraints(x, atol, "elements")
        cols = [m.inverse(m.project(x[:, i])) for i, (nm, m) in enumerate(self._maps.items())
                if nm not in self._fixed]
        t = torch.stack(cols, 1) if cols else x.new_zeros((x.shape[0], 0))
        return t[0] if squeeze else t

    # -- elements -> System ---------------------------------------------------------------------
    def assemble(self, elements: torch.Tensor) -> System:
        """The System ``A (batch, n, n), b, c (batch, n), d (batch,)`` of ``elements (batch, q)``.

        Fixed columns must hold their fixed values (as :meth:`elements` writes them).
        """
        x, squeeze = self._as_batch(elements, self.q, "elements")
        self._check_fixed_columns(x, _atol(x, 8 * torch.finfo(x.dtype).eps), "elements")
        return self._system(x, squeeze)

    def _system(self, x: torch.Tensor, squeeze: bool) -> System:
        sys = self._assemble(x)
        return System(sys.A[0], sys.b[0], sys.c[0], sys.d[0]) if squeeze else sys

    def __call__(self, theta: torch.Tensor) -> System:
        """``assemble(elements(theta))``: raw ``theta (batch, p)`` -> System."""
        x = self.elements(theta)  # validated here; its fixed columns are right by construction
        return self._system(x[None], True) if x.ndim == 1 else self._system(x, False)

    def to_control(self, theta: torch.Tensor):
        """python-control models of ``theta``: a list for a batch (:meth:`System.to_control`)."""
        return self(theta).to_control()

    def _column(self, x: torch.Tensor, name: str) -> torch.Tensor:
        return x[:, list(self._maps).index(name)]

    @abc.abstractmethod
    def _assemble(self, x: torch.Tensor) -> System:
        """System of batched elements ``x (batch, q)``."""

    # -- CasADi view (used by the refinement, refine.py) ---------------------------------------
    def element_bounds(self) -> dict[str, tuple[float, float]]:
        """name -> ``(lo, hi)`` for every element: the closed set that the elements of this
        structure's models fill, which the refinement imposes as bounds.

        The closure of each constraint map's range: ``(-inf, inf)`` for a free real,
        ``(0, inf)`` for a Descartes coefficient, ``(-inf, -1e-8)`` for an MCF real part (the
        map's margin keeps it strictly negative), ``(1e-8, inf)`` for ``omega``, the given
        ``(lo, hi)`` for a physical parameter, and ``(v, v)`` for an element fixed at ``v``.
        """
        return {name: ((self._fixed[name],) * 2 if name in self._fixed else m.bounds())
                for name, m in self._maps.items()}

    def casadi_system(self, x) -> tuple:
        """``(A (n, n), b (n, 1), c (n, 1), d (1, 1))`` of the elements ``x`` as CasADi values.

        Parameters
        ----------
        x : casadi SX, MX or DM ``(q, 1)`` (or a sequence of q numbers), all elements in
            :attr:`element_names` order, fixed ones included (they are used as given; the
            refinement passes the fixed values as constants).

        The same assembly as :meth:`assemble` (``c`` as a column: ``y = c^T x + d u``), written
        with CasADi operations so that it can enter a symbolic expression graph. A
        :class:`Physical` structure calls its CasADi map: inlined for an SX or MX map of
        elementary operations, a call node otherwise (external and callback functions too).
        """
        if not isinstance(x, (casadi.SX, casadi.MX, casadi.DM)):
            x = casadi.DM(np.asarray(x, dtype=np.float64).reshape(-1))
        if x.shape != (self.q, 1):
            raise ValueError(f"x must have shape ({self.q}, 1) for {self!r}; got {x.shape}")
        return self._casadi_assemble(x)

    def _casadi_assemble(self, x) -> tuple:
        """CasADi ``(A, b, c, d)`` of the elements ``x (q, 1)``; see :meth:`casadi_system`."""
        raise NotImplementedError(f"{type(self).__name__} has no CasADi assembly")

    # -- a given model -> elements ----------------------------------------------------------------
    @abc.abstractmethod
    def _elements_of(self, A, b, c, d, strict: bool) -> np.ndarray:
        """Elements ``(B, q)`` (float64) of batched float64 models, before constraint checks."""

    def _align(self, x: torch.Tensor, atol: torch.Tensor) -> torch.Tensor:
        """Hook: choose among equivalent element vectors (MCF mode order)."""
        return x

    def _check_range(self, x: torch.Tensor, A, b, c, d, dtype: torch.dtype) -> None:
        """Hook: check that the elements rebuild the given model (Physical)."""
        return None

    def elements_of(self, A, b, c, d=0.0, *, strict: bool = True) -> torch.Tensor:
        """Elements ``(batch, q)`` of a given model, in any realisation (not differentiable).

        Parameters
        ----------
        A : (batch, n, n) or (n, n), numpy or torch
        b : (batch, n) or (n,) (also (.., n, 1))
        c : (batch, n) or (n,) (also (.., 1, n))
        d : (batch,), scalar, default 0
        strict : bool
            If True (default), raise ValueError when the model violates the structure's
            constraints (a fixed element with another value, a Descartes coefficient < 0, a pole
            outside the left half-plane, a physical parameter out of bounds, a model outside the
            range of a physical map). If False, return the closest admissible elements instead
            (clipped elementwise, fixed ones set to their values). Models that have no elements
            at all in this structure (wrong pole pattern, repeated poles) raise either way.

        Returns
        -------
        torch.Tensor (batch, q), or (q,) for an unbatched model; the dtype of a torch or float32
        numpy ``A``, else float64.
        """
        dtype = _model_dtype(A)
        A_, b_, c_, d_, batched = _model_arrays(A, b, c, d, self.n, repr(self), self.records)
        x = torch.from_numpy(self._elements_of(A_, b_, c_, d_, strict))
        atol = _atol(x, math.sqrt(torch.finfo(dtype).eps))
        x = self._align(x, atol)
        if strict:
            self._check_fixed_columns(x, atol, "the model")
            self._check_constraints(x, atol, "the model", open_=True)
        x = x.clone()
        for i, (name, m) in enumerate(self._maps.items()):
            x[:, i] = self._fixed[name] if name in self._fixed else m.project(x[:, i])
        if strict:
            self._check_range(x, A_, b_, c_, d_, dtype)
        x = x.to(dtype)
        return x if batched else x[0]

    def theta_of(self, A, b, c, d=0.0, *, strict: bool = True) -> torch.Tensor:
        """``raw(elements_of(A, b, c, d))``: raw parameters ``(batch, p)`` of a given model."""
        return self.raw(self.elements_of(A, b, c, d, strict=strict))

    def _no_feedthrough(self, d: np.ndarray, strict: bool) -> None:
        if strict and np.any(np.abs(d) > 0.0):
            r = int(np.flatnonzero(np.abs(d) > 0.0)[0])
            raise ValueError(f"the model has feedthrough d = {d[r]:.6g} (row {r}) but {self!r} "
                             "has none; construct it with feedthrough=True")

    # -- configuration --------------------------------------------------------------------------
    @abc.abstractmethod
    def _config(self) -> dict:
        """Constructor arguments as JSON-serialisable values."""

    def config(self) -> dict:
        """A JSON-serialisable dict from which :meth:`from_config` rebuilds this structure.

        It holds data only: a :class:`Physical` structure's CasADi maps are named
        (``aeid_struct.maps``), never serialised as code, except a user's own map, which
        :meth:`from_config` reads back only when the caller passes it again or trusts the
        config.
        """
        return {"type": type(self).__name__, **self._config(), "fixed": dict(self._fixed)}

    @staticmethod
    def from_config(config: dict, *, maps: dict | None = None,
                    trust: bool = False) -> Structure:
        """The structure described by ``config`` (the output of :meth:`config`).

        Parameters
        ----------
        config : dict
            ``{"type": name, ...constructor arguments..., "fixed": {name: value}}``.
        maps : dict name -> casadi.Function, optional
            The user maps a :class:`Physical` config names (``{"map": name, "user": true,
            ...}``), passed again; each must match the SHA-256 the config recorded.
        trust : bool
            Deserialise user maps, and the serialised Functions of configs written before
            named maps, from the config itself. A serialised CasADi Function can run shell
            commands when it is read: only for configs whose source you trust.

        Raises
        ------
        ValueError
            For an unknown type, unknown or missing entries, values of the wrong type, and map
            entries that cannot be resolved (``aeid_struct.maps.from_entry``).
        """
        from aeid_struct.structures.maps import check_maps

        check_maps(maps, trust)
        if not isinstance(config, dict) or not isinstance(config.get("type"), str):
            raise ValueError(f"config must be a dict with a 'type' entry; got {config!r}")
        kind = config["type"]
        if kind not in Structure._registry:
            raise ValueError(f"unknown structure type {kind!r}; valid types: "
                             f"{', '.join(Structure._registry)}")
        fixed = config.get("fixed", {})
        if not isinstance(fixed, dict) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in fixed.values()):
            raise ValueError(f"invalid config for {kind}: 'fixed' must be a dict name -> "
                             f"number; got {fixed!r}")
        args = {k: v for k, v in config.items() if k not in ("type", "fixed")}
        try:
            structure = Structure._registry[kind]._from_config(args, maps=maps, trust=trust)
        except (TypeError, KeyError) as e:
            raise ValueError(f"invalid config for {kind}: {e}") from None
        return structure.fixed(**fixed)

    @classmethod
    def _from_config(cls, args: dict, *, maps=None, trust: bool = False) -> Structure:
        switches = {k for k, v in inspect.signature(cls.__init__).parameters.items()
                    if isinstance(v.default, bool)}
        for key in switches & set(args):
            if not isinstance(args[key], bool):     # JSON "yes" for a switch
                raise ValueError(f"invalid config for {cls.__name__}: {key!r} must be a bool; "
                                 f"got {args[key]!r}")
        structure = cls(**args)
        # JSON of the wrong type that the constructor would coerce ("descartes": "yes")
        for key, value in structure._config().items():
            if key in args and (args[key] != value
                                or isinstance(args[key], bool) != isinstance(value, bool)):
                raise ValueError(f"invalid config for {cls.__name__}: {key!r} must be a "
                                 f"{type(value).__name__}; got {args[key]!r}")
        return structure

    def _base_repr(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self._config().items())
        return f"{type(self).__name__}({args})"

    def __repr__(self) -> str:
        fixed = ", ".join(f"{k}={v!r}" for k, v in self._fixed.items())
        return self._base_repr() + (f".fixed({fixed})" if fixed else "")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Structure) and self.config() == other.config()

    def __hash__(self) -> int:
        return hash(json.dumps(self.config(), sort_keys=True))


def _constant(x: torch.Tensor, values: list[float]) -> torch.Tensor:
    """A constant (batch, len(values)) tensor like ``x``."""
    return x.new_tensor(values).expand(x.shape[0], len(values)).clone()


def _matrix(entries: dict[tuple[int, int], torch.Tensor], n: int, like: torch.Tensor):
    """(batch, n, n) from its nonzero entries; out of place, so autograd sees every entry."""
    zero = like.new_zeros(like.shape[0])
    flat = [entries.get((i, j), zero) for i in range(n) for j in range(n)]
    return torch.stack(flat, 1).reshape(-1, n, n)


# ---------------------------------------------------------------------------------------------
# Controllable canonical form
# ---------------------------------------------------------------------------------------------
class CCF(Structure):
    """Bottom-row controllable canonical form (paper Eq. 5), see the module docstring.

    Parameters
    ----------
    n : int
        Order, >= 1.
    descartes : bool
        Constrain ``a_i = softplus(theta_i) >= 0`` (no positive real pole, by Descartes' rule of
        signs; unstable complex pairs remain possible).
    feedthrough : bool
        Estimate ``d`` (element ``"d"``); otherwise ``d = 0``.

    Elements: ``a0..a{n-1}, c0..c{n-1}`` (+ ``d``); ``p = 2n`` (+1).
    """

    def __init__(self, n: int, *, descartes: bool = False, feedthrough: bool = False) -> None:
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
            raise ValueError(f"n must be an integer >= 1; got {n!r}")
        self.descartes = _flag("descartes", descartes)
        self.feedthrough = _flag("feedthrough", feedthrough)
        a_map = _Map("nonneg", note="Descartes") if self.descartes else _Map("real")
        maps = {f"a{i}": a_map for i in range(n)}
        maps |= {f"c{i}": _Map("real") for i in range(n)}
        if self.feedthrough:
            maps["d"] = _Map("real")
        super().__init__(int(n), maps)

    def _config(self) -> dict:
        return {"n": self.n, "descartes": self.descartes, "feedthrough": self.feedthrough}

    def _assemble(self, x: torch.Tensor) -> System:
        n = self.n
        one = x.new_ones(x.shape[0])
        entries = {(i, i + 1): one for i in range(n - 1)}
        entries |= {(n - 1, j): -x[:, j] for j in range(n)}
        b = _constant(x, [0.0] * (n - 1) + [1.0])
        d = self._column(x, "d") if self.feedthrough else x.new_zeros(x.shape[0])
        return System(_matrix(entries, n, x), b, x[:, n : 2 * n], d)

    def _casadi_assemble(self, x) -> tuple:
        n = self.n
        A = type(x).zeros(n, n)
        for i in range(n - 1):
            A[i, i + 1] = 1.0
        A[n - 1, :] = -x[:n].T
        b = casadi.DM([0.0] * (n - 1) + [1.0])
        d = x[2 * n] if self.feedthrough else casadi.DM(0.0)
        return A, b, x[n : 2 * n], d

    def _elements_of(self, A, b, c, d, strict):
        if not self.feedthrough:
            self._no_feedthrough(d, strict)
        a, num = _ccf_coefficients(A, b, c)
        return np.concatenate([a, num] + ([d[:, None]] if self.feedthrough else []), 1)


# ---------------------------------------------------------------------------------------------
# Modal canonical form
# ---------------------------------------------------------------------------------------------
class MCF(Structure):
    """Modal canonical form (paper Eq. 6), stable by construction; see the module docstring.

    Parameters
    ----------
    real : int
        Number of real poles ``lambda_i < 0``.
    pairs : int
        Number of complex pairs ``delta_j +- i omega_j``, ``delta_j < 0 < omega_j``.
    feedthrough : bool
        Estimate ``d``; otherwise ``d = 0``.

    Order ``n = real + 2 pairs``; ``b`` is fixed (1 per real mode, ``(0, 1)`` per pair) and ``c``
    estimated: ``p = 2n`` (+1) raw parameters, where the paper counts ``3n``.
    """

    def __init__(self, *, real: int = 0, pairs: int = 1, feedthrough: bool = False) -> None:
        for name, v in (("real", real), ("pairs", pairs)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise ValueError(f"{name} must be an integer >= 0; got {v!r}")
        if real == 0 and pairs == 0:
            raise ValueError("MCF needs at least one mode; got real=0 and pairs=0")
        self.real, self.pairs = int(real), int(pairs)
        self.feedthrough = _flag("feedthrough", feedthrough)
        n = self.real + 2 * self.pairs
        hurwitz = "poles in the open left half-plane"
        maps = {f"lambda{i}": _Map("neg", note=hurwitz) for i in range(self.real)}
        for j in range(self.pairs):
            maps[f"delta{j}"] = _Map("neg", note=hurwitz)
            maps[f"omega{j}"] = _Map("pos", note="imaginary part of the upper pole")
        maps |= {f"c{i}": _Map("real") for i in range(n)}
        if self.feedthrough:
            maps["d"] = _Map("real")
        super().__init__(n, maps)

    def _config(self) -> dict:
        return {"real": self.real, "pairs": self.pairs, "feedthrough": self.feedthrough}

    def _assemble(self, x: torch.Tensor) -> System:
        r, n = self.real, self.n
        entries = {(i, i): x[:, i] for i in range(r)}
        for j in range(self.pairs):
            k = r + 2 * j
            delta, omega = x[:, r + 2 * j], x[:, r + 2 * j + 1]
            entries |= {(k, k): delta, (k, k + 1): omega, (k + 1, k): -omega,
                        (k + 1, k + 1): delta}
        b = _constant(x, [1.0] * r + [0.0, 1.0] * self.pairs)
        d = self._column(x, "d") if self.feedthrough else x.new_zeros(x.shape[0])
        return System(_matrix(entries, n, x), b, x[:, n : 2 * n], d)

    def _casadi_assemble(self, x) -> tuple:
        r, n = self.real, self.n
        A = type(x).zeros(n, n)
        for i in range(r):
            A[i, i] = x[i]
        for j in range(self.pairs):
            k = r + 2 * j
            delta, omega = x[k], x[k + 1]
            A[k, k], A[k, k + 1], A[k + 1, k], A[k + 1, k + 1] = delta, omega, -omega, delta
        b = casadi.DM([1.0] * r + [0.0, 1.0] * self.pairs)
        d = x[2 * n] if self.feedthrough else casadi.DM(0.0)
        return A, b, x[n : 2 * n], d

    def _elements_of(self, A, b, c, d, strict):
        if not self.feedthrough:
            self._no_feedthrough(d, strict)
        B, n, r = A.shape[0], self.n, self.real
        poles, V = np.linalg.eig(A)
        # A defective A (a repeated pole with a Jordan block, e.g. G = 1/(s+1)^2) has no modal
        # form; its eigenvector matrix is then (nearly) singular.
        cond = np.linalg.cond(V)
        bad = ~np.isfinite(cond) | (cond > 1e12)
        if np.any(bad):
            row = int(np.flatnonzero(bad)[0])
            raise ValueError(f"the model (row {row}) has a repeated pole without a full set of "
                             f"eigenvectors (poles {np.round(poles[row], 6)}); {self!r} cannot "
                             "represent it")
        # Residues of G at each pole: (c v_i) (w_i^T b), W = V^-1.
        cV = np.einsum("bi,bij->bj", c.astype(complex), V)
        res = cV * np.linalg.solve(V, b.astype(complex)[..., None])[..., 0]
        scale = np.abs(poles).max(1, keepdims=True)
        is_real = np.abs(poles.imag) <= math.sqrt(np.finfo(float).eps) * scale
        n_real = is_real.sum(1)
        wrong = n_real != r
        if np.any(wrong):
            row = int(np.flatnonzero(wrong)[0])
            raise ValueError(
                f"{self!r} expects {r} real pole(s) and {self.pairs} complex pair(s); the model "
                f"(row {row}) has {n_real[row]} real and {(n - n_real[row]) // 2} complex pair(s): "
                f"poles {np.round(poles[row], 6)}"
            )
        # Canonical order: real poles slowest first, then upper poles of pairs by omega;
        # lower (conjugate) poles last, unused.
        group = np.where(is_real, 0, np.where(poles.imag > 0, 1, 2))
        key = np.where(is_real, -poles.real, np.abs(poles.imag))
        order = np.lexsort((-poles.real, key, group), axis=-1)
        poles = np.take_along_axis(poles, order, 1)
        res = np.take_along_axis(res, order, 1)
        lam, cr = poles[:, :r].real, res[:, :r].real
        p, rho = poles[:, r : r + self.pairs], res[:, r : r + self.pairs]
        delta, omega = p.real, np.abs(p.imag)
        # Pair: rho/(s-p) + conj = (beta1 s + beta0) / ((s-delta)^2 + omega^2) with
        # beta1 = 2 Re rho, beta0 = -2 Re(rho conj(p)); our block gives
        # (c_b s + c_a omega - c_b delta) / (...): c_b = beta1, c_a = (beta0 + beta1 delta) / omega.
        beta1, beta0 = 2 * rho.real, -2 * (rho * np.conj(p)).real
        cb, ca = beta1, (beta0 + beta1 * delta) / omega
        x = np.empty((B, self.q))
        j = np.arange(self.pairs)
        x[:, :r], x[:, n : n + r] = lam, cr
        x[:, r + 2 * j], x[:, r + 2 * j + 1] = delta, omega
        x[:, n + r + 2 * j], x[:, n + r + 2 * j + 1] = ca, cb
        if self.feedthrough:
            x[:, -1] = d
        return x

    def _align(self, x: torch.Tensor, atol: torch.Tensor) -> torch.Tensor:
        # Among the orderings of the real modes and of the pairs, take per row the first (in
        # canonical-first order) whose elements match the fixed values.
        r, n = self.real, self.n
        if not self._fixed or math.factorial(r) * math.factorial(self.pairs) > _MAX_PERMUTATIONS:
            return x
        modes_r = [[i, n + i] for i in range(r)]
        modes_p = [[r + 2 * j, r + 2 * j + 1, n + r + 2 * j, n + r + 2 * j + 1]
                   for j in range(self.pairs)]
        names = list(self._maps)
        idx = [names.index(k) for k in self._fixed]
        vals = x.new_tensor(list(self._fixed.values()))
        out, found = x.clone(), torch.zeros(x.shape[0], dtype=torch.bool)
        for pr in itertools.permutations(range(r)):
            for pp in itertools.permutations(range(self.pairs)):
                perm = list(range(self.q))
                for slot, mode in [*zip(modes_r, (modes_r[k] for k in pr), strict=True),
                                   *zip(modes_p, (modes_p[k] for k in pp), strict=True)]:
                    for a, b in zip(slot, mode, strict=True):
                        perm[a] = b
                xp = x[:, perm]
                ok = ((xp[:, idx] - vals).abs() <= atol[:, None]).all(1)
                take = ok & ~found
                out[take] = xp[take]
                found |= ok
        return out


# ---------------------------------------------------------------------------------------------
# Physical parameters through a CasADi map
# ---------------------------------------------------------------------------------------------
class Physical(Structure):
    """Physical parameters in bounds, mapped to a state space by a CasADi function.

    Parameters
    ----------
    function : casadi.Function
        Scalar inputs (the physical parameters, e.g. ``k, d, m``; their order is the element
        order) and outputs ``"A" (n, n), "B" (n, 1), "C" (1, n), "D" (1, 1)`` (others are
        ignored) -- or, for ``R`` systems sharing the parameters, ``"A1", .., "D1", ..,
        "AR", .., "DR"`` of those shapes (then :attr:`records` is ``R``). Evaluated through
        :class:`~aeid_struct.casadi_torch.CasadiOp`, so gradients are CasADi's.
    bounds : dict name -> (lo, hi)
        For every input, ``lo < hi``: ``element = lo + (hi - lo) sigmoid(theta)``.
    inverse : casadi.Function, optional
        Inputs ``"A", "B", "C", "D"`` holding a model in bottom-row CCF (shapes as above;
        ``"A1", .., "DR"`` for ``R`` records, e.g. ``symbolic.leg.joint_inverse``), scalar
        outputs named like (a subset of) the parameters. Needed by :meth:`elements_of`,
        which first converts the given realisation to CCF. A parameter the inverse does not
        return (e.g. ``d`` of the unstable leg, which its transfer function does not contain)
        is set to its fixed value if fixed, else to the midpoint of its bounds (``raw = 0``).

    ``elements_of`` (strict) also checks that the parameters rebuild the model: the CCF
    coefficients of ``function(parameters)`` must match the model's to ``1e-6`` relative.
    """

    def __init__(self, function: casadi.Function, *, bounds: dict, inverse=None) -> None:
        if not isinstance(function, casadi.Function):
            raise ValueError(f"function must be a casadi.Function; got {type(function).__name__}")
        fname = function.name()
        names = list(function.name_in())
        for i, nm in enumerate(names):
            if function.size_in(i) != (1, 1):
                raise ValueError(f"input {nm!r} of {fname} must be a scalar (1, 1); "
                                 f"got {function.size_in(i)}")
        outs = list(function.name_out())
        records = 1
        if "A" not in outs and "A1" in outs:
            while f"A{records + 1}" in outs:
                records += 1
        # Unnumbered outputs (A, B, C, D) unless only numbered ones (A1, .., DR) are there.
        self._keys = (["A", "B", "C", "D"] if "A" in outs or "A1" not in outs
                      else [f"{k}{r}" for r in range(1, records + 1) for k in "ABCD"])
        missing = [k for k in self._keys if k not in outs]
        if missing:
            raise ValueError(f"function {fname} must have outputs A, B, C, D; missing "
                             f"{', '.join(missing)} (outputs: {', '.join(outs)}; for several "
                             "records: A1, B1, C1, D1, A2, ..)")
        n = function.size_out(self._keys[0])[0]
        shapes = {k: {"A": (n, n), "B": (n, 1), "C": (1, n), "D": (1, 1)}[k[0]]
                  for k in self._keys}
        for k, s in shapes.items():
            if function.size_out(k) != s:
                raise ValueError(f"output {k!r} of {fname} must have shape {s}; "
                                 f"got {function.size_out(k)}")
        self._records = records
        if not isinstance(bounds, dict):
            raise ValueError(f"bounds must be a dict name -> (lo, hi); got {type(bounds).__name__}")
        for k in bounds:
            if k not in names:
                raise ValueError(f"bounds has unknown name {k!r}; inputs of {fname}: "
                                 f"{', '.join(names)}")
        maps = {}
        for k in names:
            if k not in bounds:
                raise ValueError(f"bounds is missing {k!r}; every input of {fname} needs "
                                 f"bounds: {', '.join(names)}")
            try:
                lo, hi = (float(v) for v in bounds[k])
            except (TypeError, ValueError):
                raise ValueError(f"bounds[{k!r}] must be a pair (lo, hi); "
                                 f"got {bounds[k]!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi)):
                raise ValueError(f"bounds[{k!r}] must be finite; got {tuple(bounds[k])}")
            if not lo < hi:
                raise ValueError(f"bounds[{k!r}] must satisfy lo < hi; got {tuple(bounds[k])}")
            maps[k] = _Map("interval", lo, hi, note="bounds")
        if inverse is not None:
            self._check_inverse(inverse, shapes, names, fname)
        self.function, self.inverse = function, inverse
        if outs != self._keys:
            # Keep only A, B, C, D so that CasadiOp neither computes nor differentiates the rest.
            function = function.slice(fname, list(range(len(names))),
                                      [outs.index(k) for k in self._keys])
        self._op = CasadiOp(function)
        self._inverse_op = None if inverse is None else CasadiOp(inverse)
        super().__init__(n, maps)

    @staticmethod
    def _check_inverse(inverse, shapes, names, fname) -> None:
        if not isinstance(inverse, casadi.Function):
            raise ValueError(f"inverse must be a casadi.Function; got {type(inverse).__name__}")
        if sorted(inverse.name_in()) != sorted(shapes):
            raise ValueError(f"inverse {inverse.name()} must have inputs {', '.join(shapes)}; "
                             f"got {', '.join(inverse.name_in())}")
        for k, s in shapes.items():
            if inverse.size_in(k) != s:
                raise ValueError(f"input {k!r} of inverse {inverse.name()} must have shape {s}; "
                                 f"got {inverse.size_in(k)}")
        for i, k in enumerate(inverse.name_out()):
            if k not in names:
                raise ValueError(f"output {k!r} of inverse {inverse.name()} is not a parameter "
                                 f"of {fname} ({', '.join(names)})")
            if inverse.size_out(i) != (1, 1):
                raise ValueError(f"output {k!r} of inverse {inverse.name()} must be a scalar; "
                                 f"got {inverse.size_out(i)}")

    @property
    def records(self) -> int:
        return self._records

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """name -> (lo, hi) for every parameter."""
        return {k: (m.lo, m.hi) for k, m in self._maps.items()}

    def _config(self) -> dict:
        from aeid_struct.structures import maps as maps

        return {
            "function": maps.to_entry(self.function),
            "bounds": {k: [lo, hi] for k, (lo, hi) in self.bounds.items()},
            "inverse": None if self.inverse is None else maps.to_entry(self.inverse),
        }

    @classmethod
    def _from_config(cls, args: dict, *, maps=None, trust: bool = False) -> Physical:
        from aeid_struct.structures import maps as _maps

        unknown = sorted(set(args) - {"function", "bounds", "inverse"})
        if unknown or "function" not in args or "bounds" not in args:
            raise ValueError(f"invalid config for Physical: it needs 'function' and 'bounds' "
                             f"(and optionally 'inverse'); got entries {sorted(args)}")
        bounds = args["bounds"]
        if not isinstance(bounds, dict) or not all(
                isinstance(v, (list, tuple)) and len(v) == 2
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
                for v in bounds.values()):
            raise ValueError(f"invalid config for Physical: 'bounds' must be a dict name -> "
                             f"[lo, hi] of numbers; got {bounds!r}")
        inverse = args.get("inverse")
        return cls(
            _maps.from_entry(args["function"], "Physical 'function'", maps=maps, trust=trust),
            bounds={k: tuple(v) for k, v in bounds.items()},
            inverse=None if inverse is None else _maps.from_entry(
                inverse, "Physical 'inverse'", maps=maps, trust=trust),
        )

    def _base_repr(self) -> str:
        bounds = ", ".join(f"{k!r}: ({lo:g}, {hi:g})" for k, (lo, hi) in self.bounds.items())
        inv = "None" if self.inverse is None else self.inverse.name()
        return f"Physical({self.function.name()}, bounds={{{bounds}}}, inverse={inv})"

    def _assemble(self, x: torch.Tensor) -> System:
        out = self._op(*x.unbind(1))
        B, n, R = x.shape[0], self.n, self.records
        shape = (B,) if R == 1 else (B, R)
        parts = [out[k].reshape(B, -1) for k in self._keys]      # record-major: A1 B1 C1 D1 A2..
        A, b, c, d = (torch.stack(parts[i::4], 1).reshape(*shape, -1) for i in range(4))
        return System(A.reshape(*shape, n, n), b, c, d.reshape(shape))

    def _casadi_assemble(self, x) -> tuple:
        if self.records > 1:
            raise NotImplementedError(f"{self!r} describes {self.records} records; its CasADi "
                                      "assembly is per record (refine each subsystem alone)")
        out = self.function(**{name: x[i] for i, name in enumerate(self._maps)})
        return out["A"], out["B"], out["C"].T, out["D"]

    def _elements_of(self, A, b, c, d, strict):
        if self._inverse_op is None:
            raise ValueError(f"{self!r} has no inverse: elements_of needs "
                             "Physical(..., inverse=f) with f: (A, B, C, D) in CCF -> parameters")
        a, num = _ccf_coefficients(A, b, c)
        Ac, bc, cc = _ccf_matrices(a, num)
        R, n = self.records, a.shape[1]
        B = a.shape[0] // R          # rows come record-minor: (batch * R) models
        # B (n, 1) is a column vector -> (batch, n); C (1, n) a matrix -> (batch, 1, n).
        op = self._inverse_op
        inputs = {}
        for r in range(R):
            sfx = "" if self._keys[0] == "A" else str(r + 1)
            rows = slice(r, None, R)
            inputs.update({f"A{sfx}": Ac[rows], f"B{sfx}": bc[rows],
                           f"C{sfx}": cc[rows].reshape(B, 1, n), f"D{sfx}": d[rows]})
        found = op.evaluate(**{k: torch.from_numpy(np.ascontiguousarray(v).reshape(
            B, *op.shape_in[k])) for k, v in inputs.items()})
        x = np.empty((B, self.q))
        for i, (name, m) in enumerate(self._maps.items()):
            if name in found:
                x[:, i] = found[name].reshape(B)
                bad = ~np.isfinite(x[:, i])
                if np.any(bad):
                    raise ValueError(f"inverse {self.inverse.name()} returned a non-finite "
                                     f"{name} for the model in row {int(np.flatnonzero(bad)[0])}")
            else:
                x[:, i] = self._fixed.get(name, 0.5 * (m.lo + m.hi))
        return x

    def _check_range(self, x, A, b, c, d, dtype) -> None:
        # The parameters must rebuild the model: compare transfer functions (CCF coefficients).
        out = self._op.evaluate(*x.unbind(1))
        B, n = x.shape[0] * self.records, self.n
        # the models of each parameter row, record-minor like the given ones
        An, bn, cn, dn = (np.stack([out[k].reshape(x.shape[0], -1) for k in self._keys[i::4]],
                                   1).reshape(B, -1) for i in range(4))
        given = np.concatenate([*_ccf_coefficients(A, b, c), d[:, None]], 1)
        rebuilt = np.concatenate([*_ccf_coefficients(An.reshape(B, n, n), bn, cn), dn], 1)
        err = np.abs(given - rebuilt).max(1) / (1.0 + np.abs(given).max(1))
        tol = max(1e-6, 10 * math.sqrt(torch.finfo(dtype).eps))
        if np.any(err > tol):
            i = int(np.argmax(err))
            r = i // self.records
            raise ValueError(
                f"the model (row {r}) is not in the range of {self!r}: the transfer function "
                f"rebuilt from the recovered parameters differs by {err[i]:.3g} (relative) "
                f"in its CCF coefficients {np.round(given[i], 6)} vs {np.round(rebuilt[i], 6)}"
            )
