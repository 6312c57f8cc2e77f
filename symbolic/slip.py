r"""The spring-loaded inverted pendulum of paper Sec. IV (the robot leg), derived with CasADi.

Model (paper Fig. 2)
--------------------
A point mass ``m`` sits on a massless telescopic leg whose foot is pinned at the origin. The leg
has length ``l`` and makes the angle ``theta`` with the ground horizontal, so the mass is at
``p = (l cos(theta), l sin(theta))``; upright is ``theta = pi/2``. A linear spring (stiffness
``k``, rest length ``l0``) and a viscous damper (``d``) act along the leg; gravity ``g`` pulls the
mass down. The inputs ``u = (F, tau)`` are a force along the leg (positive extends it) and a hip
torque (positive increases ``theta``)::

    T = m/2 |dp/dt|^2                         (dp/dt by CasADi's jtimes, not typed in)
    V = m g p_y + k/2 (l - l0)^2
    L = T - V
    Q = (F - d ldot, tau)                     (generalised forces on (l, theta))

``Q`` follows from virtual work (the generalised coordinates *are* the leg length and the hip
angle); the damper enters through the Rayleigh dissipation ``R = d/2 ldot^2`` as ``-dR/dqdot``.

Derivation
----------
Euler-Lagrange, ``d/dt dL/dqdot - dL/dq = Q``, with ``M = jacobian(dL/dqdot, qdot)`` and
``J qdot = jtimes(dL/dqdot, q, qdot)``, gives ``qddot = M^{-1} (Q + dL/dq - J qdot)``, solved
symbolically (exact for SX). With ``x = (l, ldot, theta, thetadot)`` this is the textbook SLIP
model::

    m lddot         = m l thetadot^2 - m g sin(theta) - k (l - l0) - d ldot + F
    m l^2 thetaddot = -2 m l ldot thetadot - m g l cos(theta) + tau.

The upright rest point is ``x_eq = (L, 0, pi/2, 0)``, ``u_eq = 0``, ``L = l0 - m g / k``, where
the spring carries the weight (the paper's text says "linearised at l = l0", where it does not;
its Eq. 16 uses ``L``, as we do). The Jacobians there reproduce Eq. 16; its coupling entries come
out as ``~1e-16`` rather than 0 (``cos(pi/2)`` in floating point), so the split into the two
subsystems holds to rounding.

Run ``python -m symbolic.slip`` to print the derivation and check it (assertions at the end).
"""

from __future__ import annotations

import math

import casadi

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


def symbols() -> list[casadi.SX]:
    """Fresh scalar symbols of the physical parameters.

    Returns
    -------
    list of casadi.SX
        ``[k, d, m, l0, g]``, each ``(1, 1)``, in :data:`PARAMETERS` order.
    """
    return [casadi.SX.sym(name) for name in PARAMETERS]


def check_constant(name: str, value: float) -> float:
    """A finite, positive physical constant (``l0``, ``g``, ...) as a float.

    Parameters
    ----------
    name : str
        The constant's name, for the error message.
    value : float
        The constant.

    Returns
    -------
    float
        ``value``, checked.

    Raises
    ------
    TypeError
        If ``value`` is not a real number.
    ValueError
        If ``value`` is not finite and positive.
    """
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
    k, d, m, l0, g = params = symbols()
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
    k, d, m, l0, g = params = symbols()

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
    k, d, m, l0, g = params = symbols()
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
    params = symbols()
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
    k, d, m, l0, g = params = symbols()
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
    params = symbols()
    A, B = linearisation()(*params)
    C = casadi.SX(casadi.DM([[1.0, 0.0]]))  # measure the position-like state
    D = casadi.SX.zeros(1, 1)
    outputs = [A[0:2, 0:2], B[0:2, 0], C, D, A[2:4, 2:4], B[2:4, 1], C, D]
    names = ["A1", "B1", "C1", "D1", "A2", "B2", "C2", "D2"]
    return casadi.Function("subsystems", params, outputs, PARAMETERS, names)


# =============================================================================
# Self-check: python -m symbolic.slip
# =============================================================================


def _textbook(x, u, k, d, m, l0, g):
    """The SLIP equations of motion typed in by hand (NumPy): the oracle of :func:`dynamics`."""
    import numpy as np

    l, ldot, th, thdot = x
    lddot = l * thdot**2 - g * np.sin(th) - (k * (l - l0) + d * ldot - u[0]) / m
    thddot = (u[1] - 2 * m * l * ldot * thdot - m * g * l * np.cos(th)) / (m * l**2)
    return np.array([ldot, lddot, thdot, thddot])


def check_derivation() -> None:
    """Print the derivation and assert it: the equations of motion against the textbook SLIP
    model at random states, the equilibrium as a rest point, the linearisation against Eq. 16.

    Raises
    ------
    AssertionError
        If a check fails.
    """
    import numpy as np

    np.set_printoptions(precision=4, suppress=True)
    rng = np.random.default_rng(0)
    q, qdot = casadi.SX.sym("q", 2), casadi.SX.sym("qdot", 2)
    params = symbols()
    f = dynamics()
    print("Spring-loaded inverted pendulum (paper Fig. 2), q = (l, theta), x = (l, ldot, theta, "
          "thetadot), u = (F, tau)")
    print("  L(q, qdot) =", lagrangian()(q, qdot, *params))
    print(f"  xdot = f(x, u) by Euler-Lagrange with CasADi derivatives: {f.n_instructions()} SX "
          "instructions")
    eom_error = 0.0
    for _ in range(5):
        x, u = rng.uniform([0.3, -1, 0.5, -2], [1.0, 1, 2.5, 2]), rng.normal(size=2)
        p_rand = [rng.uniform(*RANGES[n]) for n in ("k", "d", "m")] + [L0, G]
        derived = np.array(f(x, u, *p_rand)).ravel()
        eom_error = max(eom_error, np.max(np.abs(derived - _textbook(x, u, *p_rand))))
    print(f"  max |f - textbook SLIP| at random states: {eom_error:.1e}")
    print("  x_eq =", equilibrium()(*params)[0])

    p = {**SCENARIO, "l0": L0, "g": G}
    x_eq, u_eq = (np.array(v) for v in equilibrium()(*p.values()))
    rest = np.array(dynamics()(x_eq, u_eq, *p.values()))
    lin, paper = linearisation()(**p), eq16()(**p)
    print(f"\nScenario {SCENARIO}, l0 = {L0}, g = {G}: L = {x_eq[0, 0]:.6f} m")
    print("  A =\n", np.array(lin["A"]), "\n  B =\n", np.array(lin["B"]))
    assert eom_error < 1e-12, "derived equations of motion differ from the textbook SLIP"
    assert np.max(np.abs(rest)) < 1e-12, "the equilibrium must be a rest point"
    for key in ("A", "B"):
        assert np.allclose(np.array(lin[key]), np.array(paper[key]), rtol=0, atol=1e-12), key


if __name__ == "__main__":
    check_derivation()
    print("\nAll checks passed.")
