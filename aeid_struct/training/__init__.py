"""Training: system families, excitations, simulated records and the unsupervised training loop
(paper Eq. 14-15).
"""

from aeid_struct.training.families import EXCITATIONS as EXCITATIONS
from aeid_struct.training.families import LegFamily as LegFamily
from aeid_struct.training.families import PoleFamily as PoleFamily
from aeid_struct.training.families import Records as Records
from aeid_struct.training.families import Systems as Systems
from aeid_struct.training.families import excitation as excitation
from aeid_struct.training.families import records as records
from aeid_struct.training.loop import TrainConfig as TrainConfig
from aeid_struct.training.loop import UndertrainedWarning as UndertrainedWarning
from aeid_struct.training.loop import recalibrate as recalibrate
from aeid_struct.training.loop import train as train

__all__ = [
    "EXCITATIONS",
    "LegFamily",
    "PoleFamily",
    "Records",
    "Systems",
    "excitation",
    "records",
    "TrainConfig",
    "UndertrainedWarning",
    "recalibrate",
    "train",
]
