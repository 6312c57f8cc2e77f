"""Table I metrics against python-control and closed forms."""

import control
import numpy as np
import pytest

from aeid_struct.metrics import (
    FREQUENCIES,
    bode_errors,
    frequency_response,
    nrmse_fit,
    parameter_errors,
    step_error,
)
from tests.problems import random_system


@pytest.mark.parametrize("n", [1, 2, 4])
def test_frequency_response_matches_python_control(n):
    rng = np.random.default_rng(n)
    A, b, c, d = random_system(n, rng, feedthrough=True)
    sys = control.ss(A, b.reshape(n, 1), c.reshape(1, n), [[d]])
    expected = control.frequency_response(sys, FREQUENCIES)
    G = frequency_response(A, b, c, d)
    np.testing.assert_allclose(np.abs(G), np.squeeze(expected.magnitude), rtol=1e-10)
    np.testing.assert_allclose(np.angle(G), np.angle(np.squeeze(expected.complex)), atol=1e-10)


def test_frequency_response_batch_equals_singles():
    rng = np.random.default_rng(0)
    systems = [random_system(3, rng) for _ in range(4)]
    batch = [np.stack(x) for x in zip(*systems, strict=True)]
    G = frequency_response(*batch)
    for i, s in enumerate(systems):
        np.testing.assert_allclose(G[i], frequency_response(*s), rtol=1e-12)


def test_step_error_closed_form():
    y = np.array([0.0, 1.0, 2.0, 4.0])
    y_hat = y + np.array([0.4, -0.4, 0.0, 0.0])
    # range 4: mean |diff| = 0.2, scaled 0.05
    assert step_error(y, y_hat)[0] == pytest.approx(0.05)
    # invariant to an affine rescaling of both responses (it scales by the truth's range)
    assert step_error(3 * y + 1, 3 * y_hat + 1)[0] == pytest.approx(0.05)


def test_step_error_rejects_bad_input():
    with pytest.raises(ValueError, match="y_hat must have the shape of y_true"):
        step_error(np.ones((2, 5)), np.ones((2, 4)))
    with pytest.raises(ValueError, match="y_true must not be constant"):
        step_error(np.ones(5), np.ones(5))


def test_bode_errors_gain_and_delay_closed_form():
    # Doubling the gain adds 20 log10(2) dB everywhere and no phase.
    A, b, c = np.array([[-2.0]]), np.array([1.0]), np.array([3.0])
    mag, phase = bode_errors((A, b, c, 0.0), (A, b, 2 * c, 0.0))
    assert mag[0] == pytest.approx(20 * np.log10(2.0))
    assert phase[0] == pytest.approx(0.0, abs=1e-12)
    # Negating the gain is a phase of exactly pi, no magnitude.
    mag, phase = bode_errors((A, b, c, 0.0), (A, b, -c, 0.0))
    assert mag[0] == pytest.approx(0.0, abs=1e-12)
    assert phase[0] == pytest.approx(np.pi)


def test_parameter_errors_and_fit():
    err = parameter_errors({"k": np.array([20.0, 25.0])}, {"k": np.array([21.0, 24.0]), "x": 1})
    np.testing.assert_allclose(err["k"], [5.0, 4.0])
    assert "x" not in err
    y = np.array([1.0, 2.0, 3.0])
    assert nrmse_fit(y, y)[0] == pytest.approx(100.0)
    assert nrmse_fit(y, np.full(3, 2.0))[0] == pytest.approx(0.0)


def test_fit_of_a_constant_record_is_undefined():
    # ||y - mean(y)|| = 0: no model explains the record better than its mean, so the fit is
    # NaN, not 100 % (the old answer, which called any model perfect). 0.7 is not a binary
    # fraction: the rounded mean leaves ||y - mean|| ~ 1e-16, which must not count as a spread.
    y = np.stack([np.full(60, 0.7), np.array([1.0, 2.0, 3.0] * 20)])
    fit = nrmse_fit(y, np.stack([np.full(60, 0.7), np.array([1.0, 2.0, 3.0] * 20) + 0.1]))
    assert np.isnan(fit[0])
    # the defined one against the closed form: ||0.1||_2 over the spread of [1, 2, 3] * 20
    assert fit[1] == pytest.approx(100 * (1 - np.sqrt(60 * 0.01) / np.sqrt(40.0)))
    assert np.isnan(nrmse_fit(np.full(5, -3.0), np.zeros(5))[0])
    with pytest.raises(ValueError, match=r"y_hat must have the shape of y \(1, 5\); got \(1, 4\)"):
        nrmse_fit(np.arange(5.0), np.arange(4.0))
