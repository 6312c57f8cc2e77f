"""The assembled model: a batch of continuous-time SISO state spaces ``(A, b, c, d)``."""

from __future__ import annotations

from dataclasses import dataclass

import control
import numpy as np
import torch

__all__ = ["System"]


def _tensor(name: str, value) -> None:
    if not isinstance(value, (torch.Tensor, np.ndarray)):
        raise ValueError(f"{name} must be a torch tensor (or a numpy array); got "
                         f"{type(value).__name__}")


@dataclass(frozen=True, eq=False)
class System:
    """A batch of continuous-time SISO models ``xdot = A x + b u``, ``y = c^T x + d u``.

    A single model (from an unbatched ``theta``) drops the batch axis: ``A (n, n)``, ``d ()``.
    The models of a several-record structure (:attr:`Structure.records` ``R > 1``) carry a record
    axis after the batch axis: ``A (batch, R, n, n)``, ``b, c (batch, R, n)``, ``d (batch, R)``.
    Unpacks as ``A, b, c, d = system``.

    Attributes
    ----------
    A : torch.Tensor, (batch, n, n)
    b : torch.Tensor, (batch, n)
    c : torch.Tensor, (batch, n)
    d : torch.Tensor, (batch,)

    Raises
    ------
    ValueError
        If a field is not a tensor (or numpy array) or the shapes do not match ``A``'s.
    """

    A: torch.Tensor
    b: torch.Tensor
    c: torch.Tensor
    d: torch.Tensor

    def __post_init__(self) -> None:
        A, b, c, d = self.A, self.b, self.c, self.d
        _tensor("A", A)
        if A.ndim not in (2, 3, 4) or A.shape[-1] != A.shape[-2]:
            raise ValueError(f"A must have shape (batch, n, n) or (n, n) (or (batch, records, "
                             f"n, n)); got {tuple(A.shape)}")
        lead, n = tuple(A.shape[:-2]), A.shape[-1]
        for name, x, shape in (("b", b, (*lead, n)), ("c", c, (*lead, n)), ("d", d, lead)):
            _tensor(name, x)
            if tuple(x.shape) != shape:
                raise ValueError(
                    f"{name} must have shape {shape} to match A {tuple(A.shape)}; "
                    f"got {tuple(x.shape)}"
                )

    @property
    def n(self) -> int:
        """The order (number of states)."""
        return self.A.shape[-1]

    def to_control(self) -> list[control.StateSpace] | control.StateSpace:
        """python-control models, float64.

        Returns
        -------
        control.StateSpace or list
            One StateSpace for one model; a list for a batch (a list of lists for a batch of
            several-record models).
        """
        A, b, c, d = (x.detach().cpu().to(torch.float64).numpy() for x in self)
        if A.ndim == 2:
            return control.ss(A, b[:, None], c[None, :], d.reshape(1, 1))
        if A.ndim == 4:   # (batch, records, n, n): a list per batch row
            return [System(*(torch.from_numpy(x[i]) for x in (A, b, c, d))).to_control()
                    for i in range(A.shape[0])]
        return [
            control.ss(A[i], b[i][:, None], c[i][None, :], d[i].reshape(1, 1))
            for i in range(A.shape[0])
        ]

    def __iter__(self):
        """Unpack as ``A, b, c, d = system``."""
        return iter((self.A, self.b, self.c, self.d))
