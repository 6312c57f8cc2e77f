"""Record refinement (aeid_struct.refinement.refine_record) against independent oracles.

Oracles: a numpy recursion of ``scipy.linalg.expm``'s FOH discretisation (Eq. 10-13) from a
given state, with a delay and an offset, for the records and for the returned ``y_hat``; the
true elements, state, offset and delay behind noise-free records; central finite differences
for the graph's Jacobian; eigenvalues for the MCF constraint.
"""

from __future__ import annotations

import casadi
import numpy as np
import pytest
import scipy.linalg

from aeid_struct.refinement import BUCKETS, cache_info, clear_cache, refine_record
from aeid_struct.refinement import record as R
from aeid_struct.structures import CCF, MCF, Physical


def simulate(A, b, c, d, u, dt, x0, delay=0, offset=0.0):
    """The FOH response (Eq. 10-13) of ``u`` delayed by ``delay`` samples from state ``x0`` at
    sample ``delay``, plus ``offset``; NaN before ``delay``."""
    n = A.shape[0]
    M = np.zeros((n + 2, n + 2))
    M[:n, :n], M[:n, n], M[n, n + 1] = A * dt, b * dt, 1.0
    E = scipy.linalg.expm(M)
    Phi, g1, g2 = E[:n, :n], E[:n, n], E[:n, n + 1]
    N = u.shape[0]
    ud = np.r_[np.zeros(delay), u[:N - delay]]
    y, x = np.full(N, np.nan), np.array(x0, dtype=np.float64)
    for k in range(delay, N):
        y[k] = c @ x + d * ud[k] + offset
        if k + 1 < N:
            x = Phi @ x + (g1 - g2) * ud[k] + g2 * ud[k + 1]
    return y


def ccf_truth(poles, numerator):
    """CCF elements (a0.., c0..) and matrices of ``numerator(s) / prod(s - poles)``."""
    a = np.real(np.poly(poles))[::-1][:-1]
    n = a.size
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1] = -a
    b = np.eye(n)[-1]
    return np.r_[a, numerator], A, b, np.asarray(numerator, dtype=np.float64)


def excitation(N, seed=0):
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.standard_normal(N)) * 0.1 + np.sin(np.arange(N) * 0.05)


#: Order 3 with two zeros (numerator 26 (0.3 s^2 - 0.5 s + 2)).
CCF3 = ccf_truth([-1.0, -2.0 + 3.0j, -2.0 - 3.0j], 26.0 * np.array([2.0, -0.5, 0.3]))
X0 = np.array([0.4, -0.3, 0.8])


def ccf3_record(N=1000, dt=0.01, delay=2, offset=0.7):
    x, A, b, c = CCF3
    u = excitation(N)
    y = simulate(A, b, c, 0.0, u, dt, X0, delay, offset)
    y[:delay] = 0.25        # samples that depend on inputs before the record
    return x, u, y


def off_by(x, rel, seed=1):
    return x * (1 + rel * np.random.default_rng(seed).choice([-1.0, 1.0], x.size))


def test_recovers_elements_state_offset_and_picks_the_delay():
    x, u, y = ccf3_record()
    fit = refine_record(CCF(3), off_by(x, 0.1), y, u, 0.01, delays=(1, 2, 3))
    assert fit.delay == 2
    got = np.array([fit.elements[nm] for nm in CCF(3).element_names])
    assert np.max(np.abs(got - x) / np.abs(x)) < 1e-6
    assert np.max(np.abs(fit.x0 - X0)) < 1e-6
    assert abs(fit.offset - 0.7) < 1e-6
    assert fit.info["converged"] and fit.fit > 99.9999 and fit.info["cost"] < 1e-12
    assert np.all(np.isnan(fit.y_hat[:2])) and np.all(np.isfinite(fit.y_hat[2:]))


def test_y_hat_and_cost_are_an_expm_simulation_of_the_returned_model():
    # A noisy record, so that the residual at the solution is not zero.
    x, u, y = ccf3_record(N=900, delay=3)
    y[3:] += 0.05 * np.random.default_rng(5).standard_normal(897)
    fit = refine_record(CCF(3), off_by(x, 0.05), y, u, 0.01, delay=3)
    oracle = simulate(fit.A, fit.b, fit.c, fit.d, u, 0.01, fit.x0, 3, fit.offset)
    scale = np.max(np.abs(y))
    assert np.max(np.abs(fit.y_hat[3:] - oracle[3:])) < 1e-9 * scale
    resid, spread = y[3:] - oracle[3:], y[3:] - y[3:].mean()
    assert fit.info["cost"] == pytest.approx(resid @ resid / (spread @ spread), rel=1e-9)
    assert fit.fit == pytest.approx(100 * (1 - np.sqrt(fit.info["cost"])), rel=1e-12)
    # A, b, c are the structure's assembly of the returned elements.
    a = np.array([fit.elements[f"a{i}"] for i in range(3)])
    assert np.array_equal(fit.A[-1], -a) and np.array_equal(fit.b, [0.0, 0.0, 1.0])


def test_without_offset_the_offset_is_zero_and_the_delay_is_used_as_given():
    x, u, y = ccf3_record(delay=1, offset=0.0)
    fit = refine_record(CCF(3), off_by(x, 0.05), y, u, 0.01, delay=1, offset=False)
    assert fit.offset == 0.0 and fit.delay == 1
    got = np.array([fit.elements[nm] for nm in CCF(3).element_names])
    assert np.max(np.abs(got - x) / np.abs(x)) < 1e-6


def test_mcf_keeps_its_poles_in_the_left_half_plane_on_unstable_data():
    # The data come from a system with a real pole at +0.4: the best MCF model sits on the bound.
    dt, N = 0.02, 600
    A = np.diag([0.4, 0.0, 0.0])
    A[1:, 1:] = [[-1.0, 3.0], [-3.0, -1.0]]
    b, c = np.array([1.0, 0.0, 1.0]), np.array([1.0, 0.5, 2.0])
    u = excitation(N, seed=3)
    y = simulate(A, b, c, 0.0, u, dt, np.zeros(3))
    mcf = MCF(real=1, pairs=1)
    start = {"lambda0": -0.5, "delta0": -1.2, "omega0": 2.8, "c0": 1.0, "c1": 0.5, "c2": 2.0}
    fit = refine_record(mcf, start, y, u, dt)
    assert fit.elements["lambda0"] <= -1e-8 and fit.elements["delta0"] <= -1e-8
    assert np.max(np.linalg.eigvals(fit.A).real) < 0


def test_a_fixed_element_stays_fixed_and_the_others_are_recovered():
    x, A, b, c = ccf_truth([-2.0, -5.0], [10.0, 0.0])
    structure = CCF(2).fixed(c1=0.0)
    u = excitation(800, seed=2)
    y = simulate(A, b, c, 0.0, u, 0.01, [0.2, -0.1], 0, 0.3)
    fit = refine_record(structure, {"a0": 9.0, "a1": 7.7, "c0": 11.0}, y, u, 0.01)
    assert fit.elements["c1"] == 0.0
    got = np.array([fit.elements[nm] for nm in ("a0", "a1", "c0")])
    assert np.max(np.abs(got - x[:3]) / x[:3]) < 1e-6


def test_physical_parameters_are_recovered_within_their_bounds():
    k, dd, m = (casadi.SX.sym(nm) for nm in ("k", "d", "m"))
    A = casadi.vertcat(casadi.horzcat(0, 1), casadi.horzcat(-k / m, -dd / m))
    f = casadi.Function("msd", [k, dd, m], [A, casadi.vertcat(0, 1 / m), casadi.horzcat(1, 0),
                                            casadi.SX(0)],
                        ["k", "d", "m"], ["A", "B", "C", "D"])
    structure = Physical(f, bounds={"k": (1.0, 50.0), "d": (0.1, 5.0), "m": (0.5, 3.0)})
    truth = {"k": 20.0, "d": 1.5, "m": 1.2}
    out = f(**truth)
    An, Bn, Cn = (np.array(out[s]) for s in "ABC")
    u = excitation(700, seed=4)
    y = simulate(An, Bn.ravel(), Cn.ravel(), 0.0, u, 0.01, [0.01, 0.0], 0, -0.2)
    fit = refine_record(structure, [21.0, 1.43, 1.26], y, u, 0.01)
    for nm, v in truth.items():
        assert fit.elements[nm] == pytest.approx(v, rel=1e-6)


def test_one_graph_serves_every_length_and_dt_in_a_bucket():
    clear_cache()
    x, A, b, c = CCF3
    for N, dt in ((700, 0.01), (1000, 0.01), (700, 0.3), (1000, 0.3)):
        u = excitation(N)
        y = simulate(A, b, c, 0.0, u, dt, X0, 1, 0.1)
        y[0] = 0.1                        # before the delay: not fitted, but must be finite
        fit = refine_record(CCF(3), off_by(x, 0.05), y, u, dt, delay=1)
        got = np.array([fit.elements[nm] for nm in CCF(3).element_names])
        assert np.max(np.abs(got - x) / np.abs(x)) < 1e-6, (N, dt)
    info = cache_info()
    assert info.builds == 1 and info.hits >= 3


@pytest.mark.parametrize("structure", [CCF(2, feedthrough=True), MCF(real=1, pairs=1)],
                         ids=["ccf2d", "mcf3"])
def test_the_graphs_jacobian_is_the_finite_difference_of_its_response(structure):
    graph = R.build_record_graph(structure, BUCKETS[0])
    rng = np.random.default_rng(7)
    f = len(structure.free_names)
    if isinstance(structure, MCF):
        z = np.array([-0.8, -0.5, 2.0, 1.0, 0.4, -0.3])
    else:
        z = np.array([3.0, 1.5, 0.7, -0.4, 0.2])
    scale = 1.0 + rng.random(f)
    x0, u = rng.standard_normal(structure.n), rng.standard_normal(BUCKETS[0])

    def response(zz):
        p = np.concatenate([scale, [0.05, 0.5, 1.0], x0, u])   # dt, 2^-s, s = 1 squaring
        return graph(zz / scale, p)

    yhat, _, J = response(z)
    J = J.reshape(f, -1).T / scale[None, :]   # the graph's variables are x / scale
    h = 1e-6
    for j in range(f):
        e = np.zeros(f)
        e[j] = h
        fd = (response(z + e)[0] - response(z - e)[0]) / (2 * h)
        assert np.max(np.abs(fd - J[:, j])) < 1e-6 * (1 + np.max(np.abs(J[:, j])))
    # and the response itself is the expm simulation from x0
    A, b, c, d = structure.casadi_system(z)
    oracle = simulate(np.array(A), np.array(b).ravel(), np.array(c).ravel(), float(d), u,
                      0.05, x0)
    assert np.max(np.abs(yhat - oracle)) < 1e-10 * np.max(np.abs(oracle))


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"delays": (1, -1)}, r"delays must be integers 0 <= D <= 95"),
    ({"delay": 99}, r"delay must be integers 0 <= D <= 95"),
    ({"delays": ()}, r"delays must be integers"),
])
def test_bad_delays_are_named(kwargs, match):
    u = excitation(100)
    with pytest.raises(ValueError, match=match):
        refine_record(CCF(3), CCF3[0], u, u, 0.01, **kwargs)


def test_bad_arguments_are_named():
    u = excitation(100)
    with pytest.raises(ValueError, match=r"y and u must have the same shape \(N,\); got"):
        refine_record(CCF(3), CCF3[0], u, u[:-1], 0.01)
    with pytest.raises(ValueError, match=r"start is missing the free element\(s\) c2"):
        refine_record(CCF(3), {f"a{i}": 1.0 for i in range(3)} | {"c0": 1.0, "c1": 1.0}, u, u,
                      0.01)
    with pytest.raises(ValueError, match=r"start must hold the 6 free elements .* got shape"):
        refine_record(CCF(3), [1.0, 2.0], u, u, 0.01)
    with pytest.raises(ValueError, match=r"structure must be a Structure of one record"):
        refine_record("CCF", CCF3[0], u, u, 0.01)
    long = np.ones(BUCKETS[-1] + 1)
    with pytest.raises(ValueError, match=rf"at most {BUCKETS[-1]} samples after the delay"):
        refine_record(CCF(3), CCF3[0], long, long, 0.01)


def test_the_result_is_an_estimate_of_the_record_in_its_structure():
    """refine_record returns the one Estimate: of the record it was given, in the structure,
    with the model and the fields of a record with a delay and an offset."""
    from aeid_struct.estimates import Estimate

    x, u, y = ccf3_record()
    structure = CCF(3)
    fit = refine_record(structure, off_by(x, 0.1), y, u, 0.01, delay=2)
    assert isinstance(fit, Estimate) and fit.refined and fit.provenance.structure is structure
    assert fit.provenance.initial == "fitted" and fit.record.dt == (0.01,)
    np.testing.assert_array_equal(fit.y, y)
    assert fit.info["method"] == "refine_record" and fit.info["iterations"] >= 1
    np.testing.assert_allclose(fit.B[:, 0], fit.b)
    np.testing.assert_allclose(fit.C[0], fit.c)


def test_a_sample_that_is_not_finite_is_refused_by_name():
    x, u, y = ccf3_record()
    y[0] = np.nan
    with pytest.raises(ValueError, match="y must be finite"):
        refine_record(CCF(3), x, y, u, 0.01, delay=2)
