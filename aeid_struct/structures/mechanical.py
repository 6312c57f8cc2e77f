"""A :class:`~symbolic.mechanism.Mechanism` as a physical structure's map: the CCF of one of its
channels (``Mechanism.channel``) as a Function of its free parameters, after an identifiability
check of that channel over the structure's box, so that a structure whose record cannot
determine a parameter is refused before any training (docs/architecture.md, "Your own
mechanism")."""

from __future__ import annotations

from collections.abc import Mapping

import casadi

__all__ = ["is_mechanism", "mechanism_map"]


def is_mechanism(value) -> bool:
    """Whether ``value`` is a ``symbolic.mechanism.Mechanism`` (by its type, imported here so
    that a plain CasADi map does not import the mechanism module).

    Parameters
    ----------
    value : object

    Returns
    -------
    bool
    """
    from symbolic.mechanism import Mechanism

    return isinstance(value, Mechanism)


def mechanism_map(mechanism, bounds: Mapping, known: Mapping | None, channel,
                  operating: dict) -> casadi.Function:
    """The map of ``Physical(mechanism, ...)``: the CCF of ``channel`` as a Function of the
    parameters not in ``known``, checked identifiable over ``bounds``.

    Parameters
    ----------
    mechanism : Mechanism
    bounds : dict name -> (lo, hi)
        Every free parameter's box (``Physical``'s bounds).
    known : dict name -> float or None
        Parameters held at known values.
    channel : (output, input) or (output, input, states), or None
        The channel the records hold (``Mechanism.channel``); ``(0, 0)`` by default.
    operating : dict
        ``u``, ``q``, ``guess`` of ``Mechanism.linearise``.

    Returns
    -------
    casadi.Function
        ``'<name>_y<i>_u<j>'``: the free parameters by name -> ``A, B, C, D`` of the CCF.

    Raises
    ------
    ValueError
        A malformed channel or operating point; bounds that are not the free parameters'; a
        parameter the channel's records cannot determine (named, with what to fix).
    """
    from symbolic.identifiability import identifiability

    spec = (0, 0) if channel is None else tuple(channel)
    if len(spec) not in (2, 3):
        raise ValueError(f"channel must be (output, input) or (output, input, states); got "
                         f"{channel!r}")
    output, input, *states = spec
    free, _ = mechanism.free(known)
    if not isinstance(bounds, Mapping) or set(bounds) != set(free):
        given = sorted(bounds) if isinstance(bounds, Mapping) else bounds
        raise ValueError(f"bounds must give every parameter of {mechanism.name} not in known "
                         f"({list(free)}); got {given!r}")
    report = identifiability(mechanism, bounds, known=known, inputs=[input], outputs=[output],
                             **operating)
    if not report.full:
        raise ValueError(
            f"a record of y[{output}] from u[{input}] cannot determine "
            f"{', '.join(report.unidentifiable)} of {mechanism.name} (rank {report.rank} of "
            f"{len(report.parameters)}); fix {', '.join(report.fix)} with known={{...}} or "
            f"measure another channel:\n{report}")
    return mechanism.channel(output, input, states=states[0] if states else None, known=known,
                             **operating)
