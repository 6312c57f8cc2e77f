"""The methods of the one-pass study (``studies.onepass_bench``): what each of (a)-(f)
calls on a record, and the legs it is scored on.

(a) the encoder alone (:func:`encoder_alone`, the paper's architecture, Sec. III-A), (b) the one
pass and (c) its refinement to the least-squares optimum (:func:`with_head`: the identifier's own
separable head, or :data:`HEAD_ITERATIONS` Levenberg-Marquardt iterations in the physics
structure, :data:`PHYSICS`), and the cold classical fits (d)-(f) (:func:`baseline_calls`); the
legs are those of the identifier's training range (:func:`leg_family`).

The seam: this module says which methods are compared; ``studies.onepass_row`` scores and times
them on one set of records, and ``studies.onepass_bench`` runs the study over identifiers, input
kinds and noise levels.
"""

from __future__ import annotations

import copy

__all__ = ["BASELINES", "HEAD_ITERATIONS", "METHODS", "ORDER", "PHYSICS", "baseline_calls",
           "encoder_alone", "leg_family", "with_head"]

#: The physics structure per subsystem: the elements that are zero in the true transfer function.
PHYSICS = {"stable": {"c1": 0.0}, "unstable": {"a1": 0.0, "c1": 0.0}}
#: Iterations of the head given to an identifier file that has none.
HEAD_ITERATIONS = 3
#: The methods in table order; the last three are the cold classical baselines.
METHODS = ("encoder", "one pass", "encoder + refine", "least squares (cold)", "CasADi (cold)",
           "n4sid")
BASELINES = METHODS[3:]
#: Order of every leg subsystem.
ORDER = 2


def with_head(ident, subsystem: str):
    """``ident`` with its own head, or a copy with the default head when its file has none.

    Parameters
    ----------
    ident : Identifier
    subsystem : {"stable", "unstable"}
        Picks the physics structure (:data:`PHYSICS`).

    Returns
    -------
    Identifier
        ``ident`` itself when ``ident.head`` is set; else a shallow copy (same encoder) with
        ``Head(iterations=HEAD_ITERATIONS, fixed=PHYSICS[subsystem])``.
    """
    from aeid_struct.identification import Head

    if ident.head is not None:
        return ident
    headed = copy.copy(ident)
    headed.head = Head(iterations=HEAD_ITERATIONS, fixed=PHYSICS[subsystem])
    return headed


def encoder_alone(ident):
    """A shallow copy of ``ident`` (same encoder) without a head: the paper's architecture.

    Parameters
    ----------
    ident : Identifier

    Returns
    -------
    Identifier
    """
    alone = copy.copy(ident)
    alone.head = None
    return alone


def leg_family(ident, subsystem: str):
    """The legs of ``ident``'s training range (its file's ``training_range``), the paper's
    ranges for a parameter the file does not name.

    Parameters
    ----------
    ident : Identifier
    subsystem : {"stable", "unstable"}

    Returns
    -------
    training.LegFamily
    """
    from aeid_struct.training import LegFamily

    ranges = dict(LegFamily(subsystem=subsystem).ranges)
    trained = ident.meta.get("training_range", {}).get("physical", {})
    ranges |= {p: (float(v[0]), float(v[1])) for p, v in trained.items() if p in ranges}
    return LegFamily(subsystem=subsystem, ranges=ranges)


def baseline_calls(ident, subsystem: str) -> dict:
    """The cold classical fits (d)-(f) of one record in ``ident``'s record format
    (``studies.onepass_bench``).

    Parameters
    ----------
    ident : Identifier
    subsystem : {"stable", "unstable"}

    Returns
    -------
    dict
        :data:`BASELINES` name -> ``call(y, u)`` with ``y, u (steps,)``, returning the
        baseline's ``Estimate``.
    """
    from aeid_struct import baselines, refinement
    from aeid_struct.records import Record

    dt = ident.dt
    physics = ident.structure.fixed(**PHYSICS[subsystem])
    if ident.initial == "rest":
        kw = dict(structure=physics, inverse=ident.inverse)
        return {
            "least squares (cold)": lambda y, u: baselines.least_squares(y, u, dt, **kw),
            "CasADi (cold)": lambda y, u: baselines.casadi_cold(y, u, dt, **kw),
            "n4sid": lambda y, u: baselines.n4sid(y, u, dt, order=ORDER),
        }

    def casadi(y, u):
        start = baselines.generic_start(physics, y, u, dt)
        return refinement.refine_record(physics, start, y, u, dt, offset=False)

    return {
        "least squares (cold)": lambda y, u: baselines.least_squares(
            Record(y, u, dt, delay=0), order=ORDER),
        "CasADi (cold)": casadi,
        "n4sid": lambda y, u: baselines.n4sid(Record(y, u, dt, delay=0), order=ORDER),
    }
