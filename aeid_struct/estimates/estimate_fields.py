"""What an :class:`~aeid_struct.estimates.Estimate` reads rather than computes: the base
class of its fields taken from its ``info``, its record and its provenance (and its model in the
shapes of several channels), and the decorator of the derived properties that a generic
estimate carries in ``info``. The seam: reading what the estimate holds, apart from deriving
its response, fit and flags (``estimate.py``).
"""

from __future__ import annotations

from functools import wraps

import numpy as np

__all__ = ["EstimateFields", "from_info"]


def from_info(key: str):
    """A derived property that returns ``info[key]`` where the estimate carries it (a generic
    estimate's, made with its delay and offset) and computes it otherwise."""
    def wrap(compute):
        @wraps(compute)
        def get(self):
            return self.info[key] if key in self.info else compute(self)
        return get
    return wrap


class EstimateFields:
    """Fields of an :class:`Estimate` read from its ``info`` (the model of a record: 0 where
    none was identified) and its provenance, and its model in the shapes of several
    channels."""

    @property
    def _inverse(self):
        return self.provenance.inverse

    @property
    def delay(self):
        """Input delay in samples (``info["delay"]``): an int, or ``(m,)`` ints, one per input
        of a model of several inputs."""
        delay = self.info.get("delay", 0)
        return int(delay) if np.ndim(delay) == 0 else np.asarray(delay, dtype=int)

    @property
    def offset(self):
        """Constant output offset (``info["y_offset"]``): a float, ``(p,)`` for several
        outputs, a tuple per record for several experiments."""
        offset = self.info.get("y_offset", 0.0)
        if isinstance(offset, tuple):
            return offset
        return float(offset) if np.ndim(offset) == 0 else np.asarray(offset)

    @property
    def intersample(self) -> str:
        """The input between samples the model was identified under (``info["intersample"]``,
        ``records.Record.intersample``): ``"foh"`` (linear, the paper's Eq. 10-13) or
        ``"zoh"`` (held)."""
        return str(self.info.get("intersample", "foh"))

    # -- the record and the provenance ---------------------------------------------------------
    @property
    def y(self):
        """The outputs the estimate was made from: ``(steps,)`` or ``(batch, steps)`` (a tuple
        of ``R`` for several records)."""
        return self.record.given(self.record.y)

    @property
    def u(self):
        """The inputs, shaped like ``y`` (a unit step where none was given)."""
        return self.record.given(self.record.u)

    @property
    def dt(self):
        """Sample time (a tuple of ``R`` for several records)."""
        return self.record.times

    @property
    def structure(self):
        """The structure the model is in, or None (:class:`Provenance`)."""
        return self.provenance.structure

    @property
    def initial(self) -> str:
        """``"rest"`` or ``"fitted"`` (:class:`Provenance`)."""
        return self.provenance.initial

    @property
    def training_range(self):
        """The identifier's training range, or None (:class:`Provenance`)."""
        return self.provenance.training_range

    @property
    def records(self) -> int:
        """Records the estimate was made from jointly (1, or ``R`` for a tuple of records)."""
        return self.record.records

    @property
    def batched(self) -> bool:
        """Whether the estimate has a batch axis."""
        return self.record.batched

    # -- the model in the shapes of several channels ---------------------------------------------
    @property
    def _matrices(self) -> bool:
        """Whether ``b, c, d`` already hold ``B, C, D`` (a model of several channels: ``b`` has
        as many axes as ``A``)."""
        return np.ndim(self.b) == np.ndim(self.A)

    @property
    def B(self) -> np.ndarray:
        """``(..., n, m)`` input matrix (``m = 1``: ``b`` as a column)."""
        return np.asarray(self.b) if self._matrices else np.asarray(self.b)[..., :, None]

    @property
    def C(self) -> np.ndarray:
        """``(..., p, n)`` output matrix (``p = 1``: ``c`` as a row)."""
        return np.asarray(self.c) if self._matrices else np.asarray(self.c)[..., None, :]

    @property
    def D(self) -> np.ndarray:
        """``(..., p, m)`` feedthrough (``p = m = 1``: ``d``)."""
        d = np.asarray(self.d, dtype=np.float64)
        return d if self._matrices else d[..., None, None]
