"""The roofline of a batched identification: the encoder's FLOPs per record against the
machine's measured fp32 matrix-product rate, at the process's threads.

``records/s * FLOPs/record`` is the rate the identification achieves on the encoder's work;
its fraction of the measured peak says how far from the hardware's limit the batched pass runs
(the rest of a pass, the normalisation, the structure and the de-normalisation, is counted as
overhead, not as work).
"""

from __future__ import annotations

import time

import torch

__all__ = ["encoder_flops", "matmul_peak"]


def matmul_peak(n: int = 1024, repeats: int = 10) -> float:
    """The fp32 rate of ``torch.mm`` of two ``(n, n)`` matrices, best of ``repeats``, at the
    process's threads, in FLOP/s (``2 n^3`` a product).

    Parameters
    ----------
    n : int
    repeats : int

    Returns
    -------
    float
    """
    g = torch.Generator().manual_seed(0)
    a = torch.rand(n, n, generator=g)
    b = torch.rand(n, n, generator=g)
    torch.mm(a, b)
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        torch.mm(a, b)
        best = min(best, time.perf_counter() - t0)
    return 2.0 * n ** 3 / best


def encoder_flops(ident, batch: int = 64) -> float:
    """FLOPs per record of an identifier's encoder (``torch.utils.flop_counter`` over its
    forward pass on a batch of records of its shape).

    Parameters
    ----------
    ident : Identifier
        With a torch ``encoder`` whose ``config`` gives ``steps`` (one record), ``inputs`` and
        ``features``.
    batch : int

    Returns
    -------
    float
    """
    from torch.utils.flop_counter import FlopCounterMode

    cfg = ident.encoder.config
    x = torch.zeros(batch, 1 + int(cfg.inputs), int(cfg.steps))
    features = torch.zeros(batch, cfg.features) if cfg.features else None
    with FlopCounterMode(display=False) as counter, torch.no_grad():
        ident.encoder(x, features)
    return counter.get_total_flops() / batch
