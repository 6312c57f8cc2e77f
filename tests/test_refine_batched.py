"""refinement.batched: the separable Gauss-Newton of partly fixed CCFs, against scipy's expm,
exact simulations (ae.simulate), linear least squares, scipy.optimize.least_squares and finite
differences of its own cost (an independent derivative)."""

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

import aeid_struct as ae
from aeid_struct.refinement import Pattern
from aeid_struct.refinement.batched import _spectrum, evaluate
from aeid_struct.refinement.levenberg import gauss_newton
from aeid_struct.refinement.powers import expm_batch
from aeid_struct.training import LegFamily, records

STABLE = Pattern(a=(None, None), c=(None, 0.0), d=0.0)
UNSTABLE = Pattern(a=(None, 0.0), c=(None, 0.0), d=0.0)
WINDOW = Pattern(a=(None, None), c=(None, 0.0), d=0.0, initial=True)


def windows(count, noise=0.0, seed=0):
    return records(LegFamily(subsystem="stable"), count, steps=300, dt=0.01,
                   excitation_kind="prbs", noise=noise, seed=seed, warmup=200)


def _ccf(a, c):
    a, c = np.atleast_2d(a), np.atleast_2d(c)
    B, n = a.shape
    A = np.zeros((B, n, n))
    A[:, np.arange(n - 1), np.arange(1, n)] = 1.0
    A[:, -1] = -a
    b = np.zeros((B, n))
    b[:, -1] = 1.0
    return A, b, c


def _legs(count, seed, N=300, dt=0.01, x0=False):
    """Translational legs (k, d, m in the paper's ranges) under a binary input."""
    rng = np.random.default_rng(seed)
    k, d, m = rng.uniform(19, 27, count), rng.uniform(1.5, 5.5, count), rng.uniform(.5, 1.5, count)
    a = np.stack([k / m, d / m], 1)
    c = np.stack([1 / m, 0 * m], 1)
    u = np.repeat(np.sign(rng.standard_normal((count, N // 10))), 10, axis=1)
    A, b, c = _ccf(a, c)
    start = rng.standard_normal((count, 2)) if x0 else None
    y = np.asarray(ae.simulate(A, b, c, np.zeros(count), u, dt, x0=start))
    return a, c, u, y, start


def test_expm_batch_matches_scipy_over_decades_of_norm():
    rng = np.random.default_rng(0)
    E = rng.standard_normal((300, 4, 4)) * np.exp(rng.uniform(-18, 3.5, (300, 1, 1)))
    ref = np.stack([scipy.linalg.expm(e) for e in E])
    err = np.abs(expm_batch(E) - ref).max(axis=(1, 2)) / np.abs(ref).max(axis=(1, 2))
    assert err.max() < 1e-11


def test_projection_at_the_true_poles_fits_a_noise_free_record_exactly():
    a, c, u, y, _ = _legs(5, 1)
    e = evaluate(STABLE, a, y, u, 0.01)
    assert np.all(e["cost"] < 1e-24 * np.mean(y ** 2, axis=1))
    np.testing.assert_allclose(e["z"][:, 0], c[:, 0], rtol=1e-9)


def test_iterations_zero_is_the_linear_least_squares_oracle():
    a, c, u, y, _ = _legs(3, 2)
    rng = np.random.default_rng(2)
    y = y + 0.02 * np.abs(y).max() * rng.standard_normal(y.shape)
    start = a * 1.1
    fit = gauss_newton(STABLE, start, y, u, 0.01, iterations=0)
    for i in range(3):
        A, b, _ = _ccf(start[i], [1.0, 0.0])
        x1 = np.asarray(ae.simulate(A, b, np.array([[1.0, 0.0]]), np.zeros(1), u[i:i + 1],
                                    0.01))[0]
        c0 = np.linalg.lstsq(x1[:, None], y[i], rcond=None)[0][0]
        assert fit.c[i, 0] == pytest.approx(c0, rel=1e-9)
        np.testing.assert_array_equal(fit.a[i], start[i])


@pytest.mark.parametrize("x0", [False, True])
def test_noise_free_records_are_recovered_exactly_from_ten_percent_off(x0):
    a, c, u, y, start = _legs(16, 3, x0=x0)
    pattern = Pattern(a=(None, None), c=(None, 0.0), d=0.0, initial=x0)
    rng = np.random.default_rng(3)
    fit = gauss_newton(pattern, a * (1 + 0.1 * rng.standard_normal(a.shape)), y, u, 0.01,
                       iterations=50, tol=1e-14)
    np.testing.assert_allclose(fit.a, a, rtol=1e-7)
    np.testing.assert_allclose(fit.c[:, 0], c[:, 0], rtol=1e-7)
    assert np.all(fit.c[:, 1] == 0.0)
    if x0:
        np.testing.assert_allclose(fit.x0, start, rtol=1e-6, atol=1e-8)
    else:
        assert np.all(fit.x0 == 0.0)


def test_converged_fit_is_the_least_squares_optimum_of_scipy():
    a, c, u, y, _ = _legs(4, 4)
    rng = np.random.default_rng(4)
    y = y + 0.03 * np.abs(y).max(axis=1, keepdims=True) * rng.standard_normal(y.shape)
    fit = gauss_newton(STABLE, a * 1.08, y, u, 0.01, iterations=50, tol=1e-13)
    assert fit.converged.all()
    for i in range(4):
        def residual(p, i=i):
            A, b, cc = _ccf(p[:2], [p[2], 0.0])
            return np.asarray(ae.simulate(A, b, cc, np.zeros(1), u[i:i + 1], 0.01))[0] - y[i]
        ref = scipy.optimize.least_squares(residual, [*(a[i] * 0.95), c[i, 0] * 1.05],
                                           xtol=1e-15, ftol=1e-15, gtol=1e-15)
        np.testing.assert_allclose(fit.a[i], ref.x[:2], rtol=1e-6)
        assert fit.c[i, 0] == pytest.approx(ref.x[2], rel=1e-6)
        assert fit.cost[i] == pytest.approx(np.mean(ref.fun ** 2), rel=1e-8)


def test_unstable_leg_with_fixed_damping_term():
    # rotational leg: G2 = c0 / (s^2 + a0), a0 < 0; a1 = c1 = 0 held
    rng = np.random.default_rng(5)
    a0 = -rng.uniform(8, 20, 6)
    c0 = rng.uniform(1, 5, 6)
    a = np.stack([a0, 0 * a0], 1)
    A, b, c = _ccf(a, np.stack([c0, 0 * c0], 1))
    u = np.repeat(np.sign(rng.standard_normal((6, 10))), 10, axis=1)
    y = np.asarray(ae.simulate(A, b, c, np.zeros(6), u, 0.005))
    fit = gauss_newton(UNSTABLE, a0[:, None] * 1.1, y, u, 0.005, iterations=30, tol=1e-14)
    np.testing.assert_allclose(fit.a[:, 0], a0, rtol=1e-7)
    assert np.all(fit.a[:, 1] == 0.0)
    np.testing.assert_allclose(fit.c[:, 0], c0, rtol=1e-7)


def test_fixed_nonzero_numerator_feedthrough_and_offset():
    rng = np.random.default_rng(6)
    a = np.array([[4.0, 1.5], [9.0, 0.8]])
    c = np.array([[2.0, 0.5], [-1.0, 0.5]])
    d = np.array([0.3, -0.2])
    A, b, cc = _ccf(a, c)
    u = rng.standard_normal((2, 400)).cumsum(axis=1) * 0.1
    y = np.asarray(ae.simulate(A, b, cc, d, u, 0.02)) + np.array([[1.5], [-0.7]])
    pattern = Pattern(a=(None, None), c=(None, 0.5), d=None, offset=True)
    fit = gauss_newton(pattern, a * 0.9, y, u, 0.02, iterations=40, tol=1e-14)
    np.testing.assert_allclose(fit.a, a, rtol=1e-7)
    np.testing.assert_allclose(fit.c, c, rtol=1e-7)
    np.testing.assert_allclose(fit.d, d, rtol=1e-6)
    np.testing.assert_allclose(fit.y_offset, [1.5, -0.7], rtol=1e-7)


def test_fixed_iterations_never_raise_the_cost_and_a_bad_row_spares_the_others():
    a, c, u, y, _ = _legs(6, 7)
    rng = np.random.default_rng(7)
    y = y + 0.05 * np.abs(y).max() * rng.standard_normal(y.shape)
    start = a * (1 + 0.3 * rng.standard_normal(a.shape))
    before = evaluate(STABLE, start, y, u, 0.01)["cost"]
    fit = gauss_newton(STABLE, start, y, u, 0.01, iterations=2)
    assert np.all(fit.cost <= before)
    bad = start.copy()
    bad[2] = [-1e7, -1e7]               # e^{A dt} overflows: no response
    both = gauss_newton(STABLE, bad, y, u, 0.01, iterations=2)
    assert not np.isfinite(both.cost[2])
    keep = [0, 1, 3, 4, 5]
    np.testing.assert_allclose(both.a[keep], fit.a[keep], rtol=1e-12)
    np.testing.assert_allclose(both.c[keep], fit.c[keep], rtol=1e-12)


def test_pattern_and_start_are_checked():
    with pytest.raises(ValueError, match="at least one a_j must be free"):
        Pattern(a=(1.0, 2.0), c=(None, 0.0))
    with pytest.raises(ValueError, match="same length"):
        Pattern(a=(None, None), c=(None,))
    with pytest.raises(ValueError, match="every entry of c"):
        Pattern(a=(None, None), c=(None, float("nan")))
    a, c, u, y, _ = _legs(2, 8)
    with pytest.raises(ValueError, match="alpha0 must have 2 free a_j"):
        gauss_newton(STABLE, a[:, :1], y, u, 0.01, iterations=1)
    for kwargs, match in ((dict(y=y[0]), "y and u must be"), (dict(u=u[:, :-1]), "y and u must be"),
                          (dict(dt=0.0), "dt must be a positive"),
                          (dict(dt=float("nan")), "dt must be a positive"),
                          (dict(iterations=-1), "iterations must be an integer"),
                          (dict(iterations=2.0), "iterations must be an integer"),
                          (dict(tol=1.0), "tol must be None"),
                          (dict(pattern="ccf"), "pattern must be a refinement.Pattern")):
        call = dict(pattern=STABLE, alpha0=a, y=y, u=u, dt=0.01, iterations=1) | kwargs
        with pytest.raises(ValueError, match=match):
            gauss_newton(call.pop("pattern"), call.pop("alpha0"), call.pop("y"), call.pop("u"),
                         call.pop("dt"), **call)
    bad = y.copy()
    bad[0, 3] = np.inf
    with pytest.raises(ValueError, match="y and u must be finite"):
        gauss_newton(STABLE, a, bad, u, 0.01, iterations=1)


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


def test_the_fit_record_stays_in_refinement():
    # the head reads arrays (fit_rows); the fit's own record is no public result type
    import aeid_struct.refinement as refinement

    assert "SeparableFit" not in refinement.__all__ and "gauss_newton" not in refinement.__all__
    with pytest.warns(DeprecationWarning, match="fit_rows"):
        old = refinement.gauss_newton
    assert old is gauss_newton
    a, _, u, y, _ = _legs(5, 4)
    start = a * 1.05
    fa, fc, fd, ok = refinement.fit_rows(STABLE, start, y, u, 0.01, iterations=3)
    fit = gauss_newton(STABLE, start, y, u, 0.01, iterations=3)
    assert ok.all()
    np.testing.assert_array_equal(fa, fit.a)
    np.testing.assert_array_equal(fc, fit.c)
    np.testing.assert_array_equal(fd, fit.d)
