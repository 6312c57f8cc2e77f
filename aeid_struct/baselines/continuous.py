r"""Discrete -> continuous time under the first-order (or zero-order) hold, exactly (paper
Eq. 10-13).

``expm([[A dt, b dt, 0], [0, 0, 1], [0, 0, 0]]) = [[Phi, gamma1, gamma2], ...]`` gives, in the
shifted state ``xi = x - gamma2 u`` (what ``cont2discrete(method="foh")`` and a subspace method
return)::

    xi_{k+1} = Phi xi_k + (gamma1 - gamma2 + Phi gamma2) u_k,
    y_k      = c^T xi_k + (d + c^T gamma2) u_k.

``gamma1 = G1 b`` and ``gamma2 = G2 b`` are linear in ``b``: the same exponential with ``b``
replaced by the identity, ``expm([[A dt, I dt, 0], [0, 0, I], [0, 0, 0]]) = [[Phi, G1, G2], ...]``
(``3n x 3n``). So a discrete model ``(Phi, Bd, Cd, Dd)`` converts exactly, in its own basis, by

    A = logm(Phi) / dt,   (G1 - G2 + Phi G2) b = Bd,   c = Cd,   d = Dd - c^T G2 b,

and a zero-order-hold model by ``G1 b = Bd``, ``d = Dd``. ``logm`` is the principal logarithm;
it is real exactly when ``Phi`` has no eigenvalue on the closed negative real axis. A real
continuous pole maps to ``e^{s dt} > 0``, so a negative real (or zero) discrete pole has no real
continuous counterpart: :func:`to_continuous` raises :class:`NoRealLogarithm` -- never a complex
model. Poles with ``|Im s| >= pi / dt`` alias and come back folded into the principal strip
(nothing can tell them apart in sampled data).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from aeid_struct.simulation import check_dt, discrete_inputs

__all__ = ["HOLDS", "Continuous", "NoRealLogarithm", "convert", "hold_matrices", "logm_real",
           "to_continuous"]

HOLDS = ("foh", "zoh")


class NoRealLogarithm(ValueError):
    """A discrete pole on the closed negative real axis: no real continuous model maps to it."""


@dataclass(frozen=True)
class Continuous:
    """A continuous-time SISO model ``x' = A x + b u``, ``y = c^T x + d u`` (float64).

    Attributes
    ----------
    A : (n, n) array
    b : (n,) array
    c : (n,) array
    d : float
    """

    A: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: float


def hold_matrices(A: np.ndarray, dt: float):
    """``Phi, G1, G2`` with ``gamma1 = G1 b``, ``gamma2 = G2 b`` (module docstring): Eq. 10
    for every input direction (``simulation.discrete_inputs`` with ``B = I``).

    Parameters
    ----------
    A : (n, n) array
    dt : float, > 0

    Returns
    -------
    Phi, G1, G2 : (n, n) arrays
    """
    return discrete_inputs(A, np.eye(A.shape[0]), dt)


def logm_real(Phi: np.ndarray, dt: float) -> np.ndarray:
    """``logm(Phi) / dt``, real: the continuous ``A`` of a discrete ``Phi``.

    Parameters
    ----------
    Phi : (n, n) array
    dt : float, > 0

    Returns
    -------
    (n, n) array

    Raises
    ------
    NoRealLogarithm
        For a pole on the closed negative real axis, or a complex logarithm.
    """
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


def convert(Phi, B, C, D, dt: float, holds: tuple[str, ...], feedthrough: bool) -> Continuous:
    """The continuous model of a discrete one with several input channels, unchecked.

    Each input column follows its own hold; all share ``Phi`` and ``c``, so ``b`` comes from the
    stacked equations of every column (least squares; exact data satisfy all).

    Parameters
    ----------
    Phi : (n, n) array
    B : (n, m) array
        One column per input channel.
    C : (n,) array
    D : (m,) array
    dt : float, > 0
    holds : tuple of m str
        ``"zoh"`` or ``"foh"`` for each column.
    feedthrough : bool
        Estimate ``d`` (the mean over the channels); 0 otherwise.

    Returns
    -------
    Continuous
        In the discrete model's basis.

    Raises
    ------
    NoRealLogarithm
        When ``Phi`` has an eigenvalue on the closed negative real axis.
    """
    A = logm_real(Phi, dt)
    Phi_c, G1, G2 = hold_matrices(A, dt)
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
    hold : {"foh", "zoh"}

    Returns
    -------
    Continuous

    Raises
    ------
    NoRealLogarithm
        (a ValueError) when ``Phi`` has an eigenvalue on the closed negative real axis.
    ValueError
        For a bad ``hold``, ``dt``, shape or a non-finite entry.
    """
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {HOLDS}; got {hold!r}")
    dt = check_dt(dt)
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
    return convert(Phi, B.reshape(n, 1), c.reshape(n), D.reshape(1), dt, (hold,), True)
