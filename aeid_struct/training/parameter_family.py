"""The family of a physical structure: true systems drawn by sampling its parameters in a box
and mapping them through the structure's own CasADi map, with the true parameters kept beside
each system (what the training statistics compare the estimates with, so that no inverse map is
needed to train)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from aeid_struct.structures import ccf_coefficients, ccf_matrices
from aeid_struct.training.checks import count as counted
from aeid_struct.training.checks import generator, value_range
from aeid_struct.training.families import Systems

__all__ = ["ParameterFamily"]


class ParameterFamily:
    """True systems of a :class:`~aeid_struct.structures.Physical` structure: parameters drawn
    in a box, mapped through ``structure.function``, realised in bottom-row CCF (paper Eq. 5).

    Parameters
    ----------
    structure : Physical
        The structure whose parameters are drawn (its map, order and records).
    bounds : dict name -> (lo, hi), optional
        The box to draw from; the structure's bounds by default (a narrower box trains on part
        of the range; a wider one is refused: the encoder cannot output beyond its bounds).
    log : bool or sequence of str
        Parameters drawn log-uniformly (all with True; their box must be positive); the others
        uniformly.

    Raises
    ------
    ValueError
        Not a physical structure, a box that names other parameters or leaves the structure's,
        or a log draw over a box that is not positive.
    """

    def __init__(self, structure, *, bounds: Mapping | None = None,
                 log: bool | tuple = False) -> None:
        if not hasattr(structure, "function") or not hasattr(structure, "bounds"):
            raise ValueError(f"structure must be a Physical structure (its parameters are "
                             f"drawn); got {type(structure).__name__}")
        own = structure.bounds
        box = dict(own) if bounds is None else dict(bounds)
        if set(box) != set(own):
            raise ValueError(f"bounds must name the structure's parameters {list(own)}; got "
                             f"{sorted(box)}")
        for name, pair in box.items():
            lo, hi = value_range(f"bounds[{name!r}]", pair)
            if not (lo < hi and own[name][0] <= lo and hi <= own[name][1]):
                raise ValueError(f"bounds[{name!r}] must lie within the structure's "
                                 f"{own[name]} with lo < hi; got {(lo, hi)}")
            box[name] = (lo, hi)
        logged = tuple(own) if log is True else () if log is False else tuple(log)
        for name in logged:
            if name not in box or box[name][0] <= 0:
                raise ValueError(f"log names {name!r}, which must be a parameter with a "
                                 f"positive box; got {box.get(name)}")
        self.structure, self.bounds, self.log = structure, box, logged

    @property
    def n(self) -> int:
        """The systems' order."""
        return self.structure.n

    @property
    def records(self) -> int:
        """Systems per parameter set (the structure's records)."""
        return self.structure.records

    @property
    def shared_inputs(self) -> tuple[int, ...] | None:
        """Per record, the input it reads where the records are channels of one record
        (``Physical(mechanism, channels=...)``): records of one input are simulated with one
        excitation, as one experiment records them; None: independent records."""
        channels = getattr(self.structure, "channels", None)
        return None if channels is None else tuple(i for _, i in channels)

    @property
    def shared_outputs(self) -> tuple[int, ...] | None:
        """Per record, the output it adds to where the records are the channels of one record
        whose inputs move at once (``Physical(mechanism, outputs=..., inputs=...)``,
        ``Physical.groups``): records of one output are simulated each from its input and
        summed into one measured output; None: each record its own output."""
        return getattr(self.structure, "groups", None)

    def __repr__(self) -> str:
        return (f"ParameterFamily({self.structure!r}, bounds={self.bounds}, "
                f"log={self.log})")

    def draw(self, count: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """``count`` parameter sets in the box.

        Parameters
        ----------
        count : int
        rng : numpy.random.Generator

        Returns
        -------
        dict name -> (count,) array
        """
        count = counted("count", count)
        generator(rng)
        out = {}
        for name, (lo, hi) in self.bounds.items():
            if name in self.log:
                out[name] = np.exp(rng.uniform(math.log(lo), math.log(hi), size=count))
            else:
                out[name] = rng.uniform(lo, hi, size=count)
        return out

    def sample(self, count: int, rng: np.random.Generator) -> Systems:
        """``count`` systems of the family, with their parameters.

        Parameters
        ----------
        count : int
        rng : numpy.random.Generator

        Returns
        -------
        Systems
            ``A (count, n, n)`` (``(count, R, n, n)`` for ``R`` records), ... in bottom-row
            CCF; ``params`` the drawn parameters.
        """
        params = self.draw(count, rng)
        return Systems(*self.systems(params), params)

    def systems(self, params: Mapping[str, np.ndarray]) -> tuple:
        """The structure's models of parameter sets, in bottom-row CCF.

        Parameters
        ----------
        params : dict name -> (count,) array

        Returns
        -------
        A, b, c, d : arrays
            ``(count, [R,] n, n)``, ``(count, [R,] n)``, ``(count, [R,] n)``, ``(count, [R])``.
        """
        function, n, R = self.structure.function, self.n, self.records
        count = len(next(iter(params.values())))
        out = function.map(count)(**{k: np.asarray(v, float).reshape(1, count)
                                     for k, v in params.items()})
        keys = ["A", "B", "C", "D"] if R == 1 else [f"{k}{r}" for r in range(1, R + 1)
                                                     for k in "ABCD"]
        parts = []
        for r in range(R):
            A, B, C, D = (np.array(out[k]) for k in keys[4 * r: 4 * r + 4])
            A = A.reshape(n, count, n).transpose(1, 0, 2)        # mapped: (n, n * count)
            b = B.reshape(n, count).T
            c = C.reshape(count, n)
            a, num = ccf_coefficients(A, b, c)
            Ac, bc, cc = ccf_matrices(a, num)
            parts.append((Ac, bc, cc, D.reshape(count)))
        if R == 1:
            return parts[0]
        return tuple(np.stack([p[i] for p in parts], 1) for i in range(4))
