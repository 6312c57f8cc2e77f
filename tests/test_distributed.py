"""Data-parallel training (training.distributed): shares, devices, a real 2-process gloo run under
torchrun that matches the single-process run, a killed rank and the resumed run."""

import json
import os
import re
import socket
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers import torchrun

import aeid_struct as ae
from aeid_struct.cli.main import main
from aeid_struct.encoder import EncoderConfig
from aeid_struct.simulation import simulate
from aeid_struct.training import PoleFamily, TrainConfig, train
from aeid_struct.training import distributed as dd
from aeid_struct.training.checkpoints import fingerprint
from aeid_struct.training.loop import _check_shares

ROOT = Path(__file__).resolve().parents[1]
FAMILY = PoleFamily(real=1, pairs=0, decay=(1.0, 4.0), gain=(0.5, 2.0))
SMALL = EncoderConfig(width=4, kernel=3, dense=(16,))
#: The tolerance of a 2-process run against one process, relative. Why not bit-identical: a
#: process's loss is a float32 mean over its share of the batch and DDP adds the two shares'
#: float32 gradients, where one process takes one mean over the whole batch -- the same sums in
#: another order, each step rounding at float32's 6e-8. Measured: at most 3e-7 after 3 epochs
#: (batches of 45 split 23/22 and, last, 13/12); 1e-5 leaves that a 30x margin, while a share
#: left unweighted (its loss not scaled by n_rank W / n) moves the held-out loss by 4e-2.
RTOL_PROCESSES = 1e-5


def _config(**kw):
    base = dict(dt=0.05, steps=40, count=200, epochs=3, batch=45, lr=1e-2, seed=0,
                progress=False, noise=(0.0, 0.05), excitation="mix", gamma=0.0)
    return TrainConfig(**{**base, **kw})


#: The CLI's arguments for the runs compared (``poles:1,0`` is ``PoleFamily(real=1, pairs=0)``).
_CLI = ["train", "--structure", "ccf:1:descartes", "--family", "poles:1,0", "--dt", "0.05",
        "--steps", "40", "--count", "200", "--epochs", "3", "--batch", "45", "--lr", "0.01",
        "--noise", "0.0", "0.05", "--excitation", "mix", "--gamma", "0", "--width", "4",
        "--kernel", "3", "--dense", "16", "--quiet"]

# Run under torchrun by every process: (1) the CLI, data-parallel; (2) fresh records every epoch,
# under a wall-time budget (rank 0's clock is broadcast every step; 1e9 s leaves the schedule the
# epochs'); (3) a checkpointed run whose rank 1 kills itself (SIGKILL) after epoch 2's checkpoint.
_SCRIPT = """
import json, os, signal, sys
sys.path.insert(0, {root!r})
import aeid_struct as ae
from aeid_struct.cli.main import main
from aeid_struct.encoder import EncoderConfig
from aeid_struct.training import PoleFamily, TrainConfig, train
out, rank = sys.argv[1], int(os.environ["RANK"])
main({cli!r} + ["--out", os.path.join(out, "two.aeid")])
fam = PoleFamily(real=1, pairs=0, decay=(1.0, 4.0), gain=(0.5, 2.0))
small = EncoderConfig(width=4, kernel=3, dense=(16,))
base = dict(dt=0.05, steps=40, count=200, epochs=3, batch=45, lr=1e-2, seed=0, progress=False,
            noise=(0.0, 0.05), excitation="mix", gamma=0.0)
ident = train(ae.CCF(1, descartes=True), fam, TrainConfig(**base, fresh=True, seconds=1e9),
              encoder=small)
if rank == 0:
    with open(os.path.join(out, "fresh.json"), "w") as f:
        json.dump(ident.meta["history"]["holdout_loss"], f)

def on_epoch(epoch, history):
    if epoch == 2 and rank == 1:
        os.kill(os.getpid(), signal.SIGKILL)

cfg = TrainConfig(**{{**base, "epochs": 4}}, checkpoint=os.path.join(out, "run.ckpt"))
train(ae.CCF(1, descartes=True), fam, cfg, encoder=small, on_epoch=on_epoch)
"""


@pytest.fixture(scope="module")
def launch(tmp_path_factory):
    """One torchrun launch of two gloo processes (the launches cost seconds each on a loaded
    machine): what it wrote and how it ended."""
    out = tmp_path_factory.mktemp("torchrun")
    script = out / "run.py"
    script.write_text(_SCRIPT.format(root=str(ROOT), cli=_CLI))
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    done = torchrun(["--standalone", "--nproc-per-node", "2", "--monitor-interval", "0.1",
                     script, out], cwd=ROOT, env=env)
    return out, done


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def one_process_group(monkeypatch):
    """This test's process as a torchrun process group of one (gloo), left afterwards."""
    for key, value in {"RANK": "0", "WORLD_SIZE": "1", "LOCAL_RANK": "0",
                       "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(_free_port())}.items():
        monkeypatch.setenv(key, value)
    yield
    if torch.distributed.is_initialized():
        torch.distributed.destroy_process_group()


# -- the helpers -----------------------------------------------------------------------------
@pytest.mark.parametrize("world", [1, 2, 3, 4])
def test_shares_cover_every_row_once_in_rank_order(world):
    for count in range(0, 13):
        parts = dd.shares(count, world)
        assert len(parts) == world
        rows = np.concatenate([np.arange(count)[s] for s in parts])
        np.testing.assert_array_equal(rows, np.arange(count))     # once each, in order
        sizes = [s.stop - s.start for s in parts]
        assert max(sizes) - min(sizes) <= 1 and sizes == sorted(sizes, reverse=True)


def test_shares_refuse_bad_arguments():
    with pytest.raises(ValueError, match="world_size must be a positive integer; got 0"):
        dd.shares(4, 0)
    with pytest.raises(ValueError, match="count must be a non-negative integer; got -1"):
        dd.shares(-1, 2)


def test_device_resolution(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert dd.resolve_device("cpu") == torch.device("cpu")
    assert dd.resolve_device("auto") == torch.device("cpu")            # falls back
    with pytest.raises(ValueError, match=r"device='cuda' but torch finds no CUDA GPU.*'auto'"):
        dd.resolve_device("cuda")
    with pytest.raises(ValueError, match=r"device='cuda' but torch finds no CUDA GPU"):
        TrainConfig(dt=0.05, steps=40, device="cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert dd.resolve_device("auto") == torch.device("cuda", 0)
    assert dd.resolve_device("cuda", local_rank=3) == torch.device("cuda", 1)   # per node


@pytest.mark.parametrize("bad", ["gpu", "CUDA", None, 0])
def test_bad_device_is_refused_with_the_choices(bad):
    with pytest.raises(ValueError, match=r"device must be one of \('cpu', 'cuda', 'auto'\); got"):
        TrainConfig(dt=0.05, steps=40, device=bad)


def test_cli_device_without_a_gpu_is_an_input_error(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(SystemExit) as exit_:
        main([*_CLI, "--device", "cuda", "--out", str(tmp_path / "m.aeid")])
    assert exit_.value.code == 2
    assert "device='cuda' but torch finds no CUDA GPU" in capsys.readouterr().err


def test_launch_detection_and_rank():
    assert not dd.launched({}) and dd.process_rank({}) == 0
    env = {"RANK": "3", "WORLD_SIZE": "4", "LOCAL_RANK": "1"}
    assert dd.launched(env) and dd.process_rank(env) == 3
    ctx = dd.setup("cpu", env={})                       # not launched: one process
    assert (ctx.rank, ctx.world_size, ctx.backend, ctx.writer, ctx.distributed) == \
        (0, 1, None, True, False)
    assert ctx.sum([1.5, 2]) == [1.5, 2.0] and ctx.share(7) == slice(0, 7)
    with pytest.raises(ValueError, match="must be integers"):
        dd.setup("cpu", env={**env, "RANK": "x"})


def test_failure_message_names_the_process_and_how_to_resume():
    ctx = dd.Context(rank=1, world_size=4, backend="gloo")
    err = dd.failure(RuntimeError("[gloo] Connection closed by peer [127.0.0.1]:1234"), ctx,
                     "run.ckpt")
    assert str(err).startswith("training process 1 of 4 (gloo): a collective operation failed")
    assert "Connection closed by peer" in str(err) and "resume from the checkpoint 'run.ckpt'" \
        in str(err)
    assert "starts over" in str(dd.failure(RuntimeError("x"), ctx, None))
    assert dd.collective_error(torch.distributed.DistBackendError("any"))
    assert dd.collective_error(RuntimeError("[gloo] Connection closed by peer"))
    assert not dd.collective_error(RuntimeError("shape mismatch"))


def test_batches_too_small_to_share_are_refused():
    _check_shares(_config(), 4)                   # 160 rows: batches of 45, the last of 25
    with pytest.raises(ValueError, match=r"batch=40 with 130 training records gives a batch of "
                                         r"10 record\(s\), fewer than the 16 processes"):
        _check_shares(_config(count=162, batch=40), 16)


def test_row_records_do_not_depend_on_the_rows_drawn_with_them():
    config = _config(fresh=True)
    whole = dd.row_records(FAMILY, config, 3, np.arange(10))
    part = dd.row_records(FAMILY, config, 3, np.array([7, 2]))
    np.testing.assert_array_equal(part.y_clean, whole.y_clean[[7, 2]])
    np.testing.assert_array_equal(part.u, whole.u[[7, 2]])
    assert not np.array_equal(whole.u[0], whole.u[1])                     # rows differ
    other = dd.row_records(FAMILY, config, 4, np.arange(10))               # epochs differ
    assert not np.allclose(other.y_clean, whole.y_clean)
    s = whole.systems                                                       # the exact FOH
    np.testing.assert_allclose(whole.y_clean, simulate(s.A, s.b, s.c, s.d, whole.u, 0.05),
                               rtol=0, atol=0)


def test_checkpoint_fingerprint_ignores_the_device():
    enc = EncoderConfig(steps=40, outputs=2)
    structure = ae.CCF(1, descartes=True)
    assert fingerprint(structure, _config(), enc) == fingerprint(structure,
                                                                 _config(device="auto"), enc)


# -- real runs ---------------------------------------------------------------------------------
def _history(path):
    return ae.Identifier.load(path).meta


def test_two_processes_match_one_and_the_identifier_loads_and_identifies(launch, tmp_path):
    out, done = launch
    two = out / "two.aeid"
    assert two.is_file(), done.stderr[-3000:]
    assert main([*_CLI, "--out", str(tmp_path / "one.aeid")]) == 0        # one process
    one, par = _history(tmp_path / "one.aeid"), _history(two)
    assert (par["train"]["world_size"], par["train"]["backend"], par["train"]["device"]) == \
        (2, "gloo", "cpu")
    assert (one["train"]["world_size"], one["train"]["backend"]) == (1, None)
    for key in ("holdout_loss", "train_loss", "grad_norm_median"):
        np.testing.assert_allclose(par["history"][key], one["history"][key],
                                   rtol=RTOL_PROCESSES, err_msg=key)
    assert par["history"]["holdout_loss"][-1] < par["history"]["holdout_loss"][0] / 3
    # the file loads and identifies as the one-process identifier does (3 epochs: a rough
    # model, but the same one)
    u = np.sin(np.linspace(0.0, 6.0, 40)) + 1.0
    y = simulate(np.array([[-2.5]]), np.array([1.0]), np.array([3.0]), 0.0, u, 0.05)
    est, ref = (ae.Identifier.load(p).identify(y, u) for p in (two, tmp_path / "one.aeid"))
    assert est.A[0, 0] < 0                                                 # stable by design
    np.testing.assert_allclose([est.A[0, 0], est.c[0]], [ref.A[0, 0], ref.c[0]], rtol=1e-4)
    assert done.stdout.count("trained ") == 1                              # rank 0 reports


def test_fresh_records_do_not_depend_on_the_number_of_processes(launch, one_process_group):
    out, _ = launch
    two = json.loads((out / "fresh.json").read_text())
    # torchrun's world of one draws the same per-row streams as two processes
    one = train(ae.CCF(1, descartes=True), FAMILY, _config(fresh=True, seconds=1e9),
                encoder=SMALL)
    assert one.meta["train"]["world_size"] == 1 and one.meta["train"]["backend"] == "gloo"
    np.testing.assert_allclose(two, one.meta["history"]["holdout_loss"], rtol=RTOL_PROCESSES)


def test_a_killed_rank_ends_the_run_and_a_restart_resumes_with_one_process(launch):
    out, done = launch
    assert done.returncode != 0
    log = done.stdout + done.stderr
    # torchrun's summary names the failed rank and its signal as the root cause
    assert re.search(r"Root Cause.*?rank\s*: 1 \(local_rank: 1\).*?Signal 9 \(SIGKILL\)", log,
                     re.DOTALL), log[-3000:]
    ckpt = out / "run.ckpt"
    assert torch.load(ckpt, weights_only=True)["epoch"] == 2
    # restarted as one plain process: resumes from epoch 2 and finishes
    resumed = train(ae.CCF(1, descartes=True), FAMILY,
                    _config(epochs=4, checkpoint=str(ckpt)), encoder=SMALL)
    whole = train(ae.CCF(1, descartes=True), FAMILY, _config(epochs=4), encoder=SMALL)
    assert torch.load(ckpt, weights_only=True)["epoch"] == 4
    assert resumed.meta["train"]["world_size"] == 1
    for key in ("holdout_loss", "train_loss"):
        assert len(resumed.meta["history"][key]) == 4
        np.testing.assert_allclose(resumed.meta["history"][key], whole.meta["history"][key],
                                   rtol=RTOL_PROCESSES, err_msg=key)
