"""Argument checks shared by the classical methods, and the :class:`Estimate` they return.

A failure that depends on the data (a discrete pole without a real logarithm, a model outside the
requested structure, a solver error) does not raise: the estimate comes back with
``info["failed"] = True``, a ``info["reason"]`` in words, and NaN matrices where no model exists
(:func:`estimate`, :func:`nan_model`). Bad arguments (shapes, non-finite samples, an unknown
element name) raise ``ValueError`` naming the argument.
"""

from __future__ import annotations

import math
import time

import numpy as np

from aeid_struct.identification import Estimate, Provenance
from aeid_struct.records import Record, RecordBatch, as_array, require_finite, unit_step

__all__ = ["INITIALS", "as_measured", "check_int", "check_record", "estimate", "in_structure",
           "initial_form", "nan_model", "only_record", "physical_source"]


def check_int(name: str, value, lowest: int) -> int:
    """``value`` as an int ``>= lowest``, or a ValueError naming ``name``.

    Parameters
    ----------
    name : str
    value : int-like (not a bool)
    lowest : int

    Returns
    -------
    int
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lowest:
        raise ValueError(f"{name} must be an integer >= {lowest}; got {value!r}")
    return int(value)


def check_record(y, u) -> tuple[np.ndarray, np.ndarray]:
    """One record, checked: finite, not all zero, ``u`` like ``y``.

    Parameters
    ----------
    y : (steps,) array-like, steps >= 2
    u : (steps,) array-like, or None for a unit step

    Returns
    -------
    y, u : (steps,) float64 arrays

    Raises
    ------
    ValueError
        Naming the argument: wrong shape, non-finite sample, all zero, or shapes that differ.
    """
    out = []
    for name, v in (("y", y), ("u", unit_step(np.shape(y)) if u is None else u)):
        arr = as_array(name, v)
        if arr.ndim != 1 or arr.shape[0] < 2:
            raise ValueError(f"{name} must have shape (steps,) with steps >= 2 (one record; "
                             f"loop over a batch); got {arr.shape}")
        require_finite(name, arr)
        if not np.any(arr):
            raise ValueError(f"{name} must not be all zero: a record from rest with zero "
                             "input or output reveals nothing")
        out.append(arr)
    if out[0].shape != out[1].shape:
        raise ValueError(f"u must have the shape of y {out[0].shape}; got {out[1].shape}")
    return out[0], out[1]


def as_measured(y, what: str):
    """A measured record given as ``y``: a ``Record`` as it is, a ``(y, u)`` or ``(y, u, dt)``
    tuple of arrays as a ``Record`` (as ``ae.identify`` and ``ae.compare`` take it); None for
    anything else (the arrays of a record from rest).

    Parameters
    ----------
    y : object
    what : str
        The method, named where a record of several outputs or inputs is refused.

    Returns
    -------
    Record or None
    """
    if isinstance(y, tuple) and len(y) in (2, 3) and all(np.ndim(v) >= 1 for v in y[:2]):
        y = Record(*y)
    if not isinstance(y, Record):
        return None
    y.require_siso(what)
    return y


#: What a baseline is told about a record's start: from rest (``x(0) = 0``, no offset, no
#: delay), or mid-motion (the initial state, an output offset and a known delay fitted).
INITIALS = ("rest", "fitted")


def initial_form(method: str, y, u, dt, initial):
    """The model a baseline fits, chosen by what the caller states about the record
    (``initial``), not by the form it comes in: ``("fitted", record)`` or ``("rest", (y, u,
    dt))``.

    Parameters
    ----------
    method : str
        The baseline's name in messages.
    y : array, Record or (y, u[, dt]) tuple
    u, dt : as given
    initial : {"rest", "fitted"} or None
        None: ``"fitted"`` for a ``Record`` (a measured record), ``"rest"`` for arrays (the
        meaning they have everywhere in the library).

    Returns
    -------
    (str, Record or tuple)

    Raises
    ------
    ValueError
        An unknown ``initial``; ``u`` or ``dt`` beside a ``Record``; a record with a known
        input delay fitted from rest.
    """
    measured = as_measured(y, method)
    if initial is None:
        initial = "rest" if measured is None else "fitted"
    if initial not in INITIALS:
        raise ValueError(f"initial must be one of {INITIALS} or None; got {initial!r}")
    if measured is not None:
        only_record(method, u=u, dt=dt)
    if initial == "fitted":
        return "fitted", Record(y, u, dt) if measured is None else measured
    if measured is None:
        return "rest", (y, u, dt)
    if measured.delay:
        raise ValueError(f"initial='rest' fits the record from its first sample; this record "
                         f"has a known input delay of {measured.delay} samples: "
                         f"{method}(record, ..., initial='fitted') fits with it")
    return "rest", (measured.y, measured.u, measured.dt)


def only_record(method: str, **given) -> None:
    """Raise for an argument given beside a ``Record`` (which carries ``u`` and ``dt``).

    Parameters
    ----------
    method : str
        The baseline's name in messages.
    **given
        Arguments that must be None with a ``Record``.

    Raises
    ------
    ValueError
        Naming the first one given.
    """
    for name, value in given.items():
        if value is not None:
            raise ValueError(f"{name} must not be given with a Record ({method}(record, "
                             f"order=n) takes u and dt from the record); got {value!r}")


def physical_source(structure, inverse):
    """What ``Estimate.physical`` maps: the elements of a Physical structure, or the inverse.

    Parameters
    ----------
    structure : Structure or None
    inverse : casadi.Function or None
        CCF -> physical parameters; needs a CCF structure.

    Returns
    -------
    ``("elements", names)`` for a Physical structure, else ``inverse`` (possibly None).

    Raises
    ------
    ValueError
        For an ``inverse`` that is not a casadi.Function, or one with a structure that is not a
        CCF.
    """
    import casadi

    from aeid_struct.structures import CCF, Physical

    if inverse is not None and not isinstance(inverse, casadi.Function):
        raise ValueError(f"inverse must be a casadi.Function (e.g. "
                         f"symbolic.leg.stable_inverse()); got {type(inverse).__name__}")
    if isinstance(structure, Physical):
        return ("elements", tuple(structure.element_names))
    if inverse is not None and not isinstance(structure, CCF):
        raise ValueError(f"inverse maps a CCF model to physical parameters: structure must be "
                         f"a CCF; got {structure!r}")
    return inverse


def estimate(model, elements, y, u, dt, start, info, source) -> Estimate:
    """The :class:`Estimate` of one record, its time measured from ``start``.

    Parameters
    ----------
    model : tuple
        ``A (n, n)``, ``b, c (n,)``, ``d`` float.
    elements : dict name -> float
    y, u : (steps,) arrays
    dt : float
    start : float
        ``time.perf_counter()`` when the method began.
    info : dict
        The method's ``info``; ``seconds`` is added.
    source : object
        What ``Estimate.physical`` maps (:func:`physical_source`).

    Returns
    -------
    Estimate
    """
    A, b, c, d = model
    info = {**info, "seconds": time.perf_counter() - start}
    return Estimate(A=np.asarray(A, dtype=np.float64), b=np.asarray(b, dtype=np.float64),
                    c=np.asarray(c, dtype=np.float64), d=float(d), elements=dict(elements),
                    record=RecordBatch.of(y, u, dt, batched=False),
                    provenance=Provenance(inverse=source), seconds=info["seconds"], info=info)


def nan_model(n: int):
    """The model of a failed estimate: NaN ``A (n, n)``, ``b, c (n,)``, ``d``.

    Parameters
    ----------
    n : int

    Returns
    -------
    tuple
    """
    return np.full((n, n), np.nan), np.full(n, np.nan), np.full(n, np.nan), math.nan


def in_structure(structure, model):
    """``(A, b, c, d)`` in the structure's realisation, and its elements.

    Parameters
    ----------
    structure : Structure
    model : tuple
        ``A (n, n)``, ``b, c (n,)``, ``d``, in any basis.

    Returns
    -------
    model : tuple
        In the structure's realisation (float64).
    elements : dict name -> float

    Raises
    ------
    ValueError
        When the model violates the structure (``Structure.elements_of(strict=True)``).
    """
    import torch

    x = structure.elements_of(*model, strict=True).to(torch.float64)
    sys = structure.assemble(x)
    A, b, c, d = (t.detach().numpy() for t in sys)
    return (A, b, c, float(d)), dict(zip(structure.element_names, x.tolist(), strict=True))
