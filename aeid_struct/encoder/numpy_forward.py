"""The encoder of paper Sec. III-A as a numpy function (no gradients): the one numpy forward
pass, run by the leg identifiers' batch-1 path (``identification.fast_path``) and by the generic
identifiers' windows (``generic.forward``).

At identification a batch is one record or a handful of windows, and torch's per-operation
overhead (some twenty modules and their hooks) costs many times the arithmetic. Here average
pooling is a reshape, the records of a batch are laid end to end, zero-padded, so that each
"same" convolution (Eq. 8) is ONE matmul over a strided im2col view for the whole batch (the
columns that straddle two records are computed and zeroed), and the dense layers are one matmul
each. The network's input channels and the features appended before the dense layers are the
caller's (the leg identifiers read ``log(max|y| / max|u|)``, the generic ones their spectra):
:meth:`NumpyEncoder.convolve` and :meth:`NumpyEncoder.dense` are the two halves around them.
``tests/test_encoder.py`` checks the pass against the torch module.
"""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["ACTIVATIONS", "NUMPY_ACTIVATIONS", "NumpyEncoder"]

#: Activations numpy evaluates itself (the batch-1 path: no torch call per layer).
NUMPY_ACTIVATIONS = {"tanh": np.tanh, "relu": lambda x: np.maximum(x, 0.0)}
# torch's own activations on numpy buffers (no copy): the exact functions trained, and torch's
# vectorised erf is several times faster than scipy.special.erf on these few thousand values
_TORCH = {"tanh": torch.tanh, "relu": torch.relu, "gelu": torch.nn.functional.gelu,
          "silu": torch.nn.functional.silu}
#: How an activation may be evaluated.
ACTIVATIONS = ("numpy", "torch")


class NumpyEncoder:
    """An :class:`~aeid_struct.encoder.Encoder` as a numpy function of a batch of records.

    Parameters
    ----------
    encoder : Encoder
        Its weights are copied (later changes to the module are not seen).
    dtype : numpy dtype, optional
        The precision of the pass; default: the weights' own (float32 as trained).
    activation : {"numpy", "torch"}
        ``"numpy"``: numpy's own function (tanh, relu; a ValueError for the others);
        ``"torch"``: torch's, on the numpy buffer (bit for bit the trained function).

    Raises
    ------
    ValueError
        An activation numpy cannot evaluate where ``"numpy"`` is asked, or an unknown mode.
    """

    def __init__(self, encoder, *, dtype=None, activation: str = "torch") -> None:
        cfg = encoder.config
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {ACTIVATIONS}; got {activation!r}")
        if activation == "numpy" and cfg.activation not in NUMPY_ACTIVATIONS:
            raise ValueError(f"no numpy path for activation {cfg.activation!r}")
        sd = {k: v.detach().cpu().numpy() for k, v in encoder.state_dict().items()}
        self.dtype = np.dtype(sd["shortcut.0.weight"].dtype if dtype is None else dtype)
        sd = {k: v.astype(self.dtype, copy=True) for k, v in sd.items()}
        if activation == "numpy":
            self.act = NUMPY_ACTIVATIONS[cfg.activation]
        else:
            act = _TORCH[cfg.activation]
            self.act = lambda x: act(torch.from_numpy(x)).numpy()
        self.config = cfg
        self.pool, self.length = int(cfg.pool), cfg.length
        self.kernel, self.pad = cfg.kernel, cfg.kernel // 2
        self._index: dict[int, np.ndarray] = {}       # padded length -> im2col gather index
        convs = [(sd[f"main.{2 * i}.weight"].reshape(cfg.width, -1),
                  sd[f"main.{2 * i}.bias"][:, None]) for i in range(cfg.depth)]
        # the first main convolution and the shortcut read the same input with the same kernel:
        # one gather and one matmul of their stacked weights serve both (one layer's overhead
        # less at batch 1; the same products row by row); then the other main convolutions
        self.first = (np.concatenate([convs[0][0], sd["shortcut.0.weight"].reshape(cfg.width,
                                                                                    -1)]),
                      np.concatenate([convs[0][1], sd["shortcut.0.bias"][:, None]]))
        self.convs = convs[1:]
        self.rows = [(sd[f"head.{2 * i}.weight"], sd[f"head.{2 * i}.bias"])
                     for i in range(len(cfg.dense) + 1)]            # (out, in): W @ v
        self.layers = [(W.T.copy(), b) for W, b in self.rows]      # (in, out): z @ W

    def _conv(self, hp: np.ndarray, W: np.ndarray, b: np.ndarray) -> np.ndarray:
        """'Same' 1-D convolution (Eq. 8) + activation of zero-padded records laid end to end,
        ``hp (C, K (L + 2 pad)) -> (O, K (L + 2 pad))`` zero-padded again."""
        C, T = hp.shape
        ksz, p = self.kernel, self.pad
        # im2col by one gather, cols[c, j, t] = hp[c, t + j], with the index built once per
        # length: a few microseconds less per layer than a strided view, which matters at
        # batch 1 (the same values, so the same product)
        index = self._index.get(T)
        if index is None:
            index = self._index[T] = np.arange(ksz)[:, None] + np.arange(T - 2 * p)[None, :]
        out = np.zeros((W.shape[0], T), dtype=self.dtype)
        # the output of record i at sample l sits at column i (L + 2 pad) + l of the product
        out[:, p : T - p] = self.act(W @ hp[:, index].reshape(C * ksz, T - 2 * p) + b)
        if T > self.length + 2 * p:     # several records: zero the columns between them
            framed = out.reshape(W.shape[0], -1, self.length + 2 * p)
            framed[:, :, :p] = 0.0
            framed[:, :, self.length + p :] = 0.0
        return out

    def convolve(self, x: np.ndarray) -> np.ndarray:
        """The convolutional half: pooling, the residual convolutions and the shortcut,
        flattened as torch flattens them.

        Parameters
        ----------
        x : (C, K, steps) array
            ``C`` input channels of ``K`` records (normalised, Eq. 15).

        Returns
        -------
        (K, 2 width L) array
            In the pass's dtype, channel-major per record.
        """
        C, K, _ = x.shape
        L, p = self.length, self.pad
        x = x.astype(self.dtype, copy=False)
        if self.pool > 1:
            x = x[:, :, : L * self.pool].reshape(C, K, L, self.pool).mean(axis=3,
                                                                           dtype=self.dtype)
        xp = np.zeros((C, K, L + 2 * p), dtype=self.dtype)
        xp[:, :, p : p + L] = x
        xp = xp.reshape(C, -1)
        both = self._conv(xp, *self.first)
        h, shortcut = both[: self.config.width], both[self.config.width:]
        for W, b in self.convs:
            h = self._conv(h, W, b)
        both = np.concatenate([h, shortcut], axis=0)
        return both.reshape(-1, K, L + 2 * p)[:, :, p : p + L].transpose(1, 0, 2).reshape(K, -1)

    def dense(self, z: np.ndarray) -> np.ndarray:
        """The dense half (the activation between layers, none after the last).

        Parameters
        ----------
        z : (K, F) array
            :meth:`convolve`'s output with the caller's features appended.

        Returns
        -------
        (K, outputs) array
            In the pass's dtype.
        """
        if z.shape[0] == 1 and self.dtype == np.float64:
            # one record in float64 (the batch-1 path): matrix-vector products, a quarter
            # faster than 1-row matrix products at this size
            v = z[0]
            for i, (W, b) in enumerate(self.rows):
                v = W @ v + b
                if i < len(self.rows) - 1:
                    v = self.act(v)
            return v[None]
        for i, (W, b) in enumerate(self.layers):
            z = z @ W + b
            if i < len(self.layers) - 1:
                z = self.act(z)
        return z
