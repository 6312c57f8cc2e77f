r"""The separable head of the one pass: after the encoder, a fixed number of Gauss-Newton
iterations in the identifier's structure (docs/architecture.md, "One pass at the optimum").

The encoder (paper Sec. III-A) gives the whole model; the head keeps only its poles as the start,
projects out everything that enters the output linearly (``c``, the initial state of a
mid-motion record: exact least squares) and moves the free denominator elements by
``iterations`` Levenberg-Marquardt steps on the projected cost (``refinement.fit_rows``).
With ``iterations = 0`` it is the projection alone. Elements that ``fixed`` names are held at
their values on top of the structure's own fixed elements: the robot leg's physics, ``c1 = 0``
(translational) or ``a1 = c1 = 0`` (rotational), for an encoder trained in the free CCF.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from aeid_struct.records import RecordError
from aeid_struct.refinement import MAX_ITERATIONS, Pattern, fit_rows
from aeid_struct.structures import type_of

__all__ = ["Head", "HeadSlot", "apply_head", "checked_head", "head_failure", "pattern_of",
           "refine_route"]

@dataclass(frozen=True)
class Head:
    """What the one pass does after the encoder.

    Attributes
    ----------
    iterations : int, 0 <= iterations <= 50
        Levenberg-Marquardt iterations on the projected cost (0: projection only).
    fixed : dict str -> float
        Elements held at a value on top of the structure's fixed elements (``{"c1": 0.0}``).
    tol : float, optional
        Iterate each record until a step lowers its cost by less than this fraction (at most
        ``iterations``): the refinement (:meth:`converged`), not the fixed-cost pass.
    """

    iterations: int = 3
    fixed: dict = field(default_factory=dict)
    tol: float | None = None

    def __post_init__(self):
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or not (
                0 <= self.iterations <= MAX_ITERATIONS):
            raise ValueError(f"head: iterations must be an integer in [0, {MAX_ITERATIONS}]; "
                             f"got {self.iterations!r}")
        def finite(v) -> bool:
            try:
                return math.isfinite(float(v))
            except OverflowError:            # an int beyond float64 (10**400)
                return False

        if not isinstance(self.fixed, dict):
            raise ValueError(f"head: fixed must be a dict element name -> finite number; got "
                             f"{type(self.fixed).__name__}")
        for k, v in self.fixed.items():
            if not (isinstance(k, str) and isinstance(v, (int, float))
                    and not isinstance(v, bool) and finite(v)):
                shown = (f"an integer of {len(str(abs(v)))} digits" if isinstance(v, int)
                         and not isinstance(v, bool) else repr(v)[:60])
                raise ValueError(f"head: fixed must be a dict element name -> finite number "
                                 f"(float64); got {k!r}: {shown}")
        object.__setattr__(self, "fixed", {k: float(v) for k, v in self.fixed.items()})
        if self.tol is not None and not (isinstance(self.tol, float) and 0 < self.tol < 1):
            raise ValueError(f"head: tol must be None or a float in (0, 1); got {self.tol!r}")

    def converged(self) -> Head:
        """The same head iterated to convergence (the refinement of ``identify(refine=True)``):
        up to 50 iterations, stopping per record below a relative decrease of 1e-12.

        Returns
        -------
        Head
        """
        return Head(iterations=MAX_ITERATIONS, fixed=self.fixed, tol=1e-12)

    def to_dict(self) -> dict:
        """The file entry.

        Returns
        -------
        dict
            ``{"iterations": int, "fixed": {name: value}}``.

        Raises
        ------
        ValueError
            For a converged head (``tol`` set): a refinement, not a part of a file.
        """
        if self.tol is not None:
            raise ValueError("head: a converged head (tol set) is a refinement, not stored")
        return {"iterations": self.iterations, "fixed": dict(self.fixed)}

    @classmethod
    def from_dict(cls, entry) -> Head:
        """The head of a file entry (ValueError naming what is wrong).

        Parameters
        ----------
        entry : dict
            ``{"iterations": int, "fixed": {name: value}}``.

        Returns
        -------
        Head

        Raises
        ------
        ValueError
            For anything else.
        """
        if not isinstance(entry, dict) or set(entry) - {"iterations", "fixed"}:
            raise ValueError(f"head must be a dict with entries 'iterations' and 'fixed'; got "
                             f"{entry!r}")
        return cls(iterations=entry.get("iterations", 3), fixed=entry.get("fixed", {}))


def checked_head(ident, head) -> Head | None:
    """``head`` if ``ident`` can carry it (a ValueError naming ``head`` if not), or None.

    Parameters
    ----------
    ident : Identifier
    head : Head or None

    Returns
    -------
    Head or None
    """
    if head is None:
        return None
    if not isinstance(head, Head):
        raise ValueError(f"head must be an identification.Head or None; got {head!r}")
    pattern_of(ident, head)            # refuses a structure the head does not serve
    return head


class HeadSlot:
    """An identifier's ``head`` attribute, checked (:func:`checked_head`) whenever it is set,
    in the constructor or later (``ident.head = Head(...)``), so that a head the identifier
    cannot carry is refused where it is given, not at the next ``identify``."""

    def __set_name__(self, owner, name: str) -> None:
        self.key = f"_{name}"

    def __get__(self, obj, owner=None):
        return self if obj is None else obj.__dict__.get(self.key)

    def __set__(self, obj, value) -> None:
        obj.__dict__[self.key] = checked_head(obj, value)


def pattern_of(ident, head: Head) -> Pattern:
    """The free and fixed elements the head of ``ident`` iterates.

    Parameters
    ----------
    ident : Identifier
    head : Head

    Returns
    -------
    Pattern

    Raises
    ------
    ValueError
        For an identifier the head does not serve: not a (partly fixed) CCF or a physical
        structure, a CCF of several records, or a ``fixed`` name the structure does not have.
    """
    structure = ident.structure
    if type_of(structure) == "Physical":
        if head.fixed:
            raise ValueError(f"head: fixed names {sorted(head.fixed)}, but a physical "
                             f"structure's head holds its map's constant coefficients itself")
        from aeid_struct.identification.physical_head import physical_head

        return physical_head(structure, ident.initial == "fitted").pattern
    if type_of(structure) != "CCF" or ident.records != 1:
        raise ValueError(f"head: the separable head needs a single-record identifier in a "
                         f"(partly fixed) CCF; this one has {structure!r} over "
                         f"{ident.records} record(s)")
    names = structure.element_names
    unknown = sorted(set(head.fixed) - set(names))
    if unknown:
        raise ValueError(f"head: fixed names {unknown} that are not elements of {structure!r} "
                         f"(its elements: {', '.join(names)})")
    fixed = {**structure.config()["fixed"], **head.fixed}
    return Pattern.of(names, fixed, structure.n, initial=ident.initial == "fitted",
                      feedthrough=structure.feedthrough)


#: pattern_of's answers by (structure object, initial mode, fixed elements): a window of a
#: stream costs a fraction of a millisecond, and the pattern is the same for every one.
_PATTERNS: dict = {}


def _pattern(ident, head: Head) -> Pattern:
    """:func:`pattern_of`, remembered per structure object (compared by identity)."""
    key = (id(ident.structure), ident.initial, tuple(sorted(head.fixed.items())))
    hit = _PATTERNS.get(key)
    if hit is None or hit[0] is not ident.structure:
        if len(_PATTERNS) > 256:
            _PATTERNS.clear()
        hit = _PATTERNS[key] = (ident.structure, pattern_of(ident, head))
    return hit[1]


def refine_route(ident) -> str:
    """How ``refine=True`` reaches the least-squares optimum of an identifier with a head.

    - ``"head"``: the head iterated to convergence is the optimum in the identifier's
      structure: always for a CCF; for a physical structure of one record whose free CCF
      coefficients are as many as its parameters (``physical_head``'s square map).
    - ``"converged head"``: the output-error fit in the parameters
      (``joint_refine.refine_joint``) from the head iterated to convergence, for a physical
      structure of one record whose map is not square (more free coefficients than
      parameters: a quarter car, a chain of three masses), where the head's result is the
      parameters nearest the fitted CCF. Why not from the one pass: the separable fit of the
      CCF (the poles iterated, the numerator projected out) reaches the channel's optimum from
      much farther than the fit in the parameters does: started from a one pass whose few
      iterations had not converged, the fit in the parameters of a lightly damped
      sixth-order chain stops in other basins where from the converged CCF's nearest
      parameters it does not (``tests/test_joint_refine.py`` compares the two starts).
    - ``"one pass"``: the same fit from the one pass, for several records sharing the
      parameters (their optimum is the joint fit, not the parameters nearest each record's
      own; the one pass already ran that fit's first iterations).

    Parameters
    ----------
    ident : Identifier

    Returns
    -------
    str
    """
    if type_of(ident.structure) != "Physical":
        return "head"
    if ident.structure.records != 1:
        return "one pass"
    from aeid_struct.identification.physical_head import physical_head

    square = physical_head(ident.structure, ident.initial == "fitted").square
    return "head" if square else "converged head"


def head_failure(record: int, head: Head) -> RecordError:
    """The error of a record the head found no finite model for (:func:`apply_head`'s NaN
    rows), naming the head's fixed elements.

    Parameters
    ----------
    record : int
        The record's index in its batch.
    head : Head

    Returns
    -------
    RecordError
    """
    return RecordError(f"head: the separable head found no finite model for record {record} "
                       f"with the elements it holds fixed ({head.fixed or 'none'} besides the "
                       f"structure's); identify with ident.head = None for the encoder's pass",
                       record)


def apply_head(ident, head: Head, ys: list, us: list, model: tuple) -> tuple:
    """The head's model of good records from the encoder's ``model`` (float64, measured
    units), rows whose encoder model is not finite left as they are.

    Parameters
    ----------
    ident : Identifier
    head : Head
    ys, us : lists of one (count, steps) float64 array (``us[0]`` None: a unit step)
    model : tuple
        ``A (count, n, n), b (count, n), c (count, n), d (count,), elements (count, q)``.

    Returns
    -------
    model : tuple
        The same arrays, the head's rows in place of the encoder's; NaN rows where the head
        finds no finite model.
    failed : (count,) bool array
        Those rows (:func:`head_failure` says why to the caller's user).
    """
    if type_of(ident.structure) == "Physical":
        from aeid_struct.identification.physical_head import apply_physical_head

        return apply_physical_head(ident, head, ys, us, model)
    pattern = _pattern(ident, head)
    A, b, c, d, el = (np.array(part, dtype=np.float64) for part in model)
    y = ys[0]
    u = np.ones_like(y) if us[0] is None else np.broadcast_to(us[0], y.shape)
    a = -A[:, -1, :]
    # rows whose encoder model overflowed (a record of 1e308) are left to the caller's overflow
    # rule: the head would fail on them for the record's scale, not for its fixed elements
    rows = np.flatnonzero(np.isfinite(a).all(axis=1) & np.isfinite(c).all(axis=1)
                          & np.isfinite(d))
    failed = np.zeros(A.shape[0], dtype=bool)
    if rows.size == 0:
        return (A, b, c, d, el), failed
    fa, fc, fd, ok = fit_rows(pattern, a[rows][:, pattern.free_a], y[rows], u[rows], ident.dt,
                              iterations=head.iterations, tol=head.tol)
    # a record the head cannot fit (a fixed value no finite model takes) gets no model: the
    # encoder's, returned in its place, would pass for the head's (NaN rows are reported by
    # the caller)
    bad = rows[~ok]
    failed[bad] = True
    A[bad], c[bad], d[bad], el[bad] = math.nan, math.nan, math.nan, math.nan
    done, n = rows[ok], pattern.n
    A[done, -1, :] = -fa[ok]
    c[done], d[done] = fc[ok], fd[ok]
    values = {**{f"a{j}": fa[ok, j] for j in range(n)},
              **{f"c{j}": fc[ok, j] for j in range(n)}, "d": fd[ok]}
    for i, name in enumerate(ident.structure.element_names):
        el[done, i] = values[name]
    return (A, b, c, d, el), failed
