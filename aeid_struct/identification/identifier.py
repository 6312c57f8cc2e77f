"""The :class:`Identifier`: a trained encoder with its structure, record format and
normalisation (Eq. 15); one forward pass identifies a system (scale modes and the several-record
identifiers: docs/architecture.md).

One class, several back ends (``Identifier.backend``): the torch encoder (batched, and the
differentiable pass of training), its numpy pass for one record, or the ONNX graph of an export
run by onnxruntime (:meth:`Identifier.from_onnx`). Every back end walks the same checks, head and
result (``one_pass``); this module imports no torch, so that an identifier read from an ONNX
export runs where torch is not installed."""

from __future__ import annotations

import copy
import time

import numpy as np

from aeid_struct.estimates import Estimate, Provenance
from aeid_struct.identification import one_pass
from aeid_struct.identification.checks import ERROR_MODES as ERROR_MODES
from aeid_struct.identification.checks import INITIAL_STATES as INITIAL_STATES
from aeid_struct.identification.checks import SCALE_MODES as SCALE_MODES
from aeid_struct.identification.checks import (
    cached_provenance,
    check_call,
    check_parts,
    needs_weights,
    output_mask,
    range_of,
    scale_features,
    set_format,
    thetas,
)
from aeid_struct.identification.head import Head, HeadSlot, refine_route
from aeid_struct.identification.identifier_files import IdentifierFiles
from aeid_struct.records import arrays_of, check_record

__all__ = ["ERROR_MODES", "INITIAL_STATES", "SCALE_MODES", "Identifier"]


class Identifier(IdentifierFiles):
    """A trained encoder with its structure, record format and normalisation.

    Parameters
    ----------
    encoder : Encoder
        The network (its config fixes ``steps`` and the input channels).
    structure : Structure
        Maps raw parameters to ``(A, b, c, d)`` with its constraints.
    dt : float or tuple of R floats
        Sample time the identifier was trained for (one per record for a several-record
        structure).
    theta_mean, theta_scale : (p,) tensors
        Affine map of the network output to raw parameters, ``theta = mean + scale * net``.
    scale : {"denormalise", "feature"}
        Exact de-normalisation of ``c, d`` by ``max|y| / max|u|``, or ``log(max|y| / max|u|)``
        as an encoder feature (docs/architecture.md).
    feature_mean, feature_scale : float or tuple of R floats
        Standardisation of the scale feature (``"feature"``).
    inverse : casadi.Function, optional
        From the CCF model to physical parameters.
    meta : dict, optional
        Provenance of the training (command, seed, metrics, training range), stored in the file.
    initial : {"rest", "fitted"}
        Records start from rest (the paper), or mid-motion (the initial state is fitted by least
        squares).
    head : Head, optional
        The separable head after the encoder; None: the paper's pass, the encoder alone.
    """

    head = HeadSlot()            # may be set or cleared later; checked whenever it is set

    #: Elements that are physical parameters (an export's ``physical_elements``), or None.
    physical_elements: tuple | None = None

    def __init__(self, encoder, structure, *, dt, theta_mean, theta_scale,
                 scale: str = "denormalise", feature_mean=0.0,
                 feature_scale=1.0, inverse=None, meta: dict | None = None,
                 initial: str = "rest", head: Head | None = None):
        import torch

        from aeid_struct.identification.forward import TorchBackend

        dts = check_parts(encoder, structure, dt, scale, initial)
        cfg = encoder.config
        set_format(self, structure, dts, (cfg.steps, cfg.records, cfg.inputs), scale=scale,
                   initial=initial, inverse=inverse, meta=meta)
        R = cfg.records
        self.encoder = encoder
        self.theta_mean, self.theta_scale = thetas(theta_mean, theta_scale, structure.p)
        fm, fs = scale_features(feature_mean, feature_scale, R)
        self.feature_mean = float(fm[0]) if R == 1 else tuple(fm.tolist())
        self.feature_scale = float(fs[0]) if R == 1 else tuple(fs.tolist())
        self._features = (torch.from_numpy(fm), torch.from_numpy(fs))   # (R,) each
        self._params = list(encoder.parameters())   # cached: walking the modules is slow
        self._output_mask = output_mask(structure)
        #: What runs the encoder pass (``with_backend``): a ``TorchBackend`` here.
        self.backend = TorchBackend("auto")
        self.head = head

    def with_backend(self, name: str, *, threads: int = 1) -> Identifier:
        """This identifier on another back end (a shallow copy; ``self`` is not changed).

        Parameters
        ----------
        name : {"auto", "torch", "numpy", "onnx"}
            ``"auto"`` (the default of an identifier built from its encoder): the numpy pass
            for one record, torch for a batch; ``"torch"``: torch for every call;
            ``"numpy"``: the numpy pass, record by record; ``"onnx"``: the identifier exported
            to an ONNX graph (``online.onnx_bytes``, in memory) and run by onnxruntime.
        threads : int
            onnxruntime's intra-op threads (``"onnx"``; an export read keeps its own).

        Returns
        -------
        Identifier
            The same model: ``"auto"`` is bit for bit ``"numpy"`` for one record and
            ``"torch"`` for a batch; the numpy pass (float64) and torch (float32) agree to
            float32 precision, as ``"onnx"`` (float32) does.

        Raises
        ------
        ValueError
            An unknown name; a back end this identifier cannot run (``"numpy"`` without its
            numpy pass, ``"onnx"`` for an identifier that cannot be exported, or any back end
            but ``"onnx"`` for an identifier read from an export).
        """
        if name == "onnx":
            if self.backend.name == "onnx":
                return self
            from aeid_struct.identification.export import onnx_bytes
            from aeid_struct.identification.onnx_backend import check_onnx_runtime, export_backend

            check_onnx_runtime(threads)
            twin = copy.copy(self)
            twin.backend = export_backend(onnx_bytes(self), self, threads)
            return twin
        if self.backend.name == "onnx":
            raise ValueError(f"backend must be 'onnx' for an identifier read from an ONNX "
                             f"export (it has no encoder weights); got {name!r}")
        from aeid_struct.identification.forward import TorchBackend

        backend = TorchBackend(name)
        backend.check(self)
        twin = copy.copy(self)
        twin.backend = backend
        return twin

    # -- the record format ---------------------------------------------------------------------
    @property
    def steps(self):
        """Samples per record (a tuple, one per record, for several records)."""
        return self._format[0]

    @property
    def records(self) -> int:
        """Records read together (1, or ``R`` for a several-record structure)."""
        return self._format[1]

    @property
    def inputs(self) -> bool:
        """Whether the encoder reads the input record (arbitrary excitation)."""
        return self._format[2]

    @property
    def training_range(self) -> dict | None:
        """``{"elements": {name: (lo, hi, err)}, "physical": {...}, "fit": f, "excess": e}``
        recorded by ``train`` (``Estimate.outside``), or None."""
        return range_of(self.meta.get("training_range"))

    @property
    def provenance(self) -> Provenance:
        """What this identifier's estimates refer to (one object, shared by its estimates;
        rebuilt only when the structure, inverse, initial mode or training range changes)."""
        return cached_provenance(self)

    def time(self):
        """Sample instants ``t_k = k*dt``.

        Returns
        -------
        (steps,) array, or a tuple of R of them for several records
        """
        steps = self.steps if isinstance(self.steps, tuple) else (self.steps,)
        grids = tuple(np.arange(s) * t for s, t in zip(steps, self._dts, strict=True))
        return grids[0] if self.records == 1 else grids

    def __repr__(self) -> str:
        backend = "" if self.backend.name == "auto" else f", backend={self.backend.name!r}"
        return (f"Identifier({self.structure!r}, dt={self.dt}, steps={self.steps}, "
                f"inputs={self.inputs}, scale={self.scale!r}{backend})")

    # -- the differentiable path (training uses it) --------------------------------------------
    def system(self, y, u):
        """The identified system of checked records, ``forward(y, u)[0]``.

        Parameters
        ----------
        y, u : (batch, steps) tensors, or sequences of R of them

        Returns
        -------
        System
        """
        return self.forward(y, u)[0]

    def forward(self, y, u, *, raw: bool = False):
        """The differentiable encoder pass, in measured units.

        Parameters
        ----------
        y, u : (batch, steps) tensors, or sequences of R of them
            Checked by the caller.
        raw : bool
            Also return the encoder's standardised outputs.

        Returns
        -------
        (System, elements (batch, q)), or (System, elements, z (batch, p)) with ``raw``
        """
        from aeid_struct.identification.forward import differentiable

        needs_weights(self, "forward")
        return differentiable(self, y, u, raw=raw)

    def _fast(self):
        """The batch-1 path (``fast_path.Batch1``), or None where it does not apply."""
        from aeid_struct.identification.fast_path import fast_path

        return fast_path(self)

    # -- public identification -----------------------------------------------------------------
    def identify(self, y, u=None, *, dt: float | None = None,
                 refine: bool | str = False, errors: str = "raise",
                 starts: int = 0) -> Estimate:
        """Identify the system behind a record in one encoder pass.

        Records are normalised (Eq. 15) per record in float64 before the encoder's float32,
        and the model is de-normalised in float64, so a record's estimate does not depend on
        the other records of its batch, whatever their magnitudes.

        Parameters
        ----------
        y : Record, (steps,) or (batch, steps) array, or a sequence of R of them
            A measured ``records.Record`` (one output, one input, no input delay; ``R`` Records,
            or one of several outputs split by ``structure.channels``, for ``R`` records),
            which carries ``u`` and ``dt``; or the measured output, ``batch >= 1``, sampled at
            ``t_k = k*dt`` from rest (or mid-motion for ``initial="fitted"``); real numbers. A
            sequence of ``R`` of them (one per subsystem, on its own grid) for ``R`` records.
        u : like y, (steps,) for a whole batch, or None
            Input; None is a unit step, what step-trained identifiers expect.
        dt : float or tuple, optional
            The record's sample time, checked against the identifier's.
        refine : {False, True, "auto"}
            Polish the estimate in the same structure (``aeid_struct.refinement``'s CasADi
            NLP): every record, or ``"auto"``: those flagged ``outside`` the training range
            (``info["refined_rows"]``). With a ``head``, True iterates it to convergence
            (``info["refine"]``: ``"separable"``; ``identification.polish`` says when not);
            a physical structure of one record whose map is not square then fits its
            parameters from there (``head.refine_route``).
        errors : {"raise", "collect"}
            A record that cannot be identified (non-finite samples, an all-zero ``y`` or ``u``,
            a varying ``u`` for an identifier that does not read it, ``max|y| / max|u|`` beyond
            float64): ``"raise"`` raises a ``records.RecordError`` (a ValueError) for the first;
            ``"collect"`` identifies the good records as a batch of only them would be, gives
            the bad ones NaN model rows and their reasons in ``Estimate.errors`` (flagged
            ``outside`` where the range is known). A malformed argument (wrong shape, complex,
            no records) raises in both modes.
        starts : int, >= 0
            With ``refine=True``, a physical structure: more starts in its box (``multistart``).

        Returns
        -------
        Estimate
            Batched when ``y`` is.
        """
        start = time.perf_counter()
        y, u, dt = arrays_of(y, u, dt, what="Identifier.identify", records=self.records,
                             channels=getattr(self.structure, "channels", None))
        check_call(self, dt, refine, errors, starts)
        provenance = self.provenance
        record = check_record(y, u, steps=self.steps, dt=self.dt, reads_u=self.inputs)
        est = _identified(self, record, start, errors, refine, provenance)
        return _from_starts(est, starts) if starts else est


def _identified(ident: Identifier, record, start: float, errors: str, refine,
                provenance) -> Estimate:
    """``Identifier.identify`` after its checks: the one pass, and the refinement asked for."""
    head = ident.head
    route = refine_route(ident) if refine is True and head is not None else "one pass"
    if route == "head":
        return one_pass.refine_with_head(ident, record, start, errors, head.converged(),
                                         provenance)
    if route == "converged head":
        est = one_pass.identify_record(ident, record, start, errors, head.converged(),
                                       provenance)
        return one_pass.no_worse_than_one_pass(ident, record, start, provenance,
                                               _polished(est, True))
    est = one_pass.identify_record(ident, record, start, errors, provenance=provenance)
    return _polished(est, refine) if refine else est


def _polished(est: Estimate, refine) -> Estimate:
    """``identify(refine=...)`` through ``polish.polish`` (imported on first use: it needs the
    refinement, and an ONNX export read without torch never refines)."""
    from aeid_struct.identification.polish import polish

    return polish(est, refine)


def _from_starts(est: Estimate, starts: int) -> Estimate:
    """``identify(refine=True, starts=k)``: ``multistart.from_starts``."""
    from aeid_struct.identification.multistart import from_starts

    return from_starts(est, starts)
