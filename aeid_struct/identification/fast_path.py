"""The batch-1 forward pass: one record through an identifier without per-operation torch
overhead (the encoder in numpy, the structure as one CasADi expression graph evaluated in
numpy memory, or a frozen TorchScript trace where a structure has no CasADi assembly)."""

from __future__ import annotations

import warnings

import casadi
import numpy as np
import torch

from aeid_struct.encoder import NumpyEncoder
from aeid_struct.records import denormalise
from aeid_struct.structures import Numeric, Physical, expanded

__all__ = ["Batch1", "fast_path", "warm"]

class Batch1:
    """One record through the identifier without per-operation torch overhead.

    The encoder is the one numpy pass of one record (``encoder.NumpyEncoder.one``, in the
    weights' float32 and numpy's activations, ``theta`` in float64); the structure (theta ->
    elements -> A, b, c, d) is one CasADi Function of ``theta``
    (``ElementSet.casadi_elements`` and ``Structure.casadi_system``, SX where they expand, one
    output vector) evaluated through its buffer (``structures.Numeric``): one call of compiled
    SX instructions, where a TorchScript trace pays its interpreter's dispatch per operation;
    the trace remains for a structure without a CasADi assembly. A physical structure maps its
    elements by the head's expanded SX map (``physical_head.PhysicalHead``). A call ``(y
    (steps,), u (steps,) or None)`` returns float64 ``A (1, n, n), b, c (1, n), d (1,),
    elements (1, q)``, in measured units like ``Identifier.system``.

    Parameters
    ----------
    ident : Identifier
        A single-record identifier whose encoder has a numpy activation (tanh, relu).
    """

    def __init__(self, ident):
        # the one numpy pass in numpy's own activations (ValueError for others) and the
        # weights' float32, as the network was trained and the eager pass runs it (float64
        # would double the bytes the dense layers read for nothing the weights hold);
        # theta = theta_mean + theta_scale * z folded into the last layer, in float64
        self.net = NumpyEncoder(ident.encoder, activation="numpy",
                                affine=(ident.theta_mean.double().numpy(),
                                        ident.theta_scale.double().numpy()))
        self.cfg = ident.encoder.config
        self.ident = ident
        self.output = ident._output_mask.numpy()[0] > 0     # the elements scaled by y_bar/u_bar
        structure = ident.structure
        self.physical = self.map = None
        theta = casadi.SX.sym("theta", structure.p)
        elements = structure.casadi_elements(theta)
        if isinstance(structure, Physical):
            # elements -> (A, B, C, D) by the head's expanded SX map in numpy
            # (physical_head.PhysicalHead.model): microseconds, where the torch op that carries
            # CasADi's derivatives for training costs about half a millisecond
            from aeid_struct.identification.physical_head import physical_head

            self.physical = physical_head(structure, ident.initial == "fitted")
            self.elements = Numeric(casadi.Function("elements", [theta], [elements]))
            return
        try:
            A, b, c, d = structure.casadi_system(elements)
        except NotImplementedError:
            A = None
        if A is not None:
            # one output vector (vec A, b, c, d, elements): one result pointer to set per call
            self.n = n = structure.n
            self.split = np.cumsum([n * n, n, n, 1])
            self.map = Numeric(expanded(casadi.Function("structure", [theta], [casadi.vertcat(
                casadi.vec(A), b, c, d, elements)])))
            return

        class _Structure(torch.nn.Module):
            def forward(self, theta):
                el = structure.elements(theta)
                sys = structure.assemble(el)
                return sys.A, sys.b, sys.c, sys.d, el

        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            self.structure = torch.jit.freeze(torch.jit.trace(
                _Structure().eval(), (torch.zeros(1, structure.p, dtype=torch.float64),),
                check_trace=False))

    def __call__(self, y: np.ndarray, u: np.ndarray | None):
        # Eq. 15 with records.normalise's arithmetic on one (steps,) record, and below the
        # de-normalisation's products in place (records.denormalise's): the batched helpers'
        # extra axes, temporaries and errstate cost about 5 of this path's 45 us
        y_bar = np.abs(y).max()
        # an identifier that does not read u takes a constant step only (records.check_record
        # refuses another): its height is any sample's, no reduction over the record
        u_bar = 1.0 if u is None else abs(float(u[0])) if not self.cfg.inputs else np.abs(
            u).max()
        gain = y_bar / u_bar
        y_tilde = 2.0 * (y / y_bar) - 1.0
        if self.cfg.inputs:
            x = np.empty((2, y.size))
            x[0] = y_tilde
            np.divide(1.0 if u is None else u, u_bar, out=x[1])
        else:
            x = y_tilde[None]
        features = None
        if self.cfg.features:
            ident = self.ident
            features = (np.log(gain) - ident.feature_mean) / ident.feature_scale
        theta = self.net.one(x, features)
        if self.map is not None:
            flat = self.map(theta)[0]
            n, split = self.n, self.split
            if self.ident.scale == "denormalise":
                # records.denormalise's products, in place in the map's new vector
                flat[split[1] : split[3]] *= gain
                np.multiply(flat[split[3] :], gain, out=flat[split[3] :], where=self.output)
            A = flat[: n * n].reshape(1, n, n, order="F")
            return (A, flat[split[0] : split[1]][None], flat[split[1] : split[2]][None],
                    flat[split[2] : split[3]], flat[split[3] :][None])
        if self.physical is not None:
            A, b, c, d, el = self._physical(theta)
        else:
            with torch.no_grad():
                A, b, c, d, el = (t.numpy() for t in self.structure(
                    torch.from_numpy(theta[None])))
        if self.ident.scale == "denormalise":
            c, d, el = denormalise(c, d, el, np.array([gain]), self.output)
        return A, b, c, d, el

    def _physical(self, theta: np.ndarray) -> tuple:
        """A physical structure's ``A (1, n, n), b, c (1, n), d (1,), elements (1, q)`` of
        raw ``theta (p,)``: the structure's own element maps (``casadi_elements``, the
        bounds' intervals), then the head's numpy map."""
        el = self.elements(theta)[0]
        A, b, c, d, _ = self.physical.systems(el)[0]
        return A[None], b[None], c[None], np.array([d]), el[None]


def fast_path(ident):
    """The batch-1 path of ``ident``: a :class:`Batch1`, or None where it does not apply.

    Why: one record costs about a hundred small tensor operations, and at batch 1 PyTorch spends
    far more time dispatching them than computing. The path is rebuilt when the weights change
    (parameter version counters), compared with the eager path when it is built, and skipped
    (None) where it does not apply or does not agree.

    Parameters
    ----------
    ident : Identifier

    Returns
    -------
    Batch1 or None
    """
    if ident.records > 1:
        return None
    version = [p._version for p in ident._params]
    if ident._fast_path is not None and ident._fast_path[0] == version:
        return ident._fast_path[1]
    try:
        fast = Batch1(ident)
        ok = _agrees(ident, fast)
    except Exception:  # any structure or layer the fast path does not cover: eager path
        fast, ok = None, False
    ident._fast_path = (version, fast if ok else None)
    return ident._fast_path[1]


def _example(ident) -> tuple[torch.Tensor, torch.Tensor]:
    """A made-up record ``y, u (1, steps)``: increasing, with a varying positive input (a
    step of height 1.5 for an identifier that does not read ``u``, the only input it takes)."""
    g = torch.Generator().manual_seed(0)
    y = torch.cumsum(torch.rand(1, ident.steps, generator=g), dim=1)
    u = 0.5 + torch.rand(1, ident.steps, generator=g)
    return y, u if ident.inputs else torch.full_like(u, 1.5)


def warm(ident, chunk: int) -> None:
    """Identify a made-up record twice, so that the first call on a user's record costs what
    the next ones do.

    Why: a single-record identifier builds its batch-1 path on first use (the structure's CasADi
    graph, or a frozen TorchScript trace, which TorchScript optimises only after its first
    profiling run; and the agreement check with the eager pass, whose first torch operations
    initialise their kernels), a separable head's first FFTs and solves initialise scipy's and
    LAPACK's, and the first batched call takes its memory (a chunk's activations, ``chunk``
    records) from the system page by page. An identifier file's ``load`` runs this once (a
    record twice, then one chunk of a batch), so that none of it falls on the first
    identification. Best effort: a failure is left to that first call to report.

    Parameters
    ----------
    ident : Identifier
    chunk : int
        Records in one chunk of a batched call (``forward.CHUNK``).
    """
    if ident.records > 1:
        return
    y, u = (t.numpy()[0].astype(np.float64) for t in _example(ident))
    try:
        for _ in range(2):
            ident.identify(y, u if ident.inputs else None, errors="collect")
        # one chunk of a batch: the memory every batched call reuses, touched here
        ys = y * np.linspace(1.0, 2.0, chunk)[:, None]
        ident.identify(ys, u if ident.inputs else None, errors="collect")
    except Exception:  # noqa: S110 - warming only; the first real call raises it again
        pass


def _agrees(ident, fast: Batch1) -> bool:
    """Whether ``fast`` gives the eager path's model of a random record (to float32)."""
    y, u = _example(ident)
    was_training = ident.encoder.training
    ident.encoder.eval()
    try:
        with torch.no_grad():
            sys, el = ident.forward(y, u)
    finally:
        ident.encoder.train(was_training)
    ref = [t.double().numpy() for t in (sys.A, sys.b, sys.c, sys.d, el)]
    got = fast(y.numpy()[0].astype(np.float64), u.numpy()[0].astype(np.float64))
    return all(np.allclose(a, b, rtol=1e-4, atol=1e-6 * (1 + np.abs(a).max()))
               for a, b in zip(ref, got, strict=True))
