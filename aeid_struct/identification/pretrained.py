"""The identifiers shipped in the package (``aeid_struct/pretrained/*.aeid``).

The folder holds two kinds of file in the one container (``identification.container``, format
``aeid-struct/3``): the leg identifiers read here (kind ``"identifier"``, one system family, one
sample time, one record length), and the generic identifiers ``generic-1`` .. ``generic-4``
(kind ``"generic"``, any SISO system, any sample time and record length), read by
``aeid_struct.generic.load_generic`` and used by ``aeid_struct.identify(record, order=n)``;
``aeid_struct.load`` reads either. A shipped file's name tells its kind too: the generic ones are
named ``generic-<order>``.
"""

from __future__ import annotations

from importlib.resources import files

from aeid_struct.identification.identifier import Identifier

__all__ = ["PRETRAINED", "load_pretrained"]

#: The shipped leg identifiers' names.
PRETRAINED = ("leg-stable", "leg-unstable", "leg-stable-ccf", "leg-unstable-ccf",
              "leg-stable-noisy", "leg-unstable-noisy", "leg-stable-window", "leg-stable-any",
              "leg-unstable-any", "drive-train", "cart-pole")
#: How the shipped generic identifiers' names begin (``generic-1`` .. ``generic-4``).
_GENERIC_PREFIX = "generic-"


def _shipped() -> dict[str, list[str]]:
    """The ``.aeid`` files of ``aeid_struct/pretrained``, by kind.

    Returns
    -------
    dict
        ``{"leg": [...], "generic": [...]}``: the names (without ``.aeid``), sorted; ``"leg"``
        are those :func:`load_pretrained` reads, ``"generic"`` those
        ``aeid_struct.generic.load_generic`` reads (an installation may ship none of them).
    """
    names = sorted(p.name[: -len(".aeid")] for p in files("aeid_struct.pretrained").iterdir()
                   if p.name.endswith(".aeid"))
    return {"leg": [n for n in names if not n.startswith(_GENERIC_PREFIX)],
            "generic": [n for n in names if n.startswith(_GENERIC_PREFIX)]}


def load_pretrained(name: str) -> Identifier:
    """A structured identifier shipped in the package: the robot leg's, or a mechanism's.

    ``"leg-stable"`` and ``"leg-unstable"`` (step responses from rest) in the leg's physics
    structure: the translational leg's numerator has no s-term (``c1 = 0``), the rotational leg
    has neither damping nor an s-term (``a1 = c1 = 0``); ``"leg-stable-ccf"`` and
    ``"leg-unstable-ccf"``, the same in the paper's free CCF (its Table I comparison); the
    noise-trained free-CCF variants ``"leg-stable-noisy"``, ``"leg-unstable-noisy"``;
    ``"leg-stable-window"`` reads the input too and identifies windows of a running leg under a
    random binary force (records that start mid-motion; the tracker's identifier,
    ``aeid-struct track``); ``"leg-stable-any"`` (windows mid-motion) and ``"leg-unstable-any"``
    (records from rest) read any reasonably exciting input: steps of random height and timing,
    binary sequences, multisines, filtered noise. These three carry a separable head
    (``Identifier.head``: three Gauss-Newton iterations in the physics structure after the
    encoder; accuracy in ``pretrained/README.md``).

    ``"drive-train"`` and ``"cart-pole"`` are mechanisms written as Lagrangians
    (``symbolic.mechanisms``), identified from both outputs of one record
    (``Physical(..., channels=...)``): the drive train's motor and load angles from the motor
    torque (windows mid-motion; ``J1, J2, k, c, b``) and the cart-pole's cart position and pole
    angle from the force, upright (records from rest; ``M, m, l, b``); each carries a
    five-iteration head, and ``identify(ae.Record(y (N, 2), u, dt))`` splits the record by
    channel. Recipe: ``aeid_struct.studies.mechanism_models``.

    The generic identifiers shipped beside them (``generic-1`` .. ``generic-4``) are another
    kind of file: ``aeid_struct.identify(record, order=n)`` uses them, and
    ``aeid_struct.generic.load_generic(name)`` loads one.

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
        For a name that is not a shipped leg identifier; for a generic identifier's name, one
        that says where to load it.
    """
    kinds = _shipped()
    if isinstance(name, str) and name.startswith(_GENERIC_PREFIX):
        order = name[len(_GENERIC_PREFIX):]
        call = (f"aeid_struct.identify(record, order={order})" if order.isdigit()
                else "aeid_struct.identify(record, order=n)")
        raise ValueError(f"name {name!r} is a generic identifier (any system, any sample time), "
                         f"not a structured identifier (a leg's or a mechanism's): use {call}, or "
                         f"aeid_struct.generic.load_generic({name!r}) to load it "
                         f"(shipped generic identifiers: {kinds['generic']}); load_pretrained "
                         f"reads the structured identifiers {kinds['leg']}")
    if name not in kinds["leg"]:
        raise ValueError(f"name must be one of {kinds['leg']}; got {name!r}")
    return Identifier.load(files("aeid_struct.pretrained") / f"{name}.aeid")
