"""One identifier, several back ends (``Identifier.backend``, ``with_backend``): torch, the
numpy pass for one record, and an export's ONNX graph, against each other; the deprecated
``OnnxIdentifier`` as that identifier with its old dict call."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import aeid_struct as ae
from aeid_struct.identification import Identifier, OnnxBackend, TorchBackend

onnxruntime = pytest.importorskip("onnxruntime")


@pytest.fixture(scope="module")
def window():
    return ae.load_pretrained("leg-stable-window")


@pytest.fixture(scope="module")
def records(window):
    rec = ae.data.records(ae.LegFamily(subsystem="stable"), 4, steps=window.steps, dt=window.dt,
                          excitation_kind="prbs", seed=11, noise=0.01, warmup=100)
    return rec.y, rec.u


def test_default_backend_is_numpy_for_one_record_and_torch_for_a_batch(window, records):
    ys, us = records
    assert isinstance(window.backend, TorchBackend) and window.backend.name == "auto"
    numpy, torch_ = window.with_backend("numpy"), window.with_backend("torch")
    assert (numpy.backend.name, torch_.backend.name, window.backend.name) == (
        "numpy", "torch", "auto")            # a copy: the caller's identifier is unchanged
    one, batch = window.identify(ys[0], us[0]), window.identify(ys, us)
    np.testing.assert_array_equal(one.A, numpy.identify(ys[0], us[0]).A)
    np.testing.assert_array_equal(batch.A, torch_.identify(ys, us).A)
    # numpy (float64) and torch (float32) passes: the same model to float32 precision
    for a, b in ((numpy.identify(ys, us), batch), (torch_.identify(ys[0], us[0]), one)):
        for k in ("k", "d", "m"):
            np.testing.assert_allclose(a.physical[k], b.physical[k], rtol=1e-4)


def test_onnx_backend_in_memory_and_from_a_file_are_the_same_identifier(window, records,
                                                                         tmp_path):
    ys, us = records
    twin = window.with_backend("onnx")
    assert isinstance(twin.backend, OnnxBackend) and twin.head == window.head
    path = ae.online.to_onnx(window, tmp_path / "w.onnx")
    loaded = ae.load(path)
    assert type(loaded) is Identifier and loaded.backend.name == "onnx"
    assert (loaded.steps, loaded.dt, loaded.inputs, loaded.initial, loaded.records) == (
        window.steps, window.dt, window.inputs, window.initial, 1)
    a, b, ref = twin.identify(ys, us), loaded.identify(ys, us), window.identify(ys, us)
    np.testing.assert_array_equal(a.A, b.A)          # one graph, one head: the same numbers
    for k in ("k", "d", "m"):
        np.testing.assert_allclose(a.physical[k], ref.physical[k], rtol=1e-4)
    assert twin.with_backend("onnx") is twin


def test_onnx_backend_collects_bad_records_like_the_torch_backend(window, records):
    ys, us = records
    bad = ys.copy()
    bad[2] = 0.0
    for ident in (window, window.with_backend("onnx")):
        est = ident.identify(bad, us, errors="collect")
        assert np.isnan(est.A[2]).all() and "must not be all zero" in est.errors[2]
        good = ident.identify(ys[[0, 1, 3]], us[[0, 1, 3]])
        np.testing.assert_array_equal(est.A[[0, 1, 3]], good.A)


def test_a_backend_the_identifier_cannot_run_is_refused_by_name(window):
    with pytest.raises(ValueError, match=r"backend must be one of \('auto', 'torch', "
                                         r"'numpy'\) or 'onnx'; got 'gpu'"):
        window.with_backend("gpu")
    onnx = window.with_backend("onnx")
    with pytest.raises(ValueError, match=r"backend must be 'onnx' for an identifier read from "
                                         r"an ONNX export .*got 'torch'"):
        onnx.with_backend("torch")
    for call in (lambda: onnx.forward(None, None), lambda: onnx.save("x.aeid"),
                 onnx.to_dict):
        with pytest.raises(ValueError, match=r"needs the identifier's encoder weights; this one "
                                             r"was read from an ONNX export"):
            call()
    with pytest.raises(ValueError, match=r"it is an export already"):
        ae.online.onnx_bytes(onnx)
    with pytest.raises(ValueError, match=r"threads must be a positive integer; got 0"):
        window.with_backend("onnx", threads=0)


def test_numpy_backend_is_refused_where_the_numpy_pass_does_not_apply():
    from aeid_struct.encoder import Encoder, EncoderConfig

    enc = Encoder(EncoderConfig(steps=60, outputs=4, inputs=True, activation="gelu"))
    ident = ae.Identifier(enc, ae.CCF(2), dt=0.05, theta_mean=np.zeros(4),
                          theta_scale=np.ones(4))
    with pytest.raises(ValueError, match=r"backend 'numpy' needs .* activation 'gelu'"):
        ident.with_backend("numpy")
    assert ident.with_backend("torch").backend.name == "torch"


def test_the_old_onnx_runner_is_the_identifier_with_its_dict_call(window, records, tmp_path):
    ys, us = records
    path = ae.online.to_onnx(window, tmp_path / "w.onnx")
    with pytest.warns(DeprecationWarning, match=r"OnnxIdentifier is deprecated: "
                                                r"aeid_struct.load\(path\)"):
        runner = ae.online.OnnxIdentifier(path)
    assert isinstance(runner, Identifier)
    est = ae.load(path).identify(ys, us)
    out = runner(ys, us)
    np.testing.assert_array_equal(out["A"], est.A)
    np.testing.assert_array_equal(out["elements"][:, 0], est.elements["a0"])
    phys = runner.physical(out)
    for k in ("k", "d", "m"):
        np.testing.assert_array_equal(phys[k], est.physical[k])


def test_the_tracker_runs_the_identifiers_onnx_backend_without_a_second_class(window):
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)   # no deprecated name inside
        tracker = ae.online.Tracker(window)
    assert tracker.engine == "onnx" and type(tracker.runner) is Identifier
    assert tracker.runner.backend.name == "onnx" and window.backend.name == "auto"
    # the identifier as given (a copy only where the tracker caps its head's iterations)
    assert ae.online.Tracker(window, engine="identifier").runner.backend is window.backend
