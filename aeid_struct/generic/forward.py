r"""The generic identifier's forward pass in numpy, for identification (no gradients).

The same function as :meth:`~aeid_struct.generic.GenericIdentifier.factors_batch` (window
normalisation, spectral features, the residual 1-D encoder of paper Sec. III-A, the pole map of
:mod:`~aeid_struct.generic.poles`), evaluated without torch: at identification the batch is a
handful of windows, and torch's per-operation overhead (some twenty modules and their hooks)
costs many times the arithmetic. The encoder runs in its weights' precision (float32 as
trained), each "same" convolution as one matmul over an im2col gather; the normalisation,
the spectra and the pole map run in float64 as the torch path does.
``tests/test_generic_model.py`` checks the two paths against each other.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.special
import torch

__all__ = ["NumpyEncoder", "denominator_numpy", "factors_numpy", "normalise_numpy"]

# torch's own activations on numpy buffers (no copy): the exact functions trained, and torch's
# vectorised erf is several times faster than scipy.special.erf on these few thousand values
_ACTIVATIONS = {"tanh": torch.tanh, "relu": torch.relu, "gelu": torch.nn.functional.gelu,
                "silu": torch.nn.functional.silu}


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


class NumpyEncoder:
    """A generic identifier's encoder and spectral features as a numpy function.

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
        cfg = encoder.config
        sd = {k: v.detach().cpu().numpy().copy() for k, v in encoder.state_dict().items()}
        self.dtype = sd["shortcut.0.weight"].dtype
        act = _ACTIVATIONS[cfg.activation]
        self.act = lambda x: act(torch.from_numpy(x)).numpy()
        self.pool, self.length = int(cfg.pool), cfg.length
        self.kernel, self.pad = cfg.kernel, cfg.kernel // 2
        self.convs = [(sd[f"main.{2 * i}.weight"].reshape(cfg.width, -1),
                       sd[f"main.{2 * i}.bias"][:, None]) for i in range(cfg.depth)]
        self.shortcut = (sd["shortcut.0.weight"].reshape(cfg.width, -1),
                         sd["shortcut.0.bias"][:, None])
        self.dense = [(sd[f"head.{2 * i}.weight"].T.copy(), sd[f"head.{2 * i}.bias"])
                      for i in range(len(cfg.dense) + 1)]
        self.spectrum = spectrum
        self.hann = np.hanning(cfg.steps)                 # torch.hann_window(periodic=False)

    def _conv(self, hp: np.ndarray, W: np.ndarray, b: np.ndarray) -> np.ndarray:
        """'Same' 1-D convolution (Eq. 8) + activation of zero-padded windows laid end to end,
        ``hp (C, K (L + 2 pad)) -> (O, K (L + 2 pad))`` zero-padded again: ONE matmul over the
        whole batch (the columns that straddle two windows are computed and zeroed)."""
        C, T = hp.shape
        ksz, p = self.kernel, self.pad
        # im2col without a gather: cols[c, j, t] = hp[c, t + j]
        view = np.lib.stride_tricks.as_strided(
            hp, (C, ksz, T - 2 * p), (hp.strides[0], hp.strides[1], hp.strides[1]))
        out = np.zeros((W.shape[0], T), dtype=self.dtype)
        # the output of window i at sample l sits at column i (L + 2 pad) + l of the product
        out[:, p : T - p] = self.act(W @ view.reshape(C * ksz, T - 2 * p) + b)
        framed = out.reshape(W.shape[0], -1, self.length + 2 * p)
        framed[:, :, :p] = 0.0
        framed[:, :, self.length + p :] = 0.0
        return out

    def __call__(self, y_n: np.ndarray, u_n: np.ndarray) -> np.ndarray:
        """Raw outputs ``(K, n)`` (float64) of normalised windows ``y_n, u_n (K, steps)``."""
        K, steps = y_n.shape
        L, p = self.length, self.pad
        x = np.stack([y_n, u_n], axis=0).astype(self.dtype)           # (2, K, steps)
        if self.pool > 1:
            x = x[:, :, : L * self.pool].reshape(2, K, L, self.pool).mean(
                axis=3, dtype=self.dtype)
        xp = np.zeros((2, K, L + 2 * p), dtype=self.dtype)
        xp[:, :, p : p + L] = x
        xp = xp.reshape(2, -1)
        h = xp
        for W, b in self.convs:
            h = self._conv(h, W, b)
        both = np.concatenate([h, self._conv(xp, *self.shortcut)], axis=0)
        # torch flattens (K, channels, L) channel-major per window
        z = both.reshape(-1, K, L + 2 * p)[:, :, p : p + L].transpose(1, 0, 2).reshape(K, -1)
        if self.spectrum:
            mags = [np.abs(np.fft.rfft(s * self.hann, axis=1)) / math.sqrt(steps)
                    for s in (y_n, u_n)]
            features = np.log(np.concatenate(mags, axis=1) + 1e-3) / 4
            z = np.concatenate([z, features.astype(self.dtype)], axis=1)
        for i, (W, b) in enumerate(self.dense):
            z = z @ W + b
            if i < len(self.dense) - 1:
                z = self.act(z)
        return z.astype(np.float64)


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
