"""``--maps FILE.py``: the CasADi maps of a user's own mechanism, built again by the user's code.

An identifier trained on ``ae.Physical(mechanism, ...)`` stores its map by name and SHA-256 (a
model file holds data, never code), so reading it needs the map again. In Python that is
``ae.load(path, maps={name: structure.function})``; on the command line the user names the
Python file that builds the structure (the same file they trained it with), and this module
runs it and collects its maps. Running the file is the user's choice, as ``python FILE.py``
is: it is their own code, not something read from the model file, whose maps are still
checked against the SHA-256 it recorded.

The file runs with ``__name__ != "__main__"`` (training code under
``if __name__ == "__main__":`` does not run again); every module-level value that is a
``casadi.Function``, a structure with ``.function`` (and ``.inverse``) Functions (``ae.Physical``),
or a dict or list or tuple of those is collected under its ``Function.name()``.
"""

from __future__ import annotations

import runpy
from pathlib import Path

from aeid_struct.cli.errors import InputError, one_line

__all__ = ["MAPS_HELP", "maps_hint", "read_maps"]

#: The help of ``--maps`` (``identify``, ``track``, ``identify-many``).
MAPS_HELP = ("with an identifier file of your own mechanism (ae.Physical(mechanism, ...)): the "
             "Python file that builds its structure (or its casadi.Function), run as your own "
             "code (not as __main__) to give the maps the file names again; each is checked "
             "against the SHA-256 the file recorded (a model file holds no code)")


def read_maps(path: str | None, option: str = "--maps") -> dict | None:
    """The CasADi Functions that the Python file ``path`` builds at module level, by name.

    Parameters
    ----------
    path : str or None
        A ``.py`` file (None: no maps, returned as None).
    option : str
        The option that named it, for the errors.

    Returns
    -------
    dict str -> casadi.Function or None
        The Functions by their ``name()``: the ``maps=`` of ``aeid_struct.load``.

    Raises
    ------
    InputError
        The file is missing or not a ``.py`` file, raises when it runs, builds no Function, or
        builds two different Functions of one name.
    """
    if path is None:
        return None
    file = Path(path)
    if file.suffix != ".py":
        raise InputError(f"{option}: expected a Python file (.py) that builds the identifier's "
                         f"maps (e.g. its ae.Physical structure); got {path!r}")
    if not file.is_file():
        raise InputError(f"{option}: file not found: {path!r}")
    try:
        values = runpy.run_path(str(file), run_name="__aeid_maps__")
    except SystemExit as err:
        raise InputError(f"{option} {path!r} exited ({err.code}) while it ran") from None
    except Exception as err:  # the user's code: any error is theirs, told in one line
        raise InputError(f"{option} {path!r} raised {type(err).__name__} while it ran: "
                         f"{one_line(err)}") from None
    found: dict = {}
    where: dict = {}
    for variable, value in values.items():
        if variable.startswith("__"):
            continue
        for function in _functions(value):
            name = function.name()
            if name in found and found[name] is not function \
                    and found[name].serialize() != function.serialize():
                raise InputError(f"{option} {path!r}: two different CasADi Functions are named "
                                 f"{name!r} (in {where[name]!r} and {variable!r}); an "
                                 f"identifier file names its maps, so give each a name of its "
                                 f"own")
            found.setdefault(name, function)
            where.setdefault(name, variable)
    if not found:
        raise InputError(f"{option} {path!r} builds no CasADi map at module level: define the "
                         f"identifier's structure there (structure = ae.Physical(mechanism, "
                         f"bounds=...)), or its casadi.Function")
    return found


def maps_hint(err: Exception, maps: str | None) -> str:
    """What to add to a loading error that asks for a user map, on the command line.

    Parameters
    ----------
    err : Exception
        The error of ``aeid_struct.load``.
    maps : str or None
        The ``--maps`` option as given.

    Returns
    -------
    str
        ``" (on the command line: --maps FILE.py ...)"`` where the library asked for
        ``maps=`` and none was given, else ``""``.
    """
    if maps is not None or "is the user map" not in str(err):
        return ""
    return (" (on the command line: --maps FILE.py, the Python file that builds the "
            "identifier's structure, e.g. structure = ae.Physical(mechanism, bounds=...); the "
            "command never trusts a file)")


def _functions(value) -> list:
    """The casadi.Functions ``value`` is or holds (a structure's map and inverse, containers)."""
    import casadi

    from aeid_struct.structures import Structure

    if isinstance(value, casadi.Function):
        return [value]
    if isinstance(value, dict):
        return [f for v in value.values() for f in _functions(v)]
    if isinstance(value, (list, tuple)):
        return [f for v in value for f in _functions(v)]
    if not isinstance(value, Structure):
        return []
    return [f for f in (getattr(value, "function", None), getattr(value, "inverse", None))
            if isinstance(f, casadi.Function)]
