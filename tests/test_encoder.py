"""The residual 1-D CNN encoder: shapes, structure of paper Sec. III-A, config validation."""

import numpy as np
import pytest
import torch

from aeid_struct.encoder import Encoder, EncoderConfig


def test_paper_architecture_shapes():
    enc = Encoder(EncoderConfig(steps=300, outputs=4))
    # three sequential convolutions on the main path plus one shortcut convolution
    convs = [m for m in enc.modules() if isinstance(m, torch.nn.Conv1d)]
    assert len(convs) == 4
    assert all(c.out_channels == 8 for c in convs)
    dense = [m for m in enc.head if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in dense] == [10, 10, 4]
    # concatenated main + shortcut: 2 * 8 channels * 300 samples feed the first dense layer
    assert dense[0].in_features == 2 * 8 * 300
    out = enc(torch.randn(5, 1, 300))
    assert out.shape == (5, 4)


def test_inputs_channel_features_and_pooling():
    cfg = EncoderConfig(steps=100, outputs=3, inputs=True, features=1, pool=2, width=4,
                        dense=(7,), activation="relu")
    enc = Encoder(cfg)
    out = enc(torch.randn(2, 2, 100), torch.randn(2, 1))
    assert out.shape == (2, 3)
    assert enc.head[0].in_features == 2 * 4 * 50 + 1


def test_shortcut_and_main_both_reach_output():
    torch.manual_seed(0)
    enc = Encoder(EncoderConfig(steps=50, outputs=2))
    x = torch.randn(3, 1, 50)
    enc(x).sum().backward()
    assert enc.shortcut[0].weight.grad.abs().sum() > 0
    assert enc.main[0].weight.grad.abs().sum() > 0


def test_config_round_trip():
    cfg = EncoderConfig(steps=300, outputs=4, dense=(16, 8), pool=3)
    assert EncoderConfig.from_dict(cfg.to_dict()) == cfg


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"kernel": 4}, "kernel must be odd"),
        ({"width": 0}, "width must be a positive integer"),
        ({"dense": (10, -1)}, "dense must be a tuple of positive integers"),
        ({"activation": "sigmoid"}, "activation must be one of"),
        ({"pool": 400}, "pool must be <= steps"),
        ({"steps": -1}, "steps must be a non-negative integer"),
    ],
)
def test_config_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        EncoderConfig(**{"steps": 300, "outputs": 4, **kwargs})


def test_unset_config_cannot_build():
    with pytest.raises(ValueError, match="config.steps and config.outputs must be set"):
        Encoder(EncoderConfig())


def test_several_records_pool_each_to_a_common_length_and_stack_as_channels():
    cfg = EncoderConfig(steps=(300, 100), outputs=3, pool=(6, 2), features=2, width=4,
                        dense=(5,))
    assert (cfg.records, cfg.channels, cfg.length) == (2, 2, 50)
    enc = Encoder(cfg).double()
    y1, y2 = torch.randn(3, 1, 300, dtype=torch.float64), torch.randn(3, 1, 100,
                                                                      dtype=torch.float64)
    f = torch.randn(3, 2, dtype=torch.float64)
    # the same network fed the pooled records as one two-channel signal
    pooled = torch.cat([y1.reshape(3, 1, 50, 6).mean(-1), y2.reshape(3, 1, 50, 2).mean(-1)], 1)
    h = torch.cat([enc.main(pooled), enc.shortcut(pooled)], 1).flatten(1)
    torch.testing.assert_close(enc([y1, y2], f), enc.head(torch.cat([h, f], 1)))
    assert EncoderConfig.from_dict(cfg.to_dict()) == cfg


@pytest.mark.parametrize("kw, match", [
    (dict(steps=(300, 100), pool=(6, 3)), r"every record must pool to the same positive length"),
    (dict(steps=(300, 100), pool=(6, 2, 1)), r"pool must be a positive integer or a tuple of 2"),
    (dict(steps=(300,), pool=1), r"steps must be a non-negative integer, or a tuple of two"),
    (dict(steps=(300, 0)), r"steps must be a non-negative integer, or a tuple of two"),
])
def test_several_record_config_errors(kw, match):
    with pytest.raises(ValueError, match=match):
        EncoderConfig(outputs=3, **kw)


# -- the one numpy forward pass ------------------------------------------------------------------
@pytest.mark.parametrize(("config", "dtype", "activation"), [
    (EncoderConfig(steps=60, outputs=3, width=4, kernel=5, dense=(8,), pool=3), np.float64,
     "numpy"),
    (EncoderConfig(steps=61, outputs=2, inputs=True, features=1, kernel=3, dense=(6, 5)),
     np.float64, "numpy"),
    (EncoderConfig(steps=48, outputs=4, inputs=True, width=5, kernel=7, depth=2, pool=2,
                   activation="gelu"), np.float64, "torch"),
    (EncoderConfig(steps=64, outputs=3, inputs=True, dense=(12,), pool=4,
                   activation="silu"), None, "torch"),
])
@pytest.mark.parametrize("batch", [1, 5])
def test_numpy_pass_is_the_torch_module(config, dtype, activation, batch):
    """NumpyEncoder (convolve, the caller's features, dense) against the module's forward on
    the same records: float64 to 1e-12, the weights' float32 to float32 rounding."""
    from aeid_struct.encoder import NumpyEncoder

    torch.manual_seed(0)
    enc = Encoder(config).eval()
    channels = 2 if config.inputs else 1
    x = torch.rand(batch, channels, config.steps, dtype=torch.float64) * 2 - 1
    feats = torch.randn(batch, config.features, dtype=torch.float64) if config.features else None
    net = NumpyEncoder(enc, dtype=dtype, activation=activation)
    z = net.convolve(x.numpy().transpose(1, 0, 2))
    if feats is not None:
        z = np.concatenate([z, feats.numpy().astype(z.dtype)], axis=1)
    got = net.dense(z)
    if dtype is None:
        with torch.no_grad():
            want = enc(x.float(), None if feats is None else feats.float()).numpy()
        assert got.dtype == np.float32
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)
    else:
        with torch.no_grad():
            want = enc.double()(x, feats).numpy()
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("config, activation", [
    (EncoderConfig(steps=300, outputs=3, width=8, kernel=5, depth=3, dense=(48, 48), pool=6),
     "numpy"),
    (EncoderConfig(steps=48, outputs=4, inputs=True, features=2, width=5, kernel=7, depth=1,
                   pool=2, activation="relu"), "numpy"),
    (EncoderConfig(steps=64, outputs=3, inputs=True, features=1, dense=(12,), pool=4,
                   activation="silu"), "torch"),
])
@pytest.mark.parametrize("dtype", [np.float64, None])
def test_one_record_pass_is_the_torch_module(config, activation, dtype):
    """NumpyEncoder.one (its workspace, the bias as a row of ones, the pooling mean in the
    weights, the caller's affine map folded into the last layer) against the torch module on
    the same record, twice (the workspace reused) and from a copy (pickle, deepcopy)."""
    import copy
    import pickle

    from aeid_struct.encoder import NumpyEncoder

    torch.manual_seed(0)
    enc = Encoder(config).eval()
    channels = 2 if config.inputs else 1
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, (channels, config.steps))
    feats = rng.standard_normal(config.features) if config.features else None
    shift, scale = rng.standard_normal(config.outputs), rng.uniform(0.1, 2, config.outputs)
    net = NumpyEncoder(enc, dtype=dtype, activation=activation, affine=(shift, scale))
    with torch.no_grad():
        z = copy.deepcopy(enc).double()(
            torch.from_numpy(x[None]),
            None if feats is None else torch.from_numpy(feats[None])).numpy()[0]
    want = shift + scale * z
    tol = 1e-12 if dtype == np.float64 else 1e-5
    for other in (net, net, copy.deepcopy(net), pickle.loads(pickle.dumps(net))):
        got = other.one(x, feats)
        assert got.dtype == np.float64           # the affine map's layer computes in float64
        np.testing.assert_allclose(got, want, rtol=tol, atol=tol)
    # without a map: the network's own outputs, in the pass's dtype
    plain = NumpyEncoder(enc, dtype=dtype, activation=activation).one(x, feats)
    assert plain.dtype == (np.float64 if dtype == np.float64 else np.float32)
    np.testing.assert_allclose(plain, z, rtol=tol, atol=tol)


def test_inference_is_the_differentiable_pass_and_leaves_its_input_alone():
    """Without autograd the tanh runs in numpy, in place on each layer's fresh output: the
    same numbers as the recorded pass (float32 and float64), the caller's records untouched,
    and gradients still flow where autograd records."""
    torch.manual_seed(3)
    cfg = EncoderConfig(steps=120, outputs=3, inputs=True, features=1, pool=2, width=6,
                        dense=(9, 7))
    for dtype in (torch.float32, torch.float64):
        enc = Encoder(cfg).to(dtype)
        x = torch.rand(5, 2, 120, dtype=dtype) * 2 - 1
        f = torch.randn(5, 1, dtype=dtype)
        kept = x.clone()
        recorded = enc(x, f)
        with torch.no_grad():
            inferred = enc(x, f)
        assert torch.equal(x, kept)
        tol = 1e-6 if dtype == torch.float32 else 1e-13
        torch.testing.assert_close(inferred, recorded.detach(), rtol=tol, atol=tol)
        recorded.sum().backward()
        assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in enc.parameters())


def test_numpy_pass_refuses_what_numpy_cannot_evaluate():
    from aeid_struct.encoder import NumpyEncoder

    enc = Encoder(EncoderConfig(steps=40, outputs=2, activation="gelu"))
    with pytest.raises(ValueError, match=r"^no numpy path for activation 'gelu'"):
        NumpyEncoder(enc, activation="numpy")
    with pytest.raises(ValueError, match=r"^activation must be one of \('numpy', 'torch'\)"):
        NumpyEncoder(enc, activation="jax")
