"""The subspace step both forms of :func:`~aeid_struct.baselines.n4sid` share: nfoursid's
PO-MOESP/N4SID on given input channels, the discrete-time model and its singular values (the
record from rest in ``subspace``, the record not at rest in ``free_initial``)."""

from __future__ import annotations

import numpy as np

__all__ = ["nfoursid_model"]


def nfoursid_model(y, channels, order, block_rows, pre_zeros):
    """nfoursid on zero-padded channels: ``Phi (n, n), B (n, m), C (p, n), D (p, m)``, and the
    leading singular values of its ``R32`` decomposition (order selection); ``y`` is
    ``(steps,)`` or ``(steps, p)``."""
    import pandas as pd
    from nfoursid.nfoursid import NFourSID

    pad = np.zeros(pre_zeros)
    names = [f"u{j}" for j in range(len(channels))]
    Y = np.asarray(y).reshape(len(y), -1)
    outputs = ["y"] if Y.shape[1] == 1 else [f"y{i}" for i in range(Y.shape[1])]
    frame = pd.DataFrame({**{nm: np.concatenate([pad, ch]) for nm, ch in zip(names, channels,
                                                                            strict=True)},
                          **{nm: np.concatenate([pad, Y[:, i]]) for i, nm in
                             enumerate(outputs)}})
    model = NFourSID(frame, output_columns=outputs, input_columns=names,
                     num_block_rows=block_rows)
    model.subspace_identification()
    ss, _ = model.system_identification(rank=order)
    sv = np.diag(model.R32_decomposition.eigenvalues)[: 2 * order + 2].copy()
    Phi, B, C, D = (np.asarray(m, dtype=np.float64) for m in (ss.a, ss.b, ss.c, ss.d))
    for name, m in (("A", Phi), ("B", B), ("C", C), ("D", D)):
        if not np.all(np.isfinite(m)):
            raise ValueError(f"identified {name} is not finite")
    return Phi, B, C, D, sv
