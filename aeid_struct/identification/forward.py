"""The torch back end of an identifier: Eq. 15 per record in float64, the encoder, the
structure and the exact de-normalisation, batched in torch or, for one record, through the numpy
pass (``fast_path``); and the differentiable pass that training uses."""

from __future__ import annotations

import numpy as np
import torch

from aeid_struct.identification.fast_path import fast_path
from aeid_struct.records import normalise
from aeid_struct.structures import System

__all__ = ["CHUNK", "TORCH_BACKENDS", "TorchBackend", "decode", "differentiable", "encode"]

#: The back ends of an identifier built from an encoder (``Identifier.with_backend``):
#: ``"auto"``, the numpy pass for one record and torch for a batch (the default); ``"torch"``,
#: torch for every call; ``"numpy"``, the numpy pass record by record.
TORCH_BACKENDS = ("auto", "torch", "numpy")

#: Records through the encoder at once in a batched call.
CHUNK = 256


def differentiable(ident, y, u, *, raw: bool = False):
    """The differentiable pass of tensors (training uses it): Eq. 15, the encoder, the
    structure and the exact de-normalisation, in torch.

    Parameters
    ----------
    ident : Identifier
    y, u : (batch, steps) tensors, or sequences of R of them
    raw : bool
        Also return the encoder's standardised outputs.

    Returns
    -------
    System, elements (batch, q) tensor[, z (batch, p) tensor]
        In measured units.
    """
    ys, us = (tuple(y), tuple(u)) if ident.records > 1 else ((y,), (u,))
    if ident.initial == "fitted":
        from aeid_struct.identification.physical_head import centred

        ys = centred(ident.structure, True, list(ys))      # as identification reads them
    y_bar = torch.stack([r.abs().amax(dim=1) for r in ys], 1)     # (batch, R)
    u_bar = torch.stack([r.abs().amax(dim=1) for r in us], 1)
    x = []
    for r, (y_r, u_r) in enumerate(zip(ys, us, strict=True)):
        channels = [2.0 * y_r / y_bar[:, r, None] - 1.0]         # Eq. 15
        if ident.inputs:
            channels.append(u_r / u_bar[:, r, None])
        x.append(torch.stack(channels, dim=1))
    features = None
    gain = y_bar / u_bar                                          # (batch, R)
    if ident.scale == "feature":
        mean, spread = (f.to(gain.device, gain.dtype) for f in ident._features)
        features = (torch.log(gain) - mean) / spread
    sys, elements, z = decode(ident, x, features)
    if ident.scale == "denormalise":
        gain = gain[:, 0]
        # Exact de-normalisation: the structure described u/u_bar -> y/y_bar (linearity).
        sys = System(sys.A, sys.b, sys.c * gain[:, None].to(sys.c.dtype),
                     sys.d * gain.to(sys.d.dtype))
        mask = ident._output_mask.to(elements.device, elements.dtype)
        elements = elements * (1.0 + mask * (gain[:, None].to(elements.dtype) - 1.0))
    return (sys, elements, z) if raw else (sys, elements)


def decode(ident, x: list, features):
    """The encoder and the structure on normalised records, before any de-normalisation.

    Parameters
    ----------
    ident : Identifier
    x : list of R (batch, channels, steps_r) tensors
        Normalised records (Eq. 15).
    features : (batch, F) tensor or None
        Standardised scale features.

    Returns
    -------
    System, elements (batch, q), z (batch, p)
        As the structure outputs them, with the encoder's standardised output ``z``.
    """
    z = ident.encoder(x[0] if ident.records == 1 else x, features)
    sys, elements = structured(ident, z)
    return sys, elements, z


def structured(ident, z: torch.Tensor) -> tuple:
    """The structure's ``System`` and ``elements (batch, q)`` of the encoder's standardised
    output ``z (batch, p)``: ``theta = theta_mean + theta_scale z``, then the structure.

    Parameters
    ----------
    ident : Identifier
    z : (batch, p) tensor

    Returns
    -------
    System, elements (batch, q)
    """
    theta = (ident.theta_mean.to(z.device, z.dtype)
             + ident.theta_scale.to(z.device, z.dtype) * z)
    elements = ident.structure.elements(theta)
    return ident.structure.assemble(elements), elements


def encode(ident, ys: list, us: list) -> tuple:
    """Float64 ``A, b, c, d, elements`` of good records through the encoder, in chunks,
    without gradients.

    Eq. 15 runs per record in float64 (``records.normalise``) and only the normalised records,
    in ``[-1, 1]``, and the standardised scale features are cast to the encoder's float32; the
    model is de-normalised in float64. So one record of 1e40 (beyond float32) or 1e-44 (below
    its normal range) among others gives what it gives alone.

    Parameters
    ----------
    ident : Identifier
    ys, us : lists of R (count, steps_r) float64 arrays
        Good records (``us`` entries may be None: a unit step).

    Returns
    -------
    A : (count, n, n) or (count, R, n, n)
    b, c : (count, n) or (count, R, n)
    d : (count,) or (count, R)
    elements : (count, q)
    """
    count = ys[0].shape[0]
    x, gain = [], np.empty((count, len(ys)))                           # gain (count, R)
    for r, (y2, u2) in enumerate(zip(ys, us, strict=True)):
        x.append(np.empty((count, 2 if ident.inputs else 1, y2.shape[1]), dtype=np.float32))
        # chunk by chunk: a chunk's float64 temporaries stay in cache and reuse their memory,
        # where a whole batch's take fresh pages from the system for each operation
        for i in range(0, count, CHUNK):
            rows = slice(i, i + CHUNK)
            y_tilde, u_tilde, y_bar, u_bar = normalise(
                y2[rows], None if u2 is None else u2[rows], inputs=ident.inputs)
            x[r][rows, 0] = y_tilde
            if ident.inputs:
                x[r][rows, 1] = u_tilde
            gain[rows, r] = y_bar / u_bar
    x = [torch.from_numpy(v) for v in x]
    features = None
    if ident.scale == "feature":
        mean, spread = (f.numpy() for f in ident._features)
        features = torch.from_numpy(((np.log(gain) - mean) / spread).astype(np.float32))
    A, b, c, d, el = _decoded(ident, x, features, count)
    if ident.scale == "denormalise":
        # Exact de-normalisation (linearity), in float64: the structure described
        # u/u_bar -> y/y_bar. A product, not el * (1 + mask (g - 1)), which is 0 for g=1e-44.
        g = gain[:, 0]
        c, d = c * g[:, None], d * g
        el = np.where(ident._output_mask.numpy()[0] > 0, el * g[:, None], el)
    return A, b, c, d, el


def _decoded(ident, x: list, features, count: int) -> tuple:
    """The structure's float64 model of normalised records ``x``, before de-normalisation."""
    # Small batches are dominated by per-operation overhead, which a second thread only adds
    # to (thread wake-ups); large ones gain from both cores.
    threads = torch.get_num_threads()
    if count <= 16 and threads > 1:
        torch.set_num_threads(1)
    try:
        with torch.no_grad():
            # The encoder in chunks (CHUNK): they keep the activations in cache and bound the
            # memory a call takes, which load (fast_path.warm) touches once; the structure's
            # few numbers per record in one pass over all (a chunk's pass is its operations'
            # overhead).
            z = torch.cat([ident.encoder(
                [v[i: i + CHUNK] for v in x] if ident.records > 1 else x[0][i: i + CHUNK],
                None if features is None else features[i: i + CHUNK])
                for i in range(0, count, CHUNK)])
            sys, el = structured(ident, z)
            return tuple(t.numpy().astype(np.float64) for t in (sys.A, sys.b, sys.c, sys.d, el))
    finally:
        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)



class TorchBackend:
    """The back end of an identifier built from its encoder (torch installed).

    Parameters
    ----------
    name : {"auto", "torch", "numpy"}
        :data:`TORCH_BACKENDS`.

    Notes
    -----
    ``"auto"`` is the fastest route by batch size: one record costs about a hundred small
    tensor operations, which the numpy pass (``fast_path.Batch1``) runs without torch's
    per-operation dispatch; a batch amortises it. Where the numpy pass does not apply (several
    records, an activation numpy lacks) ``"auto"`` runs torch and ``"numpy"`` is refused.
    """

    def __init__(self, name: str = "auto") -> None:
        if name not in TORCH_BACKENDS:
            raise ValueError(f"backend must be one of {TORCH_BACKENDS} or 'onnx'; got {name!r}")
        self.name = name

    def __repr__(self) -> str:
        return f"TorchBackend({self.name!r})"

    def check(self, ident) -> None:
        """Refuse ``"numpy"`` for an identifier without a numpy pass.

        Parameters
        ----------
        ident : Identifier

        Raises
        ------
        ValueError
            Naming why the numpy pass does not apply.
        """
        if self.name == "numpy" and fast_path(ident) is None:
            raise ValueError(f"backend 'numpy' needs a one-record identifier whose encoder "
                             f"activation numpy evaluates (tanh, relu); this one reads "
                             f"{ident.records} record(s) with activation "
                             f"{ident.encoder.config.activation!r}")

    def model(self, ident, ys: list, us: list) -> tuple:
        """Float64 ``A, b, c, d, elements`` of good records, in measured units (:func:`encode`).

        Parameters
        ----------
        ident : Identifier
        ys, us : lists of R (count, steps_r) float64 arrays

        Returns
        -------
        tuple of arrays
            As :func:`encode`.
        """
        count = ys[0].shape[0]
        if self.name == "torch" or len(ys) > 1 or (self.name == "auto" and count > 1):
            return encode(ident, ys, us)
        fast = fast_path(ident)
        if fast is None:          # "auto" where the numpy pass does not apply
            return encode(ident, ys, us)
        if count == 1:
            return fast(ys[0][0], us[0][0])          # its rows carry the batch axis
        rows = [fast(ys[0][r], us[0][r]) for r in range(count)]
        return tuple(np.concatenate(part) for part in zip(*rows, strict=True))
