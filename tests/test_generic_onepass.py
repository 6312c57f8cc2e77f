"""generic.one_call: the one pass of ``ae.identify(refine=False)`` (candidates with the
Steiglitz-McBride estimate, then ``iterations`` Levenberg-Marquardt steps), against the true
system (scipy ``lsim``, exact for an input linear between samples), against
``refinement.refine_separable`` run by hand, and against the encoder's pass alone and the
refined model on unseen records of the generic family."""

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.signal

import aeid_struct as ae
from aeid_struct.generic import identify
from aeid_struct.generic.one_call import ITERATIONS
from aeid_struct.refinement import refine_separable
from aeid_struct.training import GenericFamily

DT = 0.02
POLES = np.array([-1.5 + 6.0j, -1.5 - 6.0j])              # rad/s: |p| dt = 0.12 per sample
DEN = np.real(np.poly(POLES))                              # s^2 + 3 s + 38.25
NUM = np.array([2.0, 30.0])                                # 2 s + 30 (highest power first)
DELAY, OFFSET = 3, 0.4


class PoleDouble:
    """The generic identifier's interface answering every window with the true poles in
    normalised time, the real parts scaled by ``1 + err`` and the imaginary parts by
    ``1 - err`` (a network's error); the poles of other orders get extra fast real poles
    (``extra``, rad/sample) or lose the pair for the slow real pole ``-0.03``."""

    def __init__(self, order=2, err=0.05, window=256):
        self.config = SimpleNamespace(order=order, window=window, band=(0.005, 2.5))
        p = POLES * DT
        p = p.real * (1 + err) + 1j * p.imag * (1 - err)
        p = [-0.03] if order == 1 else list(p) + [-0.8 - 0.1 * k for k in range(order - 2)]
        self.den = np.real(np.poly(p))

    def denominators(self, Y, U):
        return np.tile(self.den, (len(Y), 1))


def record(steps=1000, noise=0.0, seed=0) -> ae.Record:
    """The true system from a mid-motion state, its input delayed by DELAY samples, with an
    output offset; a staircase input (linear between samples, as the FOH model assumes)."""
    rng = np.random.default_rng(seed)
    u_all = np.repeat(rng.uniform(-1, 1, (steps + DELAY) // 20 + 1), 20)[: steps + DELAY]
    t = DT * np.arange(steps)
    system = scipy.signal.StateSpace(*scipy.signal.tf2ss(NUM, DEN))
    _, y, _ = scipy.signal.lsim(system, u_all[:steps], t, X0=[0.3, -0.2])
    y = y + OFFSET + noise * np.std(y) * rng.standard_normal(steps)
    return ae.Record(y, u_all[DELAY:], DT)


def pole_error(est) -> float:
    p = np.sort_complex(np.linalg.eigvals(est.A))
    return float(np.max(np.abs(p - np.sort_complex(POLES)) / np.abs(POLES)))


def test_one_pass_recovers_the_true_poles_from_a_perturbed_encoder():
    # noise-free: the iterations take a 5 %-off start to the true system (Gauss-Newton on a
    # zero-residual problem); the encoder's pass alone keeps the start's error, and its delay:
    # the perturbed poles chose 5 samples, the iterated ones tell the true 3 apart
    rec = record()
    alone = identify(rec, 2, refine=False, iterations=0, classical=False,
                     identifier=PoleDouble())
    one = identify(rec, 2, refine=False, classical=False, identifier=PoleDouble())
    assert pole_error(alone) > 0.02 and alone.delay == 5
    assert pole_error(one) < 1e-6 and one.fit > 99.9999
    assert one.delay == DELAY and one.info["delay_moved"]
    assert not one.refined and one.info["start"] == "encoder"
    assert one.info["iterations"] <= 2 * ITERATIONS
    assert one.offset == pytest.approx(OFFSET, abs=1e-6)
    # with the delay given there is nothing to move: at most ITERATIONS iterations
    given = identify(rec, 2, refine=False, delay=DELAY, classical=False, identifier=PoleDouble())
    assert pole_error(given) < 1e-3 and given.info["iterations"] <= ITERATIONS


def test_one_pass_is_refine_separable_with_max_iter_from_the_candidate():
    # the same iterations run by hand from the double's denominator at the true delay
    rec = record(noise=0.02, seed=1)
    double = PoleDouble(err=0.1)
    for k in (1, 2, 5):
        est = identify(rec, 2, refine=False, delay=DELAY, iterations=k, classical=False,
                       identifier=double)
        r = refine_separable(double.den, rec.y, rec.u, 1.0, delay=DELAY, max_iter=k,
                             cost_tol=1e-8)
        assert est.info["iterations"] == r.info["iterations"] <= k
        assert est.fit == pytest.approx(r.fit, abs=1e-9)
        np.testing.assert_allclose(np.poly(est.A), np.poly(r.A / DT), rtol=1e-8)


def test_classical_candidate_gives_the_true_poles_without_iterations():
    # noise-free, the Steiglitz-McBride estimate is exact and beats the perturbed encoder
    rec = record(seed=2)
    est = identify(rec, 2, refine=False, iterations=0, identifier=PoleDouble(err=0.2))
    assert est.info["start"] == "classical" and pole_error(est) < 1e-6


def test_one_pass_in_mcf_and_with_a_fixed_element():
    rec = record(seed=3)
    est = identify(rec, 2, structure="mcf", refine=False, classical=False,
                   identifier=PoleDouble())
    assert isinstance(est.structure, ae.MCF) and pole_error(est) < 1e-3
    # a structure with fixed elements: the iterations run in the free CCF (its delay found
    # with free poles), the closest model in the structure is returned with its own fit
    fixed = ae.CCF(2, feedthrough=True).fixed(a0=float(DEN[2]))
    est = identify(rec, 2, structure=fixed, refine=False, classical=False,
                   identifier=PoleDouble())
    assert est.info["iterations"] >= 1 and est.elements["a0"] == DEN[2]
    assert est.fit == pytest.approx(ae.compare(est, rec).fit, abs=1e-6)


def test_order_selection_by_the_one_pass():
    # order 3 (the true pair and a fast pole) fits as well as order 2, order 1 far worse: the
    # smallest order within the tolerance is chosen, each order's fit from its own one pass
    doubles = {n: PoleDouble(order=n) for n in (1, 2, 3)}
    est = identify(record(noise=0.01, seed=4), refine=False, classical=False,
                   identifier=doubles)
    fits = est.info["order_fits"]
    assert est.A.shape == (2, 2) and fits[1] < fits[2] - 5 and abs(fits[3] - fits[2]) < 0.5
    assert pole_error(est) < 0.01


def unseen(order, seed, steps=600, noise=0.02):
    """An estimation and a validation record of an unseen system of the generic family."""
    family = GenericFamily(order=order, max_delay=5, noise=(noise, noise), offset=0.5)
    rng = np.random.default_rng(seed)
    recs = family.records(1, 2 * steps, rng).at(0.05)
    return ae.Record(recs.y[0], recs.u[0], 0.05).split(at=steps)


@pytest.mark.parametrize("order", [2, 3])
def test_one_pass_between_the_encoder_pass_and_the_refined_model(order):
    # the shipped identifiers on unseen records: the one pass fits the estimation record at
    # least as well as the encoder's pass alone (its candidates are a superset, and the
    # iterations only lower the cost) and at most as well as the refined model (the
    # converged optimum); on validation it is near the refined model
    gaps = []
    for seed in range(4):
        estimation, validation = unseen(order, 100 + seed)
        alone = ae.identify(estimation, order, refine=False, iterations=0, classical=False)
        one = ae.identify(estimation, order, refine=False)
        refined = ae.identify(estimation, order)
        assert one.fit >= alone.fit - 0.05
        assert refined.fit >= one.fit - 0.1
        gaps.append(ae.compare(one, validation).fit - ae.compare(refined, validation).fit)
    assert np.median(gaps) > -1.0


@pytest.mark.parametrize("kwargs, match", [
    ({"iterations": -1}, "iterations must be an integer >= 0"),
    ({"iterations": 2.0}, "iterations must be an integer >= 0"),
    ({"iterations": True}, "iterations must be an integer >= 0"),
    ({"classical": "yes"}, "classical must be True or False"),
    ({"classical": None}, "classical must be True or False"),
])
def test_bad_iterations_and_classical_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        identify(record(), 2, refine=False, identifier=PoleDouble(), **kwargs)


def test_the_default_budget_is_each_paths_own(monkeypatch):
    """``iterations=None`` (the default) runs generic.pipeline.ITERATIONS for one channel and
    multi.ITERATIONS for several channels; an integer runs as given on both paths."""
    from aeid_struct import multi
    from aeid_struct.generic import one_call

    seen = []
    monkeypatch.setattr(one_call, "run", lambda *a, **kw: seen.append(("one", kw["iterations"])))
    monkeypatch.setattr(one_call, "identify_multi",
                        lambda *a, **kw: seen.append(("several", kw["iterations"])))
    one = record()
    two = ae.Record(np.stack([one.y, 2 * one.y], 1), one.u, DT)
    for rec, iterations in ((one, None), (two, None), (one, 7), (two, 7)):
        try:
            identify(rec, 2, refine=False, iterations=iterations)
        except (AttributeError, TypeError):      # the stand-ins return no estimate
            pass
    assert seen == [("one", ITERATIONS), ("several", multi.ITERATIONS), ("one", 7),
                    ("several", 7)]
    assert ITERATIONS == 30 and multi.ITERATIONS == 10
