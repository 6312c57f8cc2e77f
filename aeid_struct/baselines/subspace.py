r"""Subspace identification (nfoursid's PO-MOESP/N4SID), converted exactly to continuous time.

Records from rest, and why n4sid needs two input channels
---------------------------------------------------------
A record starts from rest (docs/architecture.md, "Conventions"): ``x(0) = 0``, ``u`` linear
between samples on ``[0, T]``. If ``u_0 != 0`` the input jumps at ``t = 0``; a subspace method that
sees only the record cannot see that jump (a unit step is a constant sequence: no excitation at
all). Prepending ``pre_zeros`` zero samples of ``u`` and ``y`` shows it the jump -- but then the
data are *not* a trajectory of the FOH model: between the last prepended zero and ``u_0`` the FOH
would ramp, while the system saw a jump (the step record with zeros in front is exactly the
*zero-order-hold* model's). The exact split: ``u(t) = u_0 + v(t)`` on ``[0, T]`` with
``v_k = u_k - u_0`` (so ``v_0 = 0``);

* the constant ``u_0``, switched on at ``t = 0``, is exact under a zero-order hold: input channel
  ``s_k = u_0`` (zeros before), column ``gamma1``, feedthrough ``d``;
* ``v`` starts at zero, so the prepended zeros add no ramp: it is exact under the FOH, column
  ``gamma1 - gamma2 + Phi gamma2``, feedthrough ``d + c^T gamma2``.

Both share ``Phi`` and ``c``, so n4sid identifies one two-input model (one input when ``u`` is a
step or ``u_0 = 0``), and :func:`~aeid_struct.baselines.continuous.convert` takes ``b`` from the
stacked equations of both columns. With ``pre_zeros = 0`` the record is passed as one FOH channel
and the subspace method absorbs the initial shifted state ``xi_0 = -gamma2 u_0`` (exact for inputs
that excite the system persistently, useless for a step).

Defaults: ``pre_zeros = 2 block_rows``: the past and future Hankel windows together span
``2 block_rows`` samples, and the step channel is persistently exciting of that order only when
the jump appears at every position of such a window (all-zero windows before it).
``block_rows = min(20, steps // (2 (m + 1)))`` (at least ``order + 1``) for ``m`` input channels:
any ``block_rows > order`` is exact on clean data, but noise decides, and on noisy leg steps the
failures fall and the step errors level off by 20 (``aeid-struct bench`` measures them). The
record must hold ``2 block_rows (m + 2) - 1`` samples with the zeros (nfoursid's QR needs as many
Hankel columns as stacked rows). nfoursid returns the model in an arbitrary basis; with a
``structure`` it is converted to that structure's elements (``Structure.elements_of``) and
realisation, and with an ``inverse`` (a CasADi map from the CCF) physical parameters follow
(``Estimate.physical``).
"""

from __future__ import annotations

import time

import numpy as np

from aeid_struct.baselines.checks import (
    check_int,
    check_record,
    estimate,
    in_structure,
    initial_form,
    nan_model,
    only_record,
    physical_source,
)
from aeid_struct.baselines.continuous import NoRealLogarithm, convert
from aeid_struct.baselines.free_initial import n4sid_record
from aeid_struct.baselines.several import n4sid_channels
from aeid_struct.baselines.subspace_step import nfoursid_model
from aeid_struct.identification import Estimate
from aeid_struct.records import Record
from aeid_struct.simulation import check_dt
from aeid_struct.threads import one_thread

__all__ = ["n4sid"]


@one_thread
def n4sid(y, u=None, dt: float | None = None, *, order: int, structure=None, inverse=None,
          feedthrough: bool = False, pre_zeros: int | None = None,
          block_rows: int | None = None, offset: str = "channel",
          initial: str | None = None) -> Estimate:
    """Subspace identification (nfoursid's PO-MOESP/N4SID) converted exactly to continuous time.

    Two models, chosen by ``initial``: a record from rest (``"rest"``, the default for arrays:
    ``n4sid(y, u, dt, order=n)``, module docstring), and a record not at rest (``"fitted"``,
    the default for a :class:`~aeid_struct.records.Record`: ``n4sid(record, order=n)``): no
    zero padding, a constant input channel for the offset, the initial state and the output
    offset fitted, a known delay applied
    (:func:`~aeid_struct.baselines.free_initial.n4sid_record`).

    Parameters
    ----------
    y : (steps,) or Record
        A record's output, or a measured ``Record`` (then ``u`` and ``dt`` come from it; with
        ``initial="fitted"`` ``structure``, ``inverse`` and ``pre_zeros`` are not given).
    u : (steps,), or None for a unit step
    dt : float, > 0
    order : int >= 1
        Model order (rank of the subspace step); ``info["singular_values"]`` helps choose it.
    structure : Structure, optional
        Return the model in this structure (elements and realisation). A model that violates
        it (a fixed element, Descartes, bounds) makes a failed estimate that still carries the
        unstructured model.
    inverse : casadi.Function, optional
        CCF -> physical parameters (e.g. ``symbolic.leg.stable_inverse()``); needs a CCF
        structure (``CCF(order)`` when ``structure`` is None).
    feedthrough : bool
        Estimate ``d`` (otherwise ``d = 0``); taken from ``structure`` when one is given.
    pre_zeros : int >= 0, default ``2 block_rows``
        Zero samples put in front of ``u`` and ``y`` (module docstring: how the step at ``t = 0``
        becomes visible and exact). 0 passes the record as one FOH channel.
    block_rows : int > order, default ``min(20, steps // (2 (m + 1)))``, at least ``order + 1``
        Block rows of the Hankel matrices (``m``: 1 or 2 input channels; module docstring).
    offset : {"channel", "mean"}
        ``Record`` form only: a constant input channel absorbs the output offset, or the means
        are removed first (biased; :mod:`aeid_struct.baselines.free_initial`).
    initial : {"rest", "fitted"}, optional
        What the record is: from rest (``x(0) = 0``) or mid-motion (``x0``, the offset and a
        known delay fitted). Default: ``"fitted"`` for a ``Record``, ``"rest"`` for arrays.

    Returns
    -------
    Estimate
        ``info``: method, seconds, failed, reason, channels (the holds of the input channels),
        discrete (``Phi, B, C, D`` as identified), singular_values; the ``Record`` form adds
        x0, y_offset, delay and fit (NRMSE % with ``x0`` and the offset fitted).

    Raises
    ------
    ValueError
        For a bad argument, or a record too short for the order, ``block_rows`` and
        ``pre_zeros``.
    """
    import pandas  # noqa: F401 -- imported before the clock starts: the first import takes ~0.5 s
    from nfoursid.nfoursid import NFourSID  # noqa: F401

    if isinstance(y, (list, tuple)) and y and all(isinstance(r, Record) for r in y):
        raise ValueError(f"y must be one Record: n4sid (nfoursid) reads one record, not "
                         f"{len(y)} experiments; least_squares(records, order=n) or "
                         f"ae.identify(records, order=n) fit one model to several")
    if isinstance(y, Record) and (y.outputs > 1 or y.inputs > 1):
        only_record("n4sid", u=u, dt=dt)
        return n4sid_channels(y, order=check_int("order", order, 1), block_rows=block_rows)
    form, data = initial_form("n4sid", y, u, dt, initial)
    if form == "fitted":
        for name, value in (("structure", structure), ("inverse", inverse),
                            ("pre_zeros", pre_zeros)):
            if value is not None:
                raise ValueError(f"{name} must not be given with a Record or initial='fitted' "
                                 f"(a record not at rest: n4sid(record, order=n)); got "
                                 f"{value!r}")
        return n4sid_record(data, order=check_int("order", order, 1),
                            feedthrough=feedthrough,
                            block_rows=_check_sizes(order, None, block_rows)[1], offset=offset)
    y, u, dt = data
    start = time.perf_counter()
    y, u_in = check_record(y, u)
    dt = check_dt(dt)
    order = check_int("order", order, 1)
    pre_zeros, block_rows = _check_sizes(order, pre_zeros, block_rows)
    structure, feedthrough = _structure(structure, inverse, order, feedthrough)
    source = physical_source(structure, inverse)
    channels, holds = _channels(u_in, pre_zeros)
    block_rows, pre_zeros = _sizes(y.shape[0], len(channels), order, block_rows, pre_zeros)
    info = {"method": "n4sid", "failed": False, "reason": "", "channels": holds,
            "order": order, "block_rows": block_rows, "pre_zeros": pre_zeros}

    def failed(reason: str, model=None) -> Estimate:
        return estimate(nan_model(order) if model is None else model, {}, y, u_in, dt, start,
                        {**info, "failed": True, "reason": reason}, None)

    try:
        Phi, B, C, D, sv = nfoursid_model(y, channels, order, block_rows, pre_zeros)
        info["discrete"] = {"Phi": Phi, "B": B, "C": C, "D": D}
        info["singular_values"] = sv
        model = convert(Phi, B, C[0], D[0], dt, holds, feedthrough)
    except NoRealLogarithm as err:
        return failed(str(err))
    except (np.linalg.LinAlgError, ValueError) as err:
        return failed(f"nfoursid failed: {type(err).__name__}: {err}")
    model = (model.A, model.b, model.c, model.d)
    if not all(np.all(np.isfinite(m)) for m in model):
        return failed("non-finite model")
    elements = {}
    if structure is not None:
        try:
            model, elements = in_structure(structure, model)
        except ValueError as err:
            return failed(f"model outside the structure: {err}", model)
    return estimate(model, elements, y, u_in, dt, start, info, source)


def _structure(structure, inverse, order: int, feedthrough: bool):
    """The structure to return the model in (``CCF(order)`` for an ``inverse`` without one) and
    whether ``d`` is estimated; checked against ``order`` and ``feedthrough``."""
    if structure is not None:
        if getattr(structure, "n", None) != order:
            raise ValueError(f"structure must have order {order}; got {structure!r}")
        has_d = "d" in structure.element_names
        if feedthrough and not has_d:
            raise ValueError(f"feedthrough=True but structure {structure!r} has no element d")
        return structure, has_d
    if inverse is not None:
        from aeid_struct.structures import CCF

        return CCF(order, feedthrough=feedthrough), feedthrough
    return None, feedthrough


def _channels(u: np.ndarray, pre_zeros: int | None):
    """The input channels (module docstring): the jump to ``u_0`` (ZOH) and ``v = u - u_0``
    (FOH), or the record as one FOH channel when ``pre_zeros == 0``; and their holds."""
    if pre_zeros == 0:
        return [u], ("foh",)
    u0, v = u[0], u - u[0]
    channels = [np.full_like(u, u0)] if u0 != 0 else []
    channels += [v] if np.any(v != 0) else []
    holds = ("zoh",) * bool(u0 != 0) + ("foh",) * bool(np.any(v != 0))
    return channels, holds


def _check_sizes(order: int, pre_zeros, block_rows) -> tuple[int | None, int | None]:
    """``pre_zeros`` (>= 0) and ``block_rows`` (> order) as given, checked; None stays None."""
    if pre_zeros is not None:
        pre_zeros = check_int("pre_zeros", pre_zeros, 0)
    if block_rows is not None:
        block_rows = check_int("block_rows", block_rows, 1)
        if block_rows <= order:
            raise ValueError(f"block_rows must be > order = {order}; got {block_rows}")
    return pre_zeros, block_rows


def _sizes(steps: int, m: int, order: int, block_rows, pre_zeros) -> tuple[int, int]:
    """``block_rows`` and ``pre_zeros`` with their defaults (module docstring), checked against
    the record's length for ``m`` input channels."""
    if block_rows is None:
        # As many as the record allows with the default zeros, up to 20 (module docstring).
        block_rows = max(order + 1, min(20, steps // (2 * (m + 1))))
    if pre_zeros is None:
        pre_zeros = 2 * block_rows
    # nfoursid's QR needs as many Hankel columns as stacked rows: N - 2i + 1 >= 2i (m + 1).
    need = 2 * block_rows * (m + 2) - 1 - pre_zeros
    if steps < need:
        raise ValueError(f"y must have at least {need} samples for order={order}, "
                         f"block_rows={block_rows}, pre_zeros={pre_zeros} and {m} input "
                         f"channel(s); got {steps}")
    return block_rows, pre_zeros
