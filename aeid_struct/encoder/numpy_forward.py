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

import threading

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
    affine : (shift, scale) of (outputs,) arrays, optional
        The caller's map of the outputs, ``shift + scale * z`` (an identifier's
        ``theta_mean + theta_scale * z``), folded into the last layer of :meth:`one` (only),
        which then computes in float64.

    Raises
    ------
    ValueError
        An activation numpy cannot evaluate where ``"numpy"`` is asked, or an unknown mode.
    """

    def __init__(self, encoder, *, dtype=None, activation: str = "torch",
                 affine: tuple | None = None) -> None:
        cfg = encoder.config
        if activation not in ACTIVATIONS:
            raise ValueError(f"activation must be one of {ACTIVATIONS}; got {activation!r}")
        if activation == "numpy" and cfg.activation not in NUMPY_ACTIVATIONS:
            raise ValueError(f"no numpy path for activation {cfg.activation!r}")
        sd = {k: v.detach().cpu().numpy() for k, v in encoder.state_dict().items()}
        self.dtype = np.dtype(sd["shortcut.0.weight"].dtype if dtype is None else dtype)
        sd = {k: v.astype(self.dtype, copy=True) for k, v in sd.items()}
        self.config = cfg
        self._activate(activation)
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
        # one record (:meth:`one`): every bias is the weight of a constant 1 appended to the
        # layer's input, the pooling mean's 1 / pool is in the first layer's weights
        first = np.concatenate([self.first[0] / self.pool, self.first[1]], axis=1)
        self._one_convs = [first] + [np.concatenate([W, b], axis=1) for W, b in self.convs]
        self._one_rows = [np.concatenate([W, b[:, None]], axis=1) for W, b in self.rows]
        if affine is not None:
            # in float64 whatever the pass's dtype: the caller's map keeps its precision (a
            # float32 vector times float64 weights is float64)
            shift, scale = (np.asarray(v, dtype=np.float64) for v in affine)
            last = self._one_rows[-1].astype(np.float64) * scale[:, None]
            last[:, -1] += shift
            self._one_rows[-1] = last

    def _activate(self, activation: str) -> None:
        """The activation ``act(v)``, ``_into(v, out)`` (written into a buffer: numpy's tanh
        writes it there itself) and the threads' workspaces of :meth:`one`."""
        self.activation = activation
        if activation == "numpy":
            act = NUMPY_ACTIVATIONS[self.config.activation]
        else:
            torch_act = _TORCH[self.config.activation]

            def act(x):
                return torch_act(torch.from_numpy(x)).numpy()
        self.act = act
        self._into = ((lambda v, out: np.tanh(v, out=out)) if act is np.tanh
                      else (lambda v, out: np.copyto(out, act(v))))
        self._local = threading.local()

    def __getstate__(self) -> dict:
        # a copy (pickle, deepcopy) makes its own workspaces; the activation's closure is
        # remade from the config's name
        return {k: v for k, v in self.__dict__.items() if k not in ("_local", "act", "_into")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._activate(self.activation)

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

    def one(self, x: np.ndarray, features: np.ndarray | None = None) -> np.ndarray:
        """The whole pass of ONE record: :meth:`convolve`, the ``features``, :meth:`dense`.

        Why: at batch 1 the pass is some twenty numpy calls of microseconds each, more than its
        arithmetic. Here each convolution is three (the im2col copy from a precomputed window
        view of a zero-padded buffer, one matmul with the bias as the weight of a row of ones,
        the activation written into the next layer's buffer) and each dense layer two; the
        buffers are the calling thread's (``threading.local``), so threads do not share them.
        The same products as the batched halves, summed in another order.

        Parameters
        ----------
        x : (C, steps) array
            The ``C`` input channels of one record (normalised, Eq. 15).
        features : (features,) array, optional
            Appended before the dense layers, as the caller appends them to :meth:`convolve`.

        Returns
        -------
        (outputs,) array
            A new array in the pass's dtype (float64, mapped by ``affine``, where one was
            given).
        """
        work = self._local.__dict__.get("work")
        if work is None:
            work = self._local.work = _Workspace(self)
        L, P = self.length, self.pool
        np.add.reduce(x[:, : L * P].reshape(x.shape[0], L, P), axis=2, out=work.pooled)
        into = self._into
        for W, columns, windows, stack, out in work.convs:
            np.copyto(columns, windows)
            into(W @ stack, out)
        if work.shortcut is not None:
            np.copyto(*work.shortcut)
        if features is not None:
            work.features[:] = features
        v = work.flat
        for W, hidden in zip(self._one_rows, work.hidden, strict=False):
            into(W @ v, hidden[:-1])
            v = hidden
        return self._one_rows[-1] @ v

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


class _Workspace:
    """One thread's buffers for :meth:`NumpyEncoder.one`.

    Per convolution: its zero-padded input ``(C, L + 2 pad)`` (the interior written by the
    layer before; the first layer's holds the pooled record, the second's the first layer's
    output with the shortcut's rows below), a precomputed window view of it ``(C, kernel, L)``,
    the im2col stack ``(C kernel + 1, L)`` whose last row is ones (the bias) and where the
    activation goes. The flattened features (the last convolution's output, then the
    shortcut, channel-major as torch flattens them, then the caller's features) and the dense
    layers' inputs each end in a constant 1.
    """

    def __init__(self, net: NumpyEncoder) -> None:
        cfg, dtype = net.config, net.dtype
        L, p, k, w = net.length, net.pad, net.kernel, cfg.width
        rows = [W.shape[0] for W in net._one_convs]          # 2 w (main + shortcut), w, ...
        reads = [(W.shape[1] - 1) // k for W in net._one_convs]   # channels each conv reads
        padded = [np.zeros((reads[0], L + 2 * p), dtype=dtype)] + [
            np.zeros((rows[i - 1], L + 2 * p), dtype=dtype) for i in range(1, len(rows))]
        self.flat = np.ones(2 * w * L + cfg.features + 1, dtype=dtype)
        self.features = self.flat[2 * w * L : 2 * w * L + cfg.features]
        self.pooled = padded[0][:, p : p + L]
        self.convs = []
        for i, (W, c) in enumerate(zip(net._one_convs, reads, strict=True)):
            stack = np.ones((c * k + 1, L), dtype=dtype)
            windows = np.lib.stride_tricks.sliding_window_view(padded[i][:c], L, axis=1)
            last = i == len(rows) - 1
            out = (self.flat[: rows[i] * L].reshape(rows[i], L) if last
                   else padded[i + 1][:, p : p + L])
            self.convs.append((W, stack[:-1].reshape(c, k, L), windows[:, :k], stack, out))
        # the shortcut's rows, below the first layer's output, where they are not the flat
        # features already (a one-layer encoder writes both there)
        self.shortcut = None if len(rows) == 1 else (
            self.flat[w * L : 2 * w * L].reshape(w, L), padded[1][w:, p : p + L])
        self.hidden = [np.ones(W.shape[0] + 1, dtype=dtype) for W in net._one_rows[:-1]]
