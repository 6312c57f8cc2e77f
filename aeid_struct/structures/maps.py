"""Named maps: how a model file refers to a CasADi Function without holding its code.

A model file holds data, never code. A serialised ``casadi.Function`` is code: one built with
``{"jit": True, "compiler": "shell", "jit_options": {"compiler": "<command>"}}`` runs the command
when ``casadi.Function.deserialize`` reads it back, with or without a C compiler installed. So
the files of this library (``.aeid`` identifiers, ``Structure.config``, the ONNX export's
metadata) store a map as an *entry*, one of

- a **reference** to a factory of the allow-list :data:`MAPS` and its numeric constants,
  ``{"map": "symbolic.leg.stable_inverse", "args": {"l0": 0.8, "g": 9.81}}``. Reading it calls
  that factory with those numbers (:func:`resolve`); nothing from the file is imported or
  executed. Every Function the factories return remembers its reference
  (``symbolic.named``), so ``leg.stable_map(l0=0.8)`` is saved as a reference;
- a **user map** (any other ``casadi.Function``),
  ``{"map": <its name>, "user": true, "sha256": <hash of fn.serialize()>, "serialized": <text>}``.
  Reading it needs the caller's consent: pass the Function again (``maps={name: fn}``; its
  SHA-256 must match the file's), or ``trust=True``, which deserialises ``"serialized"`` -- code
  from the file, for files whose source you trust only.

Files written before named maps (``aeid-struct/identifier/1``, ``aeid-struct-onnx-1``) hold
Functions as serialised text; they load only with ``trust=True`` (:func:`from_entry`). A
Function read that way that is byte-for-byte what a factory of :data:`MAPS` builds with its
default constants gets that factory's reference, so saving it again writes a reference.
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import inspect
import math

import casadi

#: The allow-list: the factories a file may name, name -> (module, attribute). Resolving a
#: reference imports only these modules; a name that is not here is an error.
MAPS: dict[str, tuple[str, str]] = {
    **{f"symbolic.leg.{f}": ("symbolic.leg", f)
       for f in ("stable_map", "unstable_map", "joint_map",
                 "stable_inverse", "unstable_inverse", "joint_inverse")},
    **{f"symbolic.mechanisms.{f}": ("symbolic.mechanisms", f)
       for f in ("drive_train_channels", "cart_pole_channels")},
}

_ENTRY_KEYS = {"map", "args"}
_USER_KEYS = {"map", "user", "sha256", "serialized"}


def factory(name: str):
    """The factory registered as ``name`` in :data:`MAPS`.

    Parameters
    ----------
    name : str
        A key of :data:`MAPS`, e.g. ``"symbolic.leg.stable_map"``.

    Returns
    -------
    callable
        The factory: keyword constants -> casadi.Function.

    Raises
    ------
    ValueError
        For a name that is not registered (the message lists the valid names).
    """
    if not isinstance(name, str) or name not in MAPS:
        raise ValueError(f"unknown map {name!r}; a file may name only {', '.join(MAPS)}")
    module, attribute = MAPS[name]
    return getattr(importlib.import_module(module), attribute)


def reference(function) -> dict | None:
    """The reference of a Function built by a factory of :data:`MAPS`.

    Parameters
    ----------
    function : casadi.Function

    Returns
    -------
    dict or None
        ``{"map": name, "args": {keyword: number}}``, or None for any other Function.
    """
    from symbolic.named import reference as _reference

    ref = _reference(function)
    return ref if ref is not None and ref["map"] in MAPS else None


def sha256(function: casadi.Function) -> str:
    """The SHA-256 of ``function.serialize()``: what a user map entry records.

    Parameters
    ----------
    function : casadi.Function

    Returns
    -------
    str
        64 hex digits.
    """
    return hashlib.sha256(function.serialize().encode()).hexdigest()


def to_entry(function: casadi.Function) -> dict:
    """What a file holds for ``function`` (module docstring).

    Parameters
    ----------
    function : casadi.Function

    Returns
    -------
    dict
        Its reference (a factory of :data:`MAPS`), else a user map entry
        ``{"map", "user", "sha256", "serialized"}``.

    Raises
    ------
    ValueError
        If ``function`` is not a casadi.Function.
    """
    if not isinstance(function, casadi.Function):
        raise ValueError(f"function must be a casadi.Function; got {type(function).__name__}")
    ref = reference(function)
    if ref is not None:
        return ref
    text = function.serialize()
    return {"map": function.name(), "user": True,
            "sha256": hashlib.sha256(text.encode()).hexdigest(), "serialized": text}


def _number(value) -> bool:
    return (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value))


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else f"{text[:60]}... ({len(text)} characters)"


@functools.lru_cache(maxsize=64)
def _build(name: str, args: tuple[tuple[str, float], ...]) -> casadi.Function:
    """The factory's Function for these constants, built once (a factory derives its model
    symbolically, which is worth caching)."""
    return factory(name)(**dict(args))


def resolve(ref: dict, what: str = "map") -> casadi.Function:
    """The Function a reference ``{"map": name, "args": {keyword: number}}`` names.

    Parameters
    ----------
    ref : dict
        The reference (:func:`reference`); ``"args"`` may omit keywords (their defaults).
    what : str
        How error messages name the reference (e.g. ``"'inverse'"``).

    Returns
    -------
    casadi.Function
        Built by the factory of :data:`MAPS` (cached per name and constants), remembering its
        reference.

    Raises
    ------
    ValueError
        For a reference that is not a dict of exactly ``map`` and ``args``, an unknown map name,
        an unknown keyword, a constant that is not a finite number, or one the factory refuses.
    """
    if not isinstance(ref, dict) or "map" not in ref:
        raise ValueError(f"{what} must be a map reference {{'map': name, 'args': {{...}}}}; "
                         f"got {_short(ref)}")
    extra = sorted(set(ref) - _ENTRY_KEYS)
    if extra:
        raise ValueError(f"{what} has unknown key(s) {extra}; a map reference has 'map' and "
                         "'args'")
    name = ref["map"]
    if not isinstance(name, str) or name not in MAPS:
        raise ValueError(f"{what} names the unknown map {_short(name)}; a file may name only "
                         f"{', '.join(MAPS)} (or a user map, passed again with maps=)")
    args = ref.get("args", {})
    if not isinstance(args, dict):
        raise ValueError(f"{what}: 'args' of {name} must be a dict keyword -> number; "
                         f"got {_short(args)}")
    keywords = list(inspect.signature(factory(name)).parameters)
    for key, value in args.items():
        if key not in keywords:
            raise ValueError(f"{what}: {name} has no constant {key!r}; its constants: "
                             f"{', '.join(keywords)}")
        if not _number(value):
            raise ValueError(f"{what}: constant {key!r} of {name} must be a finite number; "
                             f"got {_short(value)}")
    try:
        return _build(name, tuple(sorted((k, float(v)) for k, v in args.items())))
    except (TypeError, ValueError) as err:
        raise ValueError(f"{what}: {name} refuses its constants {args}: {err}") from None


def check_maps(maps, trust: bool = False) -> dict:
    """Validate the ``maps=`` and ``trust=`` arguments of a reader.

    Parameters
    ----------
    maps : dict str -> casadi.Function or None
        The user maps a caller passes again.
    trust : bool

    Returns
    -------
    dict str -> casadi.Function
        ``maps`` as a new dict (empty for None).

    Raises
    ------
    ValueError
        If ``maps`` is not None or such a dict, or ``trust`` is not a bool.
    """
    if not isinstance(trust, bool):
        raise ValueError(f"trust must be True or False; got {_short(trust)}")
    if maps is None:
        return {}
    if not isinstance(maps, dict) or not all(
            isinstance(k, str) and isinstance(v, casadi.Function) for k, v in maps.items()):
        raise ValueError("maps must be a dict name -> casadi.Function (the user maps the file "
                         f"names, keyed by their names); got {_short(maps)}")
    return dict(maps)


def _deserialize(text: str, what: str) -> casadi.Function:
    try:
        function = casadi.Function.deserialize(text)
    except Exception as err:  # CasADi raises RuntimeError with its own text
        first = str(err).strip().splitlines()[-1] if str(err).strip() else type(err).__name__
        raise ValueError(f"{what} could not be deserialised by CasADi: {first}") from None
    _recognise(function)
    return function


def _recognise(function: casadi.Function) -> None:
    """Give a deserialised Function the reference of the factory of :data:`MAPS` of the same
    name whose default build it equals byte for byte, so that saving it writes a reference."""
    from symbolic.named import remember

    for name in MAPS:
        if name.rsplit(".", 1)[1] == function.name():
            default = factory(name)()
            if default.serialize() == function.serialize():
                remember(function, name, reference(default)["args"])
            return


def from_entry(entry, what: str = "map", *, maps=None, trust: bool = False) -> casadi.Function:
    """The Function of a file's map entry (module docstring).

    Parameters
    ----------
    entry : dict or str
        A reference dict, a user map dict, or (files before named maps) serialised text.
    what : str
        How error messages name the entry (e.g. ``"'inverse'"``).
    maps : dict str -> casadi.Function, optional
        The user maps, passed again by the caller; each must have the SHA-256 the file
        recorded.
    trust : bool
        Deserialise user maps and old serialised text from the file. A serialised CasADi
        Function can run shell commands when it is read: only for files you trust.

    Returns
    -------
    casadi.Function

    Raises
    ------
    ValueError
        For a user map or serialised text without ``maps``/``trust`` (naming both ways out), a
        SHA-256 mismatch, and every malformed entry (:func:`resolve`).
    """
    maps = check_maps(maps, trust)
    if isinstance(entry, str):
        if not trust:
            raise ValueError(
                f"{what} is serialised CasADi code (how files stored maps before named maps), "
                "not a map reference {'map': name, 'args': {...}}: reading it could run code. "
                "Load it with trust=True only if you trust the file's source, then save it "
                "again to store references")
        return _deserialize(entry, what)
    if isinstance(entry, dict) and "user" in entry:
        return _user_map(entry, what, maps, trust)
    return resolve(entry, what)


def _user_map(entry: dict, what: str, maps: dict, trust: bool) -> casadi.Function:
    extra = sorted(set(entry) - _USER_KEYS)
    name, digest = entry.get("map"), entry.get("sha256")
    if extra or entry.get("user") is not True or not isinstance(name, str) \
            or not isinstance(digest, str) or len(digest) != 64:
        raise ValueError(f"{what} is not a valid user map entry {{'map': name, 'user': true, "
                         f"'sha256': 64 hex digits, 'serialized': text}}; got "
                         f"{_short({k: v for k, v in entry.items() if k != 'serialized'})}")
    if name in maps:
        got = sha256(maps[name])
        if got != digest:
            raise ValueError(f"{what}: maps[{name!r}] is not the Function the file was saved "
                             f"with (SHA-256 of its serialisation {got[:12]}..., the file "
                             f"records {digest[:12]}...)")
        return maps[name]
    if trust:
        text = entry.get("serialized")
        if not isinstance(text, str):
            raise ValueError(f"{what}: the user map {name!r} has no 'serialized' text to "
                             "deserialise; pass it again with maps=")
        if hashlib.sha256(text.encode()).hexdigest() != digest:
            raise ValueError(f"{what}: the user map {name!r}'s serialised text does not match "
                             "its recorded SHA-256 (the file was altered)")
        return _deserialize(text, what)
    given = f" (maps= has {', '.join(map(repr, maps))})" if maps else ""
    raise ValueError(
        f"{what} is the user map {name!r}, a CasADi Function that is not a named map of "
        f"aeid_struct.maps{given}. A model file holds data, never code: pass the Function "
        f"again, maps={{{name!r}: f}} (its SHA-256 is checked), or, only if you trust the "
        "file, trust=True, which deserialises the code the file holds")
