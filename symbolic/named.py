"""Named maps: a CasADi Function built by a named factory remembers how it was built.

A model file must hold data, never code: a serialised ``casadi.Function`` is code (it can carry
JIT options that run a shell command when it is read back). So a file refers to a map by the
name of the factory that builds it and the factory's numeric constants,

    {"map": "symbolic.leg.stable_map", "args": {"l0": 0.8, "g": 9.81}},

and the reader calls the factory again (``aeid_struct.structures.maps`` holds the allow-list of
factories a file may name). This module only remembers, for every Function a factory decorated
with :func:`named` returns, that reference; it depends on nothing but the standard library, so
that ``symbolic`` stays importable without ``aeid_struct``.
"""

from __future__ import annotations

import functools
import inspect
import math
import weakref
from collections.abc import Callable

#: id(Function) -> (weak reference to it, its reference). The weak reference's callback removes
#: the entry when the Function dies, so that a later object with the same id is not mistaken for
#: it and maps built in a loop do not pile up.
_BUILT: dict[int, tuple[weakref.ref, dict]] = {}


def _forget(key: int, ref: weakref.ref) -> None:
    hit = _BUILT.get(key)
    if hit is not None and hit[0] is ref:
        del _BUILT[key]


def remember(function, name: str, args: dict[str, float]) -> None:
    """Record that ``function`` is what the factory ``name`` builds from the constants ``args``.

    Parameters
    ----------
    function : casadi.Function
    name : str
        The factory's registered name, e.g. ``"symbolic.leg.stable_map"``.
    args : dict str -> float
        Every keyword argument of the factory, as finite numbers.
    """
    key = id(function)
    ref = weakref.ref(function, lambda r, key=key: _forget(key, r))
    _BUILT[key] = (ref, {"map": name, "args": dict(args)})


def reference(function) -> dict | None:
    """The reference of a Function built by a :func:`named` factory (or passed to
    :func:`remember`).

    Parameters
    ----------
    function : casadi.Function

    Returns
    -------
    dict or None
        ``{"map": name, "args": {keyword: number}}``, or None for any other Function.
    """
    hit = _BUILT.get(id(function))
    if hit is None or hit[0]() is not function:
        return None
    return {"map": hit[1]["map"], "args": dict(hit[1]["args"])}


def named(name: str) -> Callable[[Callable], Callable]:
    """Decorate a factory of CasADi Functions so that every Function it returns remembers
    ``{"map": name, "args": {...}}``, with all the factory's keyword constants (defaults
    included) as floats.

    A factory call with a constant that is not a real number (the factory validates its own
    arguments first) returns a Function without a reference.

    Parameters
    ----------
    name : str
        The name a file uses for the factory, e.g. ``"symbolic.leg.stable_map"``.

    Returns
    -------
    callable
        The decorator: factory -> the same factory, whose Functions remember their reference
        (its attribute ``map_name`` is ``name``).
    """

    def decorate(factory: Callable) -> Callable:
        signature = inspect.signature(factory)

        @functools.wraps(factory)
        def build(*args, **kwargs):
            function = factory(*args, **kwargs)
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            try:
                constants = {k: float(v) for k, v in bound.arguments.items()}
            except (TypeError, ValueError):
                return function
            if all(math.isfinite(v) for v in constants.values()):
                remember(function, name, constants)
            return function

        build.map_name = name
        return build

    return decorate
