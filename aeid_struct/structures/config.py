"""A structure as data: the registry of structure types and the reading of their configs.

``Structure.config()`` is a JSON-serialisable dict ``{"type": name, ...constructor
arguments..., "fixed": {name: value}}``; ``Structure.from_config`` rebuilds the structure and
checks every entry's type, since a config comes from a file. A ``Physical`` structure's CasADi
maps are entries of ``aeid_struct.structures.maps`` (named references, or a user's map that the
caller passes again), never code read from the file without ``trust=True``.
"""

from __future__ import annotations

import abc
import inspect
import json

from aeid_struct.structures.maps import check_maps

__all__ = ["REGISTRY", "Configurable", "Described", "register", "type_of"]

#: Structure type name -> class: every subclass of ``Structure`` registers itself.
REGISTRY: dict[str, type] = {}


def register(cls: type) -> None:
    """Register a structure type under its class name, for :meth:`Configurable.from_config`.

    Parameters
    ----------
    cls : type
        A subclass of ``Structure`` (``Structure.__init_subclass__`` calls this).
    """
    REGISTRY[cls.__name__] = cls


def type_of(structure) -> str | None:
    """The registered type name of a structure (``"CCF"``, ``"MCF"``, ``"Physical"``), or None
    for none, read without importing the structure classes (torch): a structure known by its
    config alone (:class:`Described`) answers too.

    Parameters
    ----------
    structure : Structure, Described or None

    Returns
    -------
    str or None
    """
    if structure is None:
        return None
    return getattr(structure, "type_name", None) or type(structure).__name__


class Described:
    """A structure known by its config alone: its type, element names and fixed values, and no
    assembly. What the ONNX runner holds where torch is not installed: enough for the separable
    head's pattern and an estimate's physical parameters (``refine`` needs the structure
    itself).

    Parameters
    ----------
    config : dict
        The structure's config (``Structure.config()``), e.g. ``{"type": "CCF", "n": 2,
        "feedthrough": False, "fixed": {"c1": 0.0}, ...}``.
    names : sequence of str
        Its element names.
    """

    records = 1

    def __init__(self, config: dict, names) -> None:
        if not (isinstance(config, dict) and isinstance(config.get("type"), str)):
            raise ValueError(f"config must be a structure's config with a 'type'; got "
                             f"{config!r}")
        self._config = json.loads(json.dumps(config))
        self.type_name = config["type"]
        self.element_names = tuple(names)
        self.n = int(config.get("n", 0))
        self.feedthrough = bool(config.get("feedthrough", False))
        self.fixed_values = dict(config.get("fixed", {}))

    def config(self) -> dict:
        """The config it was described by (a copy).

        Returns
        -------
        dict
        """
        return json.loads(json.dumps(self._config))

    def __repr__(self) -> str:
        return f"Described({self._config!r})"


def _parse_config(config) -> tuple[type, dict, dict]:
    """Check the frame of a structure config and find its type.

    Parameters
    ----------
    config : dict
        ``{"type": name, ...constructor arguments..., "fixed": {name: value}}``.

    Returns
    -------
    cls : type
        The registered structure type.
    args : dict
        The constructor arguments (the entries other than ``type`` and ``fixed``).
    fixed : dict str -> number
        The fixed elements.

    Raises
    ------
    ValueError
        For a config that is not a dict with a ``type`` entry, an unknown type, and a ``fixed``
        entry that is not a dict name -> number.
    """
    if not isinstance(config, dict) or not isinstance(config.get("type"), str):
        raise ValueError(f"config must be a dict with a 'type' entry; got {config!r}")
    kind = config["type"]
    if kind not in REGISTRY:
        raise ValueError(f"unknown structure type {kind!r}; valid types: "
                         f"{', '.join(REGISTRY)}")
    fixed = config.get("fixed", {})
    if not isinstance(fixed, dict) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in fixed.values()):
        raise ValueError(f"invalid config for {kind}: 'fixed' must be a dict name -> "
                         f"number; got {fixed!r}")
    args = {k: v for k, v in config.items() if k not in ("type", "fixed")}
    return REGISTRY[kind], args, fixed


def _from_arguments(cls: type, args: dict):
    """``cls(**args)`` for constructor arguments read from JSON, with their types checked.

    Parameters
    ----------
    cls : type
        A structure type whose constructor takes only JSON values (``CCF``, ``MCF``).
    args : dict
        The config's constructor arguments.

    Returns
    -------
    Structure

    Raises
    ------
    ValueError
        For a switch that is not a bool, or a value the constructor would coerce
        (``"descartes": "yes"``).
    """
    switches = {k for k, v in inspect.signature(cls.__init__).parameters.items()
                if isinstance(v.default, bool)}
    for key in switches & set(args):
        if not isinstance(args[key], bool):     # JSON "yes" for a switch
            raise ValueError(f"invalid config for {cls.__name__}: {key!r} must be a bool; "
                             f"got {args[key]!r}")
    structure = cls(**args)
    # JSON of the wrong type that the constructor would coerce ("descartes": "yes")
    for key, value in structure.config().items():
        if key in ("type", "fixed"):
            continue
        if key in args and (args[key] != value
                            or isinstance(args[key], bool) != isinstance(value, bool)):
            raise ValueError(f"invalid config for {cls.__name__}: {key!r} must be a "
                             f"{type(value).__name__}; got {args[key]!r}")
    return structure


class Configurable(abc.ABC):
    """A structure as data: ``config()`` <-> ``from_config()``, equality by config.

    The base of ``Structure``, whose subclasses :func:`register` themselves under their class
    name and define ``_config`` (their constructor arguments as JSON values) and, where the
    constructor takes more than JSON values, ``_from_config``.
    """

    @abc.abstractmethod
    def _config(self) -> dict:
        """Constructor arguments as JSON-serialisable values."""

    def config(self) -> dict:
        """A JSON-serialisable dict from which :meth:`from_config` rebuilds this structure.

        It holds data only: a ``Physical`` structure's CasADi maps are named
        (``aeid_struct.structures.maps``), never serialised as code, except a user's own map,
        which :meth:`from_config` reads back only when the caller passes it again or trusts the
        config.

        Returns
        -------
        dict
            ``{"type": name, ...constructor arguments..., "fixed": {name: value}}``.
        """
        return {"type": type(self).__name__, **self._config(), "fixed": dict(self._fixed)}

    @staticmethod
    def from_config(config: dict, *, maps: dict | None = None,
                    trust: bool = False) -> Configurable:
        """The structure described by ``config`` (the output of :meth:`config`).

        Parameters
        ----------
        config : dict
            ``{"type": name, ...constructor arguments..., "fixed": {name: value}}``.
        maps : dict name -> casadi.Function, optional
            The user maps a ``Physical`` config names (``{"map": name, "user": true, ...}``),
            passed again; each must match the SHA-256 the config recorded.
        trust : bool
            Deserialise user maps, and the serialised Functions of configs written before
            named maps, from the config itself. A serialised CasADi Function can run shell
            commands when it is read: only for configs whose source you trust.

        Returns
        -------
        Structure
            A new structure of the registered type, with the fixed elements fixed.

        Raises
        ------
        ValueError
            For an unknown type, unknown or missing entries, values of the wrong type, and map
            entries that cannot be resolved (``aeid_struct.structures.from_entry``).
        """
        check_maps(maps, trust)
        cls, args, fixed = _parse_config(config)
        try:
            structure = cls._from_config(args, maps=maps, trust=trust)
        except (TypeError, KeyError) as e:
            raise ValueError(f"invalid config for {cls.__name__}: {e}") from None
        return structure.fixed(**fixed)

    @classmethod
    def _from_config(cls, args: dict, *, maps=None, trust: bool = False) -> Configurable:
        return _from_arguments(cls, args)

    def _base_repr(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self._config().items())
        return f"{type(self).__name__}({args})"

    def __repr__(self) -> str:
        fixed = ", ".join(f"{k}={v!r}" for k, v in self._fixed.items())
        return self._base_repr() + (f".fixed({fixed})" if fixed else "")

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Configurable) and self.config() == other.config()

    def __hash__(self) -> int:
        return hash(json.dumps(self.config(), sort_keys=True))
