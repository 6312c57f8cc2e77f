"""A ``casadi.Function`` as a batched, differentiable torch operation.

:class:`CasadiOp` wraps a CasADi function ``f`` so that a batch of inputs goes through ``f`` in one
call and gradients flow back through CasADi's own reverse mode (algorithmic differentiation of the
symbolic expression graph), not through finite differences or a re-implementation in torch.

Layout conventions
------------------
CasADi stores every value as a matrix ``(rows, cols)``; torch tensors carry a leading batch axis.
An input or output of CasADi shape ``(rows, cols)`` is the torch tensor

====================  ==================  ==========================
CasADi shape          kind                torch shape
====================  ==================  ==========================
``(1, 1)``            scalar              ``(batch,)``
``(rows, 1)``         column vector       ``(batch, rows)``
``(rows, cols)``      anything else       ``(batch, rows, cols)``
====================  ==================  ==========================

so a row vector ``C (1, n)`` is the tensor ``(batch, 1, n)``. Entry ``[k, i, j]`` of a tensor is
entry ``(i, j)`` of the k-th sample's matrix, exactly as in numpy. CasADi is column-major
internally; the conversion below goes through numpy's row-major ``(rows, cols)`` arrays, which
CasADi reads by index (not by memory order), so no transposition is ever implied by the layout.

Batching uses ``f.map(batch)``: the mapped function takes the samples side by side,
``[X_0, X_1, ..., X_{batch-1}]`` of shape ``(rows, batch * cols)``. :func:`_to_casadi` and
:func:`_from_casadi` convert between that and ``(batch, rows, cols)``.

Precision: CasADi computes in float64. Inputs may be float32 or float64 tensors (mixed dtypes are
promoted); outputs and gradients come back in that dtype and on the inputs' device.

Parallelisation: the mapped functions are evaluated ``"serial"`` by default: for the small
maps this library wraps, starting threads costs more than it saves; pass
``parallelization="thread"`` for expensive functions.

Only first derivatives are supported (``backward`` is ``once_differentiable``): enough for
training and for ``torch.autograd.gradcheck``.
"""

from __future__ import annotations

from collections import OrderedDict

import casadi
import numpy as np
import torch
from torch.autograd.function import once_differentiable

__all__ = ["CasadiOp"]

_PARALLELIZATIONS = ("serial", "thread")
#: How many mapped functions (one per batch size) each CasadiOp keeps.
_CACHE_SIZE = 16


def _torch_shape(rows: int, cols: int) -> tuple[int, ...]:
    """Per-sample torch shape of a CasADi ``(rows, cols)`` value (see the module docstring)."""
    if (rows, cols) == (1, 1):
        return ()
    if cols == 1:
        return (rows,)
    return (rows, cols)


def _fmt_shape(shape: tuple[int, ...]) -> str:
    return "(" + ", ".join(["batch", *(str(s) for s in shape)]) + ")"


def _to_casadi(x: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """(batch, *torch shape) -> (rows, batch * cols): the samples side by side, as ``map`` wants."""
    batch = x.shape[0]
    return x.reshape(batch, rows, cols).transpose(1, 0, 2).reshape(rows, batch * cols)


def _from_casadi(X: np.ndarray, batch: int, rows: int, cols: int) -> np.ndarray:
    """(rows, batch * cols) -> (batch, rows, cols): inverse of :func:`_to_casadi`."""
    return np.ascontiguousarray(X.reshape(rows, batch, cols).transpose(1, 0, 2))


class CasadiOp:
    """A ``casadi.Function`` as a batched torch operation with CasADi's reverse-mode gradients.

    Calling ``op(*tensors)`` (positional, in the function's input order) or ``op(**named)`` returns
    a ``dict`` output name -> tensor ``(batch, ...)``, with shapes as in the module docstring.

    Parameters
    ----------
    function : casadi.Function
        Any CasADi function with at least one input. Inputs and outputs keep their names.
    parallelization : {"serial", "thread"}
        How ``function.map(batch, ...)`` evaluates the batch (see the module docstring).

    Raises
    ------
    TypeError
        If ``function`` is not a casadi.Function.
    ValueError
        If it has no inputs, or ``parallelization`` is not one of the two.

    Examples
    --------
    >>> k, m = casadi.SX.sym("k"), casadi.SX.sym("m")
    >>> f = casadi.Function("f", [k, m], [casadi.vertcat(k / m, k * m)], ["k", "m"], ["v"])
    >>> CasadiOp(f)(k=torch.tensor([1.0, 2.0]), m=torch.tensor([2.0, 4.0]))["v"]
    tensor([[0.5000, 2.0000],
            [0.5000, 8.0000]])
    """

    def __init__(self, function: casadi.Function, *, parallelization: str = "serial") -> None:
        if not isinstance(function, casadi.Function):
            raise TypeError(f"function must be a casadi.Function; got {type(function).__name__}")
        if function.n_in() < 1:
            raise ValueError(
                f"function {function.name()!r} has no inputs; CasadiOp needs at least one input "
                "to know the batch size"
            )
        if parallelization not in _PARALLELIZATIONS:
            raise ValueError(
                f"parallelization must be one of {', '.join(_PARALLELIZATIONS)}; "
                f"got {parallelization!r}"
            )
        self.function = function
        self.parallelization = parallelization
        self.name_in: tuple[str, ...] = tuple(function.name_in())
        self.name_out: tuple[str, ...] = tuple(function.name_out())
        self._size_in = tuple(function.size_in(i) for i in range(function.n_in()))
        self._size_out = tuple(function.size_out(i) for i in range(function.n_out()))
        #: Per-sample torch shapes of the inputs and outputs.
        self.shape_in = {
            nm: _torch_shape(*s) for nm, s in zip(self.name_in, self._size_in, strict=True)
        }
        self.shape_out = {
            nm: _torch_shape(*s) for nm, s in zip(self.name_out, self._size_out, strict=True)
        }
        self._reverse = function.reverse(1)
        self._maps: OrderedDict[int, tuple[casadi.Function, casadi.Function]] = OrderedDict()

    def __repr__(self) -> str:
        ins = ", ".join(f"{n}{_fmt_shape(s)}" for n, s in self.shape_in.items())
        outs = ", ".join(f"{n}{_fmt_shape(s)}" for n, s in self.shape_out.items())
        return f"CasadiOp({self.function.name()}: {ins} -> {outs})"

    # -- mapped functions, cached per batch size -------------------------------------------------
    def _mapped(self, batch: int) -> tuple[casadi.Function, casadi.Function]:
        if batch in self._maps:
            self._maps.move_to_end(batch)
            return self._maps[batch]
        pair = (
            self.function.map(batch, self.parallelization),
            self._reverse.map(batch, self.parallelization),
        )
        self._maps[batch] = pair
        if len(self._maps) > _CACHE_SIZE:
            self._maps.popitem(last=False)
        return pair

    # -- numpy evaluation (float64, no autograd) -------------------------------------------------
    def _forward_numpy(self, arrays: list[np.ndarray]) -> list[np.ndarray]:
        batch = arrays[0].shape[0]
        if batch == 0:
            return [np.zeros((0, *self.shape_out[n])) for n in self.name_out]
        fmap, _ = self._mapped(batch)
        args = [_to_casadi(x, *s) for x, s in zip(arrays, self._size_in, strict=True)]
        res = fmap.call(args)
        return [
            _from_casadi(r.full(), batch, *s).reshape(batch, *self.shape_out[n])
            for r, s, n in zip(res, self._size_out, self.name_out, strict=True)
        ]

    def _reverse_numpy(
        self, arrays: list[np.ndarray], outputs: list[np.ndarray], seeds: list[np.ndarray]
    ) -> list[np.ndarray]:
        # f.reverse(1) has inputs (inputs..., nominal outputs..., adjoint seeds...) and outputs the
        # adjoint sensitivities d<seed, f(x)>/dx, one per input: a vector-Jacobian product.
        batch = arrays[0].shape[0]
        if batch == 0:
            return [np.zeros((0, *self.shape_in[n])) for n in self.name_in]
        _, rmap = self._mapped(batch)
        args = [_to_casadi(x, *s) for x, s in zip(arrays, self._size_in, strict=True)]
        args += [_to_casadi(y, *s) for y, s in zip(outputs, self._size_out, strict=True)]
        args += [_to_casadi(g, *s) for g, s in zip(seeds, self._size_out, strict=True)]
        res = rmap.call(args)
        return [
            _from_casadi(r.full(), batch, *s).reshape(batch, *self.shape_in[n])
            for r, s, n in zip(res, self._size_in, self.name_in, strict=True)
        ]

    # -- the public call -------------------------------------------------------------------------
    def _collect(self, args: tuple, kwargs: dict) -> list[torch.Tensor]:
        fname = self.function.name()
        expected = ", ".join(self.name_in)
        if args and kwargs:
            raise ValueError(
                f"CasadiOp({fname}) takes its inputs either all positional or all by name; "
                f"got {len(args)} positional and {len(kwargs)} named"
            )
        if kwargs:
            unknown = [k for k in kwargs if k not in self.name_in]
            if unknown:
                raise ValueError(
                    f"unknown input {unknown[0]!r} for CasadiOp({fname}); valid inputs: {expected}"
                )
            missing = [n for n in self.name_in if n not in kwargs]
            if missing:
                raise ValueError(
                    f"missing input {missing[0]!r} for CasadiOp({fname}); expected inputs: "
                    f"{expected}"
                )
            args = tuple(kwargs[n] for n in self.name_in)
        if len(args) != len(self.name_in):
            raise ValueError(
                f"CasadiOp({fname}) expects {len(self.name_in)} inputs ({expected}); "
                f"got {len(args)}"
            )
        tensors = []
        batch, first = None, None
        for name, x in zip(self.name_in, args, strict=True):
            t = torch.as_tensor(x)
            if not t.is_floating_point():
                raise ValueError(
                    f"input {name!r} of CasadiOp({fname}) must be a float32 or float64 tensor; "
                    f"got {t.dtype}"
                )
            shape = self.shape_in[name]
            if t.ndim != len(shape) + 1 or tuple(t.shape[1:]) != shape:
                raise ValueError(
                    f"input {name!r} of CasadiOp({fname}) must have shape {_fmt_shape(shape)}; "
                    f"got {tuple(t.shape)}"
                )
            if batch is None:
                batch, first = t.shape[0], name
            elif t.shape[0] != batch:
                raise ValueError(
                    f"input {name!r} of CasadiOp({fname}) has batch size {t.shape[0]}, but input "
                    f"{first!r} has batch size {batch}"
                )
            tensors.append(t)
        return tensors

    def __call__(self, *args: torch.Tensor, **kwargs: torch.Tensor) -> dict[str, torch.Tensor]:
        tensors = self._collect(args, kwargs)
        outputs = _CasadiFunction.apply(self, *tensors)
        return dict(zip(self.name_out, outputs, strict=True))

    def evaluate(self, *args, **kwargs) -> dict[str, np.ndarray]:
        """Float64 numpy outputs, no autograd; same layout, arguments and checks as a call.

        Parameters
        ----------
        *args : (batch, ...) tensors
            The inputs in the function's order, or
        **kwargs : (batch, ...) tensors
            the inputs by name.

        Returns
        -------
        dict str -> numpy.ndarray
            Output name -> ``(batch, ...)`` float64 array.

        Raises
        ------
        ValueError
            For missing, unknown or extra inputs, non-float tensors, wrong shapes, and batch
            sizes that differ.
        """
        arrays = [t.detach().to("cpu", torch.float64).numpy() for t in self._collect(args, kwargs)]
        return dict(zip(self.name_out, self._forward_numpy(arrays), strict=True))


class _CasadiFunction(torch.autograd.Function):
    """forward: f.map(batch); backward: f.reverse(1).map(batch) (CasADi's own derivatives)."""

    @staticmethod
    def forward(ctx, op: CasadiOp, *tensors: torch.Tensor):
        dtype = tensors[0].dtype
        for t in tensors[1:]:
            dtype = torch.promote_types(dtype, t.dtype)
        device = tensors[0].device
        arrays = [t.detach().to("cpu", torch.float64).numpy() for t in tensors]
        outputs = op._forward_numpy(arrays)
        ctx.op, ctx.arrays, ctx.outputs = op, arrays, outputs
        ctx.dtypes = [t.dtype for t in tensors]
        ctx.device = device
        return tuple(torch.from_numpy(y).to(device=device, dtype=dtype) for y in outputs)

    @staticmethod
    @once_differentiable
    def backward(ctx, *grads: torch.Tensor):
        seeds = [g.detach().to("cpu", torch.float64).numpy() for g in grads]
        adj = ctx.op._reverse_numpy(ctx.arrays, ctx.outputs, seeds)
        return (
            None,
            *(
                torch.from_numpy(a).to(device=ctx.device, dtype=dt)
                for a, dt in zip(adj, ctx.dtypes, strict=True)
            ),
        )
