"""The one Levenberg-Marquardt (aeid_struct/refinement/core.py) against scipy's least squares,
row by row against the batch, lazy against eager, and its rules."""

import numpy as np
import pytest
import scipy.optimize

from aeid_struct.refinement import core


class Exponentials:
    """``r_b(x) = x_0 exp(-x_1 t) + x_2 - y_b``: a nonlinear least-squares problem per row,
    with its analytic Jacobian."""

    def __init__(self, y, t, lazy=False):
        self.y, self.t, self.lazy = y, t, lazy
        self.evaluations = 0

    def residual(self, x, y):
        return x[:, :1] * np.exp(-x[:, 1:2] * self.t) + x[:, 2:3] - y

    def jacobian(self, e):
        x = e["x"]
        decay = np.exp(-x[:, 1:2] * self.t)
        return np.stack([decay, -x[:, :1] * self.t * decay, np.ones_like(decay)], axis=1)

    def evaluate(self, x, rows, jacobian, at):
        self.evaluations += 1
        y = self.y if rows is None else self.y[rows]
        r = self.residual(x, y)
        e = {"x": x.copy(), "r": r, "cost": np.mean(r * r, axis=1)}
        if jacobian:
            e["J"] = self.jacobian(e)
        return e


def _records(rows=4, seed=0):
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 4.0, 60)
    truth = np.column_stack([rng.uniform(1, 3, rows), rng.uniform(0.5, 2, rows),
                             rng.uniform(-1, 1, rows)])
    y = truth[:, :1] * np.exp(-truth[:, 1:2] * t) + truth[:, 2:3]
    y = y + 0.01 * rng.standard_normal(y.shape)
    return t, y, truth


def _scipy_optimum(y, t, x0):
    """scipy's Levenberg-Marquardt on one row's residual, to its tightest tolerances."""
    return scipy.optimize.least_squares(
        lambda x: Exponentials(y[None], t).residual(x[None], y[None])[0], x0, method="lm",
        xtol=1e-15, ftol=1e-15, gtol=1e-15)


RULES = core.Rules(max_iter=100, lambda_max=1e10, cost_tol=1e-14, predicted_tol=1e-14,
                   step_tol=1e-12)


def test_reaches_scipys_least_squares_optimum():
    t, y, truth = _records()
    x0 = truth * 1.3 + 0.1
    out = core.minimise(Exponentials(y, t), x0, RULES)
    assert out.converged.all()
    for b in range(y.shape[0]):
        ref = _scipy_optimum(y[b], t, x0[b])
        np.testing.assert_allclose(out.x[b], ref.x, rtol=1e-7)
        np.testing.assert_allclose(out.evaluation["cost"][b], 2 * ref.cost / t.size, rtol=1e-10)


def test_rows_are_independent_of_the_batch():
    t, y, truth = _records(rows=5, seed=1)
    x0 = truth * np.array([1.5, 0.6, 1.0]) + 0.2
    together = core.minimise(Exponentials(y, t), x0, RULES)
    for b in range(y.shape[0]):
        alone = core.minimise(Exponentials(y[b:b + 1], t), x0[b:b + 1], RULES)
        np.testing.assert_allclose(together.x[b], alone.x[0], rtol=1e-12)
        assert together.iterations[b] == alone.iterations[0]
        assert together.accepted[b] == alone.accepted[0]


def test_rows_are_independent_of_the_batch_in_a_box():
    """The stacked step (several rows) and the one-row step agree where bounds are active."""
    t, y, truth = _records(rows=4, seed=8)
    upper = np.column_stack([np.full(4, np.inf), truth[:, 1] * 0.7, np.full(4, np.inf)])
    lower = np.full((4, 3), -np.inf)
    x0 = np.minimum(truth * 0.5, upper * 0.99)
    together = core.minimise(Exponentials(y, t), x0, RULES, lower=lower, upper=upper)
    assert np.all(together.x[:, 1] <= upper[:, 1])
    for b in range(y.shape[0]):
        alone = core.minimise(Exponentials(y[b:b + 1], t), x0[b:b + 1], RULES,
                              lower=lower[b:b + 1], upper=upper[b:b + 1])
        np.testing.assert_allclose(together.x[b], alone.x[0], rtol=1e-10)
        assert together.accepted[b] == alone.accepted[0]


def test_lazy_jacobian_takes_the_same_steps():
    t, y, truth = _records(rows=3, seed=2)
    x0 = truth * 1.2
    eager = core.minimise(Exponentials(y, t), x0, RULES)
    lazy = core.minimise(Exponentials(y, t, lazy=True), x0, RULES)
    np.testing.assert_allclose(lazy.x, eager.x, rtol=1e-13)
    np.testing.assert_array_equal(lazy.accepted, eager.accepted)


def test_box_is_kept_and_matches_scipy_trf():
    t, y, truth = _records(rows=1, seed=3)
    upper = np.array([[np.inf, truth[0, 1] * 0.7, np.inf]])   # the rate bound is active
    lower = np.full((1, 3), -np.inf)
    x0 = np.minimum(truth * 0.5, upper * 0.99)
    out = core.minimise(Exponentials(y, t), x0, RULES, lower=lower, upper=upper)
    assert out.x[0, 1] <= upper[0, 1]
    ref = scipy.optimize.least_squares(
        lambda x: Exponentials(y, t).residual(x[None], y)[0], x0[0],
        bounds=(lower[0], upper[0]), method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    np.testing.assert_allclose(out.x[0], ref.x, rtol=1e-6)


def test_scaled_steps_reach_the_same_point():
    t, y, truth = _records(rows=2, seed=4)
    x0 = truth * 1.2
    plain = core.minimise(Exponentials(y, t), x0, RULES)
    scaled = core.minimise(Exponentials(y, t), x0, RULES, scale=np.abs(x0) + 1e-3)
    np.testing.assert_allclose(scaled.x, plain.x, rtol=1e-7)


def test_without_stopping_rules_every_row_takes_every_iteration():
    t, y, truth = _records(rows=3, seed=5)
    out = core.minimise(Exponentials(y, t), truth * 1.1, core.Rules(max_iter=7))
    np.testing.assert_array_equal(out.iterations, 7)
    assert not out.converged.any()
    start = Exponentials(y, t).evaluate(truth * 1.1, None, False, None)["cost"]
    assert np.all(out.evaluation["cost"] <= start)


def test_a_start_that_is_not_finite_stays_and_is_not_converged():
    t, y, truth = _records(rows=2, seed=6)
    x0 = truth.copy()
    x0[1, 1] = -1e6                                   # exp overflows: cost inf
    with np.errstate(over="ignore", invalid="ignore"):
        out = core.minimise(Exponentials(y, t), x0, RULES)
    assert out.iterations[1] == 0 and not out.converged[1]
    np.testing.assert_array_equal(out.x[1], x0[1])
    assert out.converged[0]


def test_gradient_rule_stops_at_the_optimum_before_any_trial():
    t, y, truth = _records(rows=1, seed=7)
    best = core.minimise(Exponentials(y, t), truth, RULES).x
    problem = Exponentials(y, t)
    out = core.minimise(problem, best, core.Rules(max_iter=10, gradient_tol=1e-6))
    assert out.converged[0] and out.iterations[0] == 1 and problem.evaluations == 1


@pytest.mark.parametrize("field, value", [("max_iter", -1), ("max_iter", 2.0),
                                          ("lambda0", 0.0), ("factor", 1.0),
                                          ("cost_tol", -1e-3), ("step_tol", "small")])
def test_rules_refuse_bad_values_by_name(field, value):
    with pytest.raises(ValueError, match=field):
        core.Rules(**{"max_iter": 5, field: value})


def test_the_gain_ratio_reaches_scipys_optimum_at_large_residuals():
    # noise half the signal: the Gauss-Newton model misses the residual's own curvature; the
    # gain-ratio damping (Rules.gain) still ends at scipy's optimum, and a row's path does not
    # depend on the batch it is in
    t, y, truth = _records(rows=4, seed=3)
    y = y + 0.5 * np.random.default_rng(4).standard_normal(y.shape)
    x0 = truth * 1.3 + 0.1
    rules = core.Rules(max_iter=200, lambda_max=1e10, cost_tol=1e-14, step_tol=1e-12,
                       gain=True)
    out = core.minimise(Exponentials(y, t), x0, rules)
    assert out.converged.all()
    for b in range(y.shape[0]):
        ref = _scipy_optimum(y[b], t, x0[b])
        np.testing.assert_allclose(out.x[b], ref.x, rtol=1e-6, atol=1e-7)
        alone = core.minimise(Exponentials(y[b:b + 1], t), x0[b:b + 1], rules)
        np.testing.assert_allclose(alone.x[0], out.x[b], rtol=1e-12)
        assert alone.iterations[0] == out.iterations[b]
