r"""Which physical parameters a record can determine: structural identifiability of a
:class:`~symbolic.mechanism.Mechanism`'s linearisation, and its practical side.

A record of the channels ``u[inputs] -> y[outputs]`` reveals the input-output map of the linear
model, nothing more: its transfer matrix ``G(s) = C (sI - A)^{-1} B + D``, not the realisation
(a mode a channel does not see, the leg's upright mode in its translation, tells nothing). The
parameters ``p`` are locally identifiable from it where the Jacobian of the transfer matrix
with respect to them has full column rank. ``G`` is sampled at ``6 n + 6`` frequencies
``j w`` spread over the linearisation's speeds (``0.1 min |lambda|`` to ``10 max |lambda|``;
a rational matrix of degree ``n`` is fixed by ``2 n + 1`` of its values, so these samples carry
all of it), and differentiated exactly from CasADi's derivatives of ``A, B, C, D``::

    dG = dC R B + C R dA R B + C R dB + dD,        R = (j w I - A)^{-1}.

Its *generic* rank (the largest over points in the box: the rank drops only on a thin set) is
the number of independent parameter combinations a record determines; the null space's
directions are the combinations it cannot see (``d log m = d log k = d log d = d log r`` for a
mass pushed through a lever of unknown ratio ``r``: only ``k/m, d/m, r/m`` are seen), and a
parameter is identifiable exactly where the null space has no component along it.

Scaling, for the numbers (not the rank): each row is a relative change of ``G_ij(j w)``
(divided by ``|G_ij(j w)|``, floored at ``1e-6`` of the channel's largest), a channel that is
zero throughout (no path from the input to the output) is left out, and parameters enter by
their logarithm where their box is one-signed, else by the box's width. The condition number
of the identifiable parameters' columns, the worst over the box, is the practical side: how
much a relative error of the measured response grows in the parameters.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import casadi
import numpy as np

__all__ = ["IdentifiabilityReport", "identifiability"]

#: Singular values below this fraction of the largest count as zero (J is exact to rounding:
#: CasADi's derivatives of a few matrix products).
RANK_TOL = 1e-8
#: A null-space component below this marks a parameter as identifiable.
NULL_TOL = 1e-6


@dataclass(frozen=True)
class IdentifiabilityReport:
    """What the chosen channels of a mechanism determine (module docstring).

    Attributes
    ----------
    parameters : tuple of str
        The parameters examined (the mechanism's, less the known ones).
    identifiable : tuple of str
        Those the channels determine locally.
    unidentifiable : tuple of str
        The others.
    rank : int
        Generic rank of the Jacobian: independent combinations determined.
    combinations : tuple of dict str -> float
        A basis of the directions the record cannot see, in log-parameters (for a one-signed
        box; the box's width otherwise), largest entry 1: moving along one leaves every record
        unchanged.
    fix : tuple of str
        A smallest set of parameters whose values, once known, make the rest identifiable.
    condition : float
        The worst condition number over the points of generic rank, of the identifiable
        parameters' columns (inf where none is identifiable).
    drops : tuple of dict
        Points in the box where the rank falls below the generic one: their parameter values,
        rank and condition number.
    inputs : tuple of int
        The inputs examined.
    outputs : tuple of int
        The outputs examined.
    points : int
        Points of the box examined.
    pairs : tuple of (int, int) or None
        The ``(output, input)`` channels examined where not every output of every input was
        (separate experiments, one input each: ``identifiability(..., pairs=...)``).
    """

    parameters: tuple[str, ...]
    identifiable: tuple[str, ...]
    unidentifiable: tuple[str, ...]
    rank: int
    combinations: tuple[dict, ...]
    fix: tuple[str, ...]
    condition: float
    drops: tuple[dict, ...] = field(repr=False)
    inputs: tuple[int, ...] = ()
    outputs: tuple[int, ...] = ()
    points: int = 0
    pairs: tuple[tuple[int, int], ...] | None = None

    @property
    def full(self) -> bool:
        """Whether every parameter examined is identifiable."""
        return not self.unidentifiable

    def __str__(self) -> str:
        what = (f"inputs {list(self.inputs)} to outputs {list(self.outputs)}"
                if self.pairs is None else
                "channels " + ", ".join(f"y[{o}] from u[{i}]" for o, i in self.pairs))
        lines = [f"identifiability of {', '.join(self.parameters)} from {what} "
                 f"({self.points} points of the box)",
                 f"  rank {self.rank} of {len(self.parameters)}",
                 f"  identifiable: {', '.join(self.identifiable) or 'none'}"]
        for name in self.unidentifiable:
            lines.append(f"  {name} not identifiable")
        for combo in self.combinations:
            moved = " ".join(f"{v:+.3g} {k}" for k, v in combo.items())
            lines.append(f"  unseen direction (log-parameters): {moved}")
        if self.fix:
            lines.append(f"  fix {', '.join(self.fix)} (known=...) to identify the rest")
        lines.append(f"  condition number (worst in the box): {self.condition:.3g}")
        if self.drops:
            lines.append(f"  rank drops at {len(self.drops)} point(s) of the box")
        return "\n".join(lines)


def identifiability(mechanism, bounds: Mapping[str, tuple[float, float]], *,
                    known: Mapping[str, float] | None = None,
                    inputs: Sequence[int] | None = None, outputs: Sequence[int] | None = None,
                    pairs: Sequence[tuple[int, int]] | None = None, points: int = 32,
                    seed: int = 0, **operating) -> IdentifiabilityReport:
    """The identifiability report of ``mechanism`` (module docstring).

    Parameters
    ----------
    mechanism : Mechanism
    bounds : dict str -> (low, high)
        The box of every parameter not in ``known``, ``low < high``.
    known : dict str -> float, optional
        Parameters whose values are known (not examined).
    inputs, outputs : sequence of int, optional
        The channels a record holds; all by default.
    pairs : sequence of (output, input), optional
        The channels measured where they are not every output of every input: records of
        separate experiments, each moving one input and measuring some outputs. Replaces
        ``inputs`` and ``outputs`` (given together: a ValueError).
    points : int, >= 1
        Points of the box examined: its centre and ``points - 1`` drawn uniformly (in log where
        the box spans more than a decade of one sign).
    seed : int
    **operating
        ``u, q, guess`` of :meth:`Mechanism.linearise`.

    Returns
    -------
    IdentifiabilityReport

    Raises
    ------
    ValueError
        Bounds missing, extra or not ``low < high`` finite; channels out of range.
    """
    lin = mechanism.linearise(known=known, **operating)
    names = tuple(lin.name_in())
    low, high = _box(bounds, names)
    n, m, p = mechanism.shape
    if pairs is not None:
        if inputs is not None or outputs is not None:
            raise ValueError("give pairs, or inputs and outputs, not both")
        pairs = _pairs(pairs, p, m)
        inputs = sorted({i for _, i in pairs})
        outputs = sorted({o for o, _ in pairs})
    ins = _channels("inputs", inputs, m)
    outs = _channels("outputs", outputs, p)
    # the measured channels among outputs x inputs (all of them without pairs)
    measured = (np.ones((len(outs), len(ins)), dtype=bool) if pairs is None else
                np.array([[(o, i) in pairs for i in ins] for o in outs]))
    if not (isinstance(points, int) and points >= 1):
        raise ValueError(f"points must be an int >= 1; got {points!r}")
    derivatives = _derivatives(lin)
    scale_log = (low > 0) | (high < 0)
    rng = np.random.default_rng(seed)
    logged = scale_log & (high / np.where(low == 0, 1, low) > 10)
    samples = [0.5 * (low + high)]
    for _ in range(points - 1):
        draw = rng.uniform(size=len(names))
        samples.append(np.where(logged, np.exp(np.log(np.abs(low)) + draw * np.log(
            np.abs(high) / np.abs(low))) * np.sign(high), low + draw * (high - low)))
    jacobians = [_scaled(derivatives, theta, scale_log, low, high, ins, outs, measured)
                 for theta in samples]
    kept = [i for i, J in enumerate(jacobians) if np.isfinite(J).all()]
    if not kept:
        raise ValueError("the linearisation is not finite anywhere in the box examined; "
                         "check bounds and the operating point")
    samples = [samples[i] for i in kept]
    jacobians = [jacobians[i] for i in kept]
    ranks = [_rank(J) for J in jacobians]
    rank = max(ranks)
    best = min((i for i, r in enumerate(ranks) if r == rank),
               key=lambda i: _condition(jacobians[i]))
    null = _null(jacobians[best], rank)
    weight = np.linalg.norm(null, axis=1) if null.size else np.zeros(len(names))
    identifiable = tuple(k for k, w in zip(names, weight, strict=True) if w < NULL_TOL)
    columns = [names.index(k) for k in identifiable]
    condition = max((_condition(J[:, columns]) for J, r in zip(jacobians, ranks, strict=True)
                     if r == rank), default=math.inf) if columns else math.inf
    drops = tuple({"values": dict(zip(names, map(float, theta), strict=True)), "rank": r,
                   "condition": _condition(J)}
                  for theta, J, r in zip(samples, jacobians, ranks, strict=True) if r < rank)
    return IdentifiabilityReport(
        parameters=names, identifiable=identifiable,
        unidentifiable=tuple(k for k in names if k not in identifiable), rank=rank,
        combinations=_combinations(null, names), fix=_fix(jacobians[best], names),
        condition=condition, drops=drops, inputs=ins, outputs=outs, points=points,
        pairs=pairs)


def _box(bounds, names) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(bounds, Mapping):
        raise ValueError(f"bounds must be a dict name -> (low, high); got "
                         f"{type(bounds).__name__}")
    missing, extra = sorted(set(names) - set(bounds)), sorted(set(bounds) - set(names))
    if missing or extra:
        raise ValueError(f"bounds must name exactly the parameters examined {list(names)} (the "
                         f"known ones go to known=); missing {missing}, not examined {extra}")
    low, high = [], []
    for k in names:
        try:
            lo, hi = (float(v) for v in bounds[k])
        except (TypeError, ValueError):
            raise ValueError(f"bounds[{k!r}] must be a pair (low, high) of numbers; got "
                             f"{bounds[k]!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"bounds[{k!r}] must be finite with low < high; got {(lo, hi)}")
        low.append(lo)
        high.append(hi)
    return np.array(low), np.array(high)


def _channels(what: str, value, size: int) -> tuple[int, ...]:
    if value is None:
        return tuple(range(size))
    out = tuple(int(i) for i in value)
    if not out or len(set(out)) != len(out) or not all(0 <= i < size for i in out):
        raise ValueError(f"{what} must be distinct indices in [0, {size}); got {value!r}")
    return out


def _pairs(value, p: int, m: int) -> tuple[tuple[int, int], ...]:
    try:
        given = [tuple(pair) for pair in value] if not isinstance(value, (str, bytes)) else []
    except TypeError:
        given = []
    whole = all(len(pair) == 2 and all(isinstance(v, (int, np.integer))
                                       and not isinstance(v, bool) for v in pair)
                for pair in given)
    out = tuple((int(o), int(i)) for o, i in given) if whole else ()
    if not out or len(set(out)) != len(out) or not all(
            0 <= o < p and 0 <= i < m for o, i in out):
        raise ValueError(f"pairs must be distinct (output, input) indices in [0, {p}) x "
                         f"[0, {m}); got {value!r}")
    return out


def _derivatives(lin: casadi.Function) -> casadi.Function:
    """``theta -> (A, B, C, D, dA, dB, dC, dD)``: the linearisation and its Jacobians with
    respect to the parameters (CasADi's own derivatives), ``dX`` of shape ``(size(X), q)``
    in column-major order."""
    kind = casadi.SX if lin.is_a("SXFunction") else casadi.MX
    theta = kind.sym("theta", lin.n_in())
    parts = lin(*[theta[i] for i in range(lin.n_in())])
    return casadi.Function("derivatives", [theta], [*parts, *(
        casadi.jacobian(casadi.vec(X), theta) for X in parts)])


def _scaled(derivatives, theta, scale_log, low, high, ins, outs, measured) -> np.ndarray:
    """The scaled Jacobian at ``theta`` (module docstring): rows ``Re, Im`` of
    ``d G_ij(j w) / d p / |G_ij(j w)|`` per measured channel (``measured (p', m')``) and
    frequency, columns per parameter."""
    A, B, C, D, dA, dB, dC, dD = (np.array(v) for v in derivatives(theta))
    n, m, p, q = A.shape[0], B.shape[1], C.shape[0], theta.size
    if not all(np.isfinite(v).all() for v in (A, B, C, D, dA, dB, dC, dD)):
        return np.full((1, q), np.nan)
    col = np.where(scale_log, np.abs(theta), high - low)
    # column-major vec -> (rows, cols, q) derivatives, scaled per column
    dA, dB, dC, dD = (v.reshape(c, r, q).transpose(1, 0, 2) * col
                      for v, r, c in ((dA, n, n), (dB, n, m), (dC, p, n), (dD, p, m)))
    ins, outs = list(ins), list(outs)
    B, C, D = B[:, ins], C[outs], D[np.ix_(outs, ins)]
    dB, dC, dD = dB[:, ins], dC[outs], dD[np.ix_(outs, ins)]
    speeds = np.abs(np.linalg.eigvals(A))
    speeds = speeds[speeds > 1e-9 * max(1.0, speeds.max(initial=0.0))]
    lo, hi = (0.1 * speeds.min(), 10 * speeds.max()) if speeds.size else (0.1, 10.0)
    w = np.geomspace(lo, hi, 6 * n + 6)
    R = np.linalg.inv(1j * w[:, None, None] * np.eye(n) - A)        # (F, n, n), all at once
    RB, CR = R @ B, C @ R
    G = C @ RB + D                                                  # (F, p', m')
    # dG = dC R B + C R dA R B + C R dB + dD                        # (F, p', m', q)
    dG = (np.einsum("ikq,fkj->fijq", dC, RB) + np.einsum("fik,klq,flj->fijq", CR, dA, RB)
          + np.einsum("fik,kjq->fijq", CR, dB) + dD)
    size = np.abs(G).max(axis=0) * measured       # (p', m'), unmeasured channels 0
    seen = size > 1e-12 * size.max() if size.max() > 0 else np.zeros_like(size, bool)
    scale = np.maximum(np.abs(G), 1e-6 * size)[..., None]
    rows = (dG / np.where(scale > 0, scale, 1.0))[:, seen]      # (F, channels, q)
    return np.concatenate([rows.real, rows.imag]).reshape(-1, q)


def _rank(J: np.ndarray) -> int:
    s = np.linalg.svd(J, compute_uv=False)
    return int(np.sum(s > RANK_TOL * s[0])) if s.size and s[0] > 0 else 0


def _condition(J: np.ndarray) -> float:
    s = np.linalg.svd(J, compute_uv=False)
    return float(s[0] / s[-1]) if s.size and s[-1] > 0 else math.inf


def _null(J: np.ndarray, rank: int) -> np.ndarray:
    """An orthonormal basis ``(q, q - rank)`` of the null space at generic rank."""
    _, _, vt = np.linalg.svd(J)
    return vt[rank:].T


def _combinations(null: np.ndarray, names) -> tuple[dict, ...]:
    out = []
    for v in null.T:
        v = v / v[np.argmax(np.abs(v))]
        out.append({k: float(round(x, 6)) for k, x in zip(names, v, strict=True)
                    if abs(x) > NULL_TOL})
    return tuple(out)


def _fix(J: np.ndarray, names) -> tuple[str, ...]:
    """Greedy: fix the parameter with the largest null-space component (the last declared of
    equals) until the rest have full column rank."""
    rest, fixed = list(range(len(names))), []
    while rest:
        sub = J[:, rest]
        r = _rank(sub)
        if r == len(rest):
            break
        weight = np.linalg.norm(_null(sub, r), axis=1)
        # ties (a scaling all parameters share) go to the parameter declared last
        worst = rest[int(np.flatnonzero(weight > weight.max() - NULL_TOL)[-1])]
        fixed.append(names[worst])
        rest.remove(worst)
    return tuple(fixed)
