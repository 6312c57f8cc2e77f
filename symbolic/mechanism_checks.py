"""The checks of a :class:`~symbolic.mechanism.Mechanism`'s arguments, once, at its boundary:
symbols that are symbols, expressions in declared symbols only, parameter names the Functions do
not reserve, known values that are finite numbers, channels that exist."""

from __future__ import annotations

from collections.abc import Mapping

import casadi
import numpy as np

__all__ = ["RESERVED", "channel_indices", "checked_expression", "checked_known",
           "checked_parameters", "checked_vector"]

#: Names a parameter may not take: the Functions' own inputs and outputs.
RESERVED = frozenset({"x", "u", "q", "dq", "xdot", "y", "A", "B", "C", "D", "x_eq", "u_eq"})


def checked_vector(name: str, value, length: int | None = None) -> casadi.SX:
    """``value`` as an SX column of distinct symbols (a Function input).

    Parameters
    ----------
    name : str
        The argument's name, in messages.
    value : casadi.SX
    length : int, optional
        The entries it must have.

    Returns
    -------
    casadi.SX

    Raises
    ------
    ValueError
        Not an SX column of distinct symbols (of ``length``).
    """
    if not isinstance(value, casadi.SX):
        raise ValueError(f"{name} must be a casadi.SX vector of symbols (casadi.SX.sym("
                         f"'{name}', n)); got {type(value).__name__}")
    if value.size2() != 1 or value.numel() == 0:
        raise ValueError(f"{name} must be a non-empty column vector; got shape {value.shape}")
    if not value.is_valid_input():
        raise ValueError(f"{name} must hold distinct symbols only (not expressions), as "
                         f"casadi.SX.sym('{name}', n) does")
    if length is not None and value.numel() != length:
        raise ValueError(f"{name} must have {length} entries, one per coordinate of q; got "
                         f"{value.numel()}")
    return value


def checked_expression(name: str, value, allowed: casadi.SX,
                       shape: tuple | None = None) -> casadi.SX:
    """``value`` (an SX expression or numbers) in the symbols ``allowed`` only.

    Parameters
    ----------
    name : str
        The argument's name, in messages.
    value : casadi.SX, number or array
    allowed : casadi.SX
        The symbols it may depend on.
    shape : tuple, optional
        The shape it must have.

    Returns
    -------
    casadi.SX

    Raises
    ------
    ValueError
        Not an expression, another shape, or undeclared symbols (named).
    """
    if isinstance(value, (int, float, np.ndarray, list, tuple, casadi.DM)):
        value = casadi.SX(casadi.DM(value))
    if not isinstance(value, casadi.SX):
        raise ValueError(f"{name} must be a casadi.SX expression; got {type(value).__name__}")
    if shape is not None and value.shape != shape:
        raise ValueError(f"{name} must have shape {shape}; got {value.shape}")
    known = {s.name() for s in casadi.symvar(allowed)}
    stray = sorted({s.name() for s in casadi.symvar(value)} - known)
    if stray:
        raise ValueError(f"{name} depends on symbols {stray} that are neither q, dq, u nor a "
                         f"parameter; declare them (parameters={{'name': symbol}})")
    return value


def checked_parameters(parameters) -> dict[str, casadi.SX]:
    """``parameters`` checked: identifiers the Functions do not reserve, scalar symbols.

    Parameters
    ----------
    parameters : dict str -> casadi.SX

    Returns
    -------
    dict str -> casadi.SX

    Raises
    ------
    ValueError
        Empty, a reserved or non-identifier name, or a value that is no scalar symbol.
    """
    if not isinstance(parameters, Mapping) or not parameters:
        raise ValueError("parameters must be a non-empty dict name -> casadi.SX symbol; got "
                         f"{type(parameters).__name__}")
    out = {}
    for key, symbol in parameters.items():
        if not (isinstance(key, str) and key.isidentifier()) or key in RESERVED:
            raise ValueError(f"parameters: {key!r} must be an identifier other than "
                             f"{sorted(RESERVED)} (the Functions' own names)")
        if not (isinstance(symbol, casadi.SX) and symbol.is_scalar()
                and symbol.is_valid_input()):
            raise ValueError(f"parameters[{key!r}] must be a scalar casadi.SX symbol "
                             f"(casadi.SX.sym({key!r})); got {symbol!r}")
        out[key] = symbol
    return out


def checked_known(names: tuple, known) -> tuple[tuple[str, ...], dict]:
    """``Mechanism.free``: the parameters not in ``known``, and ``known`` as floats.

    Parameters
    ----------
    names : tuple of str
        The mechanism's parameters.
    known : dict str -> float or None

    Returns
    -------
    free : tuple of str
    values : dict str -> float

    Raises
    ------
    ValueError
        Not a dict, names that are not parameters, values that are not finite numbers, or
        every parameter known.
    """
    known = {} if known is None else known
    if not isinstance(known, Mapping):
        raise ValueError(f"known must be a dict name -> value; got {type(known).__name__}")
    stray = sorted(set(known) - set(names))
    if stray:
        raise ValueError(f"known names {stray}, which are not parameters of the mechanism "
                         f"({list(names)})")
    values = {}
    for key, value in known.items():
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) \
                or not np.isfinite(value):
            raise ValueError(f"known[{key!r}] must be a finite number; got {value!r}")
        values[key] = float(value)
    free = tuple(n for n in names if n not in values)
    if not free:
        raise ValueError("known fixes every parameter: nothing is left to identify")
    return free, values


def channel_indices(shape: tuple, output, input, states) -> list[int]:
    """``Mechanism.channel``'s indices checked.

    Parameters
    ----------
    shape : (n, m, p)
        The mechanism's states, inputs, outputs.
    output, input : int
    states : sequence of int or None

    Returns
    -------
    list of int
        The subsystem's states (all ``n`` for None).

    Raises
    ------
    ValueError
        An index out of range, or repeated states.
    """
    n, m, p = shape
    if not (isinstance(output, int) and 0 <= output < p):
        raise ValueError(f"output must be an int in [0, {p}); got {output!r}")
    if not (isinstance(input, int) and 0 <= input < m):
        raise ValueError(f"input must be an int in [0, {m}); got {input!r}")
    s = list(range(n)) if states is None else [int(i) for i in states]
    if not s or len(set(s)) != len(s) or not all(0 <= i < n for i in s):
        raise ValueError(f"states must be distinct state indices in [0, {n}); got {states!r}")
    return s
