r"""Classical baselines: subspace identification (n4sid) and output-error least squares.

:func:`n4sid` (nfoursid, converted exactly to continuous time), :func:`least_squares` (scipy,
exact FOH simulation and sensitivities, from :func:`generic_start`) and :func:`casadi_cold` (the
CasADi NLP of :mod:`aeid_struct.refine` from the same start). All return the library's
:class:`~aeid_struct.identify.Estimate`, so that the benchmark treats them like the encoder. A
failure that depends on the data (a discrete pole without a real logarithm, a model outside the
requested structure, a solver error) does not raise: the estimate comes back with
``info["failed"] = True``, a ``info["reason"]`` in words, and NaN matrices where no model exists.
Bad arguments (shapes, non-finite samples, an unknown element name) still raise ``ValueError``
naming the argument. :func:`failure` / :func:`failed` apply the benchmark's rule (failed,
non-finite, outside the structure, non-positive physical parameters, step error > 0.05).

Discrete -> continuous under the first-order hold (paper Eq. 10-13)
-------------------------------------------------------------------
``expm([[A dt, b dt, 0], [0, 0, 1], [0, 0, 0]]) = [[Phi, gamma1, gamma2], ...]`` gives, in the
shifted state ``xi = x - gamma2 u`` (what ``cont2discrete(method="foh")`` returns)::

    xi_{k+1} = Phi xi_k + (gamma1 - gamma2 + Phi gamma2) u_k,
    y_k      = c^T xi_k + (d + c^T gamma2) u_k.

``gamma1 = G1 b`` and ``gamma2 = G2 b`` are linear in ``b``: the same exponential with ``b``
replaced by the identity, ``expm([[A dt, I dt, 0], [0, 0, I], [0, 0, 0]]) = [[Phi, G1, G2], ...]``
(``3n x 3n``). So a discrete model ``(Phi, Bd, Cd, Dd)`` converts exactly, in its own basis, by

    A = logm(Phi) / dt,   (G1 - G2 + Phi G2) b = Bd,   c = Cd,   d = Dd - c^T G2 b,

and a zero-order-hold model by ``G1 b = Bd``, ``d = Dd``. ``logm`` is the principal logarithm;
it is real exactly when ``Phi`` has no eigenvalue on the closed negative real axis. A real
continuous pole maps to ``e^{s dt} > 0``, so a negative real (or zero) discrete pole has no real
continuous counterpart: :func:`to_continuous` raises :class:`NoRealLogarithm` and :func:`n4sid`
returns a failed estimate -- never a complex model. Poles with ``|Im s| >= pi / dt`` alias and
come back folded into the principal strip (nothing can tell them apart in sampled data).

Records from rest, and why n4sid needs two input channels
---------------------------------------------------------
A record starts from rest (DESIGN.md): ``x(0) = 0``, ``u`` linear between samples on ``[0, T]``.
If ``u_0 != 0`` the input jumps at ``t = 0``; a subspace method that sees only the record cannot
see that jump (a unit step is a constant sequence: no excitation at all). Prepending ``pre_zeros``
zero samples of ``u`` and ``y`` shows it the jump -- but then the data are *not* a trajectory of
the FOH model: between the last prepended zero and ``u_0`` the FOH would ramp, while the system
saw a jump. Measured: with the FOH conversion a stable-leg step comes back with Markov parameters
50 % off; the step record with zeros in front is exactly the *zero-order-hold* model's. The exact
split: ``u(t) = u_0 + v(t)`` on ``[0, T]`` with ``v_k = u_k - u_0`` (so ``v_0 = 0``);

* the constant ``u_0``, switched on at ``t = 0``, is exact under a zero-order hold: input channel
  ``s_k = u_0`` (zeros before), column ``gamma1``, feedthrough ``d``;
* ``v`` starts at zero, so the prepended zeros add no ramp: it is exact under the FOH, column
  ``gamma1 - gamma2 + Phi gamma2``, feedthrough ``d + c^T gamma2``.

Both share ``Phi`` and ``c``, so n4sid identifies one two-input model (one input when ``u`` is a
step or ``u_0 = 0``), and ``b`` comes from the stacked equations of both columns (least squares;
exact data satisfy both). With ``pre_zeros = 0`` the record is passed as one FOH channel and the
subspace method absorbs the initial shifted state ``xi_0 = -gamma2 u_0`` (exact for inputs that
excite the system persistently, useless for a step).

Defaults: ``pre_zeros = 2 block_rows``: the past and future Hankel windows together span
``2 block_rows`` samples, and the step channel is persistently exciting of that order only when
the jump appears at every position of such a window (all-zero windows before it).
``block_rows = min(20, steps // (2 (m + 1)))`` (at least ``order + 1``) for ``m`` input channels:
any ``block_rows > order`` is exact on clean data, but noise decides. Measured on 20 stable leg
steps (300 samples) with 1 % output noise: ``block_rows`` 4 / 8 / 12 / 20 / 30 gave 19 / 3 / 0 /
0 / 0 failures (step error > 0.05) and median step errors 0.086 / 0.032 / 0.0094 / 0.0034 /
0.0031; on the unstable leg (100 samples) 4 / 12 / 20 gave 19 / 10 / 3 failures. 20 is where the
gain levels off, and the record must hold ``2 block_rows (m + 2) - 1`` samples with the zeros
(nfoursid's QR needs as many Hankel columns as stacked rows).
nfoursid returns the model in an arbitrary basis; with a ``structure`` it is converted to that
structure's elements (``Structure.elements_of``) and realisation, and with an ``inverse`` (a CasADi
map from the CCF) physical parameters follow (``Estimate.physical``).

Output-error least squares
--------------------------
:func:`least_squares` minimises ``sum_k ((y_hat_k - y_k) / max|y|)^2`` over the structure's free
elements with ``scipy.optimize.least_squares``; fixed elements never move. The bounds are the
structure's constraints on the elements themselves (``Structure.element_bounds``: Descartes
``a_i >= 0``; MCF ``lambda, delta <= -1e-8``, ``omega >= 1e-8``; physical bounds). Solver
(``solver="auto"``): Levenberg-Marquardt (MINPACK) first, whose result is kept when it satisfies
the bounds -- a feasible unconstrained local minimum is a constrained one -- else the
trust-region reflective method within the bounds from the same start (``solver="trf"`` goes
there directly). Measured on 30 stable leg steps (``CCF(2, descartes=True)``, where the bound
is inactive at the truth), same iterations (median 11): lm 5.5 ms, trf within the bounds 9.0 ms.

``y_hat`` is the exact FOH response (Eq. 10-13) computed in numpy by :func:`_foh`: one ``expm``,
the Markov parameters ``C Phi^m`` by doubling (one GEMM per level), a cumulative sum for the
jump to ``u_0`` and a direct (not FFT) convolution for ``v``; the tests check it against
:func:`aeid_struct.simulate` to 1e-12. It replaces the torch decoder here because one record is
all overhead for torch: 0.85 ms per decoder call against ~0.1 ms (300 samples, one thread).

Jacobian (``jac="exact"``, the default): the sensitivity ``s_j = dx/dp_j`` obeys
``s_j' = A s_j + (dA/dp_j) x + (db/dp_j) u`` and ``dy/dp_j = (dc/dp_j)^T x + c^T s_j +
(dd/dp_j) u``. Stacking ``(x, s_1, .., s_p)`` gives one block lower-triangular system of
``n (p + 1)`` states with the outputs ``(y, dy/dp_1, .., dy/dp_p)``, driven by the same
piecewise-linear input: one exact FOH simulation yields the residual and the whole Jacobian.
``dA/dp`` etc. are constant for CCF and MCF (both are affine in their elements) and come from
CasADi's ``jacobian`` for a ``Physical`` map; the tests compare with central differences.
Measured (30 random leg systems, clean steps, stable 300 / unstable 100 samples): exact
5.5 / 4.5 ms per identification, finite differences (``jac="2-point"``) 14 / 12 ms at the same
accuracy. (All timings: median, one thread of a 2-core machine shared with training runs, so
they scatter by +-30 % between runs; :func:`n4sid` took 13.7 / 8.4 ms there.)

Generic ("cold") start (:func:`generic_start`), what a user without the encoder would do: CCF
with all poles at -1 (``a_i = binomial(n, i)``: ``a0 = 1, a1 = 2`` for order 2); MCF with real
poles -1, -2, ... and pairs ``-1 +- j (1, 2, ...)``; then the output elements ``c`` (and ``d``)
by *linear* least squares for those poles (the response is linear in them), which matches the
record's final value and scale; a ``Physical`` structure starts at the midpoints of its bounds.
The same start serves stable and unstable records: from poles at -1 the unstable leg converges
to its pole at +4...+12 rad/s (measured on the paper's parameter box).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from aeid_struct.identification import Estimate
from aeid_struct.records import as_array, require_finite
from aeid_struct.simulation.foh import _check_dt

__all__ = [
    "Classical",
    "Continuous",
    "NoRealLogarithm",
    "casadi_cold",
    "failed",
    "failure",
    "generic_start",
    "least_squares",
    "n4sid",
    "to_continuous",
]

HOLDS = ("foh", "zoh")
#: Open constraints (MCF ``lambda < 0``, ``omega > 0``) become closed bounds this far inside.
_MARGIN = 1e-8
#: Residual of a trial point whose simulation overflows (per sample, normalised units).
_OVERFLOW = 1e8


class NoRealLogarithm(ValueError):
    """A discrete pole on the closed negative real axis: no real continuous model maps to it."""


@dataclass(frozen=True)
class Continuous:
    """A continuous-time SISO model ``x' = A x + b u``, ``y = c^T x + d u``.

    Attributes:
        A: ``(n, n)``; b, c: ``(n,)``; d: float -- float64.
    """

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: float


# ----------------------------------------------------------------------------------------------
# Discrete -> continuous
# ----------------------------------------------------------------------------------------------
def _hold_matrices(A: np.ndarray, dt: float):
    """``Phi, G1, G2`` with ``gamma1 = G1 b``, ``gamma2 = G2 b`` (module docstring)."""
    n = A.shape[0]
    M = np.zeros((3 * n, 3 * n))
    M[:n, :n] = A * dt
    M[:n, n : 2 * n] = np.eye(n) * dt
    M[n : 2 * n, 2 * n :] = np.eye(n)
    E = scipy.linalg.expm(M)
    return E[:n, :n], E[:n, n : 2 * n], E[:n, 2 * n :]


def _logm_real(Phi: np.ndarray, dt: float) -> np.ndarray:
    """``logm(Phi) / dt``, real; raises NoRealLogarithm for a pole on the closed negative axis."""
    poles = np.linalg.eigvals(Phi)
    # LAPACK returns real eigenvalues of a real matrix with an imaginary part of exactly 0.
    bad = (poles.imag == 0) & (poles.real <= 0)
    if np.any(bad):
        z = float(poles.real[bad][0])
        where = "at the origin" if z == 0 else "negative real"
        raise NoRealLogarithm(
            f"the discrete model has a {where} pole z = {z:.6g}: no real continuous-time pole "
            f"maps to it (e^(s dt) > 0 for real s), so it has no real logarithm"
        )
    L = scipy.linalg.logm(Phi)
    if np.iscomplexobj(L):
        if np.max(np.abs(L.imag)) > 1e-10 * max(1.0, float(np.max(np.abs(L.real)))):
            raise NoRealLogarithm(f"logm of the discrete model is complex (poles {poles})")
        L = L.real
    return np.ascontiguousarray(L, dtype=np.float64) / dt


def _to_continuous(Phi, B, C, D, dt: float, holds: tuple[str, ...], feedthrough: bool):
    """Convert ``Phi (n, n)``, ``B (n, m)``, ``C (n,)``, ``D (m,)`` whose input columns follow
    ``holds`` (``"zoh"``/``"foh"`` each) in the model's own basis: returns ``Continuous``."""
    A = _logm_real(Phi, dt)
    Phi_c, G1, G2 = _hold_matrices(A, dt)
    rows = [G1 if h == "zoh" else G1 - G2 + Phi_c @ G2 for h in holds]
    b = np.linalg.lstsq(np.vstack(rows), B.T.reshape(-1), rcond=None)[0]
    c = np.asarray(C, dtype=np.float64).reshape(-1)
    d = 0.0
    if feedthrough:
        gamma2 = G2 @ b
        d = float(np.mean([D[j] - (c @ gamma2 if h == "foh" else 0.0)
                           for j, h in enumerate(holds)]))
    return Continuous(A, b, c, d)


def to_continuous(Phi, B, c, D, dt: float, *, hold: str = "foh") -> Continuous:
    """The continuous model whose exact hold discretisation is the given discrete model.

    ``hold="foh"``: ``(Phi, B, c, D)`` is the first-order-hold model in the shifted state
    (paper Eq. 10-13; ``cont2discrete(method="foh")``); ``hold="zoh"``: the zero-order-hold
    model. Inverts ``A = logm(Phi)/dt`` and the linear maps ``b -> B``, ``(b, d) -> D`` (module
    docstring); the result is in the discrete model's basis.

    Parameters
    ----------
    Phi : (n, n)
    B : (n,) or (n, 1)
    c : (n,) or (1, n)
    D : scalar
    dt : float, > 0

    Raises
    ------
    NoRealLogarithm
        (a ValueError) when ``Phi`` has an eigenvalue on the closed negative real axis.
    """
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {HOLDS}; got {hold!r}")
    dt = _check_dt(dt)
    Phi = np.asarray(Phi, dtype=np.float64)
    if Phi.ndim != 2 or Phi.shape[0] != Phi.shape[1] or Phi.shape[0] == 0:
        raise ValueError(f"Phi must be square with shape (n, n); got {Phi.shape}")
    n = Phi.shape[0]
    B, c = np.asarray(B, dtype=np.float64), np.asarray(c, dtype=np.float64)
    if B.shape not in ((n,), (n, 1)):
        raise ValueError(f"B must have shape ({n},) or ({n}, 1) to match Phi; got {B.shape}")
    if c.shape not in ((n,), (1, n)):
        raise ValueError(f"c must have shape ({n},) or (1, {n}) to match Phi; got {c.shape}")
    D = np.asarray(D, dtype=np.float64)
    if D.size != 1:
        raise ValueError(f"D must be a scalar; got shape {D.shape}")
    for name, v in (("Phi", Phi), ("B", B), ("c", c), ("D", D)):
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{name} must be finite")
    return _to_continuous(Phi, B.reshape(n, 1), c.reshape(n), D.reshape(1), dt, (hold,), True)


# ----------------------------------------------------------------------------------------------
# Input checks and the Estimate
# ----------------------------------------------------------------------------------------------
def _check_int(name: str, value, lowest: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lowest:
        raise ValueError(f"{name} must be an integer >= {lowest}; got {value!r}")
    return int(value)


def _records(y, u) -> tuple[np.ndarray, np.ndarray]:
    """One record: ``y (steps,)`` and ``u (steps,)`` (a unit step when None), finite, not zero."""
    out = []
    for name, v in (("y", y), ("u", np.ones(np.shape(y)) if u is None else u)):
        arr = as_array(name, v)
        if arr.ndim != 1 or arr.shape[0] < 2:
            raise ValueError(f"{name} must have shape (steps,) with steps >= 2 (one record; "
                             f"loop over a batch); got {arr.shape}")
        require_finite(name, arr)
        if not np.any(arr):
            raise ValueError(f"{name} must not be all zero: a record from rest with zero "
                             "input or output reveals nothing")
        out.append(arr)
    if out[0].shape != out[1].shape:
        raise ValueError(f"u must have the shape of y {out[0].shape}; got {out[1].shape}")
    return out[0], out[1]


def _physical_source(structure, inverse):
    """What ``Estimate.physical`` maps: the elements of a Physical structure, or the inverse."""
    import casadi

    from aeid_struct.structures import CCF, Physical

    if inverse is not None and not isinstance(inverse, casadi.Function):
        raise ValueError(f"inverse must be a casadi.Function (e.g. "
                         f"symbolic.leg.stable_inverse()); got {type(inverse).__name__}")
    if isinstance(structure, Physical):
        return ("elements", tuple(structure.element_names))
    if inverse is not None and not isinstance(structure, CCF):
        raise ValueError(f"inverse maps a CCF model to physical parameters: structure must be "
                         f"a CCF; got {structure!r}")
    return inverse


def _estimate(model, elements, y, u, dt, start, info, source) -> Estimate:
    A, b, c, d = model
    info = {**info, "seconds": time.perf_counter() - start}
    return Estimate(np.asarray(A, dtype=np.float64), np.asarray(b, dtype=np.float64),
                    np.asarray(c, dtype=np.float64), float(d), dict(elements), y, u, dt,
                    info["seconds"], False, info, source)


def _nan_model(n: int):
    return np.full((n, n), np.nan), np.full(n, np.nan), np.full(n, np.nan), math.nan


def _in_structure(structure, model):
    """``(A, b, c, d)`` in the structure's realisation and its elements, or raise ValueError."""
    import torch

    x = structure.elements_of(*model, strict=True).to(torch.float64)
    sys = structure.assemble(x)
    A, b, c, d = (t.detach().numpy() for t in sys)
    return (A, b, c, float(d)), dict(zip(structure.element_names, x.tolist(), strict=True))


# ----------------------------------------------------------------------------------------------
# n4sid
# ----------------------------------------------------------------------------------------------
def n4sid(y, u, dt: float, *, order: int, structure=None, inverse=None,
          feedthrough: bool = False, pre_zeros: int | None = None,
          block_rows: int | None = None) -> Estimate:
    """Subspace identification (nfoursid's PO-MOESP/N4SID) converted exactly to continuous time.

    Parameters
    ----------
    y : (steps,)
        One record from rest (``x(0) = 0``).
    u : (steps,), or None for a unit step
    dt : float, > 0
    order : int >= 1
        Model order (rank of the subspace step); ``info["singular_values"]`` helps choose it.
    structure : Structure, optional
        Return the model in this structure (elements and realisation). A model that violates
        it (a fixed element, Descartes, bounds) makes a failed estimate that still carries the
        unstructured model.
    inverse : casadi.Function, optional
        CCF -> physical parameters (e.g. ``symbolic.leg.stable_inverse()``); needs a CCF
        structure (``CCF(order)`` when ``structure`` is None).
    feedthrough : bool
        Estimate ``d`` (otherwise ``d = 0``); taken from ``structure`` when one is given.
    pre_zeros : int >= 0, default ``2 block_rows``
        Zero samples put in front of ``u`` and ``y`` (module docstring: how the step at ``t = 0``
        becomes visible and exact). 0 passes the record as one FOH channel.
    block_rows : int > order, default ``min(20, steps // (2 (m + 1)))``, at least ``order + 1``
        Block rows of the Hankel matrices (``m``: 1 or 2 input channels; module docstring).

    Returns
    -------
    Estimate
        ``info``: method, seconds, failed, reason, channels (the holds of the input channels),
        discrete (``Phi, B, C, D`` as identified), singular_values.
    """
    import pandas  # noqa: F401 -- imported before the clock starts: the first import takes ~0.5 s
    from nfoursid.nfoursid import NFourSID  # noqa: F401

    start = time.perf_counter()
    y, u_in = _records(y, u)
    dt = _check_dt(dt)
    order = _check_int("order", order, 1)
    if pre_zeros is not None:
        pre_zeros = _check_int("pre_zeros", pre_zeros, 0)
    if block_rows is not None:
        block_rows = _check_int("block_rows", block_rows, 1)
        if block_rows <= order:
            raise ValueError(f"block_rows must be > order = {order}; got {block_rows}")
    if structure is not None:
        if getattr(structure, "n", None) != order:
            raise ValueError(f"structure must have order {order}; got {structure!r}")
        feedthrough_s = "d" in structure.element_names
        if feedthrough and not feedthrough_s:
            raise ValueError(f"feedthrough=True but structure {structure!r} has no element d")
        feedthrough = feedthrough_s
    elif inverse is not None:
        from aeid_struct.structures import CCF

        structure = CCF(order, feedthrough=feedthrough)
    source = _physical_source(structure, inverse)

    # Input channels (module docstring): the jump to u_0 (ZOH) and v = u - u_0 (FOH).
    u0, v = u_in[0], u_in - u_in[0]
    if pre_zeros == 0:
        channels, holds = [u_in], ("foh",)
    else:
        channels = [np.full_like(u_in, u0)] if u0 != 0 else []
        channels += [v] if np.any(v != 0) else []
        holds = ("zoh",) * bool(u0 != 0) + ("foh",) * bool(np.any(v != 0))
    m, steps = len(channels), y.shape[0]
    if block_rows is None:
        # As many as the record allows with the default zeros, up to 20 (module docstring).
        block_rows = max(order + 1, min(20, steps // (2 * (m + 1))))
    if pre_zeros is None:
        pre_zeros = 2 * block_rows
    # nfoursid's QR needs as many Hankel columns as stacked rows: N - 2i + 1 >= 2i (m + 1).
    need = 2 * block_rows * (m + 2) - 1 - pre_zeros
    if steps < need:
        raise ValueError(f"y must have at least {need} samples for order={order}, "
                         f"block_rows={block_rows}, pre_zeros={pre_zeros} and {m} input "
                         f"channel(s); got {steps}")
    info = {"method": "n4sid", "failed": False, "reason": "", "channels": holds,
            "order": order, "block_rows": block_rows, "pre_zeros": pre_zeros}
    try:
        Phi, B, C, D, sv = _nfoursid(y, channels, order, block_rows, pre_zeros)
        info["discrete"] = {"Phi": Phi, "B": B, "C": C, "D": D}
        info["singular_values"] = sv
        model = _to_continuous(Phi, B, C[0], D[0], dt, holds, feedthrough)
    except NoRealLogarithm as err:
        return _estimate(_nan_model(order), {}, y, u_in, dt, start,
                         {**info, "failed": True, "reason": str(err)}, None)
    except (np.linalg.LinAlgError, ValueError) as err:
        return _estimate(_nan_model(order), {}, y, u_in, dt, start,
                         {**info, "failed": True,
                          "reason": f"nfoursid failed: {type(err).__name__}: {err}"}, None)
    model = (model.A, model.b, model.c, model.d)
    if not all(np.all(np.isfinite(m)) for m in model):
        return _estimate(_nan_model(order), {}, y, u_in, dt, start,
                         {**info, "failed": True, "reason": "non-finite model"}, None)
    elements = {}
    if structure is not None:
        try:
            model, elements = _in_structure(structure, model)
        except ValueError as err:
            return _estimate(model, {}, y, u_in, dt, start,
                             {**info, "failed": True,
                              "reason": f"model outside the structure: {err}"}, None)
    return _estimate(model, elements, y, u_in, dt, start, info, source)


def _nfoursid(y, channels, order, block_rows, pre_zeros):
    """nfoursid on zero-padded channels: ``Phi (n, n), B (n, m), C (1, n), D (1, m)``, and the
    leading singular values of its ``R32`` decomposition (order selection)."""
    import pandas as pd
    from nfoursid.nfoursid import NFourSID

    pad = np.zeros(pre_zeros)
    names = [f"u{j}" for j in range(len(channels))]
    frame = pd.DataFrame({**{nm: np.concatenate([pad, ch]) for nm, ch in zip(names, channels,
                                                                            strict=True)},
                          "y": np.concatenate([pad, y])})
    model = NFourSID(frame, output_columns=["y"], input_columns=names, num_block_rows=block_rows)
    model.subspace_identification()
    ss, _ = model.system_identification(rank=order)
    sv = np.diag(model.R32_decomposition.eigenvalues)[: 2 * order + 2].copy()
    Phi, B, C, D = (np.asarray(m, dtype=np.float64) for m in (ss.a, ss.b, ss.c, ss.d))
    for name, m in (("A", Phi), ("B", B), ("C", C), ("D", D)):
        if not np.all(np.isfinite(m)):
            raise ValueError(f"identified {name} is not finite")
    return Phi, B, C, D, sv


# ----------------------------------------------------------------------------------------------
# Exact FOH responses in numpy (least squares)
# ----------------------------------------------------------------------------------------------
def _foh(A: np.ndarray, b: np.ndarray, C: np.ndarray, d: np.ndarray, u: np.ndarray,
         dt: float) -> np.ndarray:
    """Exact FOH responses from rest of one system with several outputs (Eq. 10-13).

    ``A (n, n)``, ``b (n,)``, ``C (r, n)``, ``d (r,)``, ``u (steps,)`` -> ``Y (r, steps)``:
    ``y_k = u_0 (d + sum_{m<k} C Phi^m gamma1)`` (the jump to ``u_0`` at ``t = 0``, a zero-order
    hold) ``+ Dd v_k + sum_{m=1}^{k} C Phi^{m-1} Bd v_{k-m}`` (``v = u - u_0``, ``v_0 = 0``, in
    the shifted FOH state, which starts at zero); module docstring.
    """
    n, r, steps = A.shape[0], C.shape[0], u.shape[0]
    M = np.zeros((n + 2, n + 2))
    M[:n, :n] = A * dt
    M[:n, n] = b * dt
    M[n, n + 1] = 1.0
    E = scipy.linalg.expm(M)
    Phi, g1, g2 = E[:n, :n], E[:n, n], E[:n, n + 1]
    # O[m] = C Phi^m for m < steps - 1, by doubling: O[k:2k] = O[0:k] Phi^k.
    rows = max(steps - 1, 1)
    O = np.empty((rows, r, n))
    O[0] = C
    P, k = Phi, 1
    while k < rows:
        m = min(k, rows - k)
        O[k : k + m] = (O[:m].reshape(m * r, n) @ P).reshape(m, r, n)  # one GEMM, not m
        k += m
        if k < rows:
            P = P @ P
    u0 = float(u[0])
    Y = np.empty((r, steps))
    Y[:, 0] = d * u0
    if steps > 1:
        h = (O[: steps - 1].reshape(-1, n) @ g1).reshape(steps - 1, r)
        Y[:, 1:] = d[:, None] * u0 + u0 * np.cumsum(h, axis=0).T
    v = u - u0
    if np.any(v):
        Bd = g1 - g2 + Phi @ g2
        kernel = np.empty((r, steps))
        kernel[:, 0] = d + C @ g2
        kernel[:, 1:] = (O[: steps - 1].reshape(-1, n) @ Bd).reshape(steps - 1, r).T
        for i in range(r):
            Y[i] += np.convolve(kernel[i], v)[:steps]
    return Y


class _AffineModel:
    """CCF and MCF: ``(A, b, c, d)`` is affine in the elements, so its derivatives are constant:
    ``S(x) = S(x_0) + sum_j z_j S_j`` with ``z`` the free elements, ``x_0`` their zeros."""

    def __init__(self, structure, free: np.ndarray):
        import torch

        x0 = _fixed_vector(structure)
        X = np.repeat(x0[None], 1 + len(free), axis=0)
        X[1 + np.arange(len(free)), free] += 1.0
        A, b, c, d = (t.detach().numpy() for t in structure.assemble(torch.from_numpy(X)))
        flat = np.concatenate([A.reshape(len(X), -1), b, c, d[:, None]], axis=1)
        self.free, self.n = free, structure.n
        self.base, self.grad = flat[0], flat[1:] - flat[0]
        self._derivatives = _split(self.grad.T, self.n)

    def system(self, x: np.ndarray):
        A, b, c, d = _split((self.base + x[self.free] @ self.grad)[:, None], self.n)
        return A[0], b[0], c[0], d[0]

    def jacobian(self, x: np.ndarray):
        return self._derivatives


def _split(v: np.ndarray, n: int):
    """``v (n^2 + 2n + 1, k)`` (``A`` row-major) -> ``A (k, n, n)``, ``b, c (k, n)``, ``d (k,)``."""
    return (v[: n * n].T.reshape(-1, n, n), v[n * n : n * n + n].T,
            v[n * n + n : n * n + 2 * n].T, v[-1])


class _CasadiModel:
    """Physical: ``(A, b, c, d)`` and its Jacobian from the structure's CasADi map."""

    def __init__(self, structure, free: np.ndarray):
        import casadi

        f = structure.function
        x = casadi.MX.sym("x", structure.q)
        out = f.call({nm: x[i] for i, nm in enumerate(f.name_in())})
        flat = casadi.vertcat(*(casadi.vec(out[k]) for k in "ABCD"))
        self.F = casadi.Function("system_jacobian", [x], [flat, casadi.jacobian(flat, x)])
        self.free, self.n = free, structure.n

    def _split(self, v: np.ndarray):
        """``v (n^2 + 2n + 1, k)`` in CasADi's column-major order -> ``A (k, n, n)``, ..."""
        n = self.n
        A = v[: n * n].T.reshape(-1, n, n).transpose(0, 2, 1)
        return A, v[n * n : n * n + n].T, v[n * n + n : n * n + 2 * n].T, v[-1]

    def system(self, x: np.ndarray):
        flat, _ = self.F(x)
        A, b, c, d = self._split(np.array(flat))
        return A[0], b[0], c[0], d[0]

    def jacobian(self, x: np.ndarray):
        _, J = self.F(x)
        return self._split(np.array(J)[:, self.free])


def _fixed_vector(structure) -> np.ndarray:
    """All elements zero but the fixed ones, at their values: ``(q,)``."""
    fixed = structure.fixed_values
    return np.array([fixed.get(nm, 0.0) for nm in structure.element_names])


def _check_structure(structure) -> None:
    from aeid_struct.structures import Structure

    if not isinstance(structure, Structure):
        raise ValueError(f"structure must be a CCF, MCF or Physical; got "
                         f"{type(structure).__name__}")


def _model(structure, free: np.ndarray):
    from aeid_struct.structures import CCF, MCF, Physical, Structure

    if isinstance(structure, (CCF, MCF)):
        return _AffineModel(structure, free)
    if isinstance(structure, Physical):
        return _CasadiModel(structure, free)
    kind = type(structure).__name__ if isinstance(structure, Structure) else "not a Structure"
    raise ValueError(f"structure must be a CCF, MCF or Physical; got {structure!r} ({kind})")


def _bounds(structure) -> tuple[np.ndarray, np.ndarray]:
    """Closed bounds ``(lo, hi)`` of every element: ``Structure.element_bounds()`` (the closure of
    each constraint map's range; open MCF sets shrunk by 1e-8), fixed elements at their value."""
    if hasattr(structure, "element_bounds"):
        pairs = [structure.element_bounds()[nm] for nm in structure.element_names]
    else:  # structures.py without element_bounds (it arrived with refine.py): the same closure
        pairs = [({"nonneg": 0.0, "pos": _MARGIN, "interval": m.lo}.get(m.kind, -math.inf),
                  {"neg": -_MARGIN, "interval": m.hi}.get(m.kind, math.inf))
                 for m in structure._maps.values()]
    return np.array([p[0] for p in pairs], float), np.array([p[1] for p in pairs], float)


def _linear_names(structure) -> list[str]:
    """Free elements the response is linear in: ``c_i`` and ``d`` of CCF and MCF."""
    from aeid_struct.structures import Physical

    if isinstance(structure, Physical):
        return []
    fixed = structure.fixed_values
    return [nm for nm in structure.element_names if nm not in fixed
            and (nm == "d" or (nm[0] == "c" and nm[1:].isdigit()))]


def generic_start(structure, y, u, dt: float) -> dict[str, float]:
    """The cold start of :func:`least_squares`: what a user without the encoder would try.

    CCF: all poles at -1, ``a_i = binomial(n, i)`` (order 2: ``a0 = 1, a1 = 2``). MCF: real poles
    -1, -2, ..., pairs ``-1 +- j (1, 2, ...)``. Then the free ``c_i`` (and ``d``), in which the
    response is linear, by linear least squares on the record for those poles: it matches the
    record's scale and final value. Physical: the midpoints of the bounds. Fixed elements keep
    their values.

    Returns
    -------
    dict element name -> float, for every element of the structure.
    """
    y, u = _records(y, u)
    dt = _check_dt(dt)
    _check_structure(structure)
    return _generic_start(structure, _model(structure, _free(structure)), y, u, dt)


def _free(structure) -> np.ndarray:
    """Indices of the free elements in the element order."""
    fixed = structure.fixed_values
    return np.array([i for i, nm in enumerate(structure.element_names) if nm not in fixed],
                    dtype=int)


def _generic_start(structure, model, y, u, dt) -> dict[str, float]:
    from aeid_struct.structures import CCF, MCF, Physical

    names = structure.element_names
    x = {}
    if isinstance(structure, CCF):
        x |= {f"a{i}": float(math.comb(structure.n, i)) for i in range(structure.n)}
    elif isinstance(structure, MCF):
        x |= {f"lambda{i}": -(i + 1.0) for i in range(structure.real)}
        for j in range(structure.pairs):
            x |= {f"delta{j}": -1.0, f"omega{j}": j + 1.0}
    elif isinstance(structure, Physical):
        x |= {nm: 0.5 * (lo + hi) for nm, (lo, hi) in structure.bounds.items()}
    x |= structure.fixed_values
    linear = _linear_names(structure)
    if linear:
        # The response is linear in the free c_i (and d): columns = the response with them at
        # zero, then one per linear element (c = e_i; d: the input itself).
        vec = np.array([0.0 if nm in linear else x.get(nm, 0.0) for nm in names])
        A, b, c, d = model.system(vec)
        C = np.zeros((1 + len(linear), structure.n))
        D = np.zeros(1 + len(linear))
        C[0], D[0] = c, d
        for k, nm in enumerate(linear):
            if nm == "d":
                D[1 + k] = 1.0
            else:
                C[1 + k, int(nm[1:])] = 1.0
        with np.errstate(all="ignore"):
            cols = _foh(A, b, C, D, u, dt)
        coef = np.linalg.lstsq(cols[1:].T, y - cols[0], rcond=None)[0]
        x |= dict(zip(linear, coef.tolist(), strict=True))
    return {nm: float(x.get(nm, 0.0)) for nm in names}


class _Problem:
    """Residual ``(y_hat - y) / max|y|`` over the free elements and its exact Jacobian, both
    from one simulation of the system augmented by its sensitivities (module docstring)."""

    def __init__(self, model, x: np.ndarray, y, u, dt: float, exact: bool):
        self.model, self.x, self.y, self.u, self.dt = model, x.copy(), y, u, dt
        self.scale = 1.0 / float(np.max(np.abs(y)))
        self.exact = exact
        self._z = self._r = self._J = None

    def full(self, z: np.ndarray) -> np.ndarray:
        x = self.x.copy()
        x[self.model.free] = z
        return x

    def _evaluate(self, z: np.ndarray) -> None:
        x = self.full(z)
        steps, p = self.y.shape[0], len(z)
        try:
            with np.errstate(all="ignore"):
                A, b, c, d = self.model.system(x)
                if not self.exact:
                    Y = _foh(A, b, c[None], np.reshape(d, 1), self.u, self.dt)
                else:
                    # One system with state (x, s_1, .., s_p), s_j = dx/dp_j, and outputs
                    # (y, dy/dp_1, .., dy/dp_p): s_j' = A s_j + dA_j x + db_j u.
                    dA, db, dc, dd = self.model.jacobian(x)
                    n = A.shape[0]
                    N = n * (p + 1)
                    AA, bb, CC = np.zeros((N, N)), np.empty(N), np.zeros((p + 1, N))
                    bb[:n], bb[n:] = b, db.reshape(-1)
                    CC[0, :n] = c
                    for j in range(p + 1):
                        block = slice(j * n, (j + 1) * n)
                        AA[block, block] = A
                        if j:
                            AA[block, :n] = dA[j - 1]
                            CC[j, :n], CC[j, block] = dc[j - 1], c
                    Y = _foh(AA, bb, CC, np.concatenate([np.reshape(d, 1), dd]), self.u, self.dt)
            ok = bool(np.all(np.isfinite(Y)))
        except (ValueError, np.linalg.LinAlgError, OverflowError):
            ok = False
        if ok:
            r, J = (Y[0] - self.y) * self.scale, Y[1:].T * self.scale if self.exact else None
        else:  # an overflowing trial point: a large residual makes the trust region shrink
            r, J = np.full(steps, _OVERFLOW), np.zeros((steps, p))
        self._z, self._r, self._J = z.copy(), r, J

    def residual(self, z: np.ndarray) -> np.ndarray:
        if self._z is None or not np.array_equal(z, self._z):
            self._evaluate(z)
        return self._r

    def jacobian(self, z: np.ndarray, *_) -> np.ndarray:
        if self._z is None or not np.array_equal(z, self._z):
            self._evaluate(z)
        return self._J


JACOBIANS = ("exact", "2-point", "3-point")
SOLVERS = ("auto", "trf")


def least_squares(y, u, dt: float, *, structure, start: dict | None = None, inverse=None,
                  jac: str = "exact", solver: str = "auto", xtol: float = 1e-12,
                  ftol: float = 1e-12, gtol: float = 1e-12, max_nfev: int = 200) -> Estimate:
    """Output-error least squares on the structure's free elements from a generic start.

    Minimises ``sum_k ((y_hat_k - y_k) / max|y|)^2`` with ``y_hat`` the exact FOH response from
    rest (Eq. 10-13) by ``scipy.optimize.least_squares`` within the structure's bounds (module
    docstring: solver, Jacobian, timings).

    Parameters
    ----------
    y : (steps,)
    u : (steps,), or None for a unit step
    dt : float, > 0
    structure : CCF, MCF or Physical
        Fixed elements stay exactly at their values.
    start : dict name -> value, optional
        Start values for some or all elements; the rest from :func:`generic_start`.
    inverse : casadi.Function, optional
        CCF -> physical parameters for ``Estimate.physical`` (CCF structures).
    jac : "exact" (sensitivity equations), "2-point" or "3-point" (finite differences)
    solver : "auto" (lm, then trf if lm's result leaves the bounds) or "trf"
    xtol, ftol, gtol, max_nfev
        ``scipy.optimize.least_squares`` stopping rules (per solver run).

    Returns
    -------
    Estimate
        ``info``: method, seconds, failed, reason, start, jac, solver ("lm", "trf", "lm+trf"),
        nfev, njev, cost, status, message.
    """
    start_time = time.perf_counter()
    y, u = _records(y, u)
    dt = _check_dt(dt)
    _check_structure(structure)
    if jac not in JACOBIANS:
        raise ValueError(f"jac must be one of {JACOBIANS}; got {jac!r}")
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}; got {solver!r}")
    for name, v in (("xtol", xtol), ("ftol", ftol), ("gtol", gtol)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise ValueError(f"{name} must be a finite number >= 0; got {v!r}")
    max_nfev = _check_int("max_nfev", max_nfev, 1)
    source = _physical_source(structure, inverse)
    names = structure.element_names
    free = _free(structure)
    if y.shape[0] < len(free):
        raise ValueError(f"y must have at least {len(free)} samples (one per free element of "
                         f"{structure!r}); got {y.shape[0]}")
    model = _model(structure, free)
    lo, hi = _bounds(structure)
    x = _start(structure, model, start, y, u, dt, lo, hi)
    info = {"method": "least_squares", "failed": False, "reason": "",
            "start": dict(zip(names, x.tolist(), strict=True)), "jac": jac}
    if len(free) == 0:
        return _estimate(model.system(x), info["start"], y, u, dt, start_time,
                         {**info, "solver": "none"}, source)
    bounded = bool(np.any(np.isfinite(lo[free])) or np.any(np.isfinite(hi[free])))
    # lm first where allowed: a feasible unconstrained local minimum is a constrained one.
    methods = ("trf",) if bounded and solver == "trf" else ("lm", "trf") if bounded else ("lm",)
    problem = _Problem(model, x, y, u, dt, exact=jac == "exact")
    nfev = njev = 0
    for k, method in enumerate(methods):
        try:
            result = scipy.optimize.least_squares(
                problem.residual, x[free], jac=problem.jacobian if jac == "exact" else jac,
                bounds=(lo[free], hi[free]) if method == "trf" else (-np.inf, np.inf),
                method=method, x_scale="jac", xtol=xtol, ftol=ftol, gtol=gtol,
                max_nfev=max_nfev)
        except (ValueError, np.linalg.LinAlgError) as err:
            if k + 1 < len(methods):
                continue
            return _estimate(_nan_model(structure.n), {}, y, u, dt, start_time,
                             {**info, "solver": "+".join(methods[: k + 1]), "failed": True,
                              "reason": f"least squares failed: {type(err).__name__}: {err}"},
                             None)
        nfev, njev = nfev + int(result.nfev), njev + int(result.njev or 0)
        if np.all(result.x >= lo[free]) and np.all(result.x <= hi[free]):
            break
    x = problem.full(result.x)
    info |= {"solver": "+".join(methods[: k + 1]), "nfev": nfev, "njev": njev,
             "cost": float(result.cost), "status": int(result.status),
             "message": str(result.message)}
    return _finish(structure, model, names, x, y, u, dt, start_time, info, source)


def _finish(structure, model, names, x, y, u, dt, start_time, info, source) -> Estimate:
    """The estimate of optimised elements ``x``, or a failed one where they are not finite."""
    system = model.system(x)
    if not (np.all(np.isfinite(x)) and all(np.all(np.isfinite(m)) for m in system)):
        return _estimate(_nan_model(structure.n), {}, y, u, dt, start_time,
                         {**info, "failed": True, "reason": "non-finite elements"}, None)
    return _estimate(system, dict(zip(names, x.tolist(), strict=True)), y, u, dt, start_time,
                     info, source)


def _start(structure, model, start, y, u, dt, lo, hi) -> np.ndarray:
    """The start vector ``(q,)``: the user's values over the generic start, checked."""
    names = structure.element_names
    given = {} if start is None else start
    if not isinstance(given, dict):
        raise ValueError(f"start must be a dict element name -> value; got "
                         f"{type(given).__name__}")
    fixed = structure.fixed_values
    for nm, v in given.items():
        if nm not in names:
            raise ValueError(f"start has unknown element {nm!r}; elements of {structure!r}: "
                             f"{', '.join(names)}")
        if not (isinstance(v, (int, float, np.floating)) and math.isfinite(v)):
            raise ValueError(f"start[{nm!r}] must be a finite number; got {v!r}")
        if nm in fixed and v != fixed[nm]:
            raise ValueError(f"start[{nm!r}] = {v!r} but {nm} is fixed at {fixed[nm]!r} in "
                             f"{structure!r}")
        i = names.index(nm)
        if not lo[i] <= v <= hi[i]:
            raise ValueError(f"start[{nm!r}] = {v!r} is outside the structure's bounds "
                             f"[{lo[i]:g}, {hi[i]:g}]")
    free = [nm for nm in names if nm not in fixed]
    if not all(nm in given for nm in free):
        given = _generic_start(structure, model, y, u, dt) | given
    x = given
    x = np.array([float(fixed.get(nm, x.get(nm, 0.0))) for nm in names])
    return np.clip(x, lo, hi)


# ----------------------------------------------------------------------------------------------
# Failure rule of the benchmark
# ----------------------------------------------------------------------------------------------
def failure(estimate: Estimate, *, structure=None, truth_y=None, step_tol: float = 0.05):
    """Why an estimate counts as a failure, or ``""`` when it does not.

    In this order: the method reported a failure (``info["failed"]``, e.g. a negative real
    discrete pole, an exception); the model is not finite; it violates ``structure`` (when
    given: fixed elements, Descartes, bounds, via ``structure.elements_of(strict=True)``); a
    physical parameter (``Estimate.physical``) is non-finite or not positive; its unit-step
    response differs from ``truth_y`` by a Table I step error above ``step_tol``.

    Parameters
    ----------
    estimate : Estimate, single or batched (from any method, the encoder's included)
    structure : Structure, optional
    truth_y : (steps,) or (batch, steps), optional
        The true system's unit-step response on the estimate's grid ``k dt``.
    step_tol : float
        The benchmark's threshold, 0.05.

    Returns
    -------
    str for a single estimate, a list of str for a batched one.
    """
    if not isinstance(estimate, Estimate):
        raise ValueError(f"estimate must be an Estimate; got {type(estimate).__name__}")
    if not (isinstance(step_tol, (int, float)) and step_tol > 0):
        raise ValueError(f"step_tol must be a positive number; got {step_tol!r}")
    count = estimate.A.shape[0] if estimate.batched else 1
    truth = None
    if truth_y is not None:
        truth = np.atleast_2d(as_array("truth_y", truth_y))
        if truth.ndim != 2 or truth.shape[0] != count or not np.all(np.isfinite(truth)):
            raise ValueError(f"truth_y must be finite with shape (steps,) or ({count}, steps) "
                             f"for this estimate; got {np.shape(truth_y)}")
    A = np.asarray(estimate.A, dtype=np.float64).reshape(count, *estimate.A.shape[-2:])
    n = A.shape[-1]
    b = np.asarray(estimate.b, dtype=np.float64).reshape(count, n)
    c = np.asarray(estimate.c, dtype=np.float64).reshape(count, n)
    d = np.asarray(estimate.d, dtype=np.float64).reshape(count)
    info = estimate.info or {}
    physical = {}
    finite = all(np.all(np.isfinite(m)) for m in (A, b, c, d))
    if not info.get("failed") and finite:
        try:
            physical = {k: np.reshape(v, count) for k, v in estimate.physical.items()}
        except Exception as err:  # a CasADi inverse that cannot evaluate this model
            physical = {"<inverse>": np.full(count, np.nan)}
            info = {**info, "inverse_error": str(err)}
    reasons = []
    for i in range(count):
        reasons.append(_failure_one(A[i], b[i], c[i], d[i], info, structure,
                                    {k: v[i] for k, v in physical.items()},
                                    None if truth is None else truth[i], estimate.dt, step_tol))
    return reasons if estimate.batched else reasons[0]


def _failure_one(A, b, c, d, info, structure, physical, truth, dt, step_tol) -> str:
    from aeid_struct.metrics import step_error

    if info.get("failed"):
        return info.get("reason") or "the method failed"
    if not all(np.all(np.isfinite(m)) for m in (A, b, c, d)):
        return "non-finite model"
    if structure is not None:
        try:
            structure.elements_of(A, b, c, d, strict=True)
        except ValueError as err:
            return f"outside the structure: {err}"
    for name, v in physical.items():
        if not (np.isfinite(v) and v > 0):
            return f"physical parameter {name} = {float(v):.6g} is not positive"
    if truth is not None:
        with np.errstate(all="ignore"):
            y_hat = _foh(A, b, c[None], np.reshape(d, 1), np.ones(truth.shape[0]), dt)[0]
        if not np.all(np.isfinite(y_hat)):
            return "step response not finite"
        err = float(step_error(truth, y_hat)[0])
        if not err <= step_tol:
            return f"step error {err:.3g} > {step_tol:g}"
    return ""


def failed(estimate: Estimate, *, structure=None, truth_y=None, step_tol: float = 0.05):
    """``bool(failure(...))``: a bool for a single estimate, a bool array for a batch."""
    why = failure(estimate, structure=structure, truth_y=truth_y, step_tol=step_tol)
    return bool(why) if isinstance(why, str) else np.array([bool(w) for w in why])


# ----------------------------------------------------------------------------------------------
# CasADi NLP from the generic start
# ----------------------------------------------------------------------------------------------
def casadi_cold(y, u, dt: float, *, structure, start: dict | None = None, inverse=None,
                config=None) -> Estimate:
    """The CasADi NLP of :mod:`aeid_struct.refine` from the generic start of :func:`least_squares`:
    the "CasADi from a cold start" baseline, i.e. the refinement without the encoder's estimate.

    Parameters are those of :func:`least_squares` (``start`` over :func:`generic_start`), plus
    ``config``: a ``refine.RefineConfig`` (default: its defaults). The solver's outcome is in
    ``info`` (iterations, success, status, loss, loss_start); a solver that does not converge
    keeps its best point and is judged by :func:`failure` like any other estimate.
    """
    from aeid_struct.refinement import RefineConfig, refine_elements

    start_time = time.perf_counter()
    y, u = _records(y, u)
    dt = _check_dt(dt)
    if config is None:
        config = RefineConfig()
    _check_structure(structure)
    model = _model(structure, _free(structure))
    source = _physical_source(structure, inverse)
    lo, hi = _bounds(structure)
    x = _start(structure, model, start, y, u, dt, lo, hi)
    names = structure.element_names
    info = {"method": "casadi_cold", "failed": False, "reason": "",
            "start": dict(zip(names, x.tolist(), strict=True))}
    try:
        result = refine_elements(structure, x, y, u, dt, config)
    except (RuntimeError, ValueError, np.linalg.LinAlgError) as err:  # CasADi: RuntimeError
        return _estimate(_nan_model(structure.n), {}, y, u, dt, start_time,
                         {**info, "failed": True,
                          "reason": f"CasADi NLP failed: {type(err).__name__}: {err}"}, None)
    x = np.asarray(result.elements, dtype=np.float64)
    info |= {"iterations": result.iterations, "success": result.success,
             "status": result.status, "loss": result.loss, "loss_start": result.loss_start,
             "solver": result.solver}
    return _finish(structure, model, names, x, y, u, dt, start_time, info, source)


# ----------------------------------------------------------------------------------------------
# A method behind an identifier's interface
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Classical:
    """A classical method behind an identifier's interface, record by record.

    Attributes:
        method: one of this module's methods with its keyword arguments bound, e.g.
            ``functools.partial(least_squares, structure=CCF(2).fixed(a1=0.0), inverse=f)``;
            called as ``method(y, u, dt)`` on one record.
        dt, steps: the record format.

    ``identify(y, u)`` applies the method to each record and stacks the estimates into one
    batched :class:`Estimate` (NaN rows where a record failed), so that scorecards and
    benchmarks score a classical method exactly like an encoder. ``info["records"]`` keeps each
    record's own ``info`` and ``info["failed"]`` is a ``(batch,)`` bool array.
    """

    method: object
    dt: float
    steps: int

    def __post_init__(self) -> None:
        if not callable(self.method):
            raise ValueError(f"method must be callable (e.g. functools.partial(least_squares, "
                             f"structure=...)); got {type(self.method).__name__}")
        _check_dt(self.dt)
        if not isinstance(self.steps, int) or self.steps < 2:
            raise ValueError(f"steps must be an integer >= 2; got {self.steps!r}")

    def identify(self, y, u=None, *, refine: bool = False) -> Estimate:
        """Identify each record of ``y (batch, steps)`` (or one ``(steps,)``) with ``u`` like
        ``y`` (None: unit steps); ``refine`` polishes each estimate (:mod:`aeid_struct.refine`)."""
        start = time.perf_counter()
        Y = np.atleast_2d(as_array("y", y))
        if Y.ndim != 2 or Y.shape[1] != self.steps:
            raise ValueError(f"y must have shape ({self.steps},) or (batch, {self.steps}); "
                             f"got {np.shape(y)}")
        U = np.ones_like(Y) if u is None else np.atleast_2d(as_array("u", u))
        if U.ndim != 2 or U.shape[1] != self.steps or U.shape[0] not in (1, len(Y)):
            raise ValueError(f"u must have shape ({self.steps},) or ({len(Y)}, {self.steps}) "
                             f"like y; got {np.shape(u)}")
        U = np.broadcast_to(U, Y.shape)
        parts = []
        for y_i, u_i in zip(Y, U, strict=True):
            est = self.method(y_i, u_i, self.dt)
            if refine and not est.info.get("failed") and est.structure is not None:
                from aeid_struct.refinement import refine as _refine

                est = _refine(est, y_i, u_i, self.dt)
            parts.append(est)
        n = max(np.shape(p.A)[-1] for p in parts)
        names = list(dict.fromkeys(k for p in parts for k in p.elements))

        def stack(get, shape):
            out = np.full((len(parts), *shape), math.nan)
            for i, p in enumerate(parts):
                value = np.asarray(get(p), dtype=np.float64)
                if value.shape == shape:
                    out[i] = value
            return out

        A, b, c = stack(lambda p: p.A, (n, n)), stack(lambda p: p.b, (n,)), \
            stack(lambda p: p.c, (n,))
        d = stack(lambda p: p.d, ())
        elements = {k: stack(lambda p, k=k: p.elements.get(k, math.nan), ()) for k in names}
        source = next((p._inverse for p in parts if p._inverse is not None), None)
        info = {"method": parts[0].info.get("method", ""), "records": [p.info for p in parts],
                "failed": np.array([bool(p.info.get("failed")) for p in parts])}
        est = Estimate(A, b, c, d, elements, Y, np.asarray(U), self.dt,
                       time.perf_counter() - start, bool(refine), info, source,
                       structure=parts[0].structure)
        return est if np.ndim(y) == 2 else _single(est)


def _single(est: Estimate) -> Estimate:
    """The one record of a batch-1 estimate, unbatched."""
    return Estimate(est.A[0], est.b[0], est.c[0], float(est.d[0]),
                    {k: float(v[0]) for k, v in est.elements.items()}, est.y[0], est.u[0],
                    est.dt, est.seconds, est.refined, {**est.info, "failed": bool(
                        est.info["failed"][0])}, est._inverse, structure=est.structure)
