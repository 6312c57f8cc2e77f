"""Identifier: de-normalisation, batching, input checks, safe save/load."""

import pickle

import numpy as np
import pytest
import torch

import aeid_struct as ae
from aeid_struct.encoder import Encoder, EncoderConfig
from aeid_struct.identify import Identifier
from aeid_struct.metrics import nrmse_fit
from symbolic import leg


def _identifier(steps=60, dt=0.05, inputs=False, seed=0):
    torch.manual_seed(seed)
    structure = ae.CCF(2, descartes=True)
    enc = Encoder(EncoderConfig(steps=steps, outputs=4, inputs=inputs, width=4, dense=(8,)))
    enc.eval()
    return Identifier(enc, structure, dt=dt, theta_mean=torch.tensor([3.0, 1.0, 1.0, 0.0]),
                      theta_scale=torch.full((4,), 0.1), inverse=leg.stable_inverse())


def _record(steps=60, dt=0.05):
    A = np.array([[0.0, 1.0], [-20.0, -3.0]])
    b, c = np.array([0.0, 1.0]), np.array([1.0, 0.0])
    return ae.simulate(A, b, c, 0.0, np.ones(steps), dt)


def test_denormalisation_is_exact():
    ident = _identifier()
    y = _record()
    e1, e7 = ident.identify(y), ident.identify(7.0 * y)
    # the encoder sees the same normalised record; c and d scale with the output exactly
    np.testing.assert_array_equal(e1.A, e7.A)
    np.testing.assert_allclose(e7.c, 7.0 * e1.c, rtol=1e-6)
    assert e7.elements["c0"] == pytest.approx(7.0 * e1.elements["c0"], rel=1e-6)
    assert e7.elements["a0"] == e1.elements["a0"]
    # and a doubled input halves the gain
    e_u = ident.identify(y, 2.0 * np.ones(60))
    np.testing.assert_allclose(e_u.c, 0.5 * e1.c, rtol=1e-6)


def test_batch_equals_singles_and_estimate_fields():
    ident = _identifier()
    y = np.stack([_record(), 2 * _record(), -_record()])
    batch = ident.identify(y)
    assert batch.A.shape == (3, 2, 2) and batch.c.shape == (3, 2) and batch.d.shape == (3,)
    for i in range(3):
        one = ident.identify(y[i])
        assert one.A.shape == (2, 2) and isinstance(one.d, float)
        np.testing.assert_allclose(one.A, batch.A[i], rtol=1e-6)
        np.testing.assert_allclose(one.c, batch.c[i], rtol=1e-6)
    np.testing.assert_allclose(batch.fit, nrmse_fit(y, batch.y_hat))
    np.testing.assert_allclose(batch.y_hat, ae.simulate(batch.A, batch.b, batch.c, batch.d,
                                                        np.ones(60), 0.05))
    # physical parameters from the leg's CCF inverse: k = a0/c0, d = a1/c0, m = 1/c0
    np.testing.assert_allclose(batch.physical["m"], 1 / batch.elements["c0"], rtol=1e-6)
    np.testing.assert_allclose(batch.physical["k"], batch.elements["a0"] / batch.elements["c0"],
                               rtol=1e-6)
    sys = batch.to_control()
    assert len(sys) == 3 and sys[0].nstates == 2
    np.testing.assert_allclose(ident.time(), np.arange(60) * 0.05)


def test_save_load_round_trip_bit_exact(tmp_path):
    ident = _identifier(inputs=True)
    path = ident.save(tmp_path / "model.aeid")
    back = Identifier.load(path)
    for (k, v), (k2, v2) in zip(ident.encoder.state_dict().items(),
                                back.encoder.state_dict().items(), strict=True):
        assert k == k2 and torch.equal(v, v2)
    assert back.structure == ident.structure and back.dt == ident.dt
    y, u = _record(), np.linspace(0.5, 1.0, 60)
    a, b = ident.identify(y, u), back.identify(y, u)
    np.testing.assert_array_equal(a.A, b.A)
    np.testing.assert_array_equal(a.c, b.c)
    assert a.physical == b.physical


class _Exploit:
    def __reduce__(self):
        import os

        return (os.system, ("touch /tmp/aeid_pwned_marker",))


def test_malicious_model_file_does_not_execute(tmp_path):
    import os

    marker = "/tmp/aeid_pwned_marker"
    if os.path.exists(marker):
        os.remove(marker)
    evil = tmp_path / "evil.aeid"
    evil.write_bytes(pickle.dumps(_Exploit()))
    with pytest.raises(ValueError, match="is not an aeid-struct identifier file"):
        Identifier.load(evil)
    torch.save({"x": _Exploit()}, tmp_path / "evil2.aeid")
    with pytest.raises(ValueError, match="is not an aeid-struct identifier file"):
        Identifier.load(tmp_path / "evil2.aeid")
    assert not os.path.exists(marker)


def test_foreign_safetensors_rejected(tmp_path):
    from safetensors.torch import save_file

    save_file({"w": torch.zeros(2)}, str(tmp_path / "other.aeid"), metadata={"aeid": "{}"})
    with pytest.raises(ValueError, match="header format is not"):
        Identifier.load(tmp_path / "other.aeid")
    with pytest.raises(ValueError, match="path must be an existing identifier file"):
        Identifier.load(tmp_path / "missing.aeid")


@pytest.mark.parametrize(
    "y, u, match",
    [
        (np.ones(50), None, r"y must have shape \(60,\) or \(batch, 60\) for this identifier "
                            r"\(dt=0.05, steps=60\); got \(50,\)"),
        (np.ones((2, 3, 60)), None, r"y must have shape"),
        (np.zeros(60), None, r"y must not be all zero \(record 0 of 1\)"),
        (np.r_[np.ones(59), np.nan], None, r"y must be finite; got nan at record 0, sample 59"),
        (np.ones(60), np.zeros(60), r"u must not be all zero"),
        (np.ones(60), np.ones(61), r"u must have shape \(60,\)"),
        (np.ones((3, 60)), np.ones((2, 60)), r"u must have 3 records like y; got 2"),
        (np.ones(60), np.linspace(0.1, 1.0, 60), r"u must be a constant step for this "
                                                 r"identifier \(record 0 varies\)"),
    ],
)
def test_input_errors(y, u, match):
    with pytest.raises(ValueError, match=match):
        _identifier().identify(y, u)


def test_constructor_errors():
    enc = Encoder(EncoderConfig(steps=10, outputs=3))
    with pytest.raises(ValueError, match="encoder.config.outputs must equal structure.p = 4"):
        Identifier(enc, ae.CCF(2), dt=0.1, theta_mean=torch.zeros(4), theta_scale=torch.ones(4))
    enc = Encoder(EncoderConfig(steps=10, outputs=4))
    with pytest.raises(ValueError, match="dt must be a positive finite number"):
        Identifier(enc, ae.CCF(2), dt=0.0, theta_mean=torch.zeros(4), theta_scale=torch.ones(4))
    with pytest.raises(ValueError, match="scale must be one of"):
        Identifier(enc, ae.CCF(2), dt=0.1, theta_mean=torch.zeros(4), theta_scale=torch.ones(4),
                   scale="none")
    with pytest.raises(ValueError, match=r"theta_mean and theta_scale must have shape \(4,\)"):
        Identifier(enc, ae.CCF(2), dt=0.1, theta_mean=torch.zeros(3), theta_scale=torch.ones(4))


def _random_identifier(structure, *, inputs=False, features=0, scale="denormalise",
                       activation="tanh", pool=2, steps=60):
    torch.manual_seed(1)
    enc = Encoder(EncoderConfig(steps=steps, outputs=structure.p, inputs=inputs,
                                features=features, width=4, kernel=3, dense=(8, 6), pool=pool,
                                activation=activation))
    enc.eval()
    return Identifier(enc, structure, dt=0.05, theta_mean=torch.zeros(structure.p),
                      theta_scale=torch.full((structure.p,), 0.3), scale=scale)


@pytest.mark.parametrize(
    "make",
    [
        lambda: _random_identifier(ae.CCF(2, descartes=True)),
        lambda: _random_identifier(ae.CCF(3, feedthrough=True).fixed(a1=0.5), pool=3),
        lambda: _random_identifier(ae.MCF(real=1, pairs=1), inputs=True, activation="relu"),
        lambda: _random_identifier(
            ae.Physical(leg.stable_map(), bounds={"k": (20, 25), "d": (2, 5), "m": (0.5, 1.5)}),
            features=1, scale="feature", pool=1),
    ],
)
def test_batch1_fast_path_is_used_and_equals_the_eager_path(make):
    ident = make()
    assert ident._fast() is not None, "the batch-1 path fell back to eager"
    rng = np.random.default_rng(0)
    y = np.cumsum(rng.random((3, 60)), axis=1)
    # steps of random heights, or arbitrary inputs where the encoder reads u
    u = 0.5 + rng.random((3, 60)) if ident.inputs else (0.5 + rng.random((3, 1))) * np.ones(60)
    batch = ident.identify(y, u)                    # eager torch path
    for i in range(3):
        one = ident.identify(y[i], u[i])            # numpy encoder + traced structure
        np.testing.assert_allclose(one.A, batch.A[i], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(one.c, batch.c[i], rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(one.d, batch.d[i], rtol=1e-5, atol=1e-6)
        for k, v in one.elements.items():
            assert v == pytest.approx(batch.elements[k][i], rel=1e-5, abs=1e-6)


def test_fast_path_follows_weight_changes():
    ident = _random_identifier(ae.CCF(2))
    y = np.cumsum(np.ones(60))
    before = ident.identify(y).A.copy()
    with torch.no_grad():
        for p in ident.encoder.parameters():
            p.mul_(1.5)
    after = ident.identify(y)
    eager = ident.identify(np.stack([y, y]))
    assert not np.allclose(before, after.A)
    np.testing.assert_allclose(after.A, eager.A[0], rtol=1e-5, atol=1e-6)


def test_dt_mismatch_names_what_the_identifier_expects():
    ident = _identifier()
    with pytest.raises(ValueError, match=r"dt must be 0.05 s for this identifier \(trained on "
                                         r"records of 60 samples at dt=0.05\); got dt=0.01"):
        ident.identify(_record(), dt=0.01)
    assert ident.identify(_record(), dt=0.05).A.shape == (2, 2)


def test_standalone_refine_uses_the_estimates_structure():
    from aeid_struct.refine import refine

    ident = _identifier()
    y = _record()
    est = ident.identify(y)
    assert est.structure == ident.structure
    polished = refine(est, y, None, 0.05)           # no structure argument needed
    assert polished.refined and polished.info["loss"] <= polished.info["loss_start"]
    np.testing.assert_allclose(polished.A, [[0.0, 1.0], [-20.0, -3.0]], rtol=1e-6, atol=1e-8)
    bare = ae.Estimate(est.A, est.b, est.c, est.d, est.elements, y, np.ones(60), 0.05)
    with pytest.raises(ValueError, match="structure must be given: this estimate does not"):
        refine(bare, y, None, 0.05)


# -- several records, one parameter set (the joint leg) ----------------------------------------
def _joint_identifier(seed=0):
    torch.manual_seed(seed)
    structure = ae.Physical(leg.joint_map(), bounds={"k": (20, 25), "d": (2, 5),
                                                     "m": (0.5, 1.5)},
                            inverse=leg.joint_inverse())
    enc = Encoder(EncoderConfig(steps=(60, 20), pool=(3, 1), outputs=3, features=2, width=4,
                                dense=(8,)))
    enc.eval()
    return Identifier(enc, structure, dt=(0.05, 0.025), theta_mean=torch.zeros(3),
                      theta_scale=torch.ones(3), scale="feature", feature_mean=(-3.0, 0.5),
                      feature_scale=(0.2, 0.4))


def _joint_records(count=4):
    from aeid_struct.data import records

    return records(ae.LegFamily(subsystem="joint"), count, steps=(60, 20), dt=(0.05, 0.025),
                   seed=1)


def test_joint_identifier_reads_both_records_and_decodes_each_on_its_grid(tmp_path):
    ident = _joint_identifier()
    assert (ident.records, ident.steps, ident.dt) == (2, (60, 20), (0.05, 0.025))
    rec = _joint_records()
    est = ident.identify(rec.y)
    assert est.batched and est.records == 2 and est.A.shape == (4, 2, 2, 2)
    # the estimate is the joint map of its own parameters, record by record
    for r, f in ((0, leg.stable_map()), (1, leg.unstable_map())):
        out = f(k=est.physical["k"][1], d=est.physical["d"][1], m=est.physical["m"][1])
        np.testing.assert_allclose(est.A[1, r], np.array(out["A"]), rtol=1e-5)
    # y_hat and fit per record, against the decoder and nrmse on each record's own grid
    for r, dt in enumerate((0.05, 0.025)):
        ref = ae.simulate(est.A[:, r], est.b[:, r], est.c[:, r], est.d[:, r],
                          np.ones(rec.y[r].shape[1]), dt)
        np.testing.assert_allclose(est.y_hat[r], ref, rtol=1e-12)
        np.testing.assert_allclose(est.fit[:, r], nrmse_fit(rec.y[r], ref))
    one = ident.identify([rec.y[0][2], rec.y[1][2]], dt=(0.05, 0.025))
    assert not one.batched and one.A.shape == (2, 2, 2) and one.fit.shape == (2,)
    for k in "kdm":
        assert one.physical[k] == pytest.approx(est.physical[k][2], rel=1e-5)
    assert len(one.to_control()) == 2 and len(est.to_control()[0]) == 2
    # the scale features read each record's own magnitude: doubling one record changes k
    twice = ident.identify([2 * rec.y[0][2], rec.y[1][2]])
    assert twice.physical["k"] != pytest.approx(one.physical["k"], rel=1e-6)
    path = ident.save(tmp_path / "joint.aeid")
    back = Identifier.load(path)
    assert back.dt == (0.05, 0.025) and back.feature_mean == (-3.0, 0.5)
    np.testing.assert_array_equal(back.identify(rec.y).A, est.A)


def test_joint_identifier_input_errors():
    ident = _joint_identifier()
    rec = _joint_records(2)
    with pytest.raises(ValueError, match=r"y must be a sequence of 2 records \(one per subsystem"):
        ident.identify(rec.y[0])
    with pytest.raises(ValueError, match=r"y\[1\] must have shape \(20,\) or \(batch, 20\)"):
        ident.identify([rec.y[0], rec.y[0]])
    with pytest.raises(ValueError, match=r"y\[1\] must be batched like y\[0\]"):
        ident.identify([rec.y[0], rec.y[1][:1]])
    with pytest.raises(ValueError, match=r"u\[0\] must be a constant step"):
        ident.identify(rec.y, [np.linspace(0.1, 1, 60), np.ones(20)])
    with pytest.raises(ValueError, match=r"dt must be \(0.05, 0.025\) s"):
        ident.identify(rec.y, dt=0.05)
    with pytest.raises(ValueError, match=r"refine=True is not available for a several-record"):
        ident.identify(rec.y, refine=True)
    with pytest.raises(ValueError, match=r"the encoder reads 1 record\(s\) but .* describes 2"):
        Identifier(Encoder(EncoderConfig(steps=60, outputs=3, features=1)),
                   ident.structure, dt=0.05, theta_mean=torch.zeros(3),
                   theta_scale=torch.ones(3), scale="feature")


def test_physical_of_a_modal_estimate_goes_through_its_transfer_function():
    # An MCF identifier with the leg's CCF inverse: the inverse reads a CCF, so the estimate is
    # converted first. Oracle: python-control's transfer function and the closed forms
    # m = 1/c0, k = a0 m, d = a1 m of G1 = (1/m) / (s^2 + (d/m) s + k/m).
    import control

    torch.manual_seed(1)
    structure = ae.MCF(real=0, pairs=1)
    enc = Encoder(EncoderConfig(steps=60, outputs=4, width=4, dense=(8,)))
    enc.eval()
    ident = Identifier(enc, structure, dt=0.05, theta_mean=torch.tensor([1.0, 1.5, 0.5, 0.3]),
                       theta_scale=torch.full((4,), 0.1), inverse=leg.stable_inverse())
    est = ident.identify(np.stack([_record(), 2 * _record()]))
    for i in range(2):
        G = control.ss2tf(control.ss(est.A[i], est.b[i][:, None], est.c[i][None], 0.0))
        num, den = np.ravel(G.num[0][0]), np.ravel(G.den[0][0])
        a1, a0, c0 = den[-2] / den[0], den[-1] / den[0], num[-1] / den[0]
        m = 1 / c0
        assert est.physical["m"][i] == pytest.approx(m, rel=1e-8)
        assert est.physical["k"][i] == pytest.approx(a0 * m, rel=1e-8)
        assert est.physical["d"][i] == pytest.approx(a1 * m, rel=1e-8)


def test_excess_is_the_distance_beyond_the_range_in_error_units():
    from aeid_struct.identify import _excess

    rng = {"elements": {"a0": [1.0, 4.0, 0.5], "c1": [0.0, 0.0, 0.1]},
           "physical": {"k": [20.0, 25.0, 2.0]}}
    values = {"a0": np.array([2.0, 5.0, 0.0, np.nan, 2.0]),
              "c1": np.array([9.0, 9.0, 9.0, 9.0, 9.0]),        # constant in the family: skipped
              "k": np.array([22.0, 22.0, 22.0, 22.0, 31.0])}
    np.testing.assert_array_equal(_excess(values, rng), [0.0, 2.0, 2.0, np.inf, 3.0])
