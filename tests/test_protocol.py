"""identification.protocol: every identifier answers ``identify(record) -> Estimate`` and gives
the numbers of its array form (the leg identifier, its ONNX export, a generic identifier, a
classical method), and refuses what it cannot model by name."""

from __future__ import annotations

import functools

import numpy as np
import pytest

import aeid_struct as ae
from aeid_struct.baselines import Classical, n4sid
from aeid_struct.generic import load_generic
from aeid_struct.identification import Estimate, Identifies


@pytest.fixture(scope="module")
def leg():
    ident = ae.load_pretrained("leg-stable-window")
    rec = ae.data.records(ae.LegFamily(subsystem="stable"), 3, steps=ident.steps, dt=ident.dt,
                          excitation_kind="prbs", seed=4, warmup=200, noise=0.01)
    return ident, rec


def test_the_leg_identifier_takes_a_record(leg):
    ident, rec = leg
    assert isinstance(ident, Identifies)
    one = ident.identify(ae.Record(rec.y[1], rec.u[1], ident.dt))
    arrays = ident.identify(rec.y[1], rec.u[1])
    assert isinstance(one, Estimate) and not one.batched
    np.testing.assert_array_equal(one.A, arrays.A)
    np.testing.assert_array_equal(one.c, arrays.c)
    assert one.physical["k"] == arrays.physical["k"]


def test_the_onnx_export_answers_the_protocol_like_the_identifier(leg, tmp_path):
    pytest.importorskip("onnxruntime")
    from aeid_struct.online import OnnxIdentifier, to_onnx

    ident, rec = leg
    runner = OnnxIdentifier(to_onnx(ident, tmp_path / "leg.onnx"))
    assert isinstance(runner, Identifies)
    est = runner.identify(ae.Record(rec.y[0], rec.u[0], ident.dt))
    want = ident.identify(rec.y[0], rec.u[0])
    for name in ("k", "d", "m"):
        assert est.physical[name] == pytest.approx(want.physical[name], rel=1e-5)
    assert est.fit == pytest.approx(want.fit, abs=1e-3)
    batch = runner.identify(rec.y, rec.u)
    assert batch.batched and batch.A.shape == (3, 2, 2)
    np.testing.assert_allclose(batch.physical["k"], ident.identify(rec.y, rec.u).physical["k"],
                               rtol=1e-5)
    with pytest.raises(ValueError, match=r"^dt must be 0.01 s for this export"):
        runner.identify(rec.y[0], rec.u[0], dt=0.02)


def test_a_generic_identifier_is_ae_identify_with_itself():
    gen = load_generic("generic-2")
    assert isinstance(gen, Identifies)
    t = np.arange(700) * 0.05
    u = np.sign(np.sin(0.7 * t) + 0.3 * np.sin(2.1 * t))
    y = ae.simulate(np.array([[0.0, 1.0], [-4.0, -0.8]]), np.array([0.0, 1.0]),
                    np.array([2.0, 0.0]), 0.0, u, 0.05)
    rec = ae.Record(y + 0.3, u, 0.05)
    mine = gen.identify(rec, refine=False)
    theirs = ae.identify(rec, order=2, refine=False, identifier=gen)
    np.testing.assert_array_equal(mine.A, theirs.A)
    assert mine.fit > 99.9
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(mine.A)),
                               np.sort_complex(np.roots([1.0, 0.8, 4.0])), rtol=1e-6)
    with pytest.raises(ValueError, match=r"^order must be this identifier's order 2; got 3"):
        gen.identify(rec, order=3)
    with pytest.raises(ValueError, match=r"^GenericIdentifier.identify identifies one output"):
        gen.identify(ae.Record(np.stack([y, u], 1), u, 0.05))


def test_a_classical_method_takes_a_record(leg):
    ident, rec = leg
    method = Classical(functools.partial(n4sid, order=2), dt=ident.dt, steps=ident.steps)
    assert isinstance(method, Identifies)
    one = method.identify(ae.Record(rec.y[0], rec.u[0], ident.dt))
    np.testing.assert_array_equal(one.A, method.identify(rec.y[0], rec.u[0]).A)
    with pytest.raises(ValueError, match=r"^the record's dt must be this method's dt = 0.01"):
        method.identify(ae.Record(rec.y[0], rec.u[0], 0.02))


@pytest.mark.parametrize(("call", "match"), [
    (lambda i, r: i.identify(r, r.u), r"^u must be None when Identifier.identify is given a "
                                      r"Record \(the record carries its input\)"),
    (lambda i, r: i.identify(r.with_delay(3)), r"^Identifier.identify models no input delay; "
                                               r"the record has delay=3 samples"),
    (lambda i, r: i.identify([r, r]), r"^Identifier.identify reads 1 record as one set; got 2 "
                                      r"Records \(stack the arrays"),
    (lambda i, r: i.identify(r, dt=0.5), r"^dt must be the record's own \(0.01\)"),
])
def test_what_a_record_cannot_say_is_refused_by_name(leg, call, match):
    ident, rec = leg
    with pytest.raises(ValueError, match=match):
        call(ident, ae.Record(rec.y[0], rec.u[0], ident.dt))
