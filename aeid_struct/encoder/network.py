"""The residual 1-D convolutional encoder of paper Sec. III-A: normalised records -> the raw
parameters of a structure.

Three sequential 1-D convolution layers (each neuron Eq. 8 followed by an activation) and a
fourth convolution that shortcuts them; the two outputs are concatenated, flattened and fed to
dense layers (Eq. 7). Paper defaults: eight convolution neurons, two dense layers of ten.
"Same" padding keeps the time axis, so the flattened features keep the position of each pattern
in time, which the dense layers need to read time constants off the record. What the paper
leaves open (an input channel, scalar features, pooling, several records, the activation) is
set by ``EncoderConfig``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn


class _Tanh(nn.Tanh):
    """``nn.Tanh``; in inference on a CPU tensor, numpy's vectorised tanh in place.

    Why: torch's CPU tanh costs several times numpy's on the pre-activations of a batch (the
    batched identification's largest single cost; ``aeid-struct bench`` measures the path).
    In place is safe here: in the encoder each activation reads a fresh convolution or linear
    output that nothing else reads. Wherever autograd records, a compiler or tracer is at work
    (``torch.export``, ONNX), or the tensor is not a contiguous CPU float tensor, torch's own.
    """

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if (torch.is_grad_enabled() or x.device.type != "cpu" or not x.is_contiguous()
                or x.dtype not in (torch.float32, torch.float64)
                or torch.compiler.is_compiling() or torch.jit.is_tracing()):
            return torch.tanh(x)
        a = x.numpy()
        np.tanh(a, out=a)
        return x


_ACTIVATIONS = {"tanh": _Tanh, "relu": nn.ReLU, "gelu": nn.GELU, "silu": nn.SiLU}


@dataclass(frozen=True, kw_only=True)
class EncoderConfig:
    """Shape of the encoder; validates itself.

    Attributes
    ----------
    steps : int or tuple of int
        Samples per record (the time axis the network is built for); 0 = unset, filled in by
        ``train()`` from the record format. An identifier of several systems that share
        parameters (the leg's two subsystems, one ``(k, d, m)``) reads one record per system,
        each on its own grid: a tuple of two or more, one entry per record.
    outputs : int
        Raw structure parameters produced, ``p`` of the structure; 0 = unset, filled in by
        ``train()``.
    inputs : bool
        Read the normalised input record ``u / max|u|`` as a second channel (channel 0 is the
        normalised output ``y_tilde`` of Eq. 15), so that the encoder can read arbitrary
        excitations, not only a unit step.
    features : int
        Extra scalar features (e.g. ``log max|y|``, the scale that Eq. 15 removes) appended to
        the flattened convolution features before the dense layers. A canonical structure does
        not need them (``c`` and ``d`` are de-normalised exactly), a physical one does: the
        static gain of the leg is ``1/k``.
    width : int
        Neurons (channels) of each convolution layer (paper: 8).
    kernel : int
        Convolution kernel size, odd, so that "same" padding is symmetric.
    depth : int
        Sequential convolution layers on the main path (paper: 3).
    dense : tuple of int
        Widths of the hidden dense layers (paper: (10, 10)).
    pool : int or tuple of int
        Average-pooling factor applied to the record first (1 = none); it divides the
        convolution cost and loses little on smooth responses. A tuple (one per record) for
        several records, each pooled by its own factor to a common length (300 samples / 6 and
        100 / 2 both give 50), so that the records enter the convolutions as channels of one
        signal on a normalised time axis.
    activation : {"tanh", "relu", "gelu", "silu"}
        ``tanh`` by default: smooth and bounded.
    """

    steps: int | tuple[int, ...] = 0
    outputs: int = 0
    inputs: bool = False
    features: int = 0
    width: int = 8
    kernel: int = 5
    depth: int = 3
    dense: tuple[int, ...] = (10, 10)
    pool: int | tuple[int, ...] = 1
    activation: str = "tanh"

    def __post_init__(self) -> None:
        def integer(v, least: int) -> bool:
            return isinstance(v, int) and not isinstance(v, bool) and v >= least

        if isinstance(self.steps, (tuple, list)):
            steps = tuple(self.steps)
            if len(steps) < 2 or not all(integer(v, 1) for v in steps):
                raise ValueError("steps must be a non-negative integer, or a tuple of two or more "
                                 f"positive integers (one per record); got {self.steps!r}")
            object.__setattr__(self, "steps", steps)
        if isinstance(self.pool, (tuple, list)):
            pool = tuple(self.pool)
            unset = self.steps == 0    # train() fills steps in from the record format
            if (len(pool) != self.records and not unset) or not all(integer(v, 1) for v in pool):
                raise ValueError(f"pool must be a positive integer or a tuple of {self.records} "
                                 f"positive integers (one per record); got {self.pool!r}")
            object.__setattr__(self, "pool", pool)
        names = ("outputs",) if self.records > 1 else ("steps", "outputs")
        for name in names:
            value = getattr(self, name)
            if not integer(value, 0):
                raise ValueError(f"{name} must be a non-negative integer; got {value!r}")
        for name in ("width", "kernel", "depth") + (() if isinstance(self.pool, tuple)
                                                    else ("pool",)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{name} must be a positive integer; got {value!r}")
        if not integer(self.features, 0):
            raise ValueError(f"features must be a non-negative integer; got {self.features!r}")
        if self.kernel % 2 == 0:
            raise ValueError(f"kernel must be odd (symmetric 'same' padding); got {self.kernel}")
        if self.records == 1 and self.steps and self.pool > self.steps:
            raise ValueError(f"pool must be <= steps ({self.steps}); got {self.pool}")
        if self.records > 1 or isinstance(self.pool, tuple) and self.steps:
            lengths = tuple(s // p for s, p in zip(self.record_steps, self.record_pools,
                                                  strict=True))
            if len(set(lengths)) != 1 or lengths[0] < 1:
                raise ValueError(
                    "every record must pool to the same positive length: steps "
                    f"{self.record_steps} // pool {self.record_pools} = {lengths}; choose pool "
                    "factors that make them equal")
        dense = tuple(self.dense) if isinstance(self.dense, (tuple, list)) else None
        if dense is None or not all(integer(w, 1) for w in dense):
            raise ValueError(f"dense must be a tuple of positive integers; got {self.dense!r}")
        object.__setattr__(self, "dense", dense)
        if not isinstance(self.inputs, (bool, np.bool_)):
            # bool("no") is True: a string would silently add the input channel
            raise ValueError(f"inputs must be True or False; got {self.inputs!r}")
        object.__setattr__(self, "inputs", bool(self.inputs))
        if not isinstance(self.activation, str) or self.activation not in _ACTIVATIONS:
            raise ValueError(
                f"activation must be one of {sorted(_ACTIVATIONS)}; got {self.activation!r}"
            )

    @property
    def records(self) -> int:
        """Records read together (1, or the length of a ``steps`` tuple)."""
        return len(self.steps) if isinstance(self.steps, tuple) else 1

    @property
    def record_steps(self) -> tuple[int, ...]:
        """Samples of each record."""
        return self.steps if isinstance(self.steps, tuple) else (self.steps,)

    @property
    def record_pools(self) -> tuple[int, ...]:
        """Pooling factor of each record."""
        return self.pool if isinstance(self.pool, tuple) else (self.pool,) * self.records

    @property
    def length(self) -> int:
        """Samples after pooling (the same for every record)."""
        return self.record_steps[0] // self.record_pools[0]

    @property
    def channels(self) -> int:
        """Input channels: per record the output record, and the input record when ``inputs``."""
        return self.records * (2 if self.inputs else 1)

    def to_dict(self) -> dict:
        """JSON-serialisable form; ``from_dict`` (or ``EncoderConfig(**d)``) rebuilds it.

        Returns
        -------
        dict
            Field name -> value, tuples as lists.
        """
        d = asdict(self)
        d["dense"] = list(self.dense)
        for key in ("steps", "pool"):
            if isinstance(d[key], tuple):
                d[key] = list(d[key])
        return d

    @classmethod
    def from_dict(cls, d: dict) -> EncoderConfig:
        """The config of a ``to_dict`` result (lists back to tuples).

        Parameters
        ----------
        d : dict
            Field name -> value.

        Returns
        -------
        EncoderConfig
        """
        d = dict(d)
        d["dense"] = tuple(d.get("dense", (10, 10)))
        for key in ("steps", "pool"):
            if isinstance(d.get(key), list):
                d[key] = tuple(d[key])
        return cls(**d)


class Encoder(nn.Module):
    """Residual 1-D CNN of paper Sec. III-A: records ``(batch, channels, steps)`` -> raw
    parameters ``(batch, p)``.

    Main path: ``depth`` convolutions (Eq. 8 + activation); shortcut: one convolution from the
    input; both concatenated along channels, flattened, optionally joined by scalar features,
    then the dense layers (Eq. 7) and a linear output layer.

    Parameters
    ----------
    config : EncoderConfig
        With ``steps`` and ``outputs`` set (>= 1).

    Raises
    ------
    ValueError
        ``config.steps`` or ``config.outputs`` unset.
    """

    def __init__(self, config: EncoderConfig):
        super().__init__()
        if min(config.record_steps) < 1 or config.outputs < 1:
            raise ValueError(
                "config.steps and config.outputs must be set (>= 1) to build an Encoder; "
                f"got steps={config.steps}, outputs={config.outputs}"
            )
        self.config = config
        act = _ACTIVATIONS[config.activation]
        pad = config.kernel // 2
        self.pool = (nn.AvgPool1d(config.pool) if config.records == 1 and config.pool > 1
                     else nn.Identity())
        layers: list[nn.Module] = []
        channels = config.channels
        for _ in range(config.depth):
            layers += [nn.Conv1d(channels, config.width, config.kernel, padding=pad), act()]
            channels = config.width
        self.main = nn.Sequential(*layers)
        self.shortcut = nn.Sequential(
            nn.Conv1d(config.channels, config.width, config.kernel, padding=pad), act()
        )
        length = config.length
        head: list[nn.Module] = []
        width = 2 * config.width * length + config.features
        for hidden in config.dense:
            head += [nn.Linear(width, hidden), act()]
            width = hidden
        head.append(nn.Linear(width, config.outputs))
        self.head = nn.Sequential(*head)

    def forward(self, records, features: torch.Tensor | None = None) -> torch.Tensor:
        """Map records to raw structure parameters.

        Parameters
        ----------
        records : (batch, channels, steps) tensor, or a sequence of them
            Normalised records (Eq. 15); for several records one
            ``(batch, channels / records, steps_r)`` tensor per record.
        features : (batch, features) tensor, optional
            Scalar features; None when ``config.features == 0``.

        Returns
        -------
        theta : (batch, outputs) tensor
            Raw parameters for the structure.
        """
        cfg = self.config
        if cfg.records == 1:
            x = self.pool(records)
        else:
            # Each record pooled by its own factor to the common length, then stacked as channels.
            x = torch.cat([nn.functional.avg_pool1d(r, p)[..., : cfg.length] if p > 1
                           else r[..., : cfg.length]
                           for r, p in zip(records, cfg.record_pools, strict=True)], dim=1)
        # the first main convolution and the shortcut read the same input with the same kernel:
        # one convolution of their stacked weights (on CPU one convolution of 2 w channels
        # costs less than one of w), then the activation, then the rest of the main path
        first, short = self.main[0], self.shortcut[0]
        both = self.main[1](nn.functional.conv1d(
            x, torch.cat([first.weight, short.weight]), torch.cat([first.bias, short.bias]),
            padding=first.padding))
        w = cfg.width
        z = torch.cat([self.main[2:](both[:, :w]), both[:, w:]], dim=1).flatten(1)
        if self.config.features:
            z = torch.cat([z, features], dim=1)
        return self.head(z)
