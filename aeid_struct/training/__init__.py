"""Training: system families, excitations, simulated records and the unsupervised training loop
(paper Eq. 14-15).
"""

from aeid_struct.training.loop import TrainConfig as TrainConfig
from aeid_struct.training.loop import UndertrainedWarning as UndertrainedWarning
from aeid_struct.training.loop import recalibrate as recalibrate
from aeid_struct.training.loop import train as train

__all__ = [
    "TrainConfig",
    "UndertrainedWarning",
    "recalibrate",
    "train",
]
