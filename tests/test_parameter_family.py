"""Tests for ``aeid_struct/training/parameter_family.py`` and ``structures/mechanical.py``: a
physical structure of a mechanism, its family drawn in a box, trained without an inverse map.

Oracles: the closed-form transfer function of a lever-driven mass (``G = r / (m s^2 + d s +
k)``, so the CCF holds ``a0 = k/m, a1 = d/m, c0 = r/m``), the mechanism's own map evaluated
one parameter set at a time, ``scipy.signal.ss2tf``, and the true parameters of noise-free
records for the refined estimate.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

import aeid_struct as ae
from symbolic import leg, mechanisms

BOX = {"m": (0.5, 2.0), "k": (10.0, 50.0), "d": (0.5, 3.0)}


def _lever_structure():
    return ae.Physical(mechanisms.lever(), bounds=BOX, known={"r": 1.5})


def test_a_mechanism_whose_record_cannot_determine_a_parameter_is_refused():
    with pytest.raises(ValueError, match=r"cannot determine m, k, d, r of lever.*fix r with "
                                         r"known="):
        ae.Physical(mechanisms.lever(), bounds={**BOX, "r": (0.5, 2.0)})
    legs = mechanisms.leg()
    with pytest.raises(ValueError, match="cannot determine d of leg"):
        ae.Physical(legs, bounds={"k": (20, 25), "d": (2, 5), "m": (0.5, 1.5)},
                    channel=(1, 1, [1, 3]), **mechanisms.upright(legs))


def test_the_mechanism_structure_is_its_channel_map():
    structure = _lever_structure()
    assert structure.element_names == ("m", "k", "d") and structure.n == 2
    out = structure.function(m=1.2, k=30.0, d=2.0)
    np.testing.assert_allclose(np.array(out["A"])[-1], [-30.0 / 1.2, -2.0 / 1.2], rtol=1e-14)
    np.testing.assert_allclose(np.array(out["C"]).ravel(), [1.5 / 1.2, 0.0], atol=1e-14)
    with pytest.raises(ValueError, match="known, channel and an operating point"):
        ae.Physical(structure.function, bounds=BOX, known={"r": 1.0})
    with pytest.raises(ValueError, match="bounds must give every parameter of lever"):
        ae.Physical(mechanisms.lever(), bounds=BOX)


def test_the_family_draws_in_the_box_and_maps_through_the_structure():
    structure = _lever_structure()
    family = ae.ParameterFamily(structure)
    systems = family.sample(64, np.random.default_rng(0))
    m, k, d = (systems.params[n] for n in ("m", "k", "d"))
    for name, (lo, hi) in BOX.items():
        assert np.all((systems.params[name] >= lo) & (systems.params[name] <= hi))
    for i in range(0, 64, 9):
        num, den = scipy.signal.ss2tf(systems.A[i], systems.b[i][:, None],
                                      systems.c[i][None], systems.d[i])
        np.testing.assert_allclose(den, [1, d[i] / m[i], k[i] / m[i]], rtol=1e-12)
        np.testing.assert_allclose(num.ravel()[-1], 1.5 / m[i], rtol=1e-12)


def test_several_records_of_one_parameter_set():
    structure = ae.Physical(leg.joint_map(), bounds={"k": (20, 25), "d": (2, 5), "m": (0.5, 1.5)})
    systems = ae.ParameterFamily(structure).sample(5, np.random.default_rng(1))
    assert systems.A.shape == (5, 2, 2, 2) and systems.records == 2
    for i in range(5):
        point = {n: float(systems.params[n][i]) for n in ("k", "d", "m")}
        for r, reference in enumerate((leg.stable_map(), leg.unstable_map())):
            out = reference(**point)
            np.testing.assert_allclose(systems.A[i, r], np.array(out["A"]), rtol=1e-12)
            np.testing.assert_allclose(systems.c[i, r], np.array(out["C"]).ravel(),
                                       rtol=1e-12, atol=1e-15)


def test_log_uniform_draws_spread_over_decades():
    structure = ae.Physical(leg.stable_map(),
                            bounds={"k": (1.0, 1000.0), "d": (2, 5), "m": (0.5, 1.5)})
    draw = ae.ParameterFamily(structure, log=("k",)).draw(4000, np.random.default_rng(2))
    # log-uniform over three decades: a third of the draws in each
    share = np.mean(draw["k"] < 10.0)
    assert 0.3 < share < 0.37
    assert 0.3 < np.mean(draw["d"] < 3.0) < 0.37           # uniform: (3 - 2) / 3


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"bounds": {"m": (0.5, 2.0)}}, "must name the structure's parameters"),
    ({"bounds": {**BOX, "m": (0.1, 2.0)}}, r"bounds\['m'\] must lie within"),
    ({"log": ("r",)}, "log names 'r'"),
])
def test_bad_family_arguments_are_refused_by_name(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ae.ParameterFamily(_lever_structure(), **kwargs)
    with pytest.raises(ValueError, match="must be a Physical structure"):
        ae.ParameterFamily(ae.CCF(2))


def test_training_needs_no_inverse_and_refinement_reaches_the_truth():
    structure = _lever_structure()
    family = ae.ParameterFamily(structure)
    ident = ae.train(structure, family, ae.TrainConfig(
        steps=150, dt=0.02, epochs=2, count=400, excitation="prbs", progress=False))
    rng = ident.training_range
    assert set(rng["elements"]) == {"m", "k", "d"}
    for name, (lo, hi, _) in rng["elements"].items():
        assert BOX[name][0] <= lo < hi <= BOX[name][1]
    rec = ae.data.records(family, 3, steps=150, dt=0.02, excitation_kind="prbs", seed=7)
    est = ident.identify(rec.y, rec.u)
    assert set(est.physical) == {"m", "k", "d"}
    refined = ident.identify(rec.y, rec.u, refine=True)
    for name in ("m", "k", "d"):
        np.testing.assert_allclose(refined.physical[name], rec.systems.params[name], rtol=1e-5)


def test_a_mechanism_identifier_file_is_data_and_needs_its_map(tmp_path):
    structure = _lever_structure()
    ident = ae.train(structure, ae.ParameterFamily(structure), ae.TrainConfig(
        steps=100, dt=0.02, epochs=1, count=100, excitation="prbs", progress=False))
    path = ident.save(tmp_path / "lever.aeid")
    with pytest.raises(ValueError, match="user map 'lever_y0_u0'.*maps=.*SHA-256"):
        ae.load(path)
    rec = ae.data.records(ae.ParameterFamily(structure), 2, steps=100, dt=0.02,
                          excitation_kind="prbs", seed=1)
    again = ae.load(path, maps={"lever_y0_u0": _lever_structure().function})
    for k in ("m", "k", "d"):
        np.testing.assert_array_equal(again.identify(rec.y, rec.u).physical[k],
                                      ident.identify(rec.y, rec.u).physical[k])
    other = ae.Physical(mechanisms.lever(), bounds=BOX, known={"r": 2.0})   # another map
    with pytest.raises(ValueError, match="SHA-256"):
        ae.load(path, maps={"lever_y0_u0": other.function})


def test_an_integrating_mechanism_trains_on_prbs():
    # a rigid-body mode has no stationary value (Eq. 4); the loss reads none off PRBS records
    box = {"J1": (0.01, 0.05), "J2": (0.02, 0.2), "k": (50.0, 200.0), "c": (0.05, 0.5),
           "b": (0.01, 0.1)}
    structure = ae.Physical(mechanisms.drive_train(), bounds=box, q=[0, 0])
    family = ae.ParameterFamily(structure)
    ident = ae.train(structure, family, ae.TrainConfig(
        steps=200, dt=0.005, epochs=1, count=100, excitation="prbs", progress=False))
    rec = ae.data.records(family, 1, steps=200, dt=0.005, excitation_kind="prbs", seed=2)
    refined = ident.identify(rec.y[0], rec.u[0], refine=True)
    for k in box:
        assert refined.physical[k] == pytest.approx(rec.systems.params[k][0], rel=1e-4)
    with pytest.raises(ValueError, match="no finite stationary value"):
        ae.train(structure, family, ae.TrainConfig(steps=200, dt=0.005, epochs=1, count=100,
                                                   excitation="step", progress=False))
