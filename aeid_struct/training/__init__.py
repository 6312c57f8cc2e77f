"""Training: system families, excitations, simulated records and the unsupervised training loop
(paper Eq. 14-15).

Modules: ``families`` (the true systems), ``excitation`` (the inputs), ``datasets`` (simulated
records and the per-record time grid), ``config`` (``TrainConfig``), ``objective`` (Eq. 14 on
Eq. 15-normalised records), ``tensors`` (the run's records as tensors), ``loop`` (``train``),
``checkpoints``, ``generic`` (``train_generic``: generic identifiers by variable projection),
``calibration`` (the training range and flag thresholds) and ``progress`` (the
budget, the progress line, the warning).
"""

from aeid_struct.training.calibration import recalibrate as recalibrate
from aeid_struct.training.config import TrainConfig as TrainConfig
from aeid_struct.training.datasets import Records as Records
from aeid_struct.training.datasets import grids as grids
from aeid_struct.training.datasets import records as records
from aeid_struct.training.excitation import EXCITATIONS as EXCITATIONS
from aeid_struct.training.excitation import excitation as excitation
from aeid_struct.training.families import LegFamily as LegFamily
from aeid_struct.training.families import PoleFamily as PoleFamily
from aeid_struct.training.families import Systems as Systems
from aeid_struct.training.generic import GenericTrainConfig as GenericTrainConfig
from aeid_struct.training.generic import train_generic as train_generic
from aeid_struct.training.loop import train as train
from aeid_struct.training.progress import UndertrainedWarning as UndertrainedWarning

__all__ = [
    "EXCITATIONS",
    "GenericTrainConfig",
    "LegFamily",
    "PoleFamily",
    "Records",
    "Systems",
    "excitation",
    "grids",
    "records",
    "TrainConfig",
    "UndertrainedWarning",
    "recalibrate",
    "train",
    "train_generic",
]
