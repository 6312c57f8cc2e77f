"""training.train_generic: a generic identifier learns the poles of a tiny family (its held-out
loss falls), a stopped run resumes to the same weights as an uninterrupted one, the recipe is
recorded, and bad settings and checkpoints are refused."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from aeid_struct.generic import GenericConfig, GenericIdentifier, normalise_windows
from aeid_struct.simulation import project, simulate_batch
from aeid_struct.training import GenericTrainConfig, train_generic
from aeid_struct.training.generic import window_loss


class TinyFamily:
    """Stable resonant systems of order 2 in a narrow band, staircase inputs,
    a mid-motion start and 1 % noise, simulated with the exact decoder (records of dt = 1)."""

    order = 2

    def records(self, count, steps, rng):
        # resonances far above where an untrained encoder puts its poles (w ~ 0.1, the band's
        # log-centre), so that learning shows in the held-out loss
        w = np.exp(rng.uniform(np.log(0.3), np.log(0.8), count))
        z = np.exp(rng.uniform(np.log(0.05), np.log(0.5), count))
        A = np.zeros((count, 2, 2))
        A[:, 0, 1] = 1.0
        A[:, 1, 0], A[:, 1, 1] = -w ** 2, -2 * z * w
        b = np.tile([0.0, 1.0], (count, 1))
        c = np.stack([w ** 2, rng.uniform(-1, 1, count) * w], axis=1)
        hold = rng.integers(3, 20, count)
        levels = rng.uniform(-1, 1, (count, steps))
        k = np.arange(steps)
        u = np.take_along_axis(levels, (k[None] // hold[:, None]) * hold[:, None], axis=1)
        x0 = rng.standard_normal((count, 2)) * np.stack([np.ones(count), w], axis=1)
        y = simulate_batch(*(torch.as_tensor(v) for v in (A, b, c, np.zeros(count), u)), 1.0,
                           torch.as_tensor(x0)).numpy()
        y = y + 0.01 * y.std(axis=1, keepdims=True) * rng.standard_normal(y.shape)
        return SimpleNamespace(y=y, u=u)


CONFIG = GenericConfig(order=2, window=64, band=(0.01, 1.0), width=4, dense=(16,))


def settings(**kw):
    base = dict(epochs=3, count=192, holdout=64, batch=32, lr=1e-2, progress=False, threads=1)
    return GenericTrainConfig(**{**base, **kw})


def held_out_loss(ident, seed):
    rec = TinyFamily().records(64, 64, np.random.default_rng([seed, 0]))
    y, u, _ = normalise_windows(torch.tensor(rec.y), torch.tensor(rec.u))
    with torch.no_grad():
        return float(torch.log(window_loss(ident, y, u) + 1e-8).mean())


def test_training_reduces_the_held_out_loss_and_records_the_recipe():
    torch.manual_seed(0)                 # the initial weights train_generic starts from
    before = held_out_loss(GenericIdentifier(CONFIG), 0)
    ident = train_generic(CONFIG, settings(epochs=4), family=TinyFamily(), meta={"name": "t"})
    hist, info = ident.meta["history"], ident.meta["train"]
    assert len(hist["holdout_loss"]) == 4 and info["epochs"] == 4
    assert info["best_holdout_loss"] == min(hist["holdout_loss"])
    assert held_out_loss(ident, 0) == pytest.approx(info["best_holdout_loss"], rel=1e-9)
    assert info["best_holdout_loss"] < before - 0.4          # 1 - R^2 down by a factor 1.5
    assert info["settings"]["lr"] == 1e-2 and info["seed"] == 0
    assert info["config"] == CONFIG.to_dict() and ident.meta["name"] == "t"
    assert 0 < info["holdout_fit_median"] <= 100


def test_threads_are_the_runs_and_restored():
    before = torch.get_num_threads()
    seen = []
    train_generic(CONFIG, settings(epochs=1, threads=1), family=TinyFamily(),
                  on_epoch=lambda e, h: seen.append(torch.get_num_threads()))
    assert seen == [1] and torch.get_num_threads() == before


class Stop(Exception):
    pass


def test_a_stopped_run_resumes_to_the_uninterrupted_weights(tmp_path):
    whole = train_generic(CONFIG, settings(checkpoint=str(tmp_path / "a.ckpt")),
                          family=TinyFamily())

    def stop(epoch, history):
        if epoch == 2:
            raise Stop

    path = tmp_path / "b.ckpt"
    with pytest.raises(Stop):
        train_generic(CONFIG, settings(checkpoint=str(path)), family=TinyFamily(), on_epoch=stop)
    resumed = train_generic(CONFIG, settings(checkpoint=str(path)), family=TinyFamily())
    for (k, v), (_, w) in zip(whole.encoder.state_dict().items(),
                              resumed.encoder.state_dict().items(), strict=True):
        assert torch.equal(v, w), k
    for key in ("train_loss", "holdout_loss", "lr", "holdout_fit"):
        assert whole.meta["history"][key] == resumed.meta["history"][key]


def test_worker_processes_simulate_the_same_windows_and_resume_alike(tmp_path):
    # the windows come from the blocks' own streams whoever simulates them: two workers, one
    # epoch ahead, give the one-process run bit for bit, stopped and resumed too
    one = train_generic(CONFIG, settings(), family=TinyFamily())

    def stop(epoch, history):
        if epoch == 2:
            raise Stop

    path = tmp_path / "w.ckpt"
    with pytest.raises(Stop):
        train_generic(CONFIG, settings(workers=2, checkpoint=str(path)), family=TinyFamily(),
                      on_epoch=stop)
    two = train_generic(CONFIG, settings(workers=2, checkpoint=str(path)), family=TinyFamily())
    for (k, v), (_, w) in zip(one.encoder.state_dict().items(),
                              two.encoder.state_dict().items(), strict=True):
        assert torch.equal(v, w), k
    assert one.meta["history"]["holdout_loss"] == two.meta["history"]["holdout_loss"]
    assert two.meta["train"]["settings"]["workers"] == 2
    local = TinyFamily()
    local.records = lambda count, steps, rng: TinyFamily().records(count, steps, rng)
    with pytest.raises(ValueError, match="family must be picklable for workers=2"):
        train_generic(CONFIG, settings(workers=2), family=local)


def test_vanished_gradients_are_a_stall():
    from aeid_struct.training.progress import STALL, stalled

    # the wide encoder at lr 3e-3 on the GPU (aeid_struct/pretrained/README.md): its largest
    # gradient norm fell from 3.8 to 0 after one epoch, and later from 4.0 to about 5e-5
    dead = {"grad_norm_max": [3.8, 0.0, 0.0, 0.0, 0.0]}
    (note,) = stalled(dead)
    assert note.startswith("the gradients vanished after epoch 1: ") and "(3.8; last 0)" in note
    slow = {"grad_norm_max": [4.0, 4.9, 2.0, 4e-5, 5e-5, 3.9e-5, 4.0 * STALL * 1.01, 5e-5,
                              4e-5, 4e-5]}
    assert "vanished after epoch 7" in stalled(slow)[0]
    # a training run keeps them within a factor of ten (the shipped generic-2's 5.5 -> 6.7);
    # two quiet epochs are not yet a stall, and non-finite ones (skipped) are left out
    assert stalled({"grad_norm_max": [5.5, 10.0, 6.7, 6.7]}) == []
    assert stalled({"grad_norm_max": [3.8, 0.0, 0.0, 5.0]}) == []
    assert stalled({"grad_norm_max": [3.8, math.nan, 0.0, 0.0, 0.0]})[0].startswith(
        "the gradients vanished after epoch 1")
    assert stalled({"grad_norm_max": []}) == stalled({}) == []


def test_a_stalled_run_stops_and_warns(monkeypatch):
    from aeid_struct.training import UndertrainedWarning
    from aeid_struct.training import generic as tg

    # the run's own gradient norms, as a stalled run records them
    norms = iter([3.0, 0.0, 0.0, 0.0])
    monkeypatch.setattr(tg.distributed, "gradient_step",
                        lambda opt, loss, params, clip: next(norms, 0.0))
    with pytest.warns(UndertrainedWarning, match=r"the gradients vanished after epoch 1: .*"
                                                 r"\(the run stopped at epoch 4\)"):
        ident = train_generic(CONFIG, settings(epochs=9, count=32, batch=32),
                              family=TinyFamily())
    # weights that no longer move: the run stops where the stall shows, not at its budget
    assert len(ident.meta["history"]["grad_norm_max"]) == 4 and ident.meta["train"]["epochs"] == 4


def test_a_checkpoint_of_another_run_is_refused(tmp_path):
    path = tmp_path / "c.ckpt"
    train_generic(CONFIG, settings(epochs=1, checkpoint=str(path)), family=TinyFamily())
    with pytest.raises(ValueError, match=f"checkpoint '{path}' cannot be resumed: it was "
                                         "written for a different"):
        train_generic(CONFIG, settings(epochs=2, lr=2e-2, checkpoint=str(path)),
                      family=TinyFamily())
    path.write_bytes(b"junk")
    with pytest.raises(ValueError, match=f"checkpoint '{path}' cannot be resumed"):
        train_generic(CONFIG, settings(checkpoint=str(path)), family=TinyFamily())


@pytest.mark.parametrize("kw, message", [
    (dict(epochs=0), "epochs must be a positive integer; got 0"),
    (dict(loss="mse"), r"loss must be one of \('log', 'nmse'\); got 'mse'"),
    (dict(seconds=-1.0), "seconds must be positive or None; got -1.0"),
    (dict(min_epochs=9), r"min_epochs must be an integer in \[1, epochs=3\]; got 9"),
    (dict(clip=0), r"clip must be positive \(inf: no clipping\); got 0"),
    (dict(seed=-1), "seed must be a non-negative integer; got -1"),
    (dict(threads=0), "threads must be a positive integer; got 0"),
    (dict(workers=0), "workers must be a positive integer; got 0"),
])
def test_bad_settings_are_refused(kw, message):
    with pytest.raises(ValueError, match=message):
        settings(**kw)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match="config must be a GenericConfig; got dict"):
        train_generic({}, settings())
    with pytest.raises(ValueError, match="train must be a GenericTrainConfig; got dict"):
        train_generic(CONFIG, {})
    with pytest.raises(ValueError, match="family must have records.* and order 3; got "
                                         "TinyFamily of order 2"):
        train_generic(GenericConfig(order=3, window=64), settings(), family=TinyFamily())


def test_the_nmse_loss_is_one_minus_r_squared():
    ident = GenericIdentifier(CONFIG)
    rec = TinyFamily().records(8, 64, np.random.default_rng(3))
    y, u, _ = normalise_windows(torch.tensor(rec.y), torch.tensor(rec.u))
    with torch.no_grad():
        e = window_loss(ident, y, u)
        A, b = ident.companion_batch(y, u)

    for i in range(8):
        p = project(A[i].numpy(), b[i].numpy(), y[i].numpy(), u[i].numpy(), 1.0)
        assert float(e[i]) == pytest.approx((1 - p.fit / 100) ** 2, rel=1e-6)
    assert math.isfinite(float(e.sum()))


# -- the command -------------------------------------------------------------------------------

@pytest.mark.parametrize("argv, message", [
    (["--order", "5"], "train-generic: order must be an integer in 1..4; got 5"),
    (["--order", "x"], "argument --order: expected an integer > 0; got 'x'"),
    (["--order", "2", "--minutes", "-1"], "argument --minutes: expected a finite number > 0"),
    (["--order", "2", "--loss", "l1"], r"train-generic: loss must be one of \('log', 'nmse'\)"),
    (["--order", "2", "--init", "generic-9"],
     "train-generic: --init 'generic-9': name_or_path must be one of"),
    (["--order", "2", "--init", "generic-3"],
     r"train-generic: --init 'generic-3' is an identifier of order 3, window 256, width 12, "
     r"depth 3, dense \[64, 64\]; --order 2 --window 256 --width 12 --depth 3 --dense 64 64"),
    (["--order", "2", "--width", "16", "--init", "generic-2"],
     r"--init 'generic-2' is an identifier of order 2, window 256, width 12, .* --width 16"),
    (["--order", "2", "--integrating", "0.7", "--unstable", "0.6"],
     r"train-generic: integrating \+ unstable must be at most 1"),
])
def test_the_command_refuses_bad_values_in_one_line(tmp_path, argv, message):
    from aeid_struct.cli.errors import UsageExit
    from aeid_struct.cli.main import main

    with pytest.raises(UsageExit, match=message) as err:
        main(["train-generic", *argv, "--out", str(tmp_path / "g.aeid")])
    assert err.value.code == 2 and "\n" not in str(err.value)
    assert not (tmp_path / "g.aeid").exists()


def test_the_command_does_not_extend_a_run_without_resume(tmp_path):
    from aeid_struct.cli.errors import UsageExit
    from aeid_struct.cli.main import main

    (tmp_path / "g.aeid.ckpt").write_bytes(b"")
    with pytest.raises(UsageExit, match="checkpoint .*g.aeid.ckpt' exists; pass --resume"):
        main(["train-generic", "--order", "2", "--out", str(tmp_path / "g.aeid")])
    with pytest.raises(UsageExit, match="--out .* is a folder"):
        main(["train-generic", "--order", "2", "--out", str(tmp_path)])


def test_non_finite_weights_give_a_nan_loss_not_an_error():
    ident = GenericIdentifier(CONFIG)
    rec = TinyFamily().records(4, 64, np.random.default_rng(4))
    y, u, _ = normalise_windows(torch.tensor(rec.y), torch.tensor(rec.u))
    with torch.no_grad():
        ident.encoder.head[-1].bias.fill_(math.nan)
        assert torch.isnan(window_loss(ident, y, u)).all()


def test_the_command_trains_writes_and_resumes(tmp_path, capsys):
    import json

    from aeid_struct.cli.main import main
    from aeid_struct.generic import load_generic

    out = tmp_path / "g1.aeid"
    argv = ["train-generic", "--order", "1", "--epochs", "1", "--count", "32", "--holdout",
            "16", "--window", "32", "--batch", "16", "--threads", "1", "--quiet", "--out",
            str(out)]
    assert main(argv) == 0
    ident = load_generic(out)
    assert ident.config.order == 1 and ident.config.window == 32
    run = json.loads(out.with_suffix(".json").read_text())
    assert run["meta"]["train"]["epochs"] == 1 and run["meta"]["name"] == "g1"
    assert run["meta"]["train"]["family"]["type"] == "GenericFamily"
    assert "wrote" in capsys.readouterr().out
    # a second epoch from the checkpoint: the first epoch's history is kept
    assert main([*argv[:4], "2", *argv[5:], "--resume"]) == 0
    history = load_generic(out).meta["history"]["holdout_loss"]
    assert len(history) == 2 and history[0] == run["meta"]["history"]["holdout_loss"][0]


# -- fine-tuning and the growth family -----------------------------------------------------------

def test_init_starts_from_the_given_weights_and_pins_the_checkpoint(tmp_path):
    torch.manual_seed(5)
    start = GenericIdentifier(CONFIG)
    # a learning rate too small to move the weights: the run ends where it started
    still = train_generic(CONFIG, settings(epochs=1, lr=1e-12), family=TinyFamily(), init=start)
    fresh = train_generic(CONFIG, settings(epochs=1, lr=1e-12), family=TinyFamily())
    for (k, v), (_, w) in zip(start.encoder.state_dict().items(),
                              still.encoder.state_dict().items(), strict=True):
        torch.testing.assert_close(w, v, rtol=0, atol=1e-9, msg=k)
    assert any(not torch.allclose(v, f) for v, f in zip(
        start.encoder.state_dict().values(), fresh.encoder.state_dict().values(), strict=True))
    assert len(still.meta["train"]["init"]) == 64 and fresh.meta["train"]["init"] is None
    # a checkpoint resumes only from the weights it started from
    path = tmp_path / "i.ckpt"
    train_generic(CONFIG, settings(epochs=1, checkpoint=str(path)), family=TinyFamily(),
                  init=start)
    torch.manual_seed(6)
    with pytest.raises(ValueError, match="cannot be resumed: it was written for a different"):
        train_generic(CONFIG, settings(epochs=2, checkpoint=str(path)), family=TinyFamily(),
                      init=GenericIdentifier(CONFIG))
    other = GenericConfig(order=2, window=64, band=(0.01, 1.0), width=5, dense=(16,))
    with pytest.raises(ValueError, match="init must be a GenericIdentifier of the configuration"):
        train_generic(CONFIG, settings(epochs=1), family=TinyFamily(),
                      init=GenericIdentifier(other))


def test_growth_family_reads_each_record_under_a_weight_that_leaves_it_stable():
    from aeid_struct.generic.windows import weighted
    from aeid_struct.training import GenericFamily, GrowthFamily

    base = GenericFamily(order=3, integrating=0.3, unstable=0.4, growth=(2e-3, 3e-2))
    fam = GrowthFamily(base=base)
    got = fam.records(300, 256, np.random.default_rng(2))
    rec = base.records(300, 256, np.random.default_rng(2))      # the same draws come first
    top = rec.systems.poles.real.max(axis=1)
    options = np.array([0.0, 2.0, 4.0]) / 256
    assert set(np.round(got.sigma * 256, 9)) <= {0.0, 2.0, 4.0}
    # stable where a weight allows it; the strongest weight where none does
    ok = options.max() > top
    assert np.all(got.sigma[ok] > top[ok]) and np.all(got.sigma[~ok] == options.max())
    assert (~ok).any() and (top > 0).any() and (got.sigma == 0).any()
    # each record is the base record under its weight (generic.windows.weighted)
    for i in range(0, 300, 13):
        if got.sigma[i] == 0:
            np.testing.assert_array_equal(got.y[i], rec.y[i])
            continue
        y, u, _ = weighted(rec.y[i: i + 1], rec.u[i: i + 1], (got.sigma[i] * 256,))
        np.testing.assert_allclose(got.y[i], y[1], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(got.u[i], u[1], rtol=1e-12, atol=1e-15)
    assert fam.order == 3
    with pytest.raises(ValueError, match="base must be a GenericFamily"):
        GrowthFamily(base=TinyFamily())
    with pytest.raises(ValueError, match="growth must be a non-empty tuple of positive"):
        GrowthFamily(base=base, growth=(0.0,))


def test_the_command_fine_tunes_on_integrating_and_unstable_plants(tmp_path):
    import json

    from aeid_struct.cli.main import main

    out = tmp_path / "g2.aeid"
    assert main(["train-generic", "--order", "2", "--init", "generic-2", "--integrating", "0.2",
                 "--unstable", "0.2", "--growth-weights", "--epochs", "1", "--count", "64",
                 "--holdout", "32", "--batch", "32", "--threads", "1", "--quiet", "--out",
                 str(out)]) == 0
    info = json.loads(out.with_suffix(".json").read_text())["meta"]["train"]
    assert info["family"]["type"] == "GrowthFamily"
    assert info["family"]["base"]["integrating"] == 0.2 and len(info["init"]) == 64
    assert info["family"]["base"]["growth"] == [0.5 / 256, 3.0 / 256]
