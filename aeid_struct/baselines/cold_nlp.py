"""The CasADi NLP of :mod:`aeid_struct.refinement` from the generic start: the "CasADi from a cold
start" baseline, i.e. the refinement without the encoder's estimate.
"""

from __future__ import annotations

import time

import numpy as np

from aeid_struct.baselines.checks import check_record, estimate, nan_model, physical_source
from aeid_struct.baselines.models import bounds, check_structure, finish, free_indices, model_of
from aeid_struct.baselines.start import start_vector
from aeid_struct.identification import Estimate
from aeid_struct.simulation import check_dt

__all__ = ["casadi_cold"]


def casadi_cold(y, u, dt: float, *, structure, start: dict | None = None, inverse=None,
                config=None) -> Estimate:
    """The CasADi NLP of :mod:`aeid_struct.refinement` from the generic start of
    :func:`~aeid_struct.baselines.least_squares`.

    The solver's outcome is in ``info`` (iterations, success, status, loss, loss_start); a solver
    that does not converge keeps its best point and is judged by
    :func:`~aeid_struct.baselines.failure` like any other estimate.

    Parameters
    ----------
    y : (steps,)
    u : (steps,), or None for a unit step
    dt : float, > 0
    structure : CCF, MCF or Physical
        Fixed elements stay exactly at their values.
    start : dict name -> value, optional
        Start values for some or all elements; the rest from
        :func:`~aeid_struct.baselines.generic_start`.
    inverse : casadi.Function, optional
        CCF -> physical parameters for ``Estimate.physical`` (CCF structures).
    config : RefineConfig, optional
        The NLP's settings (``aeid_struct.refinement.RefineConfig``; default: its defaults).

    Returns
    -------
    Estimate
        ``info``: method, seconds, failed, reason, start, iterations, success, status, loss,
        loss_start, solver.

    Raises
    ------
    ValueError
        For a bad argument.
    """
    from aeid_struct.refinement import RefineConfig, refine

    start_time = time.perf_counter()
    y, u = check_record(y, u)
    dt = check_dt(dt)
    if config is None:
        config = RefineConfig()
    check_structure(structure)
    model = model_of(structure, free_indices(structure))
    source = physical_source(structure, inverse)
    lo, hi = bounds(structure)
    x = start_vector(structure, model, start, y, u, dt, lo, hi)
    names = structure.element_names
    info = {"method": "casadi_cold", "failed": False, "reason": "",
            "start": dict(zip(names, x.tolist(), strict=True))}
    try:
        # the start as an Estimate, polished by the one refinement of estimates
        begin = estimate(model.system(x), dict(zip(names, x.tolist(), strict=True)), y, u, dt,
                         start_time, info, source)
        result = refine(begin, structure=structure, config=config)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as err:  # CasADi: RuntimeError
        return estimate(nan_model(structure.n), {}, y, u, dt, start_time,
                        {**info, "failed": True,
                         "reason": f"CasADi NLP failed: {type(err).__name__}: {err}"}, None)
    x = np.array([result.elements[nm] for nm in names], dtype=np.float64)
    info |= {k: result.info[k] for k in ("iterations", "success", "status", "loss", "loss_start",
                                         "solver")}
    return finish(structure, model, names, x, y, u, dt, start_time, info, source)
