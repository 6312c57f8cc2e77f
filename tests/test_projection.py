"""simulation.projection: the linear part of a record's model by least squares, against a
per-step scipy ``expm`` recursion (an independent FOH oracle) and the exact kernel."""

import numpy as np
import pytest
import scipy.linalg
from helpers import companion

from aeid_struct.simulation import fit_initial, forced_states, project, simulate_outputs

ccf = companion


def oracle(A, b, c, d, u, dt, x0):
    """FOH recursion ``x_{k+1} = Phi x_k + gamma1 u_k + gamma2 (u_{k+1} - u_k)`` with scipy expm."""
    n = A.shape[0]
    M = np.zeros((n + 2, n + 2))
    M[:n, :n], M[:n, n], M[n, n + 1] = A * dt, b * dt, 1.0
    X = scipy.linalg.expm(M)
    Phi, g1, g2 = X[:n, :n], X[:n, n], X[:n, n + 1]
    x, y = np.array(x0, float), np.empty(len(u))
    for k in range(len(u)):
        y[k] = c @ x + d * u[k]
        if k + 1 < len(u):
            x = Phi @ x + g1 * u[k] + g2 * (u[k + 1] - u[k])
    return y


SYSTEMS = [
    ([1.0, 2.0], [3.0], 0.1),                                        # order 1
    (np.poly([-0.4 + 2j, -0.4 - 2j]).real, [1.0, -2.0], 0.05),       # resonance, RHP zero
    (np.poly([-1.0, -0.5 + 3j, -0.5 - 3j]).real, [0.5, -1.0, 2.0], 0.05),
    (np.poly([-0.02 + 1j, -0.02 - 1j, -3.0, -0.3]).real, [0.0, 1.0, 0.0, 4.0], 0.2),
]


@pytest.mark.parametrize("den, num, dt", SYSTEMS)
def test_forced_states_equal_the_exact_kernel(den, num, dt):
    A, b = ccf(den)
    n = A.shape[0]
    u = np.random.default_rng(1).standard_normal(600).cumsum() * 0.1
    X, gamma2 = forced_states(A, b, u, dt)
    exact = simulate_outputs(A, b, np.eye(n), np.zeros(n), u, dt).T     # from rest
    # forced_states starts from x_0 = gamma2 u_0: the difference is that state's free response
    free = np.array([oracle(A, b, e, 0.0, np.zeros(600), dt, gamma2 * u[0]) for e in np.eye(n)]).T
    scale = np.abs(exact).max()
    np.testing.assert_allclose(X, exact + free, atol=1e-10 * scale, rtol=0)


@pytest.mark.parametrize("den, num, dt", SYSTEMS)
@pytest.mark.parametrize("delay", [0, 3])
def test_project_recovers_c_d_x0_offset_exactly(den, num, dt, delay):
    A, b = ccf(den)
    n = A.shape[0]
    rng = np.random.default_rng(2)
    c = np.array(num, float)[::-1]
    d, offset, x0 = 0.3, 0.7, rng.standard_normal(n)
    u = rng.standard_normal(800).cumsum() * 0.1
    y = np.concatenate([np.full(delay, 9.0), oracle(A, b, c, d, u[: 800 - delay], dt, x0)])
    y = y + offset
    p = project(A, b, y, u, dt, delay=delay)
    np.testing.assert_allclose(p.c, c, rtol=1e-7, atol=1e-7)
    assert p.d == pytest.approx(d, abs=1e-7)
    assert p.y_offset == pytest.approx(offset, abs=1e-7)
    np.testing.assert_allclose(p.x0, x0, rtol=1e-6, atol=1e-6)
    assert p.fit == pytest.approx(100.0, abs=1e-6)
    assert np.isnan(p.y_hat[:delay]).all()
    np.testing.assert_allclose(p.y_hat[delay:], y[delay:], atol=1e-8 * np.abs(y).max())


def test_project_with_noise_is_the_least_squares_optimum():
    A, b = ccf(SYSTEMS[2][0])
    rng = np.random.default_rng(3)
    u = rng.standard_normal(500)
    c, d = np.array([2.0, -1.0, 0.5]), 0.0
    y = oracle(A, b, c, d, u, 0.05, [0.1, 0.2, -0.3]) + 0.05 * rng.standard_normal(500)
    p = project(A, b, y, u, 0.05, feedthrough=False, offset=False)
    assert p.d == 0.0 and p.y_offset == 0.0
    # the optimum is no worse than the truth, and a perturbed c with its best x0 is worse
    truth = fit_initial(A, b, c, d, y, u, 0.05, offset=False)
    other = fit_initial(A, b, p.c * 1.01, 0.0, y, u, 0.05, offset=False)
    assert p.cost <= truth.cost + 1e-15
    assert other.cost > p.cost
    # the model output from the returned x0 is the fitted output (consistency of c, x0)
    np.testing.assert_allclose(oracle(A, b, p.c, 0.0, u, 0.05, p.x0), p.y_hat, atol=1e-9)


def test_fit_initial_any_realisation_and_matlab_fit():
    # modal form (not a companion): fit_initial needs no observable first state
    A = np.array([[-0.5, 3.0], [-3.0, -0.5]])
    b, c, d = np.array([0.0, 1.0]), np.array([1.0, 0.0]), 0.0
    rng = np.random.default_rng(4)
    u = rng.standard_normal(400)
    y = oracle(A, b, c, d, u, 0.02, [0.4, -0.1]) - 1.5
    p = fit_initial(A, b, c, d, y, u, 0.02)
    np.testing.assert_allclose(p.x0, [0.4, -0.1], atol=1e-9)
    assert p.y_offset == pytest.approx(-1.5, abs=1e-9)
    # MATLAB's compare fit against its closed form, for a model with the wrong gain
    q = fit_initial(A, b, 2 * c, d, y, u, 0.02)
    expected = 100 * (1 - np.linalg.norm(y - q.y_hat) / np.linalg.norm(y - y.mean()))
    assert q.fit == pytest.approx(expected, rel=1e-12)
    assert 0 < q.fit < 99


def test_constant_record_has_no_fit():
    A, b = ccf([1.0, 1.0])
    p = project(A, b, np.full(50, 2.0), np.zeros(50), 0.1)
    assert np.isnan(p.fit)


def test_an_overflowed_response_gives_nan_not_a_lapack_error(capfd):
    """A trial model of an optimiser can overflow; its fit is NaN, quietly (LAPACK printed
    'DLASCL parameter number 4 had an illegal value' for the non-finite regressors)."""
    A, b = ccf([1.0, -2000.0])                  # a pole at +2000: overflows within the record
    u = np.ones(400)
    with np.errstate(all="ignore"):
        p = project(A, b, np.sin(np.arange(400.0)), u, 1.0)
    assert np.isnan(p.fit) and np.isnan(p.c).all()
    assert "DLASCL" not in capfd.readouterr().err


def test_outputs_and_basis_of_a_batch_are_each_systems_own():
    # a batch of systems on one input (the joint fit's Jacobian points) against each system
    # alone, and python-control's first-order-hold response as the independent oracle
    import control

    from aeid_struct.simulation import free_basis, outputs_and_basis

    rng = np.random.default_rng(4)
    n, P, steps, dt = 3, 5, 80, 0.05
    A = rng.normal(size=(P, n, n)) - 2 * np.eye(n)
    b, C, d = rng.normal(size=(P, n)), rng.normal(size=(P, 2, n)), rng.normal(size=(P, 2))
    u = rng.normal(size=steps)
    Y, O = outputs_and_basis(A, b, C, d, u, dt)
    assert Y.shape == (P, 2, steps) and O.shape == (P, steps, 2, n)
    t = dt * np.arange(steps)
    for p in range(P):
        own_Y, own_O = outputs_and_basis(A[p], b[p], C[p], d[p], u, dt)
        np.testing.assert_allclose(Y[p], own_Y, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(O[p], own_O, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(own_Y, simulate_outputs(A[p], b[p], C[p], d[p], u, dt))
        sys = control.ss(A[p], b[p][:, None], C[p], d[p][:, None])
        np.testing.assert_allclose(Y[p], control.forced_response(sys, t, u).outputs,
                                   rtol=1e-9, atol=1e-11)
        Phi = scipy.linalg.expm(A[p] * dt)
        np.testing.assert_allclose(free_basis(Phi, C[p], 4)[3], C[p] @ np.linalg.matrix_power(
            Phi, 3), rtol=1e-12)
