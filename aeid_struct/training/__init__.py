"""Training: system families, excitations, simulated records and the unsupervised training loop
(paper Eq. 14-15).

Modules: ``families`` (the true systems), ``generic_family`` (systems of order 1-8, stable or
integrating or unstable on request, and their records in normalised time, for the generic
identifiers; their types in ``generic_systems``, the polynomial algebra in
``generic_polynomials``, the windows read under the growth weights in ``generic_growth``),
``excitation`` (the inputs),
``parameter_family`` (the systems of a physical structure, its parameters drawn in a box),
``datasets`` (simulated records and the per-record time grid), ``config`` (``TrainConfig``),
``objective`` (Eq. 14 on Eq. 15-normalised records), ``tensors`` (the run's records as
tensors), ``loop`` (``train``), ``distributed`` (data-parallel runs under ``torchrun``, the
device), ``generic`` (``train_generic``: generic identifiers by variable projection; its
settings in ``generic_config``, its loss in ``generic_objective``),
``checkpoints``, ``calibration`` (the training range and flag
thresholds) and ``progress`` (the budget, the progress line, the warning).
"""

from aeid_struct.training.calibration import recalibrate as recalibrate
from aeid_struct.training.config import TrainConfig as TrainConfig
from aeid_struct.training.datasets import Records as Records
from aeid_struct.training.datasets import grids as grids
from aeid_struct.training.datasets import records as records
from aeid_struct.training.distributed import DEVICES as DEVICES
from aeid_struct.training.distributed import process_rank as process_rank
from aeid_struct.training.excitation import EXCITATIONS as EXCITATIONS
from aeid_struct.training.excitation import GENERIC_EXCITATIONS as GENERIC_EXCITATIONS
from aeid_struct.training.excitation import excitation as excitation
from aeid_struct.training.excitation import generic_excitation as generic_excitation
from aeid_struct.training.families import LegFamily as LegFamily
from aeid_struct.training.families import PoleFamily as PoleFamily
from aeid_struct.training.families import Systems as Systems
from aeid_struct.training.generic import GenericTrainConfig as GenericTrainConfig
from aeid_struct.training.generic import train_generic as train_generic
from aeid_struct.training.generic_family import GenericFamily as GenericFamily
from aeid_struct.training.generic_family import GenericRecords as GenericRecords
from aeid_struct.training.generic_family import GenericSystems as GenericSystems
from aeid_struct.training.generic_growth import GrowthFamily as GrowthFamily
from aeid_struct.training.loop import train as train
from aeid_struct.training.parameter_family import ParameterFamily as ParameterFamily
from aeid_struct.training.progress import UndertrainedWarning as UndertrainedWarning

__all__ = [
    "DEVICES",
    "EXCITATIONS",
    "GENERIC_EXCITATIONS",
    "GenericFamily",
    "GrowthFamily",
    "GenericRecords",
    "GenericSystems",
    "GenericTrainConfig",
    "LegFamily",
    "ParameterFamily",
    "PoleFamily",
    "Records",
    "Systems",
    "excitation",
    "generic_excitation",
    "grids",
    "process_rank",
    "records",
    "TrainConfig",
    "UndertrainedWarning",
    "recalibrate",
    "train",
    "train_generic",
]
