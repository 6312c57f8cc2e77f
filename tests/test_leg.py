"""Tests for ``symbolic/leg.py``: the robot leg of paper Sec. IV, derived with CasADi.

Oracles, each independent of the code under test: the textbook SLIP equations typed in NumPy, the
paper's Eq. 16 (``leg.eq16``), central finite differences, ``scipy.integrate.solve_ivp`` of the
nonlinear model against ``scipy.linalg.expm`` of the linear one, ``control.ss2tf`` transfer
functions, a NumPy generalised-least-squares combination, and compiled C against SX evaluation.
"""

from __future__ import annotations

import pathlib
import shutil
import subprocess
import sys

import casadi
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from symbolic import leg
from tests.helpers import tf_coeffs
from tests.problems import random_system

NAMES = ("k", "d", "m")


def _draw(rng: np.random.Generator, ranges=leg.RANGES) -> dict[str, float]:
    return {n: float(rng.uniform(*ranges[n])) for n in NAMES}


#: The paper's scenario, random points in the study's ranges, and two points well outside them.
POINTS = [
    leg.SCENARIO,
    *(_draw(np.random.default_rng(seed)) for seed in range(4)),
    {"k": 60.0, "d": 0.3, "m": 0.2},
    {"k": 8.0, "d": 12.0, "m": 0.4},
]
#: Beyond the study's ranges, yet with an upright equilibrium 0 < L < l0 (checked where used).
BEYOND = {"k": (5.0, 80.0), "d": (0.1, 20.0), "m": (0.05, 3.0)}


def _full(point: dict[str, float], l0: float = leg.L0, g: float = leg.G) -> dict[str, float]:
    return {**point, "l0": l0, "g": g}


def _L(point: dict[str, float], l0: float = leg.L0, g: float = leg.G) -> float:
    return l0 - point["m"] * g / point["k"]


def _np(value) -> np.ndarray:
    return np.array(value, dtype=np.float64)


def _tf(A, b, c, d=0.0):
    """``tests.helpers.tf_coeffs`` (python-control's ss2tf) of NumPy copies of casadi values."""
    return tf_coeffs(_np(A), _np(b), _np(c), _np(d))


def _both(cs, cu) -> dict:
    """The joint inverse's arguments from the stable and the unstable CCF."""
    return {f"{s}1": v for s, v in cs.items()} | {f"{s}2": v for s, v in cu.items()}


def _perturb(ccf, rng, size) -> dict[str, np.ndarray]:
    """A CCF whose informative entries (last row of A, C) carry relative errors of ~size."""
    A, C = _np(ccf["A"]).copy(), _np(ccf["C"]).copy()
    A[-1] *= 1 + size * rng.normal(size=A.shape[1])
    C *= 1 + size * rng.normal(size=C.shape)
    return {**{key: _np(v) for key, v in ccf.items()}, "A": A, "C": C}


def _textbook_slip(x, u, k, d, m, l0, g):
    """The spring-loaded inverted pendulum as in textbooks, typed in by hand (NumPy)."""
    l, ldot, th, thdot = x
    F, tau = u
    lddot = l * thdot**2 - g * np.sin(th) + (F - k * (l - l0) - d * ldot) / m
    thddot = (tau - 2.0 * m * l * ldot * thdot - m * g * l * np.cos(th)) / (m * l**2)
    return np.array([ldot, lddot, thdot, thddot])


# ---------------------------------------------------------------------------------------------
# Model and derivation
# ---------------------------------------------------------------------------------------------


def test_lagrangian_is_kinetic_minus_potential_energy():
    rng = np.random.default_rng(1)
    f = leg.lagrangian()
    assert f.name() == "lagrangian"
    assert f.name_in() == ["q", "qdot", "k", "d", "m", "l0", "g"] and f.name_out() == ["L"]
    for _ in range(5):
        (l, th), (ldot, thdot) = rng.uniform(0.2, 1.5, 2), rng.normal(size=2)
        p = _full(_draw(rng))
        T = 0.5 * p["m"] * (ldot**2 + (l * thdot) ** 2)
        V = p["m"] * p["g"] * l * np.sin(th) + 0.5 * p["k"] * (l - p["l0"]) ** 2
        value = float(f(q=[l, th], qdot=[ldot, thdot], **p)["L"])
        assert value == pytest.approx(T - V, rel=1e-13, abs=1e-13)


def test_dynamics_equal_the_textbook_slip_equations():
    rng = np.random.default_rng(2)
    f = leg.dynamics()
    assert f.name_in() == ["x", "u", "k", "d", "m", "l0", "g"] and f.name_out() == ["xdot"]
    for _ in range(20):
        x = rng.uniform([0.2, -2.0, -np.pi, -3.0], [1.5, 2.0, np.pi, 3.0])
        u = rng.normal(size=2) * [5.0, 1.0]
        p = _full(_draw(rng, BEYOND), l0=rng.uniform(0.5, 1.5), g=rng.uniform(1.0, 20.0))
        derived = _np(f(x, u, *p.values())).ravel()
        expected = _textbook_slip(x, u, *p.values())
        scale = np.abs(expected).max()
        np.testing.assert_allclose(derived, expected, rtol=1e-12, atol=1e-12 * scale)


@pytest.mark.parametrize("point", POINTS)
def test_equilibrium_is_a_rest_point(point):
    p = _full(point)
    eq = leg.equilibrium()(**p)
    x_eq, u_eq = _np(eq["x_eq"]).ravel(), _np(eq["u_eq"]).ravel()
    np.testing.assert_allclose(x_eq, [_L(point), 0.0, np.pi / 2, 0.0], rtol=1e-15, atol=0)
    np.testing.assert_array_equal(u_eq, [0.0, 0.0])
    xdot = _np(leg.dynamics()(x_eq, u_eq, *p.values())).ravel()
    np.testing.assert_allclose(xdot, 0.0, atol=1e-12)
    # The paper's text says "linearised at l = l0"; that is no rest point (the spring is slack and
    # gravity pulls the mass down at g), which is why Eq. 16 carries L = l0 - m g / k.
    at_l0 = _np(leg.dynamics()([p["l0"], 0, np.pi / 2, 0], u_eq, *p.values())).ravel()
    assert at_l0[1] == pytest.approx(-p["g"], rel=1e-12)


# ---------------------------------------------------------------------------------------------
# Linearisation = paper Eq. 16
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("point", POINTS)
def test_linearisation_equals_eq16(point):
    p = _full(point)
    derived, paper = leg.linearisation()(**p), leg.eq16()(**p)
    for key, shape in (("A", (4, 4)), ("B", (4, 2))):
        assert _np(derived[key]).shape == shape
        scale = np.abs(_np(paper[key])).max()
        np.testing.assert_allclose(
            _np(derived[key]), _np(paper[key]), rtol=1e-12, atol=1e-12 * scale, err_msg=key
        )
    # And Eq. 16 in closed form, so that eq16() itself is held to the paper.
    k, d, m, L, g = point["k"], point["d"], point["m"], _L(point), leg.G
    A, B = _np(paper["A"]), _np(paper["B"])
    assert (A[1, 0], A[1, 1], A[3, 2], B[1, 0], B[3, 1]) == pytest.approx(
        (-k / m, -d / m, g / L, 1 / m, 1 / (m * L**2)), rel=1e-14
    )


@pytest.mark.parametrize("point", POINTS[:3])
def test_linearisation_equals_finite_difference_jacobian(point):
    p = _full(point)
    f = leg.dynamics()
    x_eq = _np(leg.equilibrium()(**p)["x_eq"]).ravel()
    u_eq = np.zeros(2)

    def rhs(x, u):
        return _np(f(x, u, *p.values())).ravel()

    def central(fun, z0, h):
        cols = []
        for i in range(z0.size):
            e = np.zeros(z0.size)
            e[i] = h
            cols.append((fun(z0 + e) - fun(z0 - e)) / (2 * h))
        return np.stack(cols, axis=1)

    A_fd = central(lambda x: rhs(x, u_eq), x_eq, 1e-6)
    B_fd = central(lambda u: rhs(x_eq, u), u_eq, 1e-3)  # linear in u: any step is exact
    lin = leg.linearisation()(**p)
    for key, fd in (("A", A_fd), ("B", B_fd)):
        exact = _np(lin[key])
        assert np.abs(fd - exact).max() <= 1e-6 * np.abs(exact).max(), key


def _small_amplitude_mismatch(scale: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Nonlinear vs linear response to F = 0.01 scale N and tau = 1e-4 scale N m steps, 1 s.

    Returns the absolute mismatch per state, the linear response's peak per state, and the linear
    response's size ``eps = max(|dtheta|, |dl| / L)``.
    """
    p = _full(leg.SCENARIO)
    f = leg.dynamics()
    x_eq = _np(leg.equilibrium()(**p)["x_eq"]).ravel()
    lin = leg.linearisation()(**p)
    A, B = _np(lin["A"]), _np(lin["B"])
    u = scale * np.array([0.01, 1e-4])
    t = np.linspace(0.0, 1.0, 51)
    sol = solve_ivp(
        lambda _, x: _np(f(x, u, *p.values())).ravel(),
        (0.0, 1.0), x_eq, method="DOP853", rtol=1e-12, atol=1e-14, t_eval=t,
    )
    assert sol.success
    # Linear step response from rest: x(t) = int_0^t e^{A s} ds B u, the top-right block of the
    # exponential of the augmented matrix [[A, B u], [0, 0]].
    M = np.zeros((5, 5))
    M[:4, :4], M[:4, 4] = A, B @ u
    linear = np.array([expm(M * tk)[:4, 4] for tk in t])
    mismatch = np.abs(sol.y.T - x_eq - linear).max(axis=0)
    peak = np.abs(linear).max(axis=0)
    eps = max(peak[2], peak[0] / _L(leg.SCENARIO))
    return mismatch, peak, eps


def test_small_amplitude_response_matches_the_linear_model_to_second_order():
    mismatch, peak, eps = _small_amplitude_mismatch(1.0)
    half, _, _ = _small_amplitude_mismatch(0.5)
    # The responses are small (dl ~ 6e-4 m, dtheta ~ 2e-3 rad), so linearisation is accurate to
    # relative O(eps): the neglected terms (g dtheta^2 / 2 and l thetadot^2 in lddot,
    # g dtheta dl / L^2 and 2 ldot thetadot / l in thetaddot) are eps times the retained ones with
    # O(1) coefficients. We allow 5 eps (observed: 0.3 eps for l, 2 eps for theta), far below the
    # response itself and far above the integrator's error (rtol 1e-12).
    assert eps < 3e-3
    assert np.all(mismatch <= 5.0 * eps * peak), (mismatch / peak, eps)
    assert np.all(mismatch > 1e3 * 1e-12 * np.pi), "the mismatch must be resolved by the solver"
    # Second order: halving the inputs divides the mismatch by ~4 (2 would mean a first-order
    # error, i.e. a wrong linearisation).
    ratio = mismatch / half
    assert np.all((ratio > 3.6) & (ratio < 4.4)), ratio


# ---------------------------------------------------------------------------------------------
# Subsystems and CCF maps
# ---------------------------------------------------------------------------------------------


def _assert_ccf_shape(A, B, C, D, n=2):
    A, B, C, D = _np(A), _np(B), _np(C), _np(D)
    assert A.shape == (n, n) and B.shape == (n, 1) and C.shape == (1, n) and D.shape == (1, 1)
    np.testing.assert_array_equal(A[:-1, :], np.eye(n)[1:, :])  # ones on the superdiagonal
    np.testing.assert_array_equal(B[:, 0], np.eye(n)[:, -1])  # b = e_n


def test_subsystems_are_the_diagonal_blocks_of_eq16():
    p = _full(leg.SCENARIO)
    sub = leg.subsystems()(**p)
    assert leg.subsystems().name_out() == ["A1", "B1", "C1", "D1", "A2", "B2", "C2", "D2"]
    A, B = _np(leg.eq16()(**p)["A"]), _np(leg.eq16()(**p)["B"])
    np.testing.assert_allclose(_np(sub["A1"]), A[:2, :2], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(_np(sub["A2"]), A[2:, 2:], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(_np(sub["B1"]).ravel(), B[:2, 0], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(_np(sub["B2"]).ravel(), B[2:, 1], rtol=1e-13, atol=1e-13)
    for i in "12":
        np.testing.assert_array_equal(_np(sub[f"C{i}"]), [[1.0, 0.0]])
        np.testing.assert_array_equal(_np(sub[f"D{i}"]), [[0.0]])
    # Decoupling: the off-diagonal blocks of the derived linearisation vanish to rounding.
    lin = leg.linearisation()(**p)
    A_lin, B_lin = _np(lin["A"]), _np(lin["B"])
    assert np.abs(A_lin[:2, 2:]).max() < 1e-12 and np.abs(A_lin[2:, :2]).max() < 1e-12
    assert np.abs(B_lin[:2, 1]).max() < 1e-12 and np.abs(B_lin[2:, 0]).max() < 1e-12


@pytest.mark.parametrize("point", POINTS)
def test_maps_realise_the_transfer_functions_of_eq16(point):
    p = _full(point)
    paper = leg.eq16()(**p)
    A, B = _np(paper["A"]), _np(paper["B"])
    k, d, m, L, g = point["k"], point["d"], point["m"], _L(point), leg.G
    cases = [
        (leg.stable_map(), A[:2, :2], B[:2, 0], (k / m, d / m, 1 / m)),
        (leg.unstable_map(), A[2:, 2:], B[2:, 1], (-g / L, 0.0, 1 / (m * L**2))),
    ]
    for f, A_sub, b_sub, (a0, a1, c0) in cases:
        out = f(**point)
        _assert_ccf_shape(out["A"], out["B"], out["C"], out["D"])
        num, den = _tf(out["A"], out["B"], out["C"], out["D"])
        num_ref, den_ref = _tf(A_sub, b_sub, [1.0, 0.0], 0.0)
        np.testing.assert_allclose(den, den_ref, rtol=1e-12, atol=1e-12 * np.abs(den_ref).max())
        np.testing.assert_allclose(num, num_ref, rtol=1e-12, atol=1e-12 * np.abs(num_ref).max())
        # The closed forms of DESIGN.md: G = c0 / (s^2 + a1 s + a0).
        Ac, Cc = _np(out["A"]), _np(out["C"])
        assert (-Ac[1, 0], -Ac[1, 1], Cc[0, 0]) == pytest.approx((a0, a1, c0), rel=1e-13, abs=1e-13)
        assert Cc[0, 1] == 0.0 and float(out["D"]) == 0.0


def test_maps_are_named_and_vectorise():
    for f, name in ((leg.stable_map(), "stable_map"), (leg.unstable_map(), "unstable_map")):
        assert f.name() == name
        assert f.name_in() == ["k", "d", "m"] and f.name_out() == ["A", "B", "C", "D"]
        assert all(f.size_in(i) == (1, 1) for i in range(3))
        batch = f.map(3)(k=np.array([[20.0, 22.0, 25.0]]), d=np.array([[2.0, 3.0, 5.0]]),
                          m=np.array([[0.5, 1.0, 1.5]]))
        single = f(k=22.0, d=3.0, m=1.0)
        np.testing.assert_array_equal(_np(batch["A"])[:, 2:4], _np(single["A"]))
    assert leg.stable_inverse().name_in() == ["A", "B", "C", "D"]
    assert leg.stable_inverse().name_out() == ["k", "d", "m"]
    assert leg.unstable_inverse().name_out() == ["k", "m"]
    assert leg.joint_inverse().name_in() == ["A1", "B1", "C1", "D1", "A2", "B2", "C2", "D2"]
    assert leg.joint_inverse().name_out() == ["k", "d", "m"]


def test_unstable_map_does_not_depend_on_d():
    f = leg.unstable_map()
    k, d, m = (casadi.SX.sym(n) for n in NAMES)
    out = f(k=k, d=d, m=m)
    assert not any(casadi.depends_on(out[key], d) for key in "ABCD")
    assert casadi.depends_on(out["A"], k) and casadi.depends_on(out["C"], m)
    assert casadi.depends_on(leg.stable_map()(k=k, d=d, m=m)["A"], d)


def test_l0_and_g_can_be_overridden():
    point, l0, g = leg.SCENARIO, 1.1, 3.7  # a longer leg, on Mars
    L = l0 - point["m"] * g / point["k"]
    out = leg.unstable_map(l0=l0, g=g)(**point)
    default = leg.unstable_map()(**point)
    assert -float(out["A"][1, 0]) == pytest.approx(-g / L, rel=1e-13)
    assert float(out["C"][0, 0]) == pytest.approx(1 / (point["m"] * L**2), rel=1e-13)
    assert not np.allclose(_np(out["A"]), _np(default["A"]))
    # G1 depends on neither l0 nor g.
    for key in "ABCD":
        np.testing.assert_allclose(
            _np(leg.stable_map(l0=l0, g=g)(**point)[key]), _np(leg.stable_map()(**point)[key]),
            rtol=1e-14, atol=1e-14,
        )
    back = leg.unstable_inverse(l0=l0, g=g)(**out)
    got = (float(back["k"]), float(back["m"]))
    assert got == pytest.approx((point["k"], point["m"]), rel=1e-12)


@pytest.mark.parametrize(
    "kwargs, match",
    [({"l0": -0.8}, "l0 must be finite and positive; got -0.8"),
     ({"g": float("nan")}, "g must be finite and positive; got nan")],
)
def test_maps_reject_bad_constants(kwargs, match):
    builders = (leg.stable_map, leg.unstable_map, leg.stable_inverse, leg.unstable_inverse,
                leg.joint_inverse)
    for build in builders:
        with pytest.raises(ValueError, match=match):
            build(**kwargs)
    with pytest.raises(ValueError, match="unstable_noise must be finite and positive"):
        leg.joint_inverse(unstable_noise=0.0)


# ---------------------------------------------------------------------------------------------
# The generic CCF helper
# ---------------------------------------------------------------------------------------------


def _assert_close_scaled(actual, expected, rtol, what=""):
    actual, expected = _np(actual), _np(expected)
    scale = max(np.abs(expected).max(), 1e-300)
    assert np.abs(actual - expected).max() <= rtol * scale, (what, actual, expected)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_ccf_of_any_realisation_keeps_the_transfer_function(n):
    rng = np.random.default_rng(10 + n)
    A, b, c, d = random_system(n, rng, feedthrough=True)
    out = leg.ccf(A, b, c, d)
    assert isinstance(out, leg.CCFRealisation)
    assert all(isinstance(x, casadi.DM) for x in out)
    _assert_ccf_shape(out.A, out.b, out.c, out.d, n=n)
    num, den = _tf(out.A, out.b, out.c, out.d)
    num_ref, den_ref = _tf(A, b, c, d)
    # random_system hides the CCF in an ill-conditioned basis (cond(A) up to 1e6 for n = 5), so
    # even ss2tf is only good to ~1e-10 here.
    _assert_close_scaled(den, den_ref, 1e-8, "den")
    _assert_close_scaled(num, num_ref, 1e-8, "num")
    # Canonical: another basis of the same system gives the same matrices.
    T = rng.normal(size=(n, n)) + 3 * np.eye(n)
    other = leg.ccf(T @ A @ np.linalg.inv(T), T @ b, c @ np.linalg.inv(T), d)
    for x, y in zip(out, other, strict=True):
        _assert_close_scaled(y, x, 1e-8)


@pytest.mark.parametrize("n", [3, 6, 8])
def test_ccf_recovers_a_known_canonical_form_from_a_random_basis(n):
    # Exact oracle: build the CCF from chosen poles and numerator, hide it, recover it.
    rng = np.random.default_rng(50 + n)
    den = np.poly(-rng.uniform(0.5, 3.0, n))  # s^n + ..., highest power first
    A_c = np.zeros((n, n))
    A_c[:-1, 1:] = np.eye(n - 1)
    A_c[-1] = -den[1:][::-1]
    b_c, c_c = np.eye(n)[:, -1], rng.normal(size=n)
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    T = Q @ np.diag(rng.uniform(0.3, 3.0, n))  # cond(T) <= 10
    Ti = np.linalg.inv(T)
    out = leg.ccf(T @ A_c @ Ti, T @ b_c, c_c @ Ti, 0.7)
    _assert_close_scaled(_np(out.A)[-1], A_c[-1], 1e-9, "a")
    _assert_close_scaled(_np(out.c)[0], c_c, 1e-9, "c")
    assert float(out.d) == 0.7


def test_ccf_of_a_ccf_is_itself_and_handles_an_uncontrollable_input():
    A_c, c_c = np.array([[0.0, 1.0], [-3.0, -2.0]]), np.array([5.0, 0.0])
    out = leg.ccf(A_c, [0.0, 1.0], c_c, 0.0)
    np.testing.assert_array_equal(_np(out.A), A_c)
    np.testing.assert_array_equal(_np(out.c)[0], c_c)
    # b = e_1 with A upper triangular: only the first mode is reachable, and the Householder
    # step on A's first column meets a zero vector (the guarded reflector is the identity).
    A = np.triu(np.arange(1.0, 10.0).reshape(3, 3))
    out = leg.ccf(A, [1.0, 0.0, 0.0], [1.0, 1.0, 1.0], 0.0)
    assert np.all(np.isfinite(_np(out.A))) and np.all(np.isfinite(_np(out.c)))
    for x, y in zip(_tf(out.A, out.b, out.c), _tf(A, [1, 0, 0], [1, 1, 1]), strict=True):
        _assert_close_scaled(x, y, 1e-13)
    # b and A's first column almost along e_1: a reflector with the cancelling sign would leave
    # ~1e-9 below A's subdiagonal, which the Hessenberg recursion ignores.
    rng = np.random.default_rng(7)
    A = rng.normal(size=(4, 4))
    A[2:, 0] = [1e-9, -2e-9]
    b, c = np.array([1.0, 1e-9, 0.0, 2e-9]), rng.normal(size=4)
    out = leg.ccf(A, b, c, 0.0)
    for x, y in zip(_tf(out.A, out.b, out.c), _tf(A, b, c), strict=True):
        _assert_close_scaled(x, y, 1e-12)


@pytest.mark.parametrize("kind", [casadi.SX, casadi.MX])
def test_ccf_is_symbolic(kind):
    n = 3
    A, b, c, d = kind.sym("A", n, n), kind.sym("b", n), kind.sym("c", 1, n), kind.sym("d")
    out = leg.ccf(A, b, c, d)
    assert all(isinstance(x, kind) for x in out)
    f = casadi.Function("f", [A, b, c, d], list(out))
    A0, b0, c0, d0 = random_system(n, np.random.default_rng(3), feedthrough=True)
    for x, y in zip(f(A0, b0, c0, d0), leg.ccf(A0, b0, c0, d0), strict=True):
        np.testing.assert_allclose(_np(x), _np(y), rtol=1e-13, atol=1e-13)


def test_ccf_rejects_bad_shapes():
    A = np.eye(2)
    with pytest.raises(ValueError, match=r"A must be square \(n, n\) with n >= 1; got \(2, 3\)"):
        leg.ccf(np.ones((2, 3)), [0, 1], [1, 0], 0)
    with pytest.raises(ValueError, match=r"b must be a vector with n=2 elements; got shape \(3,"):
        leg.ccf(A, [0, 1, 2], [1, 0], 0)
    with pytest.raises(ValueError, match=r"c must be a vector with n=2 elements; got shape \(2,"):
        leg.ccf(A, [0, 1], np.eye(2), 0)
    with pytest.raises(ValueError, match=r"d must be a scalar"):
        leg.ccf(A, [0, 1], [1, 0], [0, 0])


# ---------------------------------------------------------------------------------------------
# Inverses
# ---------------------------------------------------------------------------------------------


def _points(rng, ranges, count=40):
    points = []
    while len(points) < count:
        point = _draw(rng, ranges)
        if 0.05 < _L(point):  # an upright equilibrium exists (L < l0 always holds)
            points.append(point)
    return points


@pytest.mark.parametrize("ranges", [leg.RANGES, BEYOND], ids=["ranges", "beyond"])
def test_inverses_round_trip(ranges):
    rng = np.random.default_rng(20)
    fs, fu = leg.stable_map(), leg.unstable_map()
    inv_s, inv_u = leg.stable_inverse(), leg.unstable_inverse()
    joints = [leg.joint_inverse(), leg.joint_inverse(unstable_noise=10.0)]
    for point in _points(rng, ranges):
        cs, cu = fs(**point), fu(**point)
        both = _both(cs, cu)
        estimates = [inv_s(**cs), inv_u(**cu)] + [joint(**both) for joint in joints]
        for est in estimates:
            for name, value in est.items():
                assert float(value) == pytest.approx(point[name], rel=1e-12), (name, point)


def _gls_oracle(cs, cu, l0=leg.L0, g=leg.G, noise=1.0):
    """The documented joint estimate, rebuilt in NumPy with a finite-difference covariance."""
    a0s, a1s, c0s = -float(cs["A"][1, 0]), -float(cs["A"][1, 1]), float(cs["C"][0, 0])
    z_u = np.log([float(cu["A"][1, 0]), float(cu["C"][0, 0])])  # log(-a0), log(c0) of G2

    def y_u(z):  # (log k/m, log m) from the unstable subsystem's log-coefficients
        L = g / np.exp(z[0])
        return np.array([np.log(g / (l0 - L)), -z[1] - 2 * np.log(L)])

    h = 1e-6
    J = np.stack([(y_u(z_u + h * e) - y_u(z_u - h * e)) / (2 * h) for e in np.eye(2)], axis=1)
    cov = np.block([[np.eye(2), np.zeros((2, 2))], [np.zeros((2, 2)), noise**2 * J @ J.T]])
    H = np.vstack([np.eye(2), np.eye(2)])
    y = np.concatenate([[np.log(a0s), -np.log(c0s)], y_u(z_u)])
    W = np.linalg.inv(cov)
    theta = np.linalg.solve(H.T @ W @ H, H.T @ W @ y)
    m = np.exp(theta[1])
    return {"k": np.exp(theta[0]) * m, "d": a1s * m, "m": m}


@pytest.mark.parametrize("noise", [1.0, 3.0])
def test_joint_inverse_is_the_documented_weighted_combination(noise):
    rng = np.random.default_rng(30)
    joint = leg.joint_inverse(unstable_noise=noise)
    for _ in range(5):
        truth = _draw(rng)
        # Inconsistent data, as from an imperfect identification: perturb every coefficient.
        cs, cu = leg.stable_map()(**truth), leg.unstable_map()(**truth)
        cs, cu = _perturb(cs, rng, 0.05), _perturb(cu, rng, 0.05)
        both = _both(cs, cu)
        got = joint(**both)
        expected = _gls_oracle(cs, cu, noise=noise)
        for name in NAMES:
            assert float(got[name]) == pytest.approx(expected[name], rel=1e-7), name


def test_joint_inverse_combines_both_subsystems():
    truth = leg.SCENARIO
    cs = leg.stable_map()(**truth)
    cu = leg.unstable_map()(**{**truth, "m": 1.2 * truth["m"]})  # G2 "sees" a heavier leg
    both = _both(cs, cu)
    m_s = float(leg.stable_inverse()(**cs)["m"])
    m_u = float(leg.unstable_inverse()(**cu)["m"])
    m_j = float(leg.joint_inverse()(**both)["m"])
    assert min(m_s, m_u) < m_j < max(m_s, m_u)
    # Distrusting G2 moves the estimate towards the stable subsystem's, and in the limit onto it.
    m_far = float(leg.joint_inverse(unstable_noise=10.0)(**both)["m"])
    assert abs(m_far - m_s) < abs(m_j - m_s)
    m_inf = float(leg.joint_inverse(unstable_noise=1e8)(**both)["m"])
    assert m_inf == pytest.approx(m_s, rel=1e-12)


# ---------------------------------------------------------------------------------------------
# Code generation
# ---------------------------------------------------------------------------------------------


def test_generated_c_agrees_with_sx(tmp_path):
    c_file = leg.generate_c(tmp_path, l0=0.9, g=9.7)
    assert c_file == tmp_path / "leg_maps.c" and c_file.is_file()
    source = c_file.read_text()
    assert all(name in source for name in leg.CODEGEN_FUNCTIONS)
    if shutil.which("gcc") is None and shutil.which("cc") is None:
        pytest.skip("no C compiler (gcc or cc) on PATH: compiling the generated code is untested")
    compiled = leg.compile_c(c_file)
    assert sorted(compiled) == sorted(leg.CODEGEN_FUNCTIONS)

    rng = np.random.default_rng(40)
    python = {
        "stable_map": leg.stable_map(l0=0.9, g=9.7),
        "unstable_map": leg.unstable_map(l0=0.9, g=9.7),
        "stable_inverse": leg.stable_inverse(l0=0.9, g=9.7),
        "unstable_inverse": leg.unstable_inverse(l0=0.9, g=9.7),
        "joint_inverse": leg.joint_inverse(l0=0.9, g=9.7),
    }
    for name, f in python.items():
        assert compiled[name].name_in() == f.name_in()
        assert compiled[name].name_out() == f.name_out()
    for _ in range(5):
        point = _draw(rng)
        cs = python["stable_map"](**point)
        cu = python["unstable_map"](**point)
        # Perturbed CCFs, so that the inverses are exercised away from exact data too.
        cu = {**cu, "C": cu["C"] * 1.1}
        both = _both(cs, cu)
        args = {
            "stable_map": point, "unstable_map": point, "stable_inverse": cs,
            "unstable_inverse": cu, "joint_inverse": both,
        }
        for name, f in python.items():
            expected, got = f(**args[name]), compiled[name](**args[name])
            for key in expected:
                np.testing.assert_allclose(
                    _np(got[key]), _np(expected[key]), rtol=1e-12, atol=1e-12, err_msg=name
                )


def test_compile_c_without_a_compiler_says_so(tmp_path, monkeypatch):
    c_file = leg.generate_c(tmp_path)
    monkeypatch.setattr(shutil, "which", lambda _: None)
    with pytest.raises(RuntimeError, match="needs a C compiler"):
        leg.compile_c(c_file)
    with pytest.raises(RuntimeError, match="could not run the compiler"):
        leg.compile_c(c_file, compiler=str(tmp_path / "no-such-cc"))


@pytest.mark.parametrize("module", ["symbolic.leg", "symbolic.slip", "symbolic.realisation"])
def test_module_self_check_runs(module):
    done = subprocess.run(
        [sys.executable, "-m", module], capture_output=True, text=True, timeout=120,
        cwd=pathlib.Path(__file__).resolve().parents[1],
    )
    assert done.returncode == 0, done.stderr
    assert "All checks passed." in done.stdout


def test_leg_keeps_every_name_of_the_model_it_re_exports():
    # symbolic.leg was one module; the model moved to symbolic.slip, the CCF to
    # symbolic.realisation: the old names are the same objects.
    from symbolic import realisation, slip

    for name in ("L0", "G", "RANGES", "SCENARIO", "PARAMETERS", "lagrangian", "dynamics",
                 "equilibrium", "linearisation", "eq16", "subsystems"):
        assert getattr(leg, name) is getattr(slip, name), name
    assert leg.ccf is realisation.ccf and leg.CCFRealisation is realisation.CCFRealisation


def test_codegen_compiles_any_function(tmp_path):
    from symbolic import codegen

    x = casadi.SX.sym("x", 2)
    f = casadi.Function("square_sum", [x], [casadi.sumsqr(x)], ["x"], ["s"])
    c_file = codegen.generate_c(tmp_path, [f], name="mine")
    assert c_file == tmp_path / "mine.c" and "square_sum" in c_file.read_text()
    with pytest.raises(ValueError, match="name must be a C identifier"):
        codegen.generate_c(tmp_path, [f], name="no-dash")
    loaded = codegen.compile_c(c_file, ["square_sum"])["square_sum"]
    assert float(loaded(np.array([3.0, 4.0]))) == 25.0


@pytest.mark.parametrize("point", [leg.SCENARIO, {"k": 20.0, "d": 5.0, "m": 1.5}])
def test_joint_map_is_both_subsystem_maps_and_joint_inverse_undoes_it(point):
    joint = leg.joint_map()(**point)
    for r, f in ((1, leg.stable_map()), (2, leg.unstable_map())):
        single = f(**point)
        for s in "ABCD":
            np.testing.assert_array_equal(np.array(joint[f"{s}{r}"]), np.array(single[s]))
    back = leg.joint_inverse()(**joint)
    for name, value in point.items():
        assert float(back[name]) == pytest.approx(value, rel=1e-12)
