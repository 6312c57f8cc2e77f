"""What a refinement is asked for (:class:`RefineConfig`) and what it answers
(:class:`RefineResult`, :class:`CacheInfo`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["MAX_SQUARINGS", "SOLVERS", "CacheInfo", "RefineConfig", "RefineResult"]

#: Squarings of the matrix exponential available at run time in the refinement's graphs
#: (``record.py``, ``compiled_graph.py``): ``||M||_1 <= theta_13 2^16``.
MAX_SQUARINGS = 16

#: The NLP solvers: CasADi's Gauss-Newton SQP (the default) and IPOPT with the same Hessian.
SOLVERS = ("sqpmethod", "ipopt")


@dataclass(frozen=True, kw_only=True)
class RefineConfig:
    """How to refine; validates itself.

    Attributes
    ----------
    solver : {"sqpmethod", "ipopt"}
        ``"sqpmethod"`` (the default: CasADi's SQP with a Gauss-Newton Hessian and the ``qrqp``
        QP solver, the fastest; docs/architecture.md) or ``"ipopt"`` (interior point, same
        Hessian).
    max_iter : int >= 1
        At most this many solver iterations per record. ``sqpmethod`` runs them in chunks of
        ten and stops, converged, after a chunk that lowers the loss by less than ``1e-9`` of
        itself: the loss's round-off floor, where the gradient cannot reach ``tol``.
    tol : float > 0
        Convergence tolerance on the gradient of ``J`` with respect to relative element
        changes: ``sqpmethod``'s ``tol_du`` and ``tol_pr``, ``ipopt``'s ``tol``.
    step_tol : float > 0
        ``sqpmethod`` also stops, converged, when its step changes no element by more than
        this, relatively (its ``min_step_size``): the Gauss-Newton step vanishes at a
        stationary point, also where noise keeps the gradient from reaching ``tol`` in the few
        iterations its linear convergence there allows.
    verbose : bool
        Print the solver's iterations; silent otherwise.
    """

    solver: str = "sqpmethod"
    max_iter: int = 100
    tol: float = 1e-12
    step_tol: float = 1e-10
    verbose: bool = False

    def __post_init__(self) -> None:
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}; got {self.solver!r}")
        if (isinstance(self.max_iter, bool) or not isinstance(self.max_iter, (int, np.integer))
                or self.max_iter < 1):
            raise ValueError(f"max_iter must be an integer >= 1; got {self.max_iter!r}")
        for name in ("tol", "step_tol"):
            v = getattr(self, name)
            if (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                    or v <= 0):
                raise ValueError(f"{name} must be a finite number > 0; got {v!r}")
            object.__setattr__(self, name, float(v))
        if not isinstance(self.verbose, bool):
            raise ValueError(f"verbose must be a bool; got {self.verbose!r}")
        object.__setattr__(self, "max_iter", int(self.max_iter))


@dataclass(frozen=True)
class RefineResult:
    """The refinement of one record.

    Attributes
    ----------
    elements : (q,) float64 array
        All elements in ``structure.element_names`` order (fixed ones at exactly their values),
        inside ``structure.element_bounds()``.
    loss_start : float
        ``J`` (Eq. 14 on the normalised record, Eq. 15, ``gamma = 0``) at the start, after
        clipping it into the bounds.
    loss : float
        ``J`` at ``elements``; ``loss <= loss_start`` always.
    iterations : int
        Solver iterations (summed over re-solves).
    success : bool
        The solver converged and its result was kept.
    seconds : float
        Wall time of the refinement.
    solver : str
        The NLP solver used.
    status : str
        The solver's return status, or why the start was kept.
    squarings : int
        The squarings of the matrix exponential at the result.
    """

    elements: np.ndarray
    loss_start: float
    loss: float
    iterations: int
    success: bool
    seconds: float
    solver: str
    status: str
    squarings: int


@dataclass(frozen=True)
class CacheInfo:
    """Solver cache counters.

    Attributes
    ----------
    builds : int
        Solvers built.
    hits : int
        Solvers reused.
    size : int
        Solvers kept now.
    """

    builds: int
    hits: int
    size: int
