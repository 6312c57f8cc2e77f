"""An identifier as a file: :class:`IdentifierFiles`, what ``Identifier`` reads and writes (its
weights and header, ``identification.files``; an export's graph, ``onnx_backend``). No torch at
import: reading an ONNX export needs none."""

from __future__ import annotations

from pathlib import Path

from aeid_struct.identification.checks import needs_weights

__all__ = ["IdentifierFiles"]


class IdentifierFiles:
    """Reading and writing an identifier: the ``.aeid`` file of its weights and header
    (:meth:`save`, :meth:`load`, :meth:`to_dict`) and an ONNX export (:meth:`from_onnx`).
    ``Identifier`` inherits it."""

    def to_dict(self) -> dict:
        """The JSON header: everything but the weights (``files.header``).

        Returns
        -------
        dict
        """
        from aeid_struct.identification import files

        needs_weights(self, "to_dict")
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
        from aeid_struct.identification import files

        needs_weights(self, "save")
        return files.save(self, path)

    @classmethod
    def load(cls, path, *, maps: dict | None = None, trust: bool = False) -> IdentifierFiles:
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
        from aeid_struct.identification import files

        return files.load(cls, path, maps=maps, trust=trust)

    @classmethod
    def from_onnx(cls, model, threads: int = 1, *, maps: dict | None = None,
                  trust: bool = False) -> IdentifierFiles:
        """The identifier of an ONNX export (``online.to_onnx``), run by onnxruntime: its
        ``backend`` is an ``OnnxBackend``; torch need not be installed.

        Parameters
        ----------
        model : str or Path or bytes
            The ``.onnx`` path, or the model's bytes (``online.onnx_bytes``).
        threads : int
            onnxruntime's intra-op threads (1: the one-core latency of online use).
        maps : dict of str to casadi.Function, optional
            A user inverse map the metadata names (not a named map of ``structures``), passed
            again; it must have the SHA-256 recorded.
        trust : bool
            Deserialise a user inverse map, or the inverse of an export in the format before
            named maps, from the metadata. A serialised CasADi Function can run shell commands
            when it is read: only for files you trust.

        Returns
        -------
        Identifier
            Answers ``identify`` as the exported identifier does (to float32 precision: the
            graph runs in float32), with its head; ``forward``, ``save`` and training need
            the torch back end.

        Raises
        ------
        ValueError
            A file that is not an aeid-struct ONNX export, a metadata entry of the wrong type,
            an inverse map that is neither named nor passed in ``maps``, or a head its structure
            does not serve.
        """
        from aeid_struct.identification.onnx_backend import read_onnx

        ident = cls.__new__(cls)
        read_onnx(ident, model, threads, maps=maps, trust=trust)
        return ident
