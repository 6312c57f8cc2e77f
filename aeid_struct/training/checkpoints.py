"""Training checkpoints: the run's state on disk, written atomically, read as data only.

A checkpoint is written every epoch to ``<path>.tmp``, flushed to disk with ``fsync`` and
renamed over the previous one; a ``.tmp`` left by a kill mid-write is removed at the next start.
It holds tensors and numbers only and is read with ``weights_only=True``, so a file that asks
for code is refused, never run; a file that is truncated, not a checkpoint, or written for
another setup is refused with its path and how to start over. Every random stream of the run
(torch's global generator, the shuffling and training-noise generator, the held-out noise
generator) is in it, so a resumed run ends bit-identical to an uninterrupted one.
"""

from __future__ import annotations

import json
import math
import os
import pickle
from pathlib import Path

import torch

from aeid_struct.encoder import EncoderConfig
from aeid_struct.training.config import TrainConfig, config_dict


def fingerprint(structure, config: TrainConfig, enc: EncoderConfig) -> str:
    """What must match for a checkpoint to be resumed: the structure, the family settings and
    the encoder (not the budget, the progress flag, the path, the device or the number of
    processes: a run may resume on another device or under another ``torchrun``).

    Parameters
    ----------
    structure : Structure
        Its ``config()``.
    config : TrainConfig
    enc : EncoderConfig

    Returns
    -------
    str
        Canonical JSON.
    """
    d = config_dict(config)
    for key in ("epochs", "seconds", "min_epochs", "target_loss", "progress", "checkpoint",
                "threads", "device"):
        d.pop(key)
    return json.dumps({"structure": structure.config(), "config": d,
                       "encoder": enc.to_dict()}, sort_keys=True)


def _tmp_path(path: Path) -> Path:
    """Where a checkpoint is written before the atomic rename."""
    return path.with_name(path.name + ".tmp")


def remove_leftover(path: Path) -> None:
    """Remove the ``.tmp`` file a kill between write and rename leaves: never a checkpoint
    (the rename did not happen), so nothing is lost.

    Parameters
    ----------
    path : pathlib.Path
        The checkpoint's path.
    """
    tmp = _tmp_path(path)
    if tmp.is_file():
        tmp.unlink()


def save(path: Path, fingerprint: str, ident, opt, generators: dict, state: dict) -> None:
    """Write the run's state atomically: to ``<path>.tmp``, flushed to the disk (``fsync``),
    then renamed over ``path``, so that a kill or a power loss at any point leaves the previous
    checkpoint or this one, never a torn file.

    Parameters
    ----------
    path : pathlib.Path
        The checkpoint.
    fingerprint : str
        ``fingerprint()`` of the run.
    ident : Identifier
        Its encoder's weights are saved.
    opt : torch.optim.Optimizer
        Adam, with its moments.
    generators : dict of str -> torch.Generator
        The run's random streams by name; torch's global generator is saved too.
    state : dict
        ``epoch``, ``elapsed``, ``best``, ``best_state`` and ``history``.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "fingerprint": fingerprint,
        "encoder": ident.encoder.state_dict(),
        "optimizer": opt.state_dict(),
        **{name: g.get_state() for name, g in generators.items()},
        "torch_rng": torch.get_rng_state(),
        "epoch": state["epoch"],
        "elapsed": state["elapsed"],
        "best": state["best"],
        "best_state": state["best_state"],
        "history": state["history"],
    }
    tmp = _tmp_path(path)
    try:
        with open(tmp, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())     # the bytes reach the disk before the name points at them
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_directory(path.parent)    # and the rename itself


def _fsync_directory(folder: Path) -> None:
    """Flush a directory entry (a rename) to the disk where the platform allows it (POSIX; a
    directory cannot be opened on Windows, where ``os.replace`` is durable by itself)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


#: The checkpoint's entries: written by every version (``_REQUIRED``), and since resumption is
#: bit-identical (older checkpoints without them resume with fresh held-out noise).
_REQUIRED = ("fingerprint", "encoder", "optimizer", "generator", "epoch", "elapsed", "best",
             "best_state", "history")
_RANDOM_STATES = ("held_generator", "torch_rng")
#: The per-epoch history of a run (``ident.meta["history"]``), key by key.
HISTORY = ("train_loss", "holdout_loss", "lr", "seconds", "grad_norm_median", "grad_norm_max",
            "skipped")


def _unusable(payload, fingerprint: str, encoder_state: dict, opt) -> str | None:
    """Why ``payload`` (what ``torch.load`` returned) cannot be resumed by this run, or None.

    Checked before anything is loaded, so that a wrong file changes nothing: the entries and
    their types, the fingerprint (structure, family settings, encoder), every weight's name and
    shape (the encoder's, the best epoch's, the optimizer's moments), the generator states and
    the history's length.
    """
    if not isinstance(payload, dict):
        return f"it holds a {type(payload).__name__}, not a training checkpoint"
    missing = [k for k in _REQUIRED if k not in payload]
    if missing:
        return f"it is not a training checkpoint (no {', '.join(missing)})"
    if payload["fingerprint"] != fingerprint:
        return "it was written for a different structure, family settings or encoder"

    def weights(name: str, tensors) -> str | None:
        if not isinstance(tensors, dict) or set(tensors) != set(encoder_state):
            return f"its {name} are not this encoder's weights"
        for key, ref in encoder_state.items():
            value = tensors[key]
            if not isinstance(value, torch.Tensor):
                return f"its {name} {key!r} are a {type(value).__name__}, not a tensor"
            if value.shape != ref.shape:
                return (f"its {name} {key!r} have shape {tuple(value.shape)}, expected "
                        f"{tuple(ref.shape)}")
        return None

    reason = weights("weights", payload["encoder"])
    if reason is None and payload["best_state"] is not None:
        reason = weights("best weights", payload["best_state"])
    if reason:
        return reason
    epoch = payload["epoch"]
    if not isinstance(epoch, int) or isinstance(epoch, bool) or epoch < 0:
        return f"its epoch is {epoch!r}, not a count"
    for key in ("elapsed", "best"):
        if not isinstance(payload[key], (int, float)) or math.isnan(payload[key]):
            return f"its {key} is {payload[key]!r}, not a number"
    history = payload["history"]
    if not isinstance(history, dict) or any(
            not isinstance(history.get(k), list) or len(history[k]) != epoch
            for k in HISTORY[:4]):
        return f"its history does not hold {epoch} epochs of {', '.join(HISTORY[:4])}"
    reference = torch.Generator().get_state()
    for key in ("generator", *_RANDOM_STATES):
        g = payload.get(key, reference)
        expected = torch.get_rng_state() if key == "torch_rng" else reference
        if not (isinstance(g, torch.Tensor) and g.dtype == expected.dtype
                and g.shape == expected.shape):
            return f"its {key} is not a random generator's state"
    state = payload["optimizer"]
    params = [p for group in opt.param_groups for p in group["params"]]
    if not (isinstance(state, dict) and isinstance(state.get("state"), dict)
            and isinstance(state.get("param_groups"), list)):
        return "its optimizer state is not Adam's"
    for i, moments in state["state"].items():
        if not (isinstance(i, int) and 0 <= i < len(params) and isinstance(moments, dict)):
            return "its optimizer state is for other parameters"
        for name, value in moments.items():
            if (not isinstance(value, torch.Tensor)
                    or (value.dim() > 0 and value.shape != params[i].shape)):
                return f"its optimizer's {name} of parameter {i} does not match the weights"
    return None


def _unreadable(err: Exception) -> str:
    """Why ``torch.load(..., weights_only=True)`` could not read a checkpoint, in our words
    (torch's own message for a refused pickle suggests ``weights_only=False``: never here)."""
    if isinstance(err, pickle.UnpicklingError):
        return ("it is not a file of tensors and numbers only (refused unread: loading it could "
                "run code)")
    if isinstance(err, EOFError):
        return "it is empty or truncated"
    if isinstance(err, OSError):
        return f"it cannot be opened ({err.strerror or err})"
    if isinstance(err, RuntimeError) and "zip archive" in str(err):
        return "it is truncated or not a torch file"
    first = (str(err).strip().splitlines() or [""])[0][:120]
    return f"it cannot be read as a training checkpoint ({type(err).__name__}: {first})"


def resume(path: Path, fingerprint: str, ident, opt, generators: dict) -> dict:
    """Load a checkpoint into the run (encoder, optimizer, generators) and return its state.

    ``weights_only=True``: the file is read as tensors and numbers only, a pickle that asks for
    anything else (code) is refused unrun.

    Parameters
    ----------
    path : pathlib.Path
        The checkpoint.
    fingerprint : str
        ``fingerprint()`` of this run; the file's must be equal.
    ident : Identifier
        Receives the encoder's weights.
    opt : torch.optim.Optimizer
        Receives Adam's state.
    generators : dict of str -> torch.Generator
        Receive their states (torch's global generator too).

    Returns
    -------
    state : dict
        ``epoch``, ``elapsed``, ``best``, ``best_state`` and ``history``, as ``save`` took it.

    Raises
    ------
    ValueError
        Naming ``path`` and how to start over, for any file that is not a checkpoint of this
        run; nothing is changed then.
    """
    def refused(reason: str) -> ValueError:
        return ValueError(f"checkpoint {str(path)!r} cannot be resumed: {reason}; delete it or "
                          "choose another checkpoint path to start over")

    try:
        payload = torch.load(path, weights_only=True, map_location="cpu")
    except Exception as err:    # truncated, not a torch file, a directory, a pickle of code
        raise refused(_unreadable(err)) from None
    reason = _unusable(payload, fingerprint, ident.encoder.state_dict(), opt)
    if reason is not None:
        raise refused(reason)
    try:
        opt.load_state_dict(payload["optimizer"])
    except (ValueError, KeyError, TypeError, RuntimeError) as err:
        raise refused(f"its optimizer state cannot be loaded ({err})") from None
    ident.encoder.load_state_dict(payload["encoder"])
    for name, g in generators.items():
        if name in payload:
            g.set_state(payload[name])
    if "torch_rng" in payload:
        torch.set_rng_state(payload["torch_rng"])
    state = {k: payload[k] for k in ("epoch", "elapsed", "best", "best_state", "history")}
    for key in HISTORY[4:]:   # older checkpoints
        state["history"].setdefault(key, [math.nan] * state["epoch"])
    return state


def end_epoch(run, state: dict, held: float, elapsed: float) -> None:
    """The end of an epoch, shared by ``train()`` and ``train_generic()``: keep the weights if
    the held-out loss is the best so far (on the CPU whatever the device, so that a checkpoint
    resumes on any device), count the epoch, and write the checkpoint (rank 0 alone, the other
    processes waiting for it: ``on_epoch`` may rely on it being there).

    Parameters
    ----------
    run : the loop's run record
        Its ``ident``, ``ckpt`` (Path or None), ``ctx`` (``distributed`` context: ``writer``,
        ``barrier``), ``fingerprint``, ``opt`` and ``generators``.
    state : dict
        The checkpointed state (``best``, ``best_state``, ``epoch``, ``elapsed``), changed here.
    held : float
        This epoch's held-out loss.
    elapsed : float
        Training seconds so far.
    """
    if held < state["best"] and math.isfinite(held):
        state["best"] = held
        state["best_state"] = {k: v.detach().to("cpu", copy=True)
                               for k, v in run.ident.encoder.state_dict().items()}
    state["epoch"] += 1
    state["elapsed"] = elapsed
    if run.ckpt is not None:
        if run.ctx.writer:
            save(run.ckpt, run.fingerprint, run.ident, run.opt, run.generators, state)
        run.ctx.barrier()

