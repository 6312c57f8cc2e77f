"""Simulation (the decoder): exact first-order-hold discretisation and simulation (paper Eq. 10-13),
the stationary value (Eq. 4), the normalisation (Eq. 15) and the loss (Eq. 14), the least-squares
initial state, and the same FOH simulation as a CasADi expression for the refinement NLP.

The functions without a suffix check their arguments (numpy or torch in, the same out); the
``*_batch`` kernels, :func:`fit_initial_state` and :func:`simulate_loop` are their unchecked torch
cores, for training loops and other packages that have checked their input already;
:func:`simulate_outputs` is the same kernel in numpy for one system with several outputs.

Modules: ``foh`` (:func:`simulate`, :func:`states`, :func:`discretise`), ``kernels`` (the batch
kernels), ``initial`` (:func:`initial_state`), ``normalise`` (Eq. 4, 14, 15), ``overflow`` (the
+inf rule), ``checks`` (argument handling), ``casadi_foh`` (:func:`casadi_simulate`,
:func:`expm`), ``projection`` (:func:`project`, :func:`fit_initial`: the linear part of a
record's model by least squares), ``projection_torch`` (:func:`project_batch`: the same, batched
and differentiable, for training).

The CasADi form (``casadi_foh``) and the numpy kernels (``numpy_foh``) need no torch and are
imported with the package; the other modules on first use of their names, so that the ONNX
runner, its head and its estimates run without torch.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from aeid_struct.lazy import attach
from aeid_struct.simulation.casadi_foh import THETA13 as THETA13
from aeid_struct.simulation.casadi_foh import augmented as augmented
from aeid_struct.simulation.casadi_foh import casadi_simulate as casadi_simulate
from aeid_struct.simulation.casadi_foh import expm as expm
from aeid_struct.simulation.casadi_foh import squarings_for as squarings_for
from aeid_struct.simulation.numpy_foh import discrete_foh as discrete_foh
from aeid_struct.simulation.numpy_foh import discrete_inputs as discrete_inputs
from aeid_struct.simulation.numpy_foh import free_basis as free_basis
from aeid_struct.simulation.numpy_foh import initial_state_numpy as initial_state_numpy
from aeid_struct.simulation.numpy_foh import output_groups as output_groups
from aeid_struct.simulation.numpy_foh import outputs_and_basis as outputs_and_basis
from aeid_struct.simulation.numpy_foh import simulate_numpy as simulate_numpy
from aeid_struct.simulation.numpy_foh import simulate_outputs as simulate_outputs
from aeid_struct.simulation.numpy_foh import summed_response as summed_response

if TYPE_CHECKING:
    from aeid_struct.simulation.checks import check_dt as check_dt
    from aeid_struct.simulation.foh import Discrete as Discrete
    from aeid_struct.simulation.foh import discretise as discretise
    from aeid_struct.simulation.foh import simulate as simulate
    from aeid_struct.simulation.foh import states as states
    from aeid_struct.simulation.initial import fit_initial_state as fit_initial_state
    from aeid_struct.simulation.initial import free_response as free_response
    from aeid_struct.simulation.initial import initial_state as initial_state
    from aeid_struct.simulation.initial import least_squares_x0 as least_squares_x0
    from aeid_struct.simulation.kernels import discretise_batch as discretise_batch
    from aeid_struct.simulation.kernels import foh_columns as foh_columns
    from aeid_struct.simulation.kernels import powers as powers
    from aeid_struct.simulation.kernels import scan as scan
    from aeid_struct.simulation.kernels import simulate_batch as simulate_batch
    from aeid_struct.simulation.kernels import simulate_loop as simulate_loop
    from aeid_struct.simulation.kernels import states_batch as states_batch
    from aeid_struct.simulation.kernels import states_loop as states_loop
    from aeid_struct.simulation.overflow import OverflowWarning as OverflowWarning
    from aeid_struct.simulation.projection import Projection as Projection
    from aeid_struct.simulation.projection import fit_initial as fit_initial
    from aeid_struct.simulation.projection import forced_states as forced_states
    from aeid_struct.simulation.projection import project as project
    from aeid_struct.simulation.projection_torch import BatchProjection as BatchProjection
    from aeid_struct.simulation.projection_torch import initial_states_batch as initial_states_batch
    from aeid_struct.simulation.projection_torch import project_batch as project_batch
    from aeid_struct.simulation.scaling import denormalise as denormalise
    from aeid_struct.simulation.scaling import loss as loss
    from aeid_struct.simulation.scaling import loss_batch as loss_batch
    from aeid_struct.simulation.scaling import normalise as normalise
    from aeid_struct.simulation.scaling import record_scale as record_scale
    from aeid_struct.simulation.scaling import record_scale_batch as record_scale_batch
    from aeid_struct.simulation.scaling import stationary_value as stationary_value
    from aeid_struct.simulation.scaling import stationary_value_batch as stationary_value_batch

#: name -> the module (of this package) that defines it, imported on first use
_LAZY = {
    "project": "projection",
    "forced_states": "projection",
    "fit_initial": "projection",
    "Projection": "projection",
    "check_dt": "checks",
    "Discrete": "foh",
    "discretise": "foh",
    "simulate": "foh",
    "states": "foh",
    "fit_initial_state": "initial",
    "free_response": "initial",
    "least_squares_x0": "initial",
    "initial_state": "initial",
    "discretise_batch": "kernels",
    "foh_columns": "kernels",
    "powers": "kernels",
    "scan": "kernels",
    "simulate_batch": "kernels",
    "simulate_loop": "kernels",
    "states_batch": "kernels",
    "states_loop": "kernels",
    "OverflowWarning": "overflow",
    "BatchProjection": "projection_torch",
    "initial_states_batch": "projection_torch",
    "project_batch": "projection_torch",
    "denormalise": "scaling",
    "loss": "scaling",
    "loss_batch": "scaling",
    "normalise": "scaling",
    "record_scale": "scaling",
    "record_scale_batch": "scaling",
    "stationary_value": "scaling",
    "stationary_value_batch": "scaling",
}

__all__ = [
    # checked: numpy or torch in, the same out
    "Discrete",
    "denormalise",
    "discrete_foh",
    "discrete_inputs",
    "discretise",
    "initial_state",
    "loss",
    "normalise",
    "record_scale",
    "simulate",
    "states",
    "stationary_value",
    "check_dt",
    "OverflowWarning",
    # unchecked torch kernels, one common batch size
    "discretise_batch",
    "fit_initial_state",
    "foh_columns",
    "free_response",
    "least_squares_x0",
    "loss_batch",
    "powers",
    "record_scale_batch",
    "scan",
    "simulate_batch",
    "simulate_loop",
    "simulate_outputs",
    "summed_response",
    "output_groups",
    "outputs_and_basis",
    # numpy, one system or a batch, without torch: an estimate's response and initial state
    "initial_state_numpy",
    "simulate_numpy",
    "states_batch",
    "states_loop",
    "stationary_value_batch",
    # numpy variable projection of a record's linear part (unchecked)
    "Projection",
    "fit_initial",
    "forced_states",
    "free_basis",
    "project",
    # the same projection batched and differentiable in torch (unchecked)
    "BatchProjection",
    "initial_states_batch",
    "project_batch",
    # CasADi, for the refinement NLP
    "THETA13",
    "augmented",
    "casadi_simulate",
    "expm",
    "squarings_for",
]


__getattr__, __dir__ = attach(__name__, _LAZY)
