"""Simulation (the decoder): exact first-order-hold discretisation and simulation, paper Eq. 4,
10-15.
"""

from aeid_struct.simulation.foh import Discrete as Discrete
from aeid_struct.simulation.foh import denormalise as denormalise
from aeid_struct.simulation.foh import discretise as discretise
from aeid_struct.simulation.foh import initial_state as initial_state
from aeid_struct.simulation.foh import loss as loss
from aeid_struct.simulation.foh import normalise as normalise
from aeid_struct.simulation.foh import record_scale as record_scale
from aeid_struct.simulation.foh import simulate as simulate
from aeid_struct.simulation.foh import states as states
from aeid_struct.simulation.foh import stationary_value as stationary_value

__all__ = [
    "Discrete",
    "denormalise",
    "discretise",
    "initial_state",
    "loss",
    "normalise",
    "record_scale",
    "simulate",
    "states",
    "stationary_value",
]
