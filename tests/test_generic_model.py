"""aeid_struct.generic: the pole map (against numpy.poly), the identifier's window interface, the
file format (bit-identical round trip, every corruption refused with the path named), and the
torch projection against the numpy one (simulation.project) with gradcheck."""

import json

import numpy as np
import pytest
import torch

from aeid_struct.generic import (
    FORMAT,
    GenericConfig,
    GenericIdentifier,
    denominator,
    factors,
    load_generic,
    normalise_windows,
    poles_of,
    raw_of,
    read_generic,
    spectra,
)
from aeid_struct.simulation import initial_states_batch, project, project_batch

BAND, DAMPING = (0.005, 2.5), (0.003, 5.0)


def small(order=2, **kw):
    return GenericConfig(order=order, window=64, width=4, dense=(8,), **kw)


# -- the pole map ------------------------------------------------------------------------------

@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_pole_map_lands_in_band_and_damping(order):
    raw = torch.tensor(np.random.default_rng(0).normal(0, 30, (500, order)))
    w, zeta = factors(raw, BAND, DAMPING)
    assert w.shape == (500, (order + 1) // 2) and zeta.shape == (500, order // 2)
    assert bool(((w >= BAND[0] * (1 - 1e-12)) & (w <= BAND[1] * (1 + 1e-12))).all())
    assert bool(((zeta >= DAMPING[0] * (1 - 1e-12)) & (zeta <= DAMPING[1] * (1 + 1e-12))).all())
    p = poles_of(w.numpy(), zeta.numpy())
    assert (p.real < 0).all()                         # stable by construction
    # the first factor's natural frequency: |p1 p2| = w^2 for a pair, |p| = w for a real pole
    first = np.abs(p[:, 0] * p[:, 1]) ** 0.5 if order > 1 else np.abs(p[:, 0])
    np.testing.assert_allclose(first, w.numpy()[:, 0], rtol=1e-10)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_pole_map_reproduces_a_given_denominator(order):
    rng = np.random.default_rng(order)
    w = np.exp(rng.uniform(np.log(0.01), np.log(2.0), (20, (order + 1) // 2)))
    zeta = np.exp(rng.uniform(np.log(0.005), np.log(4.0), (20, order // 2)))
    raw = raw_of(w, zeta, BAND, DAMPING)
    w_t, z_t = factors(torch.tensor(raw), BAND, DAMPING)
    np.testing.assert_allclose(w_t.numpy(), w, rtol=1e-12)
    a = denominator(w_t, z_t).numpy()
    for i in range(20):
        roots = list(-w[i, order // 2:])
        for j in range(order // 2):   # s^2 + 2 zeta w s + w^2
            roots += list(np.roots([1.0, 2 * zeta[i, j] * w[i, j], w[i, j] ** 2]))
        expected = np.poly(roots).real                       # highest power first, monic
        np.testing.assert_allclose(a[i, ::-1], expected[1:], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.sort_complex(poles_of(w[i:i + 1], zeta[i:i + 1])[0]),
                                   np.sort_complex(np.array(roots)), rtol=1e-10)


def test_config_refuses_bad_fields():
    with pytest.raises(ValueError, match="order must be an integer in 1..4; got 5"):
        GenericConfig(order=5)
    with pytest.raises(ValueError, match=r"band must be a \(lo, hi\) pair .* got \(2.0, 1.0\)"):
        GenericConfig(order=2, band=(2.0, 1.0))
    with pytest.raises(ValueError,
                       match=r"window must be an integer in \[16, 65536\] \(samples\); got 8"):
        GenericConfig(order=2, window=8)
    with pytest.raises(ValueError, match=r"window \(66\) must be a multiple of pool \(4\)"):
        GenericConfig(order=2, window=66, pool=4)
    with pytest.raises(ValueError, match="the encoder fields are not a valid encoder: kernel"):
        GenericConfig(order=2, kernel=4)


# -- the window interface ----------------------------------------------------------------------

def test_denominators_and_poles_agree_and_ignore_offset_and_scale():
    torch.manual_seed(0)
    ident = GenericIdentifier(small(3))
    rng = np.random.default_rng(1)
    y, u = rng.standard_normal((4, 64)), rng.standard_normal((4, 64))
    den = ident.denominators(y, u)
    assert den.shape == (4, 4) and den.dtype == np.float64 and (den[:, 0] == 1).all()
    p = ident.poles(y, u)
    for i in range(4):
        np.testing.assert_allclose(np.poly(p[i]).real, den[i], rtol=1e-12, atol=1e-14)
    # the window normalisation removes a record's offset and scale
    np.testing.assert_allclose(ident.denominators(3.0 * y + 7.0, 0.5 * u - 2.0), den,
                               rtol=1e-6)


@pytest.mark.parametrize("order,activation,spectrum", [(1, "gelu", True), (2, "tanh", False),
                                                       (3, "silu", True), (4, "relu", True)])
def test_numpy_forward_equals_the_torch_forward_and_follows_weight_updates(order, activation,
                                                                           spectrum):
    # identification runs the encoder in numpy (generic.forward); training runs factors_batch
    # in torch: the same function, up to float32 rounding of the encoder
    torch.manual_seed(order)
    ident = GenericIdentifier(small(order, activation=activation, spectrum=spectrum))
    rng = np.random.default_rng(order)
    y, u = rng.standard_normal((5, 64)), rng.standard_normal((5, 64))

    def torch_denominators():
        y_n, u_n, _ = normalise_windows(torch.tensor(y), torch.tensor(u))
        with torch.no_grad():
            a = denominator(*ident.factors_batch(y_n, u_n)).numpy()
        return np.concatenate([np.ones((5, 1)), a[:, ::-1]], axis=1)

    np.testing.assert_allclose(ident.denominators(y, u), torch_denominators(), rtol=1e-4)
    before = ident.denominators(y, u)
    with torch.no_grad():                # an optimiser's in-place update of the weights
        for p in ident.encoder.parameters():
            p.add_(0.05 * torch.randn_like(p))
    after = ident.denominators(y, u)
    assert np.max(np.abs(after - before) / np.abs(before)) > 1e-3
    np.testing.assert_allclose(after, torch_denominators(), rtol=1e-4)


def test_constant_windows_give_nan_rows():
    ident = GenericIdentifier(small(2))
    y, u = np.random.default_rng(2).standard_normal((3, 64)), np.ones((3, 64))
    u[0] = np.arange(64.0)
    y[2] = 5.0
    den = ident.denominators(y, u)
    assert np.isfinite(den[0]).all() and np.isnan(den[1:]).all()
    assert np.isnan(ident.poles(y, u)[1:]).all()
    _, _, ok = normalise_windows(torch.tensor(y), torch.tensor(u))
    assert ok.tolist() == [True, False, False]


def test_windows_of_the_wrong_shape_are_refused():
    ident = GenericIdentifier(small(2))
    with pytest.raises(ValueError, match=r"y must be a \(K, 64\) array of windows; got shape "
                                         r"\(64,\)"):
        ident.denominators(np.zeros(64), np.zeros(64))
    with pytest.raises(ValueError, match="y and u must have one shape"):
        ident.poles(np.zeros((2, 64)), np.zeros((3, 64)))


# -- files -------------------------------------------------------------------------------------

def test_save_load_round_trip_is_bit_identical(tmp_path):
    torch.manual_seed(3)
    ident = GenericIdentifier(small(4, band=(0.01, 1.0)), meta={"name": "x", "train": {"a": 1}})
    path = ident.save(tmp_path / "sub" / "g.aeid")
    back = load_generic(path)
    assert back.config == ident.config and back.meta == ident.meta
    for (k, v), (k2, v2) in zip(ident.encoder.state_dict().items(),
                                back.encoder.state_dict().items(), strict=True):
        assert k == k2 and torch.equal(v, v2)
    y = np.random.default_rng(4).standard_normal((5, 64))
    np.testing.assert_array_equal(back.denominators(y, y[::-1]), ident.denominators(y, y[::-1]))


def _rewrite(path, head=None, tensors=None):
    from safetensors import safe_open
    from safetensors.torch import save_file

    with safe_open(str(path), framework="pt") as f:
        old_head = json.loads(f.metadata()["aeid"])
        old = {k: f.get_tensor(k) for k in f.keys()}
    save_file(tensors(old) if tensors else old, str(path),
              metadata={"aeid": json.dumps(head(old_head) if head else old_head)})


@pytest.mark.parametrize("head, tensors, message", [
    (lambda h: {**h, "format": "aeid-struct/identifier/2"}, None,
     r"holds a structured identifier \(aeid_struct.Identifier\), kind 'identifier', not a "
     r"generic identifier \(any SISO record\): read it with ae.Identifier.load, or with "
     r"ae.load"),
    (lambda h: {**h, "extra": 1}, None, "the header must have exactly the entries"),
    (lambda h: {**h, "meta": [1]}, None, "header entry 'meta' must be a dict"),
    (lambda h: {**h, "config": {**h["config"], "order": 7}}, None,
     "header entry 'config' is not valid: order must be an integer in 1..4"),
    (lambda h: {**h, "config": {**h["config"], "depth2": 3}}, None,
     "header entry 'config' must have exactly the entries"),
    (lambda h: {**h, "config": {k: v for k, v in h["config"].items() if k != "spectrum"}},
     None, "header entry 'config' must have exactly the entries"),
    (lambda h: {**h, "config": {**h["config"], "width": 5}}, None,
     "has shape .*; the header's 'config' needs"),
    (None, lambda t: {k: v for k, v in t.items() if "head.0.bias" not in k},
     r"the weights do not match the header's 'config' \(missing \['encoder.head.0.bias'\]"),
    (None, lambda t: {**t, "encoder.head.0.bias": t["encoder.head.0.bias"] * np.nan},
     "weight 'encoder.head.0.bias' must hold finite float32 numbers"),
    (None, lambda t: {**t, "encoder.head.0.bias": t["encoder.head.0.bias"].double()},
     "must hold finite float32 numbers; got dtype torch.float64"),
])
def test_corrupted_files_are_refused_naming_the_path(tmp_path, head, tensors, message):
    path = GenericIdentifier(small(2)).save(tmp_path / "g.aeid")
    _rewrite(path, head, tensors)
    with pytest.raises(ValueError, match=message) as err:
        read_generic(path)
    assert str(path) in str(err.value)


def test_unreadable_files_and_unknown_names_are_refused(tmp_path):
    junk = tmp_path / "junk.aeid"
    junk.write_bytes(b"not safetensors at all")
    with pytest.raises(ValueError, match=f"path '{junk}' is not an aeid-struct generic "
                                         f"identifier file"):
        read_generic(junk)
    with pytest.raises(ValueError, match="path must be an existing generic identifier file"):
        read_generic(tmp_path / "missing.aeid")
    with pytest.raises(ValueError, match=r"name_or_path must be one of \['generic-1'"):
        load_generic("generic-9")
    assert FORMAT == "aeid-struct/3"


# -- the torch projection against the numpy one ------------------------------------------------

def _ccf(den):
    n = len(den) - 1
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1, :] = -np.asarray(den[1:], float)[::-1]
    return A, np.eye(n)[-1]


@pytest.mark.parametrize("den, dt", [
    ([1.0, 0.3], 1.0),
    (np.poly([-0.05 + 0.4j, -0.05 - 0.4j]).real, 1.0),
    (np.poly([-0.2, -0.1 + 0.9j, -0.1 - 0.9j]).real, 0.5),
    (np.poly([-0.02 + 0.3j, -0.02 - 0.3j, -1.5, -0.3]).real, 1.0),
])
def test_torch_projection_equals_numpy_project(den, dt):
    A, b = _ccf(den)
    rng = np.random.default_rng(5)
    y, u = rng.standard_normal(300), rng.standard_normal(300).cumsum() * 0.1
    p = project(A, b, y, u, dt)
    t = [torch.tensor(x)[None] for x in (A, b, y, u)]
    q = project_batch(*t, dt, ridge=0.0)
    x0 = initial_states_batch(t[0], t[1], q.c, q.theta, dt)
    np.testing.assert_allclose(q.c[0].numpy(), p.c, rtol=1e-8, atol=1e-8)
    assert float(q.d[0]) == pytest.approx(p.d, abs=1e-8)
    assert float(q.y_offset[0]) == pytest.approx(p.y_offset, abs=1e-8)
    np.testing.assert_allclose(x0[0].numpy(), p.x0, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(q.y_hat[0].numpy(), p.y_hat, atol=1e-8)
    np.testing.assert_allclose(q.residual[0].numpy(), y - p.y_hat, atol=1e-8)
    # the default ridge changes a well-posed fit by far less than the noise
    r = project_batch(*t, dt)
    np.testing.assert_allclose(r.y_hat[0].numpy(), p.y_hat, atol=1e-6)


def test_torch_projection_without_feedthrough_and_offset():
    A, b = _ccf(np.poly([-0.3, -0.7]).real)
    rng = np.random.default_rng(6)
    y, u = rng.standard_normal(80), rng.standard_normal(80)
    p = project(A, b, y, u, 1.0, feedthrough=False, offset=False)
    q = project_batch(*[torch.tensor(x)[None] for x in (A, b, y, u)], feedthrough=False,
                      offset=False, ridge=0.0)
    np.testing.assert_allclose(q.y_hat[0].numpy(), p.y_hat, atol=1e-9)
    assert float(q.d[0]) == 0.0 and float(q.y_offset[0]) == 0.0


def test_torch_projection_gradcheck():
    rng = np.random.default_rng(7)
    y, u = (torch.tensor(rng.standard_normal((2, 24))) for _ in range(2))

    def residual_norm(a):
        A = torch.zeros(2, 2, 2, dtype=torch.float64)
        A = A + torch.tensor([[0.0, 1.0], [0.0, 0.0]], dtype=torch.float64)
        A = torch.cat([A[:, :1], -a[:, None, :]], dim=1)
        b = torch.tensor([[0.0, 1.0]] * 2, dtype=torch.float64)
        return (project_batch(A, b, y, u, 1.0).residual ** 2).sum(dim=1)

    a = torch.tensor([[0.2, 0.5], [0.05, 0.3]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(residual_norm, (a,), eps=1e-6, atol=1e-6)


def test_spectral_features_peak_at_a_sinusoids_bin():
    k = np.arange(256)
    y = torch.tensor(np.sin(2 * np.pi * 20 * k / 256))[None]
    u = torch.tensor(np.cos(2 * np.pi * 50 * k / 256))[None]
    f = spectra(y, u)
    assert f.shape == (1, 2 * 129)
    assert int(f[0, :129].argmax()) == 20 and int(f[0, 129:].argmax()) == 50
    # the floor: a window without power gives log(1e-3) / 4, finite
    assert float(spectra(torch.zeros(1, 256, dtype=torch.float64), u)[0, 0]) == \
        pytest.approx(np.log(1e-3) / 4)


def test_an_identifier_without_spectral_features():
    config = small(2, spectrum=False)
    assert config.encoder_config().features == 0 and small(2).encoder_config().features == 66
    ident = GenericIdentifier(config)
    y = np.random.default_rng(8).standard_normal((2, 64))
    assert np.isfinite(ident.denominators(y, y[::-1])).all()
    with pytest.raises(ValueError, match="spectrum must be True or False; got 1"):
        small(2, spectrum=1)
