"""The name of the ONNX back end before it was one: :class:`OnnxIdentifier`, deprecated.

An export (``online.to_onnx``) is read by ``aeid_struct.load(path)`` or
``Identifier.from_onnx(model)`` into the one ``Identifier`` class on its ONNX back end
(``identification.onnx_backend``: onnxruntime and numpy, no torch). ``OnnxIdentifier`` is that
identifier with the call form it had (``runner(y, u) -> dict`` and ``runner.physical(dict)``),
kept so that code written against it runs, with a DeprecationWarning naming the replacement.
"""

from __future__ import annotations

import warnings

import numpy as np

from aeid_struct.identification import ONNX_FORMAT as ONNX_FORMAT
from aeid_struct.identification import ONNX_FORMAT_1 as ONNX_FORMAT_1
from aeid_struct.identification import ONNX_FORMAT_2 as ONNX_FORMAT_2
from aeid_struct.identification import ONNX_FORMAT_3 as ONNX_FORMAT_3
from aeid_struct.identification import Identifier, read_onnx
from aeid_struct.identification import inverse_names as inverse_names

__all__ = ["ONNX_FORMAT", "ONNX_FORMAT_1", "ONNX_FORMAT_2", "ONNX_FORMAT_3", "OnnxIdentifier",
           "inverse_names"]


class OnnxIdentifier(Identifier):
    """Deprecated: ``aeid_struct.load(path)`` or ``Identifier.from_onnx(model)``.

    An ``Identifier`` on its ONNX back end (it answers ``identify(record) -> Estimate`` as
    every identifier does), with the dict call of before.

    Parameters
    ----------
    model : str or Path or bytes
        The ``.onnx`` path, or the model's bytes (``online.onnx_bytes``).
    threads : int
        onnxruntime's intra-op threads.
    maps : dict of str to casadi.Function, optional
        A user inverse map the metadata names, passed again.
    trust : bool
        Deserialise a user inverse map from the metadata: only for files you trust.

    Raises
    ------
    ValueError
        As ``Identifier.from_onnx``.
    """

    def __init__(self, model, threads: int = 1, *, maps: dict | None = None,
                 trust: bool = False) -> None:
        warnings.warn("OnnxIdentifier is deprecated: aeid_struct.load(path) or "
                      "Identifier.from_onnx(model) reads an export into an Identifier on its "
                      "ONNX back end; identify(record) -> Estimate replaces the dict call",
                      DeprecationWarning, stacklevel=2)
        read_onnx(self, model, threads, maps=maps, trust=trust)

    @property
    def session(self):
        """The onnxruntime session (``Identifier.backend.session``)."""
        return self.backend.session

    @property
    def _inverse(self):
        """The inverse map under its name before the one class (``inverse``)."""
        return self.inverse

    @property
    def element_names(self) -> tuple[str, ...]:
        """The structure's elements, in the order of the ``elements`` output."""
        return tuple(self.structure.element_names)

    @property
    def physical_names(self) -> tuple[str, ...] | None:
        """The physical parameters :meth:`physical` returns (empty: none; None: an inverse map
        whose outputs cannot be named without evaluating it)."""
        if self.physical_elements:
            return tuple(self.physical_elements)
        return inverse_names(self.inverse)

    def __repr__(self) -> str:
        return (f"OnnxIdentifier(steps={self.steps}, dt={self.dt}, inputs={self.inputs}, "
                f"elements={self.element_names})")

    def __call__(self, y, u=None) -> dict[str, np.ndarray]:
        """Identify a record, or a batch of them (``identify``'s numbers as a dict).

        Parameters
        ----------
        y : (steps,) or (batch, steps) array_like
        u : (steps,) or (batch, steps) array_like, optional

        Returns
        -------
        dict of str to ndarray
            float64 ``A (n, n), b (n,), c (n,), d ()`` and ``elements (q,)``; a leading batch
            axis for a batch.

        Raises
        ------
        ValueError
            As ``identify`` (a ``records.RecordError`` for a per-record problem).
        """
        est = self.identify(y, u)
        elements = np.stack([np.asarray(est.elements[k], dtype=np.float64)
                             for k in self.element_names], axis=-1)
        return {"A": np.asarray(est.A), "b": np.asarray(est.b), "c": np.asarray(est.c),
                "d": np.asarray(est.d, dtype=np.float64), "elements": elements}

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
    need = ("elements",) if runner.physical_elements or runner.inverse is None \
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
    if runner.physical_elements:
        out = {k: el[..., runner.element_names.index(k)] for k in runner.physical_elements}
    elif runner.inverse is None:
        return {}
    else:
        from aeid_struct.estimates import inverse_of_models
        from aeid_struct.structures import type_of

        A = np.asarray(model["A"], dtype=np.float64)
        n = A.shape[-1]
        A = A.reshape(-1, n, n)
        b, c = (np.asarray(model[k], dtype=np.float64).reshape(-1, n) for k in "bc")
        d = np.asarray(model["d"], dtype=np.float64).reshape(-1)
        out = inverse_of_models(runner.inverse, A, b, c, d,
                                type_of(runner.structure) == "CCF")
    return {k: np.asarray(v, dtype=np.float64) if batched else float(np.ravel(v)[0])
            for k, v in out.items()}
