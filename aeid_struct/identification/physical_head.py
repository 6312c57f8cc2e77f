r"""The separable head of a physical structure (``Physical``, e.g. a mechanism's channel): the
one pass's few Gauss-Newton iterations, then back to the parameters.

The physical map ``p -> (A, B, C, D)`` reaches a set of transfer functions; in the CCF of
paper Eq. 5 some of their coefficients are the same for every ``p`` (a mass-spring-damper's
``c_1 = 0``, the upright leg's ``a_1 = 0``). The head therefore runs in two steps:

1. the separable Levenberg-Marquardt of the partly fixed CCF (``refinement.fit_rows``: the
   poles from the encoder's model, the numerator, ``x0`` and the offset projected out), with
   the structurally constant coefficients held at their values;
2. the parameters whose coefficients are closest to the fitted ones within the bounds:
   least squares on ``S (k(p) - k_fit)`` from the encoder's parameters, with CasADi's
   Jacobian of the coefficient map ``k(p)`` (Gauss-Newton with step halving,
   ``identification.inverse``; where a square map's inverse stops short of ``k_fit``, a
   mechanism's map not being one-to-one over its box, again from fixed points of the box).
   ``S^T S`` is
   the information of the fitted coefficients (``J J^T`` of each record's residual in its
   coefficients, :meth:`PhysicalHead.information`) where the map is not square, so the
   distance is the Gauss-Newton model of the output error itself; a square map reaches
   ``k_fit`` whatever the weights, and ``S`` is the relative ``diag(1 / |k_fit|)``.

Where the free coefficients are as many as the parameters (the map is square: a lever-driven
mass, the leg's subsystems, a two-mass system), step 2 solves ``k(p) = k_fit`` and the head's
result is the output-error optimum of the structure itself, unless ``k_fit`` lies beyond the box
(a system near its edge, at noise): the nearest parameters then sit on a bound and are not the
structure's optimum, and the head runs as many iterations of the output-error fit in the
parameters within the box (``refinement.fit_joint``) as step 1 had.

A structure of several records (the channels of one record, the joint leg) fits each record's
CCF alone in step 1, takes the parameters nearest all their coefficients in step 2, and then
runs as many iterations of the joint output-error fit in the parameters
(``refinement.fit_joint``, what ``refine=True`` converges) as step 1 had: each channel fits its
own poles, and the joint fit reads every record at once from the nearest parameters (relative
weights count a channel's poorly determined coefficient as much as a sharp one, and start the
joint fit far from its optimum: ``tests/test_joint_refine.py`` compares the two). Where one
record has more coefficients than parameters, the head's result is the nearest parameter set,
an approximation the refinement (``identify(refine=True)``) polishes in the parameters.

Where the records are the channels of one record whose inputs move at once
(``Physical(mechanism, outputs=..., inputs=...)``: each output the sum of its channels), no
channel can be fitted alone: step 1 fits every channel's CCF at once, their common denominator
iterated and the numerators projected out per output (``refinement.fit_summed``), then steps 2
and the joint fit (``groups`` of ``refinement.fit_joint``) as above."""

from __future__ import annotations

import math

import casadi
import numpy as np

from aeid_struct.identification.inverse import Inverse
from aeid_struct.refinement import Pattern, fit_rows
from aeid_struct.structures import Numeric, ccf_matrices, expanded

__all__ = ["PhysicalHead", "centred", "physical_head"]

#: Points of the box on which a coefficient must not move to count as structurally constant.
PROBES = 12


class PhysicalHead:
    """The head's view of a physical structure: its CCF pattern per record and the map
    ``p -> k(p)`` of the free coefficients of all its records (module docstring).

    Parameters
    ----------
    structure : Physical
        One record, or ``R`` (the channels of a record, the joint leg): each record's CCF
        is fitted alone (step 1), and the parameters are those nearest every record's
        coefficients together (step 2).
    initial : bool
        Whether the records start mid-motion (``x0`` projected out).
    """

    def __init__(self, structure, initial: bool) -> None:
        function, names = structure.function, structure.element_names
        n, q, R = structure.n, len(names), structure.records
        keys = [tuple("ABCD")] if R == 1 else [tuple(f"{k}{r}" for k in "ABCD")
                                               for r in range(1, R + 1)]
        p = casadi.MX.sym("p", q)
        out = function.call({k: p[i] for i, k in enumerate(function.name_in())})
        systems = [tuple(out[k] for k in key) for key in keys]
        # per record a (n), c (n), d: paper Eq. 5's coefficients, record after record
        coefficients = casadi.vertcat(*(casadi.vertcat(_ccf_coefficients(A, B, C), D)
                                        for A, B, C, D in systems))
        every = casadi.Function("k", [p], [coefficients])
        lo = np.array([structure.bounds[k][0] for k in names])
        hi = np.array([structure.bounds[k][1] for k in names])
        probes = np.random.default_rng(0).uniform(lo, hi, (PROBES, q))
        values = np.array(every.map(PROBES)(probes.T)).T          # (PROBES, R (2 n + 1))
        size = np.abs(values).max(axis=0)
        # a structural zero comes out of the CCF conversion as rounding (1e-9 beside 1e4)
        zero = size <= 1e-10 * np.abs(values).max()
        constant = zero | (np.ptp(values, axis=0) <= 1e-10 * (1.0 + size))
        level = np.where(zero, 0.0, values[0])

        def entry(i):
            return float(level[i]) if constant[i] else None

        width = 2 * n + 1
        self.patterns = tuple(Pattern(a=tuple(entry(r * width + j) for j in range(n)),
                                      c=tuple(entry(r * width + n + j) for j in range(n)),
                                      d=entry(r * width + 2 * n), initial=initial)
                              for r in range(R))
        self.pattern = self.patterns[0]
        self.free = np.flatnonzero(~constant)
        k_free = coefficients[self.free.tolist()]
        # dense outputs: the buffer writes nonzeros only, and numpy reads full matrices
        k_map = expanded(casadi.Function("k_free", [p], [
            casadi.densify(k_free), casadi.densify(casadi.jacobian(k_free, p))]))
        # per record: A, B, C, D and the CCF's a
        model = casadi.Function("model", [p], [
            casadi.densify(v) for r, system in enumerate(systems)
            for v in (*system, coefficients[r * width: r * width + n])])
        self.model = Numeric(expanded(model))
        self._model, self._mapped = model, {}
        self.lo, self.hi, self.n, self.q, self.records = lo, hi, n, q, R
        #: per record its output where the channels of one output sum (``Physical.groups``)
        self.groups = getattr(structure, "groups", None)
        self.square = self.free.size == q
        self._level = level
        #: step 2's inverse of the coefficient map; the probes' coefficients are targets it
        #: must reach where the map is square
        self.inverse = Inverse(k_map, lo, hi, square=self.square,
                               targets=values[:, self.free])

    def systems(self, p: np.ndarray) -> list[tuple]:
        """``(A (n, n), b (n,), c (n,), d, a (n,))`` of each record at the parameters ``p``.

        Parameters
        ----------
        p : (q,) array

        Returns
        -------
        list of R tuples
        """
        out = self.model(np.ascontiguousarray(p, dtype=np.float64))
        n = self.n
        return [(out[5 * r].reshape(n, n).T, out[5 * r + 1], out[5 * r + 2],
                 float(out[5 * r + 3][0]), out[5 * r + 4]) for r in range(self.records)]

    def at(self, points: np.ndarray) -> list[tuple]:
        """The systems of many parameter points in one evaluation: ``A (P, n, n), b (P, n),
        c (P, n), d (P,)`` of each record (``refinement.fit_joint``'s ``systems``).

        Why: a Jacobian by central differences needs ``2 q`` points, and one call of the
        map over all of them costs about what one point's call does.

        Parameters
        ----------
        points : (P, q) array

        Returns
        -------
        list of R tuples
        """
        points = np.ascontiguousarray(points, dtype=np.float64)
        P, n = points.shape[0], self.n
        numeric = self._mapped.get(P)
        if numeric is None:
            if len(self._mapped) > 16:
                self._mapped.clear()
            numeric = self._mapped[P] = Numeric(expanded(self._model.map(P)))
        # column-major blocks, one per point: (q, P) in, (rows, cols * P) out
        out = numeric(points.ravel())
        return [(out[5 * r].reshape(P, n, n).transpose(0, 2, 1), out[5 * r + 1].reshape(P, n),
                 out[5 * r + 2].reshape(P, n), out[5 * r + 3]) for r in range(self.records)]

    def information(self, target: np.ndarray, ys: list, us: list, dts: tuple,
                    initial: bool) -> np.ndarray | None:
        """``S`` with ``S^T S = F``, the information of each record's fitted coefficients:
        ``F_r = J_r J_r^T``, ``J_r`` the Jacobian of the record's residual (its CCF at
        ``target``, Eq. 10-13, weighted as ``refinement.joint_residual``) in its free
        coefficients, by forward differences; block-diagonal over the records.

        Why: ``||S (k(p) - target)||^2`` is the Gauss-Newton model of the records' summed
        cost about each record's own fit, so the parameters nearest in it start the joint fit
        near its optimum; relative weights count a channel's poorly determined coefficient
        (the pole angle's view of the cart's pole) as much as a sharp one.

        Parameters
        ----------
        target : (k,) array
            The fitted free coefficients, record after record.
        ys, us : lists of R (steps_r,) arrays
        dts : tuple of R floats
        initial : bool

        Returns
        -------
        (k, k) array, or None where a record's Jacobian is not finite
        """
        from aeid_struct.refinement import joint_jacobian

        n, width = self.n, 2 * self.n + 1
        F = np.zeros((target.size, target.size))
        for r in range(self.records):
            part = np.flatnonzero((self.free >= r * width) & (self.free < (r + 1) * width))
            if part.size == 0:
                continue
            where, base = self.free[part] - r * width, self._level[r * width: (r + 1) * width]

            def ccf(points, where=where, base=base):
                # the record's CCF (paper Eq. 5) at points of its free coefficients
                full = np.tile(base, (points.shape[0], 1))
                full[:, where] = points
                return [(*ccf_matrices(full[:, :n], full[:, n: 2 * n]), full[:, 2 * n])]

            k = target[part]
            J = joint_jacobian(ccf, k, [ys[r]], [us[r]], (dts[r],), initial,
                               np.maximum(np.abs(k), 1e-9 * np.abs(k).max() + 1e-300),
                               central=False)
            F[np.ix_(part, part)] = J @ J.T
        if not np.isfinite(F).all():
            return None
        s, V = np.linalg.eigh(F)
        return np.sqrt(np.clip(s, 0.0, None))[:, None] * V.T



#: PhysicalHead by (structure object, initial): built once per identifier's structure.
_HEADS: dict = {}


def physical_head(structure, initial: bool) -> PhysicalHead:
    """The :class:`PhysicalHead` of ``structure``, built once (compared by identity).

    Parameters
    ----------
    structure : Physical
    initial : bool

    Returns
    -------
    PhysicalHead
    """
    key = (id(structure), bool(initial))
    hit = _HEADS.get(key)
    if hit is None or hit[0] is not structure:
        if len(_HEADS) > 64:
            _HEADS.clear()
        hit = _HEADS[key] = (structure, PhysicalHead(structure, bool(initial)))
    return hit[1]


def centred(structure, initial: bool, ys: list) -> list:
    """The records as the encoder reads them: where the initial state is fitted, each record
    of a physical structure whose map holds a pole at zero on the whole box (``a_0 = 0``: a
    rigid-body mode, an integrator) less its first sample; the others as they are.

    Why: a constant output is a free response of the mode at zero, so the fitted initial state
    absorbs it and the fit does not depend on it; but Eq. 15 scales the encoder's input (and
    its scale feature) by ``max|y|``, which the angle a drive train has turned to before the
    window swamps. Training (``forward.differentiable``) and identification read the same.

    Parameters
    ----------
    structure : Structure
    initial : bool
        Whether the identifier fits the initial state.
    ys : list of R (count, steps_r) arrays or tensors

    Returns
    -------
    list of R arrays or tensors
        ``ys`` itself where no record is centred.
    """
    from aeid_struct.structures import type_of

    if not initial or type_of(structure) != "Physical":
        return ys
    patterns = physical_head(structure, True).patterns
    if not any(pattern.a[0] == 0.0 for pattern in patterns):
        return ys
    return [y - y[:, :1] if pattern.a[0] == 0.0 else y
            for y, pattern in zip(ys, patterns, strict=True)]


def apply_physical_head(ident, head, ys: list, us: list, model: tuple) -> tuple:
    """:func:`~aeid_struct.identification.head.apply_head` for a physical structure, with its
    arguments and results (module docstring): each record's CCF fitted alone (separable),
    then the parameters nearest all of them; rows whose encoder model is not finite are left
    as they are."""
    ph = physical_head(ident.structure, ident.initial == "fitted")
    A, b, c, d, el = (np.array(part, dtype=np.float64) for part in model)
    R = ph.records
    rows = np.flatnonzero(np.isfinite(el).all(axis=1)
                          & np.isfinite(A.reshape(A.shape[0], -1)).all(axis=1))
    failed = np.zeros(A.shape[0], dtype=bool)
    if rows.size == 0:
        return (A, b, c, d, el), failed
    if ph.groups is not None:
        from aeid_struct.identification.summed_head import summed_head

        return summed_head(ph, ident, head, ys, us, (A, b, c, d, el), rows)
    # the poles of the encoder's parameters, as the head starts from them
    starts = [ph.systems(el[row]) for row in rows]
    fitted, ok = [], np.ones(rows.size, dtype=bool)
    for r, pattern in enumerate(ph.patterns):
        y = ys[r]
        u = np.ones_like(y) if us[r] is None else np.broadcast_to(us[r], y.shape)
        a0 = np.stack([start[r][4] for start in starts])
        fa, fc, fd, ok_r = fit_rows(pattern, a0[:, pattern.free_a], y[rows], u[rows],
                                    ident._dts[r], iterations=head.iterations, tol=head.tol)
        fitted.append(np.concatenate([fa, fc, fd[:, None]], axis=1))
        ok &= ok_r
    fitted = np.concatenate(fitted, axis=1)[:, ph.free]
    # record by record: each record's Gauss-Newton stops on its own, and the step costs a few
    # evaluations of a small SX map (about 0.1-0.2 ms a record on this project's VM)
    found = np.full((rows.size, ph.q), math.nan)
    for i, row in enumerate(rows):
        if ok[i]:
            # a square map reaches the fitted coefficients whatever the weights
            weight = None if ph.square else ph.information(
                fitted[i], [y[row] for y in ys],
                [np.ones(y.shape[1]) if u is None else np.broadcast_to(u, y.shape)[row]
                 for y, u in zip(ys, us, strict=True)], ident._dts, ident.initial == "fitted")
            found[i] = ph.inverse.parameters(fitted[i], el[row], weight)
    # the same number of iterations of the output-error fit in the parameters (the one
    # refine=True converges), within the bounds: for several records, which it reads at once
    # (each channel fitted its own poles); for one, where the nearest parameters sit on a
    # bound (the channel's own optimum lies outside the box, so they are not the structure's)
    width = ph.hi - ph.lo
    joint = ok & (R > 1 or np.any((found - ph.lo <= 1e-6 * width)
                                  | (ph.hi - found <= 1e-6 * width), axis=1))
    if joint.any():
        from aeid_struct.refinement import fit_joint

        done = rows[joint]
        found[joint] = fit_joint(ph.at, found[joint], [y[done] for y in ys],
                                 [np.ones_like(y[done]) if u is None else
                                  np.broadcast_to(u, y.shape)[done]
                                  for y, u in zip(ys, us, strict=True)],
                                 ident._dts, lower=ph.lo, upper=ph.hi,
                                 initial=ident.initial == "fitted",
                                 max_iter=head.iterations, gain=False).p
    for i, row in enumerate(rows):
        if not ok[i]:
            failed[row] = True
            A[row], b[row], c[row], d[row], el[row] = (math.nan,) * 5
            continue
        p = found[i]
        parts = ph.systems(p)
        if R == 1:
            A[row], b[row], c[row], d[row] = parts[0][:4]
        else:
            for r, (Ar, br, cr, dr, _) in enumerate(parts):
                A[row, r], b[row, r], c[row, r], d[row, r] = Ar, br, cr, dr
        el[row] = p
    return (A, b, c, d, el), failed


def _ccf_coefficients(A, B, C) -> casadi.MX:
    """``(a_0 .. a_{n-1}, c_0 .. c_{n-1})`` of the CCF of ``(A, B, C)`` (paper Eq. 5), in
    CasADi (``symbolic.realisation.ccf``)."""
    from symbolic.realisation import ccf

    Ac, _, Cc, _ = ccf(A, B, C, casadi.MX(1, 1))
    return casadi.vertcat(-Ac[-1, :].T, Cc.T)
