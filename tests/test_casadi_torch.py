"""CasadiOp: values against CasADi's own evaluation, Jacobians against casadi.jacobian, gradcheck,
layout (non-square and row/column shapes), validation errors."""

from __future__ import annotations

import casadi
import numpy as np
import pytest
import torch

from aeid_struct.structures import CasadiOp


def _mixed() -> casadi.Function:
    """Inputs x (2, 1), p (1, 1), M (2, 3); outputs of every layout kind, nonlinear in each."""
    x, p, M = casadi.SX.sym("x", 2), casadi.SX.sym("p"), casadi.SX.sym("M", 2, 3)
    Y = casadi.vertcat(
        casadi.horzcat(x[0], 2 * x[1], casadi.exp(p)),
        casadi.horzcat(casadi.sin(x[0]), x[0] * x[1], p**2),
    )  # (2, 3): non-square, so a transposition anywhere would show
    return casadi.Function(
        "mixed",
        [x, p, M],
        [Y * M, M.T @ x, p * x.T, casadi.sumsqr(M) * p, casadi.vertcat(x, p)],
        ["x", "p", "M"],
        ["Y", "MTx", "row", "s", "col"],
    )


def _msd() -> casadi.Function:
    """Mass-spring-damper (k, d, m) -> bottom-row CCF of G = (1/m) / (s^2 + d/m s + k/m)."""
    k, d, m = (casadi.SX.sym(s) for s in "kdm")
    A = casadi.vertcat(casadi.horzcat(0, 1), casadi.horzcat(-k / m, -d / m))
    return casadi.Function(
        "msd",
        [k, d, m],
        [A, casadi.vertcat(0, 1), casadi.horzcat(1 / m, 0), casadi.SX(1, 1)],
        ["k", "d", "m"],
        ["A", "B", "C", "D"],
    )


def _inputs(batch: int, dtype=torch.float64, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return {
        "x": torch.randn(batch, 2, generator=g, dtype=dtype),
        "p": torch.randn(batch, generator=g, dtype=dtype),
        "M": torch.randn(batch, 2, 3, generator=g, dtype=dtype),
    }


def test_shapes_follow_the_layout_convention():
    op = CasadiOp(_mixed())
    assert op.shape_in == {"x": (2,), "p": (), "M": (2, 3)}
    assert op.shape_out == {"Y": (2, 3), "MTx": (3,), "row": (1, 2), "s": (), "col": (3,)}
    out = op(**_inputs(5))
    assert {k: tuple(v.shape) for k, v in out.items()} == {
        "Y": (5, 2, 3), "MTx": (5, 3), "row": (5, 1, 2), "s": (5,), "col": (5, 3)
    }
    assert "mixed" in repr(op) and "M(batch, 2, 3)" in repr(op)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_values_equal_casadi_evaluation(dtype):
    f, op = _mixed(), CasadiOp(_mixed())
    inp = _inputs(7, dtype)
    out = op(**inp)
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    for i in range(7):
        ref = f(x=inp["x"][i].double().numpy(), p=inp["p"][i].item(),
                M=inp["M"][i].double().numpy())
        for name, y in out.items():
            assert y.dtype == dtype
            expected = ref[name].full().reshape(op.shape_out[name])
            np.testing.assert_allclose(y[i].double().numpy(), expected, rtol=tol, atol=tol)


def test_non_square_layout_against_torch():
    # f(X) = (X^T, X): the op must reproduce torch's own transpose entry by entry.
    X = casadi.SX.sym("X", 2, 3)
    op = CasadiOp(casadi.Function("t", [X], [X.T, X, X[0, :]], ["X"], ["XT", "same", "row0"]))
    Xt = torch.arange(4 * 6, dtype=torch.float64).reshape(4, 2, 3)
    out = op(Xt)
    assert torch.equal(out["XT"], Xt.transpose(1, 2))
    assert torch.equal(out["same"], Xt)
    assert torch.equal(out["row0"], Xt[:, :1, :])


def test_positional_and_named_calls_agree():
    op = CasadiOp(_mixed())
    inp = _inputs(3)
    a, b = op(**inp), op(inp["x"], inp["p"], inp["M"])
    for k in a:
        assert torch.equal(a[k], b[k])


def test_thread_parallelization_matches_serial():
    inp = _inputs(3)
    a = CasadiOp(_mixed())(**inp)
    b = CasadiOp(_mixed(), parallelization="thread")(**inp)
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)


def test_jacobians_equal_casadi_jacobian():
    f = _msd()
    op = CasadiOp(f)
    k, d, m = (casadi.SX.sym(s) for s in "kdm")
    p_sym = casadi.vertcat(k, d, m)
    outs = f(k=k, d=d, m=m)
    jac = casadi.Function(
        "jac_msd", [k, d, m], [casadi.jacobian(casadi.vec(outs[o]), p_sym) for o in "ABCD"]
    )
    rng = np.random.default_rng(3)
    P = torch.tensor(rng.uniform([20, 2, 0.5], [25, 5, 1.5], size=(4, 3)), dtype=torch.float64)

    def flat(params):
        res = op(*params.unbind(1))
        # casadi.vec is column-major: vec(M) stacks the columns of M, i.e. M^T flattened.
        return torch.cat([res[o].reshape(4, *f.size_out(o)).transpose(1, 2).reshape(4, -1)
                          for o in "ABCD"], 1)

    J = torch.autograd.functional.jacobian(flat, P)  # (4, 9, 4, 3)
    for i in range(4):
        ref = np.vstack([j.full() for j in jac(*P[i].numpy())])
        np.testing.assert_allclose(J[i, :, i, :].numpy(), ref, rtol=1e-12, atol=1e-12)
        # No cross-talk between samples of the batch.
        others = [j for j in range(4) if j != i]
        assert torch.all(J[i][:, others, :] == 0)


def test_gradcheck_float64():
    op = CasadiOp(_mixed())
    inp = {k: v.requires_grad_() for k, v in _inputs(3).items()}

    def fn(x, p, M):
        return tuple(op(x=x, p=p, M=M).values())

    assert torch.autograd.gradcheck(fn, (inp["x"], inp["p"], inp["M"]))


def test_float32_gradients_come_back_float32():
    op = CasadiOp(_msd())
    k, d, m = (torch.full((5,), v, requires_grad=True) for v in (22.0, 3.0, 1.0))
    out = op(k, d, m)
    (out["A"].sum() + out["C"].sum()).backward()
    assert out["A"].dtype == torch.float32 and m.grad.dtype == torch.float32
    # d/dm (-k/m - d/m + 1/m) = (k + d - 1) / m^2
    torch.testing.assert_close(m.grad, torch.full((5,), 24.0))


def test_empty_and_many_batch_sizes():
    op = CasadiOp(_msd())
    out = op(*(torch.ones(0, dtype=torch.float64) for _ in range(3)))
    assert out["A"].shape == (0, 2, 2)
    for batch in range(1, 20):  # more than the cache holds
        assert op(*(torch.ones(batch) for _ in range(3)))["B"].shape == (batch, 2)


def test_validation_errors():
    op = CasadiOp(_msd())
    one = torch.ones(4)
    with pytest.raises(ValueError, match=r"expects 3 inputs \(k, d, m\); got 2"):
        op(one, one)
    with pytest.raises(ValueError, match=r"unknown input 'x'.*valid inputs: k, d, m"):
        op(k=one, d=one, x=one)
    with pytest.raises(ValueError, match=r"missing input 'm'"):
        op(k=one, d=one)
    with pytest.raises(ValueError, match=r"either all positional or all by name"):
        op(one, d=one, m=one)
    with pytest.raises(ValueError, match=r"input 'd' of CasadiOp\(msd\) must have shape "
                                         r"\(batch\); got \(4, 1\)"):
        op(k=one, d=one[:, None], m=one)
    with pytest.raises(ValueError, match=r"input 'm' .* has batch size 3, but input 'k' has "
                                         r"batch size 4"):
        op(one, one, torch.ones(3))
    with pytest.raises(ValueError, match=r"input 'k' .* must be a float32 or float64 tensor"):
        op(torch.ones(4, dtype=torch.int64), one, one)
    M = CasadiOp(_mixed())
    with pytest.raises(ValueError, match=r"input 'M' .* must have shape \(batch, 2, 3\); "
                                         r"got \(2, 3, 2\)"):
        M(x=torch.ones(2, 2), p=torch.ones(2), M=torch.ones(2, 3, 2))
    with pytest.raises(ValueError, match=r"parallelization must be one of serial, thread"):
        CasadiOp(_msd(), parallelization="openmp")
    with pytest.raises(ValueError, match=r"has no inputs"):
        CasadiOp(casadi.Function("c", [], [casadi.SX(1)]))
    with pytest.raises(TypeError, match=r"must be a casadi.Function"):
        CasadiOp(lambda k: k)


def test_evaluate_returns_float64_numpy():
    op = CasadiOp(_mixed())
    inp = _inputs(4, torch.float32)
    out = op.evaluate(**inp)
    ref = op(**{k: v.double() for k, v in inp.items()})
    for k, v in out.items():
        assert isinstance(v, np.ndarray) and v.dtype == np.float64
        np.testing.assert_array_equal(v, ref[k].numpy())
