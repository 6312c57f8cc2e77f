r"""The robot leg of paper Sec. IV: spring-loaded inverted pendulum, derived with CasADi.

Model (paper Fig. 2)
--------------------
A point mass ``m`` sits on a massless telescopic leg whose foot is pinned at the origin. The leg
has length ``l`` and makes the angle ``theta`` with the ground horizontal, so the mass is at

    p = (l cos(theta), l sin(theta)),        upright <=> theta = pi/2.

A linear spring (stiffness ``k``, rest length ``l0``) and a viscous damper (``d``) act along the
leg; gravity ``g`` pulls the mass down. The inputs are ``u = (F, tau)``: a force ``F`` along the
leg (positive extends it) and a hip torque ``tau`` (positive increases ``theta``).

    T = m/2 |dp/dt|^2                         (dp/dt by CasADi's jtimes, not typed in)
    V = m g p_y + k/2 (l - l0)^2
    L = T - V
    Q = (F - d ldot, tau)                     (generalised forces on (l, theta))

``Q`` follows from virtual work: ``F`` does work ``F dl`` and ``tau`` does ``tau dtheta``, because
the generalised coordinates *are* the leg length and the hip angle; the damper enters through the
Rayleigh dissipation function ``R = d/2 ldot^2`` as ``-dR/dqdot``.

Derivation (every step is CasADi differentiation, nothing typed in)
-------------------------------------------------------------------
Euler-Lagrange, ``d/dt dL/dqdot - dL/dq = Q``, with ``d/dt dL/dqdot = M(q) qddot + J qdot`` where
``M = jacobian(dL/dqdot, qdot)`` (mass matrix) and ``J qdot = jtimes(dL/dqdot, q, qdot)``, gives

    qddot = M^{-1} (Q + dL/dq - J qdot),

solved symbolically (``casadi.solve`` of an SX system expands the 2x2 inverse by minors, so the
result is an exact rational expression). With ``x = (l, ldot, theta, thetadot)`` this is
``xdot = f(x, u)``; written out, it is the textbook SLIP model

    m lddot       = m l thetadot^2 - m g sin(theta) - k (l - l0) - d ldot + F
    m l^2 thetaddot = -2 m l ldot thetadot - m g l cos(theta) + tau,

which the tests check against an independently typed NumPy version.

Choices
-------
* **Equilibrium.** The leg stands upright at rest where the spring carries the weight:
  ``x_eq = (L, 0, pi/2, 0)``, ``u_eq = 0``, ``L = l0 - m g / k``. The paper's text says
  "linearised at l = l0", but there the spring force does not balance gravity; its Eq. 16 uses
  ``L`` and is exactly the linearisation at ``l = L``, which is what we do.
* **Linearisation.** ``A = df/dx``, ``B = df/du`` by ``casadi.jacobian`` at the equilibrium;
  states and inputs of the linear model are deviations from ``(x_eq, u_eq)``. The result equals
  Eq. 16 (``eq16()`` types the paper's matrices by hand for the comparison). In floating point
  ``cos(pi/2) = 6.1e-17``, so the coupling entries between the two subsystems come out as
  ``~1e-16`` rather than an exact 0; Eq. 16's zeros hold to rounding.
* **Subsystems.** Eq. 16 decouples into the *translational* (stable) subsystem, states
  ``(l, ldot)``, input ``F``, output ``l``: ``G1 = (1/m) / (s^2 + (d/m) s + k/m)``; and the
  *rotational* (unstable) one, states ``(theta, thetadot)``, input ``tau``, output ``theta``:
  ``G2 = (1/(m L^2)) / (s^2 - g/L)``. Both are strictly proper (``D = 0``).
* **CCF.** The bottom-row controllable canonical form of DESIGN.md (paper Eq. 5): ones on the
  superdiagonal, last row ``(-a_0, ..., -a_{n-1})``, ``b = e_n``, ``c = (c_0, ..., c_{n-1})``.
  ``ccf()`` reaches it from *any* SISO realisation of any order through the characteristic
  polynomial and the Markov parameters (for ``n >= 3`` computed in a controller-Hessenberg basis
  by Householder reflections and La Budde's recursion, which stay accurate where
  Faddeev-LeVerrier does not), so nothing relies on the 2x2 structure.
* **Maps.** ``stable_map`` and ``unstable_map`` take the named scalars ``k, d, m`` and return
  ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)``. The outputs are capitalised because CasADi forbids
  an output ``d`` next to the input ``d``. ``l0`` and ``g`` are fixed when a map is built (keyword
  arguments), not inputs, so that every map shares the signature ``(k, d, m)``.
  ``unstable_map`` keeps the input ``d`` although ``G2`` does not depend on it: ``d`` is
  unidentifiable from the rotational subsystem.
* **Inverses.** Closed forms from the informative CCF entries only: ``a_0 = -A[1, 0]``,
  ``a_1 = -A[1, 1]``, ``c_0 = C[0, 0]``. ``B``, ``D`` and ``c_1`` (and ``a_1`` of ``G2``) carry no
  parameter information and are ignored; they are inputs so that an inverse accepts a map's output
  as it is. Data outside the physical domain (``c_0 <= 0``, ``L >= l0``) give negative or NaN
  parameters rather than an error: these are pure expressions, to be evaluated in batches.
* **Joint inverse.** See ``joint_inverse``: ``d`` from the stable subsystem, ``k`` and ``m`` from a
  first-order minimum-variance (generalised least squares) combination, in log space, of what the
  two subsystems say about ``k/m`` and ``m``.
* **SX, not MX.** The expressions are small and scalar-heavy; SX evaluates fastest, expands
  symbolic solves exactly, and generates compact C.
* **Code generation.** ``generate_c`` writes the maps and inverses into one C file with
  ``casadi.CodeGenerator``; ``compile_c`` builds a shared library with the system C compiler and
  loads each function with ``casadi.external``.
* **Named maps.** The six maps and inverses are decorated with ``symbolic.named.named``: each
  Function they return remembers its factory and constants,
  ``{"map": "symbolic.leg.stable_map", "args": {"l0": 0.8, "g": 9.81}}``, so that a model file
  names the map instead of holding its code (``aeid_struct.maps`` resolves the name from its
  allow-list).

Run ``python -m symbolic.leg`` to print the derivation and check it (assertions at the end).
"""

from __future__ import annotations

import math
import pathlib
import shutil
import subprocess
from typing import NamedTuple

import casadi

from .named import named

# =============================================================================
# Settings
# =============================================================================

#: Rest length of the leg spring, m (paper Sec. IV).
L0 = 0.8
#: Gravitational acceleration, m/s^2.
G = 9.81
#: Parameter ranges of the robot-leg study (paper Sec. IV): k in N/m, d in kg/s, m in kg.
RANGES = {"k": (20.0, 25.0), "d": (2.0, 5.0), "m": (0.5, 1.5)}
#: The paper's demonstration scenario (Sec. IV, Fig. 3).
SCENARIO = {"k": 24.23, "d": 2.24, "m": 1.01}

#: Names of the physical parameters, in the order every Function here takes them.
PARAMETERS = ("k", "d", "m", "l0", "g")
#: The Functions that ``generate_c`` writes and ``compile_c`` loads.
CODEGEN_FUNCTIONS = (
    "stable_map",
    "unstable_map",
    "joint_map",
    "stable_inverse",
    "unstable_inverse",
    "joint_inverse",
)


def _parameters() -> list[casadi.SX]:
    """Fresh scalar symbols ``[k, d, m, l0, g]``."""
    return [casadi.SX.sym(name) for name in PARAMETERS]


def _check_constant(name: str, value: float) -> float:
    """A finite, positive physical constant (``l0`` or ``g``) as a float."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a real number; got {type(value).__name__}") from None
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be finite and positive; got {value}")
    return value


# =============================================================================
# Model
# =============================================================================


def lagrangian() -> casadi.Function:
    """The Lagrangian ``L = T - V`` of the spring-loaded inverted pendulum.

    ``T = m/2 |dp/dt|^2`` with the mass position ``p = (l cos theta, l sin theta)`` and its velocity
    ``dp/dt = (dp/dq) qdot`` taken by ``casadi.jtimes``; ``V = m g p_y + k/2 (l - l0)^2``.

    Returns
    -------
    casadi.Function
        ``'lagrangian'``: ``q (2) = (l, theta)``, ``qdot (2)``, ``k, d, m, l0, g`` -> scalar ``L``.
        ``d`` does not enter ``L`` (the damper is a generalised force); it is an input so that all
        model Functions share the parameter list.
    """
    q, qdot = casadi.SX.sym("q", 2), casadi.SX.sym("qdot", 2)
    k, d, m, l0, g = params = _parameters()
    l, theta = q[0], q[1]
    p = casadi.vertcat(l * casadi.cos(theta), l * casadi.sin(theta))
    pdot = casadi.jtimes(p, q, qdot)
    T = 0.5 * m * casadi.dot(pdot, pdot)
    V = m * g * p[1] + 0.5 * k * (l - l0) ** 2
    return casadi.Function(
        "lagrangian", [q, qdot, *params], [T - V], ["q", "qdot", *PARAMETERS], ["L"]
    )


# =============================================================================
# Derivation: Euler-Lagrange equations by CasADi differentiation
# =============================================================================


def dynamics() -> casadi.Function:
    r"""Nonlinear equations of motion ``xdot = f(x, u)`` derived from ``lagrangian()``.

    ``qddot = M^{-1} (Q + dL/dq - J qdot)`` with ``M = d^2 L / dqdot^2``,
    ``J qdot = (d/dq dL/dqdot) qdot`` and ``Q = (F - d ldot, tau)``; see the module docstring.

    Returns
    -------
    casadi.Function
        ``'dynamics'``: ``x (4) = (l, ldot, theta, thetadot)``, ``u (2) = (F, tau)``,
        ``k, d, m, l0, g`` -> ``xdot (4)``.
    """
    q, qdot = casadi.SX.sym("q", 2), casadi.SX.sym("qdot", 2)
    u = casadi.SX.sym("u", 2)
    k, d, m, l0, g = params = _parameters()

    L = lagrangian()(q, qdot, *params)
    dL_dqdot = casadi.gradient(L, qdot)
    M = casadi.jacobian(dL_dqdot, qdot)  # mass matrix, diag(m, m l^2) up to exact zeros
    # Generalised forces: inputs by virtual work, damper by Rayleigh's R = d/2 ldot^2.
    R = 0.5 * d * qdot[0] ** 2
    Q = u - casadi.gradient(R, qdot)
    qddot = casadi.solve(M, Q + casadi.gradient(L, q) - casadi.jtimes(dL_dqdot, q, qdot))

    # State x = (l, ldot, theta, thetadot): interleave coordinates and velocities. An SX Function
    # accepts any vector of distinct symbols as an input, so x is assembled from q and qdot.
    x = casadi.vertcat(q[0], qdot[0], q[1], qdot[1])
    xdot = casadi.vertcat(qdot[0], qddot[0], qdot[1], qddot[1])
    return casadi.Function(
        "dynamics", [x, u, *params], [xdot], ["x", "u", *PARAMETERS], ["xdot"]
    )


# =============================================================================
# Equilibrium and linearisation (paper Eq. 16)
# =============================================================================


def equilibrium() -> casadi.Function:
    """The upright rest point ``x_eq = (L, 0, pi/2, 0)``, ``u_eq = 0``, ``L = l0 - m g / k``.

    Returns
    -------
    casadi.Function
        ``'equilibrium'``: ``k, d, m, l0, g`` -> ``x_eq (4)``, ``u_eq (2)``.
    """
    k, d, m, l0, g = params = _parameters()
    L = l0 - m * g / k  # the spring, compressed by m g / k, carries the weight
    x_eq = casadi.vertcat(L, 0, casadi.pi / 2, 0)
    u_eq = casadi.SX.zeros(2)
    return casadi.Function("equilibrium", params, [x_eq, u_eq], PARAMETERS, ["x_eq", "u_eq"])


def linearisation() -> casadi.Function:
    """Jacobian linearisation of ``dynamics()`` at ``equilibrium()`` (reproduces paper Eq. 16).

    ``A = df/dx (x_eq, u_eq)``, ``B = df/du (x_eq, u_eq)``, both by ``casadi.jacobian``; the linear
    model's states and inputs are deviations from the equilibrium.

    Returns
    -------
    casadi.Function
        ``'linearisation'``: ``k, d, m, l0, g`` -> ``A (4, 4)``, ``B (4, 2)``.
    """
    x, u = casadi.SX.sym("x", 4), casadi.SX.sym("u", 2)
    params = _parameters()
    xdot = dynamics()(x, u, *params)
    jac = casadi.Function(
        "jacobians", [x, u, *params], [casadi.jacobian(xdot, x), casadi.jacobian(xdot, u)]
    )
    x_eq, u_eq = equilibrium()(*params)
    A, B = jac(x_eq, u_eq, *params)
    return casadi.Function("linearisation", params, [A, B], PARAMETERS, ["A", "B"])


def eq16() -> casadi.Function:
    """Paper Eq. 16 typed out by hand, with ``L = l0 - m g / k``; the oracle for ``linearisation``.

    Returns
    -------
    casadi.Function
        ``'eq16'``: ``k, d, m, l0, g`` -> ``A (4, 4)``, ``B (4, 2)``.
    """
    k, d, m, l0, g = params = _parameters()
    L = l0 - m * g / k
    A = casadi.SX.zeros(4, 4)
    A[0, 1] = 1
    A[1, 0] = -k / m
    A[1, 1] = -d / m
    A[2, 3] = 1
    A[3, 2] = g / L
    B = casadi.SX.zeros(4, 2)
    B[1, 0] = 1 / m
    B[3, 1] = 1 / (m * L**2)
    return casadi.Function("eq16", params, [A, B], PARAMETERS, ["A", "B"])


# =============================================================================
# Subsystems
# =============================================================================


def subsystems() -> casadi.Function:
    """The two decoupled SISO subsystems of the linearisation.

    Translational (stable), states ``(l, ldot)``, input ``F``, output ``l``:
    ``A1 = A[0:2, 0:2]``, ``B1 = B[0:2, 0]``, ``C1 = (1, 0)``, ``D1 = 0``.
    Rotational (unstable), states ``(theta, thetadot)``, input ``tau``, output ``theta``:
    ``A2 = A[2:4, 2:4]``, ``B2 = B[2:4, 1]``, ``C2 = (1, 0)``, ``D2 = 0``.
    The off-diagonal blocks of ``A`` and ``B`` vanish at the upright equilibrium (to rounding,
    ``cos(pi/2) = 6e-17``), which is what makes the split exact.

    Returns
    -------
    casadi.Function
        ``'subsystems'``: ``k, d, m, l0, g`` -> ``A1 (2, 2), B1 (2, 1), C1 (1, 2), D1 (1, 1)``,
        ``A2, B2, C2, D2`` (same shapes).
    """
    params = _parameters()
    A, B = linearisation()(*params)
    C = casadi.SX(casadi.DM([[1.0, 0.0]]))  # measure the position-like state
    D = casadi.SX.zeros(1, 1)
    outputs = [A[0:2, 0:2], B[0:2, 0], C, D, A[2:4, 2:4], B[2:4, 1], C, D]
    names = ["A1", "B1", "C1", "D1", "A2", "B2", "C2", "D2"]
    return casadi.Function("subsystems", params, outputs, PARAMETERS, names)


# =============================================================================
# Controllable canonical form of any SISO realisation
# =============================================================================


class CCFRealisation(NamedTuple):
    """A SISO system in bottom-row controllable canonical form (DESIGN.md, paper Eq. 5).

    A NamedTuple rather than a dataclass so that ``A, b, c, d = ccf(...)`` unpacks like the maths.

    Attributes
    ----------
    A : (n, n)  ones on the superdiagonal, last row ``(-a_0, ..., -a_{n-1})``
    b : (n, 1)  ``e_n``
    c : (1, n)  ``(c_0, ..., c_{n-1})``
    d : (1, 1)  feedthrough
    """

    A: casadi.SX | casadi.MX | casadi.DM
    b: casadi.SX | casadi.MX | casadi.DM
    c: casadi.SX | casadi.MX | casadi.DM
    d: casadi.SX | casadi.MX | casadi.DM


def _reflector(x):
    """Householder reflector ``P = I - 2 v v^T / (v^T v)`` with ``P x = -sign(x_0) |x| e_1``.

    ``v = x + sign(x_0) |x| e_1`` (the sign avoids cancellation; ``sign(0) = +1``). For ``x = 0``
    nothing needs reflecting and ``P = I``: the guarded ``1 / (v^T v)`` is then 0.
    """
    r = x.shape[0]
    alpha = casadi.if_else(x[0] >= 0, 1, -1) * casadi.norm_2(x)
    v = casadi.vertcat(x[0] + alpha, x[1:])
    vv = casadi.dot(v, v)
    return casadi.DM.eye(r) - 2 * casadi.if_else(vv > 0, 1 / vv, 0) * casadi.mtimes(v, v.T)


def _controller_hessenberg(A, b, c):
    """Orthogonal ``Q`` with ``Q^T b = beta e_1`` and ``Q^T A Q`` upper Hessenberg.

    One reflector aligns ``b`` with ``e_1``; then, column by column, reflectors acting on rows and
    columns ``k+1..n`` (so they leave ``e_1`` alone) zero ``A`` below its subdiagonal. Returns
    ``(Q^T A Q, Q^T b, c Q)``, the same system in the controller-Hessenberg basis, where the Krylov
    vectors ``H^i e_1`` are upper triangular.
    """
    n = A.shape[0]
    P = _reflector(b)
    A, b, c = casadi.mtimes([P, A, P]), casadi.mtimes(P, b), casadi.mtimes(c, P)
    for k in range(n - 2):
        P = casadi.diagcat(casadi.DM.eye(k + 1), _reflector(A[k + 1 :, k]))
        A, c = casadi.mtimes([P, A, P]), casadi.mtimes(c, P)
    return A, b, c


def _charpoly_hessenberg(H):
    """``[a_0, ..., a_{n-1}]`` of ``det(sI - H) = s^n + a_{n-1} s^{n-1} + ... + a_0``, H Hessenberg.

    La Budde's recursion over the leading principal submatrices (1-based indices):
    ``p_0 = 1``, ``p_i(s) = (s - h_ii) p_{i-1}(s)
    - sum_{m=1}^{i-1} h_{i-m,i} (prod_{j=i-m+1}^{i} h_{j,j-1}) p_{i-m-1}(s)``.
    Division-free, so exact for symbolic ``H``; numerically as accurate as eigenvalue-based
    ``numpy.poly``/``control.ss2tf`` on the tests' ill-conditioned systems.
    """
    n = H.shape[0]
    p = [[1]]  # p[i][j]: coefficient of s^j in p_i
    for i in range(1, n + 1):
        prev = p[i - 1]
        new = [-H[i - 1, i - 1] * prev[0]]
        new += [prev[j - 1] - H[i - 1, i - 1] * prev[j] for j in range(1, i)] + [prev[i - 1]]
        product = 1
        for m in range(1, i):
            product = product * H[i - m, i - m - 1]
            for j, coeff in enumerate(p[i - m - 1]):
                new[j] = new[j] - H[i - m - 1, i - 1] * product * coeff
        p.append(new)
    return p[n][:n]


def ccf(A, b, c, d) -> CCFRealisation:
    r"""Bottom-row controllable canonical form of the SISO system ``(A, b, c, d)``, any order n.

    ``det(sI - A) = s^n + a_{n-1} s^{n-1} + ... + a_0`` gives the last row of ``A``. With the
    Markov parameters ``h_i = c A^{i-1} b``, the numerator of
    ``c (sI - A)^{-1} b = N(s) / det(sI - A)`` is ``N(s) = sum_j c_j s^j`` with

        c_{n-j} = sum_{i=1}^{j} a_{n-j+i} h_i,   j = 1..n   (a_n = 1),

    read off from ``N(s) = det(sI - A) * sum_{i>=1} h_i s^{-i}``. The result realises
    ``G(s) = (c_{n-1} s^{n-1} + ... + c_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0) + d``.

    Numerics. For ``n >= 3`` the system is first brought to controller-Hessenberg form by
    Householder reflections (``Q^T b = beta e_1``, ``Q^T A Q`` upper Hessenberg); the characteristic
    polynomial then comes from La Budde's recursion and the Markov parameters from triangular
    Krylov vectors. Faddeev-LeVerrier and Markov parameters in the original basis are exact in
    exact arithmetic too, but in an ill-conditioned basis they lost up to all digits (n = 5, 6)
    where this route stays as accurate as ``control.ss2tf``. For ``n <= 2`` every matrix is already
    Hessenberg and the formulas are used as they are, so the symbolic leg maps stay plain rational
    expressions and a CCF input comes back unchanged (to rounding).

    Parameters
    ----------
    A : (n, n) casadi SX, MX or DM (NumPy arrays are converted to DM)
    b : n elements (column or row)
    c : n elements (column or row)
    d : 1 element

    Returns
    -------
    CCFRealisation
        ``A (n, n), b (n, 1), c (1, n), d (1, 1)``, of the symbolic type of the inputs (SX if any
        input is SX, else MX if any is MX, else DM).
    """
    A, b, c, d = (x if isinstance(x, casadi.SX | casadi.MX) else casadi.DM(x) for x in (A, b, c, d))
    n = A.shape[0]
    if A.shape[1] != n or n == 0:
        raise ValueError(f"A must be square (n, n) with n >= 1; got {A.shape}")
    for name, value in (("b", b), ("c", c)):
        if value.numel() != n or 1 not in value.shape:
            raise ValueError(
                f"{name} must be a vector with n={n} elements; got shape {value.shape}"
            )
    if d.numel() != 1:
        raise ValueError(f"d must be a scalar (1 element); got shape {d.shape}")
    kinds = {type(x) for x in (A, b, c, d)}
    if casadi.SX in kinds and casadi.MX in kinds:
        raise TypeError("ccf: do not mix SX and MX inputs")
    kind = casadi.SX if casadi.SX in kinds else casadi.MX if casadi.MX in kinds else casadi.DM
    b, c = casadi.reshape(b, n, 1), casadi.reshape(c, 1, n)
    if n >= 3:
        A, b, c = _controller_hessenberg(A, b, c)

    a = _charpoly_hessenberg(A) + [1]  # a[0..n], monic
    markov, krylov = [], b
    for _ in range(n):  # h_1 .. h_n
        markov.append(casadi.mtimes(c, krylov))
        krylov = casadi.mtimes(A, krylov)
    num = [sum(a[n - j + i] * markov[i - 1] for i in range(1, j + 1)) for j in range(1, n + 1)]
    coeffs = num[::-1]  # num[j-1] is c_{n-j}; reverse to (c_0, ..., c_{n-1})

    last_row = -casadi.horzcat(*a[:n])
    shift = casadi.horzcat(casadi.DM.zeros(n - 1, 1), casadi.DM.eye(n - 1))
    A_c = casadi.vertcat(kind(shift), last_row) if n > 1 else kind(last_row)
    b_c = kind(casadi.DM.eye(n)[:, n - 1])
    c_c = kind(casadi.horzcat(*coeffs))
    return CCFRealisation(A_c, b_c, c_c, kind(d))


# =============================================================================
# Maps: physical parameters (k, d, m) -> CCF of each subsystem
# =============================================================================


def _subsystem_map(name: str, index: int, l0: float, g: float) -> casadi.Function:
    l0, g = _check_constant("l0", l0), _check_constant("g", g)
    k, d, m = (casadi.SX.sym(s) for s in ("k", "d", "m"))
    sub = subsystems()(k=k, d=d, m=m, l0=l0, g=g)
    A, B, C, D = ccf(*(sub[f"{s}{index}"] for s in "ABCD"))
    return casadi.Function(name, [k, d, m], [A, B, C, D], ["k", "d", "m"], ["A", "B", "C", "D"])


@named("symbolic.leg.stable_map")
def stable_map(l0: float = L0, g: float = G) -> casadi.Function:
    """``(k, d, m)`` -> CCF of the translational subsystem ``G1 = (1/m) / (s^2 + (d/m) s + k/m)``.

    Derived by ``ccf()`` from ``subsystems()``: ``a_0 = k/m``, ``a_1 = d/m``, ``c_0 = 1/m``,
    ``c_1 = 0``, ``D = 0``. ``G1`` depends on neither ``l0`` nor ``g``; they are accepted (and
    validated) so that both maps are built alike.

    Returns
    -------
    casadi.Function
        ``'stable_map'``: scalars ``k, d, m`` -> ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)``.
    """
    return _subsystem_map("stable_map", 1, l0, g)


@named("symbolic.leg.unstable_map")
def unstable_map(l0: float = L0, g: float = G) -> casadi.Function:
    """``(k, d, m)`` -> CCF of the rotational subsystem ``G2 = (1/(m L^2)) / (s^2 - g/L)``.

    Derived by ``ccf()`` from ``subsystems()``: ``a_0 = -g/L``, ``a_1 = 0``, ``c_0 = 1/(m L^2)``,
    ``c_1 = 0``, ``D = 0``, with ``L = l0 - m g / k``. ``G2`` does not depend on ``d``: the damper
    acts along the leg only, so ``d`` is unidentifiable from the rotational subsystem. The input is
    kept so that both maps share the signature ``(k, d, m)``.

    Returns
    -------
    casadi.Function
        ``'unstable_map'``: scalars ``k, d, m`` -> ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)``.
    """
    return _subsystem_map("unstable_map", 2, l0, g)


@named("symbolic.leg.joint_map")
def joint_map(l0: float = L0, g: float = G) -> casadi.Function:
    """``(k, d, m)`` -> the CCFs of both subsystems: one parameter set, two records.

    The map of a jointly identified leg (one encoder reads the stable and the unstable record and
    outputs one ``(k, d, m)``): ``stable_map`` and ``unstable_map`` side by side, outputs numbered
    by record (1 = translational ``G1``, 2 = rotational ``G2``), as ``joint_inverse`` reads them.

    Returns
    -------
    casadi.Function
        ``'joint_map'``: scalars ``k, d, m`` -> ``A1 (2, 2), B1 (2, 1), C1 (1, 2), D1 (1, 1),
        A2, B2, C2, D2``.
    """
    k, d, m = (casadi.SX.sym(s) for s in ("k", "d", "m"))
    outs = [*stable_map(l0, g)(k, d, m), *unstable_map(l0, g)(k, d, m)]
    names = [f"{s}{r}" for r in (1, 2) for s in "ABCD"]
    return casadi.Function("joint_map", [k, d, m], outs, ["k", "d", "m"], names)


# =============================================================================
# Inverses: CCF -> physical parameters
# =============================================================================


def _ccf_symbols(suffix: str = "") -> tuple[list[casadi.SX], list[str]]:
    """Input symbols ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)`` of a second-order CCF."""
    shapes = {"A": (2, 2), "B": (2, 1), "C": (1, 2), "D": (1, 1)}
    names = [f"{s}{suffix}" for s in shapes]
    symbols = [casadi.SX.sym(n, *shape) for n, shape in zip(names, shapes.values(), strict=True)]
    return symbols, names


@named("symbolic.leg.stable_inverse")
def stable_inverse(l0: float = L0, g: float = G) -> casadi.Function:
    """CCF of ``G1`` -> ``(k, d, m)``: ``m = 1/c_0``, ``k = a_0 m``, ``d = a_1 m``.

    ``a_0 = -A[1, 0]``, ``a_1 = -A[1, 1]``, ``c_0 = C[0, 0]``; ``B``, ``D`` and ``c_1`` are ignored.
    ``l0`` and ``g`` do not enter (validated only, for a uniform signature).

    Returns
    -------
    casadi.Function
        ``'stable_inverse'``: ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)`` -> scalars ``k, d, m``.
    """
    _check_constant("l0", l0)
    _check_constant("g", g)
    (A, B, C, D), names = _ccf_symbols()
    a0, a1, c0 = -A[1, 0], -A[1, 1], C[0, 0]
    m = 1 / c0
    return casadi.Function(
        "stable_inverse", [A, B, C, D], [a0 * m, a1 * m, m], names, ["k", "d", "m"]
    )


@named("symbolic.leg.unstable_inverse")
def unstable_inverse(l0: float = L0, g: float = G) -> casadi.Function:
    """CCF of ``G2`` -> ``(k, m)``: ``L = -g/a_0``, ``m = 1/(c_0 L^2)``, ``k = m g / (l0 - L)``.

    ``a_0 = -A[1, 0]``, ``c_0 = C[0, 0]``; ``a_1``, ``c_1``, ``B`` and ``D`` are ignored. ``d`` has
    no output: ``G2`` does not depend on it.

    Returns
    -------
    casadi.Function
        ``'unstable_inverse'``: ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)`` -> scalars ``k, m``.
    """
    l0, g = _check_constant("l0", l0), _check_constant("g", g)
    (A, B, C, D), names = _ccf_symbols()
    a0, c0 = -A[1, 0], C[0, 0]
    L = -g / a0
    m = 1 / (c0 * L**2)
    k = m * g / (l0 - L)
    return casadi.Function("unstable_inverse", [A, B, C, D], [k, m], names, ["k", "m"])


@named("symbolic.leg.joint_inverse")
def joint_inverse(l0: float = L0, g: float = G, *, unstable_noise: float = 1.0) -> casadi.Function:
    r"""Both subsystems' CCFs -> ``(k, d, m)``, combining what each says about ``k`` and ``m``.

    What the data say. The stable CCF gives ``omega^2 = k/m = a_0^{(1)}``, ``d/m = a_1^{(1)}`` and
    ``m = 1/c_0^{(1)}``. The unstable CCF gives ``L = -g/a_0^{(2)}`` and ``m L^2 = 1/c_0^{(2)}``,
    i.e. again ``omega^2 = g / (l0 - L)`` and ``m = 1/(c_0^{(2)} L^2)``. So ``omega^2`` and ``m``
    are each measured twice; ``d`` only once (``d = a_1^{(1)} m``).

    Combination. In log space, ``y_s = (log a_0^{(1)}, -log c_0^{(1)})`` and
    ``y_u = (log(g/(l0 - L)), -log(c_0^{(2)} L^2))`` both estimate ``theta = (log omega^2, log m)``.
    Model each informative coefficient with an independent relative error, ``sigma`` for the stable
    and ``unstable_noise * sigma`` for the unstable subsystem. To first order (delta method) the
    stable pair is then uncorrelated with covariance ``sigma^2 I`` and the unstable pair has

        Sigma_u = (unstable_noise sigma)^2 [[r^2, -2r], [-2r, 5]],   r = L / (l0 - L),

    (``d log(g/(l0-L)) = -r d log a_0``, ``d log(m) = 2 d log a_0 - d log c_0``). The
    minimum-variance (generalised least squares) estimate is the information-weighted mean

        theta = (I + W_u)^{-1} (y_s + W_u y_u),   W_u = sigma^2 Sigma_u^{-1},

    then ``m = exp(theta_2)``, ``k = exp(theta_1) m`` and ``d = a_1^{(1)} m``.

    Why this one. (i) For exact data ``y_s = y_u = theta``, so it round-trips exactly, like any
    consistent combination. (ii) It is well conditioned: the matrix solved, ``I + W_u``, is
    symmetric with eigenvalues ``>= 1`` (``W_u`` is positive semi-definite), so the solve cannot
    blow up however degenerate ``G2``'s information is, and the stable subsystem alone keeps every
    parameter identifiable. (iii) It avoids the
    poorly conditioned route "``k`` and ``m`` from ``G2`` alone", whose relative sensitivity to
    ``a_0^{(2)}`` is ``r`` for ``k/m`` (up to 3 in the study's ranges) and 2 for ``m``, while it
    still uses ``G2`` where it is informative (``r`` small: ``omega^2`` is then nearly insensitive
    to ``L``). (iv) ``unstable_noise`` states how much less one trusts ``G2`` (the paper's
    identified unstable models are markedly worse, Table I); ``unstable_noise -> inf`` recovers
    ``stable_inverse``.

    Parameters
    ----------
    l0, g : the constants of the maps that produced the data.
    unstable_noise : relative error of the unstable coefficients over that of the stable ones
        (positive); 1.0 trusts both alike.

    Returns
    -------
    casadi.Function
        ``'joint_inverse'``: ``A1 (2, 2), B1 (2, 1), C1 (1, 2), D1 (1, 1), A2, B2, C2, D2`` ->
        scalars ``k, d, m``. Needs ``L = -g/a_0^{(2)}`` with ``L < l0``, ``L != 0``, and positive
        ``a_0^{(1)}, c_0^{(1)}, c_0^{(2)}`` (NaN otherwise).
    """
    l0, g = _check_constant("l0", l0), _check_constant("g", g)
    unstable_noise = _check_constant("unstable_noise", unstable_noise)
    (A1, B1, C1, D1), names1 = _ccf_symbols("1")
    (A2, B2, C2, D2), names2 = _ccf_symbols("2")

    a0_s, a1_s, c0_s = -A1[1, 0], -A1[1, 1], C1[0, 0]
    a0_u, c0_u = -A2[1, 0], C2[0, 0]
    L = -g / a0_u
    y_s = casadi.vertcat(casadi.log(a0_s), -casadi.log(c0_s))
    y_u = casadi.vertcat(casadi.log(g / (l0 - L)), -casadi.log(c0_u * L**2))

    r = L / (l0 - L)
    # W_u = Sigma_u^{-1} sigma^2 = [[5, 2r], [2r, r^2]] / (r^2 unstable_noise^2): the closed-form
    # inverse of [[r^2, -2r], [-2r, 5]], whose determinant is r^2.
    W_u = casadi.vertcat(
        casadi.horzcat(5 / r**2, 2 / r), casadi.horzcat(2 / r, 1)
    ) / unstable_noise**2
    theta = casadi.solve(casadi.SX.eye(2) + W_u, y_s + casadi.mtimes(W_u, y_u))
    m = casadi.exp(theta[1])
    k = casadi.exp(theta[0]) * m
    d = a1_s * m
    return casadi.Function(
        "joint_inverse",
        [A1, B1, C1, D1, A2, B2, C2, D2],
        [k, d, m],
        names1 + names2,
        ["k", "d", "m"],
    )


# =============================================================================
# Code generation
# =============================================================================


def generate_c(
    directory: str | pathlib.Path, *, l0: float = L0, g: float = G, name: str = "leg_maps"
) -> pathlib.Path:
    """Write the maps and inverses (``CODEGEN_FUNCTIONS``) into one C file.

    Parameters
    ----------
    directory : where to write (created if missing).
    l0, g : the constants baked into the generated functions.
    name : the file's stem; the file is ``directory / f"{name}.c"``.

    Returns
    -------
    pathlib.Path
        The C file, self-contained (CasADi's runtime inlined), with the functions' names and their
        input/output names as symbols.
    """
    if not isinstance(name, str) or not name.isidentifier():
        raise ValueError(f"name must be a C identifier (the file stem); got {name!r}")
    if not isinstance(directory, (str, pathlib.PurePath)) or not str(directory):
        raise ValueError(f"directory must be a folder path (str or Path); got {directory!r}")
    directory = pathlib.Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    builders = {
        "stable_map": stable_map,
        "unstable_map": unstable_map,
        "joint_map": joint_map,
        "stable_inverse": stable_inverse,
        "unstable_inverse": unstable_inverse,
        "joint_inverse": joint_inverse,
    }
    generator = casadi.CodeGenerator(f"{name}.c")
    for fname in CODEGEN_FUNCTIONS:
        generator.add(builders[fname](l0=l0, g=g))
    return pathlib.Path(generator.generate(str(directory) + "/"))


def compile_c(
    c_file: str | pathlib.Path, *, compiler: str | None = None
) -> dict[str, casadi.Function]:
    """Compile a file from ``generate_c`` to a shared library and load its functions.

    Parameters
    ----------
    c_file : the C file; the library is written next to it with the suffix ``.so``.
    compiler : the C compiler's path; by default ``gcc``, else ``cc``, from ``PATH``.

    Returns
    -------
    dict[str, casadi.Function]
        ``CODEGEN_FUNCTIONS`` name -> ``casadi.external`` Function, with the same input and output
        names as the SX original.

    Raises
    ------
    RuntimeError
        If no C compiler is found, or compilation fails (the message carries the compiler's
        output).
    """
    c_file = pathlib.Path(c_file)
    if not c_file.is_file():
        raise FileNotFoundError(f"c_file must be an existing C file; got {c_file}")
    compiler = compiler or shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        raise RuntimeError("compile_c needs a C compiler: neither gcc nor cc is on PATH")
    library = c_file.with_suffix(".so")
    command = [compiler, "-shared", "-fPIC", "-O2", str(c_file), "-o", str(library), "-lm"]
    try:
        done = subprocess.run(command, capture_output=True, text=True, check=False)
    except OSError as error:
        raise RuntimeError(f"compile_c could not run the compiler {compiler!r}: {error}") from None
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stderr}")
    return {fname: casadi.external(fname, str(library)) for fname in CODEGEN_FUNCTIONS}


# =============================================================================
# Self-check: python -m symbolic.leg
# =============================================================================


def _self_check() -> None:
    import tempfile

    import numpy as np

    np.set_printoptions(precision=4, suppress=True)
    rng = np.random.default_rng(0)
    q, qdot = casadi.SX.sym("q", 2), casadi.SX.sym("qdot", 2)
    params = _parameters()
    f = dynamics()
    print("Spring-loaded inverted pendulum (paper Fig. 2), q = (l, theta), x = (l, ldot, theta, "
          "thetadot), u = (F, tau)")
    print("  L(q, qdot) =", lagrangian()(q, qdot, *params))
    print(f"  xdot = f(x, u) by Euler-Lagrange with CasADi derivatives: {f.n_instructions()} SX "
          "instructions")

    # The derived equations of motion against the textbook SLIP model, typed in independently.
    def textbook(x, u, k, d, m, l0, g):
        l, ldot, th, thdot = x
        lddot = l * thdot**2 - g * np.sin(th) - (k * (l - l0) + d * ldot - u[0]) / m
        thddot = (u[1] - 2 * m * l * ldot * thdot - m * g * l * np.cos(th)) / (m * l**2)
        return np.array([ldot, lddot, thdot, thddot])

    eom_error = 0.0
    for _ in range(5):
        x, u = rng.uniform([0.3, -1, 0.5, -2], [1.0, 1, 2.5, 2]), rng.normal(size=2)
        p_rand = [rng.uniform(*RANGES[n]) for n in ("k", "d", "m")] + [L0, G]
        derived = np.array(f(x, u, *p_rand)).ravel()
        eom_error = max(eom_error, np.max(np.abs(derived - textbook(x, u, *p_rand))))
    print(f"  max |f - textbook SLIP| at random states: {eom_error:.1e}")
    print("  x_eq =", equilibrium()(*params)[0])

    p = {**SCENARIO, "l0": L0, "g": G}
    x_eq, u_eq = (np.array(v) for v in equilibrium()(*p.values()))
    rest = np.array(dynamics()(x_eq, u_eq, *p.values()))
    lin, paper = linearisation()(**p), eq16()(**p)
    print(f"\nScenario {SCENARIO}, l0 = {L0}, g = {G}: L = {x_eq[0, 0]:.6f} m")
    print("  A =\n", np.array(lin["A"]), "\n  B =\n", np.array(lin["B"]))

    fs, fu = stable_map(), unstable_map()
    cs, cu = fs(**SCENARIO), fu(**SCENARIO)
    for label, sys in (("stable G1", cs), ("unstable G2", cu)):
        print(f"  {label}: A = {np.array(sys['A']).tolist()}, C = {np.array(sys['C']).tolist()}")
    back_s = stable_inverse()(**cs)
    back_u = unstable_inverse()(**cu)
    sub = {f"{s}1": v for s, v in cs.items()} | {f"{s}2": v for s, v in cu.items()}
    back_j = joint_inverse()(**sub)
    for label, back in (("stable", back_s), ("unstable", back_u), ("joint", back_j)):
        print(f"  {label}_inverse: " + ", ".join(f"{n} = {float(v):.6g}" for n, v in back.items()))

    compiled_ok = True
    if shutil.which("gcc") or shutil.which("cc"):
        with tempfile.TemporaryDirectory() as tmp:
            compiled = compile_c(generate_c(tmp))
            compiled_ok = np.allclose(
                np.array(compiled["stable_map"](**SCENARIO)["A"]), np.array(cs["A"]), rtol=1e-14
            )
        print("  generated C, compiled and loaded: agrees with SX:", compiled_ok)

    L = L0 - SCENARIO["m"] * G / SCENARIO["k"]
    assert eom_error < 1e-12, "derived equations of motion differ from the textbook SLIP"
    assert np.max(np.abs(rest)) < 1e-12, "the equilibrium must be a rest point"
    for key in ("A", "B"):
        assert np.allclose(np.array(lin[key]), np.array(paper[key]), rtol=0, atol=1e-12), key
    expected_s = [[0, 1], [-SCENARIO["k"] / SCENARIO["m"], -SCENARIO["d"] / SCENARIO["m"]]]
    assert np.allclose(np.array(cs["A"]), expected_s, rtol=1e-14, atol=1e-14)
    assert np.allclose(np.array(cu["A"]), [[0, 1], [G / L, 0]], rtol=1e-14, atol=1e-14)
    assert np.isclose(float(cu["C"][0, 0]), 1 / (SCENARIO["m"] * L**2), rtol=1e-14)
    for name, value in SCENARIO.items():
        assert np.isclose(float(back_s[name]), value, rtol=1e-13), name
        assert np.isclose(float(back_j[name]), value, rtol=1e-13), name
        if name != "d":
            assert np.isclose(float(back_u[name]), value, rtol=1e-13), name
    assert compiled_ok
    print("\nAll checks passed.")


if __name__ == "__main__":
    _self_check()
