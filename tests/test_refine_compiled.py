"""refinement.compiled: the separable Levenberg-Marquardt compiled to C, against the numpy path
(the same iterations with a forward-difference Jacobian) and scipy's ``least_squares`` on the
full, unprojected output error (an independent optimiser of the same model), on records made by
``aeid_struct.simulate``; and the fallback to numpy where nothing is compiled."""

import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest
import scipy.optimize

from aeid_struct import simulate
from aeid_struct.refinement import Pattern, compiled
from aeid_struct.refinement.levenberg import gauss_newton

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None,
                                reason="no C compiler: the numpy path serves alone")

STABLE = Pattern(a=(None, None), c=(None, 0.0), d=0.0)
WINDOW = Pattern(a=(None, None), c=(None, 0.0), d=0.0, initial=True)
UNSTABLE = Pattern(a=(None, 0.0), c=(None, 0.0), d=0.0)
#: The robot leg's records: (pattern, samples, dt), as the leg identifiers read them.
LEGS = {"stable": (STABLE, 300, 0.01), "window": (WINDOW, 300, 0.01),
        "unstable": (UNSTABLE, 100, 0.005)}


def system(pattern, a0, a1, c0):
    A = np.array([[0.0, 1.0], [-a0, -a1]])
    return A, np.array([0.0, 1.0]), np.array([c0, 0.0])


def records(name, count=3, noise=0.01, seed=0):
    """``count`` noisy leg records under a binary input, the true ``(a0, a1, c0, x0)`` and the
    encoder-like start (the true free ``a_j`` 3 % off)."""
    pattern, N, dt = LEGS[name]
    rng = np.random.default_rng(seed)
    ys, us, truth = [], [], []
    for _ in range(count):
        k, d, m = rng.uniform(15, 35), rng.uniform(1, 4), rng.uniform(0.7, 1.5)
        a0, a1 = (k / m, d / m) if name != "unstable" else (-rng.uniform(5, 30), 0.0)
        x0 = rng.normal(size=2) if pattern.initial else np.zeros(2)
        u = np.repeat(rng.choice([-1.0, 1.0], N // 10), 10)
        y = simulate(*system(pattern, a0, a1, 1 / m), 0.0, u, dt, x0=x0)
        ys.append(y + noise * np.std(y) * rng.standard_normal(N))
        us.append(u)
        truth.append((a0, a1, 1 / m, x0))
    a = np.array([[t[0], t[1]] for t in truth])[:, pattern.free_a]
    start = a * rng.uniform(0.97, 1.03, a.shape)
    return np.array(ys), np.array(us), dt, truth, start


def numpy_path(monkeypatch, *args, **kwargs):
    with monkeypatch.context() as m:
        m.setattr(compiled, "ENABLED", False)
        return gauss_newton(*args, **kwargs)


@pytest.mark.parametrize("name", LEGS)
@pytest.mark.parametrize("iterations, tol", [(2, None), (50, 1e-12)])
def test_compiled_equals_the_numpy_path_on_the_leg_records(name, iterations, tol, monkeypatch):
    pattern, N, _ = LEGS[name]
    y, u, dt, _, start = records(name)
    assert compiled.solver(pattern, N) is not None, "a C compiler is present: it must build"
    # a start in Fortran order, as column selections give it: each record's row is strided
    fast = gauss_newton(pattern, np.asfortranarray(start), y, u, dt, iterations=iterations,
                        tol=tol)
    ref = numpy_path(monkeypatch, pattern, start, y, u, dt, iterations=iterations, tol=tol)
    # numpy's forward-difference Jacobian moves each step in its ~8th digit
    for field in ("a", "c", "x0"):
        np.testing.assert_allclose(getattr(fast, field), getattr(ref, field), rtol=1e-7,
                                   atol=1e-9, err_msg=field)
    np.testing.assert_allclose(fast.cost, ref.cost, rtol=1e-9)
    np.testing.assert_array_equal(fast.d, 0.0)
    if tol is None:
        np.testing.assert_array_equal(fast.iterations, ref.iterations)
        assert not fast.converged.any()
    else:
        assert fast.converged.all() and (fast.iterations >= 2).all()


def oracle(name, y, u, dt, truth):
    """scipy ``least_squares`` on the output error in all parameters, ``(a0[, a1], c0[, x0])``,
    from the truth."""
    pattern = LEGS[name][0]
    free = pattern.free_a

    def residual(p):
        a = np.array([truth[0], truth[1]])
        a[free] = p[: free.size]
        x0 = p[free.size + 1:] if pattern.initial else None
        return simulate(*system(pattern, a[0], a[1], p[free.size]), 0.0, u, dt, x0=x0) - y

    p0 = np.r_[np.array(truth[:2])[free], truth[2], truth[3] if pattern.initial else []]
    fit = scipy.optimize.least_squares(residual, p0, method="lm", jac="3-point", xtol=1e-15,
                                       ftol=1e-15, gtol=1e-15, x_scale="jac")
    return fit.x, np.mean(fit.fun ** 2)


@pytest.mark.parametrize("name", LEGS)
def test_the_converged_fit_is_the_least_squares_optimum(name):
    pattern, _, _ = LEGS[name]
    y, u, dt, truth, start = records(name, count=2, seed=1)
    fit = gauss_newton(pattern, start, y, u, dt, iterations=50, tol=1e-12)
    assert fit.converged.all()
    for i in range(2):
        p, cost = oracle(name, y[i], u[i], dt, truth[i])
        nf = pattern.free_a.size
        np.testing.assert_allclose(fit.a[i, pattern.free_a], p[:nf], rtol=1e-7)
        np.testing.assert_allclose(fit.c[i, 0], p[nf], rtol=1e-7)
        if pattern.initial:
            np.testing.assert_allclose(fit.x0[i], p[nf + 1:], rtol=1e-6, atol=1e-8)
        assert fit.cost[i] <= cost * (1 + 1e-9)


def test_a_noise_free_record_is_fitted_exactly_from_a_two_iteration_pass():
    y, u, dt, truth, start = records("window", count=1, noise=0.0, seed=2)
    fit = gauss_newton(WINDOW, start, y, u, dt, iterations=50, tol=1e-12)
    a0, a1, c0, x0 = truth[0]
    np.testing.assert_allclose(fit.a[0], [a0, a1], rtol=1e-9)
    np.testing.assert_allclose(fit.c[0], [c0, 0.0], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(fit.x0[0], x0, rtol=1e-7, atol=1e-9)
    assert fit.cost[0] < 1e-20 * np.mean(y ** 2)


def test_feedthrough_offset_and_order_one_and_the_build_folder_is_removed(monkeypatch):
    """A pattern with ``d`` and an offset free (order 1: ``a0``, ``c0``, ``d``, offset), built
    in a private folder that is gone after loading."""
    pattern = Pattern(a=(None,), c=(None,), d=None, offset=True)
    rng = np.random.default_rng(3)
    N, dt = 80, 0.05
    u = rng.standard_normal(N)
    y = simulate(np.array([[-2.0]]), np.array([1.0]), np.array([1.5]), 0.4, u, dt) + 0.7
    folders = []
    mkdtemp = tempfile.mkdtemp
    monkeypatch.setattr(tempfile, "mkdtemp", lambda **kw: folders.append(mkdtemp(**kw)) or
                        folders[-1])
    fit = gauss_newton(pattern, [[2.2]], y[None], u[None], dt, iterations=50, tol=1e-12)
    assert len(folders) == 1 and not Path(folders[0]).exists()
    np.testing.assert_allclose(fit.a, [[2.0]], rtol=1e-9)
    np.testing.assert_allclose(fit.c, [[1.5]], rtol=1e-9)
    np.testing.assert_allclose(fit.d, [0.4], rtol=1e-9)
    np.testing.assert_allclose(fit.y_offset, [0.7], rtol=1e-9)


def test_disabled_or_failed_compilation_leaves_the_numpy_path(monkeypatch):
    y, u, dt, _, start = records("unstable", count=2)
    args = (UNSTABLE, start, y, u, dt)
    ref = numpy_path(monkeypatch, *args, iterations=3)

    def never(rows):
        raise AssertionError("no fallback rows expected")

    with monkeypatch.context() as m:
        m.setenv(compiled.ENV, "0")
        assert compiled.gauss_newton_rows(*args, 3, None, never) is None
        np.testing.assert_array_equal(gauss_newton(*args, iterations=3).a, ref.a)
    with monkeypatch.context() as m:
        m.setattr(compiled, "_CACHE", {})
        m.setattr(compiled, "_compile", lambda f: (_ for _ in ()).throw(RuntimeError("cc")))
        assert compiled.solver(UNSTABLE, y.shape[1]) is None
        np.testing.assert_array_equal(gauss_newton(*args, iterations=3).a, ref.a)
    fast = gauss_newton(*args, iterations=3)
    assert not np.array_equal(fast.a, ref.a)          # the compiled path did run here
    np.testing.assert_allclose(fast.a, ref.a, rtol=1e-7)


def test_a_record_the_graph_does_not_cover_is_fitted_by_numpy(monkeypatch):
    """A start so far out that the graph's squarings do not reach it: that record alone takes
    the numpy path, the others stay compiled."""
    y, u, dt, _, start = records("stable", count=2)
    start[1] = [1e12, 1e3]
    fit = gauss_newton(STABLE, start, y, u, dt, iterations=2)
    alone = numpy_path(monkeypatch, STABLE, start[1:], y[1:], u[1:], dt, iterations=2)
    first = numpy_path(monkeypatch, STABLE, start[:1], y[:1], u[:1], dt, iterations=2)
    for field in ("a", "c", "cost", "iterations"):
        np.testing.assert_array_equal(getattr(fit, field)[1:], getattr(alone, field))
    assert not np.array_equal(fit.a[0], first.a[0])
    np.testing.assert_allclose(fit.a[0], first.a[0], rtol=1e-7)
