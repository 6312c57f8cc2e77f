"""generic.classical: the Steiglitz-McBride start, against the true denominator."""

import numpy as np
import pytest
from helpers import companion

from aeid_struct.generic.classical import EARLY, arx, classical_candidates, steiglitz_mcbride
from aeid_struct.simulation import simulate

ccf = companion


POLES = {
    1: [-0.08],
    2: [-0.01 + 0.3j, -0.01 - 0.3j],                     # damping ratio 0.033
    3: [-0.05 + 0.4j, -0.05 - 0.4j, -0.02],
    4: [-0.005 + 0.2j, -0.005 - 0.2j, -0.1 + 1.0j, -0.1 - 1.0j],
}


def record(order, noise, delay=2, seed=0, steps=1500):
    den = np.real(np.poly(POLES[order]))
    A, b = ccf(den)
    rng = np.random.default_rng(seed)
    c = rng.standard_normal(order)
    u = np.repeat(rng.uniform(-1, 1, steps // 10 + 1), 10)[: steps + 300]
    y = np.asarray(simulate(A, b, c, 0.0, u, 1.0))[300:] + 2.0       # mid-motion, offset
    y = y + noise * y.std() * rng.standard_normal(y.shape)
    u_logged = np.concatenate([u[300 + delay :], np.zeros(delay)])[:steps]
    return den, y[:steps], u_logged


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_noise_free_recovers_the_true_denominator(order):
    den, y, u = record(order, 0.0)
    est = steiglitz_mcbride(y, u, order, delay=2)
    np.testing.assert_allclose(np.sort_complex(np.roots(est)), np.sort_complex(POLES[order]),
                               atol=1e-6)


def test_with_noise_it_beats_plain_arx():
    den, y, u = record(2, 0.05, seed=1)
    arx = steiglitz_mcbride(y, u, 2, delay=2, iterations=0)
    sm = steiglitz_mcbride(y, u, 2, delay=2, iterations=8)

    def err(d):
        return np.abs(np.sort_complex(np.roots(d)) - np.sort_complex(POLES[2])).max()

    assert err(sm) < 0.3 * err(arx)
    assert err(sm) < 5e-3


def test_too_short_gives_none():
    assert steiglitz_mcbride(np.ones(8), np.arange(8.0), 3) is None


def test_the_refits_run_to_the_fixed_point():
    """At a low signal-to-noise ratio a fixed five refits stop short of the fixed point; the
    default runs to it (a refit from it moves nothing), which is what the early iterate and
    the fixed point of ``classical_candidates`` are."""
    den, y, u = record(4, 0.05, seed=1)
    fixed = steiglitz_mcbride(y, u, 4, delay=2)
    np.testing.assert_allclose(steiglitz_mcbride(y, u, 4, delay=2, iterations=200), fixed,
                               rtol=1e-8)
    early = steiglitz_mcbride(y, u, 4, delay=2, iterations=EARLY)
    both = classical_candidates(y, u, 4, delay=2)
    assert both.shape == (2, 5)
    np.testing.assert_array_equal(both[0], early)
    np.testing.assert_array_equal(both[1], fixed)
    # noise-free, the fixed point is reached early and is the true denominator: one candidate
    den, y, u = record(2, 0.0)
    one = classical_candidates(y, u, 2, delay=2)
    assert one.shape == (1, 3)
    np.testing.assert_allclose(np.sort_complex(np.roots(one[0])), np.sort_complex(POLES[2]),
                               atol=1e-6)
    assert classical_candidates(np.ones(8), np.arange(8.0), 3).shape == (0, 4)


def test_arx_solves_the_least_squares_problem_of_lstsq():
    """``arx`` solves by Householder QR: the same solution as the SVD's ``lstsq`` on an
    independent problem (with the constant or ``extra`` columns), and the SVD's
    minimum-norm solution where the columns are dependent (a constant input)."""
    rng = np.random.default_rng(3)
    y, u = rng.standard_normal(400), rng.standard_normal(400)
    n = 3
    rows = np.arange(n, 400)

    def reference(y, u, extra):
        Z = np.stack([-y[rows - i] for i in range(1, n + 1)]
                     + [u[rows - j] for j in range(n + 1)]
                     + ([np.ones(rows.size)] if extra is None else list(extra[rows].T)), 1)
        return np.concatenate([[1.0], np.linalg.lstsq(Z, y[rows], rcond=None)[0][:n]])

    extra = rng.standard_normal((400, 2))
    for columns in (None, extra):
        np.testing.assert_allclose(arx(y, u, n, columns), reference(y, u, columns),
                                   rtol=1e-10, atol=1e-12)
    # a constant input: its lags and the constant are one column, and the y-lags' part of the
    # minimum-norm solution is that of lstsq
    flat = np.full(400, 0.7)
    np.testing.assert_allclose(arx(y, flat, n), reference(y, flat, None), rtol=1e-8,
                               atol=1e-10)
