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

import dataclasses
import math
import os
from dataclasses import dataclass
from importlib.resources import files
from pathlib import Path

import numpy as np
import torch

from aeid_struct.encoder import Encoder, EncoderConfig
from aeid_struct.generic.forward import (
    NumpyEncoder,
    denominator_numpy,
    factors_numpy,
    normalise_numpy,
)
from aeid_struct.generic.poles import denominator, factors, poles_of
from aeid_struct.identification import PRETRAINED
from aeid_struct.structures import CCF

__all__ = ["GENERIC", "GenericConfig", "GenericIdentifier", "load_generic", "normalise_windows",
           "spectra"]

#: The orders generic identifiers are built for.
ORDERS = (1, 2, 3, 4)
#: The shipped generic identifiers' names (``aeid_struct/pretrained/<name>.aeid``), one per order.
GENERIC = tuple(f"generic-{n}" for n in ORDERS)
#: Bounds of a generic identifier's shape: a window of this many samples at most, and an
#: encoder of at most this many weights (the shipped ones hold ~10^4-10^5); a file or a
#: command line beyond them asks for memory no machine gives, and is refused before torch
#: allocates it.
MAX_WINDOW = 65536
MAX_WEIGHTS = 50_000_000


def _range(name: str, value, what: str) -> tuple[float, float]:
    ok = isinstance(value, (tuple, list)) and len(value) == 2 and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        for v in value)
    if not ok or not 0 < value[0] < value[1]:
        raise ValueError(f"{name} must be a (lo, hi) pair of {what} with 0 < lo < hi; "
                         f"got {value!r}")
    return float(value[0]), float(value[1])


@dataclass(frozen=True, kw_only=True)
class GenericConfig:
    """A generic identifier's shape; validates itself.

    Attributes
    ----------
    order : int
        ``n``, 1..4.
    window : int
        Samples per window the encoder reads, >= 16 and a multiple of ``pool``.
    band : (lo, hi)
        Natural frequencies ``|p| dt`` (rad/sample) the poles can take.
    damping : (lo, hi)
        Damping ratios of the second-order factors (above 1: two real poles).
    width : int
        Channels of the encoder's convolutions (:class:`~aeid_struct.encoder.EncoderConfig`,
        which reads ``y`` and ``u`` as two channels).
    kernel : int
        Their kernel size, odd.
    depth : int
        Convolutions on the encoder's main path.
    dense : tuple of int
        Widths of the encoder's hidden dense layers.
    pool : int
        Average-pooling factor of the window before the convolutions.
    activation : str
        The encoder's activation (``EncoderConfig.activation``).
    spectrum : bool
        Also give the dense layers the log magnitude spectra of the Hann-windowed ``y`` and
        ``u`` (``window // 2 + 1`` bins each, :func:`spectra`). Why: a lightly damped resonance
        is one sharp peak there, at its frequency, where the pooled convolutions see it only
        spread over the whole window (or not at all above half the Nyquist frequency).

    Raises
    ------
    ValueError
        Naming the field that is out of its range.
    """

    order: int
    window: int = 256
    band: tuple[float, float] = (0.005, 2.5)
    damping: tuple[float, float] = (0.003, 5.0)
    width: int = 12
    kernel: int = 5
    depth: int = 3
    dense: tuple[int, ...] = (64, 64)
    pool: int = 2
    activation: str = "gelu"
    spectrum: bool = True

    def __post_init__(self) -> None:
        def integer(v) -> bool:
            return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))

        if not integer(self.order) or self.order not in ORDERS:
            raise ValueError(f"order must be an integer in 1..4; got {self.order!r}")
        object.__setattr__(self, "order", int(self.order))
        if not integer(self.window) or not 16 <= self.window <= MAX_WINDOW:
            raise ValueError(f"window must be an integer in [16, {MAX_WINDOW}] (samples); got "
                             f"{self.window!r}")
        object.__setattr__(self, "band", _range("band", self.band, "frequencies (rad/sample)"))
        object.__setattr__(self, "damping", _range("damping", self.damping, "damping ratios"))
        if not isinstance(self.spectrum, bool):
            raise ValueError(f"spectrum must be True or False; got {self.spectrum!r}")
        if isinstance(self.dense, list):
            object.__setattr__(self, "dense", tuple(self.dense))
        try:
            enc = self.encoder_config()
        except ValueError as err:
            raise ValueError(f"the encoder fields are not a valid encoder: {err}") from None
        if isinstance(enc.pool, int) and self.window % enc.pool:
            raise ValueError(f"window ({self.window}) must be a multiple of pool ({self.pool})")
        for name in ("width", "depth", "kernel"):
            if getattr(self, name) > 4096:
                raise ValueError(f"{name} must be at most 4096; got {getattr(self, name)}")
        if any(w > 65536 for w in self.dense):
            raise ValueError(f"dense widths must be at most 65536; got {self.dense}")
        with torch.device("meta"):       # the shapes only: nothing allocated
            weights = sum(p.numel() for p in Encoder(enc).parameters())
        if weights > MAX_WEIGHTS:
            raise ValueError(f"the encoder of this shape (window {self.window}, width "
                             f"{self.width}, depth {self.depth}, dense {self.dense}) has "
                             f"{weights} weights, more than {MAX_WEIGHTS}; choose a smaller one")

    def encoder_config(self) -> EncoderConfig:
        """The encoder's configuration: ``window`` samples of two channels (``y``, ``u``) ->
        ``order`` raw numbers.

        Returns
        -------
        EncoderConfig
        """
        return EncoderConfig(steps=self.window, outputs=self.order, inputs=True,
                             features=2 * (self.window // 2 + 1) if self.spectrum else 0,
                             width=self.width, kernel=self.kernel, depth=self.depth,
                             dense=self.dense, pool=self.pool, activation=self.activation)

    def to_dict(self) -> dict:
        """JSON-ready fields (tuples as lists); ``GenericConfig(**d)`` rebuilds it.

        Returns
        -------
        dict
        """
        d = dataclasses.asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


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

    def _numpy_encoder(self) -> NumpyEncoder:
        """The encoder as numpy (:mod:`~aeid_struct.generic.forward`), rebuilt when a weight
        changed since (training updates them in place, which bumps their version)."""
        cached = getattr(self, "_numpy", None)
        if cached is None or cached[0] is not self.encoder:
            params = list(self.encoder.parameters())    # walking the modules costs ~0.1 ms
            cached = [self.encoder, params, None, None]
            self._numpy = cached
        key = [(p.data_ptr(), p._version) for p in cached[1]]
        if cached[2] != key:
            cached[2:] = key, NumpyEncoder(self.encoder, self.config.spectrum)
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
        """Write the identifier as data (:func:`~aeid_struct.generic.save_generic`).

        Parameters
        ----------
        path : str or PathLike

        Returns
        -------
        pathlib.Path
        """
        from aeid_struct.generic.files import save_generic

        return save_generic(self, path)

    @classmethod
    def load(cls, path) -> GenericIdentifier:
        """Read a file written by :meth:`save` (:func:`~aeid_struct.generic.read_generic`).

        Parameters
        ----------
        path : str or PathLike

        Returns
        -------
        GenericIdentifier
        """
        from aeid_struct.generic.files import read_generic

        return read_generic(path)


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
    from aeid_struct.generic.files import read_generic  # files imports this module

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
