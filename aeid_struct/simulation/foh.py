r"""The decoder: exact first-order-hold simulation of continuous-time SISO systems (Eq. 10-13).

The encoder proposes a continuous-time model ``(A, b, c, d)``; the decoder turns it into the
response to the measured input on the record's time grid, differentiably and for a whole batch at
once.

Time grid (docs/architecture.md, "Conventions"): a record has ``steps`` samples at ``t_k = k dt``;
between samples the input is linear (first-order hold, FOH). On ``[t_k, t_k + dt]`` write
``s = (t - t_k)/dt`` and ``u = u_k + s Du_k`` with ``Du_k = u_{k+1} - u_k`` (Eq. 11). The augmented
state ``z = (x, u, Du)`` obeys ``dz/ds = M z`` with (Eq. 10)::

        [A dt  b dt  0]                 [Phi  gamma1  gamma2]
    M = [ 0     0    1],     expm(M) =  [ 0     1       1   ],
        [ 0     0    0]                 [ 0     0       1   ]

so, exactly for piecewise-linear inputs,

    x_{k+1} = Phi x_k + gamma1 u_k + gamma2 Du_k                                  (Eq. 10-12)
    y_k     = c^T x_k + d u_k                                                     (Eq. 13)

with ``Phi = e^{A dt}``, ``gamma1 = int_0^dt e^{A s} ds b`` and
``gamma2 = (1/dt) int_0^dt e^{A (dt - s)} s ds b``. ``x_0`` is zero unless ``x0`` is given.

:func:`simulate` runs the recursion in ``log2(steps)`` levels
(:func:`~aeid_struct.simulation.kernels.simulate_batch`; the derivation is in
:mod:`aeid_struct.simulation.kernels`) and
applies the overflow rule (:mod:`aeid_struct.simulation.overflow`). This module also keeps the
decoder's old private names (``_simulate``, ``_free_fit``, ...) as aliases of the public ones, for
code that still imports them from here.
"""

from __future__ import annotations

from dataclasses import dataclass

from aeid_struct.simulation.checks import (
    Array,
    batched,
    check_dt,
    check_system,
    output,
    prepare,
)
from aeid_struct.simulation.initial import (
    initial_state,
)
from aeid_struct.simulation.kernels import (
    discretise_batch,
    simulate_batch,
    simulate_loop,
    states_batch,
    states_loop,
)
from aeid_struct.simulation.overflow import OverflowWarning, nonfinite_records, replace_overflow
from aeid_struct.simulation.scaling import (
    denormalise,
    loss,
    normalise,
    record_scale,
    stationary_value,
)

__all__ = [
    "Discrete",
    "OverflowWarning",
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


@dataclass(frozen=True)
class Discrete:
    """The FOH-discretised system of Eq. 10: ``x_{k+1} = Phi x_k + gamma1 u_k + gamma2 Du_k``.

    Attributes
    ----------
    Phi : (batch, n, n) or (n, n)
        ``e^{A dt}``.
    gamma1 : (batch, n) or (n,)
        Input column for ``u_k``: ``int_0^dt e^{A s} ds b``.
    gamma2 : (batch, n) or (n,)
        Input column for ``Du_k = u_{k+1} - u_k`` (Eq. 11): ``(1/dt) int_0^dt e^{A(dt-s)} s ds b``.
    dt : float
        The sample time.
    """

    Phi: Array
    gamma1: Array
    gamma2: Array
    dt: float


def discretise(A: Array, b: Array, dt: float) -> Discrete:
    """Exact first-order-hold discretisation by one matrix exponential (paper Eq. 10).

    ``expm([[A dt, b dt, 0], [0, 0, 1], [0, 0, 0]])`` (block matrix)
    ``= [[Phi, gamma1, gamma2], [0, 1, 1], [0, 0, 1]]``, so that
    ``x_{k+1} = Phi x_k + gamma1 u_k + gamma2 (u_{k+1} - u_k)`` (Eq. 11) for inputs that are linear
    between samples.

    Parameters
    ----------
    A : (batch, n, n) or (n, n)
    b : (batch, n) or (n,)
    dt : float, > 0

    Returns
    -------
    Discrete
        ``Phi (batch, n, n)``, ``gamma1, gamma2 (batch, n)`` (no batch axis when neither input had
        one); numpy float64 for numpy input, torch (differentiable) for torch input.

    Raises
    ------
    ValueError
        Naming the argument with a wrong shape, a non-finite entry, or a bad ``dt``.
    """
    t, torch_out = prepare({"A": A, "b": b})
    dt = check_dt(dt)
    _, batch, is_batched = check_system(t)
    t = batched(t, batch)
    Phi, gamma1, gamma2 = discretise_batch(t["A"], t["b"], dt)
    return Discrete(
        Phi=output(Phi, torch_out, is_batched),
        gamma1=output(gamma1, torch_out, is_batched),
        gamma2=output(gamma2, torch_out, is_batched),
        dt=dt,
    )


def states(A: Array, b: Array, u: Array, dt: float, *, x0: Array | None = None) -> Array:
    """The state sequence of Eq. 12, ``X[:, k] = x(k dt)``, exact for a first-order-hold input.

    Parameters
    ----------
    A : (batch, n, n) or (n, n)
    b : (batch, n) or (n,)
    u : (batch, steps) or (steps,)
        Input samples at ``t_k = k dt``; linear in between.
    dt : float, > 0
    x0 : (batch, n) or (n,), optional
        State at ``t_0``; zero by default (the paper's assumption, needed by Eq. 15).

    Returns
    -------
    X : (batch, steps, n), or (steps, n) when no input had a batch axis.

    Raises
    ------
    ValueError
        Naming the argument with a wrong shape, a non-finite entry, disagreeing batch sizes, or a
        bad ``dt``.

    Warns
    -----
    RuntimeWarning
        When a state leaves the floating range of the dtype: as in :func:`simulate`, every entry
        of a record from its first sample with an overflowing entry on is +inf, never NaN.
    """
    t, torch_out = prepare({"A": A, "b": b, "u": u, "x0": x0})
    dt = check_dt(dt)
    _, batch, is_batched = check_system(t)
    t = batched(t, batch)
    X = states_batch(t["A"], t["b"], t["u"], dt, t["x0"])
    index = nonfinite_records(X)
    if len(index):
        exact = states_loop(*(t[k][index] for k in ("A", "b", "u")), dt,
                            None if t["x0"] is None else t["x0"][index])
        X = replace_overflow(X, index, exact, "states", t["A"], dt, is_batched)
    return output(X, torch_out, is_batched)


def simulate(
    A: Array, b: Array, c: Array, d: Array | float, u: Array, dt: float, *, x0: Array | None = None
) -> Array:
    """The decoder: exact FOH response ``y_k = c^T x_k + d u_k`` on ``t_k = k dt`` (Eq. 10-13).

    Batched over systems and inputs with no Python loop over either; the time recursion runs in
    ``log2(steps)`` levels (:func:`~aeid_struct.simulation.kernels.simulate_batch`).
    Differentiable with respect to every tensor argument; works in float32 and float64.

    Parameters
    ----------
    A : (batch, n, n) or (n, n)
    b, c : (batch, n) or (n,)
    d : (batch,) or scalar
    u : (batch, steps) or (steps,)
        Input samples; linear between samples (first-order hold). A ``(steps,)`` input drives
        every system of the batch; a batch of inputs may drive one system.
    dt : float, > 0
    x0 : (batch, n) or (n,), optional
        Initial state; zero by default.

    Returns
    -------
    y : (batch, steps), or (steps,) when no input had a batch axis.
        numpy float64 for numpy input, torch for torch input. Where it is finite, each sample
        equals the per-step recursion of Eq. 12-13 to its own relative accuracy, at any
        ``|pole| dt``.

    Raises
    ------
    ValueError
        Naming the argument with a wrong shape, a non-finite entry, disagreeing batch sizes, or a
        bad ``dt``.

    Warns
    -----
    RuntimeWarning
        When the response leaves the floating range of the dtype (float64: 1.8e308, float32:
        3.4e38; an unstable pole ``p`` over ``steps`` samples grows by ``e^{Re(p) dt steps}``):
        the overflowing records are recomputed by the per-step recursion, and every sample of
        theirs from the first that overflows on is +inf (no sign is implied), never NaN; the
        samples before it are exact. The warning (an
        :class:`~aeid_struct.simulation.overflow.OverflowWarning`) names the records, the first
        sample and ``Re(p) dt steps``. The same rule holds for numpy and torch input, float32 and
        float64; other records of the batch are untouched.
    """
    t, torch_out = prepare({"A": A, "b": b, "c": c, "d": d, "u": u, "x0": x0})
    dt = check_dt(dt)
    _, batch, is_batched = check_system(t)
    t = batched(t, batch)
    y = simulate_batch(t["A"], t["b"], t["c"], t["d"], t["u"], dt, t["x0"])
    index = nonfinite_records(y)
    if len(index):
        exact = simulate_loop(*(t[k][index] for k in ("A", "b", "c", "d", "u")), dt,
                              None if t["x0"] is None else t["x0"][index])
        y = replace_overflow(y, index, exact, "simulate", t["A"], dt, is_batched)
    return output(y, torch_out, is_batched)
