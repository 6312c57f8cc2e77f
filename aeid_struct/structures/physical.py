r"""Physical parameters in bounds, mapped to a state space by a CasADi function.

A CasADi map from named physical parameters to ``(A, B, C, D)``; elements are the parameters,
``element = lo + (hi - lo) * sigmoid(theta)`` within the given bounds.

*Several records, one parameter set.* A map with outputs ``A1, B1, C1, D1, ..., AR, .., DR``
describes ``R`` SISO systems (e.g. the leg's two subsystems, ``symbolic.leg.joint_map``) that
share the parameters, each identified from its own record. Its models carry a record axis
after the batch axis: ``A (batch, R, n, n), b, c (batch, R, n), d (batch, R)``
(:attr:`Structure.records`).
"""

from __future__ import annotations

import math

import casadi
import numpy as np
import torch

from aeid_struct.structures import maps as named_maps
from aeid_struct.structures.base import Structure
from aeid_struct.structures.casadi_torch import CasadiOp
from aeid_struct.structures.constraints import ElementMap
from aeid_struct.structures.mechanical import channel_specs, is_mechanism, mechanism_structure
from aeid_struct.structures.realisation import ccf_coefficients, ccf_matrices
from aeid_struct.structures.system import System

__all__ = ["Physical"]


class Physical(Structure):
    """Physical parameters in bounds, mapped to a state space by a CasADi function.

    ``elements_of`` (strict) also checks that the parameters rebuild the model: the CCF
    coefficients of ``function(parameters)`` must match the model's to ``1e-6`` relative.

    Parameters
    ----------
    function : casadi.Function or symbolic.Mechanism
        A mechanism is turned into the CCF map of one channel (``Mechanism.channel``) of its
        parameters not in ``known``, after a check that the channel's records determine every
        one of them in ``bounds`` (``symbolic.identifiability``; refused by name otherwise).
        A Function has scalar inputs (the physical parameters, e.g. ``k, d, m``; their order
        is the element order) and outputs ``"A" (n, n), "B" (n, 1), "C" (1, n), "D" (1, 1)``
        (others are ignored) -- or, for ``R`` systems sharing the parameters, ``"A1", .., "D1", ..,
        "AR", .., "DR"`` of those shapes (then :attr:`records` is ``R``). Evaluated through
        ``CasadiOp``, so gradients are CasADi's.
    bounds : dict name -> (lo, hi)
        For every input, ``lo < hi``: ``element = lo + (hi - lo) sigmoid(theta)``.
    inverse : casadi.Function, optional
        Inputs ``"A", "B", "C", "D"`` holding a model in bottom-row CCF (shapes as above;
        ``"A1", .., "DR"`` for ``R`` records, e.g. ``symbolic.leg.joint_inverse``), scalar
        outputs named like (a subset of) the parameters. Needed by :meth:`elements_of`,
        which first converts the given realisation to CCF. A parameter the inverse does not
        return (e.g. ``d`` of the unstable leg, which its transfer function does not contain)
        is set to its fixed value if fixed, else to the midpoint of its bounds (``raw = 0``).

    known : dict name -> float, optional
        A mechanism's parameters held at known values (gravity, a lever ratio).
    channel : (output, input) or (output, input, states), optional
        A mechanism's channel the records hold; ``(0, 0)`` by default.
    channels : sequence of (output, input) or (output, input, states), optional
        Several channels of a mechanism's record, each output once (a cart's position and a
        pole's angle from one force; the upright leg's two decoupled inputs): one record per
        channel (:attr:`records`), all of one order, checked identifiable together; a
        :class:`~aeid_struct.records.Record` with several outputs is split by them
        (:attr:`channels`). With a Function of ``R`` records (``Mechanism.channels``, a named
        factory), its ``R`` pairs ``(output, input)``.
    experiments : bool
        With a mechanism's ``channels``: each channel is a record of its own experiment, in
        which its input alone moves (the other inputs at their operating values), so outputs
        may repeat (a coupled mechanism recorded one input at a time; a record of all inputs
        at once is ``outputs=..., inputs=...``). The records are passed one per channel
        (a sequence of ``R``), as for the joint leg (:attr:`channels` is None).
    outputs, inputs : sequences of int, optional
        A mechanism's record of these outputs in which these inputs move at once (a coupled
        mechanism driven by all its actuators together): its records are the channels
        ``(output, input)``, output after output (:attr:`channels`), and each output is the
        sum of its channels' responses (:attr:`groups`); checked identifiable from every
        output of every input. A :class:`~aeid_struct.records.Record` of those outputs and
        inputs is split into them.
    **operating
        A mechanism's operating point: ``q``, ``u``, ``guess`` of ``Mechanism.linearise``.

    Raises
    ------
    ValueError
        If ``function`` or ``inverse`` is not a casadi.Function of the described inputs and
        outputs, or ``bounds`` does not give finite ``lo < hi`` for every input.
    """

    def __init__(self, function: casadi.Function, *, bounds: dict, inverse=None,
                 known: dict | None = None, channel=None, channels=None,
                 experiments: bool = False, outputs=None, inputs=None, **operating) -> None:
        self._channels = None
        if is_mechanism(function) or experiments is not False or outputs is not None \
                or inputs is not None:
            function, self._channels = mechanism_structure(
                function, bounds, known, channel, channels, experiments, operating,
                outputs, inputs)
        elif known is not None or channel is not None or operating:
            raise ValueError("known, channel and an operating point (q, u, guess) are read "
                             "from a symbolic.Mechanism; a casadi.Function map fixes them itself")
        elif channels is not None:
            # a map of R records that are channels of one record (a named factory's)
            self._channels = tuple(spec[:2] for spec in channel_specs(None, channels))
        if not isinstance(function, casadi.Function):
            raise ValueError(f"function must be a casadi.Function; got {type(function).__name__}")
        fname = function.name()
        names = list(function.name_in())
        for i, nm in enumerate(names):
            if function.size_in(i) != (1, 1):
                raise ValueError(f"input {nm!r} of {fname} must be a scalar (1, 1); "
                                 f"got {function.size_in(i)}")
        outs = list(function.name_out())
        records = 1
        if "A" not in outs and "A1" in outs:
            while f"A{records + 1}" in outs:
                records += 1
        # Unnumbered outputs (A, B, C, D) unless only numbered ones (A1, .., DR) are there.
        self._keys = (["A", "B", "C", "D"] if "A" in outs or "A1" not in outs
                      else [f"{k}{r}" for r in range(1, records + 1) for k in "ABCD"])
        missing = [k for k in self._keys if k not in outs]
        if missing:
            raise ValueError(f"function {fname} must have outputs A, B, C, D; missing "
                             f"{', '.join(missing)} (outputs: {', '.join(outs)}; for several "
                             "records: A1, B1, C1, D1, A2, ..)")
        n = function.size_out(self._keys[0])[0]
        shapes = {k: {"A": (n, n), "B": (n, 1), "C": (1, n), "D": (1, 1)}[k[0]]
                  for k in self._keys}
        for k, s in shapes.items():
            if function.size_out(k) != s:
                raise ValueError(f"output {k!r} of {fname} must have shape {s}; "
                                 f"got {function.size_out(k)}")
        self._records = records
        if self._channels is not None and len(self._channels) != records:
            raise ValueError(f"channels must give one (output, input) per record of {fname} "
                             f"({records}); got {channels!r}")
        if not isinstance(bounds, dict):
            raise ValueError(f"bounds must be a dict name -> (lo, hi); got {type(bounds).__name__}")
        for k in bounds:
            if k not in names:
                raise ValueError(f"bounds has unknown name {k!r}; inputs of {fname}: "
                                 f"{', '.join(names)}")
        maps = {}
        for k in names:
            if k not in bounds:
                raise ValueError(f"bounds is missing {k!r}; every input of {fname} needs "
                                 f"bounds: {', '.join(names)}")
            try:
                lo, hi = (float(v) for v in bounds[k])
            except (TypeError, ValueError):
                raise ValueError(f"bounds[{k!r}] must be a pair (lo, hi); "
                                 f"got {bounds[k]!r}") from None
            if not (math.isfinite(lo) and math.isfinite(hi)):
                raise ValueError(f"bounds[{k!r}] must be finite; got {tuple(bounds[k])}")
            if not lo < hi:
                raise ValueError(f"bounds[{k!r}] must satisfy lo < hi; got {tuple(bounds[k])}")
            maps[k] = ElementMap("interval", lo, hi, note="bounds")
        if inverse is not None:
            _check_inverse(inverse, shapes, names, fname)
        self.function, self.inverse = function, inverse
        if outs != self._keys:
            # Keep only A, B, C, D so that CasadiOp neither computes nor differentiates the rest.
            function = function.slice(fname, list(range(len(names))),
                                      [outs.index(k) for k in self._keys])
        self._op = CasadiOp(function)
        self._inverse_op = None if inverse is None else CasadiOp(inverse)
        super().__init__(n, maps)

    @property
    def records(self) -> int:
        return self._records

    @property
    def channels(self) -> tuple[tuple[int, int], ...] | None:
        """``(output, input)`` of each record where the records are channels of one measured
        record (``Physical(mechanism, channels=...)``), else None."""
        return self._channels

    @property
    def groups(self) -> tuple[int, ...] | None:
        """Per record its output where the records are channels summed into outputs (one
        record of several inputs, ``outputs=..., inputs=...``: an output named twice); else None."""
        channels = self._channels
        if channels is None or len({o for o, _ in channels}) == len(channels):
            return None
        return tuple(o for o, _ in channels)

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """name -> (lo, hi) for every parameter."""
        return {k: (m.lo, m.hi) for k, m in self._maps.items()}

    def _config(self) -> dict:
        out = {
            "function": named_maps.to_entry(self.function),
            "bounds": {k: [lo, hi] for k, (lo, hi) in self.bounds.items()},
            "inverse": None if self.inverse is None else named_maps.to_entry(self.inverse),
        }
        if self._channels is not None:
            out["channels"] = [list(c) for c in self._channels]
        return out

    @classmethod
    def _from_config(cls, args: dict, *, maps=None, trust: bool = False) -> Physical:
        unknown = sorted(set(args) - {"function", "bounds", "inverse", "channels"})
        if unknown or "function" not in args or "bounds" not in args:
            raise ValueError(f"invalid config for Physical: it needs 'function' and 'bounds' "
                             f"(and optionally 'inverse'); got entries {sorted(args)}")
        bounds = args["bounds"]
        if not isinstance(bounds, dict) or not all(
                isinstance(v, (list, tuple)) and len(v) == 2
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
                for v in bounds.values()):
            raise ValueError(f"invalid config for Physical: 'bounds' must be a dict name -> "
                             f"[lo, hi] of numbers; got {bounds!r}")
        inverse = args.get("inverse")
        out = cls(
            named_maps.from_entry(args["function"], "Physical 'function'", maps=maps, trust=trust),
            bounds={k: tuple(v) for k, v in bounds.items()},
            inverse=None if inverse is None else named_maps.from_entry(
                inverse, "Physical 'inverse'", maps=maps, trust=trust),
        )
        if args.get("channels") is not None:
            out._channels = _channels_of(args["channels"], out.records)
        return out

    def _base_repr(self) -> str:
        bounds = ", ".join(f"{k!r}: ({lo:g}, {hi:g})" for k, (lo, hi) in self.bounds.items())
        inv = "None" if self.inverse is None else self.inverse.name()
        return f"Physical({self.function.name()}, bounds={{{bounds}}}, inverse={inv})"

    def _assemble(self, x: torch.Tensor) -> System:
        out = self._op(*x.unbind(1))
        B, n, R = x.shape[0], self.n, self.records
        shape = (B,) if R == 1 else (B, R)
        parts = [out[k].reshape(B, -1) for k in self._keys]      # record-major: A1 B1 C1 D1 A2..
        A, b, c, d = (torch.stack(parts[i::4], 1).reshape(*shape, -1) for i in range(4))
        return System(A.reshape(*shape, n, n), b, c, d.reshape(shape))

    def _casadi_assemble(self, x) -> tuple:
        if self.records > 1:
            raise NotImplementedError(f"{self!r} describes {self.records} records; its CasADi "
                                      "assembly is per record (refine each subsystem alone)")
        out = self.function(**{name: x[i] for i, name in enumerate(self._maps)})
        return out["A"], out["B"], out["C"].T, out["D"]

    def _elements_of(self, A, b, c, d, strict):
        if self._inverse_op is None:
            raise ValueError(f"{self!r} has no inverse: elements_of needs "
                             "Physical(..., inverse=f) with f: (A, B, C, D) in CCF -> parameters")
        a, num = ccf_coefficients(A, b, c)
        Ac, bc, cc = ccf_matrices(a, num)
        R, n = self.records, a.shape[1]
        B = a.shape[0] // R          # rows come record-minor: (batch * R) models
        # B (n, 1) is a column vector -> (batch, n); C (1, n) a matrix -> (batch, 1, n).
        op = self._inverse_op
        inputs = {}
        for r in range(R):
            sfx = "" if self._keys[0] == "A" else str(r + 1)
            rows = slice(r, None, R)
            inputs.update({f"A{sfx}": Ac[rows], f"B{sfx}": bc[rows],
                           f"C{sfx}": cc[rows].reshape(B, 1, n), f"D{sfx}": d[rows]})
        found = op.evaluate(**{k: torch.from_numpy(np.ascontiguousarray(v).reshape(
            B, *op.shape_in[k])) for k, v in inputs.items()})
        x = np.empty((B, self.q))
        for i, (name, m) in enumerate(self._maps.items()):
            if name in found:
                x[:, i] = found[name].reshape(B)
                bad = ~np.isfinite(x[:, i])
                if np.any(bad):
                    raise ValueError(f"inverse {self.inverse.name()} returned a non-finite "
                                     f"{name} for the model in row {int(np.flatnonzero(bad)[0])}")
            else:
                x[:, i] = self._fixed.get(name, 0.5 * (m.lo + m.hi))
        return x

    def _check_range(self, x, A, b, c, d, dtype) -> None:
        _check_rebuilt(self, x, A, b, c, d, dtype)


def _check_rebuilt(structure: Physical, x, A, b, c, d, dtype) -> None:
    """``Physical._check_range``: the parameters ``x`` must rebuild the models ``A, b, c, d``
    (their transfer functions, by CCF coefficients, to ``1e-6`` relative)."""
    # The parameters must rebuild the model: compare transfer functions (CCF coefficients).
    out = structure._op.evaluate(*x.unbind(1))
    B, n = x.shape[0] * structure.records, structure.n
    # the models of each parameter row, record-minor like the given ones
    An, bn, cn, dn = (np.stack([out[k].reshape(x.shape[0], -1) for k in structure._keys[i::4]],
                               1).reshape(B, -1) for i in range(4))
    given = np.concatenate([*ccf_coefficients(A, b, c), d[:, None]], 1)
    rebuilt = np.concatenate([*ccf_coefficients(An.reshape(B, n, n), bn, cn), dn], 1)
    err = np.abs(given - rebuilt).max(1) / (1.0 + np.abs(given).max(1))
    tol = max(1e-6, 10 * math.sqrt(torch.finfo(dtype).eps))
    if np.any(err > tol):
        i = int(np.argmax(err))
        r = i // structure.records
        raise ValueError(
            f"the model (row {r}) is not in the range of {structure!r}: the transfer function "
            f"rebuilt from the recovered parameters differs by {err[i]:.3g} (relative) "
            f"in its CCF coefficients {np.round(given[i], 6)} vs {np.round(rebuilt[i], 6)}"
        )


def _check_inverse(inverse, shapes, names, fname) -> None:
    """``Physical``'s ``inverse``: a Function from the records' CCF to named parameters."""
    if not isinstance(inverse, casadi.Function):
        raise ValueError(f"inverse must be a casadi.Function; got {type(inverse).__name__}")
    if sorted(inverse.name_in()) != sorted(shapes):
        raise ValueError(f"inverse {inverse.name()} must have inputs {', '.join(shapes)}; "
                         f"got {', '.join(inverse.name_in())}")
    for k, s in shapes.items():
        if inverse.size_in(k) != s:
            raise ValueError(f"input {k!r} of inverse {inverse.name()} must have shape {s}; "
                             f"got {inverse.size_in(k)}")
    for i, k in enumerate(inverse.name_out()):
        if k not in names:
            raise ValueError(f"output {k!r} of inverse {inverse.name()} is not a parameter "
                             f"of {fname} ({', '.join(names)})")
        if inverse.size_out(i) != (1, 1):
            raise ValueError(f"output {k!r} of inverse {inverse.name()} must be a scalar; "
                             f"got {inverse.size_out(i)}")


def _channels_of(channels, records: int) -> tuple:
    """A config's ``channels``: ``records`` pairs ``[output, input]``."""
    ok = isinstance(channels, list) and len(channels) == records and all(
        isinstance(c, list) and len(c) == 2 and all(
            isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in c)
        for c in channels)
    if not ok:
        raise ValueError(f"invalid config for Physical: 'channels' must be {records} pairs "
                         f"[output, input] of non-negative integers (one per record); got "
                         f"{channels!r}")
    return tuple(tuple(c) for c in channels)
