"""Data-parallel training of the generic identifiers (train_generic, ``aeid-struct train-generic``)
under torchrun: per-block fresh windows, a real 2-process gloo run that matches the single-process
run, the file loads and identifies, a killed rank and the resumed run."""

import os
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import torchrun

from aeid_struct.cli.main import main
from aeid_struct.generic import GenericConfig, load_generic, normalise_windows
from aeid_struct.simulation import simulate
from aeid_struct.training import GenericFamily, GenericTrainConfig, train_generic
from aeid_struct.training import distributed as dd
from aeid_struct.training.generic import _check_shares

ROOT = Path(__file__).resolve().parents[1]
#: The tolerance of a 2-process run against one process, relative, as tests/test_distributed.py
#: argues it: the encoder runs in float32, a process's loss sums its share's windows and DDP adds
#: the two shares' gradients, where one process sums the whole batch -- the same sums in another
#: order. Measured after 2 epochs: 6e-9 on the held-out loss, 5e-8 on the fit, 5e-7 on the median
#: gradient norm; a share left unweighted (each process's mean, not its sum times W / n) moves the
#: held-out loss by 3e-3 and the median gradient norm by 0.2.
RTOL_PROCESSES = 1e-5
#: Batches of 95 of 256 windows: 95, 95, 66, shared 48 / 47 and 33 / 33, so that the shares are
#: unequal and straddle the blocks of 64 (both processes simulate block 0, each using its part).
_CLI = ["train-generic", "--order", "1", "--window", "64", "--count", "256", "--holdout", "64",
        "--batch", "95", "--epochs", "2", "--lr", "0.01", "--threads", "1", "--quiet"]
SMALL = GenericConfig(order=1, window=64, width=4, dense=(16,))

# Run under torchrun by every process: (1) the CLI, data-parallel; (2) a checkpointed run whose
# rank 1 kills itself (SIGKILL) after epoch 2's checkpoint.
_SCRIPT = """
import os, signal, sys
sys.path.insert(0, {root!r})
from aeid_struct.cli.main import main
from aeid_struct.generic import GenericConfig
from aeid_struct.training import GenericTrainConfig, train_generic
out, rank = sys.argv[1], int(os.environ["RANK"])
main({cli!r} + ["--out", os.path.join(out, "two.aeid")])

def on_epoch(epoch, history):
    if epoch == 2 and rank == 1:
        os.kill(os.getpid(), signal.SIGKILL)

train_generic(GenericConfig(order=1, window=64, width=4, dense=(16,)),
              GenericTrainConfig(epochs=4, count=192, holdout=64, batch=64, lr=1e-2,
                                 progress=False, threads=1,
                                 checkpoint=os.path.join(out, "run.ckpt")), on_epoch=on_epoch)
"""


def _settings(**kw):
    base = dict(epochs=4, count=192, holdout=64, batch=64, lr=1e-2, progress=False, threads=1)
    return GenericTrainConfig(**{**base, **kw})


@pytest.fixture(scope="module")
def launch(tmp_path_factory):
    """One torchrun launch of two gloo processes: what it wrote and how it ended."""
    out = tmp_path_factory.mktemp("torchrun_generic")
    script = out / "run.py"
    script.write_text(_SCRIPT.format(root=str(ROOT), cli=_CLI))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    done = torchrun(["--standalone", "--nproc-per-node", "2", "--monitor-interval", "0.1",
                     script, out], cwd=ROOT, env=env)
    return out, done


# -- the helpers -----------------------------------------------------------------------------
def test_block_windows_are_the_blocks_streams_whoever_draws_them():
    family = GenericFamily(order=2)
    whole_y, whole_u, ok = dd.block_windows(family, 5, 150, 48, 3, np.arange(150))
    assert whole_y.shape == (150, 48) and 140 <= int(ok.sum()) < 150   # window 36: constant
    # the oracle: block k of epoch 3 is family.records on the stream (seed, epoch + 1, k);
    # the last block holds the 150 - 128 = 22 windows left
    for k, size in ((0, 64), (2, 22)):
        rec = family.records(size, 48, np.random.default_rng([5, 4, k]))
        y, u, good = normalise_windows(torch.tensor(rec.y), torch.tensor(rec.u))
        np.testing.assert_array_equal(ok[64 * k: 64 * k + size], good)
        np.testing.assert_array_equal(whole_y[64 * k: 64 * k + size][good], y[good])
        np.testing.assert_array_equal(whole_u[64 * k: 64 * k + size][good], u[good])
    rows = np.array([149, 3, 70, 64])                   # any rows, any order, several blocks
    part_y, part_u, _ = dd.block_windows(family, 5, 150, 48, 3, rows)
    np.testing.assert_array_equal(part_y, whole_y[rows])
    np.testing.assert_array_equal(part_u, whole_u[rows])
    other, _, _ = dd.block_windows(family, 5, 150, 48, 4, rows)            # epochs differ
    assert not np.allclose(other, part_y)


class _ConstantFamily:
    """Order 1; every third window of a block is constant (cannot be normalised)."""

    order = 1

    def records(self, count, steps, rng):
        from types import SimpleNamespace
        y, u = rng.standard_normal((2, count, steps))
        y[::3] = 1.0
        return SimpleNamespace(y=y, u=u)


def test_constant_windows_weigh_nothing():
    y, u, ok = dd.block_windows(_ConstantFamily(), 0, 70, 16, 0, np.arange(70))
    np.testing.assert_array_equal(ok.numpy(), np.arange(70) % 64 % 3 != 0)
    assert torch.isfinite(y).all() and torch.isfinite(u).all()              # a ramp stands in
    ident = train_generic(GenericConfig(order=1, window=16, width=4, dense=(16,)),
                          _settings(epochs=1, count=70, batch=35, holdout=32),
                          family=_ConstantFamily())
    assert np.isfinite(ident.meta["history"]["train_loss"][0])
    assert ident.meta["history"]["skipped"] == [0]


def test_batches_too_small_to_share_are_refused():
    _check_shares(_settings(count=256, batch=96), 32)     # batches of 96, 96 and 64
    with pytest.raises(ValueError, match=r"batch=96 with count=200 gives a batch of 8 "
                                         r"window\(s\), fewer than the 16 processes"):
        _check_shares(_settings(count=200, batch=96), 16)


def test_bad_device_is_refused(monkeypatch, capsys, tmp_path):
    with pytest.raises(ValueError, match=r"device must be one of \('cpu', 'cuda', 'auto'\); "
                                         r"got 'gpu'"):
        _settings(device="gpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ValueError, match=r"device='cuda' but torch finds no CUDA GPU"):
        _settings(device="cuda")
    assert _settings(device="auto").device == "auto"                       # falls back
    with pytest.raises(SystemExit) as exit_:
        main([*_CLI, "--device", "cuda", "--out", str(tmp_path / "g.aeid")])
    assert exit_.value.code == 2
    assert "device='cuda' but torch finds no CUDA GPU" in capsys.readouterr().err


def test_a_checkpoint_resumes_on_another_device_setting(tmp_path):
    ckpt = str(tmp_path / "run.ckpt")

    def stop(epoch, history):
        raise KeyboardInterrupt                        # stopped after epoch 1's checkpoint

    with pytest.raises(KeyboardInterrupt):
        train_generic(SMALL, _settings(epochs=2, checkpoint=ckpt), on_epoch=stop)
    # the device is not part of the checkpoint's fingerprint: "auto" resumes a "cpu" run
    resumed = train_generic(SMALL, _settings(epochs=2, checkpoint=ckpt, device="auto"))
    whole = train_generic(SMALL, _settings(epochs=2))
    assert resumed.meta["train"]["device"] == "cpu" == whole.meta["train"]["device"]
    np.testing.assert_array_equal(resumed.meta["history"]["holdout_loss"],
                                  whole.meta["history"]["holdout_loss"])


# -- real runs ---------------------------------------------------------------------------------
def test_two_processes_match_one_and_the_identifier_loads_and_identifies(launch, tmp_path):
    out, done = launch
    two = out / "two.aeid"
    assert two.is_file(), done.stderr[-3000:]
    assert main([*_CLI, "--out", str(tmp_path / "one.aeid")]) == 0        # one plain process
    par, one = load_generic(two), load_generic(tmp_path / "one.aeid")
    assert (par.meta["train"]["world_size"], par.meta["train"]["backend"],
            par.meta["train"]["device"]) == (2, "gloo", "cpu")
    assert (one.meta["train"]["world_size"], one.meta["train"]["backend"]) == (1, None)
    for key in ("holdout_loss", "holdout_fit", "train_loss", "grad_norm_median"):
        np.testing.assert_allclose(par.meta["history"][key], one.meta["history"][key],
                                   rtol=RTOL_PROCESSES, err_msg=key)
    assert done.stdout.count("trained ") == 1                              # rank 0 reports
    # the file identifies a first-order system as the one-process file does: the pole of
    # y' = -0.2 y + 0.5 u (dt = 1, normalised time), simulated exactly from a step sequence
    rng = np.random.default_rng(1)
    u = np.repeat(rng.uniform(-1, 1, 8), 8)
    y = simulate(np.array([[-0.2]]), np.array([1.0]), np.array([0.5]), 0.0, u, 1.0)
    poles = [ident.poles(y[None], u[None])[0, 0] for ident in (par, one)]
    assert poles[0].real < 0                                              # stable by design
    np.testing.assert_allclose(poles[0], poles[1], rtol=1e-4)


def test_a_killed_rank_ends_the_run_and_a_restart_resumes_with_one_process(launch):
    out, done = launch
    assert done.returncode != 0
    log = done.stdout + done.stderr
    assert re.search(r"Root Cause.*?rank\s*: 1 \(local_rank: 1\).*?Signal 9 \(SIGKILL\)", log,
                     re.DOTALL), log[-3000:]
    ckpt = out / "run.ckpt"
    assert torch.load(ckpt, weights_only=True)["epoch"] == 2
    resumed = train_generic(SMALL, _settings(checkpoint=str(ckpt)))       # a plain process
    whole = train_generic(SMALL, _settings())
    assert torch.load(ckpt, weights_only=True)["epoch"] == 4
    assert resumed.meta["train"]["world_size"] == 1
    for key in ("holdout_loss", "train_loss", "holdout_fit"):
        assert len(resumed.meta["history"][key]) == 4
        np.testing.assert_allclose(resumed.meta["history"][key], whole.meta["history"][key],
                                   rtol=RTOL_PROCESSES, err_msg=key)
