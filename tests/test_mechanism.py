"""Tests for ``symbolic/mechanism.py`` and ``symbolic/mechanisms.py``: a mechanism from its
Lagrangian.

Oracles, each independent of the code under test: the robot leg derived by hand in
``symbolic.slip`` (the textbook SLIP equations and paper Eq. 16) and its maps in
``symbolic.leg``; linearisations typed in NumPy from the textbook equations of motion; central
finite differences of the nonlinear dynamics; ``scipy.signal.lsim`` of the linear model against
CasADi's ``cvodes`` integration of the nonlinear one; compiled C against SX evaluation.
"""

from __future__ import annotations

import shutil

import casadi
import control
import numpy as np
import pytest
import scipy.signal

from symbolic import leg as leg_maps
from symbolic import mechanisms, slip
from symbolic.mechanism import Mechanism

#: slip's state (l, ldot, theta, thetadot) in Mechanism's order x = (q, dq) = (l, theta, ldot,
#: thetadot)
SLIP_ORDER = [0, 2, 1, 3]
LEG_POINTS = [slip.SCENARIO, {"k": 21.0, "d": 4.5, "m": 0.6}, {"k": 60.0, "d": 0.3, "m": 0.2}]


def _two_mass_oracle(m1, m2, k1, k2, c1, c2):
    """The two-mass linear model written from Newton's law."""
    M = np.diag([m1, m2])
    K = np.array([[k1 + k2, -k2], [-k2, k2]])
    Cd = np.array([[c1 + c2, -c2], [-c2, c2]])
    A = np.block([[np.zeros((2, 2)), np.eye(2)],
                  [-np.linalg.solve(M, K), -np.linalg.solve(M, Cd)]])
    return A, np.array([[0], [0], [0], [1 / m2]]), np.array([[1.0, 0, 0, 0]]), np.zeros((1, 1))


def _cart_pole_oracle(M, m, l, b, g=9.81):
    """The cart-pole linearised upright by hand: ``M xdd = F - b xd - m g theta``,
    ``M l thdd = (M + m) g theta - F + b xd``."""
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [0, -m * g / M, -b / M, 0],
                  [0, (M + m) * g / (M * l), b / (M * l), 0]])
    B = np.array([[0], [0], [1 / M], [-1 / (M * l)]])
    return A, B, np.hstack([np.eye(2), np.zeros((2, 2))]), np.zeros((2, 1))


def _numbers(function, **values):
    return [np.array(v) for v in function(**values).values()]


def _hanging_pendulum() -> Mechanism:
    """A mechanism none of ``symbolic.mechanisms`` ships, written as a user would: a point mass
    ``m`` on a massless rod ``l`` hanging from a pivot with viscous friction ``b``, a torque in,
    the angle out (a nonlinear Lagrangian whose rest point the rootfinder finds)."""
    q, dq, u = casadi.SX.sym("q", 1), casadi.SX.sym("dq", 1), casadi.SX.sym("u", 1)
    p = {k: casadi.SX.sym(k) for k in ("m", "l", "b", "g")}
    L = 0.5 * p["m"] * p["l"] ** 2 * dq[0] ** 2 + p["m"] * p["g"] * p["l"] * casadi.cos(q[0])
    return Mechanism(q=q, dq=dq, u=u, parameters=p, lagrangian=L,
                     dissipation=0.5 * p["b"] * dq[0] ** 2, forces=u, outputs=q,
                     name="pendulum")


# -- the robot leg rebuilt on Mechanism ------------------------------------------------------------
def test_leg_equations_of_motion_equal_slip_at_random_states():
    legs = mechanisms.leg()
    f = legs.dynamics()
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = rng.uniform([0.3, 0.5, -1, -2], [1.0, 2.5, 1, 2])
        u = rng.normal(size=2)
        p = {"k": 23.0, "d": 3.0, "m": 1.1, "l0": slip.L0, "g": slip.G}
        mine = np.array(f(x=x, u=u, **p)["xdot"]).ravel()
        x_slip = x[[0, 2, 1, 3]]
        theirs = np.array(slip.dynamics()(x_slip, u, *p.values())).ravel()[SLIP_ORDER]
        np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("point", LEG_POINTS)
def test_leg_linearisation_is_eq16_two_inputs_two_outputs(point):
    legs = mechanisms.leg()
    A, B, C, D = _numbers(legs.linearise(**mechanisms.upright(legs)), **point)
    A16, B16 = (np.array(v) for v in slip.eq16()(*point.values(), slip.L0, slip.G))
    np.testing.assert_allclose(A, A16[np.ix_(SLIP_ORDER, SLIP_ORDER)], atol=1e-12)
    np.testing.assert_allclose(B, B16[SLIP_ORDER], atol=1e-12)
    np.testing.assert_array_equal(C, np.hstack([np.eye(2), np.zeros((2, 2))]))
    np.testing.assert_array_equal(D, np.zeros((2, 2)))
    # the coupling between translation (l) and rotation (theta) vanishes upright
    translation, rotation = [0, 2], [1, 3]
    assert np.abs(A[np.ix_(translation, rotation)]).max() < 1e-12
    assert np.abs(A[np.ix_(rotation, translation)]).max() < 1e-12
    assert abs(B[2, 1]) < 1e-12 and abs(B[3, 0]) < 1e-12


def test_leg_rootfinder_finds_the_upright_rest_point():
    legs = mechanisms.leg()
    eq = legs.equilibrium(guess=[0.7, 1.5])
    for point in LEG_POINTS:
        out = eq(**point, l0=slip.L0, g=slip.G)
        x_eq, u_eq = np.array(out["x_eq"]).ravel(), np.array(out["u_eq"]).ravel()
        L = slip.L0 - point["m"] * slip.G / point["k"]
        np.testing.assert_allclose(x_eq, [L, np.pi / 2, 0, 0], rtol=1e-12, atol=1e-14)
        np.testing.assert_array_equal(u_eq, [0, 0])
    solved = legs.linearise(guess=[0.7, 1.5], known={"l0": slip.L0, "g": slip.G})
    named = legs.linearise(**mechanisms.upright(legs))
    for a, b in zip(_numbers(solved, **slip.SCENARIO), _numbers(named, **slip.SCENARIO),
                    strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize(("subsystem", "output", "states", "reference"), [
    ("stable", 0, [0, 2], leg_maps.stable_map), ("unstable", 1, [1, 3], leg_maps.unstable_map)])
def test_leg_channels_equal_the_leg_maps(subsystem, output, states, reference):
    legs = mechanisms.leg()
    channel = legs.channel(output, output, states=states, **mechanisms.upright(legs))
    assert channel.name_in() == ["k", "d", "m"] and channel.name_out() == ["A", "B", "C", "D"]
    for point in LEG_POINTS:
        for mine, theirs in zip(_numbers(channel, **point), _numbers(reference(), **point),
                                strict=True):
            np.testing.assert_allclose(mine, theirs, rtol=1e-12, atol=1e-12)


# -- other mechanisms against linearisations typed by hand -----------------------------------------
def test_two_mass_and_cart_pole_equal_their_hand_linearisations():
    two = mechanisms.two_mass()
    p = {"m1": 1.3, "m2": 0.7, "k1": 3.0, "k2": 5.0, "c1": 0.2, "c2": 0.4}
    for mine, theirs in zip(_numbers(two.linearise(), **p), _two_mass_oracle(**p), strict=True):
        np.testing.assert_allclose(mine, theirs, rtol=1e-13, atol=1e-13)
    cart = mechanisms.cart_pole()
    p = {"M": 1.2, "m": 0.3, "l": 0.6, "b": 0.4}
    lin = cart.linearise(q=[0, 0], known={"g": 9.81})
    for mine, theirs in zip(_numbers(lin, **p), _cart_pole_oracle(**p), strict=True):
        np.testing.assert_allclose(mine, theirs, rtol=1e-13, atol=1e-13)


def test_quarter_car_is_its_closed_form_transfer_function():
    # force between body and wheel, body position out: G = (mu s^2 + kt) / det, det the
    # determinant of the two masses' coupled second-order equations (python-control's tf)
    p = {"ms": 320.0, "mu": 41.0, "ks": 2.2e4, "cs": 1300.0, "kt": 1.9e5}
    A, B, C, D = _numbers(mechanisms.quarter_car().linearise(), **p)
    body = np.polyadd(np.polymul([p["ms"], p["cs"], p["ks"]],
                                 [p["mu"], p["cs"], p["ks"] + p["kt"]]),
                      -np.polymul([p["cs"], p["ks"]], [p["cs"], p["ks"]]))
    mine = control.ss2tf(A, B, C, D)
    num, den = np.ravel(mine.num[0][0]), np.ravel(mine.den[0][0])
    np.testing.assert_allclose(den, body / body[0], rtol=1e-10)
    # the whole numerator, leading zeros included: ss2tf's round-off leaves them ~1e-14, not 0
    want = np.array([0.0, 0.0, p["mu"], 0.0, p["kt"]])[-num.size:] / body[0]
    np.testing.assert_allclose(num, want, rtol=1e-10, atol=1e-10 * p["kt"] / body[0])


def test_linearisation_equals_finite_differences_of_the_dynamics():
    cart = mechanisms.cart_pole()
    p = {"M": 1.2, "m": 0.3, "l": 0.6, "b": 0.4, "g": 9.81}
    A, B, _, _ = _numbers(cart.linearise(q=[0, 0], known={"g": 9.81}),
                          **{k: v for k, v in p.items() if k != "g"})
    f = cart.dynamics()
    h = 1e-6

    def xdot(x, u):
        return np.array(f(x=x, u=u, **p)["xdot"]).ravel()

    fd_A = np.column_stack([(xdot(h * e, [0]) - xdot(-h * e, [0])) / (2 * h) for e in np.eye(4)])
    fd_B = ((xdot(np.zeros(4), [h]) - xdot(np.zeros(4), [-h])) / (2 * h))[:, None]
    np.testing.assert_allclose(A, fd_A, rtol=1e-7, atol=1e-8)
    np.testing.assert_allclose(B, fd_B, rtol=1e-7, atol=1e-8)


def _pendulum() -> Mechanism:
    """A damped pendulum hanging at rest, torque in, angle out: nonlinear and stable."""
    th, w, tau = casadi.SX.sym("th"), casadi.SX.sym("w"), casadi.SX.sym("tau")
    m, l, c = casadi.SX.sym("m"), casadi.SX.sym("l"), casadi.SX.sym("c")
    return Mechanism(q=th, dq=w, u=tau, parameters={"m": m, "l": l, "c": c},
                     lagrangian=0.5 * m * l ** 2 * w ** 2 + 9.81 * m * l * casadi.cos(th),
                     dissipation=0.5 * c * w ** 2, forces=tau, outputs=th, name="pendulum")


def test_nonlinear_simulation_approaches_the_linear_model_for_small_excitations():
    pendulum = _pendulum()
    p = {"m": 0.8, "l": 0.5, "c": 0.3}
    A, B, C, D = _numbers(pendulum.linearise(guess=[0.1]), **p)
    dt, N = 0.01, 400
    u = np.sign(np.sin(np.arange(N) * dt * 7.0))[:, None]
    errors = []
    for amplitude in (0.4, 0.2, 0.1):
        y = pendulum.simulate(p, amplitude * u, dt)
        sysd = scipy.signal.cont2discrete((A, B, C, D), dt, method="zoh")
        _, y_lin, _ = scipy.signal.dlsim(sysd[:4] + (dt,), amplitude * u)
        errors.append(np.abs(y - y_lin).max() / np.abs(y_lin).max())
    # the linear model is the first-order term; sin(th) = th - th^3/6 leaves a relative error
    # that falls with the amplitude squared
    assert errors[-1] < 1e-3
    assert 3.2 < errors[0] / errors[1] < 4.8 and 3.2 < errors[1] / errors[2] < 4.8


def test_linear_mechanism_simulates_exactly_like_its_linearisation():
    two = mechanisms.two_mass()
    p = {"m1": 1.3, "m2": 0.7, "k1": 3.0, "k2": 5.0, "c1": 0.2, "c2": 0.4}
    dt = 0.02
    u = np.random.default_rng(1).standard_normal((300, 1))
    y = two.simulate(p, u, dt)
    sysd = scipy.signal.cont2discrete(_two_mass_oracle(**p), dt, method="zoh")
    _, y_lin, _ = scipy.signal.dlsim(sysd[:4] + (dt,), u)
    np.testing.assert_allclose(y, y_lin, atol=1e-9 * np.abs(y_lin).max())


# -- operating points and C code ---------------------------------------------------------------
def test_a_rigid_body_mode_needs_a_named_equilibrium():
    drive = mechanisms.drive_train()
    with pytest.raises(ValueError, match="rigid-body mode.*equilibrium\\(q=...\\)"):
        drive.linearise()
    A, B, C, D = _numbers(drive.linearise(q=[0, 0]), J1=0.02, J2=0.1, k=100.0, c=0.2, b=0.05)
    # the free rotation integrates: one pole at s = 0 (its speed decays through b)
    assert np.sum(np.abs(np.linalg.eigvals(A)) < 1e-9) == 1
    assert np.linalg.matrix_rank(A) == 3


def test_operating_input_moves_the_equilibrium():
    pendulum = _pendulum()
    p = {"m": 0.8, "l": 0.5, "c": 0.3}
    tau = 0.5                                   # holds the pendulum at asin(tau / (m g l))
    x_eq = np.array(pendulum.equilibrium(u=[tau], guess=[0.3])(**p)["x_eq"]).ravel()
    np.testing.assert_allclose(x_eq, [np.arcsin(tau / (0.8 * 9.81 * 0.5)), 0], rtol=1e-12)
    A = _numbers(pendulum.linearise(u=[tau], guess=[0.3]), **p)[0]
    np.testing.assert_allclose(A[1, 0], -9.81 * np.cos(x_eq[0]) / 0.5, rtol=1e-12)


@pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None,
                    reason="no C compiler")
def test_generated_c_matches_the_symbolic_functions(tmp_path):
    from symbolic.codegen import compile_c

    legs = mechanisms.leg()
    op = mechanisms.upright(legs)
    path = legs.generate_c(tmp_path, channels=[(0, 0, [0, 2])], **op)
    compiled = compile_c(path, ["leg_linearisation", "leg_y0_u0"])
    for name, function in (("leg_linearisation", legs.linearise(**op)),
                           ("leg_y0_u0", legs.channel(0, 0, states=[0, 2], **op))):
        for a, b in zip(_numbers(compiled[name], **slip.SCENARIO),
                        _numbers(function, **slip.SCENARIO), strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-14, atol=1e-14)


# -- bad input -------------------------------------------------------------------------------------
def _parts():
    q, dq, u, k = (casadi.SX.sym(s) for s in ("q", "dq", "u", "k"))
    return {"q": q, "dq": dq, "u": u, "parameters": {"k": k},
            "lagrangian": 0.5 * dq ** 2 - 0.5 * k * q ** 2, "forces": u, "outputs": q}


@pytest.mark.parametrize(("change", "message"), [
    ({"q": [1.0]}, "q must be a casadi.SX"),
    ({"q": casadi.SX.sym("a") * 2}, "q must hold distinct symbols"),
    ({"dq": casadi.SX.sym("v", 2)}, "dq must have 1 entries"),
    ({"parameters": {"A": casadi.SX.sym("A")}}, "the Functions' own names"),
    ({"parameters": {"k": casadi.SX.sym("k") * 2}}, "scalar casadi.SX symbol"),
    ({"parameters": {}}, "non-empty dict"),
    ({"outputs": casadi.SX.sym("z")}, r"symbols \['z'\]"),
    ({"name": "my leg"}, "C identifier"),
])
def test_bad_construction_is_refused_by_name(change, message):
    parts = {**_parts(), **change}
    if "parameters" in change and "k" not in change["parameters"]:
        parts["lagrangian"] = 0.5 * parts["dq"] ** 2
    with pytest.raises(ValueError, match=message):
        Mechanism(**parts)


def test_an_input_in_the_kinetic_energy_is_refused():
    parts = _parts()
    parts["lagrangian"] = 0.5 * (parts["dq"] + parts["u"]) ** 2
    with pytest.raises(ValueError, match="dL/ddq depends on u"):
        Mechanism(**parts)


def test_known_and_channels_are_checked():
    two = mechanisms.two_mass()
    with pytest.raises(ValueError, match=r"known names \['mass'\]"):
        two.linearise(known={"mass": 1.0})
    with pytest.raises(ValueError, match="known\\['m1'\\] must be a finite number"):
        two.linearise(known={"m1": float("nan")})
    with pytest.raises(ValueError, match="output must be an int in \\[0, 1\\)"):
        two.channel(1, 0)
    with pytest.raises(ValueError, match="states must be distinct"):
        two.channel(0, 0, states=[0, 0])


@pytest.mark.parametrize(("call", "message"), [
    ({"u": np.zeros((5, 2))}, r"u must be finite \(N, 1\)"),
    ({"u": np.array([0.0, np.nan])}, r"u must be finite"),
    ({"dt": 0.0}, "dt must be a positive number"),
    ({"x0": np.zeros(3)}, r"x0 must be 4 numbers"),
])
def test_simulate_refuses_bad_arguments_by_name(call, message):
    two = mechanisms.two_mass()
    p = {"m1": 1.3, "m2": 0.7, "k1": 3.0, "k2": 5.0, "c1": 0.2, "c2": 0.4}
    args = {"u": np.zeros(5), "dt": 0.01, **call}
    with pytest.raises(ValueError, match=message):
        two.simulate(p, args.pop("u"), args.pop("dt"), **args)


@pytest.mark.parametrize("point", [{"m": 0.4, "l": 0.5, "b": 0.05}, {"m": 1.0, "l": 0.2, "b": 0.2}])
def test_a_users_hanging_pendulum_linearises_to_its_closed_form(point):
    # m l^2 thdd + b thd + m g l sin(th) = tau: at the rest point th = 0 (found by the
    # rootfinder from a guess off it) A = [[0, 1], [-g / l, -b / (m l^2)]], B = [0, 1 / (m l^2)]
    pendulum = _hanging_pendulum()
    m, l, b, g = point["m"], point["l"], point["b"], 9.81
    eq = pendulum.equilibrium(guess=[0.3])(**point, g=g)
    np.testing.assert_allclose(np.array(eq["x_eq"]).ravel(), [0, 0], atol=1e-12)
    A, B, C, D = _numbers(pendulum.linearise(guess=[0.3], known={"g": g}), **point)
    np.testing.assert_allclose(A, [[0, 1], [-g / l, -b / (m * l * l)]], rtol=1e-12)
    np.testing.assert_allclose(B, [[0], [1 / (m * l * l)]], rtol=1e-12)
    np.testing.assert_array_equal(C, [[1, 0]])
    np.testing.assert_array_equal(D, [[0]])
