"""Tests for ``aeid_struct/identification/multistart.py``: ``identify(refine=True, starts=k)``,
the refined estimate beside the fits from fixed points of the box.

Oracles: the true parameters of noise-free records (the global optimum, cost zero), and
``scipy.optimize.least_squares`` on the joint residual from the same points of the box at
noise (the lowest optimum they reach).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize

import aeid_struct as ae
from aeid_struct.identification import Head
from aeid_struct.identification.multistart import best_of_starts, box_points
from aeid_struct.identification.physical_head import physical_head
from aeid_struct.refinement import joint_residual
from symbolic import mechanisms

TWO_MASS = {n: (0.5, 2.0) for n in ("m1", "m2", "k1", "k2", "c1", "c2")}
CART = {"M": (0.5, 2.0), "m": (0.05, 0.5), "l": (0.3, 1.0), "b": (0.05, 1.0)}
GRID = dict(steps=(120, 120), dt=(0.01, 0.01))


def _two_mass():
    return ae.Physical(mechanisms.two_mass(), bounds=TWO_MASS, channel=(0, 0))


def _records(structure, count, noise, seed, **grid):
    family = ae.ParameterFamily(structure)
    rec = ae.data.records(family, count, **grid, excitation_kind="prbs", seed=seed,
                          noise=noise)
    truth = np.stack([rec.systems.params[k] for k in structure.element_names], 1)
    several = structure.records > 1
    ys = list(rec.y) if several else [rec.y]
    us = list(rec.u) if several else [rec.u]
    dts = tuple(rec.dt) if several else (rec.dt,)
    return rec, truth, ys, us, dts


def test_the_points_are_fixed_and_in_the_box():
    lo, hi = np.array([0.5, 10.0, 0.1]), np.array([2.0, 50.0, 3.0])
    P = box_points(lo, hi, 5)
    assert P.shape == (5, 3) and np.all(P > lo) and np.all(P < hi)
    np.testing.assert_array_equal(P, box_points(lo, hi, 5))
    np.testing.assert_array_equal(P[:3], box_points(lo, hi, 3))     # a prefix: k + 1 adds one
    assert box_points(lo, hi, 0).shape == (0, 3)


def test_a_start_replaces_a_poor_estimate_and_keeps_the_optimum():
    """Noise-free two-mass records: from a corner of the box the fit from the points reaches
    the truth (the global optimum) and replaces it; at the truth nothing moves."""
    structure = _two_mass()
    ph = physical_head(structure, False)
    rec, truth, ys, us, dts = _records(structure, 3, 0.0, 5, steps=400, dt=0.05)
    corner = np.tile(ph.lo, (3, 1))
    P, cost, start = best_of_starts(ph, corner, ys, us, dts, False, 4)
    assert np.all(start > 0)
    np.testing.assert_allclose(P, truth, rtol=1e-6)
    assert np.all(cost < 1e-18)
    P, cost, start = best_of_starts(ph, truth, ys, us, dts, False, 4)
    np.testing.assert_array_equal(start, 0)
    np.testing.assert_array_equal(P, truth)


def test_the_best_start_is_the_lowest_optimum_scipy_reaches_from_the_points():
    """At 5 % noise, from a corner: the cost kept is the lowest that scipy's least squares on
    the same residual reaches from the same points of the box (to its tolerance)."""
    structure = _two_mass()
    ph = physical_head(structure, False)
    rec, truth, ys, us, dts = _records(structure, 2, 0.05, 11, steps=400, dt=0.05)
    corner = np.tile(ph.hi, (2, 1))
    P, cost, start = best_of_starts(ph, corner, ys, us, dts, False, 4)
    for i in range(2):
        y, u = [v[i] for v in ys], [v[i] for v in us]

        def residual(p, y=y, u=u):
            return joint_residual(ph.at, p, y, u, dts, False)

        best = min(2 * scipy.optimize.least_squares(
            residual, p0, bounds=(ph.lo, ph.hi), x_scale=ph.hi - ph.lo, xtol=1e-12,
            ftol=1e-12, gtol=1e-12).cost for p0 in box_points(ph.lo, ph.hi, 4))
        assert cost[i] <= best * (1 + 1e-6)
        np.testing.assert_allclose(np.sum(residual(P[i]) ** 2), cost[i], rtol=1e-10)


@pytest.fixture(scope="module")
def cart_pole():
    """A briefly trained cart-pole identifier of both outputs, with a five-iteration head."""
    structure = ae.Physical(mechanisms.cart_pole(), bounds=CART, known={"g": 9.81},
                            channels=[(0, 0), (1, 0)], q=[0, 0])
    family = ae.ParameterFamily(structure)
    ident = ae.train(structure, family, ae.TrainConfig(
        **GRID, epochs=3, count=600, excitation="prbs", progress=False))
    ident.head = Head(iterations=5)
    return ident, family


def test_identify_with_starts_keeps_the_truth_and_says_where_it_came_from(cart_pole):
    ident, family = cart_pole
    rec = ae.data.records(family, 3, **GRID, excitation_kind="prbs", seed=3)
    truth = np.stack([rec.systems.params[k] for k in ("M", "m", "l", "b")], 1)
    est = ident.identify(rec.y, rec.u, refine=True, starts=2)
    np.testing.assert_allclose(np.stack([est.physical[k] for k in ("M", "m", "l", "b")], 1),
                               truth, rtol=1e-8)
    assert est.info["starts"] == 2 and est.info["start"].shape == (3,)
    assert np.all(est.info["cost"] < 1e-18) and set(est.info["std"]) == {"M", "m", "l", "b"}
    one = ident.identify(tuple(y[0] for y in rec.y), tuple(u[0] for u in rec.u),
                         refine=True, starts=2)
    assert isinstance(one.info["start"], int) and isinstance(one.info["cost"], float)
    np.testing.assert_allclose(one.physical["M"], truth[0, 0], rtol=1e-8)


@pytest.mark.parametrize("kwargs, message", [
    ({"refine": True, "starts": -1}, "starts must be an integer >= 0"),
    ({"refine": True, "starts": 1.5}, "starts must be an integer >= 0"),
    ({"refine": True, "starts": True}, "starts must be an integer >= 0"),
    ({"refine": False, "starts": 2}, "starts=2 needs refine=True"),
    ({"refine": "auto", "starts": 2}, "starts=2 needs refine=True"),
])
def test_bad_starts_are_refused_by_name(cart_pole, kwargs, message):
    ident, family = cart_pole
    rec = ae.data.records(family, 1, **GRID, excitation_kind="prbs", seed=3)
    with pytest.raises(ValueError, match=message):
        ident.identify(rec.y, rec.u, **kwargs)


def test_starts_need_a_physical_structure():
    ident = ae.load_pretrained("leg-stable")
    with pytest.raises(ValueError, match="starts=1 needs refine=True and a physical"):
        ident.identify(np.ones(300), refine=True, starts=1)


@pytest.fixture(scope="module")
def two_mass():
    """A briefly trained two-mass identifier (a square map that is not one-to-one over its
    box), with a five-iteration head."""
    structure = _two_mass()
    ident = ae.train(structure, ae.ParameterFamily(structure), ae.TrainConfig(
        steps=400, dt=0.05, epochs=2, count=300, excitation="prbs", progress=False))
    ident.head = Head(iterations=5)
    return ident


def _cost(ph, P, ys, us, dts):
    from aeid_struct.refinement import fit_joint

    return fit_joint(ph.at, P, ys, us, dts, lower=ph.lo, upper=ph.hi, initial=False,
                     max_iter=0).cost


def test_a_refinement_worse_than_its_one_pass_is_refitted_from_the_one_pass(two_mass):
    """``no_worse_than``: a refined estimate left at a corner of the box beside a one pass
    near the truth (noise-free records) is refitted from the one pass and reaches the truth,
    the global optimum, with its systems; a refinement at the truth is kept as it is."""
    import dataclasses

    from aeid_struct.identification.multistart import no_worse_than

    ph = physical_head(two_mass.structure, False)
    rec, truth, ys, us, dts = _records(two_mass.structure, 3, 0.0, 8, steps=400, dt=0.05)
    names = two_mass.structure.element_names
    est = two_mass.identify(rec.y, rec.u, refine=True)

    def at(P):
        return dataclasses.replace(est, elements={k: P[:, j].copy()
                                                  for j, k in enumerate(names)})

    corner, near = np.tile(ph.lo, (3, 1)), truth * (1 + 0.01 * np.linspace(-1, 1, 6))
    out = no_worse_than(at(corner), at(near))
    assert np.all(out.info["from_one_pass"])
    got = np.stack([out.physical[k] for k in names], 1)
    np.testing.assert_allclose(got, truth, rtol=1e-6)
    for i in range(3):
        A, b, c, d, _ = ph.systems(got[i])[0]
        np.testing.assert_allclose(out.A[i], A, rtol=1e-12)
        np.testing.assert_allclose(out.c[i], c, rtol=1e-12)
    kept = no_worse_than(at(truth), at(corner))
    assert not kept.info["from_one_pass"].any()
    np.testing.assert_array_equal(np.stack([kept.physical[k] for k in names], 1), truth)


def test_refine_is_never_worse_than_the_one_pass(two_mass):
    """At 3 % noise, on every record: the refined parameters' output-error cost is at most the
    one pass's (the cost ``refinement.fit_joint`` minimises, evaluated at both)."""
    ph = physical_head(two_mass.structure, False)
    rec, truth, ys, us, dts = _records(two_mass.structure, 12, 0.03, 21, steps=400, dt=0.05)
    names = two_mass.structure.element_names
    one = two_mass.identify(rec.y, rec.u)
    refined = two_mass.identify(rec.y, rec.u, refine=True)
    P1, P2 = (np.stack([e.physical[k] for k in names], 1) for e in (one, refined))
    assert np.all(_cost(ph, P2, ys, us, dts) <= _cost(ph, P1, ys, us, dts) * (1 + 1e-9))
