"""Numeric evaluation of a ``casadi.Function`` through its buffer: how the library evaluates a
CasADi map (a physical structure's, an inverse, a refinement graph) on numpy arrays."""

from __future__ import annotations

import threading

import casadi
import numpy as np

__all__ = ["Numeric", "expanded"]


class Numeric:
    """Numeric evaluation of a ``casadi.Function`` through its buffer.

    Why: a Python call of a CasADi Function converts every numpy argument to a DM and every
    result back, which would dominate a refinement of about a millisecond; the buffer reads and
    writes numpy memory directly. A buffer holds the pointers of one evaluation and its work
    memory, so each thread evaluates through its own (``threading.local``): two threads that
    shared one could each read the other's arguments.

    Parameters
    ----------
    function : casadi.Function
        Evaluated with contiguous float64 vectors of its inputs' sizes (CasADi's column-major
        order); results come back as flat float64 arrays.
    """

    def __init__(self, function: casadi.Function) -> None:
        self.function = function
        self.sizes = [function.nnz_out(i) for i in range(function.n_out())]
        self._local = threading.local()

    def __getstate__(self) -> dict:
        return {"function": self.function}        # the buffers are rebuilt where it is read

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["function"])

    @property
    def buffer(self):
        """The calling thread's ``casadi.FunctionBuffer``, made on its first use there."""
        return self._buffer()[0]

    def _buffer(self) -> tuple:
        got = self._local.__dict__.get("buffer")
        if got is None:
            got = self._local.buffer = self.function.buffer()
        return got

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        buffer, evaluate = self._buffer()
        out = [np.empty(k) for k in self.sizes]
        for i, a in enumerate(args):
            buffer.set_arg(i, memoryview(a))
        for i, r in enumerate(out):
            buffer.set_res(i, memoryview(r))
        evaluate()
        return out

    def stats(self) -> dict:
        """The Function's statistics after the last evaluation (a solver's iterations, status).

        Returns
        -------
        dict
        """
        return self.buffer.stats()


def expanded(function: casadi.Function) -> casadi.Function:
    """``function`` as an SX Function where it expands (a map with a rootfinder does not).

    Why: SX evaluates a small map in a few microseconds, MX's virtual machine in tens.

    Parameters
    ----------
    function : casadi.Function

    Returns
    -------
    casadi.Function
    """
    try:
        return function.expand()
    except RuntimeError:
        return function
