"""Baselines: exact discrete -> continuous conversion, n4sid, output-error least squares, failure.

Oracles: ``aeid_struct.discretise`` / ``simulate`` (the decoder), ``scipy.signal.cont2discrete``
(FOH and ZOH), discrete-time simulation by ``scipy.signal.lfilter``-free plain recursion, the
robot leg's known (k, d, m), and central finite differences for the sensitivity Jacobian.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.signal
from helpers import rel_max_error
from problems import modal_system

import aeid_struct as ae
from aeid_struct import baselines as bl
from aeid_struct.baselines.models import free_indices, model_of
from aeid_struct.baselines.output_error import Problem
from aeid_struct.identification import Estimate, Provenance
from aeid_struct.records import Record, RecordBatch
from aeid_struct.simulation import simulate_outputs
from aeid_struct.training import LegFamily
from symbolic import leg

#: The study's record grids (aeid_struct.study.RECORDS).
STABLE = (0.01, 300)
UNSTABLE = (0.005, 100)
SCENARIO = {"k": 24.23, "d": 2.24, "m": 1.01}


def _leg(subsystem, k=24.23, d=2.24, m=1.01):
    """The leg subsystem's CCF ``(A, b, c)``, its grid and its unit-step record."""
    s = LegFamily(subsystem=subsystem).systems(k, d, m)
    A, b, c = s.A[0], s.b[0], s.c[0]
    dt, steps = STABLE if subsystem == "stable" else UNSTABLE
    return A, b, c, dt, ae.simulate(A, b, c, 0.0, np.ones(steps), dt)


def _prbs(steps, rng, hold=5):
    return np.repeat(rng.choice([-1.0, 1.0], size=steps // hold + 1), hold)[:steps]


def _pole_error(A_hat, A):
    """max |p_hat - p| / max |p| over the sorted poles (complex: rel_max_error is real-only)."""
    p_hat, p = (np.sort_complex(np.linalg.eigvals(M)) for M in (A_hat, A))
    return float(np.max(np.abs(p_hat - p)) / np.max(np.abs(p)))


# ---------------------------------------------------------------------------------------------
# The numpy FOH kernel least squares uses (aeid_struct.simulation.simulate_outputs)
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["step", "prbs", "random", "ramp"])
def test_numpy_foh_matches_the_decoder(kind):
    rng = np.random.default_rng(1)
    systems = [_leg("stable")[:4], _leg("unstable")[:4], (*modal_system(3, rng)[:3], 0.01)]
    for A, b, c, dt in systems:
        steps = 300
        u = {"step": np.full(steps, 2.5), "prbs": _prbs(steps, rng),
             "random": rng.normal(size=steps), "ramp": 0.3 + np.arange(steps) * dt}[kind]
        C = np.stack([c, rng.normal(size=c.shape[0])])
        d = np.array([0.0, 0.7])
        Y = simulate_outputs(A, b, C, d, u, dt)
        for i in range(2):
            ref = ae.simulate(A, b, C[i], d[i], u, dt)
            assert rel_max_error(Y[i], ref) < 1e-12


# ---------------------------------------------------------------------------------------------
# Discrete -> continuous
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_to_continuous_inverts_discretise_exactly(n):
    rng = np.random.default_rng(n)
    for stable in (True, False):
        A, b, c, d = modal_system(n, rng, stable=stable, feedthrough=True)
        dt = 0.02
        disc = ae.discretise(A, b, dt)
        # The FOH model in the shifted state (decoder module docstring).
        Bd = disc.gamma1 - disc.gamma2 + disc.Phi @ disc.gamma2
        Dd = d + c @ disc.gamma2
        back = bl.to_continuous(disc.Phi, Bd, c, Dd, dt)
        assert rel_max_error(back.A, A) < 1e-10
        assert rel_max_error(back.b, b) < 1e-10
        np.testing.assert_allclose(back.c, c, rtol=0, atol=0)
        assert back.d == pytest.approx(d, rel=1e-10, abs=1e-12)
        assert back.A.dtype == np.float64
        # ZOH: Phi and gamma1 with the unchanged c, d.
        zoh = bl.to_continuous(disc.Phi, disc.gamma1, c, d, dt, hold="zoh")
        assert rel_max_error(zoh.A, A) < 1e-10 and rel_max_error(zoh.b, b) < 1e-10


@pytest.mark.parametrize("method", ["foh", "zoh"])
def test_to_continuous_inverts_scipy_cont2discrete(method):
    rng = np.random.default_rng(7)
    A, b, c, d = modal_system(3, rng, feedthrough=True)
    dt = 0.05
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((A, b[:, None], c[None], [[d]]), dt,
                                                   method=method)
    back = bl.to_continuous(Ad, Bd, Cd, Dd, dt, hold=method)
    assert rel_max_error(back.A, A) < 1e-10
    assert rel_max_error(back.b, b) < 1e-10
    assert back.d == pytest.approx(d, rel=1e-10)


def test_negative_real_discrete_pole_has_no_real_logarithm():
    Phi = np.diag([0.9, -0.5])
    with pytest.raises(bl.NoRealLogarithm, match=r"negative real pole z = -0\.5"):
        bl.to_continuous(Phi, [1.0, 1.0], [1.0, 1.0], 0.0, 0.1)
    with pytest.raises(ValueError, match="at the origin"):
        bl.to_continuous(np.diag([0.9, 0.0]), [1.0, 1.0], [1.0, 1.0], 0.0, 0.1)


# ---------------------------------------------------------------------------------------------
# n4sid
# ---------------------------------------------------------------------------------------------
def test_n4sid_recovers_the_stable_leg_from_a_step_exactly():
    A, b, c, dt, y = _leg("stable")
    est = bl.n4sid(y, None, dt, order=2, structure=ae.CCF(2, descartes=True),
                   inverse=leg.stable_inverse())
    assert not est.info["failed"] and not bl.failed(est, truth_y=y)
    assert est.info["channels"] == ("zoh",)  # a step is the jump to u_0 at t = 0
    assert _pole_error(est.A, A) < 1e-6
    assert rel_max_error(est.y_hat, y) < 1e-6
    for name, value in SCENARIO.items():
        assert est.physical[name] == pytest.approx(value, rel=1e-6)
    # the CCF realisation of the structure: elements rebuild A
    assert est.A[1, 0] == -est.elements["a0"] and est.A[1, 1] == -est.elements["a1"]


def test_n4sid_default_block_rows_tolerate_noise():
    """The default Hankel size (20 block rows) is what keeps n4sid usable on noisy steps; with
    2 order block rows the same record fails (module docstring)."""
    A, b, c, dt, y = _leg("stable")
    noisy = y + 0.01 * np.abs(y).max() * np.random.default_rng(11).normal(size=y.shape[0])
    est = bl.n4sid(noisy, None, dt, order=2)
    assert est.info["block_rows"] == 20 and est.info["pre_zeros"] == 40
    assert not bl.failed(est, truth_y=y, step_tol=0.02)
    small = bl.n4sid(noisy, None, dt, order=2, block_rows=4)
    assert bl.failure(small, truth_y=y, step_tol=0.02).startswith("step error")


def test_n4sid_needs_the_zoh_channel_for_a_step():
    """The FOH-only reading of a zero-padded step is wrong (documented in the module): the
    recovered poles are right but the gain is not."""
    A, b, c, dt, y = _leg("stable")
    good = bl.n4sid(y, None, dt, order=2)
    assert rel_max_error(good.y_hat, y) < 1e-6
    # pre_zeros=0: one FOH channel; a constant input excites nothing -> no exact model
    plain = bl.n4sid(y, None, dt, order=2, pre_zeros=0)
    assert plain.info["channels"] == ("foh",)
    assert plain.info["failed"] or rel_max_error(plain.y_hat, y) > 1e-3


def test_n4sid_recovers_the_unstable_leg():
    A, b, c, dt, y = _leg("unstable")
    est = bl.n4sid(y, np.ones_like(y), dt, order=2, inverse=leg.unstable_inverse())
    assert not bl.failed(est, truth_y=y)
    assert _pole_error(est.A, A) < 1e-6
    assert est.physical["k"] == pytest.approx(24.23, rel=1e-6)
    assert est.physical["m"] == pytest.approx(1.01, rel=1e-6)


@pytest.mark.parametrize("pre_zeros", [None, 0])
def test_n4sid_recovers_a_third_order_system_from_prbs(pre_zeros):
    rng = np.random.default_rng(3)
    A, b, c, _ = modal_system(3, rng)
    dt = 0.01
    u = _prbs(300, rng)  # starts at +-1: a jump at t = 0 and an FOH part
    y = ae.simulate(A, b, c, 0.0, u, dt)
    est = bl.n4sid(y, u, dt, order=3, pre_zeros=pre_zeros)
    assert not est.info["failed"]
    assert est.info["channels"] == (("zoh", "foh") if pre_zeros is None else ("foh",))
    assert _pole_error(est.A, A) < 1e-6
    step = ae.simulate(A, b, c, 0.0, np.ones(300), dt)
    assert rel_max_error(ae.simulate(est.A, est.b, est.c, est.d, np.ones(300), dt), step) < 1e-6
    assert est.d == 0.0 and est.elements == {}


def test_n4sid_estimates_feedthrough():
    rng = np.random.default_rng(4)
    A, b, c, d = modal_system(2, rng, feedthrough=True)
    u = rng.normal(size=200)
    y = ae.simulate(A, b, c, d, u, 0.02)
    est = bl.n4sid(y, u, 0.02, order=2, structure=ae.CCF(2, feedthrough=True))
    assert est.d == pytest.approx(d, rel=1e-6)
    assert est.elements["d"] == pytest.approx(d, rel=1e-6)


def test_n4sid_fails_cleanly_on_a_negative_real_discrete_pole():
    # A discrete system with poles 0.9 and -0.5 in a random basis, from rest, PRBS input.
    rng = np.random.default_rng(5)
    T = rng.normal(size=(2, 2)) + 2 * np.eye(2)
    Phi = T @ np.diag([0.9, -0.5]) @ np.linalg.inv(T)
    B, C = rng.normal(size=2), rng.normal(size=2)
    u = _prbs(200, rng)
    x, y = np.zeros(2), np.empty(200)
    for k in range(200):
        y[k] = C @ x
        x = Phi @ x + B * u[k]
    est = bl.n4sid(y, u, 0.1, order=2)
    assert est.info["failed"]
    assert "negative real pole" in est.info["reason"]
    assert est.A.dtype == np.float64 and np.all(np.isnan(est.A))
    assert bl.failed(est) and "negative real" in bl.failure(est)


def test_n4sid_model_outside_the_structure_is_a_failure_with_the_model():
    A, b, c, dt, y = _leg("stable")
    est = bl.n4sid(y, None, dt, order=2, structure=ae.CCF(2).fixed(c1=0.5))
    assert est.info["failed"] and "outside the structure" in est.info["reason"]
    assert np.all(np.isfinite(est.A)) and est.elements == {}
    assert bl.failed(est)


# ---------------------------------------------------------------------------------------------
# Least squares
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("jac", "solver"), [("exact", "auto"), ("exact", "trf"),
                                             ("2-point", "auto")])
def test_least_squares_recovers_the_stable_leg_from_the_generic_start(jac, solver):
    A, b, c, dt, y = _leg("stable")
    structure = ae.CCF(2, descartes=True)
    est = bl.least_squares(y, None, dt, structure=structure, inverse=leg.stable_inverse(),
                           jac=jac, solver=solver)
    assert est.info["start"]["a0"] == 1.0 and est.info["start"]["a1"] == 2.0  # poles at -1
    assert est.info["solver"] == ("lm" if solver == "auto" else "trf")
    assert not est.info["failed"]
    assert ae.metrics.step_error(y, est.y_hat)[0] < 1e-8
    for name, value in SCENARIO.items():
        assert abs(est.physical[name] / value - 1) * 100 < 1e-6  # percent
    assert not bl.failed(est, structure=structure, truth_y=y)


@pytest.mark.parametrize("structure", [ae.CCF(2), ae.CCF(2).fixed(a1=0.0, c1=0.0)],
                         ids=["free", "fixed"])
def test_least_squares_recovers_the_unstable_leg_from_the_generic_start(structure):
    A, b, c, dt, y = _leg("unstable", k=20.0, m=1.5)  # pole +12.4 rad/s, growth e^6
    est = bl.least_squares(y, None, dt, structure=structure, inverse=leg.unstable_inverse())
    assert est.info["start"]["a0"] == 1.0  # the generic (stable) start, not the truth
    assert ae.metrics.step_error(y, est.y_hat)[0] < 1e-8
    assert abs(est.physical["k"] / 20.0 - 1) * 100 < 1e-6
    assert abs(est.physical["m"] / 1.5 - 1) * 100 < 1e-6
    if structure.fixed_values:
        assert est.elements["a1"] == 0.0 and est.elements["c1"] == 0.0  # exactly
        assert est.A[1, 1] == 0.0 and est.c[1] == 0.0


def test_fixed_elements_stay_fixed_at_a_wrong_value():
    A, b, c, dt, y = _leg("stable")
    structure = ae.CCF(2, descartes=True).fixed(a1=1.0)  # the truth has a1 = 2.218
    est = bl.least_squares(y, None, dt, structure=structure)
    assert est.elements["a1"] == 1.0 and est.A[1, 1] == -1.0
    assert est.info["start"]["a1"] == 1.0
    assert ae.metrics.step_error(y, est.y_hat)[0] > 1e-3  # the best fit is not exact
    with pytest.raises(ValueError, match=r"start\['a1'\] = 2.0 but a1 is fixed at 1.0"):
        bl.least_squares(y, None, dt, structure=structure, start={"a1": 2.0})


def test_least_squares_with_mcf_and_a_random_input():
    rng = np.random.default_rng(8)
    A, b, c, dt, _ = _leg("stable")
    u = _prbs(300, rng)
    y = ae.simulate(A, b, c, 0.0, u, dt)
    est = bl.least_squares(y, u, dt, structure=ae.MCF(pairs=1))
    assert rel_max_error(est.y_hat, y) < 1e-8
    assert _pole_error(est.A, A) < 1e-8
    assert est.info["solver"].startswith("lm")  # the bounds are inactive at the solution


def test_least_squares_with_a_physical_structure_respects_the_bounds():
    A, b, c, dt, y = _leg("stable")
    structure = ae.Physical(leg.stable_map(), bounds={"k": (20, 25), "d": (2, 5),
                                                      "m": (0.5, 1.5)})
    est = bl.least_squares(y, None, dt, structure=structure)
    assert est.info["start"] == {"k": 22.5, "d": 3.5, "m": 1.0}  # midpoints
    for name, value in SCENARIO.items():
        assert est.physical[name] == pytest.approx(value, rel=1e-8)
    # the truth outside the bounds: the estimate stays inside them
    tight = ae.Physical(leg.stable_map(), bounds={"k": (20, 22), "d": (2, 5), "m": (0.5, 1.5)})
    est = bl.least_squares(y, None, dt, structure=tight)
    assert 20 <= est.elements["k"] <= 22 and est.info["solver"] in ("trf", "lm+trf")


@pytest.mark.parametrize("which", ["ccf", "physical"])
def test_sensitivity_jacobian_matches_finite_differences(which):
    rng = np.random.default_rng(9)
    A, b, c, dt, _ = _leg("stable")
    u = rng.normal(size=120)
    y = ae.simulate(A, b, c, 0.0, u, dt)
    if which == "ccf":
        structure, x = ae.CCF(2, feedthrough=True), np.array([20.0, 3.0, 1.2, 0.1, 0.05])
    else:
        structure = ae.Physical(leg.stable_map(), bounds={"k": (20, 25), "d": (2, 5),
                                                          "m": (0.5, 1.5)})
        x = np.array([22.0, 3.0, 0.9])
    free = free_indices(structure)
    problem = Problem(model_of(structure, free), x, y, u, dt, exact=True)
    J = problem.jacobian(x[free])
    h = 1e-6 * np.maximum(1.0, np.abs(x[free]))
    for j in range(len(free)):
        e = np.zeros(len(free))
        e[j] = h[j]
        fd = (problem.residual(x[free] + e) - problem.residual(x[free] - e)) / (2 * h[j])
        assert rel_max_error(J[:, j], fd) < 1e-6


def test_generic_start_is_exact_when_the_poles_are_right():
    # A system with poles at -1, -1: the linear least squares for c is then exact.
    A = np.array([[0.0, 1.0], [-1.0, -2.0]])
    b, c = np.array([0.0, 1.0]), np.array([3.0, -0.5])
    y = ae.simulate(A, b, c, 0.0, np.ones(200), 0.05)
    start = bl.generic_start(ae.CCF(2), y, None, 0.05)
    assert start["a0"] == 1.0 and start["a1"] == 2.0
    assert start["c0"] == pytest.approx(3.0, rel=1e-10)
    assert start["c1"] == pytest.approx(-0.5, rel=1e-8)
    mcf = bl.generic_start(ae.MCF(real=2, pairs=1), y, None, 0.05)
    assert (mcf["lambda0"], mcf["lambda1"], mcf["delta0"], mcf["omega0"]) == (-1, -2, -1, 1)


# ---------------------------------------------------------------------------------------------
# Failure rule and arguments
# ---------------------------------------------------------------------------------------------
def _estimate(A, b, c, d, y, dt, **info):
    return Estimate(A=np.asarray(A, float), b=np.asarray(b, float), c=np.asarray(c, float),
                    d=d, elements={}, record=Record(y, np.ones_like(y), dt), info=info,
                    provenance=Provenance(inverse=leg.stable_inverse()))


def test_failure_rule():
    A, b, c, dt, y = _leg("stable")
    assert bl.failure(_estimate(A, b, c, 0.0, y, dt), truth_y=y) == ""
    # step error above 0.05: a gain 20 % off
    why = bl.failure(_estimate(A, b, 1.2 * c, 0.0, y, dt), truth_y=y)
    assert why.startswith("step error")
    # non-positive physical parameter: c0 < 0 -> m < 0
    assert "physical parameter k" in bl.failure(_estimate(A, b, -c, 0.0, y, dt))
    assert bl.failure(_estimate(np.full((2, 2), np.nan), b, c, 0.0, y, dt)) == "non-finite model"
    assert bl.failure(_estimate(A, b, c, 0.0, y, dt, failed=True, reason="boom")) == "boom"
    # a structure the model violates: Descartes with an unstable real pole
    unstable = np.array([[0.0, 1.0], [4.0, 0.0]])
    why = bl.failure(_estimate(unstable, b, c, 0.0, y, dt), structure=ae.CCF(2, descartes=True))
    assert why.startswith("outside the structure")


def test_failed_on_a_batched_estimate():
    A, b, c, dt, y = _leg("stable")
    est = Estimate(A=np.stack([A, A]), b=np.stack([b, b]), c=np.stack([c, 2 * c]),
                   d=np.zeros(2), elements={}, record=RecordBatch.of(
                       np.stack([y, y]), np.ones((2, y.shape[0])), dt, batched=True))
    np.testing.assert_array_equal(bl.failed(est, truth_y=np.stack([y, y])), [False, True])


def test_invalid_arguments_raise():
    A, b, c, dt, y = _leg("stable")
    cases = [
        (lambda: bl.n4sid(y, None, dt, order=0), r"order must be an integer >= 1; got 0"),
        (lambda: bl.n4sid(y, None, dt, order=2, block_rows=2), r"block_rows must be > order"),
        (lambda: bl.n4sid(y, None, dt, order=2, pre_zeros=-1), r"pre_zeros must be an integer"),
        (lambda: bl.n4sid(np.stack([y, y]), None, dt, order=2), r"y must have shape \(steps,\)"),
        (lambda: bl.n4sid(y[:10], None, dt, order=2), r"y must have at least"),
        (lambda: bl.n4sid(y, np.ones(5), dt, order=2), r"u must have the shape of y"),
        (lambda: bl.n4sid(np.where(np.arange(300) == 7, np.nan, y), None, dt, order=2),
         r"y must be finite; got nan at sample 7"),
        (lambda: bl.n4sid(y, None, -1.0, order=2), r"dt must be a positive finite number"),
        (lambda: bl.n4sid(y, np.zeros(300), dt, order=2), r"u must not be all zero"),
        (lambda: bl.n4sid(y, None, dt, order=2, structure=ae.MCF(pairs=1),
                          inverse=leg.stable_inverse()), r"structure must be a CCF"),
        (lambda: bl.n4sid(y, None, dt, order=3, structure=ae.CCF(2)),
         r"structure must have order 3"),
        (lambda: bl.n4sid(y, None, dt, order=2, structure=ae.CCF(2), feedthrough=True),
         r"feedthrough=True but structure"),
        (lambda: bl.least_squares(y, None, dt, structure="CCF"), r"structure must be a CCF"),
        (lambda: bl.least_squares(y, None, dt, structure=ae.CCF(2), jac="bfgs"),
         r"jac must be one of"),
        (lambda: bl.least_squares(y, None, dt, structure=ae.CCF(2), solver="lm"),
         r"solver must be one of"),
        (lambda: bl.least_squares(y, None, dt, structure=ae.CCF(2), start={"a9": 1.0}),
         r"start has unknown element 'a9'"),
        (lambda: bl.least_squares(y, None, dt, structure=ae.CCF(2, descartes=True),
                                  start={"a0": -1.0}), r"start\['a0'\] = -1.0 is outside"),
        (lambda: bl.least_squares(y, None, dt, structure=ae.CCF(2), start={"a0": np.inf}),
         r"start\['a0'\] must be a finite number"),
        (lambda: bl.to_continuous(np.eye(2), np.ones(3), np.ones(2), 0.0, dt),
         r"B must have shape \(2,\) or \(2, 1\)"),
        (lambda: bl.to_continuous(np.eye(2), np.ones(2), np.ones(2), 0.0, dt, hold="tustin"),
         r"hold must be one of"),
        (lambda: bl.failure(_estimate(A, b, c, 0.0, y, dt), truth_y=np.ones(3)[None, None]),
         r"truth_y must be finite with shape"),
    ]
    for call, match in cases:
        with pytest.raises(ValueError, match=match):
            call()


def test_casadi_cold_recovers_the_stable_leg_from_the_generic_start():
    A, b, c, dt, y = _leg("stable")
    est = bl.casadi_cold(y, None, dt, structure=ae.CCF(2, descartes=True),
                         inverse=leg.stable_inverse())
    assert est.info["start"]["a0"] == 1.0 and est.info["method"] == "casadi_cold"
    assert not bl.failed(est, truth_y=y)
    for name, value in SCENARIO.items():
        assert est.physical[name] == pytest.approx(value, rel=1e-6)


def test_classical_stacks_per_record_estimates_like_an_identifier():
    from functools import partial

    from aeid_struct.training import records

    rec = records(LegFamily(subsystem="unstable"), 3, steps=UNSTABLE[1], dt=UNSTABLE[0], seed=4)
    method = partial(bl.least_squares, structure=ae.CCF(2).fixed(a1=0.0),
                     inverse=leg.unstable_inverse())
    runner = bl.Classical(method, UNSTABLE[0], UNSTABLE[1])
    est = runner.identify(rec.y)
    assert est.batched and est.A.shape == (3, 2, 2) and est.info["failed"].tolist() == [False] * 3
    for i in range(3):
        one = method(rec.y[i], np.ones(UNSTABLE[1]), UNSTABLE[0])
        np.testing.assert_array_equal(est.A[i], one.A)
        assert est.elements["c0"][i] == one.elements["c0"]
    # noise-free records: the true legs come back through the inverse
    for name in ("k", "m"):
        np.testing.assert_allclose(est.physical[name], rec.systems.params[name], rtol=1e-6)
    single = runner.identify(rec.y[1])
    assert not single.batched and single.physical["k"] == pytest.approx(est.physical["k"][1])
    # a failed record is a NaN row, not an error
    bad = bl.Classical(lambda y, u, dt: bl.n4sid(-np.cumsum(np.ones_like(y)) * (-1) ** np.arange(
        y.size), u, dt, order=2), UNSTABLE[0], UNSTABLE[1]).identify(rec.y[:1])
    assert bad.info["failed"].tolist() == [True] and np.isnan(bad.A).all()
    with pytest.raises(ValueError, match=r"y must have shape \(100,\) or \(batch, 100\)"):
        runner.identify(rec.y[:, :50])
    with pytest.raises(ValueError, match=r"method must be callable"):
        bl.Classical("least_squares", 0.01, 100)



# ---------------------------------------------------------------------------------------------
# Records not at rest (issue 14 deliver 6): free initial state, offset, known delay
# ---------------------------------------------------------------------------------------------
#: 3rd order with zeros: G(s) = (2 s^2 + s + 6) / ((s + 0.5)(s^2 + 2 s + 10)).
_DEN = np.real(np.poly([-0.5, -1 + 3j, -1 - 3j]))
_NUM = np.array([2.0, 1.0, 6.0])
_X0 = np.array([1.0, -2.0, 0.5])


def _third_order():
    """The system in bottom-row CCF ``(A, b, c)``."""
    A = np.eye(3, k=1)
    A[-1] = -_DEN[1:][::-1]
    return A, np.eye(3)[-1], _NUM[::-1].copy()


def _moving_record(noise=0.0, seed=0, steps=1000, dt=0.05, delay=None, offset=1.7):
    """A PRBS record of the 3rd-order system that starts mid-motion (``x0 = _X0``), with an
    output offset, an input level 0.3 and ``noise`` (a fraction of std y)."""
    rng = np.random.default_rng(seed)
    A, b, c = _third_order()
    u = _prbs(steps, rng, hold=10) + 0.3
    D = delay or 0
    y = np.empty(steps)
    y[D:] = ae.simulate(A, b, c, 0.0, u[: steps - D], dt, x0=_X0)
    y[:D] = rng.normal(size=D)                       # answers inputs before the record
    y += offset + noise * np.std(y) * rng.normal(size=steps)
    return ae.Record(y, u, dt, delay=delay)


def _validation_fit(est, record):
    """MATLAB's compare: the NRMSE fit on ``record`` with x0 and the offset fitted."""
    from aeid_struct.simulation import fit_initial

    return fit_initial(est.A, est.b, est.c, est.d, record.y, record.u, record.dt,
                       delay=record.delay or 0).fit


def _transfer_function(A, b, c, d=0.0):
    """(num, den) of python-control's ss2tf, den monic."""
    import control

    tf = control.ss2tf(A, b[:, None], c[None], d)
    num, den = np.asarray(tf.num[0][0], float), np.asarray(tf.den[0][0], float)
    return np.trim_zeros(num / den[0], "f"), den / den[0]


def test_record_n4sid_fits_a_record_not_at_rest_where_zero_padding_fails():
    record = _moving_record()
    new = bl.n4sid(record, order=3)
    old = bl.n4sid(record.y, record.u, record.dt, order=3)           # pads zeros: assumes rest
    assert not new.info["failed"] and new.info["delay"] == 0 and new.initial == "fitted"
    assert new.info["fit"] > 99.0                     # measured 100.00 (noise-free)
    assert old.fit < 0.0                              # measured -196
    assert new.fit == pytest.approx(new.info["fit"], abs=1e-6)        # Estimate.fit agrees
    assert new.info["y_offset"] == pytest.approx(1.7, abs=1e-6)
    assert _pole_error(new.A, _third_order()[0]) < 1e-6
    # the fitted x0 reproduces the record: simulate from it, add the offset
    y_hat = ae.simulate(new.A, new.b, new.c, new.d, record.u, record.dt, x0=new.info["x0"])
    np.testing.assert_allclose(y_hat + new.info["y_offset"], record.y, atol=1e-6)


def test_record_n4sid_constant_channel_beats_mean_removal():
    # the mean of y is not the offset plus the stationary response to the mean input (the
    # transient has a mean of its own), so mean removal leaves a bias; a constant channel does not
    record = _moving_record()
    channel = bl.n4sid(record, order=3, offset="channel").info["fit"]
    mean = bl.n4sid(record, order=3, offset="mean").info["fit"]
    assert channel > 99.99 and mean < 95.0            # measured 100.00 and 90.1


def test_record_least_squares_recovers_the_transfer_function():
    record = _moving_record()
    est = bl.least_squares(record, order=3)
    assert not est.info["failed"] and est.info["start"] == "n4sid"
    num, den = _transfer_function(est.A, est.b, est.c)
    num_true, den_true = _transfer_function(*_third_order())
    assert rel_max_error(den, den_true) < 1e-6
    assert rel_max_error(num, num_true) < 1e-6
    np.testing.assert_allclose(est.info["x0"], _X0, rtol=1e-6, atol=1e-6)   # the same CCF
    assert est.info["y_offset"] == pytest.approx(1.7, rel=1e-6)
    assert est.info["fit"] > 99.999 and est.fit == pytest.approx(est.info["fit"], abs=1e-6)
    assert sorted(est.elements) == ["a0", "a1", "a2", "c0", "c1", "c2"]
    np.testing.assert_allclose([est.elements[f"c{i}"] for i in range(3)], _NUM[::-1], rtol=1e-6)


def test_record_least_squares_validates_at_least_as_well_as_n4sid_with_noise():
    estimation, validation = _moving_record(noise=0.02, seed=2).split()
    ls = _validation_fit(bl.least_squares(estimation, order=3), validation)
    sub = _validation_fit(bl.n4sid(estimation, order=3), validation)
    assert ls >= sub > 90.0                           # measured 95.79 and 95.46


def test_record_baselines_apply_a_known_delay():
    record = _moving_record(delay=4)
    for method in (bl.n4sid, bl.least_squares):
        est = method(record, order=3)
        assert est.info["delay"] == 4 and est.info["fit"] > 99.99
        assert est.y.shape == (996,)                  # y[4:] fitted against u[:996]
        assert _pole_error(est.A, _third_order()[0]) < 1e-6


def test_record_least_squares_starts_from_arx_where_n4sid_cannot_run():
    # 30 samples are too few for n4sid's Hankel matrices at order 2 (39 needed)
    A, b, c = np.array([[0.0, 1.0], [-4.0, -0.8]]), np.array([0.0, 1.0]), np.array([3.0, 0.5])
    u = _prbs(30, np.random.default_rng(3), hold=3)
    y = ae.simulate(A, b, c, 0.0, u, 0.1, x0=np.array([0.5, -1.0])) - 0.4
    record = ae.Record(y, u, 0.1)
    with pytest.raises(ValueError, match="record must have at least 39 samples"):
        bl.n4sid(record, order=2)
    est = bl.least_squares(record, order=2)
    assert est.info["start"] == "arx" and est.info["fit"] > 99.999
    assert _pole_error(est.A, A) < 1e-6


def test_record_forms_reject_array_arguments():
    record = _moving_record(steps=200)
    cases = [
        (lambda: bl.n4sid(record, record.u, order=3), r"u must not be given with a Record"),
        (lambda: bl.n4sid(record, dt=0.1, order=3), r"dt must not be given with a Record"),
        (lambda: bl.n4sid(record, order=3, pre_zeros=0), r"pre_zeros must not be given"),
        (lambda: bl.n4sid(record, order=0), r"order must be an integer >= 1; got 0"),
        (lambda: bl.n4sid(record, order=3, offset="median"),
         r"offset must be one of \('mean', 'channel'\); got 'median'"),
        (lambda: bl.n4sid(record, order=3, block_rows=3), r"block_rows must be > order = 3"),
        (lambda: bl.least_squares(record), r"order must be given with a Record"),
        (lambda: bl.least_squares(record, order=3, structure=ae.CCF(3)),
         r"structure must not be given with a Record"),
        (lambda: bl.least_squares(record, order=1.5), r"order must be an integer >= 1"),
        (lambda: bl.least_squares(record.y, record.u, record.dt, structure=ae.CCF(3), order=3),
         r"order is for a Record"),
        (lambda: bl.least_squares(ae.Record(record.y[:11], record.u[:11]), order=3),
         r"record must have at least 12 samples after the delay"),
    ]
    for call, match in cases:
        with pytest.raises(ValueError, match=match):
            call()


def _mid_motion_record(seed=3, steps=400, dt=0.05):
    """A second-order record that starts mid-motion, with an output offset."""
    rng = np.random.default_rng(seed)
    u = _prbs(steps, rng)
    A = np.array([[0.0, 1.0], [-4.0, -1.2]])
    b, c = np.array([0.0, 1.0]), np.array([[3.0, 0.5]])
    x0 = np.array([0.8, -0.3])
    y = simulate_outputs(A, b, c, np.zeros(1), u, dt)[0]
    Phi = scipy.linalg.expm(A * dt * np.arange(steps)[:, None, None])
    y = y + (c @ Phi @ x0)[:, 0] + 0.4 + 0.002 * rng.standard_normal(steps)
    return y, u, dt


@pytest.mark.parametrize("method", ["least_squares", "n4sid"])
def test_the_model_follows_initial_not_the_form_of_the_record(method):
    """``initial`` chooses the model: arrays with initial="fitted" are the Record's fit, a
    Record with initial="rest" is the arrays' fit, number for number."""
    fit = getattr(bl, method)
    y, u, dt = _mid_motion_record()
    as_record = fit(Record(y, u, dt), order=2)
    as_arrays = fit(y, u, dt, order=2, initial="fitted")
    np.testing.assert_array_equal(as_arrays.A, as_record.A)
    np.testing.assert_array_equal(as_arrays.c, as_record.c)
    assert as_record.fit > 99.0 and as_record.offset == pytest.approx(0.4, abs=0.02)
    rest = dict(structure=ae.CCF(2)) if method == "least_squares" else dict(order=2)
    from_arrays = fit(y, u, dt, **rest)
    from_record = fit(Record(y, u, dt), **rest, initial="rest")
    np.testing.assert_array_equal(from_record.A, from_arrays.A)
    np.testing.assert_array_equal(from_record.c, from_arrays.c)
    # from rest the mid-motion record is fitted worse: a different model, not a relabelling
    assert not np.allclose(from_arrays.A, as_record.A, rtol=1e-3)


@pytest.mark.parametrize("kwargs, match", [
    (dict(initial="moving"), "initial must be one of"),
    (dict(initial="fitted", structure=ae.CCF(2)), "structure must not be given with"),
])
def test_initial_is_checked_by_name(kwargs, match):
    y, u, dt = _mid_motion_record()
    with pytest.raises(ValueError, match=match):
        bl.least_squares(y, u, dt, order=2, **kwargs)


def test_a_known_delay_is_not_fitted_from_rest():
    y, u, dt = _mid_motion_record()
    with pytest.raises(ValueError, match="known input delay of 2"):
        bl.n4sid(Record(y, u, dt, delay=2), order=2, initial="rest")
