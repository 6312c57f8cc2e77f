r"""Mechanisms written as an engineer writes them: a Lagrangian, a dissipation, forces and outputs
(``symbolic.mechanism.Mechanism``). Each function returns a fresh :class:`Mechanism`; its
docstring gives the operating point and the box the shipped recipes use.

- :func:`leg`: the spring-loaded inverted pendulum of paper Sec. IV (``symbolic.slip``), two
  inputs and two outputs; Eq. 16 at the upright rest point.
- :func:`two_mass`: two masses on springs and dampers in series, force on the second, position
  of the first.
- :func:`lever`: a mass-spring-damper pushed through a lever of unknown ratio: only three
  combinations of its four parameters are identifiable.
- :func:`drive_train`: motor and load inertias coupled by a compliant shaft (a rigid-body mode:
  integrating).
- :func:`cart_pole`: a pole balanced on a cart, linearised upright (unstable, two outputs).
- :func:`quarter_car`: a vehicle's suspension, body and wheel: parameters whose scales spread
  over four decades, and more transfer-function coefficients than parameters.
- :func:`coupled_masses`: the two masses of :func:`two_mass` with a force on each and both
  positions measured: coupled inputs, identified from one experiment per input.

Run ``python -m symbolic.mechanisms`` to print each one's identifiability report.
"""

from __future__ import annotations

import casadi

from .mechanism import Mechanism
from .named import named
from .slip import L0, G

__all__ = ["cart_pole", "coupled_masses", "drive_train", "leg", "lever", "quarter_car", "two_mass",
           "upright"]


def _symbols(*names: str) -> dict[str, casadi.SX]:
    return {name: casadi.SX.sym(name) for name in names}


def leg() -> Mechanism:
    """The robot leg (paper Fig. 2): a point mass on a telescopic leg with a spring ``k`` and a
    damper ``d``, pinned at the foot; ``q = (l, theta)``, inputs ``(F, tau)`` (along the leg, at
    the hip), outputs ``(l, theta)``; parameters ``k, d, m`` and the constants ``l0, g``
    (``known={"l0": 0.8, "g": 9.81}``). Operating point: :func:`upright`.

    Returns
    -------
    Mechanism
    """
    q, dq, u = casadi.SX.sym("q", 2), casadi.SX.sym("dq", 2), casadi.SX.sym("u", 2)
    p = _symbols("k", "d", "m", "l0", "g")
    l, theta = q[0], q[1]
    position = casadi.vertcat(l * casadi.cos(theta), l * casadi.sin(theta))
    velocity = casadi.jtimes(position, q, dq)
    T = 0.5 * p["m"] * casadi.dot(velocity, velocity)
    V = p["m"] * p["g"] * position[1] + 0.5 * p["k"] * (l - p["l0"]) ** 2
    return Mechanism(q=q, dq=dq, u=u, parameters=p, lagrangian=T - V,
                     dissipation=0.5 * p["d"] * dq[0] ** 2, forces=u, outputs=q, name="leg")


def upright(mechanism: Mechanism) -> dict:
    """The leg's upright rest point and constants, the keywords of ``linearise`` and
    ``channel``: ``q = (l0 - m g / k, pi / 2)``, where the spring carries the weight.

    Parameters
    ----------
    mechanism : Mechanism
        From :func:`leg`.

    Returns
    -------
    dict
        ``{"q": ..., "known": {"l0": 0.8, "g": 9.81}}``.
    """
    p = mechanism.parameters
    return {"q": casadi.vertcat(p["l0"] - p["m"] * p["g"] / p["k"], casadi.pi / 2),
            "known": {"l0": L0, "g": G}}


def two_mass() -> Mechanism:
    """Masses ``m1, m2``; spring ``k1`` and damper ``c1`` from the wall to mass 1, ``k2, c2``
    between the masses; force on mass 2, position of mass 1 measured. At rest at the origin
    (isolated: the rootfinder finds it).

    Returns
    -------
    Mechanism
    """
    F = casadi.SX.sym("F")
    return _masses_in_series(F, casadi.vertcat(0, F), lambda q: q[0], "two_mass")


def _masses_in_series(u, forces, outputs, name: str) -> Mechanism:
    """The two masses of :func:`two_mass` and :func:`coupled_masses` (one Lagrangian and
    dissipation), driven by ``forces(u)`` on the coordinates, ``outputs(q)`` measured."""
    q, dq = casadi.SX.sym("q", 2), casadi.SX.sym("dq", 2)
    p = _symbols("m1", "m2", "k1", "k2", "c1", "c2")
    T = 0.5 * p["m1"] * dq[0] ** 2 + 0.5 * p["m2"] * dq[1] ** 2
    V = 0.5 * p["k1"] * q[0] ** 2 + 0.5 * p["k2"] * (q[1] - q[0]) ** 2
    R = 0.5 * p["c1"] * dq[0] ** 2 + 0.5 * p["c2"] * (dq[1] - dq[0]) ** 2
    return Mechanism(q=q, dq=dq, u=u, parameters=p, lagrangian=T - V, dissipation=R,
                     forces=forces, outputs=outputs(q), name=name)


def lever() -> Mechanism:
    """A mass ``m`` on a spring ``k`` and damper ``d``, pushed by a force through a lever of
    ratio ``r``; force in, position out. ``G = r / (m s^2 + d s + k)``: only ``k/m, d/m, r/m``
    are identifiable.

    Returns
    -------
    Mechanism
    """
    x, v, F = casadi.SX.sym("x"), casadi.SX.sym("v"), casadi.SX.sym("F")
    p = _symbols("m", "k", "d", "r")
    return Mechanism(q=x, dq=v, u=F, parameters=p,
                     lagrangian=0.5 * p["m"] * v ** 2 - 0.5 * p["k"] * x ** 2,
                     dissipation=0.5 * p["d"] * v ** 2, forces=p["r"] * F, outputs=x,
                     name="lever")


def drive_train() -> Mechanism:
    """Motor inertia ``J1`` and load inertia ``J2`` coupled by a shaft of stiffness ``k`` and
    damping ``c``, viscous friction ``b`` on the motor; motor torque in, motor and load angles
    out. The angles may turn together freely (a rigid-body mode, an integrator): the
    equilibrium is named, ``q = (0, 0)``.

    Returns
    -------
    Mechanism
    """
    q, dq, tau = casadi.SX.sym("q", 2), casadi.SX.sym("dq", 2), casadi.SX.sym("tau")
    p = _symbols("J1", "J2", "k", "c", "b")
    T = 0.5 * p["J1"] * dq[0] ** 2 + 0.5 * p["J2"] * dq[1] ** 2
    V = 0.5 * p["k"] * (q[0] - q[1]) ** 2
    R = 0.5 * p["c"] * (dq[0] - dq[1]) ** 2 + 0.5 * p["b"] * dq[0] ** 2
    return Mechanism(q=q, dq=dq, u=tau, parameters=p, lagrangian=T - V, dissipation=R,
                     forces=casadi.vertcat(tau, 0), outputs=q, name="drive_train")


def cart_pole() -> Mechanism:
    """A cart of mass ``M`` with viscous friction ``b`` carrying a pole of mass ``m`` at length
    ``l`` (a point mass on a massless rod), ``theta`` from upright; force on the cart in, cart
    position and pole angle out; gravity ``g`` (``known={"g": 9.81}``). Linearised upright, at
    a named position ``q = (0, 0)`` (the cart may rest anywhere): unstable.

    Returns
    -------
    Mechanism
    """
    q, dq, F = casadi.SX.sym("q", 2), casadi.SX.sym("dq", 2), casadi.SX.sym("F")
    p = _symbols("M", "m", "l", "b", "g")
    x, theta = q[0], q[1]
    pole = casadi.vertcat(x + p["l"] * casadi.sin(theta), p["l"] * casadi.cos(theta))
    pole_velocity = casadi.jtimes(pole, q, dq)
    T = 0.5 * p["M"] * dq[0] ** 2 + 0.5 * p["m"] * casadi.dot(pole_velocity, pole_velocity)
    V = p["m"] * p["g"] * pole[1]
    return Mechanism(q=q, dq=dq, u=F, parameters=p, lagrangian=T - V,
                     dissipation=0.5 * p["b"] * dq[0] ** 2, forces=casadi.vertcat(F, 0),
                     outputs=q, name="cart_pole")


def quarter_car() -> Mechanism:
    """A quarter car: body mass ``ms`` and wheel mass ``mu``, the suspension's spring ``ks`` and
    damper ``cs`` between them, the tyre's spring ``kt`` from the wheel to the road; an
    actuator's force between body and wheel in (active suspension), the body's position out.
    At rest at the origin. ``G = (mu s^2 + kt) / det``: four denominator and three numerator
    coefficients shaped by five parameters, all identifiable; the benchmark's box, ``ms``
    200-400 kg, ``mu`` 25-50 kg, ``ks`` 1.5e4-3e4 N/m, ``cs`` 800-2000 N s/m, ``kt`` 1.5e5-2.5e5
    N/m, spreads over four decades.

    Returns
    -------
    Mechanism
    """
    q, dq, F = casadi.SX.sym("q", 2), casadi.SX.sym("dq", 2), casadi.SX.sym("F")
    p = _symbols("ms", "mu", "ks", "cs", "kt")
    T = 0.5 * p["ms"] * dq[0] ** 2 + 0.5 * p["mu"] * dq[1] ** 2
    V = 0.5 * p["ks"] * (q[0] - q[1]) ** 2 + 0.5 * p["kt"] * q[1] ** 2
    R = 0.5 * p["cs"] * (dq[0] - dq[1]) ** 2
    return Mechanism(q=q, dq=dq, u=F, parameters=p, lagrangian=T - V, dissipation=R,
                     forces=casadi.vertcat(F, -F), outputs=q[0], name="quarter_car")


def coupled_masses() -> Mechanism:
    """The masses ``m1, m2`` of :func:`two_mass` (spring ``k1`` and damper ``c1`` from the wall
    to mass 1, ``k2, c2`` between the masses) with a force on each, ``F1`` on mass 1 and
    ``F2`` on mass 2, and both positions out: each output answers both inputs, so a record
    of both forces at once cannot be split by channel; one experiment per force
    (``Physical(..., channels=..., experiments=True)``) identifies all six parameters. At rest
    at the origin.

    Returns
    -------
    Mechanism
    """
    F = casadi.SX.sym("F", 2)
    return _masses_in_series(F, F, lambda q: q, "coupled_masses")


@named("symbolic.mechanisms.drive_train_channels")
def drive_train_channels() -> casadi.Function:
    """The drive train's two channels of one record (motor and load angle from the motor
    torque) at ``q = (0, 0)``: the map of the shipped ``drive-train`` identifier.

    Returns
    -------
    casadi.Function
        ``J1, J2, k, c, b -> A1, B1, C1, D1, A2, .., D2`` (``Mechanism.channels``).
    """
    return drive_train().channels([(0, 0), (1, 0)], q=[0, 0])


@named("symbolic.mechanisms.cart_pole_channels")
def cart_pole_channels(g: float = 9.81) -> casadi.Function:
    """The cart-pole's two channels of one record (cart position and pole angle from the
    force) linearised upright at ``q = (0, 0)``: the map of the shipped ``cart-pole``
    identifier.

    Parameters
    ----------
    g : float
        Gravity.

    Returns
    -------
    casadi.Function
        ``M, m, l, b -> A1, B1, C1, D1, A2, .., D2`` (``Mechanism.channels``).
    """
    return cart_pole().channels([(0, 0), (1, 0)], q=[0, 0], known={"g": g})


if __name__ == "__main__":
    from .identifiability import identifiability

    legs = leg()
    print(identifiability(legs, {"k": (20, 25), "d": (2, 5), "m": (0.5, 1.5)},
                          inputs=[1], outputs=[1], **upright(legs)))
    print(identifiability(two_mass(), {n: (0.5, 2.0) for n in two_mass().names}))
    print(identifiability(lever(), {"m": (0.5, 2), "k": (10, 50), "d": (0.5, 3),
                                    "r": (0.5, 2)}))
    print(identifiability(drive_train(), {"J1": (0.01, 0.05), "J2": (0.02, 0.2),
                                          "k": (50, 200), "c": (0.05, 0.5),
                                          "b": (0.01, 0.1)}, q=[0, 0]))
    print(identifiability(cart_pole(), {"M": (0.5, 2), "m": (0.05, 0.5), "l": (0.2, 1),
                                        "b": (0.05, 1)}, q=[0, 0], known={"g": 9.81}))
    print(identifiability(coupled_masses(), {n: (0.5, 2.0) for n in coupled_masses().names},
                          pairs=[(0, 0), (1, 1)]))
