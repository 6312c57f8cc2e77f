"""Refinement (aeid_struct.refine) against independent oracles.

Oracles: ``scipy.linalg.expm`` for the CasADi matrix exponential; the decoder's float64
simulation (``aeid_struct.simulate``) and Eq. 14-15 (``normalise``, ``loss``) for the NLP's
objective; the true systems behind noise-free records (the robot leg through ``symbolic.leg``,
closed-form CCF / MCF / fixed models) for what the refinement recovers; eigenvalues for the
constraints.
"""

from __future__ import annotations

import dataclasses

import casadi
import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
import torch
from helpers import rel_max_error
from problems import inputs, modal_system
from test_identify import _identifier, _record
from test_joint_refine import QUARTER, _oracle_residual

import aeid_struct as ae
from aeid_struct import simulation as S
from aeid_struct.identification import Head
from aeid_struct.refinement import (
    RefineConfig,
    cache_info,
    clear_cache,
    refine,
    solve,
)
from aeid_struct.refinement import nlp as R
from aeid_struct.refinement.solve import refine_elements
from symbolic import leg
from symbolic.mechanisms import quarter_car

# -- records with exact answers ---------------------------------------------------------------

#: The robot-leg records of the study (aeid_struct.study): (dt, steps).
LEG = {"stable": (0.01, 300), "unstable": (0.005, 100)}


def leg_truth(subsystem: str, k=24.23, d=2.24, m=1.01):
    """CCF elements (a0, a1, c0, c1) of a leg subsystem and its unit-step record."""
    f = leg.stable_map() if subsystem == "stable" else leg.unstable_map()
    out = f(k=k, d=d, m=m)
    A, B, C = (np.array(out[s]) for s in "ABC")
    dt, steps = LEG[subsystem]
    y = ae.simulate(A, B.ravel(), C.ravel(), 0.0, np.ones(steps), dt)
    return np.r_[-A[1], C.ravel()], y, dt


def record_of(structure, x, u, dt):
    A, b, c, d = (v.numpy() for v in structure.assemble(torch.tensor(x, dtype=torch.float64)))
    return ae.simulate(A, b, c, d, u, dt)


def step_error(structure, x, x_true, steps, dt):
    """max |step response difference| / max |true step response|."""
    u = np.ones(steps)
    return rel_max_error(record_of(structure, x, u, dt), record_of(structure, x_true, u, dt))


def perturbed(x, rel, seed, structure=None):
    rng = np.random.default_rng(seed)
    x0 = x * (1.0 + rel * rng.choice([-1.0, 1.0], size=x.shape))
    if structure is not None:
        for name, v in structure.fixed_values.items():
            x0[structure.element_names.index(name)] = v
    return x0


# -- the matrix exponential ---------------------------------------------------------------------


@pytest.mark.parametrize("order", range(1, 9))
@pytest.mark.parametrize("norm", [1e-3, 0.3, 1.0, 3.0, 5.0, 10.0])
def test_expm_matches_scipy(order, norm):
    # orders 1-8: M of Eq. 10 is (n + 2) x (n + 2) for n = 1..6; ||M||_1 up to 10 (squarings)
    rng = np.random.default_rng(100 * order + int(10 * norm))
    M = rng.normal(size=(order, order))
    M *= norm / np.abs(M).sum(0).max()
    s = S.squarings_for(np.abs(M).sum(0).max())
    X = casadi.SX.sym("M", order, order)
    f = casadi.Function("expm", [X], [S.expm(X, s)])
    expected = scipy.linalg.expm(M)
    assert rel_max_error(np.array(f(M)), expected) <= 1e-12
    # a numeric M picks its squarings itself, and spare squarings do not hurt
    assert rel_max_error(np.array(S.expm(M)), expected) <= 1e-12
    assert rel_max_error(np.array(casadi.Function("e", [X], [S.expm(X, s + 3)])(M)),
                         expected) <= 1e-12


def test_expm_of_the_augmented_matrix_gives_the_decoders_discretisation():
    rng = np.random.default_rng(1)
    for n in range(1, 7):
        A, b, _, _ = modal_system(n, rng, stable=n % 2 == 0)
        dt = 0.05
        E = np.array(S.expm(S.augmented(casadi.DM(A), casadi.DM(b), dt)))
        ref = ae.discretise(A, b, dt)
        assert rel_max_error(E[:n, :n], ref.Phi) <= 1e-12
        assert rel_max_error(E[:n, n], ref.gamma1) <= 1e-12
        assert rel_max_error(E[:n, n + 1], ref.gamma2) <= 1e-12
        np.testing.assert_allclose(E[n:, n:], [[1.0, 1.0], [0.0, 1.0]], atol=1e-15)


def test_expm_errors():
    with pytest.raises(ValueError, match="squarings must be given for a symbolic M"):
        S.expm(casadi.SX.sym("M", 2, 2))
    with pytest.raises(ValueError, match="squarings must be an integer >= 0; got -1"):
        S.expm(np.eye(2), -1)
    with pytest.raises(ValueError, match=r"M must be square; got shape \(2, 3\)"):
        S.expm(np.ones((2, 3)))


# -- the simulation inside the NLP ----------------------------------------------------------------


@pytest.mark.parametrize("n", range(1, 7))
@pytest.mark.parametrize("stable", [True, False])
def test_casadi_simulation_equals_the_decoder(n, stable):
    rng = np.random.default_rng(10 * n + stable)
    A, b, c, d = modal_system(n, rng, stable=stable, feedthrough=True)
    steps, dt = 120, 0.02
    sA, sb, sc = casadi.SX.sym("A", n, n), casadi.SX.sym("b", n), casadi.SX.sym("c", n)
    sd, su = casadi.SX.sym("d"), casadi.SX.sym("u", steps)
    norm = max(np.abs(A).sum(0).max() * dt, np.abs(b).sum() * dt, 1.0)
    y = S.casadi_simulate(sA, sb, sc, sd, su, dt, squarings=S.squarings_for(norm))
    f = casadi.Function("sim", [sA, sb, sc, sd, su], [y])
    for name, u in inputs(steps, dt, rng).items():
        expected = ae.simulate(A, b, c, d, u, dt)
        got = np.array(f(A, b, c, d, u)).ravel()
        assert rel_max_error(got, expected) <= 1e-12, name


def _casadi_response(A, b, c, d, u, dt):
    """``casadi_simulate`` of a numeric system, through a symbolic graph as the NLP builds it."""
    n, steps = A.shape[0], len(u)
    sA, sb, sc = casadi.SX.sym("A", n, n), casadi.SX.sym("b", n), casadi.SX.sym("c", n)
    sd, su = casadi.SX.sym("d"), casadi.SX.sym("u", steps)
    norm = max(np.abs(A).sum(0).max() * dt, np.abs(b).sum() * dt, 1.0)
    y = S.casadi_simulate(sA, sb, sc, sd, su, dt, squarings=S.squarings_for(norm))
    return np.array(casadi.Function("sim", [sA, sb, sc, sd, su], [y])(A, b, c, d, u)).ravel()


@pytest.mark.parametrize("pole_dt", [-30.0, -10.0, -1.0, 0.1, 1.0, 10.0, 20.0, 30.0])
@pytest.mark.parametrize("kind", ["real", "pair", "two real"])
def test_casadi_simulation_keeps_each_samples_digits_at_large_pole_dt(pole_dt, kind):
    """One FOH simulator (issue 13): the CasADi graph carries x itself like the decoder, so each
    sample agrees with ``simulate`` (numpy, float64) to 1e-9 relative up to |p| dt = 30. The
    shifted state xi = x - gamma2 u (cont2discrete's) lost ~1e-4 of it there: from rest
    xi_0 = -gamma2 u_0 grows like the response and cancels against the input's kernel."""
    dt = 0.1
    p = pole_dt / dt
    if kind == "real":
        A, b, c, d = np.array([[p]]), np.array([1.0]), np.array([1.0]), 0.3
    elif kind == "pair":   # p +- j 0.5 |p|
        A = np.array([[p, 0.5 * abs(p)], [-0.5 * abs(p), p]])
        b, c, d = np.array([0.0, 1.0]), np.array([1.0, 0.3]), 0.0
    else:                  # p and -0.3 p: one stable and one unstable mode, or two stable
        A = np.diag([p, -0.3 * p]) if p > 0 else np.diag([p, 0.3 * p])
        b, c, d = np.array([1.0, 1.0]), np.array([1.0, -2.0]), 0.1
    rng = np.random.default_rng(int(abs(pole_dt) * 10) + len(kind))
    u = 1.0 + rng.normal(size=20)       # u_0 != 0: the case the shifted state got wrong
    expected = ae.simulate(A, b, c, d, u, dt)
    got = _casadi_response(A, b, c, d, u, dt)
    assert np.all(np.isfinite(expected))
    nonzero = expected != 0.0           # y_0 = d u_0 = 0 for the pair, exactly in both
    np.testing.assert_array_equal(got[~nonzero], 0.0)
    assert np.max(np.abs(got - expected)[nonzero] / np.abs(expected[nonzero])) <= 1e-9


def test_casadi_simulation_matches_the_decoder_up_to_the_decoders_overflow():
    """p dt = 30 over 30 samples grows by e^870, beyond float64: ``simulate`` returns +inf from
    the first overflowing sample on (with its warning); every finite sample before it agrees."""
    A, b, c, dt = np.array([[300.0]]), np.array([1.0]), np.array([1.0]), 0.1
    u = np.linspace(1.0, 2.0, 30)
    with pytest.warns(S.OverflowWarning, match="the response overflows float64"):
        expected = ae.simulate(A, b, c, 0.0, u, dt)
    finite = np.isfinite(expected)
    assert 20 < finite.sum() < 30 and np.all(finite[: finite.sum()])
    with np.errstate(all="ignore"):
        got = _casadi_response(A, b, c, 0.0, u, dt)
    got, expected = got[finite], expected[finite]
    assert got[0] == expected[0] == 0.0            # y_0 = d u_0, d = 0
    assert np.max(np.abs(got[1:] - expected[1:]) / np.abs(expected[1:])) <= 1e-9


def test_the_nlp_objective_is_eq14_of_the_normalised_record():
    rng = np.random.default_rng(3)
    structure = ae.MCF(real=1, pairs=1, feedthrough=True)
    x = np.array([-2.0, -1.0, 5.0, 3.0, 0.5, -1.0, 0.2])
    steps, dt = 150, 0.02
    u = rng.normal(size=steps)
    y = record_of(structure, x, u, dt) + 0.01 * rng.normal(size=steps)
    x0 = perturbed(x, 0.1, 0)
    res = refine_elements(structure, x0, y, u, dt, RefineConfig(max_iter=1))
    y_bar = ae.decoder.record_scale(y)
    for elements, value in ((x0, res.loss_start), (res.elements, res.loss)):
        y_hat = record_of(structure, elements, u, dt)
        expected = float(ae.decoder.loss(ae.decoder.normalise(y_hat, y_bar),
                                         ae.decoder.normalise(y, y_bar)))
        assert value == pytest.approx(expected, rel=1e-10)


# -- recovering the exact system ------------------------------------------------------------------


def _cases():
    x_s, y_s, dt_s = leg_truth("stable")
    x_u, y_u, dt_u = leg_truth("unstable")
    steps = 200
    u_rand = inputs(steps, 0.02, np.random.default_rng(0))["prbs"]
    mcf = ae.MCF(real=1, pairs=1)
    x_mcf = np.array([-2.0, -1.0, 5.0, 3.0, 0.5, -1.0])
    fixed = ae.CCF(3).fixed(a1=0.5, c2=-1.25)
    x_fix = np.array([6.0, 0.5, 4.0, 2.0, 1.0, -1.25])
    physical = ae.Physical(leg.stable_map(), bounds=dict(leg.RANGES),
                           inverse=leg.stable_inverse())
    x_phys = np.array([leg.SCENARIO[k] for k in "kdm"])
    return {
        "ccf-stable-leg": (ae.CCF(2, descartes=True), x_s, y_s, None, dt_s),
        "ccf-unstable-leg": (ae.CCF(2), x_u, y_u, None, dt_u),
        "mcf": (mcf, x_mcf, record_of(mcf, x_mcf, u_rand, 0.02), u_rand, 0.02),
        "fixed": (fixed, x_fix, record_of(fixed, x_fix, np.ones(steps), 0.02), None, 0.02),
        "physical-stable-leg": (physical, x_phys, y_s, None, dt_s),
    }


CASES = _cases()


@pytest.mark.parametrize("name", CASES)
def test_refinement_recovers_the_exact_system(name):
    structure, x_true, y, u, dt = CASES[name]
    x0 = perturbed(x_true, 0.15, 1, structure)
    if name == "physical-stable-leg":
        x0 = np.array([22.0, 3.5, 0.9])  # 9-56 % off, inside the bounds
    res = refine_elements(structure, x0, y, u, dt)
    assert res.success and res.solver == "sqpmethod" and res.iterations >= 1
    assert res.loss <= 1e-20 < res.loss_start
    scale = np.abs(x_true).max()
    assert np.abs(res.elements - x_true).max() <= 1e-8 * scale
    assert step_error(structure, res.elements, x_true, y.shape[0], dt) <= 1e-8
    for k, v in structure.fixed_values.items():
        assert res.elements[structure.element_names.index(k)] == v  # exactly


def test_ipopt_recovers_the_stable_leg_too():
    structure, x_true, y, u, dt = CASES["ccf-stable-leg"]
    res = refine_elements(structure, perturbed(x_true, 0.1, 2), y, u, dt,
                          RefineConfig(solver="ipopt"))
    assert res.success and res.solver == "ipopt"
    assert np.abs(res.elements - x_true).max() <= 1e-8 * np.abs(x_true).max()


def test_iterates_beyond_the_squarings_trigger_a_rebuild():
    # Fast poles (||A dt||_1 = 125 needs 5 squarings) from a slow start (norm 5 -> 3 squarings):
    # the problem is rebuilt with more squarings at the solution and solved again.
    structure = ae.CCF(2)
    x_true = np.array([2500.0, 70.0, 2500.0, 0.0])
    dt, steps = 0.05, 60
    y = record_of(structure, x_true, np.ones(steps), dt)
    x0 = np.array([100.0, 10.0, 100.0, 0.0])
    res = refine_elements(structure, x0, y, None, dt)
    assert R.fewest_squarings(solve._NORM_MARGIN * 5.0) == 3 and res.squarings >= 5
    assert res.success
    assert np.abs(res.elements - x_true).max() <= 1e-8 * 2500.0


# -- constraints ----------------------------------------------------------------------------------


def test_descartes_refinement_cannot_return_a_positive_real_pole():
    # data from (s + 2)(s - 1): the best Descartes model has no pole on the positive real axis
    A = np.array([[0.0, 1.0], [2.0, -1.0]])
    y = ae.simulate(A, np.r_[0.0, 1.0], np.r_[1.0, 0.0], 0.0, np.ones(100), 0.01)
    structure = ae.CCF(2, descartes=True)
    res = refine_elements(structure, [1.0, 1.0, 1.0, 0.0], y, None, 0.01)
    assert res.loss < res.loss_start
    assert np.all(res.elements[:2] >= 0.0)
    poles = np.linalg.eigvals(structure.assemble(torch.tensor(res.elements)).A.numpy())
    assert not np.any((poles.real > 0) & (np.abs(poles.imag) < 1e-12)), poles
    # without Descartes the same data give the unstable truth back
    free = refine_elements(ae.CCF(2), [1.0, 1.0, 1.0, 0.0], y, None, 0.01)
    np.testing.assert_allclose(free.elements, [-2.0, 1.0, 1.0, 0.0], atol=1e-8)


def test_mcf_stays_hurwitz_on_unstable_data():
    structure = ae.MCF(real=1, pairs=1)
    x_true = np.array([1.0, -1.0, 5.0, 1.0, 0.5, -1.0])  # lambda0 = +1: outside the structure
    dt, steps = 0.02, 150
    y = record_of(structure, x_true, np.ones(steps), dt)  # assemble does not check constraints
    res = refine_elements(structure, [-0.5, -1.0, 4.0, 1.0, 1.0, -1.0], y, None, dt)
    assert res.loss <= res.loss_start
    A = structure.assemble(torch.tensor(res.elements)).A.numpy()
    assert np.linalg.eigvals(A).real.max() < 0.0
    lo_hi = structure.element_bounds()
    for name, v in zip(structure.element_names, res.elements, strict=True):
        assert lo_hi[name][0] <= v <= lo_hi[name][1], name


def test_physical_parameters_stay_inside_their_bounds():
    # a leg stiffer than the bounds allow: k is held at its upper bound
    structure = ae.Physical(leg.stable_map(), bounds=dict(leg.RANGES))
    _, y, dt = leg_truth("stable", k=30.0, d=3.0, m=1.0)
    res = refine_elements(structure, [22.0, 3.0, 1.0], y, None, dt)
    assert res.loss < res.loss_start
    for name, v in zip(structure.element_names, res.elements, strict=True):
        lo, hi = leg.RANGES[name]
        assert lo <= v <= hi, name
    assert res.elements[0] == pytest.approx(25.0, abs=1e-9)


def test_an_unidentifiable_parameter_stays_put():
    # the unstable leg does not depend on d; the Gauss-Newton floor keeps the QP well posed
    structure = ae.Physical(leg.unstable_map(), bounds=dict(leg.RANGES))
    _, y, dt = leg_truth("unstable", k=22.0, d=3.5, m=1.2)
    res = refine_elements(structure, [21.0, 2.5, 1.3], y, None, dt)
    assert res.success
    np.testing.assert_allclose(res.elements[[0, 2]], [22.0, 1.2], rtol=1e-8)
    assert res.elements[1] == pytest.approx(2.5, abs=1e-6)


# -- never worse than the start -------------------------------------------------------------------


def test_the_start_is_kept_when_the_solver_makes_it_worse():
    # G = 2 / (s (s + 3)) starts exactly on the bound a0 = 0; one ipopt iteration pushes it into
    # the interior (bound_push) and raises the loss: the start comes back, flagged.
    structure = ae.CCF(2, descartes=True)
    x = np.array([0.0, 3.0, 2.0, 0.0])
    y = record_of(structure, x, np.ones(100), 0.01)
    res = refine_elements(structure, x, y, None, 0.01, RefineConfig(solver="ipopt", max_iter=1))
    assert not res.success and "kept the start" in res.status
    assert np.array_equal(res.elements, x) and res.loss == res.loss_start


def test_the_start_is_kept_when_the_solver_fails(monkeypatch):
    structure, x_true, y, u, dt = CASES["ccf-stable-leg"]
    x0 = perturbed(x_true, 0.05, 3)
    real = R.problem

    class Broken:
        def __call__(self, z, p, lbz, ubz):
            return [np.full_like(z, np.nan)]

        def stats(self):
            return {"iter_count": 7, "return_status": "Broken", "success": True}

    monkeypatch.setattr(R, "problem", lambda *a: dataclasses.replace(real(*a), solver=Broken()))
    res = refine_elements(structure, x0, y, u, dt)
    assert not res.success and "kept the start" in res.status
    assert np.array_equal(res.elements, x0) and res.loss == res.loss_start


def test_max_iter_one_reports_failure_and_never_raises_the_loss():
    structure, x_true, y, u, dt = CASES["ccf-stable-leg"]
    res = refine_elements(structure, perturbed(x_true, 0.3, 4), y, u, dt,
                          RefineConfig(max_iter=1))
    assert res.iterations == 1 and not res.success
    assert res.loss < res.loss_start


# -- the solver cache -----------------------------------------------------------------------------


def test_the_solver_is_built_once_per_format():
    clear_cache()
    structure, x_true, y, u, dt = CASES["ccf-stable-leg"]
    refine_elements(structure, perturbed(x_true, 0.05, 5), y, u, dt)
    assert cache_info().builds == 1
    res = refine_elements(ae.CCF(2, descartes=True), perturbed(x_true, 0.05, 6), 3.0 * y, u, dt)
    assert res.success
    assert (cache_info().builds, cache_info().hits) == (1, 1)   # no build: the cached solver
    refine_elements(structure, perturbed(x_true, 0.05, 7), y[:200], None, dt)  # new format
    assert cache_info().builds == 2


def test_refinement_from_one_percent_off_takes_three_iterations_on_the_stable_leg():
    # what makes the warm solve cheap, counted rather than timed (the time is the benchmark's,
    # `aeid-struct bench`): Gauss-Newton from a start 1 % off reaches the truth to 1e-12 in the
    # (at most) 3 iterations the module docstring states, from every one of 30 starts
    structure, x_true, y, u, dt = CASES["ccf-stable-leg"]
    free = x_true != 0
    for i in range(30):
        res = refine_elements(structure, perturbed(x_true, 0.01, i), y, u, dt)
        assert res.success and res.iterations <= 3, (i, res.iterations)
        np.testing.assert_allclose(res.elements[free], x_true[free], rtol=1e-12)


# -- Estimates and the Identifier -----------------------------------------------------------------


def test_identify_with_refine_single():
    ident = _identifier()
    y = _record()
    plain = ident.identify(y)
    est = ident.identify(y, refine=True)
    assert est.refined and not plain.refined
    assert set(est.info) >= {"iterations", "loss_start", "loss", "success", "seconds", "solver"}
    assert est.info["success"] and est.info["loss"] < 1e-20 < est.info["loss_start"]
    # the untrained encoder's start is far off; the refinement reaches the truth
    np.testing.assert_allclose([est.elements[k] for k in ("a0", "a1", "c0")], [20.0, 3.0, 1.0],
                               rtol=1e-8)
    assert est.fit > 99.999 > plain.fit
    # A, b, c, d assembled from the elements through the structure
    sys = ident.structure.assemble(torch.tensor([est.elements[k] for k in
                                                 ident.structure.element_names],
                                                dtype=torch.float64))
    np.testing.assert_array_equal(est.A, sys.A.numpy())
    np.testing.assert_array_equal(est.c, sys.c.numpy())
    assert isinstance(est.d, float) and est.A.shape == (2, 2)
    assert est.physical["k"] == pytest.approx(20.0, rel=1e-8)


def test_identify_with_refine_batched():
    ident = _identifier()
    y = np.stack([_record(), 2.0 * _record(), -_record()])
    est = ident.identify(y, refine=True)
    assert est.A.shape == (3, 2, 2) and est.c.shape == (3, 2) and est.d.shape == (3,)
    assert est.info["iterations"].shape == (3,) and est.info["success"].all()
    assert np.all(est.info["loss"] <= est.info["loss_start"])
    np.testing.assert_allclose(est.elements["c0"], [1.0, 2.0, -1.0], rtol=1e-8)
    np.testing.assert_allclose(est.fit, 100.0, atol=1e-3)
    for i in range(3):
        one = refine(ident.identify(y[i]))
        np.testing.assert_allclose(one.A, est.A[i], rtol=1e-10)


def test_refine_keeps_the_estimate_and_reports():
    ident = _identifier()
    y = _record()
    est = ident.identify(y)
    out = refine(est)
    assert out.refined and out.info["solver"] == "sqpmethod"
    assert out.seconds >= est.seconds and out.info["seconds"] > 0
    assert out.dt == est.dt and np.array_equal(out.y, y)
    assert out.info["loss"] <= out.info["loss_start"]
    # what the estimate refers to is kept, not copied: the same record and provenance
    assert out.record is est.record and out.provenance is est.provenance
    assert out.provenance is ident.provenance


def test_refine_takes_everything_from_the_estimate():
    # refine(estimate) and refine(estimate, config) need nothing the estimate holds; the
    # deprecated refine(estimate, y, u, dt) with the same records gives the same model, with a
    # DeprecationWarning (oracle: the closed-form model behind the noise-free record).
    ident = _identifier()
    y = _record()
    est = ident.identify(y)
    new = refine(est)
    with_config = refine(est, RefineConfig(max_iter=50))
    with pytest.warns(DeprecationWarning, match=r"refine\(estimate, y, u, dt\) is deprecated"):
        old = refine(est, y, None, 0.05)
    np.testing.assert_allclose(new.A, [[0.0, 1.0], [-20.0, -3.0]], rtol=1e-8, atol=1e-10)
    for other in (with_config, old):
        np.testing.assert_allclose(other.A, new.A, rtol=1e-12, atol=1e-14)
        assert other.info["iterations"] == new.info["iterations"]
    # the old form refines against the records it is given: a shorter record
    with pytest.warns(DeprecationWarning):
        short = refine(est, y[:40], None, 0.05)
    assert short.y.shape == (40,) and short.record.dt == (0.05,)
    with pytest.raises(ValueError, match=r"y must be given with u and dt \(the deprecated form"):
        refine(est, None, np.ones(60))
    with pytest.raises(ValueError, match=r"y must be given with u and dt"):
        refine(est, dt=0.05)


def test_refine_of_a_collected_estimate_names_the_record_set_aside():
    from aeid_struct.records import RecordError

    ident = _identifier()
    est = ident.identify(np.stack([_record(), np.zeros(60)]), errors="collect")
    with pytest.raises(RecordError, match=r"y must not be all zero \(record 1 of 2\)") as err:
        refine(est)
    assert err.value.record == 1
    good = refine(est.take([0]))          # the good record alone refines
    np.testing.assert_allclose(good.A[0], [[0.0, 1.0], [-20.0, -3.0]], rtol=1e-8, atol=1e-10)


def test_an_estimate_built_by_hand_has_its_record_checked_when_refined():
    # Estimate(...) of arrays taken as they are (no check at construction, as the baselines
    # build theirs); refine checks such a record before fitting it.
    from aeid_struct.records import RecordBatch

    ident = _identifier()
    est = ident.identify(_record())
    bare = ae.Estimate(A=est.A, b=est.b, c=est.c, d=est.d, elements=est.elements,
                       record=RecordBatch.of(np.zeros(60), None, 0.05),
                       provenance=est.provenance)
    assert not bare.record.checked and est.record.checked
    with pytest.raises(ValueError, match=r"y must not be all zero \(record 0 of 1\)"):
        refine(bare)


# -- silence and errors ---------------------------------------------------------------------------


def test_silent_unless_verbose(capfd):
    structure, x_true, y, u, dt = CASES["ccf-unstable-leg"]
    refine_elements(structure, perturbed(x_true, 0.05, 8), y, u, dt)
    assert capfd.readouterr().out == ""
    refine_elements(structure, perturbed(x_true, 0.05, 8), y, u, dt, RefineConfig(verbose=True))
    assert "iter" in capfd.readouterr().out


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"solver": "lbfgs"}, r"solver must be one of \('sqpmethod', 'ipopt'\); got 'lbfgs'"),
        ({"max_iter": 0}, r"max_iter must be an integer >= 1; got 0"),
        ({"max_iter": 2.5}, r"max_iter must be an integer >= 1; got 2.5"),
        ({"tol": -1.0}, r"tol must be a finite number > 0; got -1.0"),
        ({"tol": float("nan")}, r"tol must be a finite number > 0; got nan"),
        ({"step_tol": 0.0}, r"step_tol must be a finite number > 0; got 0.0"),
        ({"verbose": 1}, r"verbose must be a bool; got 1"),
    ],
)
def test_config_validates_itself(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RefineConfig(**kwargs)
    with pytest.raises(TypeError):
        RefineConfig("sqpmethod")  # keyword-only


def test_refine_elements_errors():
    structure = ae.CCF(2).fixed(a1=1.0)
    y = np.ones(20)
    with pytest.raises(ValueError, match=r"x0 must have shape \(4,\) for CCF"):
        refine_elements(structure, [1.0, 1.0, 1.0], y, None, 0.1)
    with pytest.raises(ValueError, match="x0 must be finite; got nan for element c0"):
        refine_elements(structure, [1.0, 1.0, np.nan, 0.0], y, None, 0.1)
    with pytest.raises(ValueError, match="x0: element a1 is fixed at 1.0"):
        refine_elements(structure, [1.0, 2.0, 1.0, 0.0], y, None, 0.1)
    with pytest.raises(ValueError, match="x0 is missing the element"):
        refine_elements(structure, {"a0": 1.0}, y, None, 0.1)
    with pytest.raises(ValueError, match="dt must be a positive finite number; got 0"):
        refine_elements(structure, [1.0, 1.0, 1.0, 0.0], y, None, 0)
    with pytest.raises(ValueError, match=r"u must have shape \(20,\) like y; got \(19,\)"):
        refine_elements(structure, [1.0, 1.0, 1.0, 0.0], y, np.ones(19), 0.1)
    with pytest.raises(ValueError, match=r"y must have shape \(steps,\); got \(2, 20\)"):
        refine_elements(structure, [1.0, 1.0, 1.0, 0.0], np.ones((2, 20)), None, 0.1)
    with pytest.raises(ValueError, match="y must not be all zero"):
        refine_elements(structure, [1.0, 1.0, 1.0, 0.0], np.zeros(20), None, 0.1)
    with pytest.raises(ValueError, match="y must be finite; got inf at sample 3"):
        refine_elements(structure, [1.0, 1.0, 1.0, 0.0], np.r_[1, 1, 1, np.inf], None, 0.1)
    with pytest.raises(ValueError, match=r"structure must be a Structure \(CCF.*got str"):
        refine_elements("CCF", [1.0], y, None, 0.1)
    with pytest.raises(ValueError, match="config must be a RefineConfig; got dict"):
        refine_elements(structure, [1.0, 1.0, 1.0, 0.0], y, None, 0.1, {"max_iter": 3})
    # a float32 start holds a fixed value to its precision: accepted and set exactly
    res = refine_elements(ae.CCF(2).fixed(a1=0.1), np.float32([1.0, 0.1, 1.0, 0.0]), y, None, 0.1)
    assert res.elements[1] == 0.1


@pytest.mark.filterwarnings("ignore:refine\\(estimate, y, u, dt\\) is deprecated")
def test_refine_errors():
    ident = _identifier()
    y = _record()
    est = ident.identify(y)
    batch = ident.identify(np.stack([y, y]))
    with pytest.raises(ValueError, match="estimate must be an Estimate; got dict"):
        refine({}, y, None, 0.05, structure=ident.structure)
    with pytest.raises(ValueError, match=r"y must have shape \(steps,\); got \(2, 60\)"):
        refine(est, np.stack([y, y]), None, 0.05, structure=ident.structure)
    with pytest.raises(ValueError, match=r"y must have shape \(steps,\) or \(2, steps\) like "
                                         r"the estimate; got \(3, 60\)"):
        refine(batch, np.stack([y, y, y]), None, 0.05, structure=ident.structure)
    with pytest.raises(ValueError, match="u must have 60 samples like y; got 59"):
        refine(est, y, np.ones(59), 0.05, structure=ident.structure)
    with pytest.raises(ValueError, match=r"y must not be all zero \(record 1 of 2\)"):
        refine(batch, np.stack([y, 0 * y]), None, 0.05, structure=ident.structure)
    with pytest.raises(ValueError, match="dt must be a positive finite number; got -1"):
        refine(est, y, None, -1, structure=ident.structure)
    with pytest.raises(ValueError, match="estimate.elements must hold every element of MCF"):
        refine(est, y, None, 0.05, structure=ae.MCF(real=0, pairs=1))
    with pytest.raises(ValueError, match=r"structure must be a Structure \(CCF.*got str"):
        refine(est, y, None, 0.05, structure="CCF(2)")


# -- records that start mid-motion (initial="fitted") --------------------------------------------
def test_free_response_basis_is_python_controls_response_from_an_initial_state():
    import control

    rng = np.random.default_rng(21)
    A, b, c, d = modal_system(3, rng, stable=False, feedthrough=True)
    steps, dt = 80, 0.02
    sA, sb, sc = casadi.SX.sym("A", 3, 3), casadi.SX.sym("b", 3), casadi.SX.sym("c", 3)
    sd, su = casadi.SX.sym("d"), casadi.SX.sym("u", steps)
    norm = max(np.abs(A).sum(0).max() * dt, np.abs(b).sum() * dt, 1.0)
    y, O = S.casadi_simulate(sA, sb, sc, sd, su, dt, squarings=S.squarings_for(norm), free=True)
    f = casadi.Function("sim", [sA, sb, sc, sd, su], [y, O])
    u = np.sin(np.arange(steps) * 0.3)
    x0 = rng.normal(size=3)
    got_y, got_O = (np.array(v) for v in f(A, b, c, d, u))
    sys = control.ss(A, b[:, None], c[None], d)
    t = np.arange(steps) * dt
    ref = control.forced_response(sys, t, u, X0=x0).outputs
    assert rel_max_error(got_y.ravel() + got_O @ x0, ref) <= 1e-10


@pytest.mark.parametrize("kind", ["prbs", "multisine", "mix"])
def test_refinement_of_a_mid_motion_window_recovers_the_system_and_its_state(kind):
    from aeid_struct.simulation import initial_state
    from aeid_struct.training import records

    structure = ae.CCF(2, descartes=True)
    rec = records(ae.LegFamily(subsystem="stable"), 3, steps=300, dt=0.01,
                  excitation_kind=kind, seed=4, warmup=150)
    for i in range(3):
        A, b, c = rec.systems.A[i], rec.systems.b[i], rec.systems.c[i]
        x_true = structure.elements_of(A, b, c).numpy()
        start = x_true * np.array([1.25, 0.7, 1.2, 1.0]) + np.array([0, 0, 0, 0.05])
        res = refine_elements(structure, start, rec.y[i], rec.u[i], 0.01, initial="fitted")
        assert res.success and res.loss <= 1e-20 < res.loss_start
        assert np.abs(res.elements - x_true).max() <= 1e-8 * np.abs(x_true).max()
        # and the state the decoder fits to the refined model is the window's true state
        sys = structure.assemble(torch.tensor(res.elements)[None])
        x0 = initial_state(sys.A.numpy(), sys.b.numpy(), sys.c.numpy(), sys.d.numpy(),
                           rec.u[i][None], rec.y[i][None], 0.01)[0]
        np.testing.assert_allclose(x0, rec.x0[i], rtol=1e-7, atol=1e-12)
        if np.abs(rec.x0[i]).max() > 1e-3 * np.abs(rec.y[i]).max():
            # from rest, the same start cannot explain the window's free response
            rest = refine_elements(structure, start, rec.y[i], rec.u[i], 0.01)
            assert rest.loss > 1e3 * max(res.loss, 1e-25)
    with pytest.raises(ValueError, match=r"initial must be 'rest' or 'fitted'; got 'zero'"):
        refine_elements(structure, start, rec.y[0], rec.u[0], 0.01, initial="zero")


def test_identify_refines_windows_of_a_running_leg():
    from aeid_struct.training import records

    ident = ae.load_pretrained("leg-stable-window")
    ident.head = None                  # the encoder alone, then the CasADi NLP
    rec = records(ae.LegFamily(subsystem="stable"), 4, steps=300, dt=0.01,
                  excitation_kind="mix", seed=9, warmup=200)
    enc = ident.identify(rec.y, rec.u)
    est = ident.identify(rec.y, rec.u, refine=True)
    assert est.refined and np.all(est.info["loss"] <= est.info["loss_start"])
    for p in ("k", "d", "m"):
        truth = rec.systems.params[p]
        assert np.abs(est.physical[p] / truth - 1).max() < 1e-7
        assert np.abs(enc.physical[p] / truth - 1).max() > 1e-3     # the encoder alone is not
    np.testing.assert_allclose(est.x0, rec.x0, rtol=1e-6, atol=1e-9)
    assert np.all(est.fit > 99.9999)
    # with a head, refine=True iterates the head instead: the same legs, exactly
    ident.head = Head(iterations=3, fixed={"c1": 0.0})
    sep = ident.identify(rec.y, rec.u, refine=True)
    assert sep.refined and sep.info["refine"] == "separable"
    for p in ("k", "d", "m"):
        assert np.abs(sep.physical[p] / rec.systems.params[p] - 1).max() < 1e-7
    np.testing.assert_allclose(sep.x0, rec.x0, rtol=1e-6, atol=1e-9)


def test_the_nlp_result_stays_in_refinement():
    # refine(Estimate) is the public call; the NLP's own record is no public result type
    import aeid_struct.refinement as refinement

    assert "RefineResult" not in refinement.__all__ and "refine_elements" not in refinement.__all__
    with pytest.warns(DeprecationWarning, match=r"refine\(Estimate\)"):
        assert refinement.refine_elements is refine_elements
    with pytest.warns(DeprecationWarning, match="private to refinement"):
        assert refinement.RefineResult is solve.RefineResult


# -- a companion form of widely spread coefficients ---------------------------------------------
def _quarter_windows():
    """Two windows of a quarter car cut mid-motion (2 % noise), its structure and the truth."""
    structure = ae.Physical(quarter_car(), bounds=QUARTER)
    family = ae.ParameterFamily(structure)
    rec = ae.data.records(family, 2, steps=400, dt=0.002, excitation_kind="prbs", seed=21,
                          noise=0.02, warmup=200)
    truth = np.stack([rec.systems.params[k] for k in structure.element_names], 1)
    return structure, rec, truth


def test_the_fitted_initial_state_is_projected_exactly_for_spread_scales():
    # the quarter car's CCF: free-response columns eight decades apart; the NLP's loss is the
    # python-control residual with lstsq's initial state (it was 7e-4 off: a ridge relative to
    # the unscaled normal equations' trace bent the small columns' projection)
    structure, rec, truth = _quarter_windows()
    for i in range(2):
        out = refine_elements(structure, truth[i], rec.y[i], rec.u[i], 0.002,
                              RefineConfig(max_iter=1), initial="fitted")
        oracle = _oracle_residual(structure, truth[i], [rec.y[i]], [rec.u[i]], 0.002)
        assert out.loss_start == pytest.approx(np.sum(oracle ** 2), rel=1e-7)


def test_sqpmethod_stops_at_the_round_off_floor_of_its_loss():
    # the gradient of this loss cannot reach tol (1e-12): sqpmethod ran all 100 iterations at
    # the optimum; now a chunk of iterations that lowers the loss by less than STALL ends it,
    # converged, at scipy's optimum of the python-control residual
    structure, rec, truth = _quarter_windows()
    lo, hi = (np.array([QUARTER[k][j] for k in structure.element_names]) for j in (0, 1))
    for i in range(2):
        ys, us = [rec.y[i]], [rec.u[i]]
        oracle = scipy.optimize.least_squares(
            lambda z, ys=ys, us=us: _oracle_residual(structure, z, ys, us, 0.002), truth[i],
            bounds=(lo, hi), x_scale=hi - lo, xtol=1e-12, ftol=1e-12, gtol=1e-12)
        out = refine_elements(structure, truth[i], rec.y[i], rec.u[i], 0.002, RefineConfig(),
                              initial="fitted")
        assert out.success and out.iterations < 100, out.status
        assert out.loss <= 2 * oracle.cost * (1 + 1e-7)
        np.testing.assert_allclose(out.elements, oracle.x, rtol=1e-5)
        capped = refine_elements(structure, truth[i], rec.y[i], rec.u[i], 0.002,
                                 RefineConfig(max_iter=13), initial="fitted")
        assert capped.iterations <= 13
