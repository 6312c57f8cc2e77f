"""The run's simulated records as tensors: the first stage of ``train()``, and the fresh
records of ``TrainConfig.fresh`` drawn into them each epoch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from aeid_struct.simulation import stationary_value
from aeid_struct.structures import Physical, Structure
from aeid_struct.training.config import TrainConfig
from aeid_struct.training.datasets import Records, holdout_split, records
from aeid_struct.training.distributed import row_records
from aeid_struct.training.objective import output_free, raw_statistics, theta


@dataclass
class RecordTensors:
    """The run's records as tensors, ``(count, ...)`` rows, and how the network's outputs are
    standardised (``objective.raw_statistics``).

    Attributes
    ----------
    rec : Records
        The records drawn first (the training range is computed on them).
    u, y : list of R tensors (count, steps_r)
        Inputs and clean outputs, float32.
    yinf : (count, R) tensor
        True stationary values (Eq. 4).
    scale : (count, R) tensor
        ``max|y|`` of the clean records.
    train, held : int arrays
        Training and held-out indices (``datasets.holdout_split``).
    scale_mode : {"denormalise", "feature"}
        The identifier's ``scale``.
    mean, spread : (p,) arrays
        Centre and spread of the raw parameters.
    gain : (count, R) array
        ``max|y| / max|u|``.
    z : (count, p) tensor or None
        Standardised true parameters (``TrainConfig.supervised``).
    """

    rec: Records                  # the records drawn first (the training range is on them)
    u: list[torch.Tensor]         # R tensors (count, steps_r)
    y: list[torch.Tensor]         # R clean records (count, steps_r)
    yinf: torch.Tensor            # (count, R) true stationary values (Eq. 4)
    scale: torch.Tensor           # (count, R) max|y| of the clean records
    train: np.ndarray             # training indices
    held: np.ndarray              # held-out indices
    scale_mode: str               # "denormalise" or "feature" (Identifier's scale)
    mean: np.ndarray              # (p,) centre of the raw parameters
    spread: np.ndarray            # (p,) their spread
    gain: np.ndarray              # (count, R) max|y| / max|u|
    z: torch.Tensor | None = None  # (count, p) standardised true parameters (supervised)

    def targets(self, structure: Structure, systems, gain: np.ndarray) -> torch.Tensor:
        """Standardised true raw parameters (``TrainConfig.supervised``).

        Parameters
        ----------
        structure : Structure
        systems : Systems
            ``N`` systems of one record.
        gain : (N, R) array
            ``max|y| / max|u|`` of their records.

        Returns
        -------
        (N, p) float32 tensor
        """
        t = theta(structure, systems, gain[:, 0] if self.scale_mode == "denormalise" else None)
        return torch.tensor((t - self.mean) / self.spread, dtype=torch.float32)

    def batch(self, idx: torch.Tensor, ys: list[torch.Tensor]):
        """The records ``idx`` as ``objective.batch_loss`` takes them.

        Parameters
        ----------
        idx : (B,) int tensor
        ys : list of R tensors (B, steps_r)
            Their outputs, already taken (and noisy).

        Returns
        -------
        y, u, yinf, z
            Tensors for one record, lists (and ``yinf (B, R)``) for several; ``z`` None
            without supervision.
        """
        u = [v[idx] for v in self.u]
        z = None if self.z is None else self.z[idx]
        if len(ys) == 1:
            return ys[0], u[0], self.yinf[idx, 0], z
        return ys, u, self.yinf[idx], z


def record_tensors(structure: Structure, family, config: TrainConfig) -> RecordTensors:
    """The first stage of ``train()``: the simulated records as tensors, their split, their
    scales and the output standardisation.

    Parameters
    ----------
    structure : Structure
        What the encoder outputs (its records per system, its raw parameters).
    family : LegFamily, PoleFamily or any family
        Samples the true systems.
    config : TrainConfig
        The record format, count, split, excitation and seed.

    Returns
    -------
    RecordTensors
    """
    R = structure.records
    rec = records(family, config.count, steps=config.steps, dt=config.dt,
                  excitation_kind=config.excitation, seed=config.seed, warmup=config.warmup)
    scale_mode = ("feature" if isinstance(structure, Physical) or not output_free(structure)
                  else "denormalise")
    ys_clean, us = (rec.y_clean, rec.u) if R > 1 else ((rec.y_clean,), (rec.u,))
    y_bar = np.stack([np.max(np.abs(y), axis=1) for y in ys_clean], 1)     # (count, R)
    u_bar = np.stack([np.max(np.abs(u), axis=1) for u in us], 1)
    gain = y_bar / u_bar
    mean, spread = raw_statistics(structure, rec.systems,
                                  gain[:, 0] if scale_mode == "denormalise" else None)
    train_idx, held_idx = holdout_split(config.count, config.holdout, config.seed)
    dtype = torch.float32
    yinf = torch.tensor(np.stack([
        _stationary(rec.systems.record(r), config) for r in range(R)], 1),
        dtype=dtype)                                                          # (count, R)
    data = RecordTensors(rec=rec, u=[torch.tensor(u, dtype=dtype) for u in us],
                 y=[torch.tensor(y, dtype=dtype) for y in ys_clean], yinf=yinf,
                 scale=torch.tensor(y_bar, dtype=dtype), train=train_idx, held=held_idx,
                 scale_mode=scale_mode, mean=mean, spread=spread, gain=gain)
    if config.supervised > 0:
        data.z = data.targets(structure, rec.systems, gain)
    return data


def refresh(data: RecordTensors, structure: Structure, family, config: TrainConfig,
            epoch: int, rows: np.ndarray | None = None) -> None:
    """New training records for ``epoch`` (``TrainConfig.fresh``) in ``data``'s training rows,
    and their targets; the held-out rows stay.

    Parameters
    ----------
    data : RecordTensors
        Changed in place.
    structure : Structure
    family : LegFamily, PoleFamily or any family
    config : TrainConfig
    epoch : int
        Seeds the draw (``seed + 7919 epoch``), so that a resumed run draws the same records.
    rows : int array, optional
        Only these training rows, each from a stream of its own (``distributed.row_records``):
        a process of a data-parallel run draws the rows it trains on. None: every training row,
        from one stream, as one process draws them.
    """
    if rows is None:
        rows = data.train
        new = redraw(family, config, epoch, rows, data.u, data.y, data.yinf, data.scale)
    else:
        new = redraw(family, config, epoch, rows, data.u, data.y, data.yinf, data.scale,
                     rec=row_records(family, config, epoch, rows))
    if data.z is not None:
        index = torch.as_tensor(rows)
        new_u = new.u if structure.records > 1 else (new.u,)
        u_new = np.stack([np.max(np.abs(u), axis=1) for u in new_u], 1)
        data.z[index] = data.targets(structure, new.systems,
                                     data.scale[index].double().numpy() / u_new)


def redraw(family, config: TrainConfig, epoch: int, rows: np.ndarray, u_all, y_all,
           yinf_all, scale_all, rec: Records | None = None) -> Records:
    """Replace the rows ``rows`` of the record tensors in place by records drawn with a seed
    of their own (``seed + 7919 epoch``), or by ``rec``.

    Parameters
    ----------
    family : LegFamily, PoleFamily or any family
    config : TrainConfig
    epoch : int
    rows : (M,) int array
    u_all, y_all : list of R tensors (count, steps_r)
        Inputs and clean outputs.
    yinf_all, scale_all : (count, R) tensors
        Stationary values (Eq. 4) and ``max|y|``.
    rec : Records, optional
        The ``M`` new records, drawn already (None: drawn here).

    Returns
    -------
    Records
        The new records (``M`` of them).
    """
    if rec is None:
        rec = records(family, len(rows), steps=config.steps, dt=config.dt,
                      excitation_kind=config.excitation, seed=config.seed + 7919 * epoch,
                      warmup=config.warmup)
    multi = isinstance(rec.u, tuple)
    ys, us = (rec.y_clean, rec.u) if multi else ((rec.y_clean,), (rec.u,))
    index = torch.as_tensor(rows)
    for r, (y, u) in enumerate(zip(ys, us, strict=True)):
        y_all[r][index] = torch.as_tensor(y, dtype=y_all[r].dtype)
        u_all[r][index] = torch.as_tensor(u, dtype=u_all[r].dtype)
        scale_all[index, r] = torch.as_tensor(np.max(np.abs(y), axis=1), dtype=scale_all.dtype)
        s = rec.systems.record(r)
        yinf_all[index, r] = torch.as_tensor(_stationary(s, config), dtype=yinf_all.dtype)
    return rec


def _stationary(systems, config) -> np.ndarray:
    """The true stationary values (Eq. 4) the loss's stationary term reads, or zeros where its
    weight is 0 (the loss never reads them then). Why: an integrating or unstable mechanism
    has no finite stationary value, and trains on inputs other than steps without one."""
    if config.stationary_weight == 0:
        return np.zeros(len(systems))
    return stationary_value(systems.A, systems.b, systems.c, systems.d)

