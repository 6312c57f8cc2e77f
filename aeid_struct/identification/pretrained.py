"""The identifiers shipped in the package (``aeid_struct/pretrained/*.aeid``)."""

from __future__ import annotations

from importlib.resources import files

from aeid_struct.identification.identifier import Identifier

__all__ = ["PRETRAINED", "load_pretrained"]

#: The shipped identifiers' names.
PRETRAINED = ("leg-stable", "leg-unstable", "leg-stable-noisy", "leg-unstable-noisy",
              "leg-stable-window", "leg-stable-any", "leg-unstable-any")


def load_pretrained(name: str) -> Identifier:
    """An identifier shipped in the package.

    ``"leg-stable"``, ``"leg-unstable"``, and their noise-trained variants
    ``"leg-stable-noisy"``, ``"leg-unstable-noisy"`` for measured (noisy) records;
    ``"leg-stable-window"`` reads the input too and identifies windows of a running leg under a
    random binary force (records that start mid-motion; the tracker's identifier,
    ``aeid-struct track``); ``"leg-stable-any"`` (windows mid-motion) and ``"leg-unstable-any"``
    (records from rest) read any reasonably exciting input: steps of random height and timing,
    binary sequences, multisines, filtered noise (their encoder alone is a start for
    ``refine=True``; accuracy in ``pretrained/README.md``).

    Parameters
    ----------
    name : str
        One of ``PRETRAINED``.

    Returns
    -------
    Identifier

    Raises
    ------
    ValueError
        For a name that is not shipped.
    """
    root = files("aeid_struct.pretrained")
    available = sorted(p.name[: -len(".aeid")] for p in root.iterdir()
                       if p.name.endswith(".aeid"))
    if name not in available:
        raise ValueError(f"name must be one of {available}; got {name!r}")
    return Identifier.load(root / f"{name}.aeid")
