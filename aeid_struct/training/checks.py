"""Argument checks shared by the training modules: each returns the checked value or raises a
``ValueError`` that names the argument, what was expected and what came.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np


def real(name: str, value, what: str, test: Callable[[float], bool]) -> float:
    """``value`` as a float when it is a finite real number that passes ``test``.

    Parameters
    ----------
    name : str
        The argument's name, for the message.
    value : object
        What came; strings, bools, NaN and inf are refused.
    what : str
        What is expected, for the message ("positive and finite").
    test : callable float -> bool
        The range check.

    Returns
    -------
    value : float

    Raises
    ------
    ValueError
        "<name> must be <what>; got <value>".
    """
    ok = isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool)
    v = float(value) if ok else math.nan
    if not (math.isfinite(v) and test(v)):
        raise ValueError(f"{name} must be {what}; got {value!r}")
    return v


def positive(name: str, value) -> float:
    """A positive finite number (not a bool, not a string) as a float.

    Parameters
    ----------
    name : str
        The argument's name, for the message.
    value : object
        What came.

    Returns
    -------
    value : float
    """
    if not (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, (bool, np.bool_)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number; got {value!r}")
    return float(value)


def count(name: str, value) -> int:
    """A positive integer (not a bool) as an int.

    Parameters
    ----------
    name : str
        The argument's name, for the message.
    value : object
        What came.

    Returns
    -------
    value : int
    """
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) \
            or value < 1:
        raise ValueError(f"{name} must be a positive integer; got {value!r}")
    return int(value)


def value_range(name: str, value) -> tuple[float, float]:
    """A ``(lo, hi)`` pair of finite numbers with ``lo <= hi``.

    Parameters
    ----------
    name : str
        The argument's name, for the message.
    value : object
        What came: a pair of numbers (a string is refused, though it unpacks).

    Returns
    -------
    lo, hi : float
    """
    try:
        if isinstance(value, (str, bytes)):
            raise TypeError    # "12" would unpack to (1.0, 2.0)
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a (lo, hi) pair of numbers; got {value!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi)) or lo > hi:
        raise ValueError(f"{name} must satisfy lo <= hi, both finite; got ({lo}, {hi})")
    return lo, hi


def generator(rng) -> np.random.Generator:
    """``rng`` when it is a numpy ``Generator`` (every random draw comes from an explicit one).

    Parameters
    ----------
    rng : object
        What came.

    Returns
    -------
    rng : numpy.random.Generator
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator (np.random.default_rng(seed)); "
                         f"got {type(rng).__name__}")
    return rng
