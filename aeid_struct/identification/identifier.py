"""The :class:`Identifier`: a trained encoder with its structure, record format and
normalisation (Eq. 15); one forward pass identifies a system (scale modes and the several-record
identifiers: docs/architecture.md)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import torch

from aeid_struct.encoder import Encoder
from aeid_struct.estimates import Estimate, Provenance
from aeid_struct.identification import files, forward
from aeid_struct.identification.fast_path import fast_path
from aeid_struct.identification.head import Head, HeadSlot
from aeid_struct.identification.polish import polish
from aeid_struct.records import arrays_of, check_record
from aeid_struct.structures import Physical, Structure, System

__all__ = ["ERROR_MODES", "INITIAL_STATES", "SCALE_MODES", "Identifier"]

#: How the model's scale is handled: de-normalised exactly, or read as a feature.
SCALE_MODES = ("denormalise", "feature")
#: How the decoder treats a record's initial state: from rest (the paper), or fitted by least
#: squares (records that start mid-motion; ``simulation.initial_state``).
INITIAL_STATES = ("rest", "fitted")
#: What ``Identifier.identify`` does with a record it cannot identify (non-finite, all zero,
#: ...): raise (the default), or collect a reason per record and identify the good ones.
ERROR_MODES = ("raise", "collect")


def _features(name: str, value, records: int) -> np.ndarray:
    """``(records,)`` float64 from a number or one finite number per record."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.array([np.nan])
    if arr.ndim > 1 or arr.size not in (1, records) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite number or {records} of them (one per "
                         f"record); got {value!r}")
    return np.broadcast_to(arr.reshape(-1), (records,)).copy()


def _same_dt(dt, dts: tuple[float, ...]) -> bool:
    """Whether a user's ``dt`` (a number, or a sequence for several records) is ``dts``."""
    given = tuple(dt) if isinstance(dt, (tuple, list)) else (dt,)
    return len(given) == len(dts) and all(
        isinstance(g, (int, float)) and math.isclose(g, t, rel_tol=1e-9)
        for g, t in zip(given, dts, strict=True))


def _thetas(theta_mean, theta_scale, p: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``theta_mean, theta_scale`` as finite float32 ``(p,)`` tensors."""
    mean = torch.as_tensor(theta_mean, dtype=torch.float32).reshape(-1)
    scale = torch.as_tensor(theta_scale, dtype=torch.float32).reshape(-1)
    if mean.shape != (p,) or scale.shape != (p,):
        raise ValueError(f"theta_mean and theta_scale must have shape ({p},); got "
                         f"{tuple(mean.shape)}, {tuple(scale.shape)}")
    if not bool(torch.isfinite(mean).all() & torch.isfinite(scale).all()):
        raise ValueError("theta_mean and theta_scale must be finite: every estimate would be "
                         "NaN")
    return mean, scale


def _scale_features(feature_mean, feature_scale, R: int) -> tuple[np.ndarray, np.ndarray]:
    """The scale feature's standardisation, ``(R,)`` each, the spread positive."""
    fm, fs = (_features(name, v, R) for name, v in (("feature_mean", feature_mean),
                                                    ("feature_scale", feature_scale)))
    if not np.all(fs > 0):
        # the scale feature is divided by it: 0 gives inf features and NaN estimates
        raise ValueError(f"feature_scale must be positive (one per record); got "
                         f"{feature_scale!r}")
    return fm, fs


def _check_parts(encoder, structure, dt, scale: str, initial: str) -> tuple[float, ...]:
    """The constructor's checks of the parts against each other; the sample times."""
    if scale not in SCALE_MODES:
        raise ValueError(f"scale must be one of {SCALE_MODES}; got {scale!r}")
    if initial not in INITIAL_STATES:
        raise ValueError(f"initial must be one of {INITIAL_STATES}; got {initial!r}")
    if not isinstance(encoder, Encoder):
        raise ValueError(f"encoder must be an Encoder; got {type(encoder).__name__}")
    if not isinstance(structure, Structure):
        raise ValueError(f"structure must be a Structure (CCF, MCF, Physical, ...); got "
                         f"{type(structure).__name__}")
    R = encoder.config.records
    if structure.records != R:
        raise ValueError(f"the encoder reads {R} record(s) but {structure!r} describes "
                         f"{structure.records}: encoder.config.steps must have one entry "
                         "per record")
    dts = tuple(dt) if isinstance(dt, (tuple, list)) else (dt,)
    if len(dts) != R or not all(isinstance(t, (int, float)) and math.isfinite(t) and t > 0
                                for t in dts):
        raise ValueError(f"dt must be {'a positive finite number' if R == 1 else f'{R} '}"
                         f"{'' if R == 1 else 'positive finite numbers, one per record'}; "
                         f"got {dt!r}")
    if R > 1 and scale != "feature":
        raise ValueError("several records need scale='feature' (one physical parameter "
                         f"set cannot be de-normalised per record); got {scale!r}")
    if encoder.config.outputs != structure.p:
        raise ValueError(f"encoder.config.outputs must equal structure.p = {structure.p}; "
                         f"got {encoder.config.outputs}")
    if scale == "feature" and encoder.config.features != R:
        raise ValueError(f"scale='feature' needs an encoder with features={R} (one scale "
                         f"per record); got features={encoder.config.features}")
    return tuple(float(t) for t in dts)


def _provenance_of(ident) -> Provenance:
    """The Provenance of an identifier's estimates."""
    inverse = (("elements", tuple(ident.structure.element_names))
               if isinstance(ident.structure, Physical) else ident.inverse)
    return Provenance(structure=ident.structure, inverse=inverse, initial=ident.initial,
                      training_range=ident.training_range)


def _range_of(rng) -> dict | None:
    """The training range of ``meta["training_range"]`` with tuples for its triples."""
    if not rng:
        return None
    return {g: ({k: tuple(v) for k, v in rng[g].items()} if isinstance(rng[g], dict)
                else rng[g]) for g in rng}


def _cached_provenance(ident) -> Provenance:
    """``ident``'s Provenance, rebuilt only when one of its sources is another object."""
    sources = (ident.structure, ident.inverse, ident.initial,
               ident.meta.get("training_range"))
    cached = ident._provenance
    if cached is None or any(a is not b for a, b in zip(cached[0], sources, strict=True)):
        cached = ident._provenance = (sources, _provenance_of(ident))
    return cached[1]


def _check_call(ident, dt, refine, errors: str) -> None:
    """``Identifier.identify``'s options: ``refine``, ``errors``, and a ``dt`` that must be the
    identifier's."""
    if refine not in (True, False, "auto"):
        raise ValueError(f"refine must be True, False or 'auto'; got {refine!r}")
    if errors not in ERROR_MODES:
        raise ValueError(f"errors must be one of {ERROR_MODES}; got {errors!r}")
    if dt is not None and not _same_dt(dt, ident._dts):
        raise ValueError(f"dt must be {ident.dt} s for this identifier (trained on records of "
                         f"{ident.steps} samples at dt={ident.dt}); got dt={dt!r}")
    if refine and ident.records > 1:
        raise ValueError("refine=True is not available for a several-record identifier: "
                         "the refinement fits one record; refine each subsystem's estimate "
                         "in its own structure")


def _output_mask(structure: Structure) -> torch.Tensor:
    """``(1, q)``: 1 for the elements that scale with the output (``c_i``, ``d``), 0 elsewhere."""
    return torch.tensor([[1.0 if (k == "d" or (k[0] == "c" and k[1:].isdigit())) else 0.0
                          for k in structure.element_names]])


class Identifier:
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

    def __init__(self, encoder: Encoder, structure: Structure, *, dt,
                 theta_mean: torch.Tensor, theta_scale: torch.Tensor,
                 scale: str = "denormalise", feature_mean=0.0,
                 feature_scale=1.0, inverse=None, meta: dict | None = None,
                 initial: str = "rest", head: Head | None = None):
        self._dts = _check_parts(encoder, structure, dt, scale, initial)
        R = encoder.config.records
        self.encoder, self.structure, self.scale, self.initial = encoder, structure, scale, initial
        #: Sample time (a tuple, one per record, for several records).
        self.dt = self._dts[0] if R == 1 else self._dts
        self.theta_mean, self.theta_scale = _thetas(theta_mean, theta_scale, structure.p)
        fm, fs = _scale_features(feature_mean, feature_scale, R)
        self.feature_mean = float(fm[0]) if R == 1 else tuple(fm.tolist())
        self.feature_scale = float(fs[0]) if R == 1 else tuple(fs.tolist())
        self._features = (torch.from_numpy(fm), torch.from_numpy(fs))   # (R,) each
        self.inverse = inverse
        self.meta = dict(meta or {})
        self._fast_path = None                      # (weight versions, Batch1 or None)
        self._provenance = None                     # (its sources, Provenance)
        self._params = list(encoder.parameters())   # cached: walking the modules is slow
        self._output_mask = _output_mask(structure)
        self.head = head

    # -- the record format ---------------------------------------------------------------------
    @property
    def steps(self):
        """Samples per record (a tuple, one per record, for several records)."""
        return self.encoder.config.steps

    @property
    def records(self) -> int:
        """Records read together (1, or ``R`` for a several-record structure)."""
        return self.encoder.config.records

    @property
    def inputs(self) -> bool:
        """Whether the encoder reads the input record (arbitrary excitation)."""
        return self.encoder.config.inputs

    @property
    def training_range(self) -> dict | None:
        """``{"elements": {name: (lo, hi, err)}, "physical": {...}, "fit": f, "excess": e}``
        recorded by ``train`` (``Estimate.outside``), or None."""
        return _range_of(self.meta.get("training_range"))

    @property
    def provenance(self) -> Provenance:
        """What this identifier's estimates refer to (one object, shared by its estimates;
        rebuilt only when the structure, inverse, initial mode or training range changes)."""
        return _cached_provenance(self)

    def time(self):
        """Sample instants ``t_k = k*dt``.

        Returns
        -------
        (steps,) array, or a tuple of R of them for several records
        """
        grids = tuple(np.arange(s) * t for s, t in zip(self.encoder.config.record_steps,
                                                       self._dts, strict=True))
        return grids[0] if self.records == 1 else grids

    def __repr__(self) -> str:
        return (f"Identifier({self.structure!r}, dt={self.dt}, steps={self.steps}, "
                f"inputs={self.inputs}, scale={self.scale!r})")

    # -- the differentiable path (training uses it) --------------------------------------------
    def system(self, y, u) -> System:
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
        return forward.differentiable(self, y, u, raw=raw)

    def _decode(self, x: list, features):
        """Normalised records ``x`` (one ``(batch, channels, steps_r)`` tensor per record) and
        scale ``features`` -> ``(System, elements, z)`` as the structure outputs them (before
        any de-normalisation), with the encoder's standardised output ``z (batch, p)``."""
        z = self.encoder(x[0] if self.records == 1 else x, features)
        theta = self.theta_mean.to(z.device, z.dtype) + self.theta_scale.to(z.device, z.dtype) * z
        elements = self.structure.elements(theta)
        return self.structure.assemble(elements), elements, z

    def _fast(self):
        """The batch-1 path (``fast_path.Batch1``), or None where it does not apply."""
        return fast_path(self)

    # -- public identification -----------------------------------------------------------------
    def identify(self, y, u=None, *, dt: float | None = None,
                 refine: bool | str = False, errors: str = "raise") -> Estimate:
        """Identify the system behind a record in one encoder pass.

        Records are normalised (Eq. 15) per record in float64 before the encoder's float32,
        and the model is de-normalised in float64, so a record's estimate does not depend on
        the other records of its batch, whatever their magnitudes.

        Parameters
        ----------
        y : Record, (steps,) or (batch, steps) array, or a sequence of R of them
            A measured ``records.Record`` (one output, one input, no input delay; a sequence of
            ``R`` Records for a several-record identifier), which carries ``u`` and ``dt``;
            or the measured output, ``batch >= 1``, sampled at ``t_k = k*dt`` from rest (or
            mid-motion for ``initial="fitted"``); real numbers (a complex array is refused).
            A sequence of ``R`` records (one per subsystem, each on its own grid) for a
            several-record identifier.
        u : like y, (steps,) for a whole batch, or None
            Input; None is a unit step, what step-trained identifiers expect.
        dt : float or tuple, optional
            The record's sample time, checked against the identifier's.
        refine : {False, True, "auto"}
            Polish the estimate with a CasADi NLP in the same structure
            (``aeid_struct.refinement``): True for every record, ``"auto"`` for exactly the
            records flagged ``outside`` the training range (``info["refined_rows"]``). With a
            ``head``, True iterates the head to convergence instead (``info["refine"]`` is
            ``"separable"``): the least-squares optimum in the head's structure, batched.
        errors : {"raise", "collect"}
            A record that cannot be identified (non-finite samples, an all-zero ``y`` or ``u``,
            a varying ``u`` for an identifier that does not read it, ``max|y| / max|u|`` beyond
            float64): ``"raise"`` raises a ``records.RecordError`` (a ValueError) for the first;
            ``"collect"`` identifies the good records as a batch of only them would be, gives
            the bad ones NaN model rows and their reasons in ``Estimate.errors`` (flagged
            ``outside`` where the range is known). A malformed argument (wrong shape, complex,
            no records) raises in both modes.

        Returns
        -------
        Estimate
            Batched when ``y`` is.
        """
        start = time.perf_counter()
        y, u, dt = arrays_of(y, u, dt, what="Identifier.identify", records=self.records)
        _check_call(self, dt, refine, errors)
        record = check_record(y, u, steps=self.steps, dt=self.dt, reads_u=self.inputs)
        if refine is True and self.head is not None:
            return forward.refine_with_head(self, record, start, errors, self.head.converged(),
                                            self.provenance)
        est = forward.identify_record(self, record, start, errors, provenance=self.provenance)
        return polish(est, refine) if refine else est

    # -- files ---------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The JSON header: everything but the weights (``files.header``).

        Returns
        -------
        dict
        """
        return files.header(self)

    def save(self, path) -> Path:
        """Write the identifier to ``path`` (safetensors: weights + JSON header).

        Parameters
        ----------
        path : str or PathLike

        Returns
        -------
        Path
        """
        return files.save(self, path)

    @classmethod
    def load(cls, path, *, maps: dict | None = None, trust: bool = False) -> Identifier:
        """Read an identifier written by ``save``. Parses JSON and raw tensors only.

        Parameters
        ----------
        path : str or PathLike
            The ``.aeid`` file.
        maps : dict name -> casadi.Function, optional
            The user maps the file names (a ``Physical`` structure's map or an inverse that is
            not a named map of ``aeid_struct.structures.maps``), passed again; each must have
            the SHA-256 the file recorded.
        trust : bool
            Deserialise the user maps, and the CasADi Functions of files in the format before
            named maps (``FORMAT_1``), from the file itself. A serialised CasADi Function can
            run shell commands when it is read: only for files you trust.

        Returns
        -------
        Identifier

        Raises
        ------
        ValueError
            Naming the file and what is wrong: not an identifier file, a corrupted header or
            weights, or a map the file cannot name without ``maps``/``trust``.
        """
        return files.load(cls, path, maps=maps, trust=trust)
