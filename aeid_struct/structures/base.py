r"""The Structure base class: the encoder's raw output ``theta`` -> a continuous-time SISO model.

Data flow::

    theta (batch, p) --elementwise constraint map--> elements (batch, q) --assemble--> System

``theta`` is unconstrained (what a network's last linear layer emits). Each *element* is a named
scalar of the structure (``a0``, ``c1``, ``lambda0``, ``k``, ...); its constraint map
(``constraints.ElementMap``) is applied to its own column of ``theta`` only, so the map is cheap,
invertible (:meth:`Structure.raw`) and its Jacobian is diagonal. Elements held fixed
(:meth:`Structure.fixed`) take no column of ``theta``: ``p = q - (number of fixed elements)``.
The structures themselves are ``CCF`` and ``MCF`` (``canonical.py``) and ``Physical``
(``physical.py``).

Models given from outside (:meth:`Structure.elements_of`) may come in any realisation; they are
converted through the transfer function (``realisation.py``). That path is numpy float64 and not
differentiable; the forward path (``theta -> System``) is torch and differentiable.

CasADi view (for the refinement): :meth:`Structure.element_bounds` gives the closure of every
constraint map's range as ``(lo, hi)``, and :meth:`Structure.casadi_system` the same assembly
``elements -> (A, b, c, d)`` with CasADi operations, so that an NLP over the elements keeps the
structure and its constraints exactly.

Tolerances: a model element counts as satisfying a closed constraint (Descartes ``a_i >= 0``,
bounds) or a fixed value if it does so within ``sqrt(eps) * (1 + max|element|)`` of its row
(``eps`` of the model's dtype), since it is computed through eigenvalues; it is then set to the
closest admissible value. Open constraints are strict for models: an MCF pole must have
``Re < 0`` (a pole at 0 is rejected). :meth:`Structure.raw` accepts the closure of every set
(``lambda = 0`` maps to the boundary of the softplus range).
"""

from __future__ import annotations

import abc
import math
from typing import Any

import casadi
import numpy as np
import torch

from aeid_struct.structures import constraints as cons
from aeid_struct.structures.config import Configurable, register
from aeid_struct.structures.constraints import ElementMap
from aeid_struct.structures.elements import ElementSet
from aeid_struct.structures.realisation import model_arrays
from aeid_struct.structures.system import System

__all__ = ["Structure"]


def model_dtype(A: Any) -> torch.dtype:
    """The dtype in which elements of a given model are returned.

    Parameters
    ----------
    A : array-like or torch.Tensor

    Returns
    -------
    torch.dtype
        ``A``'s dtype for a float32 or float64 tensor, float32 for a float32 numpy array,
        else float64.
    """
    if isinstance(A, torch.Tensor) and A.dtype in (torch.float32, torch.float64):
        return A.dtype
    if isinstance(A, np.ndarray) and A.dtype == np.float32:
        return torch.float32
    return torch.float64


class Structure(ElementSet, Configurable):
    """A parameterisation ``theta (batch, p) -> elements (batch, q) -> System``.

    Subclasses define the elements (names and constraint maps), ``_assemble`` and
    ``_elements_of``; fixing elements, validation, ``raw``, configuration and the conversions
    live here.

    Parameters
    ----------
    n : int
        The order of the models.
    maps : dict str -> ElementMap
        Every element's constraint map, in column order.
    """

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        register(cls)

    def __init__(self, n: int, maps: dict[str, ElementMap]) -> None:
        super().__init__(maps)
        self._n = n

    # -- names and sizes ------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """Order of the models (number of states)."""
        return self._n

    @property
    def records(self) -> int:
        """Records (SISO systems) each parameter vector describes: 1, or ``R`` for a
        ``Physical`` map of several systems."""
        return 1

    # -- elements -> System ---------------------------------------------------------------------
    def assemble(self, elements: torch.Tensor) -> System:
        """The System of ``elements``; fixed columns must hold their fixed values.

        Parameters
        ----------
        elements : (batch, q) or (q,) tensor

        Returns
        -------
        System
            ``A (batch, n, n), b, c (batch, n), d (batch,)`` (no batch axis for ``(q,)``).
        """
        x, squeeze = cons.as_batch(elements, self.q, "elements", repr(self))
        self._check(x, cons.row_tolerance(x, 8 * torch.finfo(x.dtype).eps), "elements",
                    constraints=False)
        return self._system(x, squeeze)

    def _system(self, x: torch.Tensor, squeeze: bool) -> System:
        sys = self._assemble(x)
        return System(sys.A[0], sys.b[0], sys.c[0], sys.d[0]) if squeeze else sys

    def __call__(self, theta: torch.Tensor) -> System:
        """``assemble(elements(theta))``: raw ``theta (batch, p)`` -> System."""
        x = self.elements(theta)  # validated here; its fixed columns are right by construction
        return self._system(x[None], True) if x.ndim == 1 else self._system(x, False)

    def to_control(self, theta: torch.Tensor):
        """python-control models of ``theta`` (:meth:`System.to_control`).

        Parameters
        ----------
        theta : (batch, p) or (p,) tensor

        Returns
        -------
        control.StateSpace or list of them
        """
        return self(theta).to_control()

    def _column(self, x: torch.Tensor, name: str) -> torch.Tensor:
        return x[:, list(self._maps).index(name)]

    @abc.abstractmethod
    def _assemble(self, x: torch.Tensor) -> System:
        """System of batched elements ``x (batch, q)``."""

    # -- CasADi view (used by the refinement) ---------------------------------------------------
    def element_bounds(self) -> dict[str, tuple[float, float]]:
        """The closed set that the elements of this structure's models fill, which the
        refinement imposes as bounds.

        Returns
        -------
        dict str -> (lo, hi)
            For every element, the closure of its constraint map's range: ``(-inf, inf)`` for a
            free real, ``(0, inf)`` for a Descartes coefficient, ``(-inf, -1e-8)`` for an MCF
            real part, ``(1e-8, inf)`` for ``omega``, the given ``(lo, hi)`` for a physical
            parameter, and ``(v, v)`` for an element fixed at ``v``.
        """
        return {name: ((self._fixed[name],) * 2 if name in self._fixed else m.bounds())
                for name, m in self._maps.items()}

    def casadi_system(self, x) -> tuple:
        """The assembly of :meth:`assemble` written with CasADi operations.

        ``c`` comes as a column (``y = c^T x + d u``), so that the model can enter a symbolic
        expression graph. A ``Physical`` structure calls its CasADi map: inlined for an SX or MX
        map of elementary operations, a call node otherwise.

        Parameters
        ----------
        x : casadi SX, MX or DM (q, 1), or a sequence of q numbers
            All elements in :attr:`element_names` order, fixed ones included (used as given;
            the refinement passes the fixed values as constants).

        Returns
        -------
        tuple
            ``(A (n, n), b (n, 1), c (n, 1), d (1, 1))`` as CasADi values.

        Raises
        ------
        ValueError
            If ``x`` does not have ``q`` entries.
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
        """Elements of a given model, in any realisation (not differentiable).

        Parameters
        ----------
        A : (batch, n, n) or (n, n), numpy or torch
        b : (batch, n) or (n,) (also (.., n, 1))
        c : (batch, n) or (n,) (also (.., 1, n))
        d : (batch,) or scalar, default 0
        strict : bool
            If True (default), raise ValueError when the model violates the structure's
            constraints; if False, return the closest admissible elements instead (clipped
            elementwise, fixed ones set to their values).

        Returns
        -------
        torch.Tensor (batch, q), or (q,) for an unbatched model
            In the dtype of a torch or float32 numpy ``A``, else float64.

        Raises
        ------
        ValueError
            For shapes that do not match, non-finite values, and models that have no elements
            in this structure (wrong pole pattern, repeated poles); with ``strict``, also a fixed
            element with another value, a Descartes coefficient < 0, a pole outside the left
            half-plane, a physical parameter out of bounds, a model outside the range of a
            physical map.
        """
        dtype = model_dtype(A)
        A_, b_, c_, d_, batched = model_arrays(A, b, c, d, self.n, repr(self), self.records)
        x = torch.from_numpy(self._elements_of(A_, b_, c_, d_, strict))
        atol = cons.row_tolerance(x, math.sqrt(torch.finfo(dtype).eps))
        x = self._align(x, atol)
        if strict:
            self._check(x, atol, "the model", open_=True)
        x = x.clone()
        for i, (name, m) in enumerate(self._maps.items()):
            x[:, i] = self._fixed[name] if name in self._fixed else m.project(x[:, i])
        if strict:
            self._check_range(x, A_, b_, c_, d_, dtype)
        x = x.to(dtype)
        return x if batched else x[0]

    def theta_of(self, A, b, c, d=0.0, *, strict: bool = True) -> torch.Tensor:
        """``raw(elements_of(A, b, c, d))``: the raw parameters of a given model.

        Parameters
        ----------
        A, b, c, d, strict
            As for :meth:`elements_of`.

        Returns
        -------
        torch.Tensor (batch, p), or (p,) for an unbatched model
        """
        return self.raw(self.elements_of(A, b, c, d, strict=strict))

    def _no_feedthrough(self, d: np.ndarray, strict: bool) -> None:
        if strict and np.any(np.abs(d) > 0.0):
            r = int(np.flatnonzero(np.abs(d) > 0.0)[0])
            raise ValueError(f"the model has feedthrough d = {d[r]:.6g} (row {r}) but {self!r} "
                             "has none; construct it with feedthrough=True")
