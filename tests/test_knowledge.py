"""The partial-knowledge variants of the leg: each structure can represent its family exactly,
knows what it says it knows, trains, caches, and has a classical counterpart."""

import numpy as np
import pytest

import aeid_struct as ae
from aeid_struct.metrics import step_error
from aeid_struct.structures import Physical
from aeid_struct.studies import knowledge as knowledge

VARIANTS = knowledge.variants()


def test_the_variants_and_their_outputs():
    free = {name: v.structure.free_names for name, v in VARIANTS.items()}
    assert free == {
        "stable / CCF": ("a0", "a1", "c0", "c1"),
        "stable / CCF c1=0": ("a0", "a1", "c0"),
        "stable / physical": ("k", "d", "m"),
        "stable / CCF m known": ("a0", "a1"),
        "stable / physical m known": ("k", "d"),
        "unstable / CCF": ("a0", "a1", "c0", "c1"),
        "unstable / CCF a1=0": ("a0", "c0", "c1"),
        "unstable / CCF a1=0 c1=0": ("a0", "c0"),
        "unstable / physical": ("k", "m"),
        "unstable / physical m known": ("k",),
        "joint / physical": ("k", "d", "m"),
        "joint / physical m known": ("k", "d"),
    }
    assert VARIANTS["stable / CCF m known"].structure.fixed_values["c0"] == pytest.approx(
        1 / knowledge.KNOWN_MASS)
    assert VARIANTS["joint / physical"].structure.records == 2


@pytest.mark.parametrize("name", list(VARIANTS))
def test_every_structure_represents_its_family_exactly(name):
    # The known elements are right: the true systems of the family satisfy every fixed value
    # and bound (strict elements_of), and physical elements are the true parameters.
    v = VARIANTS[name]
    systems = v.family.sample(25, np.random.default_rng(7))
    x = v.structure.elements_of(systems.A, systems.b, systems.c, systems.d).numpy()
    if isinstance(v.structure, Physical):
        for i, p in enumerate(v.structure.element_names):
            if p in v.structure.free_names:
                np.testing.assert_allclose(x[:, i], systems.params[p], rtol=1e-9)
    else:   # and the CasADi inverse of the CCF gives the parameters back
        out = v.inverse.map(25)(A=np.concatenate(list(systems.A), 1), B=systems.b.T,
                                C=systems.c.reshape(1, -1), D=systems.d.reshape(1, -1))
        for p in v.inverse.name_out():
            np.testing.assert_allclose(np.array(out[p]).ravel(), systems.params[p], rtol=1e-9)


def test_validation_sets_share_the_legs_and_hold_the_known_mass():
    val = knowledge.validation(6, noise=0.05, seed=3)
    again = knowledge.validation(6, noise=0.05, seed=3)
    np.testing.assert_array_equal(val.y[1], again.y[1])
    assert val.dt == (0.01, 0.005) and [y.shape for y in val.y] == [(6, 300), (6, 100)]
    known = knowledge.validation(6, known_mass=True, seed=3)
    np.testing.assert_array_equal(known.systems.params["m"], knowledge.KNOWN_MASS)


def test_train_variant_caches_every_setting(tmp_path):
    v = VARIANTS["unstable / physical m known"]
    ident = knowledge.train_variant(v, noisy=True, count=200, epochs=1, cache=tmp_path)
    files = list(tmp_path.glob("*.aeid"))
    assert [f.name for f in files] == ["unstable-physical-m-known-noisy-200x1-s0.aeid"]
    assert ident.meta["name"] == v.name and ident.meta["train"]["config"]["noise"] == [0.0, 0.06]
    again = knowledge.train_variant(v, noisy=True, count=200, epochs=1, cache=tmp_path)
    val = knowledge.validation(4, known_mass=True).record(1)
    np.testing.assert_array_equal(again.identify(val.y).A, ident.identify(val.y).A)
    with pytest.raises(ValueError, match=r"variant must be a Variant"):
        knowledge.train_variant("unstable / CCF", noisy=False, count=200, epochs=1)


def test_least_squares_counterpart_recovers_noise_free_legs():
    val = knowledge.validation(3, seed=5).record(1)
    est = knowledge.least_squares(VARIANTS["unstable / CCF a1=0 c1=0"]).identify(val.y)
    for p in ("k", "m"):
        np.testing.assert_allclose(est.physical[p], val.systems.params[p], rtol=1e-6)
    with pytest.raises(ValueError, match=r"variant must identify one subsystem"):
        knowledge.least_squares(VARIANTS["joint / physical"])


def test_evaluate_scores_a_joint_identifier_per_record_with_one_parameter_set(tmp_path):
    v = VARIANTS["joint / physical"]
    ident = knowledge.train_variant(v, noisy=False, count=200, epochs=1, cache=tmp_path)
    val = knowledge.validation(5, seed=9)
    stable, unstable = knowledge.evaluate(v, ident, val, label="encoder")
    assert (stable.name, unstable.name) == ("encoder, joint / physical (stable record)",
                                            "encoder, joint / physical (unstable record)")
    est = ident.identify(val.y)
    for r, s in enumerate((stable, unstable)):
        truth = val.record(r)
        np.testing.assert_allclose(s.per_record["k"], 100 * np.abs(
            est.physical["k"] / truth.systems.params["k"] - 1), rtol=1e-9)
        # the step error of record r's own decoded subsystem, on its own grid (Table I)
        steps, dt = truth.y.shape[1], truth.dt
        one = np.ones(steps)
        y_true = ae.simulate(truth.systems.A, truth.systems.b, truth.systems.c,
                             truth.systems.d, one, dt)
        y_hat = ae.simulate(est.A[:, r], est.b[:, r], est.c[:, r], est.d[:, r], one, dt)
        np.testing.assert_allclose(s.per_record["step"], step_error(y_true, y_hat),
                                   rtol=1e-9)


def test_evaluate_leaves_d_out_of_an_unstable_identifiers_score(tmp_path):
    v = VARIANTS["unstable / physical"]
    ident = knowledge.train_variant(v, noisy=False, count=200, epochs=1, cache=tmp_path)
    (s,) = knowledge.evaluate(v, ident, knowledge.validation(5, seed=9))
    assert "d" not in s.per_record and {"k", "m"} <= set(s.per_record)
