"""A model file holds data, never code (issue 11): real CasADi payloads in every place a file is
read, corrupted headers, named-map and user-map round trips, export paths."""

from __future__ import annotations

import hashlib
import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import casadi
import numpy as np
import pytest
import torch
from safetensors import safe_open
from safetensors.torch import save_file

import aeid_struct as ae
from aeid_struct.encoder import Encoder, EncoderConfig
from aeid_struct.identification import FORMAT, FORMAT_1, Identifier
from aeid_struct.structures import maps as maps
from symbolic import leg, named

ROOT = Path(__file__).resolve().parents[1]


# -- payloads -------------------------------------------------------------------------------------


def _shell_jit(function_of, marker: Path) -> str:
    """The serialisation of a CasADi Function whose JIT options run ``touch marker`` when
    ``casadi.Function.deserialize`` reads it (issue 11).

    Built with ``jit=True`` the command would already run (and need a C compiler) here, at
    construction; so the Function is built with ``jit=False`` -- its options, the command
    included, are serialised all the same -- and the ``jit`` flag is set in the text, where
    CasADi writes each byte as two letters ``'a' + nibble`` (low nibble first) and the flag is
    the byte two before the ``jit_serialize`` string ``"source"``. ``false`` after the command
    makes the compilation fail, so that deserialising raises once the command has run, with or
    without a compiler. ``test_the_payload_runs_under_trust`` proves that the result runs.
    """
    options = {"jit": False, "compiler": "shell",
               "jit_options": {"compiler": f"touch {shlex.quote(str(marker))}; false"}}
    text = function_of(options).serialize()
    raw = bytearray((ord(text[i]) - 97) | ((ord(text[i + 1]) - 97) << 4)
                    for i in range(0, len(text), 2))
    at = raw.index(b"\x06\x00\x00\x00source") - 2
    assert raw[at] == 0, "CasADi's serialisation changed: the jit flag is not where expected"
    raw[at] = 1
    return "".join(chr(97 + (b & 15)) + chr(97 + (b >> 4)) for b in raw)


def inverse_payload(marker: Path) -> str:
    """A CCF -> (k, d, m) inverse (``stable_inverse``'s signature) that runs ``touch marker``."""
    A, B, C, D = (casadi.SX.sym(s, *shape) for s, shape in
                  zip("ABCD", [(2, 2), (2, 1), (1, 2), (1, 1)], strict=True))
    m = 1 / C[0, 0]
    return _shell_jit(lambda opts: casadi.Function(
        "stable_inverse", [A, B, C, D], [-A[1, 0] * m, -A[1, 1] * m, m], list("ABCD"),
        ["k", "d", "m"], opts), marker)


def map_payload(marker: Path) -> str:
    """A (k, d, m) -> CCF map (``stable_map``'s signature) that runs ``touch marker``."""
    k, d, m = (casadi.SX.sym(s) for s in "kdm")
    A = casadi.vertcat(casadi.horzcat(0, 1), casadi.horzcat(-k / m, -d / m))
    return _shell_jit(lambda opts: casadi.Function(
        "stable_map", [k, d, m], [A, casadi.vertcat(0, 1), casadi.horzcat(1 / m, 0),
                                  casadi.SX(1, 1)], ["k", "d", "m"], list("ABCD"), opts), marker)


def user_entry(text: str, name: str) -> dict:
    """A payload dressed as a user map entry, with a consistent SHA-256."""
    return {"map": name, "user": True, "sha256": hashlib.sha256(text.encode()).hexdigest(),
            "serialized": text}


# -- identifiers and files ------------------------------------------------------------------------


def msd_map(gain: float = 1.0) -> casadi.Function:
    """A user's own map (not a named one): (k, d, m) -> CCF of (gain/m) / (s^2 + d/m s + k/m)."""
    k, d, m = (casadi.SX.sym(s) for s in "kdm")
    A = casadi.vertcat(casadi.horzcat(0, 1), casadi.horzcat(-k / m, -d / m))
    return casadi.Function("msd", [k, d, m], [A, casadi.vertcat(0, 1),
                                               casadi.horzcat(gain / m, 0), casadi.SX(1, 1)],
                           ["k", "d", "m"], list("ABCD"))


def msd_inverse() -> casadi.Function:
    A, B, C, D = (casadi.SX.sym(s, *shape) for s, shape in
                  zip("ABCD", [(2, 2), (2, 1), (1, 2), (1, 1)], strict=True))
    m = 1 / C[0, 0]
    return casadi.Function("msd_inv", [A, B, C, D], [-A[1, 0] * m, -A[1, 1] * m, m],
                           list("ABCD"), ["k", "d", "m"])


def ccf_identifier(inverse=None, initial="rest") -> Identifier:
    torch.manual_seed(0)
    enc = Encoder(EncoderConfig(steps=60, outputs=4, width=4, dense=(8,))).eval()
    return Identifier(enc, ae.CCF(2, descartes=True), dt=0.05,
                      theta_mean=torch.tensor([3.0, 1.0, 1.0, 0.0]),
                      theta_scale=torch.full((4,), 0.1),
                      inverse=leg.stable_inverse() if inverse is None else inverse,
                      initial=initial)


def physical_identifier(function, inverse) -> Identifier:
    torch.manual_seed(1)
    enc = Encoder(EncoderConfig(steps=60, outputs=3, features=1, width=4, dense=(8,))).eval()
    structure = ae.Physical(function, bounds=dict(leg.RANGES), inverse=inverse)
    return Identifier(enc, structure, dt=0.05, theta_mean=torch.zeros(3),
                      theta_scale=torch.full((3,), 0.5), scale="feature", feature_mean=-3.0)


def record() -> np.ndarray:
    A = np.array([[0.0, 1.0], [-20.0, -3.0]])
    return ae.simulate(A, np.array([0.0, 1.0]), np.array([1.0, 0.0]), 0.0, np.ones(60), 0.05)


def read(path: Path) -> tuple[dict, dict]:
    with safe_open(str(path), framework="pt") as f:
        return json.loads(f.metadata()["aeid"]), {k: f.get_tensor(k) for k in f.keys()}


def rewrite(src: Path, dst: Path, edit=None, edit_tensors=None) -> Path:
    """Copy an identifier file with its header (and tensors) edited in place."""
    header, tensors = read(src)
    if edit is not None:
        edit(header)
    if edit_tensors is not None:
        edit_tensors(tensors)
    save_file(tensors, str(dst), metadata={"aeid": json.dumps(header)})
    return dst


def names(path: Path) -> str:
    """The regex of a file name as the errors quote it."""
    return re.escape(repr(str(path)))


@pytest.fixture
def marker(tmp_path, monkeypatch):
    """The file a payload creates; the test's folder as working directory, so that a payload
    run under trust leaves CasADi's JIT files there."""
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "pwned"
    yield path


# -- payloads are never run -----------------------------------------------------------------------


def test_the_payload_runs_under_trust(tmp_path, marker):
    # The positive control: trust=True is the only path that deserialises, and it does run the
    # command, so the tests below would see the marker if any reader deserialised.
    src = ccf_identifier().save(tmp_path / "ok.aeid")
    evil = rewrite(src, tmp_path / "evil.aeid", lambda h: h.update(inverse=inverse_payload(marker)))
    assert not marker.exists()
    with pytest.raises(ValueError, match=names(evil) + r": 'inverse' could not be deserialised"):
        Identifier.load(evil, trust=True)
    assert marker.exists()


def test_identifier_inverse_payload_is_not_run(tmp_path, marker):
    src = ccf_identifier().save(tmp_path / "ok.aeid")
    text = inverse_payload(marker)
    evil = rewrite(src, tmp_path / "evil.aeid", lambda h: h.update(inverse=text))
    with pytest.raises(ValueError, match=names(evil) + r": 'inverse' is serialised CasADi code"
                       r".*trust=True only if you trust"):
        Identifier.load(evil)
    evil_user = rewrite(src, tmp_path / "evil_user.aeid",
                        lambda h: h.update(inverse=user_entry(text, "stable_inverse")))
    with pytest.raises(ValueError, match=names(evil_user) + r": 'inverse' is the user map "
                       r"'stable_inverse'.*maps=\{'stable_inverse': f\}.*trust=True"):
        Identifier.load(evil_user)
    # passing a Function under the payload's name checks it, never reads the file's code
    with pytest.raises(ValueError, match=r"maps\['stable_inverse'\] is not the Function the "
                                         r"file was saved with"):
        Identifier.load(evil_user, maps={"stable_inverse": leg.stable_inverse()})
    assert not marker.exists()


@pytest.mark.parametrize("field", ["function", "inverse"])
@pytest.mark.parametrize("dress", ["text", "user"])
def test_physical_structure_payload_is_not_run(tmp_path, marker, field, dress):
    ident = physical_identifier(leg.stable_map(), leg.stable_inverse())
    src = ident.save(tmp_path / "phys.aeid")
    text = (map_payload if field == "function" else inverse_payload)(marker)
    entry = text if dress == "text" else user_entry(text, f"stable_{field}")
    evil = rewrite(src, tmp_path / "evil.aeid", lambda h: h["structure"].update({field: entry}))
    what = (r"is serialised CasADi code" if dress == "text"
            else rf"is the user map 'stable_{field}'.*maps=.*trust=True")
    with pytest.raises(ValueError, match=names(evil) + rf": Physical '{field}' {what}"):
        Identifier.load(evil)
    config = {**ident.structure.config(), field: entry}
    with pytest.raises(ValueError, match=rf"^Physical '{field}' {what}"):
        ae.Structure.from_config(config)
    assert not marker.exists()
    if dress == "user":
        # the positive control for this field: trust=True deserialises the entry and runs it
        with pytest.raises(ValueError, match=rf"Physical '{field}' could not be deserialised"):
            ae.Structure.from_config(config, trust=True)
        assert marker.exists()


def _onnx_with(ident, edit) -> bytes:
    import onnx

    from aeid_struct.online import onnx_bytes

    model = onnx.load_from_string(onnx_bytes(ident))
    for prop in model.metadata_props:
        if prop.key == "aeid":
            header = json.loads(prop.value)
            edit(header)
            prop.value = json.dumps(header)
    return model.SerializeToString()


def test_onnx_metadata_payload_is_not_run(tmp_path, marker):
    from aeid_struct.online import OnnxIdentifier

    ident = ccf_identifier()
    text = inverse_payload(marker)
    path = tmp_path / "evil.onnx"
    path.write_bytes(_onnx_with(ident, lambda h: h.update(inverse=text)))
    with pytest.raises(ValueError, match=r"model file " + names(path) +
                       r": 'inverse' is serialised CasADi code"):
        OnnxIdentifier(path)
    raw = _onnx_with(ident, lambda h: h.update(inverse=user_entry(text, "stable_inverse")))
    with pytest.raises(ValueError, match=r"^model: 'inverse' is the user map 'stable_inverse'"):
        OnnxIdentifier(raw)
    assert not marker.exists()
    with pytest.raises(ValueError, match=r"'inverse' could not be deserialised"):
        OnnxIdentifier(path, trust=True)
    assert marker.exists()


def test_cli_identify_never_trusts_a_file(tmp_path):
    marker = tmp_path / "pwned"
    src = ccf_identifier().save(tmp_path / "ok.aeid")
    evil = rewrite(src, tmp_path / "evil.aeid",
                   lambda h: h.update(inverse=inverse_payload(marker)))
    np.savetxt(tmp_path / "rec.csv", record(), delimiter=",")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "aeid_struct.cli", "identify", str(evil),
                           "--y", str(tmp_path / "rec.csv")], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert "'inverse' is serialised CasADi code" in done.stderr and str(evil) in done.stderr
    assert not marker.exists()
    # the same file without the payload identifies: the refusal is the payload's
    done = subprocess.run([sys.executable, "-m", "aeid_struct.cli", "identify", str(src),
                           "--y", str(tmp_path / "rec.csv")], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr


# -- files before named maps ----------------------------------------------------------------------


def test_old_format_loads_only_with_trust_and_resaves_as_reference(tmp_path):
    ident = ccf_identifier()
    src = ident.save(tmp_path / "new.aeid")
    old = rewrite(src, tmp_path / "old.aeid", lambda h: h.update(
        format=FORMAT_1, inverse=leg.stable_inverse().serialize()))
    with pytest.raises(ValueError, match=names(old) + r" \(format 'aeid-struct/identifier/1', "
                       r"which stored CasADi maps as code\): 'inverse' is serialised CasADi "
                       r"code.*trust=True"):
        Identifier.load(old)
    back = Identifier.load(old, trust=True)
    # byte-identical to the named factory's default build: saved again as its reference
    assert maps.reference(back.inverse) == {"map": "symbolic.leg.stable_inverse",
                                            "args": {"l0": 0.8, "g": 9.81}}
    header, _ = read(back.save(tmp_path / "resaved.aeid"))
    assert header["format"] == FORMAT and header["inverse"] == maps.reference(back.inverse)
    y = record()
    a, b = ident.identify(y), Identifier.load(tmp_path / "resaved.aeid").identify(y)
    np.testing.assert_array_equal(a.A, b.A)
    assert a.physical == b.physical
    # an old file that holds no Function holds no code: it loads as it is
    plain = rewrite(src, tmp_path / "plain.aeid", lambda h: h.update(format=FORMAT_1,
                                                                       inverse=None))
    assert Identifier.load(plain).inverse is None


def test_old_onnx_format_loads_only_with_trust():
    from aeid_struct.online import ONNX_FORMAT_1, OnnxIdentifier

    ident = ccf_identifier()
    raw = _onnx_with(ident, lambda h: h.update(format=ONNX_FORMAT_1,
                                               inverse=leg.stable_inverse().serialize()))
    with pytest.raises(ValueError, match=r"model \(format 'aeid-struct-onnx-1', which stored its "
                                         r"inverse map as code\): 'inverse' is serialised"):
        OnnxIdentifier(raw)
    runner = OnnxIdentifier(raw, trust=True)
    model = runner(record())
    physical = runner.physical(model)
    # the stable inverse's closed form: m = 1/c0, k = a0 m (CCF: A[1, 0] = -a0)
    assert physical["m"] == pytest.approx(1 / model["c"][0], rel=1e-12)
    assert physical["k"] == pytest.approx(-model["A"][1, 0] / model["c"][0], rel=1e-12)


# -- named maps and user maps round trip ----------------------------------------------------------


def test_named_factories_remember_their_reference():
    f = leg.stable_map(l0=0.8)
    assert maps.reference(f) == {"map": "symbolic.leg.stable_map",
                                 "args": {"l0": 0.8, "g": 9.81}}
    assert maps.to_entry(leg.joint_inverse(0.9, unstable_noise=2)) == {
        "map": "symbolic.leg.joint_inverse",
        "args": {"l0": 0.9, "g": 9.81, "unstable_noise": 2.0}}
    assert maps.reference(msd_map()) is None
    # a reference dies with its Function (no table growing with every map built)
    key = id(f)
    del f
    assert key not in named._BUILT
    # resolving builds the factory's Function, cached, and it remembers its reference
    ref = {"map": "symbolic.leg.unstable_map", "args": {"l0": 0.9, "g": 9.7}}
    g = maps.resolve(ref)
    assert maps.resolve(json.loads(json.dumps(ref))) is g and maps.reference(g) == ref
    L = 0.9 - 1.0 * 9.7 / 22.0                          # L = l0 - m g / k
    assert float(g(k=22.0, d=3.0, m=1.0)["A"][1, 0]) == pytest.approx(9.7 / L, rel=1e-14)


def test_physical_identifier_of_named_maps_round_trips_through_references(tmp_path):
    ident = physical_identifier(leg.unstable_map(l0=0.9, g=9.7),
                                leg.unstable_inverse(l0=0.9, g=9.7))
    path = ident.save(tmp_path / "phys.aeid")
    header, _ = read(path)
    assert header["structure"]["function"] == {"map": "symbolic.leg.unstable_map",
                                               "args": {"l0": 0.9, "g": 9.7}}
    assert header["structure"]["inverse"] == {"map": "symbolic.leg.unstable_inverse",
                                              "args": {"l0": 0.9, "g": 9.7}}
    assert "serialized" not in json.dumps(header)
    back = Identifier.load(path)
    assert back.structure == ident.structure
    y = record()
    a, b = ident.identify(y), back.identify(y)
    np.testing.assert_array_equal(a.A, b.A)
    np.testing.assert_array_equal(a.c, b.c)
    assert a.physical == b.physical
    # the constants matter: the same file naming l0 = 0.8 decodes another leg
    other = rewrite(path, tmp_path / "other.aeid",
                    lambda h: h["structure"]["function"]["args"].update(l0=0.8))
    assert not np.allclose(Identifier.load(other).identify(y).A, a.A)
    # the joint leg, through its config: the inverse keeps its keyword-only constant
    joint = ae.Physical(leg.joint_map(), bounds=dict(leg.RANGES),
                        inverse=leg.joint_inverse(unstable_noise=2.0))
    config = json.loads(json.dumps(joint.config()))
    assert config["inverse"]["args"] == {"l0": 0.8, "g": 9.81, "unstable_noise": 2.0}
    assert ae.Structure.from_config(config) == joint
    # deterministic: the training checkpoint's fingerprint and refine's cache key
    again = ae.Physical(leg.joint_map(), bounds=dict(leg.RANGES),
                        inverse=leg.joint_inverse(unstable_noise=2.0))
    assert json.dumps(again.config(), sort_keys=True) == json.dumps(config, sort_keys=True)


def test_user_maps_need_maps_or_trust(tmp_path):
    ident = physical_identifier(msd_map(), msd_inverse())
    path = ident.save(tmp_path / "user.aeid")
    header, _ = read(path)
    entry = header["structure"]["function"]
    assert entry["map"] == "msd" and entry["user"] is True
    assert entry["sha256"] == hashlib.sha256(msd_map().serialize().encode()).hexdigest()
    with pytest.raises(ValueError, match=names(path) + r": Physical 'function' is the user map "
                       r"'msd'.*A model file holds data, never code: pass the Function again, "
                       r"maps=\{'msd': f\}.*trust=True"):
        Identifier.load(path)
    with pytest.raises(ValueError, match=r"Physical 'inverse' is the user map 'msd_inv',.*"
                                         r"\(maps= has 'msd'\)"):
        Identifier.load(path, maps={"msd": msd_map()})
    with pytest.raises(ValueError, match=names(path) + r": Physical 'function': maps\['msd'\] "
                       r"is not the Function the file was saved with \(SHA-256"):
        Identifier.load(path, maps={"msd": msd_map(gain=2.0), "msd_inv": msd_inverse()})
    with pytest.raises(ValueError, match=r"maps must be a dict name -> casadi.Function"):
        Identifier.load(path, maps={"msd": "msd_map"})
    y = record()
    a = ident.identify(y)
    for back in (Identifier.load(path, maps={"msd": msd_map(), "msd_inv": msd_inverse()}),
                 Identifier.load(path, trust=True)):
        b = back.identify(y)
        np.testing.assert_array_equal(a.A, b.A)
        assert a.physical == b.physical
    # a user inverse of a canonical identifier, likewise
    canon = ccf_identifier(inverse=msd_inverse()).save(tmp_path / "canon.aeid")
    with pytest.raises(ValueError, match=names(canon) + r": 'inverse' is the user map 'msd_inv'"):
        Identifier.load(canon)
    assert Identifier.load(canon, maps={"msd_inv": msd_inverse()}).inverse.name() == "msd_inv"
    # altered serialised text under trust: the recorded SHA-256 no longer matches
    altered = rewrite(path, tmp_path / "altered.aeid", lambda h: h["structure"]["function"]
                      .update(serialized=msd_map(gain=2.0).serialize()))
    with pytest.raises(ValueError, match=r"serialised text does not match its recorded SHA-256"):
        Identifier.load(altered, trust=True)


# -- corrupted headers ----------------------------------------------------------------------------


def _set(*keys, value):
    def edit(header):
        node = header
        for k in keys[:-1]:
            node = node[k]
        node[keys[-1]] = value
    return edit


def _drop(*keys):
    def edit(header):
        node = header
        for k in keys[:-1]:
            node = node[k]
        del node[keys[-1]]
    return edit


CORRUPT = {
    "unknown encoder key": (_set("encoder", "colour", value="red"),
                            r"'encoder' has unknown entries \['colour'\]"),
    "missing scale": (_drop("scale"), r"the header is missing 'scale'"),
    "missing encoder": (_drop("encoder"), r"the header is missing 'encoder'"),
    "unknown header key": (_set("extra", value=1), r"the header has unknown entries \['extra'\]"),
    "garbage inverse text": (_set("inverse", value="rm -rf /"),
                             r"'inverse' is serialised CasADi code"),
    "garbage inverse dict": (_set("inverse", value={"x": 1}),
                             r"'inverse' must be a map reference \{'map': name"),
    "inverse of wrong type": (_set("inverse", value=5),
                              r"header entry 'inverse' must be a map reference or null; got 5"),
    "unknown map": (_set("inverse", value={"map": "os.system", "args": {}}),
                    r"'inverse' names the unknown map 'os.system'; a file may name only "
                    r"symbolic.leg.stable_map"),
    "reference with extra key": (_set("inverse", value={"map": "symbolic.leg.stable_inverse",
                                                        "args": {}, "module": "os"}),
                                 r"'inverse' has unknown key\(s\) \['module'\]"),
    "non-numeric map arg": (_set("inverse", "args", "l0", value="0.8"),
                            r"constant 'l0' of symbolic.leg.stable_inverse must be a finite "
                            r"number; got '0.8'"),
    "non-finite map arg": (_set("inverse", "args", "g", value=float("inf")),
                           r"constant 'g' of symbolic.leg.stable_inverse must be a finite "
                           r"number; got inf"),
    "unknown map arg": (_set("inverse", "args", "unstable_noise", value=2.0),
                        r"symbolic.leg.stable_inverse has no constant 'unstable_noise'; its "
                        r"constants: l0, g"),
    "map arg refused": (_set("inverse", "args", "l0", value=-1.0),
                        r"symbolic.leg.stable_inverse refuses its constants .*l0 must be finite "
                        r"and positive"),
    "map args not a dict": (_set("inverse", "args", value=[0.8]),
                            r"'args' of symbolic.leg.stable_inverse must be a dict"),
    "user entry without hash": (_set("inverse", value={"map": "f", "user": True}),
                                r"'inverse' is not a valid user map entry"),
    "dt as text": (_set("dt", value="0.05"),
                   r"header entry 'dt' must be a finite number or a list of them; got '0.05'"),
    "dt negative": (_set("dt", value=-0.05), r"dt must be a positive finite number"),
    "scale unknown": (_set("scale", value="both"), r"scale must be one of"),
    "feature_mean NaN": (_set("feature_mean", value=float("nan")),
                         r"header entry 'feature_mean' must be a finite number"),
    "meta a list": (_set("meta", value=[1]), r"header entry 'meta' must be a dict; got \[1\]"),
    "structure a string": (_set("structure", value="CCF"),
                           r"header entry 'structure' must be a dict; got 'CCF'"),
    "structure unknown type": (_set("structure", "type", value="LTI"),
                               r"unknown structure type 'LTI'"),
    "structure n as text": (_set("structure", "n", value="2"),
                            r"n must be an integer >= 1; got '2'"),
    "structure flag as text": (_set("structure", "descartes", value="yes"),
                               r"invalid config for CCF: 'descartes' must be a bool; got 'yes'"),
    "structure fixed a list": (_set("structure", "fixed", value=[1]),
                               r"'fixed' must be a dict name -> number"),
    "encoder inputs as text": (_set("encoder", "inputs", value="yes"),
                               r"'encoder' entry 'inputs' must be true or false"),
    "encoder width as text": (_set("encoder", "width", value="4"),
                              r"'encoder' is not a valid encoder configuration: width must be a "
                              r"positive integer"),
    "training range garbage": (_set("meta", "training_range", value={"elements": [1, 2]}),
                               r"'meta' entry 'training_range' must be \{'elements': "),
    "training range bound as text": (_set("meta", "training_range",
                                          value={"physical": {"k": ["20", 25, 0.1]}}),
                                     r"'meta' entry 'training_range' must be"),
    "encoder other width": (_set("encoder", "width", value=5),
                            r"weight 'encoder\.main\.0\.weight' has shape \(4, 1, 5\); the "
                            r"header's 'encoder' needs \(5, 1, 5\)"),
}


@pytest.mark.parametrize("case", sorted(CORRUPT))
def test_corrupted_header_names_the_file_and_the_fault(tmp_path, case):
    edit, match = CORRUPT[case]
    src = ccf_identifier().save(tmp_path / "ok.aeid")
    bad = rewrite(src, tmp_path / "bad.aeid", edit)
    with pytest.raises(ValueError, match=names(bad) + ": .*" + match):
        Identifier.load(bad)


def _weights(edit):
    return lambda tensors: edit(tensors)


CORRUPT_WEIGHTS = {
    "wrong shape": (lambda t: t.update({"encoder.head.0.weight": torch.zeros(3, 3)}),
                    r"weight 'encoder\.head\.0\.weight' has shape \(3, 3\); the header's "
                    r"'encoder' needs \(8, \d+\)"),
    "missing": (lambda t: t.pop("encoder.head.0.bias"),
                r"weights \['encoder\.head\.0\.bias'\] are missing"),
    "missing theta": (lambda t: t.pop("theta_scale"), r"weights \['theta_scale'\] are missing"),
    "unknown": (lambda t: t.update({"encoder.extra": torch.zeros(2)}),
                r"unknown weights \['encoder\.extra'\]"),
    "non-finite": (lambda t: t["encoder.head.0.bias"].fill_(float("nan")),
                   r"weight 'encoder\.head\.0\.bias' must hold finite floating-point numbers"),
    "integer": (lambda t: t.update({"theta_mean": torch.zeros(4, dtype=torch.int64)}),
                r"weight 'theta_mean' must hold finite floating-point numbers; got dtype "
                r"torch.int64"),
    "theta shape": (lambda t: t.update({"theta_mean": torch.zeros(5)}),
                    r"theta_mean and theta_scale must have shape \(4,\)"),
}


@pytest.mark.parametrize("case", sorted(CORRUPT_WEIGHTS))
def test_corrupted_weights_name_the_file_and_the_tensor(tmp_path, case):
    edit, match = CORRUPT_WEIGHTS[case]
    src = ccf_identifier().save(tmp_path / "ok.aeid")
    bad = rewrite(src, tmp_path / "bad.aeid", edit_tensors=edit)
    with pytest.raises(ValueError, match=names(bad) + ": .*" + match):
        Identifier.load(bad)


def test_corrupted_physical_config(tmp_path):
    src = physical_identifier(leg.stable_map(), leg.stable_inverse()).save(tmp_path / "p.aeid")
    cases = {
        "bounds": (_set("structure", "bounds", value=[1, 2]),
                   r"'bounds' must be a dict name -> \[lo, hi\] of numbers"),
        "no function": (_drop("structure", "function"),
                        r"invalid config for Physical: it needs 'function' and 'bounds'"),
        "function garbage": (_set("structure", "function", value=[1, 2]),
                             r"Physical 'function' must be a map reference"),
        "function unknown map": (_set("structure", "function", "map", value="builtins.eval"),
                                 r"Physical 'function' names the unknown map 'builtins.eval'"),
    }
    for name, (edit, match) in cases.items():
        bad = rewrite(src, tmp_path / f"{name}.aeid", edit)
        with pytest.raises(ValueError, match=names(bad) + ": .*" + match):
            Identifier.load(bad)


def test_reader_options_are_checked(tmp_path):
    path = ccf_identifier().save(tmp_path / "ok.aeid")
    with pytest.raises(ValueError, match=r"trust must be True or False; got 1"):
        Identifier.load(path, trust=1)
    with pytest.raises(ValueError, match=r"trust must be True or False; got 'yes'"):
        ae.Structure.from_config(ae.CCF(2).config(), trust="yes")
    with pytest.raises(ValueError, match=r"maps must be a dict name -> casadi.Function"):
        ae.Structure.from_config(ae.CCF(2).config(), maps=[msd_map()])


def test_tracker_onnx_engine_passes_its_own_user_inverse():
    from aeid_struct.online import Tracker

    # the identifier's ONNX back end keeps the identifier's own Function (the export is made
    # in memory from it), so it needs neither file code nor trust
    ident = ccf_identifier(inverse=msd_inverse(), initial="fitted")
    tracker = Tracker(ident, engine="onnx")
    assert tracker.engine == "onnx" and tracker.runner.inverse is ident.inverse


# -- exports --------------------------------------------------------------------------------------


def test_exports_refuse_a_directory_and_the_reader_refuses_non_onnx(tmp_path):
    from aeid_struct.online import OnnxIdentifier, to_exported, to_onnx

    ident = ccf_identifier()
    folder = re.escape(repr(str(tmp_path)))
    with pytest.raises(ValueError, match=rf"path must be a file to write; {folder} is a "
                                         r"directory"):
        to_exported(ident, tmp_path)
    with pytest.raises(ValueError, match=rf"path must be a file to write; {folder} is a "
                                         r"directory"):
        to_onnx(ident, tmp_path)
    with pytest.raises(ValueError, match=rf"path must be a file to write; {folder} is a "
                                         r"directory"):
        ident.save(tmp_path)
    with pytest.raises(ValueError, match=r"^model is not an ONNX model onnxruntime can load"):
        OnnxIdentifier(b"garbage")
    text = tmp_path / "notes.onnx"
    text.write_text("not a model")
    with pytest.raises(ValueError, match=r"^model file " + names(text) + r" is not an ONNX "
                                         r"model onnxruntime can load"):
        OnnxIdentifier(text)
    with pytest.raises(ValueError, match=r"model must be an existing \.onnx file or its bytes; "
                                         rf"got {folder} \(a directory\)"):
        OnnxIdentifier(tmp_path)
    with pytest.raises(ValueError, match=r"model must be the path of an \.onnx file or its "
                                         r"bytes; got int"):
        OnnxIdentifier(123)
    bad = _onnx_with(ident, lambda h: h.pop("steps"))
    with pytest.raises(ValueError, match=r"^model: its 'aeid' metadata is missing 'steps'"):
        OnnxIdentifier(bad)
    bad = _onnx_with(ident, lambda h: h.update(inverse={"map": "os.system"}))
    with pytest.raises(ValueError, match=r"^model: 'inverse' names the unknown map 'os.system'"):
        OnnxIdentifier(bad)
    # and the export it reads writes the inverse as a reference, never as code
    from aeid_struct.online import ONNX_FORMAT

    runner = OnnxIdentifier(to_onnx(ident, tmp_path / "ok.onnx"))
    assert maps.reference(runner.inverse) == {"map": "symbolic.leg.stable_inverse",
                                               "args": {"l0": 0.8, "g": 9.81}}
    from aeid_struct.identification import container

    assert ONNX_FORMAT == container.FORMAT == "aeid-struct/3"     # the one container
