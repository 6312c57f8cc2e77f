"""What is known about the robot leg, as structures: from a free CCF to physical parameters.

The paper claims that the structured decoder lets one identify partly known systems, and never
shows it. This module lines up, for each leg record set (the stable subsystem, the unstable one,
and both jointly), identifiers that know progressively more, all trained the same way:

==========================  ======================================================  ==========
name                        structure (elements the encoder outputs)                 knows
==========================  ======================================================  ==========
stable / CCF                ``CCF(2, descartes=True)``: a0, a1, c0, c1               --
stable / CCF c1=0           ``.fixed(c1=0)``: a0, a1, c0                             numerator
stable / physical           ``Physical(stable_map)``: k, d, m in their ranges        the model
stable / CCF m known        ``.fixed(c1=0, c0=1/m)``: a0, a1                         + m
stable / physical m known   ``Physical(stable_map).fixed(m=m)``: k, d                + m
unstable / CCF              ``CCF(2)``: a0, a1, c0, c1                               --
unstable / CCF a1=0         ``.fixed(a1=0)``: a0, c0, c1                             no damping
unstable / CCF a1=0 c1=0    ``.fixed(a1=0, c1=0)``: a0, c0                           + numerator
unstable / physical         ``Physical(unstable_map).fixed(d=3.5)``: k, m            the model
unstable / physical m known ``Physical(unstable_map).fixed(d=3.5, m=m)``: k          + m
joint / physical            ``Physical(joint_map)``: k, d, m from both records       the model
joint / physical m known    ``Physical(joint_map).fixed(m=m)``: k, d                 + m
==========================  ======================================================  ==========

"m known" identifiers are trained and evaluated on legs of that mass (``KNOWN_MASS``, the paper's
scenario); the others on the paper's ranges. ``d`` does not enter the rotational subsystem
``G2``, so its physical identifiers hold it at the middle of its range (any value would do: the
record cannot tell). Physical parameters of canonical estimates come from the CasADi inverses of
``symbolic.leg`` (:attr:`Variant.inverse`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from pathlib import Path

from aeid_struct.structures import CCF, Physical, Structure
from aeid_struct.training import LegFamily

#: The known mass of the "m known" variants, kg (the paper's scenario).
KNOWN_MASS = 1.01
#: Where the rotational subsystem's physical identifiers hold d (it does not enter G2), kg/s.
D_UNUSED = 3.5
#: Training noise of the noise-trained variants (std relative to max|y|, drawn per record).
NOISE = (0.0, 0.06)


@dataclass(frozen=True)
class Variant:
    """One identifier of the comparison: what it is trained on and what it outputs.

    Attributes
    ----------
    name : str
        ``"<subsystem> / <structure>"``, e.g. ``"unstable / CCF a1=0"``.
    subsystem : str
        ``"stable"``, ``"unstable"`` or ``"joint"``.
    structure : Structure
        The structure the encoder outputs.
    family : training.LegFamily
        The legs it is trained and evaluated on.
    known : str
        What the structure takes as known, in words.
    inverse : casadi.Function or None
        CasADi map from a CCF estimate to physical parameters (None for physical structures,
        whose elements are the parameters).
    """

    name: str
    subsystem: str
    structure: Structure
    family: LegFamily
    known: str
    inverse: object = None

    @property
    def slug(self) -> str:
        """A file-name form of ``name``."""
        return re.sub(r"[^a-z0-9]+", "-", self.name.lower()).strip("-")


def variants(l0: float = 0.8, g: float = 9.81) -> dict[str, Variant]:
    """All the comparison's identifiers (the module docstring's table).

    Parameters
    ----------
    l0 : float
        The leg's rest length [m].
    g : float
        Gravity [m/s^2].

    Returns
    -------
    dict of str to Variant
        By name.
    """
    ranges = {"k": (20.0, 25.0), "d": (2.0, 5.0), "m": (0.5, 1.5)}
    m = KNOWN_MASS
    out: list[Variant] = []
    for sub in ("stable", "unstable", "joint"):
        fam = LegFamily(subsystem=sub, ranges=ranges, l0=l0, g=g)
        fam_m = LegFamily(subsystem=sub, ranges={**ranges, "m": (m, m)}, l0=l0, g=g)
        inv = fam.inverse()
        phys = Physical(fam.map(), bounds=ranges, inverse=inv)
        if sub == "stable":
            ccf = CCF(2, descartes=True)
            out += [
                Variant("stable / CCF", sub, ccf, fam, "-", inv),
                Variant("stable / CCF c1=0", sub, ccf.fixed(c1=0.0), fam, "numerator", inv),
                Variant("stable / physical", sub, phys, fam, "the model"),
                Variant("stable / CCF m known", sub, ccf.fixed(c1=0.0, c0=1.0 / m), fam_m,
                        "numerator, m", inv),
                Variant("stable / physical m known", sub, phys.fixed(m=m), fam_m,
                        "the model, m"),
            ]
        elif sub == "unstable":
            ccf = CCF(2)
            phys = phys.fixed(d=D_UNUSED)
            out += [
                Variant("unstable / CCF", sub, ccf, fam, "-", inv),
                Variant("unstable / CCF a1=0", sub, ccf.fixed(a1=0.0), fam, "no damping", inv),
                Variant("unstable / CCF a1=0 c1=0", sub, ccf.fixed(a1=0.0, c1=0.0), fam,
                        "no damping, numerator", inv),
                Variant("unstable / physical", sub, phys, fam, "the model"),
                Variant("unstable / physical m known", sub, phys.fixed(m=m), fam_m,
                        "the model, m"),
            ]
        else:
            out += [
                Variant("joint / physical", sub, phys, fam, "the model, both records"),
                Variant("joint / physical m known", sub, phys.fixed(m=m), fam_m,
                        "the model, both records, m"),
            ]
    return {v.name: v for v in out}


def train_variant(variant: Variant, *, noisy: bool, count: int, epochs: int, seed: int = 0,
                  cache=None, progress: bool = False):
    """Train (or load from ``cache``) the identifier of ``variant`` with the leg study's
    settings (``leg_paper.training_config``, ``leg_paper.leg_encoder``) and an epoch budget.

    Parameters
    ----------
    variant : Variant
        From :func:`variants`.
    noisy : bool
        Train with measurement noise drawn per record from ``NOISE``.
    count, epochs, seed : int
        The training budget and seed (the same for every variant).
    cache : str or Path, optional
        A directory; an identifier trained with these settings is saved there and loaded
        instead of retrained next time (the file name holds every setting).
    progress : bool
        Print training progress.

    Returns
    -------
    Identifier

    Raises
    ------
    ValueError
        ``variant`` is not a :class:`Variant`.
    """
    from aeid_struct.identification import Identifier
    from aeid_struct.studies.leg_paper import leg_encoder, training_config
    from aeid_struct.training import train

    if not isinstance(variant, Variant):
        raise ValueError(f"variant must be a Variant (knowledge.variants()); "
                         f"got {type(variant).__name__}")
    path = None
    if cache is not None:
        tag = "noisy" if noisy else "clean"
        path = Path(cache) / f"{variant.slug}-{tag}-{count}x{epochs}-s{seed}.aeid"
        if path.is_file():
            return Identifier.load(path)
    config = training_config(variant.subsystem, seconds=None, seed=seed, count=count,
                             noise=NOISE if noisy else 0.0, progress=progress, epochs=epochs)
    # head=None: the paper's study compares the encoders alone (a physical structure's
    # identifier otherwise carries train()'s head)
    ident = train(variant.structure, variant.family, config,
                  encoder=leg_encoder(variant.subsystem), inverse=variant.inverse,
                  meta={"name": variant.name, "noisy": noisy, "seed": seed}, head=None)
    if path is not None:
        ident.save(path)
    return ident


def validation(count: int, *, noise: float = 0.0, known_mass: bool = False,
               seed: int = 12345):
    """Fresh legs for the comparison, each with both records.

    Single-subsystem identifiers are scored on ``.record(0)`` / ``.record(1)`` of the same set,
    so every variant sees the same legs.

    Parameters
    ----------
    count : int
        Legs.
    noise : float
        Measurement noise of their records.
    known_mass : bool
        Legs of mass ``KNOWN_MASS`` (else the paper's mass range).
    seed : int
        Their seed.

    Returns
    -------
    training.Records
        ``training.records`` of the joint family on the study's grids (``leg_paper.RECORDS``).
    """
    from aeid_struct.studies.leg_paper import RECORDS
    from aeid_struct.training import records

    ranges = {"k": (20.0, 25.0), "d": (2.0, 5.0), "m": (0.5, 1.5)}
    if known_mass:
        ranges["m"] = (KNOWN_MASS, KNOWN_MASS)
    family = LegFamily(subsystem="joint", ranges=ranges)
    return records(family, count, steps=tuple(RECORDS[s][1] for s in RECORDS),
                   dt=tuple(RECORDS[s][0] for s in RECORDS), noise=noise, seed=seed)


def evaluate(variant: Variant, ident, val, *, label: str = "") -> list:
    """Scorecards of ``ident`` on a :func:`validation` set.

    Parameters
    ----------
    variant : Variant
        What ``ident`` was trained for.
    ident : Identifier or baselines.Classical
        Its identifier, or its :func:`least_squares` counterpart.
    val : training.Records
        A :func:`validation` set.
    label : str
        Prefixes the scores' names.

    Returns
    -------
    list of evaluation.Score
        One for a single-subsystem identifier (on its record), one per record for a joint one
        (each with the same k, d, m errors: one parameter set is identified from both records).
    """
    from aeid_struct.evaluation import score

    name = f"{label}, {variant.name}" if label else variant.name
    if variant.subsystem == "joint":
        return [score(ident, val, name=f"{name} ({sub} record)", record=r)
                for r, sub in enumerate(("stable", "unstable"))]
    if variant.subsystem == "stable":
        return [score(ident, val.record(0), name=name)]
    # d does not enter G2: what an unstable identifier says of d is no estimate, not scored
    s = score(ident, val.record(1), name=name)
    return [replace(s, per_record={k: v for k, v in s.per_record.items() if k != "d"})]


def least_squares(variant: Variant):
    """The classical counterpart of a single-subsystem ``variant``, to score side by side.

    Parameters
    ----------
    variant : Variant
        A variant of one subsystem.

    Returns
    -------
    baselines.Classical
        Output-error least squares (``baselines.least_squares``, from its generic start) in
        the same structure, record by record behind an identifier's interface.

    Raises
    ------
    ValueError
        A joint variant (least squares fits one record).
    """
    from functools import partial

    from aeid_struct import baselines
    from aeid_struct.studies.leg_paper import RECORDS

    if variant.subsystem not in RECORDS:
        raise ValueError(f"variant must identify one subsystem (least squares fits one record); "
                         f"got {variant.name!r}")
    dt, steps = RECORDS[variant.subsystem]
    method = partial(baselines.least_squares, structure=variant.structure,
                     inverse=variant.inverse)
    return baselines.Classical(method, dt, steps)
