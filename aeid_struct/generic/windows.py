r"""Candidate denominators from a record of any length: windows at several time scales.

A generic identifier reads windows of a fixed length ``window`` (samples) and sees poles in a
band of ``|p| dt`` (rad/sample; docs/architecture.md, "Any system, any record"). A record of any
length ``steps >= window`` is read at several time scales: block averaging by ``m = 1, 2, 4,
...`` (while ``steps // m >= window``) turns a pole ``p`` per sample into ``m p`` per decimated
sample, so a scale ``m`` window shows the network the band ``|p| dt`` in ``[lo / m, hi / m]``
of the original record (slow systems in long records are seen). At each scale at most
``most`` windows are cut evenly (overlapping when the record is short). All windows of all
scales go through one batched ``identifier.denominators`` call, and each denominator found at
scale ``m`` (poles in decimated time) is rescaled to the original sample time (poles ``/ m``):

    a(s) = s^n + a_{n-1} s^{n-1} + ... + a_0   ->   a_k / m^{n-k}.

A record shorter than the window is read once at a finer grid: ``window`` samples linearly
interpolated over its ``steps`` (``m = (steps - 1) / (window - 1) < 1``), the same rescaling.

*Growth in the normalisation.* The encoders were trained on stable systems; a record of an
integrating or unstable plant is one they never saw. Weighting a window by ``e^{-sigma k}``
turns it into a record of a shifted system: if ``y = G(s) u`` then
``y e^{-sigma t} = G(s + sigma) (u e^{-sigma t})``, whose poles are ``p - sigma`` (continuous
time; sampled, the input's ramp between samples is weighted too: an error of order
``sigma dt`` times the input's change over a sample, at the ``sigma dt <= 4 / window`` used
here). Every window is therefore read unweighted and under the weights of :data:`GROWTH`
(``sigma = g / window`` per window sample, ``y`` less its first sample so that the output's
level does not become a decaying mode of its own), and the poles found under a weight are
shifted back, ``a(s) -> a(s - sigma)`` (:func:`unshift`): a pole at ``0`` or at
``+sigma / 2`` is seen at ``-sigma`` or ``-sigma / 2``, inside the family the encoder knows.
A stable record's weighted windows give one more set of stable candidates; the whole-record
scoring decides among all of them.

The whole-record choice among the candidates is :mod:`aeid_struct.generic.scoring`.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["GROWTH", "MOST_WINDOWS", "Windows", "candidates", "cut", "decimate", "rescale",
           "scales", "unshift", "weighted"]

#: At most this many windows per time scale.
MOST_WINDOWS = 8
#: The exponential weights ``e^{-g k / window}`` every window is also read under (``g``: the
#: weight's decay over one window). Chosen with the stable-only encoders (before generic-1..3
#: were fine-tuned on weighted windows) on integrating and unstable plants of orders 2 and 3 at
#: 2 % noise, 12 records each: among the grids (2), (4), (2, 4) and (1, 2, 4, 8), (2, 4)
#: gave the encoder's pass alone its best median and 10th percentile against refined but for
#: (1, 2, 4, 8), which matched it at twice the candidates.
GROWTH = (2.0, 4.0)


def scales(steps: int, window: int) -> list[int]:
    """Decimation factors ``1, 2, 4, ...`` that leave at least ``window`` samples.

    Parameters
    ----------
    steps, window : int, steps >= window >= 1

    Returns
    -------
    list of int
    """
    out, m = [], 1
    while steps // m >= window:
        out.append(m)
        m *= 2
    return out


def decimate(x: np.ndarray, m: int) -> np.ndarray:
    """Block averages of ``m`` samples (the tail that does not fill a block is dropped).

    Parameters
    ----------
    x : (steps,) array
    m : int, >= 1

    Returns
    -------
    (steps // m,) array
    """
    if m == 1:
        return x
    L = x.shape[0] // m
    return x[: L * m].reshape(L, m).mean(axis=1)


def cut(length: int, window: int, most: int = MOST_WINDOWS) -> np.ndarray:
    """First samples of ``K = min(most, ceil(length / window))`` windows spread evenly over
    ``[0, length - window]`` (overlapping when ``K window > length``).

    Parameters
    ----------
    length, window : int, length >= window
    most : int, >= 1

    Returns
    -------
    (K,) int array
    """
    K = min(most, math.ceil(length / window))
    return np.unique(np.linspace(0, length - window, K).round().astype(int))


class Windows:
    """The windows of a record at every time scale, stacked for one identifier call.

    Parameters
    ----------
    y, u : (steps,) arrays
    window : int
        Samples per window; a shorter record is one window at a finer grid (linear
        interpolation, ``window`` samples over its ``steps``).
    most : int
        Windows per scale, at most.

    Attributes
    ----------
    y, u : (K, window) arrays
    scale : (K,) array
        Record samples per window sample: the decimation factor of each window (``< 1`` for
        a short record's).
    """

    def __init__(self, y: np.ndarray, u: np.ndarray, window: int,
                 most: int = MOST_WINDOWS) -> None:
        steps = y.shape[0]
        if steps < window:
            # a record shorter than the window: one window over all of it at a finer grid,
            # linearly interpolated (the first-order hold's own input; for y a start only: the
            # candidates are scored and refined on the record itself), its poles rescaled
            grid = np.linspace(0.0, steps - 1.0, window)
            self.y = np.interp(grid, np.arange(steps), y)[None]
            self.u = np.interp(grid, np.arange(steps), u)[None]
            self.scale = np.array([(steps - 1.0) / (window - 1.0)])
            return
        ys, us, ms = [], [], []
        for m in scales(y.shape[0], window):
            yd, ud = decimate(y, m), decimate(u, m)
            for s in cut(yd.shape[0], window, most):
                ys.append(yd[s : s + window])
                us.append(ud[s : s + window])
                ms.append(m)
        self.y, self.u = np.stack(ys), np.stack(us)
        self.scale = np.asarray(ms)


def rescale(dens: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Denominators found in decimated time (one sample = ``scale`` samples) in the original
    sample time: poles divided by ``scale``, ``a_k -> a_k / scale^(n-k)``.

    Parameters
    ----------
    dens : (K, n + 1) array
        Monic, highest power first.
    scale : (K,) array

    Returns
    -------
    (K, n + 1) array
    """
    n = dens.shape[1] - 1
    return dens / np.asarray(scale, float)[:, None] ** np.arange(n + 1)


def weighted(y: np.ndarray, u: np.ndarray, growth=GROWTH):
    """Windows unweighted and under each exponential weight of ``growth`` (the module
    docstring), stacked.

    Parameters
    ----------
    y, u : (K, window) arrays
    growth : sequence of float
        Each weight's decay over one window, ``g > 0``.

    Returns
    -------
    Y, U : ((1 + G) K, window) arrays
        The windows as given, then under ``e^{-g k / window}`` for each ``g`` (``y`` less its
        first sample).
    sigma : ((1 + G) K,) array
        Each row's weight, ``g / window`` per window sample (0 for the unweighted rows).
    """
    window = y.shape[1]
    k = np.arange(window)
    Y, U, sigma = [y], [u], [np.zeros(y.shape[0])]
    for g in growth:
        w = np.exp(-(g / window) * k)
        Y.append((y - y[:, :1]) * w)
        U.append(u * w)
        sigma.append(np.full(y.shape[0], g / window))
    return np.concatenate(Y), np.concatenate(U), np.concatenate(sigma)


def unshift(dens: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """The denominators with every pole moved right by ``sigma``: ``a(s) -> a(s - sigma)``
    (Horner's scheme in ``s - sigma``, exact polynomial arithmetic, no roots).

    Parameters
    ----------
    dens : (K, n + 1) array
        Monic, highest power first.
    sigma : (K,) array

    Returns
    -------
    (K, n + 1) array
    """
    sigma = np.asarray(sigma, float)[:, None]
    out = np.zeros_like(dens[:, :1])
    for j in range(dens.shape[1]):
        # out(s) * (s - sigma) + a_j: out grows by one degree per coefficient read
        out = (np.concatenate([out, np.zeros_like(out[:, :1])], axis=1)
               - sigma * np.concatenate([np.zeros_like(out[:, :1]), out], axis=1))
        out[:, -1] += dens[:, j]
    return out[:, 1:]


def candidates(identifier, y: np.ndarray, u: np.ndarray,
               most: int = MOST_WINDOWS, growth=GROWTH) -> np.ndarray:
    """The identifier's denominators of all windows at all scales, unweighted and under the
    weights of ``growth`` (the module docstring), in normalised time of the record (one
    batched ``denominators`` call); unusable (non-finite) rows are dropped.

    Parameters
    ----------
    identifier : object
        ``config.window`` (samples) and ``denominators(Y (K, window), U) -> (K, n + 1)``.
    y, u : (steps,) arrays
    most : int
    growth : sequence of float
        The weights (:data:`GROWTH`); ``()`` reads the windows unweighted only.

    Returns
    -------
    (K', n + 1) array
        Monic denominators, highest power first; possibly none. The unweighted windows' come
        first, in the order of :class:`Windows`.
    """
    w = Windows(y, u, int(identifier.config.window), most)
    Y, U, sigma = weighted(w.y, w.u, tuple(growth))
    dens = np.asarray(identifier.denominators(Y, U), dtype=np.float64)
    dens = rescale(unshift(dens, sigma), np.tile(w.scale, len(growth) + 1))
    return dens[np.isfinite(dens).all(axis=1)]
