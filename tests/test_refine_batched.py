"""refinement.batched: the batched separable Gauss-Newton against scipy's ``expm``, the true
systems and initial states of simulated mid-motion records, and finite differences of its own
cost (an independent derivative)."""

import numpy as np
import pytest
import scipy.linalg

from aeid_struct.refinement import Pattern, gauss_newton
from aeid_struct.refinement.batched import _spectrum, evaluate, expm_batch
from aeid_struct.training import LegFamily, records

WINDOW = Pattern(a=(None, None), c=(None, 0.0), d=0.0, initial=True)


def windows(count, noise=0.0, seed=0):
    return records(LegFamily(subsystem="stable"), count, steps=300, dt=0.01,
                   excitation_kind="prbs", noise=noise, seed=seed, warmup=200)


def test_expm_batch_is_scipys_for_every_scale():
    rng = np.random.default_rng(0)
    E = rng.standard_normal((40, 4, 4)) * np.geomspace(1e-3, 30, 40)[:, None, None]
    got = expm_batch(E)
    for e, g in zip(E, got, strict=True):
        ref = scipy.linalg.expm(e)
        assert np.abs(g - ref).max() <= 1e-12 * np.abs(ref).max()


def test_noise_free_windows_converge_to_the_true_leg_and_its_initial_state():
    rec = windows(3)
    truth = -rec.systems.A[:, -1, :]                            # a0, a1
    start = truth * np.array([[1.08, 0.9], [0.93, 1.1], [1.05, 1.06]])
    fit = gauss_newton(WINDOW, start, rec.y, rec.u, 0.01, iterations=30, tol=1e-12)
    assert np.allclose(fit.a, truth, rtol=1e-7)
    assert np.allclose(fit.c, rec.systems.c, rtol=1e-7)
    assert np.allclose(fit.x0, rec.x0, rtol=1e-6, atol=1e-9)
    assert np.all(fit.cost < 1e-20)


def test_one_record_alone_is_its_row_of_a_large_batch():
    # a few records evaluate every Jacobian point in one call, many one call per point
    rec = windows(30, noise=0.01, seed=1)
    start = -rec.systems.A[:, -1, :] * 1.05
    batch = gauss_newton(WINDOW, start, rec.y, rec.u, 0.01, iterations=2)
    for r in (0, 17):
        one = gauss_newton(WINDOW, start[r:r + 1], rec.y[r:r + 1], rec.u[r:r + 1], 0.01,
                           iterations=2)
        assert np.allclose(one.a[0], batch.a[r], rtol=1e-10)
        assert np.allclose(one.c[0], batch.c[r], rtol=1e-10)


@pytest.mark.parametrize("count", [1, 30])
def test_jacobian_gives_the_finite_difference_gradient_of_the_cost(count):
    rec = windows(count, noise=0.02, seed=2)
    alpha = -rec.systems.A[:, -1, :] * 1.03
    U = _spectrum(rec.u)
    e = evaluate(WINDOW, alpha, rec.y, rec.u, 0.01, U, jacobian=True)
    gradient = 2.0 * np.einsum("bjn,bn->bj", e["J"], e["r"]) / rec.y.shape[1]
    for j in range(2):
        h = 1e-5 * alpha[:, j]
        up, down = alpha.copy(), alpha.copy()
        up[:, j] += h
        down[:, j] -= h
        fd = (evaluate(WINDOW, up, rec.y, rec.u, 0.01, U)["cost"]
              - evaluate(WINDOW, down, rec.y, rec.u, 0.01, U)["cost"]) / (2 * h)
        assert np.allclose(gradient[:, j], fd, rtol=1e-4, atol=1e-12)
