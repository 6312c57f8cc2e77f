r"""A classical start beside the encoder's: Steiglitz-McBride iterations from an ARX fit.

The refinement is local: from a poor start (a short record, a lightly damped mode the encoder
hedged) it can stop in a local minimum far from the output-error optimum. A classical estimate
that costs a few small least-squares problems makes the start robust: the candidates of the
encoder and this one are scored alike (whole-record projection), and the refinement starts from
the best. ``ae.identify`` reports which start won (``info["start"]``).

*Steiglitz-McBride* (1965; MATLAB's ``oe`` initialisation): the ARX fit

    A(q) y_k = B(q) u_{k-D} + const + e_k,   A = 1 + a_1 q^-1 + .. + a_n q^-n,
    B = b_0 + .. + b_n q^-n  (the FOH discretisation of an order-n model has n + 1 terms),

is repeated on the signals prefiltered by ``1 / A`` of the previous fit; at the fixed point the
equation error is the output error filtered by ``1 / A``, so the estimate is consistent under
white output noise where plain ARX is biased. The refits run to that fixed point (the
denominator changing by less than :data:`TOL`, relative), at most :data:`MAX_ITERATIONS`: at
low signal-to-noise ratios a fixed few leave the estimate far from it (a resonant pair still
split into two real poles), and it is the start the one pass's few iterations need. Unstable
roots are reflected into the unit circle. The discrete poles ``z`` become continuous ones
``s = log z`` in normalised time (``dt = 1``); a negative real ``z`` (no real continuous
counterpart) is replaced by ``|z|``.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import scipy.linalg
import scipy.signal

from aeid_struct.multi import continuous_poles, reflected

__all__ = ["EARLY", "MAX_ITERATIONS", "MAX_ORDER", "TOL", "NoEncoder", "arx",
           "classical_candidates", "steiglitz_mcbride"]

#: The highest order ``ae.identify`` takes (above the shipped encoders' through
#: :class:`NoEncoder`): the orders the generic benchmark measures.
MAX_ORDER = 8

#: The early iterate :func:`classical_candidates` keeps beside the fixed point.
EARLY = 5
#: The most prefiltered refits of :func:`steiglitz_mcbride`.
MAX_ITERATIONS = 50
#: The fixed point: a refit that moves the denominator by less than this (relative, max norm).
TOL = 1e-10


def arx(y: np.ndarray, u: np.ndarray, n: int, extra: np.ndarray | None = None) -> np.ndarray:
    """The denominator of the least-squares ARX fit of order ``n`` with a constant (the one
    ARX of the library: the Steiglitz-McBride start here, the classical least squares' start
    where n4sid fails).

    ``y_k + A_1 y_{k-1} + ... + A_n y_{k-n} = B_0 u_k + ... + B_n u_{k-n} + const``, solved
    in least squares with the columns scaled to unit peak (Householder QR; the SVD's
    minimum-norm solution where the columns are dependent).

    Parameters
    ----------
    y, u : (steps,) arrays
    n : int, >= 1
    extra : (steps, m) array, optional
        Columns in place of the constant.

    Returns
    -------
    (n + 1,) array
        ``A`` with ``A[0] = 1`` (the discrete denominator, highest power first).
    """
    N = y.shape[0]
    k = 2 * n + 1 + (1 if extra is None else extra.shape[1])
    # the regressors and y as one column-major block: one Householder QR of [Z, y] gives R
    # and Q^T y together, several times cheaper than the SVD of lstsq, and Steiglitz-McBride
    # solves up to 50 of these problems per record
    Z = np.empty((N - n, k + 1), order="F")
    for i in range(1, n + 1):
        Z[:, i - 1] = -y[n - i: N - i]
    for j in range(n + 1):
        Z[:, n + j] = u[n - j: N - j]
    if extra is None:
        Z[:, 2 * n + 1] = 1.0
    else:
        Z[:, 2 * n + 1: k] = extra[n:]
    Z[:, k] = y[n:]
    scale = np.abs(Z[:, :k]).max(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    Z[:, :k] /= scale
    z = _least_squares(Z, k) / scale
    return np.concatenate([[1.0], z[:n]])


#: A diagonal of the QR's ``R`` below this, relative to its largest, counts as rank deficient:
#: such a problem is solved by the SVD (``lstsq``'s minimum-norm solution) as it always was.
RANK_TOL = 1e-9


def _least_squares(Zy: np.ndarray, k: int) -> np.ndarray:
    """The least-squares solution of ``Zy[:, :k] x = Zy[:, k]`` (columns scaled to unit peak):
    Householder QR where the columns are independent, the SVD otherwise."""
    if Zy.shape[0] > k:
        qr, _, _, info = scipy.linalg.lapack.dgeqrf(Zy)
        R = qr[:k, :k]
        diag = np.abs(np.diagonal(R))
        if info == 0 and np.all(np.isfinite(diag)) and diag.min() > RANK_TOL * diag.max():
            return scipy.linalg.solve_triangular(R, qr[:k, k], check_finite=False)
    return np.linalg.lstsq(Zy[:, :k], Zy[:, k], rcond=None)[0]


class NoEncoder:
    """The generic identifier protocol (``config.order, window, band``, ``denominators``) for an
    order without a trained encoder: it proposes no candidate (NaN rows, which the candidates'
    stage drops), so ``ae.identify`` starts from the classical candidates alone
    (:func:`classical_candidates`), scored, iterated and refined as the encoder's would be.

    Why not refuse: above the shipped orders the Steiglitz-McBride fixed point is a start the
    separable iterations take to the output-error optimum on lightly damped multi-mode records,
    where n4sid's model is far from it (``aeid-struct bench-generic``).

    Parameters
    ----------
    order : int, >= 1
    window : int
        The holdout rule's length (``generic.pipeline``: order selection), as an encoder's.
    band : (lo, hi)
        ``|p| dt`` the float64 check assumes (``generic.boundary.check_grid``).
    """

    def __init__(self, order: int, window: int, band: tuple[float, float]) -> None:
        self.config = SimpleNamespace(order=int(order), window=int(window), band=tuple(band))

    def __repr__(self) -> str:
        return f"NoEncoder(order={self.config.order})"

    def denominators(self, Y, U) -> np.ndarray:
        """No candidate: ``(K, order + 1)`` NaN rows for ``K`` windows.

        Parameters
        ----------
        Y, U : (K, window) arrays

        Returns
        -------
        (K, order + 1) array
        """
        return np.full((len(Y), self.config.order + 1), np.nan)


def steiglitz_mcbride(y, u, order: int, delay: int = 0,
                      iterations: int = MAX_ITERATIONS) -> np.ndarray | None:
    """A continuous monic denominator in normalised time from Steiglitz-McBride iterations.

    Parameters
    ----------
    y, u : (steps,) arrays
        The record (normalised time: one sample per time unit).
    order : int, >= 1
    delay : int, >= 0
        Input delay in samples: ``y[delay:]`` against ``u[:steps - delay]``.
    iterations : int, >= 0
        Prefiltered refits after the ARX fit, at most (fewer where the fixed point is
        reached: :data:`TOL`).

    Returns
    -------
    (order + 1,) float64 array or None
        Highest power first; None where the fit is not finite (a record with too few samples).
    """
    found = _iterates(y, u, order, delay, iterations, ())
    return None if found is None else found[-1]


def classical_candidates(y, u, order: int, delay: int = 0) -> np.ndarray:
    """The classical candidates of the one pass: the Steiglitz-McBride estimate after
    :data:`EARLY` refits and at its fixed point (:func:`steiglitz_mcbride`), as continuous
    monic denominators in normalised time; one row where they coincide.

    Why both: at a low signal-to-noise ratio only the fixed point is near the optimum, but on
    the generic benchmark's records the early iterate, a coarser start, was as often the better
    one to iterate from; they are scored alike (whole-record projection) and the better kept.

    Parameters
    ----------
    y, u : (steps,) arrays
    order : int, >= 1
    delay : int, >= 0

    Returns
    -------
    (k, order + 1) float64 array
        ``k`` is 0 (no finite fit), 1 or 2.
    """
    found = _iterates(y, u, order, delay, MAX_ITERATIONS, (EARLY,))
    if found is None:
        return np.zeros((0, order + 1))
    rows = [d for d in found if d is not None]
    if len(rows) == 2 and np.array_equal(rows[0], rows[1]):
        rows = rows[1:]
    return np.array(rows).reshape(-1, order + 1)


def _iterates(y, u, order: int, delay: int, iterations: int, keep: tuple):
    """The denominators after the refits in ``keep`` (where reached; the fixed point before
    them stands for them) and at the last refit, or None where the record is too short or
    the fit not finite."""
    y = np.asarray(y, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    N = y.shape[0] - delay
    if N <= 3 * order + 2:
        return None
    yy, uu = y[delay:] - y[delay:].mean(), u[:N] - u[:N].mean()
    kept = []
    with np.errstate(all="ignore"):
        a = reflected(arx(yy, uu, order))
        impulse = np.zeros(N)
        impulse[0] = 1.0
        extra = np.zeros((N, order + 1))
        done = 0
        for _ in range(iterations):
            # Filtering from zero initial conditions leaves a transient of 1 / A driven by the
            # first n equation errors and by the constant: its n impulse responses and its step
            # response are regressors, so the fixed point stays exact on noise-free data. They
            # are one impulse response, shifted, and its running sum.
            h = scipy.signal.lfilter([1.0], a, impulse)
            for j in range(order):
                extra[j:, j] = h[: N - j]
            np.cumsum(h, out=extra[:, order])
            a_next = reflected(arx(scipy.signal.lfilter([1.0], a, yy),
                                  scipy.signal.lfilter([1.0], a, uu), order, extra))
            if not np.all(np.isfinite(a_next)):
                break
            settled = np.max(np.abs(a_next - a)) <= TOL * np.max(np.abs(a_next))
            a, done = a_next, done + 1
            if done in keep:
                kept.append(_continuous(a))
            if settled:
                break
        if not np.all(np.isfinite(a)):
            return None
        kept += [_continuous(a)] * (len(keep) - len(kept))
        return [*kept, _continuous(a)]


def _continuous(a: np.ndarray) -> np.ndarray | None:
    """The continuous monic denominator (normalised time) of a discrete one ``a``: poles
    ``s = log z`` (``multi.continuous_poles``, module docstring); None where not finite."""
    den = np.real(np.poly(continuous_poles(a)))
    return den if np.all(np.isfinite(den)) else None
