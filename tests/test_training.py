"""Unsupervised training: the loss falls, checkpoints resume after a kill, configs validate."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

import aeid_struct as ae
from aeid_struct.data import PoleFamily
from aeid_struct.decoder import simulate
from aeid_struct.encoder import EncoderConfig
from aeid_struct.training import TrainConfig, train

FAMILY = PoleFamily(real=1, pairs=0, decay=(1.0, 4.0), gain=(0.5, 2.0))
SMALL = EncoderConfig(width=4, kernel=3, dense=(16,))


def _config(**kw):
    base = dict(dt=0.05, steps=40, count=400, epochs=12, batch=50, lr=1e-2, seed=0,
                progress=False)
    return TrainConfig(**{**base, **kw})


def test_training_lowers_the_loss_and_identifies():
    ident = train(ae.CCF(1, descartes=True), FAMILY, _config(), encoder=SMALL)
    hist = ident.meta["history"]
    assert len(hist["holdout_loss"]) == 12
    # Stated factor: 12 epochs on a first-order family cut the held-out loss (Eq. 14) 10x.
    assert hist["holdout_loss"][-1] < hist["holdout_loss"][0] / 10
    # and the identifier recovers a fresh first-order system's pole and gain within 10 %
    A, b, c = np.array([[-2.5]]), np.array([1.0]), np.array([2.5 * 1.2])
    y = simulate(A, b, c, 0.0, np.ones(40), 0.05)
    est = ident.identify(y)
    assert est.A[0, 0] == pytest.approx(-2.5, rel=0.1)
    assert -est.c[0] / est.A[0, 0] == pytest.approx(1.2, rel=0.1)


def test_training_noise_has_the_stated_level():
    from aeid_struct.training import _add_noise

    g = torch.Generator().manual_seed(0)
    y = torch.ones(2000, 400, dtype=torch.float64)
    y_bar = torch.full((2000,), 4.0, dtype=torch.float64)
    noisy = _add_noise(y, y_bar, 0.01, 0.05, g)
    level = (noisy - y).std(dim=1) / y_bar          # per-record std relative to max|y|
    assert level.min() > 0.01 * 0.85 and level.max() < 0.05 * 1.15
    assert level.mean().item() == pytest.approx(0.03, rel=0.03)   # uniform in [0.01, 0.05]
    assert (noisy - y).mean().abs().item() < 1e-3                  # zero mean
    assert torch.equal(_add_noise(y, y_bar, 0.0, 0.0, g), y)       # no noise asked, none added


def test_noise_training_records_its_settings():
    ident = train(ae.MCF(real=1, pairs=0), FAMILY, _config(epochs=2, noise=(0.0, 0.05)),
                  encoder=SMALL)
    assert ident.meta["train"]["config"]["noise"] == [0.0, 0.05]
    hist = ident.meta["history"]
    assert len(hist["holdout_loss"]) == 2 and all(np.isfinite(hist["holdout_loss"]))


_SCRIPT = """
import sys
sys.path.insert(0, {root!r})
import aeid_struct as ae
from aeid_struct.data import PoleFamily
from aeid_struct.encoder import EncoderConfig
from aeid_struct.training import TrainConfig, train
import torch
fam = PoleFamily(real=1, pairs=0, decay=(1.0, 4.0), gain=(0.5, 2.0))
cfg = TrainConfig(dt=0.05, steps=40, count=400, epochs=int(sys.argv[1]), batch=50, lr=1e-2,
                  seed=0, progress=False, checkpoint=sys.argv[2])
ident = train(ae.CCF(1, descartes=True), fam, cfg,
              encoder=EncoderConfig(width=4, kernel=3, dense=(16,)))
ident.save(sys.argv[3])
"""


@pytest.mark.slow
def test_killed_run_resumes_from_checkpoint(tmp_path):
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    script = tmp_path / "run.py"
    script.write_text(_SCRIPT.format(root=root))
    ckpt = tmp_path / "ckpt.pt"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    epochs = "40"
    proc = subprocess.Popen([sys.executable, str(script), epochs, str(ckpt),
                             str(tmp_path / "a.aeid")], env=env)
    deadline = time.time() + 120
    while not ckpt.exists() and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(0.3)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert ckpt.exists(), "no checkpoint was written"
    done = torch.load(ckpt, weights_only=True)["epoch"]
    assert 1 <= done < int(epochs), f"the run was not killed mid-training (epoch {done})"
    # Start again with the same checkpoint: it resumes and finishes.
    subprocess.run([sys.executable, str(script), epochs, str(ckpt), str(tmp_path / "a.aeid")],
                   env=env, check=True, timeout=300)
    assert torch.load(ckpt, weights_only=True)["epoch"] == int(epochs)
    # An uninterrupted run with the same seed gives the same weights: nothing was lost.
    subprocess.run([sys.executable, str(script), epochs, str(tmp_path / "fresh.pt"),
                    str(tmp_path / "b.aeid")], env=env, check=True, timeout=300)
    a = ae.Identifier.load(tmp_path / "a.aeid")
    b = ae.Identifier.load(tmp_path / "b.aeid")
    for (ka, va), (kb, vb) in zip(a.encoder.state_dict().items(),
                                  b.encoder.state_dict().items(), strict=True):
        assert ka == kb
        torch.testing.assert_close(va, vb, rtol=1e-5, atol=1e-6)


def test_checkpoint_of_another_setup_is_refused(tmp_path):
    ckpt = tmp_path / "ckpt.pt"
    train(ae.CCF(1), FAMILY, _config(epochs=1, checkpoint=str(ckpt)), encoder=SMALL)
    with pytest.raises(ValueError, match="was written for a different structure"):
        train(ae.CCF(1), FAMILY, _config(epochs=2, seed=5, checkpoint=str(ckpt)), encoder=SMALL)


@pytest.mark.parametrize(
    "kw, match",
    [
        ({"dt": 0.0}, "dt must be a positive finite number"),
        ({"steps": 0}, "steps must be a positive integer"),
        ({"holdout": 1.0}, r"holdout must be in \(0, 1\)"),
        ({"count": 2, "holdout": 0.2}, "count=2 is too small to hold out 20%"),
        ({"seconds": -1.0}, "seconds must be positive or None"),
        ({"gamma": -1.0}, "gamma must be >= 0"),
        ({"noise": (0.1, 0.0)}, "noise must be a level >= 0 or a"),
        ({"excitation": "chirp"}, "excitation must be one of"),
        ({"supervised": -1.0}, "supervised must be a finite weight >= 0"),
    ],
)
def test_config_errors(kw, match):
    with pytest.raises(ValueError, match=match):
        _config(**kw)


def test_structure_argument_checked():
    with pytest.raises(ValueError, match="structure must be a Structure"):
        train("CCF", FAMILY, _config())


def test_history_records_gradient_norms_before_clipping():
    ident = train(ae.CCF(1, descartes=True), FAMILY, _config(epochs=3, clip=1e-3), encoder=SMALL)
    hist = ident.meta["history"]
    assert hist["skipped"] == [0, 0, 0]
    # The norms are measured before clipping: far above the 1e-3 clip limit, finite.
    assert all(1e-3 < med <= mx < 1e6 for med, mx in
               zip(hist["grad_norm_median"], hist["grad_norm_max"], strict=True))


def test_non_finite_batches_are_skipped_not_stepped_on(monkeypatch):
    import aeid_struct.training as training

    real = training._batch_loss
    calls = {"n": 0}

    def flaky(*args):
        calls["n"] += 1
        loss = real(*args)
        return loss * float("nan") if calls["n"] % 3 == 0 else loss   # every third batch NaN

    monkeypatch.setattr(training, "_batch_loss", flaky)
    ident = train(ae.CCF(1, descartes=True), FAMILY, _config(epochs=2), encoder=SMALL)
    hist = ident.meta["history"]
    assert sum(hist["skipped"]) > 0
    # The weights never took a NaN step: every parameter is finite and the identifier works.
    assert all(torch.isfinite(p).all() for p in ident.encoder.parameters())
    assert np.isfinite(ident.identify(np.linspace(0.1, 1.0, 40)).A).all()


def test_joint_training_reads_both_records_and_lowers_the_loss():
    from symbolic import leg

    fam = ae.LegFamily(subsystem="joint")
    structure = ae.Physical(leg.joint_map(), bounds=fam.ranges, inverse=leg.joint_inverse())
    config = _config(dt=(0.02, 0.01), steps=(150, 50), count=600, epochs=8, lr=5e-3)
    ident = train(structure, fam, config,
                  encoder=EncoderConfig(width=4, kernel=3, dense=(16,), pool=(3, 1)))
    hist = ident.meta["history"]
    assert ident.records == 2 and ident.encoder.config.features == 2
    # Stated factor: 8 epochs of 480 records halve the held-out loss (Eq. 14, both records).
    assert hist["holdout_loss"][-1] < hist["holdout_loss"][0] / 2
    with pytest.raises(ValueError, match=r"describes 2 record\(s\) per parameter set"):
        train(structure, fam, _config(), encoder=SMALL)


def test_windows_mid_motion_train_with_a_fitted_initial_state():
    from aeid_struct.data import records
    from aeid_struct.decoder import initial_state

    # gamma = 0: the stationary-value term of Eq. 14 is a step-response term
    config = _config(epochs=10, count=600, excitation="mix", warmup=30, initial="fitted",
                     gamma=0.0)
    ident = train(ae.CCF(1, descartes=True), FAMILY, config, encoder=SMALL)
    assert ident.initial == "fitted" and ident.inputs
    hist = ident.meta["history"]
    # Stated factor: 10 epochs more than halve the held-out loss (measured 0.32 -> 0.11).
    assert hist["holdout_loss"][-1] < hist["holdout_loss"][0] / 2
    val = records(FAMILY, 20, steps=40, dt=0.05, excitation_kind="mix", seed=77, warmup=30)
    est = ident.identify(val.y, val.u)
    # the estimate starts where least squares puts its initial state, and its response too
    np.testing.assert_allclose(est.x0, initial_state(est.A, est.b, est.c, est.d, val.u, val.y,
                                                     0.05), rtol=1e-12)
    np.testing.assert_allclose(est.y_hat, ae.simulate(est.A, est.b, est.c, est.d, val.u, 0.05,
                                                      x0=est.x0), rtol=1e-12)
    with pytest.raises(ValueError, match=r"need initial='fitted'"):
        _config(warmup=5)


def test_stationary_weight_defaults_to_the_paper_for_steps_only():
    assert _config().stationary_weight == 1.0
    assert _config(excitation="mix").stationary_weight == 0.0
    assert _config(excitation="mix", gamma=0.5).stationary_weight == 0.5
    with pytest.raises(ValueError, match=r"gamma must be >= 0 or None; got -1"):
        _config(gamma=-1)


def test_fresh_records_every_epoch_are_new_and_reproducible(monkeypatch):
    import aeid_struct.training as training

    drawn = []
    real = training._redraw

    def spy(family, config, epoch, rows, u_all, y_all, yinf_all, scale_all):
        before = y_all[0][torch.as_tensor(rows)].clone()
        out = real(family, config, epoch, rows, u_all, y_all, yinf_all, scale_all)
        drawn.append((epoch, bool((y_all[0][torch.as_tensor(rows)] != before).any())))
        return out

    monkeypatch.setattr(training, "_redraw", spy)
    config = _config(epochs=3, fresh=True, excitation="mix", gamma=0.0)
    a = train(ae.CCF(1, descartes=True), FAMILY, config, encoder=SMALL)
    assert drawn == [(1, True), (2, True)]               # new training records from epoch 2 on
    b = train(ae.CCF(1, descartes=True), FAMILY, config, encoder=SMALL)
    for (k, va), vb in zip(a.encoder.state_dict().items(), b.encoder.state_dict().values(),
                           strict=True):
        assert torch.equal(va, vb), k                    # seeded draws: the same run twice


def test_training_records_its_range_and_estimates_outside_it_are_flagged():
    ident = train(ae.CCF(1, descartes=True), FAMILY, _config(), encoder=SMALL)
    rng = ident.training_range
    assert set(rng["elements"]) == {"a0", "c0"}
    lo, hi, err = rng["elements"]["a0"]
    # the family's poles are -1 .. -4: a0 = -pole spans [1, 4] (up to sampling), err >= 0
    assert 1.0 <= lo < 1.2 and 3.8 < hi <= 4.0 and err >= 0
    t = np.arange(40) * 0.05
    inside = 1.2 * (1 - np.exp(-2.5 * t))                # pole -2.5, gain 1.2: in the family
    far = 1.2 * (1 - np.exp(-12.0 * t))                  # pole -12: three times the fastest
    est = ident.identify(np.stack([inside, far]))
    assert est.outside.tolist() == [False, True]
    assert ident.identify(inside).outside is False
    # a file from before the calibration (no thresholds): no verdict until recalibrated, and
    # recalibrate re-creates the run's records and split, so it gives the same range exactly
    calibrated = ident.meta["training_range"]
    ident.meta["training_range"] = {k: v for k, v in calibrated.items() if k != "excess"}
    assert ident.identify(inside).outside is None
    from aeid_struct.training import recalibrate

    assert recalibrate(ident, FAMILY).meta["training_range"] == calibrated
    assert ident.identify(np.stack([inside, far])).outside.tolist() == [False, True]
    ident.meta.pop("training_range")
    assert ident.identify(inside).outside is None        # unknown range: no verdict


def test_supervised_targets_rebuild_the_true_systems_and_the_term_is_a_mean_square():
    from aeid_struct.data import records
    from aeid_struct.training import _batch_loss, _theta

    structure = ae.CCF(2, descartes=True)
    fam = ae.LegFamily(subsystem="stable")
    rec = records(fam, 6, steps=50, dt=0.02, excitation_kind="prbs", seed=3)
    gain = np.abs(rec.y_clean).max(axis=1) / np.abs(rec.u).max(axis=1)
    # the encoder describes u/u_bar -> y/y_bar: its targets rebuild A and c / gain exactly
    sys = structure.assemble(structure.elements(torch.tensor(_theta(structure, rec.systems,
                                                                    gain))))
    np.testing.assert_allclose(sys.A.numpy(), rec.systems.A, rtol=1e-9)
    np.testing.assert_allclose(sys.c.numpy(), rec.systems.c / gain[:, None], rtol=1e-9)
    ident = train(structure, fam, _config(dt=0.02, steps=50, count=20, epochs=1,
                                          excitation="prbs"), encoder=SMALL)
    y, u = torch.tensor(rec.y, dtype=torch.float32), torch.tensor(rec.u, dtype=torch.float32)
    yinf = torch.zeros(6)
    z = torch.randn(6, structure.p, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        raw = ident._forward(y, u, raw=True)[2]
        plain = _batch_loss(ident, y, u, yinf, 0.0)
        both = _batch_loss(ident, y, u, yinf, 0.0, z, 0.7)
    assert float(both - plain) == pytest.approx(0.7 * float(torch.mean((raw - z) ** 2)),
                                                rel=1e-4)


def test_supervised_training_steers_the_parameters_and_ends_on_the_paper_loss():
    from aeid_struct.data import records
    from aeid_struct.training import _theta

    val = records(FAMILY, 200, steps=40, dt=0.05, excitation_kind="mix", seed=77, warmup=30)
    gain = np.abs(val.y_clean).max(axis=1) / np.abs(val.u).max(axis=1)
    errors = {}
    for weight in (0.0, 1.0):
        config = _config(excitation="mix", warmup=30, initial="fitted", supervised=weight)
        ident = train(ae.CCF(1, descartes=True), FAMILY, config, encoder=SMALL)
        hist = ident.meta["history"]
        assert hist["holdout_loss"][-1] < hist["holdout_loss"][0] / 2    # Eq. 14, held out
        target = (_theta(ident.structure, val.systems, gain) - ident.theta_mean.numpy()) \
            / ident.theta_scale.numpy()
        with torch.no_grad():
            raw = ident._forward(torch.tensor(val.y, dtype=torch.float32),
                                 torch.tensor(val.u, dtype=torch.float32), raw=True)[2]
        errors[weight] = float(np.mean((raw.numpy() - target) ** 2))
    assert ident.meta["train"]["config"]["supervised"] == 1.0
    # Stated factor: the parameter term brings the outputs 1.5x closer to the true parameters
    assert errors[1.0] < errors[0.0] / 1.5, errors
