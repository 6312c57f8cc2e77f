"""Identification: ``Identifier`` (encoder + structure + normalisation), ``Estimate``, files.
"""

from aeid_struct.identification.identifier import ERROR_MODES as ERROR_MODES
from aeid_struct.identification.identifier import FLAG_FALSE_RATE as FLAG_FALSE_RATE
from aeid_struct.identification.identifier import FORMAT as FORMAT
from aeid_struct.identification.identifier import FORMAT_1 as FORMAT_1
from aeid_struct.identification.identifier import INITIAL_STATES as INITIAL_STATES
from aeid_struct.identification.identifier import PRETRAINED as PRETRAINED
from aeid_struct.identification.identifier import SCALE_MODES as SCALE_MODES
from aeid_struct.identification.identifier import Estimate as Estimate
from aeid_struct.identification.identifier import Identifier as Identifier
from aeid_struct.identification.identifier import load_pretrained as load_pretrained

__all__ = [
    "ERROR_MODES",
    "Estimate",
    "FLAG_FALSE_RATE",
    "FORMAT",
    "FORMAT_1",
    "INITIAL_STATES",
    "Identifier",
    "PRETRAINED",
    "SCALE_MODES",
    "load_pretrained",
]
