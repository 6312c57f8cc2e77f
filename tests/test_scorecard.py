"""Scorecard against closed forms: exact estimates score zero, a scaled gain gives the known step,
fit and Bode errors, known poles give the known stability, bad physics is flagged."""

import math

import numpy as np
import pytest
import torch

import aeid_struct as ae
from aeid_struct import training as data
from aeid_struct.evaluation import Score, pool, score, table, training_summary, training_table
from aeid_struct.evaluation import scorecard as scorecard
from aeid_struct.identification import Provenance
from aeid_struct.records import RecordBatch
from aeid_struct.studies import leg_paper as study
from symbolic import leg


class _Given:
    """An 'identifier' whose estimates are given models, whatever the record says."""

    def __init__(self, A, b, c, d, *, dt, steps, inverse=None):
        self.model = tuple(np.asarray(x, dtype=np.float64) for x in (A, b, c, d))
        self.dt, self.steps, self.inverse = dt, steps, inverse
        self.calls = []

    def identify(self, y, u=None, *, refine=False):
        self.calls.append(refine)
        A, b, c, d = self.model
        return ae.Estimate(A=A, b=b, c=c, d=d, elements={},
                           record=RecordBatch.of(y, u, self.dt, batched=np.ndim(y) == 2),
                           provenance=Provenance(inverse=self.inverse))


def _leg_records(count=6, noise=0.0):
    return data.records(ae.LegFamily(subsystem="stable"), count, steps=300, dt=0.01,
                        noise=noise, seed=3)


def _first_order(steps=50, dt=0.1, count=3):
    """Records of G = 1/(s + 1) exactly (one pole at -1, static gain 1)."""
    family = ae.PoleFamily(real=1, pairs=0, decay=(1.0, 1.0), gain=(1.0, 1.0))
    return data.records(family, count, steps=steps, dt=dt, seed=0)


def test_true_systems_score_zero():
    rec = _leg_records(noise=0.05)
    s = rec.systems
    # parameters from Estimate.physical, and through the CCF conversion of score's inverse
    for own, given in ((leg.stable_inverse(), None), (None, leg.stable_inverse())):
        ident = _Given(s.A, s.b, s.c, s.d, dt=0.01, steps=300, inverse=own)
        sc = score(ident, rec, name="truth", inverse=given)
        r = sc.per_record
        np.testing.assert_allclose(r["step"], 0.0, atol=1e-12)
        np.testing.assert_allclose(r["fit"], 100.0, atol=1e-9)   # against y_clean, not noisy y
        np.testing.assert_allclose(r["magnitude_db"], 0.0, atol=1e-9)
        np.testing.assert_allclose(r["phase_rad"], 0.0, atol=1e-9)
        assert r["stable"].all() and r["valid"].all()
        for p in ("k", "d", "m"):
            np.testing.assert_allclose(r[p], 0.0, atol=1e-9)
        assert sc.parameters == ("k", "d", "m")
        assert sc.summary()["valid_share"] == 1.0
    # an identifier without physical parameters gets no parameter columns
    bare = score(_Given(s.A, s.b, s.c, s.d, dt=0.01, steps=300), rec, name="bare")
    assert "valid" not in bare.per_record and bare.parameters == ()
    assert "valid_share" not in bare.summary()


def test_scaled_gain_closed_form():
    steps, dt = 50, 0.1
    rec = _first_order(steps, dt)
    t = np.arange(steps) * dt
    y = 1.0 - np.exp(-t)                       # unit-step response of 1/(s+1), FOH exact
    np.testing.assert_allclose(rec.y_clean[0], y, atol=1e-12)
    A, b, c, d = rec.systems.A, rec.systems.b, 1.1 * rec.systems.c, rec.systems.d
    sc = score(_Given(A, b, c, d, dt=dt, steps=steps), rec, name="1.1 gain")
    # both scaled by the true range [0, y_max]: |1.1 y - y| / y_max = 0.1 y / y_max
    expected_step = 0.1 * y.mean() / y.max()
    np.testing.assert_allclose(sc.per_record["step"], expected_step, rtol=1e-10)
    expected_fit = 100 * (1 - 0.1 * np.linalg.norm(y) / np.linalg.norm(y - y.mean()))
    np.testing.assert_allclose(sc.per_record["fit"], expected_fit, rtol=1e-10)
    np.testing.assert_allclose(sc.per_record["magnitude_db"], 20 * np.log10(1.1), rtol=1e-10)
    np.testing.assert_allclose(sc.per_record["phase_rad"], 0.0, atol=1e-12)
    np.testing.assert_allclose(sc.poles, -1.0)
    assert sc.summary()["step_median"] == pytest.approx(expected_step, rel=1e-10)


def test_leg_parameters_closed_form_in_any_realisation():
    rec = _leg_records()
    s = rec.systems
    # c / 1.1: m = 1/c0 -> 1.1 m, k = a0 m -> 1.1 k, d = a1 m -> 1.1 d: every error is 10 %
    c = s.c / 1.1
    ccf = score(_Given(s.A, s.b, c, s.d, dt=0.01, steps=300, inverse=leg.stable_inverse()),
                rec, name="ccf")
    for p in ("k", "d", "m"):
        np.testing.assert_allclose(ccf.per_record[p], 10.0, rtol=1e-9)
    # the same transfer function in modal form; its parameters come through the CCF conversion
    mcf = ae.MCF(real=0, pairs=1)
    sys = mcf.assemble(mcf.elements_of(s.A, s.b, c, s.d))
    A, b, cm, d = (x.numpy() for x in sys)
    assert np.abs(A[:, 0, 1]).min() > 0 and np.all(A[:, 1, 0] == -A[:, 0, 1])   # modal blocks
    modal = score(_Given(A, b, cm, d, dt=0.01, steps=300), rec, name="mcf",
                  inverse=ae.LegFamily(subsystem="stable").inverse())
    for p in ("k", "d", "m"):
        np.testing.assert_allclose(modal.per_record[p], 10.0, rtol=1e-8)
    np.testing.assert_allclose(modal.per_record["step"], ccf.per_record["step"], rtol=1e-8)


def _ccf(a_rows):
    """Bottom-row CCF models with denominators s^3 + a2 s^2 + a1 s + a0, numerator a0."""
    a = np.asarray(a_rows, dtype=np.float64)
    count = len(a)
    A = np.zeros((count, 3, 3))
    A[:, [0, 1], [1, 2]] = 1.0
    A[:, 2, :] = -a
    b = np.zeros((count, 3))
    b[:, 2] = 1.0
    c = np.zeros((count, 3))
    c[:, 0] = a[:, 0]
    return A, b, c, np.zeros(count)


def test_stability_of_known_poles_and_overflow():
    rec = data.records(ae.PoleFamily(real=1, pairs=1), 5, steps=300, dt=0.01, seed=1)
    # (s+1)^3; s^3 + s^2 + s + 10 (0.68 +- 1.94j, Descartes-admissible yet unstable);
    # (s+1)(s+2)(s+3); (s-1)(s-2)(s-3); (s-400)(s+1)^2 (e^1200 overflows float64)
    rows = [(1, 3, 3), (10, 1, 1), (6, 11, 6), (-6, 11, -6), (-400, -799, -398)]
    A, b, c, d = _ccf(rows)
    sc = score(_Given(A, b, c, d, dt=0.01, steps=300), rec, name="known")
    np.testing.assert_array_equal(sc.per_record["stable"], [True, False, True, False, False])
    upper = np.sort_complex(sc.poles[1])[-1]
    assert upper.real > 0.68 and upper.real < 0.69
    np.testing.assert_allclose(np.sort(sc.poles[3].real), [1, 2, 3], rtol=1e-8)
    assert sc.per_record["step"][4] == math.inf and sc.per_record["fit"][4] == -math.inf
    assert np.all(np.isfinite(sc.per_record["step"][:4]))
    summary = sc.summary()
    assert summary["stable_share"] == pytest.approx(0.4)
    assert summary["pole_real_max"] == pytest.approx(400.0, rel=1e-9)
    assert summary["step_mean"] == math.inf
    assert math.isfinite(summary["step_median"])


def test_invalid_physics_is_flagged_and_left_out_of_parameter_means():
    rec = _leg_records(count=4)
    s = rec.systems
    c = s.c / 1.1
    c[3] = -c[3]                                   # m = 1/c0 < 0 for the last record
    sc = score(_Given(s.A, s.b, c, s.d, dt=0.01, steps=300, inverse=leg.stable_inverse()),
               rec, name="bad")
    np.testing.assert_array_equal(sc.per_record["valid"], [True, True, True, False])
    summary = sc.summary()
    assert summary["valid_share"] == 0.75
    for p in ("k", "d", "m"):
        assert summary[f"{p}_mean"] == pytest.approx(10.0, rel=1e-9)
        assert sc.per_record[p][3] == pytest.approx(210.0, rel=1e-9)   # |-1.1 - 1| = 2.1


def test_summary_pool_and_table():
    ones = np.ones(4)
    a = Score("a", {"step": np.array([1.0, 2.0, 3.0, 4.0]), "fit": np.array([90., 80, 70, 60]),
                    "stable": np.array([True, True, False, True]),
                    "magnitude_db": np.array([1.0, np.inf, 3.0, 2.0]), "phase_rad": ones},
              np.zeros((4, 2), complex), 0.004)
    s = a.summary()
    assert (s["count"], s["step_mean"], s["step_median"]) == (4, 2.5, 2.5)
    assert s["step_p90"] == 4.0                   # an order statistic, not interpolated
    assert s["fit_median"] == 75.0 and s["stable_share"] == 0.75
    assert s["magnitude_db_mean"] == 2.0          # the infinite row is left out
    assert s["ms_per_record"] == pytest.approx(1.0)
    assert s["pole_real_max"] == 0.0
    b = Score("b", {k: v[:2] for k, v in a.per_record.items()}, np.zeros((2, 3), complex), 1.0)
    both = pool([a, b], name="both")
    assert len(both) == 6 and both.poles.shape == (6, 3) and both.seconds == 1.004
    assert both.summary()["stable_share"] == pytest.approx(5 / 6)
    assert np.isnan(both.poles[0, 2])
    md = table([a, both], columns=("count", "step_median", "stable_share", "k_mean"))
    lines = md.splitlines()
    assert lines[0].startswith("| identifier | records | step error median | stable (%)")
    assert lines[2] == "| a | 4 | 2.50e+00 | 75.0% | - |"
    assert len(lines) == 4
    with pytest.raises(ValueError, match="columns must be keys"):
        table([a], columns=("nope",))
    with pytest.raises(ValueError, match="scores must be a non-empty"):
        table([])
    with pytest.raises(ValueError, match="same measures"):
        pool([a, Score("c", {"step": ones}, np.zeros((4, 1)), 0.0)], name="x")


def _history(held, gmax=(1.0,), skipped=(0,)):
    n = len(held)
    return {"holdout_loss": list(held), "grad_norm_max": list(gmax) * (n // len(gmax)),
            "grad_norm_median": [0.5] * n, "skipped": list(skipped) * (n // len(skipped)),
            "seconds": list(np.arange(1, n + 1) * 2.0)}


def test_training_summary():
    ok = training_summary(_history([1.0, 0.5, 0.4, 0.45], gmax=(3.0, math.nan)))
    assert ok == {"epochs": 4, "seconds": 8.0, "final_holdout": 0.45, "best_holdout": 0.4,
                  "grad_norm_max": 3.0, "grad_norm_median": 0.5, "skipped": 0,
                  "diverged": False}
    assert training_summary(_history([1.0, 0.4, 4.1]))["diverged"]       # > 10 x best
    assert not training_summary(_history([1.0, 0.4, 3.9]))["diverged"]
    nan = training_summary(_history([1.0, math.nan], skipped=(2,)))
    assert nan["diverged"] and nan["best_holdout"] == 1.0 and nan["skipped"] == 4
    with pytest.raises(ValueError, match="ident must be a trained Identifier"):
        training_summary(object())
    with pytest.raises(ValueError, match="at least one epoch"):
        training_summary(_history([]))
    md = training_table({"x": [training_summary(_history([1.0, 0.4, 4.1], skipped=(1,))),
                               training_summary(_history([1.0, 0.5]))]})
    row = md.splitlines()[2].split("|")
    assert [c.strip() for c in row[1:5]] == ["x", "2", "1", "3"]
    with pytest.raises(ValueError, match="runs must be"):
        training_table({})


def test_a_trained_identifier_end_to_end():
    torch.set_num_threads(1)
    family = ae.PoleFamily(real=1, pairs=0)
    config = ae.TrainConfig(dt=0.1, steps=40, count=60, epochs=2, batch=32, progress=False)
    ident = ae.train(ae.MCF(real=1, pairs=0), family, config,
                     encoder=ae.EncoderConfig(width=4, dense=(8,)))
    summary = training_summary(ident)
    assert summary["epochs"] == 2 and summary["skipped"] == 0 and summary["grad_norm_max"] > 0
    rec = data.records(family, 10, steps=40, dt=0.1, seed=5)
    sc = score(ident, rec, name="mcf")
    assert sc.per_record["stable"].all()            # MCF: Hurwitz by construction
    assert sc.poles.shape == (10, 1) and sc.seconds > 0
    assert np.all(sc.per_record["step"] >= 0)


@pytest.mark.slow
def test_agrees_with_the_leg_study():
    ident = ae.load_pretrained("leg-stable")
    ev = study.evaluate(ident, "stable", count=12, seed=12345, timing=False)
    rec = data.records(ae.LegFamily(subsystem="stable"), 12, steps=300, dt=0.01, seed=12345)
    sc = score(ident, rec, name="leg-stable")
    for key in ("step", "magnitude_db", "k", "d", "m"):
        np.testing.assert_allclose(sc.per_record[key], ev.per_system[key], rtol=1e-3,
                                   atol=1e-9, err_msg=key)
    # the CCF conversion gives a CCF identifier the same parameters as its own inverse
    via = score(ident, rec, name="via", inverse=ae.LegFamily(subsystem="stable").inverse())
    for key in ("k", "d", "m"):
        np.testing.assert_allclose(via.per_record[key], sc.per_record[key], rtol=1e-6,
                                   atol=1e-9)


def test_refine_is_passed_on():
    rec = _first_order()
    s = rec.systems
    ident = _Given(s.A, s.b, s.c, s.d, dt=0.1, steps=50)
    score(ident, rec, name="x", refine=True)
    assert ident.calls == [True]


def test_inverse_errors():
    rec = _first_order()
    s = rec.systems
    ident = _Given(s.A, s.b, s.c, s.d, dt=0.1, steps=50)
    with pytest.raises(ValueError, match="inverse must be a casadi.Function"):
        score(ident, rec, name="x", inverse=lambda A: A)
    with pytest.raises(ValueError, match=r"inverse must take A \(1, 1\), B, C, D of the "
                                         r"estimates' order n = 1; got inputs \{'A': \(2, 2\)"):
        score(ident, rec, name="x", inverse=leg.stable_inverse())


@pytest.mark.parametrize("change, match", [
    (dict(name=""), "name must be a non-empty string"),
    (dict(records="y"), "records must be a data.Records"),
    (dict(ident=object()), "ident must be an Identifier"),
    (dict(records=_first_order(steps=40)), r"records must be on the identifier's grid "
                                           r"\(dt=0.1, steps=50\); got dt=0.1, steps=40"),
])
def test_argument_errors(change, match):
    rec = _first_order()
    s = rec.systems
    args = dict(ident=_Given(s.A, s.b, s.c, s.d, dt=0.1, steps=50), records=rec, name="x")
    args.update(change)
    with pytest.raises(ValueError, match=match):
        score(args.pop("ident"), args.pop("records"), **args)


def test_columns_cover_the_summary():
    keys = set(scorecard.COLUMNS) - {"count"}
    rec = _leg_records(count=2)
    s = rec.systems
    sc = score(_Given(s.A, s.b, s.c, s.d, dt=0.01, steps=300, inverse=leg.stable_inverse()),
               rec, name="x")
    assert keys <= set(sc.summary())
