"""The :class:`~aeid_struct.identification.Identifier`'s checks of its parts and of a call,
and the provenance its estimates share: what its constructor and ``identify`` check once at the
boundary (no torch at import: an identifier read from an ONNX export uses them too)."""

from __future__ import annotations

import math

import numpy as np

from aeid_struct.estimates import Provenance
from aeid_struct.structures import Described, type_of

__all__ = ["ERROR_MODES", "INITIAL_STATES", "SCALE_MODES", "cached_provenance", "check_call",
           "check_parts", "needs_weights", "output_elements", "output_mask", "range_of",
           "scale_features", "set_format", "thetas"]

#: How the model's scale is handled: de-normalised exactly, or read as a feature.
SCALE_MODES = ("denormalise", "feature")
#: How the decoder treats a record's initial state: from rest (the paper), or fitted by least
#: squares (records that start mid-motion; ``simulation.initial_state``).
INITIAL_STATES = ("rest", "fitted")
#: What ``Identifier.identify`` does with a record it cannot identify (non-finite, all zero,
#: ...): raise (the default), or collect a reason per record and identify the good ones.
ERROR_MODES = ("raise", "collect")


def per_record(name: str, value, records: int) -> np.ndarray:
    """``(records,)`` float64 from a number or one finite number per record."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.array([np.nan])
    if arr.ndim > 1 or arr.size not in (1, records) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite number or {records} of them (one per "
                         f"record); got {value!r}")
    return np.broadcast_to(arr.reshape(-1), (records,)).copy()


def same_dt(dt, dts: tuple[float, ...]) -> bool:
    """Whether a user's ``dt`` (a number, or a sequence for several records) is ``dts``."""
    given = tuple(dt) if isinstance(dt, (tuple, list)) else (dt,)
    return len(given) == len(dts) and all(
        isinstance(g, (int, float)) and math.isclose(g, t, rel_tol=1e-9)
        for g, t in zip(given, dts, strict=True))


def thetas(theta_mean, theta_scale, p: int) -> tuple:
    """``theta_mean, theta_scale`` as finite float32 ``(p,)`` tensors."""
    import torch

    mean = torch.as_tensor(theta_mean, dtype=torch.float32).reshape(-1)
    scale = torch.as_tensor(theta_scale, dtype=torch.float32).reshape(-1)
    if mean.shape != (p,) or scale.shape != (p,):
        raise ValueError(f"theta_mean and theta_scale must have shape ({p},); got "
                         f"{tuple(mean.shape)}, {tuple(scale.shape)}")
    if not bool(torch.isfinite(mean).all() & torch.isfinite(scale).all()):
        raise ValueError("theta_mean and theta_scale must be finite: every estimate would be "
                         "NaN")
    return mean, scale


def scale_features(feature_mean, feature_scale, R: int) -> tuple[np.ndarray, np.ndarray]:
    """The scale feature's standardisation, ``(R,)`` each, the spread positive."""
    fm, fs = (per_record(name, v, R) for name, v in (("feature_mean", feature_mean),
                                                    ("feature_scale", feature_scale)))
    if not np.all(fs > 0):
        # the scale feature is divided by it: 0 gives inf features and NaN estimates
        raise ValueError(f"feature_scale must be positive (one per record); got "
                         f"{feature_scale!r}")
    return fm, fs


def check_parts(encoder, structure, dt, scale: str, initial: str) -> tuple[float, ...]:
    """The constructor's checks of the parts against each other; the sample times."""
    from aeid_struct.encoder import Encoder
    from aeid_struct.structures import Structure

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


def provenance_of(ident) -> Provenance:
    """The Provenance of an identifier's estimates."""
    if ident.physical_elements:      # elements that are physical parameters (an export's)
        inverse = ("elements", tuple(ident.physical_elements))
    elif type_of(ident.structure) == "Physical":
        inverse = ("elements", tuple(ident.structure.element_names))
    else:
        inverse = ident.inverse
    return Provenance(structure=ident.structure, inverse=inverse, initial=ident.initial,
                      training_range=ident.training_range)


def range_of(rng) -> dict | None:
    """The training range of ``meta["training_range"]`` with tuples for its triples."""
    if not rng:
        return None
    return {g: ({k: tuple(v) for k, v in rng[g].items()} if isinstance(rng[g], dict)
                else rng[g]) for g in rng}


def cached_provenance(ident) -> Provenance:
    """``ident``'s Provenance, rebuilt only when one of its sources is another object."""
    sources = (ident.structure, ident.inverse, ident.initial,
               ident.meta.get("training_range"))
    cached = ident._provenance
    if cached is None or any(a is not b for a, b in zip(cached[0], sources, strict=True)):
        cached = ident._provenance = (sources, provenance_of(ident))
    return cached[1]


def check_call(ident, dt, refine, errors: str, starts: int = 0) -> None:
    """``Identifier.identify``'s options: ``refine``, ``errors``, ``starts``, and a ``dt`` that
    must be the identifier's."""
    if refine not in (True, False, "auto"):
        raise ValueError(f"refine must be True, False or 'auto'; got {refine!r}")
    if isinstance(starts, bool) or not isinstance(starts, (int, np.integer)) or starts < 0:
        raise ValueError(f"starts must be an integer >= 0; got {starts!r}")
    if starts and (refine is not True or type_of(ident.structure) != "Physical"):
        raise ValueError(f"starts={starts} needs refine=True and a physical structure (the "
                         f"starts are points of its parameters' box); got refine={refine!r} "
                         f"and a {type_of(ident.structure)} structure")
    if errors not in ERROR_MODES:
        raise ValueError(f"errors must be one of {ERROR_MODES}; got {errors!r}")
    if dt is not None and not same_dt(dt, ident._dts):
        what = "export" if ident.backend.name == "onnx" else "identifier"
        raise ValueError(f"dt must be {ident.dt} s for this {what} (trained on records of "
                         f"{ident.steps} samples at dt={ident.dt}); got dt={dt!r}")
    if refine and not (refine is True and ident.head is not None) and isinstance(
            ident.structure, Described):
        # the CasADi NLP assembles the structure itself (torch); the head needs only its
        # description
        raise ValueError(f"refine={refine!r} needs torch installed: the CasADi refinement "
                         "assembles the structure, which this identifier (an ONNX export "
                         "read without torch) knows by its description only; install torch, "
                         "or export an identifier with a head (refine=True then iterates it)")
    if refine and ident.records > 1 and type_of(ident.structure) != "Physical":
        raise ValueError("refine=True is not available for a several-record identifier: "
                         "the refinement fits one record; refine each subsystem's estimate "
                         "in its own structure")


def output_elements(names) -> np.ndarray:
    """``(q,)`` bool: the elements that scale with the output (``c_i``, ``d``), which the exact
    de-normalisation multiplies by ``max|y| / max|u|`` (Eq. 15 and linearity)."""
    return np.array([k == "d" or (k[0] == "c" and k[1:].isdigit()) for k in names], dtype=bool)


def output_mask(structure):
    """``(1, q)`` float tensor of :func:`output_elements` (the torch back end's mask)."""
    import torch

    return torch.from_numpy(output_elements(structure.element_names)[None].astype(np.float32))


def set_format(ident, structure, dts: tuple, record_format: tuple, *, scale, initial,
                inverse, meta) -> None:
    """Set the attributes every back end of an identifier shares: structure, sample times
    ``dts``, record format ``(steps, records, inputs)``, scale mode, initial state, inverse map,
    training metadata, and empty caches (the constructor and ``Identifier.from_onnx``)."""
    ident.structure, ident.scale, ident.initial = structure, scale, initial
    ident._dts = dts
    ident._format = record_format
    ident.dt = dts[0] if len(dts) == 1 else dts
    ident.inverse = inverse
    ident.meta = dict(meta or {})
    ident._fast_path = None                      # (weight versions, Batch1 or None)
    ident._provenance = None                     # (its sources, Provenance)


def needs_weights(ident, what: str) -> None:
    """Refuse ``what`` on an identifier read from an ONNX export (no encoder weights)."""
    if ident.backend.name == "onnx":
        raise ValueError(f"{what} needs the identifier's encoder weights; this one was "
                         "read from an ONNX export (backend 'onnx'): load the .aeid file "
                         "it was exported from")
