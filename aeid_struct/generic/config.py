"""A generic identifier's shape (:class:`GenericConfig`), the orders it is built for and the
shipped identifiers' names; what a generic identifier file's header holds, checked on reading."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch

from aeid_struct.encoder import Encoder, EncoderConfig

__all__ = ["GENERIC", "MAX_WEIGHTS", "MAX_WINDOW", "ORDERS", "GenericConfig"]

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
