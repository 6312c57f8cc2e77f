"""Identification from an exported ONNX file with onnxruntime and numpy alone (CasADi for the
separable head and the physical parameters): :class:`OnnxIdentifier` reads what
``online.to_onnx`` writes and answers the identifier protocol, ``identify(record) -> Estimate``,
without torch installed (``tests/test_export.py`` runs it with torch blocked). Where torch is
absent, the structure is known by its description (``structures.Described``): enough for the
head and the physical parameters; an estimate's self-check (``fit``, ``y_hat``, ``x0``) reads
the numpy decoder (``simulation.simulate_numpy``); ``refine`` needs torch."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from aeid_struct.records import (
    Checked,
    RecordError,
    arrays_of,
    check_record,
    check_records,
    denormalise,
    normalise,
    overflow_problem,
)

#: The metadata format written: the one container of every identifier file
#: (``identification.container.FORMAT``, kind ``"onnx"``; spelled out here so that this module
#: imports no torch, and tested to agree), with the entries of ``ONNX_FORMAT_3``.
ONNX_FORMAT = "aeid-struct/3"
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


def _read_head(runner, header: dict, source: str) -> None:
    """Set ``runner.head`` and ``runner.structure`` from the metadata (a ValueError naming
    ``source`` for a malformed entry or a head the structure refuses)."""
    from aeid_struct.identification import Head, pattern_of
    from aeid_struct.structures import Described

    try:
        from aeid_struct.structures import Structure
    except ImportError:
        Structure = None        # torch is not installed: the head needs the description alone
    try:
        runner.head = Head.from_dict(header["head"])
        runner.structure = (Described(header.get("structure"), header["elements"])
                            if Structure is None
                            else Structure.from_config(header.get("structure")))
        pattern_of(runner, runner.head)
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{source}: 'aeid' metadata entry 'head': {err}") from None


class OnnxIdentifier:
    """Identification from an exported ONNX file (:func:`to_onnx`) with onnxruntime and numpy.

    Parameters
    ----------
    model : str or Path or bytes
        The ``.onnx`` path, or the model's bytes (:func:`onnx_bytes`).
    threads : int
        onnxruntime's intra-op threads (1: the one-core latency of online use).
    maps : dict of str to casadi.Function, optional
        A user inverse map the metadata names (not a named map of ``structures``), passed
        again; it must have the SHA-256 recorded.
    trust : bool
        Deserialise a user inverse map, or the inverse of an export in the format before named
        maps (``ONNX_FORMAT_1``), from the metadata. A serialised CasADi Function can run shell
        commands when it is read: only for files you trust.

    Attributes
    ----------
    steps : int
        Samples per record the identifier was trained on.
    dt : float
        Their sample time [s].
    inputs : bool
        Whether it reads ``u``.
    initial : str
        ``"rest"`` or ``"fitted"`` (records that start mid-motion).
    element_names : tuple of str
        The structure's elements, in the order of the ``elements`` output.
    head : identification.Head or None
        The separable head of the exported identifier, applied after the graph (may be set or
        cleared, as ``Identifier.head``).
    structure : Structure or None
        The structure the head iterates in (from the metadata; None without a head).

    Raises
    ------
    ValueError
        A file that is not an aeid-struct ONNX export, a metadata entry of the wrong type, an
        inverse map that is neither named nor passed in ``maps``, or a head its structure does
        not serve.
    """

    def __init__(self, model, threads: int = 1, *, maps: dict | None = None,
                 trust: bool = False) -> None:
        import onnxruntime as ort

        from aeid_struct.structures import check_maps

        if not (isinstance(threads, int) and threads >= 1):
            raise ValueError(f"threads must be a positive integer; got {threads!r}")
        check_maps(maps, trust)
        raw, source = _model_bytes(model)
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        try:
            self.session = ort.InferenceSession(raw, options,
                                                providers=["CPUExecutionProvider"])
        except Exception as err:  # onnxruntime raises its own error types
            text = str(err).strip().splitlines()
            raise ValueError(f"{source} is not an ONNX model onnxruntime can load: "
                             f"{text[0] if text else type(err).__name__}") from None
        _read_metadata(self, source, maps, trust)

    @property
    def physical_names(self) -> tuple[str, ...] | None:
        """The physical parameters :meth:`physical` returns (empty: none; None: an inverse map
        whose outputs cannot be named without evaluating it)."""
        if self._physical_elements:
            return tuple(self._physical_elements)
        return inverse_names(self._inverse)

    def __repr__(self) -> str:
        return (f"OnnxIdentifier(steps={self.steps}, dt={self.dt}, inputs={self.inputs}, "
                f"elements={self.element_names})")

    def __call__(self, y, u=None) -> dict[str, np.ndarray]:
        """Identify a record, or a batch of them.

        Parameters
        ----------
        y : (steps,) or (batch, steps) array_like
            The output record(s).
        u : (steps,) or (batch, steps) array_like, optional
            The input (None: a unit step; ``(steps,)`` for every record of a batch).

        Returns
        -------
        dict of str to ndarray
            float64 ``A (n, n), b (n,), c (n,), d ()`` and ``elements (q,)``, the numbers of
            ``Identifier.identify`` to float32 precision (the head's iterations, when the file
            has one, after the graph in float64); a leading batch axis for a batch.

        Raises
        ------
        ValueError
            Records refused by ``records.check_records`` (a ``records.RecordError`` for a
            per-record problem), or a scale ratio outside float32's range.

        Notes
        -----
        The records are checked by ``records.check_records``, as ``Identifier.identify`` checks
        them: the same inputs are refused with the same ValueError and message (a complex or
        misshapen array, a batch of no records; per record, as a ``records.RecordError``:
        non-finite samples, an all-zero ``y`` or ``u``, a varying ``u`` for an identifier that
        does not read it). Eq. 15 runs per record in float64 before the graph's float32: the
        graph receives ``y / max|y|`` and ``u / max|u|`` and the model is de-normalised in
        float64, so a record of 1e40 or 1e-44 gives what the identifier gives. (For a
        ``scale="feature"`` export, or a file written before the scale was recorded, the graph
        reads ``max|y| / max|u|`` itself: it must lie within float32's normal range.)
        """
        checked = check_records(y, u, steps=self.steps, dt=self.dt, reads_u=self.inputs)
        checked.raise_first()
        out = self._run(checked)
        return out if checked.batched else {k: v[0] for k, v in out.items()}

    def identify(self, y, u=None, *, dt: float | None = None):
        """Identify a record, or a batch of them, into an :class:`~aeid_struct.Estimate`: the
        identifier protocol (``identify(record) -> Estimate``), the numbers of :meth:`__call__`.

        Parameters
        ----------
        y : Record, (steps,) or (batch, steps) array_like
            A measured ``records.Record`` (which carries ``u`` and ``dt``), or the outputs.
        u : (steps,) or (batch, steps) array_like, optional
            As :meth:`__call__`.
        dt : float, optional
            The record's sample time, checked against the export's.

        Returns
        -------
        Estimate
            Batched when ``y`` is; its provenance names the export's inverse map or physical
            elements and its structure where the metadata has one.

        Raises
        ------
        ValueError
            As :meth:`__call__`; a ``dt`` other than the export's.
        """
        from aeid_struct.estimates import Estimate, Provenance

        start = time.perf_counter()
        y, u, dt = arrays_of(y, u, dt, what="OnnxIdentifier.identify")
        if dt is not None and dt != self.dt:
            raise ValueError(f"dt must be {self.dt} s for this export (trained on records of "
                             f"{self.steps} samples at dt={self.dt}); got dt={dt!r}")
        record = check_record(y, u, steps=self.steps, dt=self.dt, reads_u=self.inputs)
        record.raise_first()
        out = self._run(Checked(record.y[0], record.u[0], record.batched, record.problems))
        if not record.batched:
            out = {k: v[0] for k, v in out.items()}
        inverse = (("elements", tuple(self._physical_elements)) if self._physical_elements
                   else self._inverse)
        elements = dict(zip(self.element_names, np.moveaxis(out["elements"], -1, 0),
                            strict=True))
        if not record.batched:
            elements = {k: float(v) for k, v in elements.items()}
        # the structure is known where the metadata has one (a head's); without it
        # Estimate.physical takes the model to CCF first, which a CCF model passes unchanged
        return Estimate(A=out["A"], b=out["b"], c=out["c"], d=out["d"], elements=elements,
                        record=record, provenance=Provenance(
                            structure=self.structure, inverse=inverse, initial=self.initial),
                        seconds=time.perf_counter() - start)

    def _run(self, checked) -> dict[str, np.ndarray]:
        """The graph (and the head) on checked records: batched arrays (:meth:`__call__`)."""
        _, u_unit, y_bar, u_bar = normalise(checked.y, checked.u)
        y_unit = checked.y / y_bar[:, None]
        gain = y_bar / u_bar
        if self._scale == "denormalise":
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
        A, b, c, d, el = (np.stack(t).astype(np.float64) for t in zip(*rows, strict=True))
        if self._scale == "denormalise":
            # exact, in float64, as the identifier's own path (overflow: refused below)
            c, d, el = denormalise(c, d, el, gain, self._output_mask)
        if self.head is not None:     # after the graph, as Identifier.identify runs it
            from aeid_struct.identification import apply_head, head_failure

            with np.errstate(over="ignore", invalid="ignore"):
                (A, b, c, d, el), missed = apply_head(self, self.head, [checked.y],
                                                      [checked.u], (A, b, c, d, el))
            if missed.any():
                raise head_failure(int(np.argmax(missed)), self.head)
        finite = np.isfinite(c).all(axis=1) & np.isfinite(d.reshape(len(d), -1)).all(axis=1)
        if not finite.all():          # as Identifier.identify refuses it (identify._overflowed)
            r = int(np.argmin(finite))
            raise RecordError(overflow_problem(r, float(gain[r])), r)
        return dict(zip(("A", "b", "c", "d", "elements"), (A, b, c, d, el), strict=True))

    def physical(self, model: dict) -> dict:
        """Physical parameters of a model returned by ``__call__``.

        Parameters
        ----------
        model : dict
            What ``__call__`` returned.

        Returns
        -------
        dict of str to float or (batch,) ndarray
            Through the stored inverse map, or the elements that are physical parameters;
            empty when the export has none.

        Raises
        ------
        ValueError
            ``model`` is not such a dict.
        """
        return _physical(self, model)


def _physical(runner: OnnxIdentifier, model: dict) -> dict:
    """``OnnxIdentifier.physical``: the checks of ``model`` and the map."""
    need = ("elements",) if runner._physical_elements or runner._inverse is None \
        else ("A", "b", "c", "d", "elements")
    if not isinstance(model, dict) or any(k not in model for k in need):
        got = sorted(model) if isinstance(model, dict) else type(model).__name__
        raise ValueError(f"model must be a dict with {', '.join(need)} as __call__ returns "
                         f"it; got keys {got}" if isinstance(model, dict) else
                         f"model must be the dict __call__ returns; got {got}")
    try:
        el = np.asarray(model["elements"], dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("model['elements'] must be an array of real numbers, as __call__ "
                         f"returns it; got {model['elements']!r}") from None
    if el.ndim not in (1, 2) or el.shape[-1] != len(runner.element_names):
        raise ValueError(f"model['elements'] must have shape ({len(runner.element_names)},) "
                         f"or (batch, {len(runner.element_names)}); got {el.shape}")
    batched = el.ndim == 2
    if runner._physical_elements:
        out = {k: el[..., runner.element_names.index(k)] for k in runner._physical_elements}
    elif runner._inverse is None:
        return {}
    else:
        from aeid_struct.estimates import inverse_of_models

        A = np.asarray(model["A"], dtype=np.float64)
        n = A.shape[-1]
        A = A.reshape(-1, n, n)
        b, c = (np.asarray(model[k], dtype=np.float64).reshape(-1, n) for k in "bc")
        d = np.asarray(model["d"], dtype=np.float64).reshape(-1)
        out = inverse_of_models(runner._inverse, A, b, c, d, runner._ccf)
    return {k: np.asarray(v, dtype=np.float64) if batched else float(np.ravel(v)[0])
            for k, v in out.items()}


def _read_metadata(runner: OnnxIdentifier, source: str, maps, trust: bool) -> None:
    """Set the runner's record format, structure, head and inverse from its model's ``aeid``
    metadata, checked against the graph (``OnnxIdentifier.__init__``)."""
    from aeid_struct.structures import from_entry

    meta = runner.session.get_modelmeta().custom_metadata_map
    if "aeid" not in meta:
        raise ValueError(f"{source} is not an aeid-struct export: its metadata has no "
                         "'aeid' entry (write it with aeid_struct.export.to_onnx)")
    try:
        header = json.loads(meta["aeid"])
    except ValueError:
        header = None
    if not isinstance(header, dict):
        raise ValueError(f"{source}: its 'aeid' metadata is not a JSON object")
    from aeid_struct.identification import kind_of, refuse_other

    if header.get("format") not in (ONNX_FORMAT, ONNX_FORMAT_3, ONNX_FORMAT_2, ONNX_FORMAT_1):
        raise ValueError(f"{source} has format {header.get('format')!r}; this reader reads "
                         f"{ONNX_FORMAT!r} (and {ONNX_FORMAT_3!r}, {ONNX_FORMAT_2!r}, "
                         f"{ONNX_FORMAT_1!r})")
    refuse_other(kind_of(header, source), "onnx", source)
    if header["format"] == ONNX_FORMAT_1:
        source += f" (format {ONNX_FORMAT_1!r}, which stored its inverse map as code)"
    _check_onnx_header(header, source)
    runner.steps, runner.dt = int(header["steps"]), float(header["dt"])
    graph = {i.name: i.shape for i in runner.session.get_inputs()}
    if set(graph) != {"y", "u"} or any(shape != [runner.steps] for shape in graph.values()):
        # the metadata and the graph must describe the same record, or every call fails
        # inside onnxruntime (or, for a looser graph, reads another record format)
        raise ValueError(f"{source}: its 'aeid' metadata says steps={runner.steps} but its "
                         f"graph reads inputs {graph}; expected y and u of shape "
                         f"[{runner.steps}]")
    runner.inputs, runner.initial = bool(header["inputs"]), header["initial"]
    runner.element_names = tuple(header["elements"])
    runner._output_mask = np.array([k == "d" or (k[0] == "c" and k[1:].isdigit())
                                    for k in runner.element_names])
    runner.records = 1
    runner._physical_elements = header.get("physical_elements")
    runner._ccf = bool(header.get("ccf", True))
    runner._scale = header.get("scale")       # None: a file written before it was recorded
    runner._inverse = None
    runner.head = runner.structure = None
    if header.get("head") is not None:
        _read_head(runner, header, source)
    if header.get("inverse"):
        try:
            runner._inverse = from_entry(header["inverse"], "'inverse'", maps=maps, trust=trust)
        except ValueError as err:
            raise ValueError(f"{source}: {err}") from None
