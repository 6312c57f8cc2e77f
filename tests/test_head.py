"""identification.head: the separable head after the encoder, on the shipped identifiers and in
identifier files (data only)."""

import json
import struct

import numpy as np
import pytest

import aeid_struct as ae
from aeid_struct.identification import Identifier
from aeid_struct.identification.head import Head, pattern_of
from aeid_struct.refinement.levenberg import gauss_newton
from aeid_struct.training import LegFamily, records

RANGES = {"k": (19, 27), "d": (1.5, 5.5), "m": (0.5, 1.5)}


def _windows(kind="prbs", count=12, noise=0.0, seed=11):
    return records(LegFamily(subsystem="stable", ranges=RANGES), count, steps=300, dt=0.01,
                   excitation_kind=kind, noise=noise, seed=seed, warmup=200)


HEADS = {"leg-stable-any": Head(iterations=3, fixed={"c1": 0.0}),
         "leg-stable-window": Head(iterations=8, fixed={"c1": 0.0}),
         "leg-unstable-any": Head(iterations=4, fixed={"a1": 0.0, "c1": 0.0})}


def _load(name):
    """A shipped identifier with its physics head."""
    ident = ae.load_pretrained(name)
    if ident.head is None:
        ident.head = HEADS[name]
    return ident


def _errors(est, rec):
    return np.stack([np.abs(est.physical[p] / rec.systems.params[p] - 1) for p in "kdm"])


def test_head_checks_its_fields():
    for bad in (True, -1, 51, 2.0):
        with pytest.raises(ValueError, match="iterations must be an integer"):
            Head(iterations=bad)
    with pytest.raises(ValueError, match="fixed must be a dict"):
        Head(fixed={"c1": float("inf")})
    with pytest.raises(ValueError, match="tol must be None or a float"):
        Head(tol=2.0)
    with pytest.raises(ValueError, match="head must be a dict"):
        Head.from_dict({"iterations": 3, "code": "__import__('os')"})
    head = Head(iterations=2, fixed={"c1": 0})
    assert Head.from_dict(head.to_dict()) == head
    with pytest.raises(ValueError, match="not stored"):
        head.converged().to_dict()


def test_shipped_identifiers_carry_the_physics_head():
    for name, head in HEADS.items():
        assert ae.load_pretrained(name).head == head
    for name in ("leg-stable", "leg-unstable", "leg-stable-ccf", "leg-stable-noisy"):
        assert ae.load_pretrained(name).head is None


def test_a_head_set_later_is_checked_where_it_is_given():
    ident = ae.load_pretrained("leg-stable-any")
    stored = ident.head
    with pytest.raises(ValueError, match="head must be an identification.Head or None"):
        ident.head = {"iterations": 3}
    with pytest.raises(ValueError, match="not elements"):
        ident.head = Head(fixed={"zz": 0.0})
    assert ident.head is stored                        # a refused head changes nothing
    ident.head = None
    assert ident.head is None


def test_the_physics_heads_patterns():
    stable = _load("leg-stable-any")
    p = pattern_of(stable, stable.head)
    assert p.a == (None, None) and p.c == (None, 0.0) and p.initial
    unstable = _load("leg-unstable-any")
    p = pattern_of(unstable, unstable.head)
    assert p.a == (None, 0.0) and p.c == (None, 0.0) and not p.initial
    with pytest.raises(ValueError, match="not elements"):
        pattern_of(stable, Head(fixed={"b1": 0.0}))


def test_head_takes_the_encoder_to_the_noise_free_parameters():
    rec = _windows()
    ident = _load("leg-stable-any")
    one_pass = ident.identify(rec.y, rec.u)
    ident.head = None                              # the paper's pass: the encoder alone
    encoder = ident.identify(rec.y, rec.u)
    assert np.median(_errors(encoder, rec)) > 1e-2
    assert np.max(_errors(one_pass, rec)) < 1e-4
    assert np.all(one_pass.c[:, 1] == 0.0)


def test_refine_true_iterates_the_head_to_the_least_squares_optimum():
    rec = _windows(kind="noise", count=6, noise=0.02, seed=12)
    ident = _load("leg-stable-any")
    est = ident.identify(rec.y, rec.u, refine=True)
    assert est.info["refine"] == "separable"
    pattern = pattern_of(ident, ident.head)
    oracle = gauss_newton(pattern, -est.A[:, -1, :] * 1.05, rec.y, rec.u, 0.01,
                          iterations=50, tol=1e-14)
    np.testing.assert_allclose(-est.A[:, -1, :], oracle.a, rtol=1e-6)
    one_pass = ident.identify(rec.y, rec.u)
    assert np.median(_errors(est, rec)) <= np.median(_errors(one_pass, rec)) * 1.05


def test_a_bad_record_costs_no_good_one():
    rec = _windows(count=4)
    y = rec.y.copy()
    y[1, 5] = np.nan
    ident = _load("leg-stable-any")
    est = ident.identify(y, rec.u, errors="collect")
    alone = ident.identify(rec.y[[0, 2, 3]], rec.u[[0, 2, 3]])
    assert np.isnan(est.A[1]).all()
    np.testing.assert_allclose(est.A[[0, 2, 3]], alone.A, rtol=1e-9)


def _header(path):
    raw = path.read_bytes()
    size = struct.unpack("<Q", raw[:8])[0]
    return raw, size, json.loads(raw[8: 8 + size])


def _rewrite(path, out, change):
    raw, size, head = _header(path)
    meta = json.loads(head["__metadata__"]["aeid"])
    change(meta)
    head["__metadata__"]["aeid"] = json.dumps(meta)
    text = json.dumps(head).encode()
    text += b" " * (-len(text) % 8)
    out.write_bytes(struct.pack("<Q", len(text)) + text + raw[8 + size:])


def test_head_round_trips_through_the_file_as_data(tmp_path):
    ident = _load("leg-stable-window")
    path = ident.save(tmp_path / "w.aeid")
    assert Identifier.load(path).head == ident.head
    bad = tmp_path / "bad.aeid"
    _rewrite(path, bad, lambda m: m.update(head={"iterations": "__import__('os').system('x')"}))
    with pytest.raises(ValueError, match="bad.aeid.*iterations must be an integer"):
        Identifier.load(bad)
    _rewrite(path, bad, lambda m: m.update(head=[3]))
    with pytest.raises(ValueError, match="header entry 'head' must be a dict"):
        Identifier.load(bad)
    mcf = tmp_path / "mcf.aeid"
    _rewrite(path, mcf, lambda m: m.update(head={"iterations": 2, "fixed": {"q9": 0.0}}))
    with pytest.raises(ValueError, match="not elements"):
        Identifier.load(mcf)
