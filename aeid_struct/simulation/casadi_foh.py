r"""The decoder's FOH simulation (Eq. 10-13) as a CasADi expression, for the refinement NLP.

CasADi has no ``expm`` plugin, so :func:`expm` is Higham's (2005) scaling and squaring with the
diagonal Pade approximant of degree 13, written with CasADi operations: with
``||M / 2^s||_1 <= theta_13 = 5.37`` its backward error is below the unit roundoff. The number of
squarings ``s`` is part of the graph, so it is fixed when a graph is built
(:func:`squarings_for` a bound on ``||M||_1``); spare squarings keep the accuracy.

:func:`casadi_simulate` uses the coefficients of the torch decoder
(:mod:`aeid_struct.simulation.kernels`): from ``x_0 = 0``, ``x_1 = E u_0 + gamma2 u_1`` with
``E = gamma1 - gamma2`` (Eq. 11 rearranged), then ``z_k = x_k - gamma2 u_k`` (``z_1 = E u_0``)
obeys ``z_{k+1} = Phi z_k + Bd u_k``, ``y_k = c^T z_k + (d + c^T gamma2) u_k`` with
``Bd = E + Phi gamma2``. The shifted state ``xi = x - gamma2 u`` of ``cont2discrete(method="foh")``
from ``k = 0`` has the same graph but starts at ``xi_0 = -gamma2 u_0``, which is carried as
``Phi^k xi_0`` and cancelled by a term as large: an unstable response with large ``p dt`` loses
all its digits. tests/test_refine.py checks the graph against
:func:`~aeid_struct.simulation.simulate` up to ``|p| dt = 30``.
"""

from __future__ import annotations

import math

import casadi
import numpy as np

from aeid_struct.records import as_array, check_dt

__all__ = ["THETA13", "augmented", "casadi_simulate", "expm", "squarings_for"]

# Pade [13/13] coefficients b_0..b_13 and its scaling threshold (Higham 2005, Table 2.3).
_PADE13 = (64764752532480000.0, 32382376266240000.0, 7771770303897600.0, 1187353796428800.0,
           129060195264000.0, 10559470521600.0, 670442572800.0, 33522128640.0, 1323241920.0,
           40840800.0, 960960.0, 16380.0, 182.0, 1.0)
#: The largest ``||M / 2^s||_1`` at which Pade [13/13] is accurate to the unit roundoff.
THETA13 = 5.371920351148152

_CASADI = (casadi.SX, casadi.MX, casadi.DM)


def squarings_for(norm: float) -> int:
    """The fewest squarings ``s >= 0`` with ``norm / 2^s <= theta_13``.

    Parameters
    ----------
    norm : float
        A bound on ``||M||_1``.

    Returns
    -------
    int

    Raises
    ------
    ValueError
        For a non-finite ``norm``.
    """
    if not math.isfinite(norm):
        raise ValueError(f"||M||_1 must be finite to choose the squarings; got {norm}")
    return max(0, math.ceil(math.log2(norm / THETA13))) if norm > THETA13 else 0


def expm(M, squarings: int | None = None):
    """Matrix exponential with CasADi operations: scaling and squaring, Pade [13/13].

    ``expm(M) = r(M / 2^s)^(2^s)`` with ``r(X) = (V - U)^{-1} (V + U)`` the diagonal Pade
    approximant of degree 13 (``U`` odd, ``V`` even in ``X``; Higham 2005); accurate to rounding
    (backward error below the unit roundoff) when ``||M||_1 / 2^s <= theta_13 = 5.37``.

    Parameters
    ----------
    M : (N, N) casadi SX, MX or DM, or numpy
    squarings : int >= 0, optional
        ``s``, fixed in the graph. Required for a symbolic ``M`` (choose it from a bound on
        ``||M||_1``, :func:`squarings_for`); for a numeric ``M`` it defaults to the fewest that
        meet the bound.

    Returns
    -------
    (N, N), the type of ``M`` (DM for numpy).

    Raises
    ------
    ValueError
        For a non-square ``M``, a symbolic ``M`` without ``squarings``, or a bad ``squarings``.
    """
    if not isinstance(M, _CASADI):
        M = casadi.DM(np.asarray(M, dtype=np.float64))
    if M.shape[0] != M.shape[1]:
        raise ValueError(f"M must be square; got shape {M.shape}")
    if squarings is None:
        if not isinstance(M, casadi.DM):
            raise ValueError("squarings must be given for a symbolic M: the graph needs a fixed "
                             "number of squarings (choose it from a bound on ||M||_1)")
        squarings = squarings_for(float(casadi.norm_1(M)))
    if isinstance(squarings, bool) or not isinstance(squarings, (int, np.integer)) \
            or squarings < 0:
        raise ValueError(f"squarings must be an integer >= 0; got {squarings!r}")
    N, b = M.shape[0], _PADE13
    X = M / 2.0 ** int(squarings)
    eye = type(X).eye(N)
    X2 = X @ X
    X4 = X2 @ X2
    X6 = X4 @ X2
    U = X @ (X6 @ (b[13] * X6 + b[11] * X4 + b[9] * X2)
             + b[7] * X6 + b[5] * X4 + b[3] * X2 + b[1] * eye)
    V = X6 @ (b[12] * X6 + b[10] * X4 + b[8] * X2) + b[6] * X6 + b[4] * X4 + b[2] * X2 \
        + b[0] * eye
    E = casadi.solve(V - U, V + U)
    for _ in range(int(squarings)):
        E = E @ E
    return E


def augmented(A, b, dt: float):
    """Eq. 10's matrix ``M = [[A dt, b dt, 0], [0, 0, 1], [0, 0, 0]]`` in CasADi.

    Parameters
    ----------
    A : (n, n) casadi SX, MX or DM
    b : (n, 1) of the same type
    dt : float, > 0

    Returns
    -------
    M : (n + 2, n + 2), the type of ``A``
        ``expm(M) = [[Phi, gamma1, gamma2], [0, 1, 1], [0, 0, 1]]``.
    """
    n = A.shape[0]
    zeros = type(A).zeros
    top = casadi.horzcat(A * dt, b * dt, zeros(n, 1))
    bottom = casadi.DM([[0.0] * n + [0.0, 1.0], [0.0] * (n + 2)])
    return casadi.vertcat(top, bottom)


def casadi_simulate(A, b, c, d, u, dt: float, *, squarings: int, free: bool = False):
    """The decoder's exact FOH response (Eq. 10-13) as a CasADi expression, ``x_0 = 0``.

    ``x_{k+1} = Phi x_k + E u_k + gamma2 u_{k+1}`` (``E = gamma1 - gamma2``, Eq. 11 rearranged),
    ``y_k = c^T x_k + d u_k``, with ``(Phi, gamma1, gamma2)`` from :func:`expm` of Eq. 10's
    matrix (:func:`augmented`); unrolled over the record (a graph of ``O(steps n^2)`` nodes) in
    the form of the module docstring, which keeps each sample's relative accuracy.

    Parameters
    ----------
    A : (n, n) CasADi (SX, MX or DM) or numpy
    b, c : (n, 1) CasADi, or numpy (n,)
    d : (1, 1) CasADi, or a numpy scalar
    u : (steps, 1) CasADi, or numpy (steps,)
    dt : float > 0
    squarings : int >= 0
        Squarings of the matrix exponential (see :func:`expm`).
    free : bool
        Also return the free-response basis ``O (steps, n)``, row ``k`` = ``c^T Phi^k``: the
        response from an initial state ``x_0`` is ``y + O x_0``.

    Returns
    -------
    y : (steps, 1) CasADi
        And ``O (steps, n)`` with ``free``.

    Raises
    ------
    ValueError
        Naming the argument with a wrong shape, or a bad ``dt`` or ``squarings``.
    """
    dt = check_dt(dt)
    A, b, c, d, u = (v if isinstance(v, _CASADI) else casadi.DM(as_array(name, v))
                     for name, v in zip("Abcdu", (A, b, c, d, u), strict=True))
    n = A.shape[0]
    for name, v, shape in (("A", A, (n, n)), ("b", b, (n, 1)), ("c", c, (n, 1)),
                           ("d", d, (1, 1))):
        if v.shape != shape:
            raise ValueError(f"{name} must have shape {shape} with n = {n} from A; "
                             f"got {v.shape}")
    if u.shape[1] != 1 or u.shape[0] < 1:
        raise ValueError(f"u must have shape (steps, 1) with steps >= 1; got {u.shape}")
    M = expm(augmented(A, b, dt), squarings)
    Phi, gamma1, gamma2 = M[:n, :n], M[:n, n], M[:n, n + 1]
    E = gamma1 - gamma2
    Bd, Dd = E + Phi @ gamma2, d + c.T @ gamma2
    steps = u.shape[0]
    # x_0 = 0, so y_0 = d u_0 and x_1 = E u_0 + gamma2 u_1. From k = 1 on, z_k = x_k - gamma2 u_k
    # (z_1 = E u_0) takes the input through one column: z_{k+1} = Phi z_k + Bd u_k,
    # y_k = c^T z_k + Dd u_k (the decoder kernel's Toeplitz form). Every term is one power of Phi
    # on E or Bd: no large start value to cancel, unlike xi_0 = -gamma2 u_0.
    y, rows, o = [d * u[0]], [c.T], c.T
    z = E * u[0]
    for k in range(1, steps):
        y.append(c.T @ z + Dd * u[k])
        if free:
            o = o @ Phi
            rows.append(o)
        if k + 1 < steps:
            z = Phi @ z + Bd * u[k]
    return (casadi.vertcat(*y), casadi.vertcat(*rows)) if free else casadi.vertcat(*y)
