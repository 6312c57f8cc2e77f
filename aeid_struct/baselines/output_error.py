r"""Output-error least squares in a structure, from the generic start.

:func:`least_squares` minimises ``sum_k ((y_hat_k - y_k) / max|y|)^2`` over the structure's free
elements with ``scipy.optimize.least_squares``; fixed elements never move. ``y_hat`` is the exact
FOH response from rest (Eq. 10-13) of the decoder's numpy kernel
(:func:`aeid_struct.simulation.simulate_outputs`: one record is all overhead for torch). The bounds
are the structure's constraints on the elements themselves (``Structure.element_bounds``:
Descartes ``a_i >= 0``; MCF ``lambda, delta <= -1e-8``, ``omega >= 1e-8``; physical bounds).
Solver (``solver="auto"``): Levenberg-Marquardt (MINPACK) first, whose result is kept when it
satisfies the bounds -- a feasible unconstrained local minimum is a constrained one -- else the
trust-region reflective method within the bounds from the same start (``solver="trf"`` goes there
directly).

Jacobian (``jac="exact"``, the default): the sensitivity ``s_j = dx/dp_j`` obeys
``s_j' = A s_j + (dA/dp_j) x + (db/dp_j) u`` and
``dy/dp_j = (dc/dp_j)^T x + c^T s_j + (dd/dp_j) u``. Stacking ``(x, s_1, .., s_p)`` gives one block
lower-triangular system of ``n (p + 1)`` states with the outputs ``(y, dy/dp_1, .., dy/dp_p)``,
driven by the same piecewise-linear input: one exact FOH simulation yields the residual and the
whole Jacobian. ``dA/dp`` etc. are constant for CCF and MCF (both are affine in their elements) and
come from CasADi's ``jacobian`` for a ``Physical`` map (:mod:`aeid_struct.baselines.models`).
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.optimize

from aeid_struct.baselines.checks import (
    check_int,
    check_record,
    estimate,
    initial_form,
    nan_model,
    only_record,
    physical_source,
)
from aeid_struct.baselines.free_initial import least_squares_record
from aeid_struct.baselines.models import bounds, check_structure, finish, free_indices, model_of
from aeid_struct.baselines.several import least_squares_channels
from aeid_struct.baselines.start import start_vector
from aeid_struct.identification import Estimate
from aeid_struct.multi import several
from aeid_struct.simulation import check_dt, simulate_outputs
from aeid_struct.threads import one_thread

__all__ = ["JACOBIANS", "SOLVERS", "Problem", "least_squares"]

JACOBIANS = ("exact", "2-point", "3-point")
SOLVERS = ("auto", "trf")
#: Residual of a trial point whose simulation overflows (per sample, normalised units).
_OVERFLOW = 1e8


class Problem:
    """Residual ``(y_hat - y) / max|y|`` over the free elements and its exact Jacobian, both
    from one simulation of the system augmented by its sensitivities (module docstring).

    Parameters
    ----------
    model : AffineModel or CasadiModel
        The structure's model (:func:`aeid_struct.baselines.models.model_of`).
    x : (q,) array
        Every element; the free ones are overwritten by the solver's ``z``.
    y, u : (steps,) arrays
    dt : float
    exact : bool
        Compute the Jacobian from the sensitivities (True) or leave it to finite differences.
    """

    def __init__(self, model, x: np.ndarray, y, u, dt: float, exact: bool):
        self.model, self.x, self.y, self.u, self.dt = model, x.copy(), y, u, dt
        self.scale = 1.0 / float(np.max(np.abs(y)))
        self.exact = exact
        self._z = self._r = self._J = None

    def full(self, z: np.ndarray) -> np.ndarray:
        """Every element, with the free ones at ``z``.

        Parameters
        ----------
        z : (p,) array

        Returns
        -------
        (q,) array
        """
        x = self.x.copy()
        x[self.model.free] = z
        return x

    def _responses(self, x: np.ndarray) -> np.ndarray:
        """``(y, dy/dp_1, .., dy/dp_p)`` at ``x``, ``(p + 1, steps)`` (only ``y`` unless
        ``exact``)."""
        A, b, c, d = self.model.system(x)
        if not self.exact:
            return simulate_outputs(A, b, c[None], np.reshape(d, 1), self.u, self.dt)
        # One system with state (x, s_1, .., s_p), s_j = dx/dp_j, and outputs
        # (y, dy/dp_1, .., dy/dp_p): s_j' = A s_j + dA_j x + db_j u.
        dA, db, dc, dd = self.model.jacobian(x)
        n, p = A.shape[0], len(self.model.free)
        N = n * (p + 1)
        AA, bb, CC = np.zeros((N, N)), np.empty(N), np.zeros((p + 1, N))
        bb[:n], bb[n:] = b, db.reshape(-1)
        CC[0, :n] = c
        for j in range(p + 1):
            block = slice(j * n, (j + 1) * n)
            AA[block, block] = A
            if j:
                AA[block, :n] = dA[j - 1]
                CC[j, :n], CC[j, block] = dc[j - 1], c
        return simulate_outputs(AA, bb, CC, np.concatenate([np.reshape(d, 1), dd]), self.u,
                                self.dt)

    def _evaluate(self, z: np.ndarray) -> None:
        steps, p = self.y.shape[0], len(z)
        try:
            with np.errstate(all="ignore"):
                Y = self._responses(self.full(z))
            ok = bool(np.all(np.isfinite(Y)))
        except (ValueError, np.linalg.LinAlgError, OverflowError):
            ok = False
        if ok:
            r, J = (Y[0] - self.y) * self.scale, Y[1:].T * self.scale if self.exact else None
        else:  # an overflowing trial point: a large residual makes the trust region shrink
            r, J = np.full(steps, _OVERFLOW), np.zeros((steps, p))
        self._z, self._r, self._J = z.copy(), r, J

    def residual(self, z: np.ndarray) -> np.ndarray:
        """The normalised residual at the free elements ``z``.

        Parameters
        ----------
        z : (p,) array

        Returns
        -------
        (steps,) array
        """
        if self._z is None or not np.array_equal(z, self._z):
            self._evaluate(z)
        return self._r

    def jacobian(self, z: np.ndarray, *_) -> np.ndarray:
        """The residual's Jacobian at ``z`` (from the same simulation as the residual).

        Parameters
        ----------
        z : (p,) array

        Returns
        -------
        (steps, p) array
        """
        if self._z is None or not np.array_equal(z, self._z):
            self._evaluate(z)
        return self._J


@one_thread
def least_squares(y, u=None, dt: float | None = None, *, structure=None,
                  start: dict | None = None, inverse=None, jac: str = "exact",
                  solver: str = "auto", xtol: float = 1e-12, ftol: float = 1e-12,
                  gtol: float = 1e-12, max_nfev: int = 200, order: int | None = None,
                  feedthrough: bool = False, initial: str | None = None) -> Estimate:
    """Output-error least squares on the structure's free elements from a generic start.

    Minimises ``sum_k ((y_hat_k - y_k) / max|y|)^2`` with ``y_hat`` the exact FOH response from
    rest (Eq. 10-13) by ``scipy.optimize.least_squares`` within the structure's bounds (module
    docstring: solver, Jacobian). ``least_squares(record, order=n)`` on a record not at rest
    (``initial="fitted"``, the default for a :class:`~aeid_struct.records.Record`) fits a CCF of
    order ``n`` with the initial state, the output offset and a known delay
    (:func:`~aeid_struct.baselines.free_initial.least_squares_record`). The model follows
    ``initial``, not the form of ``y``: arrays fitted with ``initial="fitted"`` are that record,
    a ``Record`` fitted with ``initial="rest"`` is its samples from rest.

    Parameters
    ----------
    y : (steps,) or Record
        A record's output, or a measured ``Record`` (then ``u`` and ``dt`` come from it). With
        ``initial="fitted"`` only ``order``, ``feedthrough`` and ``max_nfev`` apply.
    u : (steps,), or None for a unit step
    dt : float, > 0
    structure : CCF, MCF or Physical
        Fixed elements stay exactly at their values (required unless ``y`` is a Record).
    start : dict name -> value, optional
        Start values for some or all elements; the rest from
        :func:`~aeid_struct.baselines.generic_start`.
    inverse : casadi.Function, optional
        CCF -> physical parameters for ``Estimate.physical`` (CCF structures).
    jac : {"exact", "2-point", "3-point"}
        Sensitivity equations, or finite differences.
    solver : {"auto", "trf"}
        ``"auto"``: lm, then trf if lm's result leaves the bounds.
    xtol, ftol, gtol : float, >= 0
        ``scipy.optimize.least_squares`` stopping rules (per solver run).
    max_nfev : int, >= 1
        Function evaluations per solver run.
    order : int >= 1, optional
        ``Record`` form: the CCF's order (required there, not given otherwise).
    feedthrough : bool
        ``Record`` form: estimate ``d`` (else 0).
    initial : {"rest", "fitted"}, optional
        What the record is: from rest (the structure's output error, ``x(0) = 0``) or
        mid-motion (``x0``, the offset and a known delay fitted, a CCF of ``order``). Default:
        ``"fitted"`` for a ``Record``, ``"rest"`` for arrays.

    Returns
    -------
    Estimate
        ``info``: method, seconds, failed, reason, start, jac, solver ("lm", "trf", "lm+trf"),
        nfev, njev, cost, status, message; the ``Record`` form: method, failed, reason, order,
        delay, start, restarts, nfev, x0, y_offset, fit (NRMSE % with ``x0`` and the offset
        fitted), cost.

    Raises
    ------
    ValueError
        For a bad argument, or a record shorter than the number of free elements.
    """
    if several(y):
        only_record("least_squares", u=u, dt=dt)
        return least_squares_channels(y, order=check_int("order", order, 1))
    form, data = initial_form("least_squares", y, u, dt, initial)
    if form == "fitted":
        for name, value in (("structure", structure), ("start", start), ("inverse", inverse)):
            if value is not None:
                raise ValueError(f"{name} must not be given with a Record or initial='fitted' "
                                 f"(a record not at rest is fitted in a free CCF: "
                                 f"least_squares(record, order=n)); got {value!r}")
        if order is None:
            raise ValueError("order must be given with a Record or initial='fitted': "
                             "least_squares(record, order=n)")
        return least_squares_record(data, order=check_int("order", order, 1),
                                    feedthrough=feedthrough,
                                    max_nfev=check_int("max_nfev", max_nfev, 1))
    if order is not None:
        raise ValueError(f"order is for a Record or initial='fitted' (least_squares(record, "
                         f"order=n)); from rest the structure gives the order; got "
                         f"order={order!r}")
    y, u, dt = data
    start_time = time.perf_counter()
    y, u = check_record(y, u)
    dt = check_dt(dt)
    check_structure(structure)
    if jac not in JACOBIANS:
        raise ValueError(f"jac must be one of {JACOBIANS}; got {jac!r}")
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}; got {solver!r}")
    for name, v in (("xtol", xtol), ("ftol", ftol), ("gtol", gtol)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite number >= 0; got {v!r}")
    max_nfev = check_int("max_nfev", max_nfev, 1)
    source = physical_source(structure, inverse)
    names = structure.element_names
    free = free_indices(structure)
    if y.shape[0] < len(free):
        raise ValueError(f"y must have at least {len(free)} samples (one per free element of "
                         f"{structure!r}); got {y.shape[0]}")
    model = model_of(structure, free)
    lo, hi = bounds(structure)
    x = start_vector(structure, model, start, y, u, dt, lo, hi)
    info = {"method": "least_squares", "failed": False, "reason": "",
            "start": dict(zip(names, x.tolist(), strict=True)), "jac": jac}
    if len(free) == 0:
        return estimate(model.system(x), info["start"], y, u, dt, start_time,
                        {**info, "solver": "none"}, source)
    bounded = bool(np.any(np.isfinite(lo[free])) or np.any(np.isfinite(hi[free])))
    # lm first where allowed: a feasible unconstrained local minimum is a constrained one.
    methods = ("trf",) if bounded and solver == "trf" else ("lm", "trf") if bounded else ("lm",)
    problem = Problem(model, x, y, u, dt, exact=jac == "exact")
    nfev = njev = 0
    for k, method in enumerate(methods):
        try:
            result = scipy.optimize.least_squares(
                problem.residual, x[free], jac=problem.jacobian if jac == "exact" else jac,
                bounds=(lo[free], hi[free]) if method == "trf" else (-np.inf, np.inf),
                method=method, x_scale="jac", xtol=xtol, ftol=ftol, gtol=gtol,
                max_nfev=max_nfev)
        except (ValueError, np.linalg.LinAlgError) as err:
            if k + 1 < len(methods):
                continue
            return estimate(nan_model(structure.n), {}, y, u, dt, start_time,
                            {**info, "solver": "+".join(methods[: k + 1]), "failed": True,
                             "reason": f"least squares failed: {type(err).__name__}: {err}"},
                            None)
        nfev, njev = nfev + int(result.nfev), njev + int(result.njev or 0)
        if np.all(result.x >= lo[free]) and np.all(result.x <= hi[free]):
            break
    x = problem.full(result.x)
    info |= {"solver": "+".join(methods[: k + 1]), "nfev": nfev, "njev": njev,
             "cost": float(result.cost), "status": int(result.status),
             "message": str(result.message)}
    return finish(structure, model, names, x, y, u, dt, start_time, info, source)
