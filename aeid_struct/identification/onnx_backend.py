"""The ONNX back end of an identifier: the encoder pass of an export (``export.onnx_bytes``) run
by onnxruntime, read with numpy and CasADi alone (no torch).

:func:`read_onnx` reads an ``.onnx`` file (or its bytes) into an ``Identifier`` whose ``backend``
is an :class:`OnnxBackend`: the record format, structure, head and inverse map come from the
model's ``aeid`` metadata (the one container header, kind ``"onnx"``), checked against the
graph. Where torch is absent the structure is known by its description
(``structures.Described``): enough for the head and the physical parameters; an estimate's
self-check (``fit``, ``y_hat``, ``x0``) reads the numpy decoder (``simulation.simulate_numpy``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from aeid_struct.identification.container import FORMAT, kind_of, refuse_other
from aeid_struct.records import denormalise, normalise

__all__ = ["ONNX_FORMAT", "ONNX_FORMAT_1", "ONNX_FORMAT_2", "ONNX_FORMAT_3", "OnnxBackend",
           "check_onnx_runtime", "export_backend", "inverse_names", "read_onnx"]

#: The metadata format written: the one container of every identifier file (kind ``"onnx"``),
#: with the entries of ``ONNX_FORMAT_3``.
ONNX_FORMAT = FORMAT
#: The format before the container: the inverse map as a reference to a named map
#: (``structures``), and the separable head (``identification.head``) that the reader applies
#: after the graph; still read.
ONNX_FORMAT_3 = "aeid-struct-onnx-3"
#: The format before the head: read as a file without one.
ONNX_FORMAT_2 = "aeid-struct-onnx-2"
#: The format before named maps (the inverse serialised inline): read with ``trust=True``.
ONNX_FORMAT_1 = "aeid-struct-onnx-1"


def inverse_names(inverse) -> tuple[str, ...] | None:
    """The outputs of an inverse map.

    Parameters
    ----------
    inverse : casadi.Function or None
        A CCF ``(A, B, C, D)`` -> physical parameters map.

    Returns
    -------
    tuple of str or None
        Its output names; empty for no map; None for an object without ``name_out``.
    """
    if inverse is None:
        return ()
    try:
        return tuple(inverse.name_out())
    except AttributeError:
        return None


class OnnxBackend:
    """The encoder pass of an ONNX export, run by onnxruntime (``Identifier.backend``).

    Parameters
    ----------
    session : onnxruntime.InferenceSession
        The graph: ``y, u (steps,)`` float32 -> ``A, b, c, d, elements``.
    scale : {"denormalise", "feature"} or None
        How the graph handles the model's scale (None: a file written before it was
        recorded, whose graph reads ``max|y| / max|u|`` itself).
    mask : (q,) bool array
        The elements that scale with the output (``c_i``, ``d``).
    """

    name = "onnx"

    def __init__(self, session, scale, mask: np.ndarray) -> None:
        self.session, self.scale, self.mask = session, scale, mask

    def __repr__(self) -> str:
        return "OnnxBackend()"

    def model(self, ident, ys: list, us: list) -> tuple:
        """Float64 ``A, b, c, d, elements`` of good records, in measured units.

        Eq. 15 runs per record in float64 before the graph's float32: for a ``"denormalise"``
        export the graph receives ``y / max|y|`` and ``u / max|u|`` and the model is
        de-normalised in float64, so a record of 1e40 or 1e-44 gives what the torch back end
        gives. (For a ``"feature"`` export, or a file written before the scale was recorded,
        the graph reads ``max|y| / max|u|`` itself: it must lie within float32's normal range.)

        Parameters
        ----------
        ident : Identifier
        ys, us : lists of one (count, steps) float64 array

        Returns
        -------
        A (count, n, n), b, c (count, n), d (count,), elements (count, q)

        Raises
        ------
        ValueError
            A scale ratio outside float32's range where the graph reads it.
        """
        y, u = ys[0], us[0]
        _, u_unit, y_bar, u_bar = normalise(y, u)
        y_unit = y / y_bar[:, None]
        gain = y_bar / u_bar
        if self.scale == "denormalise":
            y_in, u_in = y_unit, u_unit                   # the graph sees a gain of 1
        else:
            # The graph reads log(max|y| / max|u|): split the ratio between y and u so that
            # each stays inside float32 whatever the record's own magnitude.
            bad = ~((gain > 1e-37) & (gain < 1e37))
            if bad.any():
                r = int(np.argmax(bad))
                raise ValueError(f"y and u must have a scale ratio max|y| / max|u| inside "
                                 f"float32's range for this export (its graph reads it); got "
                                 f"{gain[r]:.3g} at record {r}")
            root = np.sqrt(gain)[:, None]
            y_in, u_in = y_unit * root, u_unit / root
        rows = [self.session.run(None, {"y": y_r, "u": u_r})
                for y_r, u_r in zip(y_in.astype(np.float32), u_in.astype(np.float32),
                                    strict=True)]
        if len(rows) == 1:      # one window of a stream: no stacking
            A, b, c, d, el = (t[None].astype(np.float64) for t in rows[0])
        else:
            A, b, c, d, el = (np.stack(t).astype(np.float64) for t in zip(*rows, strict=True))
        if self.scale == "denormalise":
            # exact, in float64, as the torch back end (overflow: one_pass refuses it)
            c, d, el = denormalise(c, d, el, gain, self.mask)
        return A, b, c, d, el


def _session(raw: bytes, source: str, threads: int):
    """An onnxruntime session of the model's bytes on ``threads`` intra-op threads."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    try:
        return ort.InferenceSession(raw, options, providers=["CPUExecutionProvider"])
    except Exception as err:  # onnxruntime raises its own error types
        text = str(err).strip().splitlines()
        raise ValueError(f"{source} is not an ONNX model onnxruntime can load: "
                         f"{text[0] if text else type(err).__name__}") from None


def _check_threads(threads) -> None:
    if isinstance(threads, bool) or not (isinstance(threads, int) and threads >= 1):
        raise ValueError(f"threads must be a positive integer; got {threads!r}")


def export_backend(raw: bytes, ident, threads: int = 1) -> OnnxBackend:
    """The ONNX back end of an identifier built from its encoder, from its export in memory
    (``export.onnx_bytes``, made by the caller: ``Identifier.with_backend``).

    Parameters
    ----------
    raw : bytes
        The identifier's ONNX model.
    ident : Identifier
        The identifier exported (its scale mode and elements).
    threads : int
        onnxruntime's intra-op threads.

    Returns
    -------
    OnnxBackend
    """
    from aeid_struct.identification.checks import output_elements

    return OnnxBackend(_session(raw, "the export", threads), ident.scale,
                       output_elements(ident.structure.element_names))


def check_onnx_runtime(threads) -> None:
    """Refuse ``threads`` that is not a positive integer, or a missing onnx / onnxruntime,
    before anything is exported (``Identifier.with_backend("onnx")``).

    Parameters
    ----------
    threads : int

    Raises
    ------
    ValueError
        Naming ``threads``, or the extra to install.
    """
    _check_threads(threads)
    try:
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError:
        raise ValueError("backend 'onnx' needs onnx and onnxruntime: pip install "
                         "\"aeid-struct[onnx]\"") from None


def _model_bytes(model) -> tuple[bytes, str]:
    """The bytes of an ONNX ``model`` (bytes or a file path) and how errors name it."""
    if isinstance(model, (bytes, bytearray)):
        return bytes(model), "model"
    if not isinstance(model, (str, Path)):
        raise ValueError(f"model must be the path of an .onnx file or its bytes; got "
                         f"{type(model).__name__}")
    path = Path(model)
    if not path.is_file():
        raise ValueError(f"model must be an existing .onnx file or its bytes; got "
                         f"{str(path)!r}" + (" (a directory)" if path.is_dir() else ""))
    return path.read_bytes(), f"model file {str(path)!r}"


def _check_onnx_header(header: dict, source: str) -> None:
    """Entries and JSON types of the ``aeid`` metadata (one ValueError naming ``source``)."""
    def integer(v) -> bool:
        return isinstance(v, int) and not isinstance(v, bool) and v >= 1

    def number(v) -> bool:
        return (isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                and v > 0)

    checks = {
        "steps": (integer, "a positive integer"),
        "dt": (number, "a positive finite number"),
        "inputs": (lambda v: isinstance(v, bool), "true or false"),
        "initial": (lambda v: v in ("rest", "fitted"), "'rest' or 'fitted'"),
        "elements": (lambda v: isinstance(v, list) and all(isinstance(e, str) for e in v),
                     "a list of names"),
    }
    for key, (ok, expected) in checks.items():
        if key not in header:
            raise ValueError(f"{source}: its 'aeid' metadata is missing {key!r}")
        if not ok(header[key]):
            raise ValueError(f"{source}: 'aeid' metadata entry {key!r} must be {expected}; "
                             f"got {header[key]!r}")
    physical = header.get("physical_elements")
    if physical is not None and not (isinstance(physical, list) and all(
            p in header["elements"] for p in physical)):
        raise ValueError(f"{source}: 'aeid' metadata entry 'physical_elements' must list "
                         f"elements of {header['elements']}; got {physical!r}")


def _structure(header: dict, n: int, what: str):
    """The structure the metadata describes: the structure itself where torch is installed,
    else its description; a description by element names for files that recorded none."""
    from aeid_struct.structures import Described

    config = header.get("structure")
    if not isinstance(config, dict):
        config = {"type": "CCF" if header.get("ccf", True) else "model", "n": n}
        return Described(config, header["elements"])
    try:
        from aeid_struct.structures import Structure
    except ImportError:      # torch is not installed: the description is enough to identify
        return Described(config, header["elements"])
    try:
        structure = Structure.from_config(config)
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"'aeid' metadata entry 'structure': {err}") from None
    if tuple(structure.element_names) != tuple(header["elements"]):
        raise ValueError(f"'aeid' metadata entry 'structure' has elements "
                         f"{list(structure.element_names)}, not the graph's {header['elements']}")
    return structure


def _header(session, source: str) -> dict:
    """The ``aeid`` metadata of a session's model, checked (format, kind, entries)."""
    meta = session.get_modelmeta().custom_metadata_map
    if "aeid" not in meta:
        raise ValueError(f"{source} is not an aeid-struct export: its metadata has no "
                         "'aeid' entry (write it with aeid_struct.export.to_onnx)")
    try:
        header = json.loads(meta["aeid"])
    except ValueError:
        header = None
    if not isinstance(header, dict):
        raise ValueError(f"{source}: its 'aeid' metadata is not a JSON object")
    if header.get("format") not in (ONNX_FORMAT, ONNX_FORMAT_3, ONNX_FORMAT_2, ONNX_FORMAT_1):
        raise ValueError(f"{source} has format {header.get('format')!r}; this reader reads "
                         f"{ONNX_FORMAT!r} (and {ONNX_FORMAT_3!r}, {ONNX_FORMAT_2!r}, "
                         f"{ONNX_FORMAT_1!r})")
    refuse_other(kind_of(header, source), "onnx", source)
    return header


def read_onnx(ident, model, threads: int = 1, *, maps: dict | None = None,
              trust: bool = False) -> None:
    """Fill a new ``Identifier`` from an ONNX export (``Identifier.from_onnx``): its record
    format, structure, head and inverse map from the ``aeid`` metadata, checked against the
    graph, and an :class:`OnnxBackend`.

    Parameters
    ----------
    ident : Identifier
        Made by ``Identifier.__new__``.
    model : str or Path or bytes
    threads : int
    maps : dict, optional
    trust : bool
        As ``Identifier.from_onnx``.

    Raises
    ------
    ValueError
        Naming the source and what is wrong.
    """
    from aeid_struct.identification.checks import output_elements, set_format
    from aeid_struct.identification.head import Head
    from aeid_struct.structures import check_maps, from_entry

    _check_threads(threads)
    check_maps(maps, trust)
    raw, source = _model_bytes(model)
    session = _session(raw, source, threads)
    header = _header(session, source)
    if header["format"] == ONNX_FORMAT_1:
        source += f" (format {ONNX_FORMAT_1!r}, which stored its inverse map as code)"
    _check_onnx_header(header, source)
    steps, dt = int(header["steps"]), float(header["dt"])
    graph = {i.name: i.shape for i in session.get_inputs()}
    if set(graph) != {"y", "u"} or any(shape != [steps] for shape in graph.values()):
        # the metadata and the graph must describe the same record, or every call fails
        # inside onnxruntime (or, for a looser graph, reads another record format)
        raise ValueError(f"{source}: its 'aeid' metadata says steps={steps} but its "
                         f"graph reads inputs {graph}; expected y and u of shape [{steps}]")
    n = session.get_outputs()[0].shape[-1]
    try:
        structure = _structure(header, n if isinstance(n, int) else 0, source)
        inverse = (None if not header.get("inverse") else
                   from_entry(header["inverse"], "'inverse'", maps=maps, trust=trust))
    except ValueError as err:
        raise ValueError(f"{source}: {err}") from None
    set_format(ident, structure, (dt,), (steps, 1, bool(header["inputs"])),
                      scale=header.get("scale"), initial=header["initial"], inverse=inverse,
                      meta={})
    ident.feature_mean, ident.feature_scale = 0.0, 1.0     # the graph standardises itself
    names = tuple(header["elements"])
    ident.physical_elements = (tuple(header["physical_elements"])
                               if header.get("physical_elements") else None)
    ident.backend = OnnxBackend(session, header.get("scale"), output_elements(names))
    try:
        ident.head = (None if header.get("head") is None
                      else Head.from_dict(header["head"]))
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{source}: 'aeid' metadata entry 'head': {err}") from None
