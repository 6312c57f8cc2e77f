"""identification.container and ``ae.load``: one container with a ``kind`` for every identifier
file, one ``load`` that reads each kind, and every older format still read with the same
numbers (real files rewritten to the old headers)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from safetensors import safe_open
from safetensors.torch import save_file

import aeid_struct as ae
from aeid_struct.generic import load_generic, read_generic, save_generic
from aeid_struct.identification import FORMAT, Identifier, kind_of, stamp


def _rewrite(src, dst, change):
    """``src`` with its header changed by ``change(header) -> header``, written to ``dst``."""
    with safe_open(str(src), framework="pt") as f:
        head = json.loads(f.metadata()["aeid"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    save_file(tensors, str(dst), metadata={"aeid": json.dumps(change(head))})
    return dst


def _old(head, fmt):
    return {"format": fmt, **{k: v for k, v in head.items() if k not in ("format", "kind")}}


@pytest.fixture(scope="module")
def record():
    ident = ae.load_pretrained("leg-stable-window")
    rec = ae.data.records(ae.LegFamily(subsystem="stable"), 1, steps=ident.steps, dt=ident.dt,
                          excitation_kind="prbs", seed=3, warmup=200, noise=0.01)
    return ae.Record(rec.y[0], rec.u[0], ident.dt)


def test_every_writer_stamps_the_container_with_its_kind(tmp_path):
    ident = ae.load_pretrained("leg-stable")
    for path, kind in ((ident.save(tmp_path / "leg.aeid"), "identifier"),
                       (save_generic(load_generic("generic-2"), tmp_path / "g.aeid"), "generic")):
        with safe_open(str(path), framework="pt") as f:
            head = json.loads(f.metadata()["aeid"])
        assert (head["format"], head["kind"]) == (FORMAT, kind) == ("aeid-struct/3", kind)
        assert list(head)[:2] == ["format", "kind"]
    assert stamp("onnx", {"format": "x", "steps": 3}) == {"format": FORMAT, "kind": "onnx",
                                                          "steps": 3}


def test_load_reads_every_kind_and_every_older_format_alike(tmp_path, record):
    ident = ae.load_pretrained("leg-stable-window")
    want = ident.identify(record)
    new = ident.save(tmp_path / "leg.aeid")
    old = _rewrite(new, tmp_path / "old.aeid", lambda h: _old(h, "aeid-struct/identifier/2"))
    for path in (new, old, "leg-stable-window"):
        got = ae.load(path)
        assert isinstance(got, Identifier) and isinstance(got, ae.Identifies)
        np.testing.assert_array_equal(got.identify(record).A, want.A)
    gen = load_generic("generic-2")
    g_new = save_generic(gen, tmp_path / "g.aeid")
    g_old = _rewrite(g_new, tmp_path / "g1.aeid", lambda h: _old(h, "aeid-struct/generic/1"))
    windows = np.stack([record.y[:256], record.y[40:296]])
    inputs = np.stack([record.u[:256], record.u[40:296]])
    for path in (g_new, g_old, "generic-2"):
        got = ae.load(path)
        assert type(got).__name__ == "GenericIdentifier"
        np.testing.assert_array_equal(got.denominators(windows, inputs),
                                      gen.denominators(windows, inputs))


def test_load_reads_onnx_exports_new_and_old(tmp_path, record):
    onnx = pytest.importorskip("onnx")
    from aeid_struct.online import to_onnx

    ident = ae.load_pretrained("leg-stable-window")
    path = to_onnx(ident, tmp_path / "x.onnx")
    model = onnx.load(str(path))
    entry = next(p for p in model.metadata_props if p.key == "aeid")
    head = json.loads(entry.value)
    assert (head["format"], head["kind"]) == (FORMAT, "onnx")
    entry.value = json.dumps(_old(head, "aeid-struct-onnx-3"))
    old = tmp_path / "old.onnx"
    onnx.save(model, str(old))
    want = ident.identify(record).physical["k"]
    for p in (path, old):
        runner = ae.load(p)
        # one identifier class: an export is an Identifier on its ONNX back end
        assert type(runner) is Identifier and runner.backend.name == "onnx"
        assert runner.identify(record).physical["k"] == pytest.approx(want, rel=1e-5)


def test_each_reader_refuses_another_kind_by_name(tmp_path):
    leg = ae.load_pretrained("leg-stable").save(tmp_path / "leg.aeid")
    gen = save_generic(load_generic("generic-1"), tmp_path / "g.aeid")
    with pytest.raises(ValueError, match=r"holds a generic identifier \(any SISO record\), kind "
                                         r"'generic', not a structured identifier .*read it "
                                         r"with ae.generic.load_generic, or with ae.load"):
        Identifier.load(gen)
    with pytest.raises(ValueError, match=r"holds a structured identifier .*kind 'identifier', "
                                         r"not a generic identifier"):
        read_generic(leg)
    bad_kind = _rewrite(leg, tmp_path / "k.aeid", lambda h: {**h, "kind": "model"})
    with pytest.raises(ValueError, match=r"header entry 'kind' must be one of \['generic', "
                                         r"'identifier', 'onnx'\]; got 'model'"):
        ae.load(bad_kind)
    onnx_in_safetensors = _rewrite(leg, tmp_path / "o.aeid", lambda h: {**h, "kind": "onnx"})
    with pytest.raises(ValueError, match=r"says kind 'onnx' but is a safetensors file"):
        ae.load(onnx_in_safetensors)
    with pytest.raises(ValueError, match=r"header format is 'aeid-struct/9'; this version reads "
                                         r"'aeid-struct/3'"):
        kind_of({"format": "aeid-struct/9"}, "header")


def test_load_refuses_what_is_not_an_identifier(tmp_path):
    junk = tmp_path / "junk.aeid"
    junk.write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{" + b"x" * 40)
    with pytest.raises(ValueError, match=r"is not an aeid-struct identifier file"):
        ae.load(junk)
    with pytest.raises(ValueError, match=r"^source must be a shipped identifier's name or an "
                                         r"existing identifier file; got .* \(a directory\)"):
        ae.load(tmp_path)
    with pytest.raises(ValueError, match=r"^source must be a shipped identifier's name "
                                         r"\(leg-stable, .*generic-4\) or the path"):
        ae.load(3)
    text = tmp_path / "model.onnx"
    text.write_bytes(b"not a model")
    with pytest.raises(ValueError, match=r"is not an ONNX model onnxruntime can load"):
        ae.load(text)
