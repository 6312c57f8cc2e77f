"""The residual 1-D CNN encoder: shapes, structure of paper Sec. III-A, config validation."""

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
