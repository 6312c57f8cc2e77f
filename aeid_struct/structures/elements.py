"""The named elements of a structure: ``theta (batch, p)`` <-> ``elements (batch, q)``.

Every element has its constraint map (``constraints.ElementMap``) acting on its own column of
``theta``; elements held fixed take no column (``p = q - number fixed``). :class:`ElementSet`
holds the maps and the fixed values and implements both directions with their checks;
``Structure`` adds the assembly of the elements into a model.
"""

from __future__ import annotations

import copy

import casadi
import numpy as np
import torch

from aeid_struct.structures import constraints as cons
from aeid_struct.structures.constraints import ElementMap

__all__ = ["ElementSet"]


class ElementSet:
    """Named elements with constraint maps, some held fixed: ``theta`` <-> elements.

    Parameters
    ----------
    maps : dict str -> ElementMap
        Every element's constraint map, in column order.
    """

    def __init__(self, maps: dict[str, ElementMap]) -> None:
        self._maps = dict(maps)
        self._fixed: dict[str, float] = {}

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
    def p(self) -> int:
        """Number of raw parameters (width of ``theta``)."""
        return len(self._maps) - len(self._fixed)

    @property
    def q(self) -> int:
        """Number of elements (width of :meth:`elements`)."""
        return len(self._maps)

    # -- fixing elements ------------------------------------------------------------------------
    def fixed(self, **values: float) -> ElementSet:
        """A new structure with the named elements held at exactly these values.

        Composable: ``CCF(2).fixed(a1=0.0).fixed(c1=0.0)``.

        Parameters
        ----------
        **values : float
            Element name -> value.

        Returns
        -------
        ElementSet
            A copy (of the same structure type) with those elements fixed (they leave ``theta``).

        Raises
        ------
        ValueError
            For an unknown or already fixed name and for a value that is not a real number or
            violates the element's constraint.
        """
        for name, v in values.items():
            self._check_fixable(name, v)
        new = copy.copy(self)
        merged = {**self._fixed, **{k: float(v) for k, v in values.items()}}
        new._fixed = {nm: merged[nm] for nm in self._maps if nm in merged}
        return new

    def _check_fixable(self, name: str, v) -> None:
        if name not in self._maps:
            hint = " (no feedthrough: construct with feedthrough=True)" if name == "d" else ""
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

    # -- theta <-> elements ---------------------------------------------------------------------
    def elements(self, theta: torch.Tensor) -> torch.Tensor:
        """All elements (fixed ones included) of raw ``theta``: each free element is its
        constraint map applied to its own column.

        Parameters
        ----------
        theta : (batch, p) or (p,) tensor

        Returns
        -------
        (batch, q) or (q,) tensor
        """
        t, squeeze = cons.as_batch(theta, self.p, "theta", repr(self))
        cols, j = [], 0
        for name, m in self._maps.items():
            if name in self._fixed:
                cols.append(t.new_full((t.shape[0],), self._fixed[name]))
            else:
                cols.append(m.forward(t[:, j]))
                j += 1
        x = torch.stack(cols, dim=1)
        return x[0] if squeeze else x

    def casadi_elements(self, theta):
        """:meth:`elements` of one raw ``theta`` written with CasADi operations (the fixed
        elements as constants): with :meth:`~aeid_struct.structures.Structure.casadi_system`,
        the whole map ``theta -> (A, b, c, d)`` as one expression graph.

        Parameters
        ----------
        theta : casadi SX or MX (p, 1)

        Returns
        -------
        casadi SX or MX (q, 1)
        """
        cols, j = [], 0
        for name, m in self._maps.items():
            if name in self._fixed:
                cols.append(type(theta)(self._fixed[name]))
            else:
                cols.append(m.casadi(theta[j]))
                j += 1
        return casadi.vertcat(*cols)

    def _check(self, x: torch.Tensor, atol, what: str, *, fixed: bool = True,
               constraints: bool = True, open_: bool = False) -> None:
        if fixed:
            cons.check_fixed_columns(x, self._maps, self._fixed, atol, what, repr(self))
        if constraints:
            cons.check_constraints(x, self._maps, self._fixed, atol, what, repr(self), open_)

    def raw(self, elements: torch.Tensor) -> torch.Tensor:
        """Raw ``theta`` of ``elements``: the inverse constraint map.

        Elements on the boundary of an open set (``a_i = 0`` for Descartes, ``lambda = 0``,
        ``k = lo``) are clamped to the nearest value the map reaches, ``eps`` of the dtype
        inside (``raw(0) = log(expm1(eps))`` for softplus, ``logit(eps)`` for an interval).

        Parameters
        ----------
        elements : (batch, q) or (q,) tensor

        Returns
        -------
        (batch, p) or (p,) tensor

        Raises
        ------
        ValueError
            For elements outside the constraints, or fixed elements not at their values.
        """
        x, squeeze = cons.as_batch(elements, self.q, "elements", repr(self))
        self._check(x, cons.row_tolerance(x, 8 * torch.finfo(x.dtype).eps), "elements")
        cols = [m.inverse(m.project(x[:, i])) for i, (nm, m) in enumerate(self._maps.items())
                if nm not in self._fixed]
        t = torch.stack(cols, 1) if cols else x.new_zeros((x.shape[0], 0))
        return t[0] if squeeze else t
