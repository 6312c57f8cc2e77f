"""Tests for ``aeid_struct/identification/physical_head.py``: the one pass's head in a physical
structure's parameters; and ``physical_errors.py``, the standard errors at its optimum.

Oracles: the closed-form CCF of a lever-driven mass (``a0 = k/m, a1 = d/m, c0 = r/m``, ``c1 =
0``), the true parameters of noise-free records, and scipy's output-error least squares in the
same structure (``baselines.least_squares``, started at the truth) on noisy ones.
"""

from __future__ import annotations

import numpy as np
import pytest

import aeid_struct as ae
from aeid_struct import baselines
from aeid_struct.identification import Head
from aeid_struct.identification.physical_head import physical_head
from symbolic import mechanisms

BOX = {"m": (0.5, 2.0), "k": (10.0, 50.0), "d": (0.5, 3.0)}
NAMES = ("m", "k", "d")


@pytest.fixture(scope="module")
def lever():
    """A briefly trained lever identifier (r known) with a five-iteration head."""
    structure = ae.Physical(mechanisms.lever(), bounds=BOX, known={"r": 1.5})
    family = ae.ParameterFamily(structure)
    ident = ae.train(structure, family, ae.TrainConfig(
        steps=200, dt=0.02, epochs=3, count=600, excitation="prbs", progress=False))
    ident.head = Head(iterations=5)
    return ident, family


def test_the_pattern_holds_the_maps_constant_coefficients():
    structure = ae.Physical(mechanisms.lever(), bounds=BOX, known={"r": 1.5})
    head = physical_head(structure, initial=False)
    # G = r / (m s^2 + d s + k): a0, a1 and c0 move with the parameters, c1 = d = 0 do not
    assert head.pattern.a == (None, None) and head.pattern.c == (None, 0.0)
    assert head.pattern.d == 0.0 and head.square
    assert physical_head(structure, initial=False) is head          # built once


def test_the_coefficient_inverse_recovers_the_parameters():
    structure = ae.Physical(mechanisms.lever(), bounds=BOX, known={"r": 1.5})
    head = physical_head(structure, initial=False)
    rng = np.random.default_rng(0)
    for _ in range(5):
        p = np.array([rng.uniform(*BOX[k]) for k in NAMES])
        target = np.array([p[1] / p[0], p[2] / p[0], 1.5 / p[0]])      # a0, a1, c0
        np.testing.assert_allclose(head.inverse.coefficients(p)[0], target, rtol=1e-14)
        start = np.clip(p * rng.uniform(0.7, 1.3, 3), [v[0] for v in BOX.values()],
                        [v[1] for v in BOX.values()])
        np.testing.assert_allclose(head.inverse.parameters(target, start), p, rtol=1e-10)


def test_the_unrolled_newton_inverse_is_the_step_halving_loops():
    """A small square map's inverse runs as one SX graph of Newton steps; its parameters are
    the Python loop's, inside the box and where the target lies beyond its image (the graph
    stops on a bound and the loop goes on); a large map (the two-mass system's) keeps the
    loop alone."""
    structure = ae.Physical(mechanisms.lever(), bounds=BOX, known={"r": 1.5})
    head = physical_head(structure, initial=False)
    assert head.inverse._newton is not None
    rng = np.random.default_rng(4)
    lo, hi = np.array([v[0] for v in BOX.values()]), np.array([v[1] for v in BOX.values()])
    for scale in (1.0, 1.0, 1.0, 3.0, 0.2):            # the last two beyond the box's image
        p = rng.uniform(lo, hi)
        target = (head.inverse.coefficients(p)[0].copy() * scale
                  * (1 + 1e-3 * rng.standard_normal(3)))
        start = rng.uniform(lo, hi)
        graph = head.inverse.parameters(target, start)
        newton, head.inverse._newton = head.inverse._newton, None
        try:
            loop = head.inverse.parameters(target, start)
        finally:
            head.inverse._newton = newton
        assert np.all(graph >= lo) and np.all(graph <= hi)
        np.testing.assert_allclose(graph, loop, rtol=1e-8)
    two_mass = ae.Physical(mechanisms.two_mass(), bounds={n: (0.5, 2.0) for n in (
        "m1", "m2", "k1", "k2", "c1", "c2")}, channel=(0, 0))
    assert physical_head(two_mass, initial=False).inverse._newton is None


def test_an_inverse_that_stops_short_is_started_again_in_the_box():
    # a two-mass system's coefficient map is square but not one-to-one over the box, and
    # Gauss-Newton from this start stops near a bound, far from the coefficients; from the
    # box's fixed points the inverse reaches them: the transfer function of the parameters
    # found is the generating system's (scipy's ss2tf of the structure's own A, B, C, D)
    import scipy.signal

    box = {n: (0.5, 2.0) for n in ("m1", "m2", "k1", "k2", "c1", "c2")}
    head = physical_head(ae.Physical(mechanisms.two_mass(), bounds=box), initial=False)
    truth = np.array([1.587, 0.923, 1.013, 1.678, 0.955, 1.576])
    target = head.inverse.coefficients(truth)[0]
    start = np.full(6, 0.6)
    stopped, distance = head.inverse._nearest(target, start, None)
    assert distance > 1e-6 and np.abs(stopped - truth).max() > 0.5
    found = head.inverse.parameters(target, start)
    np.testing.assert_allclose(head.inverse.coefficients(found)[0], target, rtol=1e-8)

    def tf(p):
        A, b, c, d, _ = head.systems(p)[0]
        num, den = scipy.signal.ss2tf(A, b[:, None], c[None, :], [[d]])
        return num[0] / den[0], den

    for got, want in zip(tf(found), tf(truth), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-7, atol=1e-9)
    assert head.inverse._retries().shape == (8, 6)
    # the lever's map is inverted from anywhere: no further starts (they would only cost time)
    lever_head = physical_head(ae.Physical(mechanisms.lever(), bounds=BOX, known={"r": 1.5}),
                               initial=False)
    assert lever_head.inverse._retries().shape == (0, 3)


def test_the_batch1_path_maps_theta_as_the_structure_does(lever):
    # oracle: the structure's own torch maps (elements, then the CasADi op) in float64
    import torch

    from aeid_struct.identification.fast_path import fast_path

    ident, _ = lever
    fast = fast_path(ident)
    assert fast is not None and fast.physical is not None
    theta = np.random.default_rng(0).normal(0.0, 3.0, (8, ident.structure.p))
    for t in theta:
        el = ident.structure.elements(torch.from_numpy(t[None]))
        sys = ident.structure.assemble(el)
        for got, want in zip(fast._physical(t), (sys.A, sys.b, sys.c, sys.d, el), strict=True):
            np.testing.assert_allclose(got, want.numpy(), rtol=1e-12, atol=1e-12)


def test_a_physical_head_refuses_fixed_elements(lever):
    ident, _ = lever
    with pytest.raises(ValueError, match="constant coefficients itself"):
        ident.head = Head(iterations=3, fixed={"m": 1.0})


def test_one_pass_and_refinement_reach_the_truth_on_noise_free_records(lever):
    ident, family = lever
    rec = ae.data.records(family, 8, steps=200, dt=0.02, excitation_kind="prbs", seed=3)
    refined = ident.identify(rec.y, rec.u, refine=True)
    assert refined.info["refine"] == "separable"
    for k in NAMES:
        np.testing.assert_allclose(refined.physical[k], rec.systems.params[k], rtol=1e-7)
    ident.head = None
    encoder = ident.identify(rec.y, rec.u)
    ident.head = Head(iterations=5)
    one = ident.identify(rec.y, rec.u)
    for k in NAMES:
        truth = rec.systems.params[k]
        # the head moves the encoder's estimate most of the way to the truth
        assert np.median(np.abs(one.physical[k] / truth - 1)) < 0.2 * np.median(
            np.abs(encoder.physical[k] / truth - 1))


def test_a_one_pass_on_a_bound_iterates_in_the_parameters(lever):
    # at 5 % noise a system near the box's edge often has its channel's own optimum outside
    # the box, so the nearest parameters sit on a bound and are not the structure's optimum;
    # the head then iterates the output-error fit in the parameters within the box. Oracle:
    # that bounded fit run to convergence from the truth (refinement.fit_joint, which
    # tests/test_joint_refine.py checks against scipy)
    from aeid_struct.refinement import fit_joint, fit_rows, joint_residual

    ident, family = lever
    count = 32
    rec = ae.data.records(family, count, steps=200, dt=0.02, excitation_kind="prbs", seed=8,
                          noise=0.05)
    ph = physical_head(ident.structure, initial=False)
    truth = np.stack([rec.systems.params[k] for k in NAMES], 1)
    one = np.stack([ident.identify(rec.y, rec.u).physical[k] for k in NAMES], 1)
    optimum = fit_joint(ph.at, truth, [rec.y], [rec.u], (0.02,), lower=ph.lo, upper=ph.hi,
                        initial=False)
    # the head's steps before its iterations in the parameters: the encoder's poles, five
    # separable iterations, the nearest parameters
    ident.head = None
    try:
        start = np.stack([ident.identify(rec.y, rec.u).physical[k] for k in NAMES], 1)
    finally:
        ident.head = Head(iterations=5)
    a, c, d, _ = fit_rows(ph.patterns[0], np.stack([ph.systems(p)[0][4] for p in start]),
                          rec.y, rec.u, 0.02, iterations=5)
    nearest = np.stack([ph.inverse.parameters(np.concatenate([a[i], c[i], [d[i]]])[ph.free],
                                              start[i]) for i in range(count)])
    width = ph.hi - ph.lo
    on_bound = np.any((nearest - ph.lo <= 1e-6 * width) | (ph.hi - nearest <= 1e-6 * width),
                      axis=1)
    assert on_bound.sum() >= 3                     # the case this test is about occurs

    def cost(P):
        return np.array([np.sum(joint_residual(ph.at, p, [rec.y[i]], [rec.u[i]], (0.02,),
                                               False) ** 2) for i, p in enumerate(P)])

    excess = cost(one) / optimum.cost - 1
    assert np.median(excess[on_bound]) < 1e-6 and np.median(excess) < 1e-6


def test_the_converged_head_is_the_output_error_optimum_on_noisy_records(lever):
    ident, family = lever
    rec = ae.data.records(family, 3, steps=200, dt=0.02, excitation_kind="prbs", seed=4,
                          noise=0.02)
    refined = ident.identify(rec.y, rec.u, refine=True)
    for i in range(3):
        truth = {k: float(rec.systems.params[k][i]) for k in NAMES}
        oracle = baselines.least_squares(rec.y[i], rec.u[i], 0.02, structure=ident.structure,
                                         start=truth)
        for k in NAMES:
            np.testing.assert_allclose(refined.physical[k][i], oracle.elements[k], rtol=1e-5)


def test_a_map_of_more_coefficients_than_parameters_is_polished_by_the_nlp():
    drive = mechanisms.drive_train()
    box = {"J1": (0.01, 0.05), "J2": (0.02, 0.2), "k": (50.0, 200.0), "c": (0.05, 0.5),
           "b": (0.01, 0.1)}
    structure = ae.Physical(drive, bounds=box, q=[0, 0], channel=(0, 0))
    head = physical_head(structure, initial=False)
    # G = (J2 s^2 + c s + k) / (s (J1 J2 s^3 + ...)): a0 = 0 and c3 = 0 are constant; six
    # coefficients move with five parameters
    assert head.pattern.a[0] == 0.0 and head.pattern.c[3] == 0.0
    assert head.free.size == 6 and not head.square
    # so refine=True fits the parameters from the converged head instead of iterating the head
    from types import SimpleNamespace

    from aeid_struct.identification.head import refine_route

    assert refine_route(SimpleNamespace(structure=structure, initial="rest")) == "converged head"


def test_records_left_on_a_bound_are_polished_by_the_nlp(lever):
    # a record whose CCF optimum lies beyond the box: the head's nearest parameters stop on a
    # bound, and refine=True hands that record to the NLP (the optimum within the bounds)
    ident, family = lever
    rec = ae.data.records(family, 2, steps=200, dt=0.02, excitation_kind="prbs", seed=5)
    y = np.array(rec.y)
    y[1] = y[1] * 3.0          # a gain beyond the box: m = r / c0 would fall below 0.5
    refined = ident.identify(y, rec.u, refine=True)
    np.testing.assert_array_equal(refined.info["refined_rows"], [False, True])
    oracle = baselines.least_squares(y[1], rec.u[1], 0.02, structure=ident.structure,
                                     start={k: float(refined.physical[k][1]) for k in NAMES})
    cost = np.mean((refined.take([1]).y_hat[0] - y[1]) ** 2)
    assert cost <= np.mean((oracle.y_hat - y[1]) ** 2) * (1 + 1e-6)


def test_standard_errors_match_the_spread_over_noise_draws(lever):
    # Monte Carlo oracle: one system, 200 draws of 2 % noise, each refined; the spread of the
    # estimates is what the standard errors (from the Jacobian at each optimum) predict
    ident, family = lever
    rec = ae.data.records(family, 1, steps=200, dt=0.02, excitation_kind="prbs", seed=6)
    rng = np.random.default_rng(0)
    y = rec.y[0] + 0.02 * np.abs(rec.y[0]).max() * rng.standard_normal((200, 200))
    est = ident.identify(y, np.broadcast_to(rec.u[0], y.shape), refine=True)
    for k in NAMES:
        spread = np.std(est.physical[k])
        assert np.median(est.info["std"][k]) == pytest.approx(spread, rel=0.2)
    one = ident.identify(y[0], rec.u[0], refine=True)
    assert set(one.info["std"]) == set(NAMES) and all(v > 0 for v in one.info["std"].values())
    ident.head = None                        # the NLP's refinement carries them too
    try:
        nlp = ident.identify(y[0], rec.u[0], refine=True)
    finally:
        ident.head = Head(iterations=5)
    for k in NAMES:
        assert nlp.info["std"][k] == pytest.approx(one.info["std"][k], rel=1e-4)
