r"""The generic identifier: a window of any system's record in normalised time -> its poles.

A window of ``window`` samples (``dt = 1``: time in samples) is normalised (its mean removed, then
divided by its largest magnitude, for ``y`` and ``u`` each), read by the residual 1-D encoder of
paper Sec. III-A (two channels, ``y`` and ``u``), and mapped to the poles of a stable monic
denominator (:mod:`~aeid_struct.generic.poles`). The rest of the model (``c``, ``d``, the initial
state, the output offset) is linear in the record for a fixed denominator and comes from least
squares (:func:`~aeid_struct.simulation.project`; in training
:func:`~aeid_struct.simulation.project_batch`), docs/architecture.md, "Any system, any record".
The normalisation changes none of that: an offset is absorbed by the initial state and the
output offset, a scale by ``c`` and ``d``.
"""

from __future__ import annotations

import math
import os
from importlib.resources import files
from pathlib import Path

import numpy as np
import torch

from aeid_struct.encoder import Encoder
from aeid_struct.generic import files as generic_files
from aeid_struct.generic.config import GENERIC, ORDERS, GenericConfig
from aeid_struct.generic.forward import (
    WindowEncoder,
    denominator_numpy,
    factors_numpy,
    normalise_numpy,
)
from aeid_struct.generic.pipeline import run
from aeid_struct.generic.poles import denominator, factors, poles_of
from aeid_struct.identification import PRETRAINED, Estimate
from aeid_struct.structures import CCF
from aeid_struct.threads import one_thread

__all__ = ["GENERIC", "ORDERS", "GenericConfig", "GenericIdentifier", "load_generic",
           "normalise_windows", "read_generic", "save_generic", "spectra"]

def normalise_windows(y: torch.Tensor, u: torch.Tensor):
    """Each window without its mean and divided by its largest magnitude, ``y`` and ``u`` alike.

    Parameters
    ----------
    y, u : (batch, steps) tensors

    Returns
    -------
    y_n, u_n : (batch, steps) tensors
        NaN rows where a window of ``y`` or ``u`` is constant or not finite.
    ok : (batch,) bool tensor
        The windows that could be normalised.
    """
    out = []
    ok = torch.ones(y.shape[0], dtype=torch.bool, device=y.device)
    for x in (y, u):
        x = x - x.mean(dim=1, keepdim=True)
        peak = x.abs().amax(dim=1)
        good = torch.isfinite(peak) & (peak > 0)
        ok &= good
        out.append(x / torch.where(good, peak, torch.ones_like(peak))[:, None])
    nan = torch.full_like(out[0], math.nan)
    return (torch.where(ok[:, None], out[0], nan), torch.where(ok[:, None], out[1], nan), ok)


def spectra(y_n: torch.Tensor, u_n: torch.Tensor) -> torch.Tensor:
    """The spectral features: ``log(|rfft(h x)| / sqrt(steps) + 1e-3) / 4`` of the Hann-windowed
    ``x = y_n, u_n`` (the floor keeps bins without power finite; the scale keeps the features of
    order one, like the normalised windows).

    Parameters
    ----------
    y_n, u_n : (batch, steps) tensors

    Returns
    -------
    (batch, 2 (steps // 2 + 1)) tensor
    """
    steps = y_n.shape[1]
    h = torch.hann_window(steps, periodic=False, dtype=y_n.dtype, device=y_n.device)
    mags = [torch.fft.rfft(x * h, dim=1).abs() / math.sqrt(steps) for x in (y_n, u_n)]
    return torch.log(torch.cat(mags, dim=1) + 1e-3) / 4


class GenericIdentifier:
    """A trained generic identifier: encoder weights, its configuration and where it comes from.

    Parameters
    ----------
    config : GenericConfig
    encoder : Encoder, optional
        With ``config.encoder_config()``; freshly initialised when None.
    meta : dict, optional
        Provenance (JSON-ready): ``meta["train"]`` holds the training recipe.

    Raises
    ------
    ValueError
        ``config`` is not a GenericConfig, or ``encoder`` is not of its shape.
    """

    def __init__(self, config: GenericConfig, encoder: Encoder | None = None,
                 meta: dict | None = None) -> None:
        if not isinstance(config, GenericConfig):
            raise ValueError(f"config must be a GenericConfig; got {type(config).__name__}")
        if encoder is None:
            encoder = Encoder(config.encoder_config())
        elif not isinstance(encoder, Encoder) or encoder.config != config.encoder_config():
            raise ValueError("encoder must be an Encoder of config.encoder_config()")
        self.config = config
        self.encoder = encoder
        self.meta = dict(meta or {})
        self._ccf = CCF(config.order)

    def __repr__(self) -> str:
        name = self.meta.get("name", "")
        return (f"GenericIdentifier(order={self.config.order}, window={self.config.window}"
                + (f", name={name!r}" if name else "") + ")")

    # -- the identifier protocol -----------------------------------------------------------------
    @one_thread
    def identify(self, record, **options) -> Estimate:
        """Identify a measured record with this identifier: ``ae.identify(record,
        order=self.config.order, identifier=self, **options)``.

        Parameters
        ----------
        record : Record, (y, u) or (y, u, dt) tuple, or (steps,) array
            As ``ae.identify`` takes it (a record shorter than ``config.window`` is read at a
            finer grid).
        **options
            ``structure, refine, delay, max_delay, method, iterations, classical`` as
            ``ae.identify`` takes them.

        Returns
        -------
        Estimate

        Raises
        ------
        ValueError
            As ``ae.identify``; an ``order`` other than this identifier's.
        """
        order = options.pop("order", self.config.order)
        if order != self.config.order:
            raise ValueError(f"order must be this identifier's order {self.config.order}; got "
                             f"{order!r}")
        mine = {self.config.order: self}
        return run(lambda _: mine, record, order, what="GenericIdentifier.identify", **options)

    # -- torch: differentiable, for training -----------------------------------------------------
    def factors_batch(self, y_n: torch.Tensor, u_n: torch.Tensor):
        """Natural frequencies and damping ratios (float64) of normalised windows.

        Parameters
        ----------
        y_n, u_n : (batch, window) tensors
            From :func:`normalise_windows`.

        Returns
        -------
        w : (batch, ceil(n/2)) float64 tensor
        zeta : (batch, floor(n/2)) float64 tensor
        """
        weight = next(self.encoder.parameters())
        x = torch.stack([y_n, u_n], dim=1).to(weight.dtype)
        features = spectra(y_n, u_n).to(weight.dtype) if self.config.spectrum else None
        raw = self.encoder(x, features).to(torch.float64)
        return factors(raw, self.config.band, self.config.damping)

    def companion(self, w: torch.Tensor, zeta: torch.Tensor):
        """The CCF ``(A, b)`` (paper Eq. 5) of the factors' denominator.

        Parameters
        ----------
        w : (batch, ceil(n/2)) tensor
        zeta : (batch, floor(n/2)) tensor
            Finite (:meth:`factors_batch`).

        Returns
        -------
        A : (batch, n, n) tensor
        b : (batch, n) tensor
            ``e_n``.

        Raises
        ------
        ValueError
            Non-finite factors.
        """
        a = denominator(w, zeta)
        system = self._ccf.assemble(torch.cat([a, torch.zeros_like(a)], dim=1))
        return system.A, system.b

    def companion_batch(self, y_n: torch.Tensor, u_n: torch.Tensor):
        """The CCF ``(A, b)`` (paper Eq. 5, float64) of normalised windows' denominators.

        Parameters
        ----------
        y_n, u_n : (batch, window) tensors
            Windows that could be normalised (no NaN rows).

        Returns
        -------
        A : (batch, n, n) float64 tensor
        b : (batch, n) float64 tensor
            ``e_n``.
        """
        return self.companion(*self.factors_batch(y_n, u_n))

    # -- numpy: identification -----------------------------------------------------------------
    def _windows(self, y, u):
        """Checked ``(K, window)`` float64 windows, normalised (numpy)."""
        arrays = []
        for name, x in (("y", y), ("u", u)):
            x = np.ascontiguousarray(x, dtype=np.float64)     # torch refuses negative strides
            if x.ndim != 2 or x.shape[1] != self.config.window:
                raise ValueError(f"{name} must be a (K, {self.config.window}) array of windows; "
                                 f"got shape {x.shape}")
            arrays.append(x)
        if arrays[0].shape != arrays[1].shape:
            raise ValueError(f"y and u must have one shape (K, {self.config.window}); got "
                             f"{arrays[0].shape} and {arrays[1].shape}")
        return normalise_numpy(arrays[0], arrays[1])

    def _numpy_encoder(self) -> WindowEncoder:
        """The encoder as numpy (:mod:`~aeid_struct.generic.forward`), rebuilt when a weight
        changed since (training updates them in place, which bumps their version)."""
        cached = getattr(self, "_numpy", None)
        if cached is None or cached[0] is not self.encoder:
            params = list(self.encoder.parameters())    # walking the modules costs ~0.1 ms
            cached = [self.encoder, params, None, None]
            self._numpy = cached
        key = [(p.data_ptr(), p._version) for p in cached[1]]
        if cached[2] != key:
            cached[2:] = key, WindowEncoder(self.encoder, self.config.spectrum)
        return cached[3]

    def _factors(self, y, u):
        """``w, zeta, ok`` of windows by the numpy forward pass (the same function as
        :meth:`factors_batch`, without torch's per-operation overhead on a few windows)."""
        y_n, u_n, ok = self._windows(y, u)
        with np.errstate(invalid="ignore"):
            raw = self._numpy_encoder()(y_n, u_n)
        return (*factors_numpy(raw, self.config.band, self.config.damping), ok)

    def denominators(self, y, u) -> np.ndarray:
        """Monic continuous-time denominators of windows, in normalised time (``dt = 1``).

        One batched encoder pass. At sample time ``dt`` the poles are these over ``dt``
        (``a_i / dt^(n-i)``).

        Parameters
        ----------
        y, u : (K, window) arrays
            Windows in sample units; each is normalised here.

        Returns
        -------
        (K, n + 1) float64 array
            Highest power first (``numpy.poly`` order), leading 1; NaN rows for windows whose
            ``y`` or ``u`` is constant or not finite.

        Raises
        ------
        ValueError
            Shapes that are not ``(K, window)``.
        """
        w, zeta, ok = self._factors(y, u)
        a = denominator_numpy(w, zeta)
        out = np.concatenate([np.ones((a.shape[0], 1)), a[:, ::-1]], axis=1)
        out[~ok] = np.nan
        return out

    def poles(self, y, u) -> np.ndarray:
        """Poles of windows in normalised time (rad/sample).

        Parameters
        ----------
        y, u : (K, window) arrays

        Returns
        -------
        (K, n) complex array
            Per second-order factor a conjugate pair (or two real poles), then the real pole of
            an odd order; NaN rows as in :meth:`denominators`.

        Raises
        ------
        ValueError
            Shapes that are not ``(K, window)``.
        """
        w, zeta, ok = self._factors(y, u)
        p = poles_of(w, zeta)
        p[~ok] = np.nan
        return p

    # -- files ---------------------------------------------------------------------------------
    def save(self, path):
        """Write the identifier as data (:func:`save_generic`).

        Parameters
        ----------
        path : str or PathLike

        Returns
        -------
        pathlib.Path
        """
        return save_generic(self, path)

    @classmethod
    def load(cls, path) -> GenericIdentifier:
        """Read a file written by :meth:`save` (:func:`read_generic`).

        Parameters
        ----------
        path : str or PathLike

        Returns
        -------
        GenericIdentifier
        """
        return generic_files.read(cls, path)


def save_generic(ident: GenericIdentifier, path):
    """Write ``ident`` to ``path`` (safetensors: weights + JSON header; ``generic.files``).

    Parameters
    ----------
    ident : GenericIdentifier
    path : str or PathLike

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ValueError
        ``ident`` is not a generic identifier, ``path`` cannot be written (a directory, below a
        file), or ``ident.meta`` is not JSON.
    """
    if not isinstance(ident, GenericIdentifier):
        raise ValueError(f"ident must be a GenericIdentifier; got {type(ident).__name__}")
    return generic_files.write(ident, path)


def read_generic(path) -> GenericIdentifier:
    """Read a generic identifier file written by :func:`save_generic` (``generic.files``).

    Parameters
    ----------
    path : str or PathLike
        An existing file.

    Returns
    -------
    GenericIdentifier

    Raises
    ------
    ValueError
        Naming ``path`` and what is wrong: not a file, not safetensors, a header that is not
        this format's, a weight of the wrong name, shape, dtype or value.
    """
    return generic_files.read(GenericIdentifier, path)


def load_generic(name_or_path) -> GenericIdentifier:
    """A shipped generic identifier by name (``GENERIC``), or one from a file.

    Parameters
    ----------
    name_or_path : str or PathLike
        ``"generic-1"`` .. ``"generic-4"`` (the order), or the path of a ``.aeid`` file written
        by :func:`~aeid_struct.generic.save_generic`.

    Returns
    -------
    GenericIdentifier

    Raises
    ------
    ValueError
        A name that is not shipped and not an existing file, or a file that is not a generic
        identifier (naming it).
    """
    if isinstance(name_or_path, str) and name_or_path in GENERIC:
        shipped = files("aeid_struct.pretrained") / f"{name_or_path}.aeid"
        if not shipped.is_file():
            raise ValueError(f"name_or_path {name_or_path!r} is a generic identifier name, but "
                             "this installation does not ship it (train it with "
                             "`aeid-struct train-generic`)")
        return read_generic(Path(str(shipped)))
    if isinstance(name_or_path, (str, os.PathLike)) and Path(name_or_path).is_file():
        return read_generic(name_or_path)
    if isinstance(name_or_path, str) and name_or_path in PRETRAINED:
        raise ValueError(f"name_or_path {name_or_path!r} is a shipped leg identifier, not a "
                         f"generic one: load it with aeid_struct.load_pretrained("
                         f"{name_or_path!r}); generic identifiers: {list(GENERIC)}")
    raise ValueError(f"name_or_path must be one of {list(GENERIC)} or an existing generic "
                     f"identifier file; got {name_or_path!r}")
