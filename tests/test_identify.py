"""Identifier: de-normalisation, batching, input checks, safe save/load."""

import pickle

import numpy as np
import pytest
import torch

import aeid_struct as ae
from aeid_struct.encoder import Encoder, EncoderConfig
from aeid_struct.identification import Identifier
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
    with pytest.raises(ValueError, match=r"is not an aeid-struct file: its header format is None; "
                                         r"this version reads .aeid-struct/3."):
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
    fast = ident._fast()
    assert fast is not None, "the batch-1 path fell back to eager"
    # the structure runs as one CasADi graph (a physical one by its head's map), not a trace
    assert (fast.physical if isinstance(ident.structure, ae.Physical) else fast.map) is not None
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


def test_batch1_identifications_from_several_threads_are_each_records_own():
    """A web server's threads identify on one identifier: each call's model is its own
    record's (the structure's CasADi buffer and the encoder's workspace are per thread; a
    shared buffer gave one thread another's arguments)."""
    from helpers import wrong_in_threads

    ident = _random_identifier(ae.CCF(3, feedthrough=True), inputs=True)
    rng = np.random.default_rng(5)
    ys, us = np.cumsum(rng.random((4, 60)), axis=1), 0.5 + rng.random((4, 60))
    want = [ident.identify(ys[k], us[k]).A for k in range(4)]
    assert wrong_in_threads(lambda k: np.array_equal(ident.identify(ys[k], us[k]).A,
                                                     want[k])) == []


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


def test_a_loaded_identifier_has_built_and_run_its_batch1_path(tmp_path, monkeypatch):
    # load warms the identifier (fast_path.warm): its first single-record call builds nothing
    # (the build, its TorchScript trace and the eager agreement check took ~40 ms there)
    from aeid_struct.identification import fast_path

    path = _random_identifier(ae.CCF(2, descartes=True), inputs=True).save(tmp_path / "i.aeid")
    ident = Identifier.load(path)
    built = ident._fast_path
    assert built is not None and built[1] is not None
    assert built[0] == [p._version for p in ident._params]

    builds = []
    monkeypatch.setattr(fast_path, "Batch1", lambda *a: builds.append(a))
    rng = np.random.default_rng(3)
    y, u = np.cumsum(rng.random(60)), 0.5 + rng.random(60)
    one = ident.identify(y, u)
    assert builds == [] and ident._fast_path is built
    np.testing.assert_allclose(one.A, ident.identify(np.stack([y, y]), u).A[0], rtol=1e-5,
                               atol=1e-6)


def test_chunked_batches_equal_one_pass(monkeypatch):
    # the encoder's and the head's chunks (forward.CHUNK, levenberg.CHUNK) bound memory only
    from aeid_struct.identification import forward, head
    from aeid_struct.refinement import levenberg

    ident = ae.load_pretrained("leg-stable-window")
    ident.head = head.Head(iterations=2, fixed={"c1": 0.0})
    rec = ae.data.records(ae.LegFamily(subsystem="stable"), 7, steps=300, dt=0.01,
                          excitation_kind="prbs", seed=2, warmup=200, noise=0.01)
    whole = ident.identify(rec.y, rec.u)
    monkeypatch.setattr(forward, "CHUNK", 3)
    monkeypatch.setattr(levenberg, "CHUNK", 2)
    parts = ident.identify(rec.y, rec.u)
    np.testing.assert_allclose(parts.A, whole.A, rtol=1e-8)
    np.testing.assert_allclose(parts.c, whole.c, rtol=1e-8)


def test_dt_mismatch_names_what_the_identifier_expects():
    ident = _identifier()
    with pytest.raises(ValueError, match=r"dt must be 0.05 s for this identifier \(trained on "
                                         r"records of 60 samples at dt=0.05\); got dt=0.01"):
        ident.identify(_record(), dt=0.01)
    assert ident.identify(_record(), dt=0.05).A.shape == (2, 2)


def test_standalone_refine_uses_the_estimates_structure():
    from aeid_struct.refinement import refine

    ident = _identifier()
    y = _record()
    est = ident.identify(y)
    assert est.structure == ident.structure
    polished = refine(est)                          # no further argument needed
    assert polished.refined and polished.info["loss"] <= polished.info["loss_start"]
    np.testing.assert_allclose(polished.A, [[0.0, 1.0], [-20.0, -3.0]], rtol=1e-6, atol=1e-8)
    bare = ae.Estimate(A=est.A, b=est.b, c=est.c, d=est.d, elements=est.elements,
                       record=ae.Record(y, np.ones(60), 0.05))
    with pytest.raises(ValueError, match="structure must be given: this estimate does not"):
        refine(bare)


# -- the boundary, the Record and the Provenance (issue 13) -------------------------------------
def test_a_record_is_checked_once_from_identify_to_the_refined_estimate(monkeypatch):
    # One check of y at the public boundary (records.record_problems: finite, all zero, scale),
    # none inside: neither the encoder pass nor the refinement re-checks the record.
    import aeid_struct.records.checks as records
    from aeid_struct.refinement import solve

    calls = {"records": 0, "refine": 0}
    real_problems, real_check = records.record_problems, solve._check_not_zero

    def counted_problems(*args, **kwargs):
        calls["records"] += 1
        return real_problems(*args, **kwargs)

    def counted_check(*args):
        calls["refine"] += 1
        return real_check(*args)

    monkeypatch.setattr(records, "record_problems", counted_problems)
    monkeypatch.setattr(solve, "_check_not_zero", counted_check)
    est = _identifier().identify(_record(), refine=True)
    assert calls == {"records": 1, "refine": 0}
    np.testing.assert_allclose(est.A, [[0.0, 1.0], [-20.0, -3.0]], rtol=1e-6, atol=1e-8)
    assert est.record.checked and est.record.y[0].shape == (1, 60)


def test_an_estimate_refers_to_its_identifiers_provenance():
    import dataclasses

    from aeid_struct.identification import Estimate, Provenance

    ident = _identifier()
    y = _record()
    one, two = ident.identify(y), ident.identify(np.stack([y, 2 * y]))
    assert one.provenance is two.provenance is ident.provenance      # one object, not copies
    assert one.provenance == one.provenance and isinstance(one.provenance, Provenance)
    assert one.structure is ident.structure and one.initial == "rest"
    assert one.provenance.inverse is ident.inverse and one.training_range is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        one.provenance.initial = "fitted"
    with pytest.raises(dataclasses.FrozenInstanceError):
        one.record.batched = True
    # a training range recorded later (train, recalibrate) gives a new provenance
    ident.meta["training_range"] = {"elements": {"a0": [1.0, 30.0, 0.5]}, "fit": 90.0,
                                    "excess": 2.0}
    assert ident.provenance is not one.provenance
    assert ident.identify(y).training_range["elements"]["a0"] == (1.0, 30.0, 0.5)
    # every public attribute of the estimate, read through its record and provenance
    assert np.array_equal(one.y, y) and np.array_equal(one.u, np.ones(60)) and one.dt == 0.05
    assert two.y.shape == (2, 60) and np.array_equal(two.y[1], 2 * y)
    assert one.x0.shape == (2,) and two.x0.shape == (2, 2) and one.errors is None
    assert one.fit == pytest.approx(nrmse_fit(y, one.y_hat)[0])
    assert not one.refined and one.seconds > 0 and one.info == {}
    assert set(one.physical) == {"k", "d", "m"} and one.outside is None and one.excess is None
    assert two.take(1).A.shape == (2, 2) and two.take([1]).y.shape == (1, 60)
    assert len(two.to_control()) == 2 and one.to_control().nstates == 2
    # keywords build it; the old positional form and the old keywords give the same estimate
    kw = Estimate(A=one.A, b=one.b, c=one.c, d=one.d, elements=one.elements, record=one.record,
                  provenance=one.provenance)
    with pytest.warns(DeprecationWarning, match=r"positionally is deprecated: construct it "
                                                r"with keywords"):
        old = Estimate(one.A, one.b, one.c, one.d, one.elements, y, np.ones(60), 0.05, 0.0,
                       False, {}, ident.inverse, structure=ident.structure)
    # the model in the shapes of several channels: B (n, m), C (p, n), D (p, m)
    assert (one.B.shape, one.C.shape, one.D.shape) == ((2, 1), (1, 2), (1, 1))
    assert two.B.shape == (2, 2, 1) and two.D.shape == (2, 1, 1)
    np.testing.assert_array_equal(one.C[0], one.c)
    ss = one.to_control()
    np.testing.assert_array_equal(ss.B, one.B)
    np.testing.assert_array_equal(ss.C, one.C)
    for e in (kw, old):
        assert e.fit == pytest.approx(one.fit, rel=1e-12)
        assert e.physical["k"] == pytest.approx(one.physical["k"], rel=1e-12)
        assert e.structure is ident.structure and e.dt == 0.05 and not e.batched
    with pytest.warns(DeprecationWarning, match=r"keywords \['structure'\] are deprecated"):
        bare = dataclasses.replace(one, structure=None)
    assert bare.structure is None and one.structure is ident.structure
    assert bare.record is one.record
    with pytest.raises(TypeError, match=r"unexpected keyword arguments \['shape'\]"):
        Estimate(A=one.A, b=one.b, c=one.c, d=one.d, elements={}, record=one.record, shape=3)
    with pytest.raises(TypeError, match=r"Estimate needs a record"):
        Estimate(A=one.A, b=one.b, c=one.c, d=one.d, elements={})


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
    from aeid_struct.training import records

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


def test_joint_identifier_refines_both_records_to_their_parameters():
    # refine=True fits k, d, m to both records at once (refinement.fit_joint) from the
    # (untrained) encoder's estimate: noise-free records give the truth back
    ident = _joint_identifier()
    rec = _joint_records(3)
    est = ident.identify(rec.y, refine=True)
    assert est.refined and est.info["refine"] == "joint" and est.info["converged"].all()
    for k in "kdm":
        np.testing.assert_allclose(est.physical[k], rec.systems.params[k], rtol=1e-7)
    assert np.all(est.info["std"]["k"] < 1e-6 * rec.systems.params["k"])


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
    with pytest.raises(ValueError, match=r"refine must be True, False or 'auto'"):
        ident.identify(rec.y, refine="always")
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
    from aeid_struct.identification import excess as _excess

    rng = {"elements": {"a0": [1.0, 4.0, 0.5], "c1": [0.0, 0.0, 0.1]},
           "physical": {"k": [20.0, 25.0, 2.0]}}
    values = {"a0": np.array([2.0, 5.0, 0.0, np.nan, 2.0]),
              "c1": np.array([9.0, 9.0, 9.0, 9.0, 9.0]),        # constant in the family: skipped
              "k": np.array([22.0, 22.0, 22.0, 22.0, 31.0])}
    np.testing.assert_array_equal(_excess(values, rng), [0.0, 2.0, 2.0, np.inf, 3.0])


# -- every bad input answered (issue 11): complex records, extreme magnitudes, no records, ------
# -- constant records, and a batch whose bad records are set aside ------------------------------
def _complex(n=60):
    return np.linspace(1.0, 2.0, n) * (1 + 0.5j)


def _complex_cases():
    """(entry point, call, message): a complex ``y`` or ``u`` at every place a record enters."""
    from aeid_struct import baselines as bl
    from aeid_struct.refinement import refine

    ident = _identifier()
    reads_u = _identifier(inputs=True)
    y, z = _record(), _complex()
    est = ident.identify(y)
    ls = lambda y_, u_: bl.least_squares(y_, u_, 0.05, structure=ae.CCF(2))  # noqa: E731
    classical = bl.Classical(ls, dt=0.05, steps=60)
    real = r"must be real; got a complex array \(dtype complex128\)"
    return [
        ("identify y", lambda: ident.identify(z), "y " + real),
        ("identify u", lambda: reads_u.identify(y, z), "u " + real),
        ("identify collect", lambda: ident.identify(z, errors="collect"), "y " + real),
        ("joint identify", lambda: _joint_identifier().identify(
            [_joint_records(1).y[0][0].astype(complex), _joint_records(1).y[1][0]]),
         r"y\[0\] " + real),
        ("n4sid y", lambda: bl.n4sid(z, np.ones(60), 0.05, order=2), "y " + real),
        ("n4sid u", lambda: bl.n4sid(y, z, 0.05, order=2), "u " + real),
        ("least_squares y", lambda: ls(z, None), "y " + real),
        ("Classical y", lambda: classical.identify(z), "y " + real),
        ("Classical u", lambda: classical.identify(y, z), "u " + real),
        ("failure truth_y", lambda: bl.failure(est, truth_y=z), "truth_y " + real),
        ("refine y", lambda: refine(est, z, None, 0.05), "y " + real),
        ("refine u", lambda: refine(est, y, z, 0.05), "u " + real),
        ("simulate u", lambda: ae.simulate(est.A, est.b, est.c, 0.0, z, 0.05),
         r"u must be a real array; got dtype complex128"),
        # a complex number among floats (object array): no silent cast either
        ("identify object y", lambda: ident.identify(np.array([1.0] * 59 + [1j], dtype=object)),
         r"y must be an array of real numbers; got ndarray of dtype object"),
        ("identify complex tensor", lambda: ident.identify(torch.tensor(z)), "y " + real),
    ]


def test_complex_records_are_refused_at_every_entry_point():
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")      # numpy's ComplexWarning would mean a silent cast
        for name, call, match in _complex_cases():
            with pytest.raises(ValueError, match=match):
                call()
            assert name


@pytest.mark.parametrize("make", [
    lambda: _identifier(),                                                 # step, denormalise
    lambda: _random_identifier(ae.CCF(3, feedthrough=True), inputs=True),  # reads u, d != 0
    lambda: _random_identifier(                                             # scale feature
        ae.Physical(leg.stable_map(), bounds={"k": (20, 25), "d": (2, 5), "m": (0.5, 1.5)}),
        features=1, scale="feature", pool=1),
])
def test_a_batch_gives_each_record_what_it_gives_alone_whatever_the_magnitudes(make):
    # Eq. 15 per record in float64 before the float32 encoder: a record of 1e40 (float32
    # overflows at 3.4e38) or 1e-44 (a float32 subnormal) among ordinary ones (before: NaN
    # rows, "theta must be finite"). Oracles: the record in a batch without the extreme others
    # (the same float32 path: 1e-6), the record alone (the batch-1 path, float64 throughout:
    # the float32 encoder's rounding, 1e-5 as for the fast path above) and, by the exact
    # de-normalisation, the unscaled record's model with c and d times the scale.
    ident = make()
    rng = np.random.default_rng(3)
    base = np.cumsum(rng.uniform(0.1, 1.0, (4, 60)), axis=1)
    scales = np.array([1.0, 1e40, 1e-44, 3.0])
    y = base * scales[:, None]
    u = 0.5 + rng.random((4, 60)) if ident.inputs else None
    batch = ident.identify(y, u)
    for i in range(4):
        alone = ident.identify(y[i], None if u is None else u[i])
        pair = ident.identify(np.stack([y[i], base[0]]),
                              None if u is None else np.stack([u[i], u[0]]))
        for name in "Abcd":
            got = np.asarray(getattr(batch, name))[i]
            np.testing.assert_allclose(got, np.asarray(getattr(pair, name))[0], rtol=1e-6,
                                       atol=0, err_msg=f"{name}[{i}]")
            np.testing.assert_allclose(got, np.asarray(getattr(alone, name)), rtol=1e-5,
                                       atol=0, err_msg=f"{name}[{i}]")
        for k, v in alone.elements.items():
            assert batch.elements[k][i] == pytest.approx(pair.elements[k][0], rel=1e-6, abs=0)
            assert batch.elements[k][i] == pytest.approx(v, rel=1e-5, abs=0), (k, i)
    if ident.scale == "denormalise":
        plain = ident.identify(base, u)
        for i in range(4):
            np.testing.assert_allclose(batch.A[i], plain.A[i], rtol=1e-6)
            np.testing.assert_allclose(batch.c[i], scales[i] * plain.c[i], rtol=1e-6)
            np.testing.assert_allclose(batch.d[i], scales[i] * plain.d[i], rtol=1e-6, atol=0)


def test_a_batch_of_no_records_and_an_unrepresentable_scale_are_refused():
    ident, reads_u = _identifier(), _identifier(inputs=True)
    with pytest.raises(ValueError, match=r"y must be an array of real numbers; got None"):
        ident.identify(None)
    with pytest.raises(ValueError, match=r"y must be an array of real numbers; got list"):
        ident.identify([[1.0, 2.0], [3.0]])
    # a tensor that requires grad is read, not refused with torch's RuntimeError
    y = torch.tensor(_record(), requires_grad=True)
    np.testing.assert_array_equal(ident.identify(y).A, ident.identify(_record()).A)
    with pytest.raises(ValueError, match=r"y must hold at least one record; got shape \(0, 60\)"):
        ident.identify(np.ones((0, 60)))
    with pytest.raises(ValueError, match=r"y must hold at least one record"):
        ident.identify(np.ones((0, 60)), errors="collect")
    with pytest.raises(ValueError, match=r"u must hold at least one record; got shape \(0, 60\)"):
        reads_u.identify(np.ones(60), np.ones((0, 60)))
    # max|y| / max|u| = 1e300 / 1e-300 is beyond float64: the model could not be de-normalised
    with pytest.raises(ValueError, match=r"y and u must have a scale ratio max\|y\| / max\|u\| "
                                         r"that float64 holds .*got 1e\+300 / 1e-300 at record 0"):
        reads_u.identify(np.full(60, 1e300), np.full(60, 1e-300))


def _ranged(ident, fit=-1e9, excess=1.0):
    """``ident`` with a calibrated training range that flags nothing by itself (no element
    ranges, a fit threshold below any fit): only the undefined-fit rule is left to flag."""
    ident.meta["training_range"] = {"elements": {}, "physical": {}, "excess": excess,
                                    "fit": fit}
    return ident


def test_a_constant_record_has_no_fit_and_is_flagged():
    ident = _ranged(_identifier())
    y = _record()
    est = ident.identify(np.stack([y, np.full(60, 0.7)]))
    assert np.isfinite(est.fit[0]) and np.isnan(est.fit[1])
    assert est.outside.tolist() == [False, True]
    one = ident.identify(np.full(60, -2.0))
    assert np.isnan(one.fit) and one.outside is True
    # the fit is still the closed form where it is defined
    np.testing.assert_allclose(est.fit[0], 100 * (1 - np.linalg.norm(y - est.y_hat[0])
                                                  / np.linalg.norm(y - y.mean())))


def test_collect_identifies_the_good_records_as_alone_and_gives_a_reason_for_each_bad_one():
    ident = _ranged(_identifier())
    rng = np.random.default_rng(5)
    y = np.cumsum(rng.uniform(0.1, 1.0, (5, 60)), axis=1)
    y[1, 7] = np.nan
    y[3] = 0.0
    est = ident.identify(y, errors="collect")
    assert est.errors == (None, "y must be finite; got nan at record 1, sample 7", None,
                          "y must not be all zero (record 3 of 5): the normalisation y_tilde = "
                          "2 y / max|y| - 1 (Eq. 15) needs max|y| > 0", None)
    good = [0, 2, 4]
    together = ident.identify(y[good])
    for i, row in enumerate(good):
        alone = ident.identify(y[row])
        for name in "Abcd":
            np.testing.assert_array_equal(np.asarray(getattr(est, name))[row],
                                          np.asarray(getattr(together, name))[i])
            np.testing.assert_allclose(np.asarray(getattr(est, name))[row],
                                       np.asarray(getattr(alone, name)), rtol=1e-6)
    for bad in (1, 3):
        assert np.all(np.isnan(est.A[bad])) and np.isnan(est.d[bad])
        assert all(np.isnan(v[bad]) for v in est.elements.values())
        assert np.all(np.isnan(est.y_hat[bad])) and np.isnan(est.fit[bad])
        assert np.isnan(est.physical["k"][bad])
    np.testing.assert_allclose(est.y_hat[good], together.y_hat)
    np.testing.assert_allclose(est.fit[good], together.fit)
    assert est.outside.tolist() == [False, True, False, True, False]
    kept = est.take(np.array(good))
    assert kept.errors == (None, None, None) and kept.outside.tolist() == [False] * 3
    np.testing.assert_allclose(kept.physical["k"], together.physical["k"])
    # all good: the same numbers as errors="raise", with no reason anywhere
    clean = ident.identify(y[good], errors="collect")
    assert clean.errors == (None, None, None)
    np.testing.assert_array_equal(clean.A, together.A)
    assert together.errors is None
    # one unbatched bad record: a NaN estimate with its reason
    one = ident.identify(np.zeros(60), errors="collect")
    assert one.errors[0].startswith("y must not be all zero") and np.isnan(one.A).all()
    assert one.outside is True and np.isnan(one.fit)
    # the default raises, naming the first bad record
    with pytest.raises(ValueError, match=r"y must be finite; got nan at record 1, sample 7"):
        ident.identify(y)
    with pytest.raises(ValueError, match=r"errors must be one of \('raise', 'collect'\); "
                                         r"got 'ignore'"):
        ident.identify(y, errors="ignore")


def test_collect_checks_inputs_per_record_too_and_refines_only_the_good_records():
    ident = _identifier()
    y = np.stack([_record(), 2 * _record(), _record()])
    u = np.ones((3, 60))
    u[1] = 0.0                                     # a system at rest: nothing to identify
    u[2, 30:] = 2.0                                # a step identifier cannot read this input
    est = ident.identify(y, u, errors="collect", refine=True)
    assert est.errors[0] is None
    assert est.errors[1] == "u must not be all zero (record 1): a system at rest with zero " \
                            "input reveals nothing"
    assert est.errors[2].startswith("u must be a constant step for this identifier (record 2 "
                                    "varies)")
    assert est.refined and est.info["refined_rows"].tolist() == [True, False, False]
    np.testing.assert_allclose(est.A[0], [[0.0, 1.0], [-20.0, -3.0]], rtol=1e-6, atol=1e-8)
    assert np.isnan(est.A[1:]).all()
    # refine="auto" refines the flagged records that were identified (a fit threshold of 99 %
    # flags the untrained identifier's estimate), never a record set aside
    auto = _ranged(_identifier(), fit=99.0).identify(np.stack([_record(), np.zeros(60)]),
                                                     errors="collect", refine="auto")
    assert auto.info["refined_rows"].tolist() == [True, False]
    assert auto.fit[0] > 99.9 and np.isnan(auto.A[1]).all()
    assert auto.outside.tolist() == [False, True]   # refined: it fits now; set aside: flagged


def test_collect_on_a_several_record_identifier():
    ident = _joint_identifier()
    rec = _joint_records(3)
    y = [rec.y[0].copy(), rec.y[1].copy()]
    y[1][1, 4] = np.inf
    est = ident.identify(y, errors="collect")
    assert est.errors == (None, "y[1] must be finite; got inf at record 1, sample 4", None)
    together = ident.identify([v[[0, 2]] for v in y])
    np.testing.assert_array_equal(est.A[[0, 2]], together.A)
    assert np.isnan(est.A[1]).all() and np.isnan(est.physical["k"][1])
    assert np.isnan(est.fit[1]).all() and np.isfinite(est.fit[[0, 2]]).all()
    with pytest.raises(ValueError, match=r"y\[1\] must be finite; got inf at record 1, sample 4"):
        ident.identify(y)
