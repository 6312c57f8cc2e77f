r"""The generic identifier's forward pass in numpy, for identification (no gradients).

The same function as :meth:`~aeid_struct.generic.GenericIdentifier.factors_batch` (window
normalisation, spectral features, the residual 1-D encoder of paper Sec. III-A, the pole map of
:mod:`~aeid_struct.generic.poles`), evaluated without torch: at identification the batch is a
handful of windows, and torch's per-operation overhead (some twenty modules and their hooks)
costs many times the arithmetic. The encoder is the one numpy pass (``encoder.NumpyEncoder``)
in its weights' precision (float32 as trained); the normalisation, the spectra and the pole map
run in float64 as the torch path does.
``tests/test_generic_model.py`` checks the two paths against each other.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.special

from aeid_struct.encoder import NumpyEncoder

__all__ = ["WindowEncoder", "denominator_numpy", "factors_numpy", "normalise_numpy"]


def normalise_numpy(y: np.ndarray, u: np.ndarray):
    """:func:`~aeid_struct.generic.normalise_windows` in numpy.

    Parameters
    ----------
    y, u : (batch, steps) float64 arrays

    Returns
    -------
    y_n, u_n : (batch, steps) arrays
        NaN rows where a window of ``y`` or ``u`` is constant or not finite.
    ok : (batch,) bool array
    """
    out = []
    ok = np.ones(y.shape[0], dtype=bool)
    with np.errstate(invalid="ignore"):
        for x in (y, u):
            x = x - x.mean(axis=1, keepdims=True)
            peak = np.abs(x).max(axis=1)
            good = np.isfinite(peak) & (peak > 0)
            ok &= good
            out.append(x / np.where(good, peak, 1.0)[:, None])
    out[0][~ok], out[1][~ok] = np.nan, np.nan
    return out[0], out[1], ok


class WindowEncoder:
    """A generic identifier's encoder and spectral features as a numpy function: the one
    numpy forward pass (``encoder.NumpyEncoder``, in the weights' float32 and torch's own
    activations, as trained) with the windows' spectra appended between its halves.

    Parameters
    ----------
    encoder : Encoder
        Single-record, with an input channel (``config.encoder_config()`` of a
        :class:`~aeid_struct.generic.GenericConfig`).
    spectrum : bool
        Whether the encoder reads the spectral features
        (:func:`~aeid_struct.generic.spectra`).
    """

    def __init__(self, encoder, spectrum: bool) -> None:
        self.net = NumpyEncoder(encoder)
        self.spectrum = spectrum
        self.hann = np.hanning(encoder.config.steps)      # torch.hann_window(periodic=False)

    def __call__(self, y_n: np.ndarray, u_n: np.ndarray) -> np.ndarray:
        """Raw outputs ``(K, n)`` (float64) of normalised windows ``y_n, u_n (K, steps)``.

        Parameters
        ----------
        y_n, u_n : (K, steps) arrays

        Returns
        -------
        (K, n) float64 array
        """
        steps = y_n.shape[1]
        z = self.net.convolve(np.stack([y_n, u_n], axis=0))
        if self.spectrum:
            mags = [np.abs(np.fft.rfft(s * self.hann, axis=1)) / math.sqrt(steps)
                    for s in (y_n, u_n)]
            features = np.log(np.concatenate(mags, axis=1) + 1e-3) / 4
            z = np.concatenate([z, features.astype(self.net.dtype)], axis=1)
        return self.net.dense(z).astype(np.float64)


def factors_numpy(raw: np.ndarray, band, damping):
    """:func:`~aeid_struct.generic.factors` in numpy: ``w (K, ceil(n/2))``, ``zeta (K,
    floor(n/2))`` of raw outputs ``(K, n)``."""
    def log_range(x, lo, hi):
        return np.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * scipy.special.expit(x))

    half = raw.shape[1] // 2
    w = log_range(raw[:, 0 : 2 * half : 2], *band)
    zeta = log_range(raw[:, 1 : 2 * half : 2], *damping)
    if raw.shape[1] % 2:
        w = np.concatenate([w, log_range(raw[:, -1:], *band)], axis=1)
    return w, zeta


def denominator_numpy(w: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """:func:`~aeid_struct.generic.denominator` in numpy: ``(a_0, .., a_{n-1})`` ``(K, n)``,
    ascending, without the leading 1."""
    half = zeta.shape[1]
    coef = np.ones((w.shape[0], 1))                                  # ascending, monic
    parts = [np.stack([w[:, j] ** 2, 2 * zeta[:, j] * w[:, j]], axis=1) for j in range(half)]
    if w.shape[1] > half:
        parts.append(w[:, half:])
    for low in parts:                         # times s^k + low (k = its length)
        k = low.shape[1]
        factor = np.concatenate([low, np.ones((low.shape[0], 1))], axis=1)
        m = coef.shape[1]
        out = np.zeros((coef.shape[0], m + k))
        for i in range(m):
            out[:, i : i + k + 1] += coef[:, i : i + 1] * factor
        coef = out
    return coef[:, :-1]
