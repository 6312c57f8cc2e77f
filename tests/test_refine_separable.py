"""refinement.separable: the variable-projection refinement of free CCFs, against a scipy
``expm`` FOH recursion (the oracle of the records), ``simulation.project`` (the exact linear part)
and the CasADi ``refine_record`` (an independent optimiser of the same model)."""

import numpy as np
import pytest
import scipy.linalg

from aeid_struct.refinement import projected_cost, refine_record, refine_separable
from aeid_struct.simulation import project
from aeid_struct.structures import CCF


def ccf(den):
    n = len(den) - 1
    A = np.zeros((n, n))
    A[np.arange(n - 1), np.arange(1, n)] = 1.0
    A[-1] = -np.asarray(den, float)[:0:-1]
    return A, np.eye(n)[-1]


def simulate(den, num, d, u, x0, delay, offset):
    """Normalised-time FOH recursion (scipy expm), CCF of ``den`` with ``c = num``, feedthrough
    ``d``; the input delayed by ``delay`` samples, ``x0`` the state at sample ``delay``."""
    A, b = ccf(den)
    n = A.shape[0]
    M = np.zeros((n + 2, n + 2))
    M[:n, :n], M[:n, n], M[n, n + 1] = A, b, 1.0
    E = scipy.linalg.expm(M)
    Phi, g1, g2 = E[:n, :n], E[:n, n], E[:n, n + 1]
    uu = u[: len(u) - delay]
    x, out = np.array(x0, float), np.empty(len(uu))
    for k in range(len(uu)):
        out[k] = num @ x + d * uu[k]
        if k + 1 < len(uu):
            x = Phi @ x + g1 * uu[k] + g2 * (uu[k + 1] - uu[k])
    head = np.random.default_rng(7).standard_normal(delay)
    return np.concatenate([head, out + offset])


# (poles per sample, c, d): orders 1-4, real poles, pairs, zeros, one with a feedthrough
SYSTEMS = {
    1: ([-0.05], [0.03], 0.0),
    2: ([-0.02 + 0.1j, -0.02 - 0.1j], [0.01, 0.002], 0.3),
    3: ([-0.02, -0.015 + 0.08j, -0.015 - 0.08j], [4e-5, -6e-4, 0.02], 0.0),
    4: ([-0.03, -0.01 + 0.08j, -0.01 - 0.08j, -0.2], [1e-4, 2e-4, 1e-3, 1e-3], 0.0),
}


def record(n, steps=1000, delay=2, offset=0.7, noise=0.0, seed=1):
    poles, num, d = SYSTEMS[n]
    den = np.real(np.poly(poles))
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1, 1, steps // 25 + 1), 25)[:steps] + 0.3
    x0 = np.linspace(0.5, -1.0, n) * 10.0 ** -np.arange(n)
    y = simulate(den, np.array(num), d, u, x0, delay, offset)
    y += noise * np.std(y) * np.random.default_rng(seed + 100).standard_normal(steps)
    return den, y, u


def perturbed(n, seed=3, size=0.1):
    poles = np.array(SYSTEMS[n][0])
    e = 1 + size * np.random.default_rng(seed).standard_normal((2, n))
    q = poles.real * e[0] + 1j * poles.imag * e[1]
    for j in np.flatnonzero(poles.imag < 0):              # pairs stay conjugate
        q[j] = np.conj(q[np.argmin(np.abs(poles - np.conj(poles[j])))])
    return np.real(np.poly(q))


def transfer(A, b, c, d, s):
    n = A.shape[0]
    return np.array([c @ np.linalg.solve(x * np.eye(n) - A, b) + d for x in s])


S = 1j * np.array([0.003, 0.03, 0.1, 0.3, 1.0])


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_noise_free_from_a_perturbed_start_is_the_true_system(n):
    den, y, u = record(n)
    fit = refine_separable(perturbed(n), y, u, delay=2, feedthrough=True)
    poles, num, d = SYSTEMS[n]
    truth = transfer(*ccf(den), np.array(num), d, S)
    assert fit.info["converged"] and fit.delay == 2
    np.testing.assert_allclose(transfer(fit.A, fit.b, fit.c, fit.d, S), truth, rtol=1e-6)
    assert fit.offset == pytest.approx(0.7, abs=1e-6) and fit.fit > 99.999
    # x0 reproduces the record: the CCF state at sample 2 of the truth
    again = simulate(np.concatenate([[1.0], -fit.A[-1, ::-1]]), fit.c, fit.d, u, fit.x0, 2,
                     fit.offset)
    np.testing.assert_allclose(again[2:], y[2:], atol=1e-6 * np.ptp(y))


def test_without_feedthrough_and_in_physical_time():
    den, y, u = record(3)
    dt = 0.01
    start = perturbed(3) / dt ** np.arange(4)             # the start in the time unit of dt
    fit = refine_separable(start, y, u, dt, delay=2, feedthrough=False)
    assert "d" not in fit.elements and fit.d == 0.0
    # physical poles are the normalised ones / dt; G(s) at s/dt is the normalised G
    truth = transfer(*ccf(den), np.array(SYSTEMS[3][1]), 0.0, S)
    np.testing.assert_allclose(transfer(fit.A, fit.b, fit.c, fit.d, S / dt), truth, rtol=1e-6)
    np.testing.assert_allclose([fit.elements[f"a{i}"] for i in range(3)],
                               (den / dt ** np.arange(4))[:0:-1], rtol=1e-6)


@pytest.mark.parametrize("n, feedthrough", [(2, True), (3, False), (4, True)])
def test_cost_is_project_cost(n, feedthrough):
    den, y, u = record(n, noise=0.03)
    start = perturbed(n)
    cost, _ = projected_cost(start, y, u, delay=2, feedthrough=feedthrough)
    want = project(*ccf(start), y, u, 1.0, delay=2, feedthrough=feedthrough).cost
    assert cost == pytest.approx(want, rel=1e-9)


@pytest.mark.parametrize("n, feedthrough, offset", [(1, True, True), (2, False, True),
                                                    (3, True, False), (4, False, True)])
def test_gradient_is_the_finite_difference_of_the_cost(n, feedthrough, offset):
    den, y, u = record(n, noise=0.03)
    start = perturbed(n)
    _, grad = projected_cost(start, y, u, delay=2, feedthrough=feedthrough, offset=offset)
    fd = np.empty(n)
    for j in range(n):
        h = 1e-6 * abs(start[n - j])
        step = np.zeros(n + 1)
        step[n - j] = h
        plus = projected_cost(start + step, y, u, delay=2, feedthrough=feedthrough,
                              offset=offset)[0]
        minus = projected_cost(start - step, y, u, delay=2, feedthrough=feedthrough,
                               offset=offset)[0]
        fd[j] = (plus - minus) / (2 * h)
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-8 * np.abs(fd).max())


@pytest.mark.parametrize("n", [2, 3, 4])
def test_noisy_optimum_is_casadis_optimum(n):
    # two optimisers of the same model from the same start reach the same minimum
    den, y, u = record(n, noise=0.05, seed=5)
    start = perturbed(n, size=0.05)
    fit = refine_separable(start, y, u, delay=2)
    p = project(*ccf(start), y, u, 1.0, delay=2)
    x = np.concatenate([start[:0:-1], p.c, [p.d]])
    ref = refine_record(CCF(n, feedthrough=True), x, y, u, 1.0, delay=2, offset=True)
    assert fit.info["cost"] == pytest.approx(ref.info["cost"], rel=1e-8)
    np.testing.assert_allclose(transfer(fit.A, fit.b, fit.c, fit.d, S),
                               transfer(ref.A, ref.b, ref.c, ref.d, S), rtol=1e-3)


@pytest.mark.parametrize("args, kwargs, match", [
    (([1.0, 0.1], "y"), {}, r"y and u must have the same shape"),
    (([2.0, 0.1],), {}, r"den must be a finite monic denominator"),
    (([1.0, np.nan],), {}, r"den must be a finite monic denominator"),
    (([1.0, 0.1],), {"delay": 996}, r"delay must be an integer in \[0, 995\] .* got 996"),
    (([1.0, 0.1],), {"delay": -1}, r"delay must be an integer in \[0, 995\] .* got -1"),
    (([1.0, 0.1],), {"dt": 0.0}, r"dt must be a positive finite number; got 0.0"),
    (([1.0, 0.1],), {"max_iter": 0}, r"max_iter must be an integer >= 1; got 0"),
])
def test_bad_arguments_name_themselves(args, kwargs, match):
    _, y, u = record(1)
    if len(args) == 2:
        with pytest.raises(ValueError, match=match):
            refine_separable(args[0], y, u[:-1], **kwargs)
        return
    with pytest.raises(ValueError, match=match):
        refine_separable(args[0], y, u, **kwargs)


def test_a_sample_that_is_not_finite_is_refused_by_name():
    den, y, u = record(2)
    u = u.copy()
    u[3] = np.inf
    with pytest.raises(ValueError, match="u must be finite"):
        refine_separable(perturbed(2), y, u, delay=2)
