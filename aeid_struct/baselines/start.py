"""The generic ("cold") start of the classical optimisers: what a user without the encoder would
try.

CCF with all poles at -1 (``a_i = binomial(n, i)``: ``a0 = 1, a1 = 2`` for order 2); MCF with real
poles -1, -2, ... and pairs ``-1 +- j (1, 2, ...)``; then the output elements ``c`` (and ``d``) by
*linear* least squares for those poles (the response is linear in them), which matches the
record's final value and scale; a ``Physical`` structure starts at the midpoints of its bounds.
The same start serves stable and unstable records (from poles at -1 the unstable leg's fit
converges to its pole in the right half-plane).
"""

from __future__ import annotations

import math

import numpy as np

from aeid_struct.baselines.checks import check_record
from aeid_struct.baselines.models import check_structure, free_indices, linear_names, model_of
from aeid_struct.simulation import check_dt, simulate_outputs

__all__ = ["generic_start", "start_vector"]


def generic_start(structure, y, u, dt: float) -> dict[str, float]:
    """The cold start of :func:`~aeid_struct.baselines.least_squares` (module docstring).

    CCF: all poles at -1, ``a_i = binomial(n, i)`` (order 2: ``a0 = 1, a1 = 2``). MCF: real poles
    -1, -2, ..., pairs ``-1 +- j (1, 2, ...)``. Then the free ``c_i`` (and ``d``), in which the
    response is linear, by linear least squares on the record for those poles: it matches the
    record's scale and final value. Physical: the midpoints of the bounds. Fixed elements keep
    their values.

    Parameters
    ----------
    structure : CCF, MCF or Physical
    y : (steps,)
        One record from rest.
    u : (steps,), or None for a unit step
    dt : float, > 0

    Returns
    -------
    dict element name -> float, for every element of the structure.

    Raises
    ------
    ValueError
        For a bad record, ``dt`` or structure.
    """
    y, u = check_record(y, u)
    dt = check_dt(dt)
    check_structure(structure)
    return _generic_start(structure, model_of(structure, free_indices(structure)), y, u, dt)


def _generic_start(structure, model, y, u, dt) -> dict[str, float]:
    from aeid_struct.structures import CCF, MCF, Physical

    names = structure.element_names
    x = {}
    if isinstance(structure, CCF):
        x |= {f"a{i}": float(math.comb(structure.n, i)) for i in range(structure.n)}
    elif isinstance(structure, MCF):
        x |= {f"lambda{i}": -(i + 1.0) for i in range(structure.real)}
        for j in range(structure.pairs):
            x |= {f"delta{j}": -1.0, f"omega{j}": j + 1.0}
    elif isinstance(structure, Physical):
        x |= {nm: 0.5 * (lo + hi) for nm, (lo, hi) in structure.bounds.items()}
    x |= structure.fixed_values
    linear = linear_names(structure)
    if linear:
        # The response is linear in the free c_i (and d): columns = the response with them at
        # zero, then one per linear element (c = e_i; d: the input itself).
        vec = np.array([0.0 if nm in linear else x.get(nm, 0.0) for nm in names])
        A, b, c, d = model.system(vec)
        C = np.zeros((1 + len(linear), structure.n))
        D = np.zeros(1 + len(linear))
        C[0], D[0] = c, d
        for k, nm in enumerate(linear):
            if nm == "d":
                D[1 + k] = 1.0
            else:
                C[1 + k, int(nm[1:])] = 1.0
        with np.errstate(all="ignore"):
            cols = simulate_outputs(A, b, C, D, u, dt)
        coef = np.linalg.lstsq(cols[1:].T, y - cols[0], rcond=None)[0]
        x |= dict(zip(linear, coef.tolist(), strict=True))
    return {nm: float(x.get(nm, 0.0)) for nm in names}


def start_vector(structure, model, start, y, u, dt, lo, hi) -> np.ndarray:
    """The start of an optimiser: the user's values over the generic start, checked.

    Parameters
    ----------
    structure : Structure
    model : AffineModel or CasadiModel
    start : dict name -> value, or None
        Start values for some or all elements; the rest from the generic start.
    y, u : (steps,) arrays
    dt : float
    lo, hi : (q,) arrays
        The structure's bounds (the result is clipped into them).

    Returns
    -------
    (q,) array
        Every element, in ``structure.element_names`` order; fixed ones at their values.

    Raises
    ------
    ValueError
        For a ``start`` that is not a dict, names an unknown element, is not finite, moves a
        fixed element or leaves the bounds.
    """
    names = structure.element_names
    given = {} if start is None else start
    if not isinstance(given, dict):
        raise ValueError(f"start must be a dict element name -> value; got "
                         f"{type(given).__name__}")
    fixed = structure.fixed_values
    for nm, v in given.items():
        if nm not in names:
            raise ValueError(f"start has unknown element {nm!r}; elements of {structure!r}: "
                             f"{', '.join(names)}")
        if not (isinstance(v, (int, float, np.floating)) and math.isfinite(v)):
            raise ValueError(f"start[{nm!r}] must be a finite number; got {v!r}")
        if nm in fixed and v != fixed[nm]:
            raise ValueError(f"start[{nm!r}] = {v!r} but {nm} is fixed at {fixed[nm]!r} in "
                             f"{structure!r}")
        i = names.index(nm)
        if not lo[i] <= v <= hi[i]:
            raise ValueError(f"start[{nm!r}] = {v!r} is outside the structure's bounds "
                             f"[{lo[i]:g}, {hi[i]:g}]")
    free = [nm for nm in names if nm not in fixed]
    if not all(nm in given for nm in free):
        given = _generic_start(structure, model, y, u, dt) | given
    x = np.array([float(fixed.get(nm, given.get(nm, 0.0))) for nm in names])
    return np.clip(x, lo, hi)
