"""Structures: transfer functions against python-control, similarity invariance and round trips,
stability by construction, fixed elements, Physical (CasADi maps), gradcheck, configs, errors."""

from __future__ import annotations

import json

import casadi
import control
import numpy as np
import pytest
import torch
from helpers import tf_coeffs
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from aeid_struct.structures import (
    CCF,
    MCF,
    Physical,
    Structure,
    System,
    ccf_coefficients,
    ccf_matrices,
)

# -- test systems ---------------------------------------------------------------------------------


def msd_map() -> casadi.Function:
    """Mass-spring-damper (k, d, m) -> bottom-row CCF of G = (1/m) / (s^2 + d/m s + k/m)."""
    k, d, m = (casadi.SX.sym(s) for s in "kdm")
    A = casadi.vertcat(casadi.horzcat(0, 1), casadi.horzcat(-k / m, -d / m))
    return casadi.Function("msd", [k, d, m], [A, casadi.vertcat(0, 1), casadi.horzcat(1 / m, 0),
                                               casadi.SX(1, 1)], ["k", "d", "m"], list("ABCD"))


def msd_inverse(outputs=("k", "d", "m")) -> casadi.Function:
    """CCF -> (k, d, m): m = 1/c0, k = a0 m, d = a1 m (a subset of them if asked)."""
    A, B, C, D = (casadi.SX.sym(s, *shape) for s, shape in
                  zip("ABCD", [(2, 2), (2, 1), (1, 2), (1, 1)], strict=True))
    m = 1 / C[0, 0]
    values = {"k": -A[1, 0] * m, "d": -A[1, 1] * m, "m": m}
    return casadi.Function("msd_inv", [A, B, C, D], [values[o] for o in outputs], list("ABCD"),
                           list(outputs))


BOUNDS = {"k": (20.0, 25.0), "d": (2.0, 5.0), "m": (0.5, 1.5)}


def msd() -> Physical:
    return Physical(msd_map(), bounds=BOUNDS, inverse=msd_inverse())


STRUCTURES = {
    "ccf1": CCF(1),
    "ccf3": CCF(3),
    "ccf3-descartes": CCF(3, descartes=True),
    "ccf2-feedthrough": CCF(2, feedthrough=True),
    "ccf3-fixed": CCF(3).fixed(a1=0.5).fixed(c2=-1.25),
    "ccf2-descartes-fixed": CCF(2, descartes=True).fixed(a1=0.0),
    "mcf-real": MCF(real=1, pairs=0),
    "mcf-pair": MCF(real=0, pairs=1),
    "mcf-1-1-feedthrough": MCF(real=1, pairs=1, feedthrough=True),
    "mcf-2-2": MCF(real=2, pairs=2),
    "mcf-fixed": MCF(real=1, pairs=1).fixed(omega0=2.0, c0=0.5),
    "physical": msd(),
    "physical-fixed": msd().fixed(m=1.0),
}
CANONICAL = {k: v for k, v in STRUCTURES.items() if not k.startswith("physical")}


def theta_for(structure: Structure, batch: int, seed: int = 0, dtype=torch.float64):
    return torch.randn(batch, structure.p, generator=torch.Generator().manual_seed(seed),
                       dtype=dtype)


def polys(num_den):
    return [np.asarray(x, dtype=float) for x in num_den]


def expected_tf(structure: Structure, x: np.ndarray):
    """Closed-form (num, den) of one model from its elements, by polynomial algebra (numpy)."""
    e = dict(zip(structure.element_names, x, strict=True))
    n, d = structure.n, e.get("d", 0.0)
    if isinstance(structure, CCF):
        den = np.r_[1.0, [e[f"a{i}"] for i in reversed(range(n))]]
        num = np.r_[0.0, [e[f"c{i}"] for i in reversed(range(n))]]
        return num + d * den, den
    # MCF: sum of c_i / (s - lambda_i) and pair terms, over the common denominator.
    terms = [(np.array([e[f"c{i}"]]), np.array([1.0, -e[f"lambda{i}"]]))
             for i in range(structure.real)]
    for j in range(structure.pairs):
        dl, om = e[f"delta{j}"], e[f"omega{j}"]
        ca, cb = e[f"c{structure.real + 2 * j}"], e[f"c{structure.real + 2 * j + 1}"]
        terms.append((np.array([cb, ca * om - cb * dl]), np.array([1.0, -2 * dl, dl**2 + om**2])))
    den = np.array([1.0])
    for _, q in terms:
        den = np.polymul(den, q)
    num = np.zeros(1)
    for i, (p, _) in enumerate(terms):
        rest = np.array([1.0])
        for k, (_, q) in enumerate(terms):
            if k != i:
                rest = np.polymul(rest, q)
        num = np.polyadd(num, np.polymul(p, rest))
    num = np.r_[np.zeros(len(den) - len(num)), num]
    return num + d * den, den


def random_basis(n: int, batch: int, seed: int):
    rng = np.random.default_rng(seed)
    T = rng.normal(size=(batch, n, n)) + 3.0 * np.eye(n)
    return T, np.linalg.inv(T)


def transformed(system: System, seed: int):
    """(T A T^-1, T b, c T^-1, d) in numpy, a random basis per sample."""
    A, b, c, d = (x.detach().double().numpy() for x in system)
    T, Ti = random_basis(A.shape[-1], A.shape[0], seed)
    return T @ A @ Ti, np.einsum("bij,bj->bi", T, b), np.einsum("bi,bij->bj", c, Ti), d


def assert_same_tf(sys1, sys2, rtol=1e-8):
    for i in range(sys1[0].shape[0]):
        n1, d1 = tf_coeffs(*(np.asarray(v[i], dtype=float) for v in sys1))
        n2, d2 = tf_coeffs(*(np.asarray(v[i], dtype=float) for v in sys2))
        scale = 1 + np.abs(np.r_[n1, d1]).max()
        np.testing.assert_allclose(np.r_[n1, d1], np.r_[n2, d2], rtol=0, atol=rtol * scale)


def numpy_system(system: System):
    return tuple(x.detach().double().numpy() for x in system)


# -- structure of the matrices ----------------------------------------------------------------


def test_ccf_matrices_follow_eq5():
    s = CCF(3, feedthrough=True)
    theta = theta_for(s, 4)
    A, b, c, d = s(theta)
    assert s.element_names == ("a0", "a1", "a2", "c0", "c1", "c2", "d")
    assert torch.equal(A[:, :2, :], torch.tensor([[0.0, 1, 0], [0, 0, 1]]).expand(4, 2, 3)
                       .double())
    assert torch.equal(A[:, 2, :], -theta[:, :3])
    assert torch.equal(b, torch.tensor([0.0, 0, 1]).double().expand(4, 3))
    assert torch.equal(c, theta[:, 3:6]) and torch.equal(d, theta[:, 6])
    assert torch.equal(CCF(2)(theta_for(CCF(2), 3)).d, torch.zeros(3, dtype=torch.float64))


def test_mcf_matrices_follow_eq6():
    s = MCF(real=1, pairs=1)
    assert s.element_names == ("lambda0", "delta0", "omega0", "c0", "c1", "c2")
    assert (s.n, s.p) == (3, 6)
    x = s.elements(theta_for(s, 5))
    A, b, c, _ = s.assemble(x)
    lam, dl, om = x[:, 0], x[:, 1], x[:, 2]
    expected = torch.zeros(5, 3, 3, dtype=torch.float64)
    expected[:, 0, 0], expected[:, 1, 1], expected[:, 2, 2] = lam, dl, dl
    expected[:, 1, 2], expected[:, 2, 1] = om, -om
    assert torch.equal(A, expected)
    assert torch.equal(b, torch.tensor([1.0, 0.0, 1.0]).double().expand(5, 3))
    assert torch.equal(c, x[:, 3:])


@pytest.mark.parametrize("name", sorted(CANONICAL))
def test_transfer_function_equals_ss2tf(name):
    s = CANONICAL[name]
    x = s.elements(theta_for(s, 12, seed=1))
    sys_ = numpy_system(s.assemble(x))
    for i in range(12):
        num, den = tf_coeffs(*(v[i] for v in sys_))
        num_e, den_e = expected_tf(s, x[i].numpy())
        np.testing.assert_allclose(den, den_e, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(num, num_e, rtol=1e-10, atol=1e-10)


# -- similarity transforms and round trips -------------------------------------------------------


@pytest.mark.parametrize("name", sorted(STRUCTURES))
def test_similarity_round_trip(name):
    s = STRUCTURES[name]
    theta = theta_for(s, 10, seed=2)
    sys_ = s(theta)
    T_sys = transformed(sys_, seed=3)
    # The oracle: a basis change leaves the transfer function unchanged.
    assert_same_tf(numpy_system(sys_), T_sys)
    x_T = s.elements_of(*T_sys)
    assert x_T.shape == (10, s.q) and x_T.dtype == torch.float64
    if isinstance(s, MCF):
        # The mode order is canonical, not theta's: compare with the given model's own elements,
        # and the transfer function of the rebuilt model.
        torch.testing.assert_close(x_T, s.elements_of(*sys_), rtol=1e-8, atol=1e-8)
        assert_same_tf(numpy_system(s.assemble(x_T)), T_sys)
        assert_same_tf(numpy_system(s(s.theta_of(*T_sys))), T_sys)
    else:
        torch.testing.assert_close(x_T, s.elements(theta), rtol=1e-8, atol=1e-8)
        torch.testing.assert_close(s.theta_of(*T_sys), theta, rtol=1e-7, atol=1e-7)


def test_elements_of_accepts_unbatched_numpy_and_column_shapes():
    s = CCF(2)
    theta = theta_for(s, 1, seed=4)
    A, b, c, d = numpy_system(s(theta))
    x = s.elements_of(A[0], b[0][:, None], c[0][None, :], 0.0)
    assert x.shape == (4,)
    torch.testing.assert_close(x, s.elements(theta)[0])
    x32 = s.elements_of(torch.as_tensor(A, dtype=torch.float32), b, c)
    assert x32.dtype == torch.float32 and x32.shape == (1, 4)


def test_mcf_elements_of_canonical_order_and_fixed_alignment():
    # Poles -3 and -1 (real), residues 2 and 5: G = 2/(s+3) + 5/(s+1).
    A, b, c = np.diag([-3.0, -1.0]), np.ones(2), np.array([2.0, 5.0])
    s = MCF(real=2, pairs=0)
    x = s.elements_of(A, b, c)
    torch.testing.assert_close(x, torch.tensor([-1.0, -3.0, 5.0, 2.0], dtype=torch.float64))
    # Fixing lambda1 = -1 forces the other order; the model is the same.
    sf = s.fixed(lambda1=-1.0)
    xf = sf.elements_of(A, b, c)
    torch.testing.assert_close(xf, torch.tensor([-3.0, -1.0, 2.0, 5.0], dtype=torch.float64))
    assert xf[1] == -1.0
    with pytest.raises(ValueError, match=r"element lambda1 is fixed at -2.0"):
        s.fixed(lambda1=-2.0).elements_of(A, b, c)


def test_mcf_pair_elements_from_a_known_transfer_function():
    # G = (3 s + 7) / ((s + 1)^2 + 4): delta = -1, omega = 2, c_b = 3, c_a = (7 + 3 * -1) / 2 = 2.
    num, den = [3.0, 7.0], [1.0, 2.0, 5.0]
    ss = control.tf2ss(num, den)
    x = MCF(real=0, pairs=1).elements_of(ss.A, ss.B, ss.C, ss.D)
    torch.testing.assert_close(x, torch.tensor([-1.0, 2.0, 2.0, 3.0], dtype=torch.float64))


# -- stability by construction --------------------------------------------------------------------


def wide_theta(p: int, batch: int, seed: int, dtype=torch.float64):
    """Raw vectors from |theta| ~ 1e-2 up to 1e3, plus the extremes +-1e4."""
    g = torch.Generator().manual_seed(seed)
    scale = 10.0 ** (torch.rand(batch, 1, generator=g, dtype=torch.float64) * 5 - 2)
    theta = torch.randn(batch, p, generator=g, dtype=torch.float64) * scale
    theta[:2] = torch.tensor([1e4, -1e4]).repeat_interleave(p).reshape(2, p)
    return theta.to(dtype)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("structure", [MCF(real=1, pairs=1), MCF(real=3, pairs=0),
                                       MCF(real=1, pairs=2, feedthrough=True)], ids=repr)
def test_every_sampled_mcf_is_hurwitz(structure, dtype):
    A = structure(wide_theta(structure.p, 2000, seed=5, dtype=dtype)).A
    assert A.dtype == dtype
    poles = np.linalg.eigvals(A.double().numpy())
    assert np.all(poles.real < 0), poles.real.max()


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_descartes_ccf_has_no_positive_real_pole(dtype):
    s = CCF(3, descartes=True)
    theta = wide_theta(s.p, 1000, seed=6, dtype=dtype)
    theta[2:500, :3] = torch.randn(498, 3, dtype=dtype) * 3  # more poles near the axis
    x = s.elements(theta).double().numpy()
    a = x[:, :3]
    assert np.all(a >= 0)
    for row in a:
        roots = np.roots(np.r_[1.0, row[::-1]])
        tol = 1e-6 * max(1.0, np.abs(roots).max())
        real_roots = roots[np.abs(roots.imag) <= tol].real
        assert np.all(real_roots <= tol), (row, roots)


def test_descartes_does_not_exclude_unstable_complex_pairs():
    # s^3 + s^2 + s + 10 has no sign change but poles 0.6 +- 1.9j (documented limitation).
    s = CCF(3, descartes=True)
    theta = s.raw(torch.tensor([[10.0, 1.0, 1.0, 1.0, 0.0, 0.0]], dtype=torch.float64))
    poles = np.linalg.eigvals(s(theta).A[0].numpy())
    assert poles.real.max() > 0.5


# -- constraint maps and raw() -----------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, (3, 6), elements=st.floats(-30, 30)))
def test_raw_inverts_the_constraint_maps(theta):
    theta = torch.from_numpy(theta)
    for s in (CCF(3, descartes=True), MCF(real=1, pairs=1)):
        x = s.elements(theta)
        torch.testing.assert_close(s.raw(x), theta, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("make", [lambda: CCF(3, descartes=True, feedthrough=True).fixed(a1=0.5),
                                  lambda: MCF(real=1, pairs=1), lambda: msd()])
def test_casadi_elements_equal_the_torch_maps_and_assemble_the_same_system(make):
    # the batch-1 path evaluates theta -> (A, b, c, d, elements) as one CasADi graph: torch's
    # maps are the oracle, at moderate theta and where softplus switches to the identity (> 20)
    # or underflows, where exp overflows in the branch not taken, and the sigmoid saturates
    s = make()
    theta = casadi.SX.sym("theta", s.p)
    el = s.casadi_elements(theta)
    f = casadi.Function("f", [theta], [el, *s.casadi_system(el)])
    rng = np.random.default_rng(4)
    for row in [*rng.normal(0.0, 3.0, (5, s.p)), np.full(s.p, 25.0), np.full(s.p, -40.0),
                np.full(s.p, 19.999), np.full(s.p, 800.0), np.full(s.p, -800.0)]:
        x = s.elements(torch.from_numpy(row[None]))
        system = s.assemble(x)
        got = [np.array(v) for v in f(row)]
        np.testing.assert_allclose(got[0].ravel(), x[0].numpy(), rtol=1e-13, atol=1e-300)
        for mine, theirs in zip(got[1:], (system.A, system.b, system.c, system.d), strict=True):
            np.testing.assert_allclose(mine.reshape(theirs[0].shape), theirs[0].numpy(),
                                       rtol=1e-13, atol=1e-14)


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, (2, 3), elements=st.floats(-15, 15)))
def test_physical_raw_inverts_the_sigmoid(theta):
    theta = torch.from_numpy(theta)
    s = msd()
    torch.testing.assert_close(s.raw(s.elements(theta)), theta, rtol=1e-6, atol=1e-6)


def test_raw_clamps_at_the_boundary():
    s = CCF(2, descartes=True)
    theta = s.raw(torch.tensor([[0.0, 1.0, 2.0, 3.0]], dtype=torch.float64))
    assert torch.isfinite(theta).all()
    x = s.elements(theta)
    assert 0 < x[0, 0] < 1e-15
    m = MCF(real=1, pairs=0)
    assert m.elements(m.raw(torch.tensor([[0.0, 1.0]])))[0, 0] < 0
    p = msd()
    edge = torch.tensor([[20.0, 5.0, 0.5]], dtype=torch.float64)
    torch.testing.assert_close(p.elements(p.raw(edge)), edge, rtol=1e-12, atol=1e-12)


def test_physical_bounds_hold_for_extreme_theta():
    s = msd()
    for dtype in (torch.float64, torch.float32):
        theta = wide_theta(3, 500, seed=7, dtype=dtype)
        x = s.elements(theta)
        for i, name in enumerate(s.element_names):
            lo, hi = BOUNDS[name]
            assert torch.all(x[:, i] >= lo) and torch.all(x[:, i] <= hi)
        assert torch.isfinite(s(theta).A).all()


# -- fixed elements -----------------------------------------------------------------------------


def test_fixed_elements_are_exact_and_free_ones_follow_theta():
    base = CCF(3)
    s = base.fixed(a1=0.5).fixed(c2=-1.25)
    assert (base.p, s.p) == (6, 4)
    assert s.free_names == ("a0", "a2", "c0", "c1")
    assert s.fixed_values == {"a1": 0.5, "c2": -1.25}
    for dtype in (torch.float64, torch.float32):
        theta = theta_for(s, 6, dtype=dtype)
        A, _, c, _ = s(theta)
        assert torch.all(A[:, 2, 1] == -0.5) and torch.all(c[:, 2] == -1.25)
        assert torch.equal(A[:, 2, 0], -theta[:, 0]) and torch.equal(A[:, 2, 2], -theta[:, 1])
        assert torch.equal(c[:, :2], theta[:, 2:])
    assert repr(s) == "CCF(n=3, descartes=False, feedthrough=False).fixed(a1=0.5, c2=-1.25)"


def test_fixed_mcf_and_physical():
    s = MCF(real=1, pairs=1).fixed(omega0=2.0)
    A = s(theta_for(s, 4)).A
    assert torch.all(A[:, 1, 2] == 2.0) and torch.all(A[:, 2, 1] == -2.0)
    p = msd().fixed(m=1.0, d=2.0)
    assert p.free_names == ("k",)
    A = p(torch.zeros(3, 1, dtype=torch.float64)).A
    torch.testing.assert_close(A[:, 1], torch.tensor([-22.5, -2.0]).double().expand(3, 2))


def test_all_elements_fixed():
    s = CCF(1).fixed(a0=2.0, c0=3.0)
    sys_ = s(torch.zeros(5, 0))
    assert sys_.A.shape == (5, 1, 1) and torch.all(sys_.A == -2.0) and torch.all(sys_.c == 3.0)
    assert s.raw(s.elements(torch.zeros(5, 0))).shape == (5, 0)


def test_fixed_errors():
    with pytest.raises(ValueError, match=r"unknown element 'a5' for CCF\(n=2.*valid names: "
                                         r"a0, a1, c0, c1"):
        CCF(2).fixed(a5=1.0)
    with pytest.raises(ValueError, match=r"unknown element 'd' .*feedthrough=True"):
        CCF(2).fixed(d=1.0)
    with pytest.raises(ValueError, match=r"cannot fix a1=-1.0 .*a1 >= 0 \(Descartes\)"):
        CCF(2, descartes=True).fixed(a1=-1)
    with pytest.raises(ValueError, match=r"cannot fix lambda0=0.0 .*lambda0 < 0"):
        MCF(real=1, pairs=0).fixed(lambda0=0.0)
    with pytest.raises(ValueError, match=r"cannot fix omega0=-1.0 .*omega0 > 0"):
        MCF().fixed(omega0=-1.0)
    with pytest.raises(ValueError, match=r"cannot fix m=2.0 .*0.5 <= m <= 1.5"):
        msd().fixed(m=2.0)
    with pytest.raises(ValueError, match=r"cannot fix c0=nan"):
        CCF(2).fixed(c0=float("nan"))
    with pytest.raises(ValueError, match=r"a1 must be a real number; got 'x'"):
        CCF(2).fixed(a1="x")
    with pytest.raises(ValueError, match=r"element 'a1' .* is already fixed at 0.0"):
        CCF(2).fixed(a1=0.0).fixed(a1=1.0)


def test_fixed_elements_in_given_models():
    s = CCF(2).fixed(a1=3.0)
    A = np.array([[0.0, 1.0], [-2.0, -3.0]])
    torch.testing.assert_close(s.elements_of(A, [0, 1], [1, 0]),
                               torch.tensor([2.0, 3.0, 1.0, 0.0], dtype=torch.float64))
    with pytest.raises(ValueError, match=r"the model: element a1 is fixed at 3.0 .*got 4"):
        s.elements_of(np.array([[0.0, 1.0], [-2.0, -4.0]]), [0, 1], [1, 0])
    x = s.elements_of(np.array([[0.0, 1.0], [-2.0, -4.0]]), [0, 1], [1, 0], strict=False)
    assert x[1] == 3.0
    with pytest.raises(ValueError, match=r"elements: element a1 is fixed at 3.0"):
        s.assemble(torch.tensor([[2.0, 4.0, 1.0, 0.0]]))
    with pytest.raises(ValueError, match=r"elements: element a1 is fixed at 3.0 .*got 4 "
                                         r"\(row 2\)"):
        s.raw(torch.tensor([[2.0, 3.0, 1.0, 0.0]] * 2 + [[2.0, 4.0, 1.0, 0.0]]))
    with pytest.raises(ValueError, match=r"a1 = -0.5 \(row 1\)"):
        CCF(2, descartes=True).raw(torch.tensor([[1.0, 0.5, 0.0, 0.0], [1.0, -0.5, 0.0, 0.0]]))


# -- Physical ------------------------------------------------------------------------------------


def test_physical_matches_casadi_evaluation():
    s, f = msd(), msd_map()
    assert s.element_names == ("k", "d", "m") and s.n == 2
    theta = theta_for(s, 6, seed=8)
    x = s.elements(theta)
    A, b, c, d = s.assemble(x)
    for i in range(6):
        ref = f(*x[i].numpy())
        np.testing.assert_allclose(A[i].numpy(), ref[0].full(), rtol=1e-14)
        np.testing.assert_allclose(b[i].numpy(), ref[1].full()[:, 0], rtol=1e-14)
        np.testing.assert_allclose(c[i].numpy(), ref[2].full()[0], rtol=1e-14)
        assert d[i] == 0.0


def test_physical_without_every_parameter_in_the_inverse():
    # The inverse knows k and m only (like d of the unstable leg): d goes to its midpoint.
    s = Physical(msd_map(), bounds=BOUNDS, inverse=msd_inverse(("k", "m")))
    theta = theta_for(s, 4, seed=9)
    sys_ = s(theta)
    # d enters the model, so the range check sees that the midpoint does not rebuild it ...
    with pytest.raises(ValueError, match=r"not in the range of Physical\(msd"):
        s.elements_of(*sys_)
    # ... unless d is the midpoint, or the check is off.
    x = s.elements_of(*s(theta.index_fill(1, torch.tensor([1]), 0.0)))
    assert torch.all(x[:, 1] == 3.5)
    x = s.elements_of(*sys_, strict=False)
    torch.testing.assert_close(x[:, [0, 2]], s.elements(theta)[:, [0, 2]])
    assert torch.all(s.raw(x)[:, 1] == 0.0)
    assert torch.all(s.fixed(d=2.0).elements_of(*sys_, strict=False)[:, 1] == 2.0)


def test_physical_elements_of_errors():
    s = msd()
    with pytest.raises(ValueError, match=r"has no inverse: elements_of needs"):
        Physical(msd_map(), bounds=BOUNDS).elements_of(np.eye(2), [0, 1], [1, 0])
    # k = 22, d = 3, m = 1/c0 = 4: m is out of bounds.
    A = np.array([[0.0, 1.0], [-5.5, -0.75]])
    with pytest.raises(ValueError, match=r"violates the constraint 0.5 <= m <= 1.5 \(bounds\)"):
        s.elements_of(A, [0, 1], [0.25, 0])
    # c1 != 0 is not a mass-spring-damper.
    with pytest.raises(ValueError, match=r"not in the range of Physical"):
        s.elements_of(np.array([[0.0, 1.0], [-22.0, -3.0]]), [0, 1], [1.0, 0.5])
    with pytest.raises(ValueError, match=r"inverse msd_inv returned a non-finite k"):
        s.elements_of(np.array([[0.0, 1.0], [-22.0, -3.0]]), [0, 1], [0.0, 1.0])
    with pytest.raises(ValueError, match=r"elements violates the constraint 20 <= k <= 25"):
        s.raw(torch.tensor([[26.0, 3.0, 1.0]]))


def test_physical_constructor_errors():
    f = msd_map()
    with pytest.raises(ValueError, match=r"bounds\['k'\] must satisfy lo < hi; got \(25, 20\)"):
        Physical(f, bounds={**BOUNDS, "k": (25, 20)})
    with pytest.raises(ValueError, match=r"bounds\['m'\] must be finite; got \(0, inf\)"):
        Physical(f, bounds={**BOUNDS, "m": (0, float("inf"))})
    with pytest.raises(ValueError, match=r"bounds is missing 'm'; every input of msd needs"):
        Physical(f, bounds={"k": (20, 25), "d": (2, 5)})
    with pytest.raises(ValueError, match=r"bounds has unknown name 'x'; inputs of msd: k, d, m"):
        Physical(f, bounds={**BOUNDS, "x": (0, 1)})
    with pytest.raises(ValueError, match=r"bounds\['d'\] must be a pair"):
        Physical(f, bounds={**BOUNDS, "d": 3.0})
    x = casadi.SX.sym("x", 2)
    bad = casadi.Function("bad", [x], [casadi.diag(x), x, x.T, 0], ["x"], list("ABCD"))
    with pytest.raises(ValueError, match=r"input 'x' of bad must be a scalar"):
        Physical(bad, bounds={"x": (0, 1)})
    k = casadi.SX.sym("k")
    no_d = casadi.Function("no_d", [k], [k, k, k], ["k"], list("ABC"))
    with pytest.raises(ValueError, match=r"must have outputs A, B, C, D; missing D"):
        Physical(no_d, bounds={"k": (0, 1)})
    with pytest.raises(ValueError, match=r"output 'x' of inverse msd_inv is not a parameter"):
        inv = msd_inverse()
        A, B, C, D = (casadi.SX.sym(s, *inv.size_in(s)) for s in "ABCD")
        Physical(f, bounds=BOUNDS, inverse=casadi.Function("msd_inv", [A, B, C, D], [C[0, 0]],
                                                           list("ABCD"), ["x"]))
    with pytest.raises(ValueError, match=r"function must be a casadi.Function"):
        Physical(lambda k: k, bounds={})


def test_physical_with_extra_outputs_and_other_output_order():
    k, d, m = (casadi.SX.sym(s) for s in "kdm")
    ref = msd_map()(k=k, d=d, m=m)
    g = casadi.Function("msd2", [k, d, m], [k * m, ref["D"], ref["C"], ref["B"], ref["A"]],
                        ["k", "d", "m"], ["energy", "D", "C", "B", "A"])
    s = Physical(g, bounds=BOUNDS, inverse=msd_inverse())
    theta = theta_for(s, 3, seed=10)
    torch.testing.assert_close(s(theta).A, msd()(theta).A)


def test_physical_with_the_robot_leg_maps():
    import symbolic.leg as leg

    bounds = {"k": (20, 25), "d": (2, 5), "m": (0.5, 1.5)}
    stable = Physical(leg.stable_map(), bounds=bounds, inverse=leg.stable_inverse())
    theta = theta_for(stable, 8, seed=11)
    sys_ = stable(theta)
    # G1 = (1/m) / (s^2 + d/m s + k/m) (DESIGN.md), checked against python-control.
    k, d, m = stable.elements(theta).unbind(1)
    for i in range(8):
        num, den = tf_coeffs(*(v[i].numpy() for v in sys_))
        np.testing.assert_allclose(den, [1, d[i] / m[i], k[i] / m[i]], rtol=1e-12)
        np.testing.assert_allclose(num, [0, 0, 1 / m[i]], rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(stable.theta_of(*transformed(sys_, seed=12)), theta,
                               rtol=1e-6, atol=1e-6)
    # G2 does not depend on d: its inverse returns k and m, d goes to the midpoint of its bounds.
    unstable = Physical(leg.unstable_map(), bounds=bounds, inverse=leg.unstable_inverse())
    x = unstable.elements_of(*transformed(unstable(theta), seed=13))
    torch.testing.assert_close(x[:, [0, 2]], unstable.elements(theta)[:, [0, 2]])
    assert torch.all(x[:, 1] == 3.5)
    assert torch.autograd.gradcheck(lambda t: tuple(stable(t)),
                                    (theta[:2].clone().requires_grad_(),))


# -- gradients ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(STRUCTURES))
def test_gradcheck(name):
    s = STRUCTURES[name]
    theta = theta_for(s, 3, seed=14).requires_grad_()
    assert torch.autograd.gradcheck(lambda t: tuple(s(t)), (theta,))


# -- configuration and conversions ----------------------------------------------------------------


@pytest.mark.parametrize("name", sorted(STRUCTURES))
def test_config_round_trip(name):
    s = STRUCTURES[name]
    text = json.dumps(s.config())
    # a Physical structure of user maps (msd_map, not a named map) gets them passed again
    maps = ({f.name(): f for f in (s.function, s.inverse) if f is not None}
            if isinstance(s, Physical) else None)
    s2 = Structure.from_config(json.loads(text), maps=maps)
    assert type(s2) is type(s) and s2 == s and repr(s2) == repr(s) and hash(s2) == hash(s)
    assert s2.element_names == s.element_names and s2.free_names == s.free_names
    theta = theta_for(s, 4, seed=15)
    for a, b in zip(s(theta), s2(theta), strict=True):
        assert torch.equal(a, b)


def test_from_config_errors():
    with pytest.raises(ValueError, match=r"unknown structure type 'LTI'; valid types: CCF, MCF"):
        Structure.from_config({"type": "LTI"})
    with pytest.raises(ValueError, match=r"config must be a dict with a 'type' entry"):
        Structure.from_config({"n": 2})
    with pytest.raises(ValueError, match=r"invalid config for CCF: .*unexpected keyword.*order"):
        Structure.from_config({"type": "CCF", "n": 2, "order": 3})


def test_to_control():
    s = MCF(real=1, pairs=1, feedthrough=True)
    theta = theta_for(s, 3, seed=16)
    models = s.to_control(theta)
    sys_ = numpy_system(s(theta))
    assert isinstance(models, list) and len(models) == 3
    for i, m in enumerate(models):
        assert isinstance(m, control.StateSpace)
        np.testing.assert_array_equal(m.A, sys_[0][i])
        np.testing.assert_array_equal(m.B[:, 0], sys_[1][i])
        np.testing.assert_array_equal(m.C[0], sys_[2][i])
        assert m.D[0, 0] == sys_[3][i]
    one = s.to_control(theta[0].float())
    assert isinstance(one, control.StateSpace) and one.A.dtype == np.float64


def test_unbatched_theta_gives_an_unbatched_system():
    s = CCF(2)
    sys_ = s(torch.ones(4))
    assert sys_.A.shape == (2, 2) and sys_.b.shape == (2,) and sys_.d.shape == ()
    assert s.elements(torch.ones(4)).shape == (4,) and s.raw(torch.ones(4)).shape == (4,)


# -- validation ----------------------------------------------------------------------------------


def test_constructor_errors():
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match=r"n must be an integer >= 1"):
            CCF(bad)
    with pytest.raises(ValueError, match=r"real must be an integer >= 0; got -1"):
        MCF(real=-1)
    with pytest.raises(ValueError, match=r"pairs must be an integer >= 0; got -1"):
        MCF(pairs=-1)
    with pytest.raises(ValueError, match=r"MCF needs at least one mode; got real=0 and pairs=0"):
        MCF(real=0, pairs=0)


def test_theta_errors():
    s = CCF(2)
    with pytest.raises(ValueError, match=r"theta must have shape \(batch, 4\) for "
                                         r"CCF\(n=2, .*\); got \(8, 3\)"):
        s(torch.zeros(8, 3))
    with pytest.raises(ValueError, match=r"theta must have shape \(batch, 3\) for "
                                         r"CCF\(n=2.*\.fixed\(a1=0.0\); got \(8, 4\)"):
        s.fixed(a1=0.0)(torch.zeros(8, 4))
    with pytest.raises(ValueError, match=r"theta must be finite; got nan or inf in row\(s\) \[1\]"):
        s(torch.tensor([[0.0] * 4, [0.0, float("nan"), 0, 0]]))
    with pytest.raises(ValueError, match=r"theta must be a float32 or float64 tensor"):
        s(torch.zeros(2, 4, dtype=torch.int64))
    with pytest.raises(ValueError, match=r"elements must have shape \(batch, 4\)"):
        s.raw(torch.zeros(2, 5))


def test_system_shape_errors():
    A = torch.zeros(3, 2, 2)
    with pytest.raises(ValueError, match=r"b must have shape \(3, 2\) to match A \(3, 2, 2\); "
                                         r"got \(3, 3\)"):
        System(A, torch.zeros(3, 3), torch.zeros(3, 2), torch.zeros(3))
    with pytest.raises(ValueError, match=r"d must have shape \(3,\)"):
        System(A, torch.zeros(3, 2), torch.zeros(3, 2), torch.zeros(2))
    with pytest.raises(ValueError, match=r"A must have shape \(batch, n, n\)"):
        System(torch.zeros(3, 2, 3), torch.zeros(3, 2), torch.zeros(3, 2), torch.zeros(3))


def test_elements_of_model_errors():
    s = CCF(2)
    with pytest.raises(ValueError, match=r"A must have shape \(batch, 2, 2\) or \(2, 2\) for "
                                         r"CCF\(n=2.*got \(3, 3\)"):
        s.elements_of(np.eye(3), np.ones(3), np.ones(3))
    with pytest.raises(ValueError, match=r"b must have shape \(4, 2\) to match A \(4, 2, 2\); "
                                         r"got \(4, 3\)"):
        s.elements_of(np.zeros((4, 2, 2)), np.ones((4, 3)), np.ones((4, 2)))
    with pytest.raises(ValueError, match=r"A must be finite"):
        s.elements_of(np.full((2, 2), np.inf), np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match=r"feedthrough d = 0.5 \(row 0\) but CCF\(n=2.*has none"):
        s.elements_of(np.eye(2), np.ones(2), np.ones(2), 0.5)
    # s^2 - 3 s + 2 = (s - 1)(s - 2): a1 = -3 violates Descartes.
    A = np.array([[0.0, 1.0], [-2.0, 3.0]])
    with pytest.raises(ValueError, match=r"the model violates the constraint a1 >= 0 "
                                         r"\(Descartes\) .*a1 = -3"):
        CCF(2, descartes=True).elements_of(A, [0, 1], [1, 0])
    x = CCF(2, descartes=True).elements_of(A, [0, 1], [1, 0], strict=False)
    assert x[1] == 0.0
    with pytest.raises(ValueError, match=r"elements violates the constraint a1 >= 0"):
        CCF(2, descartes=True).raw(torch.tensor([[1.0, -0.5, 0.0, 0.0]]))


def test_mcf_model_errors():
    with pytest.raises(ValueError, match=r"expects 0 real pole\(s\) and 1 complex pair\(s\); the "
                                         r"model \(row 0\) has 2 real"):
        MCF(real=0, pairs=1).elements_of(np.diag([-1.0, -2.0]), np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match=r"expects 2 real pole\(s\) and 0 complex pair\(s\)"):
        MCF(real=2, pairs=0).elements_of(np.array([[-1.0, 2.0], [-2.0, -1.0]]), np.ones(2),
                                         np.ones(2))
    with pytest.raises(ValueError, match=r"violates the constraint lambda0 < 0 \(poles in the "
                                         r"open left half-plane\)"):
        MCF(real=2, pairs=0).elements_of(np.diag([0.5, -2.0]), np.ones(2), np.ones(2))
    # a pair whose oscillation is below working precision (the form's floor on omega, where a
    # fit held stable ends) is still the structure's pair, not two real poles: the same
    # transfer function comes back (it was refused as "2 real")
    A = np.array([[-2.0, 7e-9], [-7e-9, -2.0]])
    b, c = np.array([0.3, 1.0]), np.array([1.0, -0.5])
    s = MCF(real=0, pairs=1, feedthrough=False)
    back = s.assemble(s.elements_of(A, b, c).to(torch.float64))
    given = control.ss(A, b[:, None], c[None], 0.0)
    found = control.ss(back.A.numpy().reshape(2, 2), back.b.numpy().reshape(2, 1),
                       back.c.numpy().reshape(1, 2), 0.0)
    w = np.array([0.1, 2.0, 30.0])
    np.testing.assert_allclose(found(1j * w), given(1j * w), rtol=1e-6)
    with pytest.raises(ValueError, match=r"has 2 real"):      # two distinct real poles: no pair
        s.elements_of(np.diag([-1.0, -1.0 - 1e-12]), b, c)
    with pytest.raises(ValueError, match=r"violates the constraint lambda0 < 0 .*lambda0 = 0 "):
        MCF(real=1, pairs=0).elements_of([[0.0]], [1.0], [1.0])
    with pytest.raises(ValueError, match=r"violates the constraint delta0 < 0"):
        MCF().elements_of(np.array([[0.1, 2.0], [-2.0, 0.1]]), np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match=r"repeated pole without a full set of eigenvectors"):
        MCF(real=2, pairs=0).elements_of(np.array([[-1.0, 1.0], [0.0, -1.0]]), np.ones(2),
                                         np.ones(2))


# -- the CasADi view used by the refinement ------------------------------------------------------


@pytest.mark.parametrize("name", STRUCTURES)
def test_casadi_system_equals_assemble(name):
    s = STRUCTURES[name]
    x = s.elements(theta_for(s, 3, seed=4))
    A, b, c, d = numpy_system(s.assemble(x))
    sym = casadi.SX.sym("x", s.q)
    f = casadi.Function("system", [sym], list(s.casadi_system(sym)))
    for i in range(3):
        Ai, bi, ci, di = (np.array(v) for v in f(x[i].numpy()))
        np.testing.assert_allclose(Ai, A[i], rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(bi.ravel(), b[i], rtol=1e-14, atol=1e-14)
        np.testing.assert_allclose(ci.ravel(), c[i], rtol=1e-14, atol=1e-14)
        assert di.item() == pytest.approx(d[i], abs=1e-14)
        # numeric elements give numeric matrices directly
        An = np.array(casadi.DM(s.casadi_system(x[i].numpy())[0]))
        np.testing.assert_allclose(An, A[i], rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("name", STRUCTURES)
def test_element_bounds_close_the_constraint_maps(name):
    s = STRUCTURES[name]
    bounds = s.element_bounds()
    assert tuple(bounds) == s.element_names
    x = s.elements(wide_theta(s.p, 512, seed=5))
    for i, nm in enumerate(s.element_names):
        lo, hi = bounds[nm]
        assert bool((x[:, i] >= lo).all() and (x[:, i] <= hi).all()), nm
        if nm in s.fixed_values:
            assert lo == hi == s.fixed_values[nm]


def test_element_bounds_by_kind():
    assert CCF(2, descartes=True).element_bounds() == {
        "a0": (0.0, np.inf), "a1": (0.0, np.inf), "c0": (-np.inf, np.inf), "c1": (-np.inf, np.inf)}
    mcf = MCF(real=1, pairs=1).element_bounds()
    assert mcf["lambda0"] == mcf["delta0"] == (-np.inf, -1e-8)
    assert mcf["omega0"] == (1e-8, np.inf)
    assert msd().fixed(m=1.0).element_bounds() == {"k": (20.0, 25.0), "d": (2.0, 5.0),
                                                   "m": (1.0, 1.0)}


def test_casadi_system_shape_error():
    with pytest.raises(ValueError, match=r"x must have shape \(4, 1\) for CCF"):
        CCF(2).casadi_system(casadi.SX.sym("x", 3))


# -- several records, one parameter set (the joint leg) ----------------------------------------
def _joint():
    from symbolic import leg

    return Physical(leg.joint_map(), bounds={"k": (20, 25), "d": (2, 5), "m": (0.5, 1.5)},
                    inverse=leg.joint_inverse())


def test_joint_physical_assembles_a_record_axis_equal_to_each_subsystem_map():
    from symbolic import leg

    s = _joint()
    assert (s.records, s.p, s.q) == (2, 3, 3)
    params = torch.tensor([[24.23, 2.24, 1.01], [20.5, 4.0, 0.6]], dtype=torch.float64)
    sys = s.assemble(params)
    assert tuple(sys.A.shape) == (2, 2, 2, 2) and tuple(sys.d.shape) == (2, 2)
    for i, row in enumerate(params.tolist()):
        for r, f in enumerate((leg.stable_map(), leg.unstable_map())):
            out = f(k=row[0], d=row[1], m=row[2])
            np.testing.assert_allclose(sys.A[i, r].numpy(), np.array(out["A"]), rtol=1e-14)
            np.testing.assert_allclose(sys.b[i, r].numpy(), np.array(out["B"]).ravel())
            np.testing.assert_allclose(sys.c[i, r].numpy(), np.array(out["C"]).ravel(),
                                       rtol=1e-14)
    # one parameter vector: the record axis leads
    assert tuple(s.assemble(params[0]).A.shape) == (2, 2, 2)
    assert len(s.assemble(params).to_control()[0]) == 2


def test_joint_physical_elements_of_round_trips_and_rejects_inconsistent_records():
    s = _joint()
    params = torch.tensor([[24.23, 2.24, 1.01], [20.5, 4.0, 0.6]], dtype=torch.float64)
    sys = s.assemble(params)
    back = s.elements_of(sys.A, sys.b, sys.c, sys.d)
    torch.testing.assert_close(back, params, rtol=1e-10, atol=0)
    torch.testing.assert_close(s.elements_of(sys.A[1], sys.b[1], sys.c[1], sys.d[1]),
                               params[1], rtol=1e-10, atol=0)
    # the stable record of row 1 from another leg: no (k, d, m) rebuilds both records
    A = sys.A.clone()
    A[1, 0, 1, 0] *= 1.05
    with pytest.raises(ValueError, match=r"the model \(row 1\) is not in the range"):
        s.elements_of(A, sys.b, sys.c, sys.d)
    with pytest.raises(ValueError, match=r"A must have shape \(batch, 2, 2, 2\) or \(2, 2, 2\)"):
        s.elements_of(np.zeros((3, 2, 2)), np.zeros((3, 2)), np.zeros((3, 2)), np.zeros(3))


def test_joint_physical_is_differentiable_and_serialisable():
    s = _joint()
    theta = torch.tensor([[0.3, -0.2, 0.5]], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: tuple(s(t)), (theta,))
    assert Structure.from_config(json.loads(json.dumps(s.config()))) == s
    with pytest.raises(ValueError, match=r"inverse stable_inverse must have inputs A1, B1"):
        from symbolic import leg

        Physical(leg.joint_map(), bounds={"k": (20, 25), "d": (2, 5), "m": (0.5, 1.5)},
                 inverse=leg.stable_inverse())


# -- the one model -> CCF conversion (issue 13 item 4) ----------------------------------------


def _hidden_ccf(n: int, rng: np.random.Generator, batch: int):
    """Batches of known CCF coefficients and the same systems in random bases with cond <= 10:
    an exact oracle for the conversion."""
    a = np.stack([np.poly(-rng.uniform(0.5, 3.0, n))[1:][::-1] for _ in range(batch)])
    num = rng.normal(size=(batch, n))
    A_c, b_c, _ = ccf_matrices(a, num)
    A, b, c = np.empty_like(A_c), np.empty_like(b_c), np.empty_like(num)
    for i in range(batch):
        Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
        T = Q @ np.diag(rng.uniform(0.3, 3.0, n))
        Ti = np.linalg.inv(T)
        A[i], b[i], c[i] = T @ A_c[i] @ Ti, T @ b_c[i], num[i] @ Ti
    return a, num, A, b, c


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5])
def test_ccf_coefficients_agree_with_symbolic_ccf_and_python_control(n):
    # structures' batched numpy conversion evaluates symbolic.realisation.ccf: per row it must
    # give what leg.ccf gives, the coefficients the systems were built from, and python-control's
    # transfer function.
    import symbolic.leg as leg

    rng = np.random.default_rng(100 + n)
    a, num, A, b, c = _hidden_ccf(n, rng, batch=6)
    a_got, num_got = ccf_coefficients(A, b, c)
    assert a_got.shape == num_got.shape == (6, n)
    np.testing.assert_allclose(a_got, a, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(num_got, num, rtol=1e-10, atol=1e-10)
    for i in range(6):
        one = leg.ccf(A[i], b[i], c[i], 0.0)
        np.testing.assert_allclose(-np.array(one.A)[-1], a_got[i], rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(np.array(one.c)[0], num_got[i], rtol=1e-13, atol=1e-13)
        num_tf, den_tf = tf_coeffs(A[i], b[i], c[i])
        scale = 1 + np.abs(np.r_[num_tf, den_tf]).max()
        np.testing.assert_allclose(a_got[i], den_tf[1:][::-1], rtol=0, atol=1e-9 * scale)
        np.testing.assert_allclose(num_got[i], num_tf[1:][::-1], rtol=0, atol=1e-9 * scale)


def test_ccf_matrices_and_coefficients_round_trip_and_take_an_empty_batch():
    a, num = np.array([[6.0, 11.0, 6.0]]), np.array([[4.0, 3.0, 2.0]])
    A, b, c = ccf_matrices(a, num)
    np.testing.assert_array_equal(A[0], [[0, 1, 0], [0, 0, 1], [-6, -11, -6]])
    np.testing.assert_array_equal(b[0], [0, 0, 1])
    a2, num2 = ccf_coefficients(A, b, c)
    np.testing.assert_allclose(a2, a, rtol=1e-14)
    np.testing.assert_allclose(num2, num, rtol=1e-14)
    empty = ccf_coefficients(np.zeros((0, 2, 2)), np.zeros((0, 2)), np.zeros((0, 2)))
    assert [x.shape for x in empty] == [(0, 2), (0, 2)]


def test_coefficients_function_rejects_a_bad_order():
    from symbolic.realisation import coefficients_function

    assert coefficients_function(np.int64(2)) is coefficients_function(2)   # cached per order
    for bad in (0, -1, 2.0, True, "3"):
        with pytest.raises(ValueError, match=r"n must be an integer >= 1; got"):
            coefficients_function(bad)


def test_element_map_rejects_an_unknown_kind():
    from aeid_struct.structures.constraints import ElementMap

    with pytest.raises(ValueError, match=r"kind must be one of real, nonneg, pos, neg, interval; "
                                         r"got 'positive'"):
        ElementMap("positive")


def test_old_module_paths_still_resolve():
    # the flat layout's paths users import keep working (aeid_struct._compat, the package API)
    import aeid_struct.maps as old_maps

    from aeid_struct import structures
    from aeid_struct.structures import maps

    assert old_maps is maps
    assert (structures.CCF, structures.MCF, structures.Physical) == (CCF, MCF, Physical)
    assert structures.ccf_coefficients is ccf_coefficients


def test_a_fresh_interpreter_reads_every_structure_type_whichever_name_came_first():
    """The package imports its structures on first use of a name: the registry that reads a
    config knows every type however the structures were reached."""
    import subprocess
    import sys

    script = ("from aeid_struct.structures import Structure\n"
              "for t in ({'type': 'CCF', 'n': 2, 'descartes': False, 'feedthrough': False,"
              " 'fixed': {}}, {'type': 'MCF', 'real': 1, 'pairs': 1, 'feedthrough': False,"
              " 'fixed': {}}):\n"
              "    print(type(Structure.from_config(t)).__name__)\n")
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["CCF", "MCF"]


def test_numeric_evaluates_each_threads_own_arguments():
    """Four threads evaluate one Numeric with their own arguments, switching between any two
    bytecodes: each gets its own result (one shared buffer gave a thread another's
    arguments: 3 of 4 threads wrong here before each thread had its own)."""
    from helpers import wrong_in_threads

    from aeid_struct.structures import Numeric

    x = casadi.SX.sym("x", 3)
    f = casadi.Function("f", [x], [casadi.sin(x) * 2 + x[0] * x[1]])
    numeric = Numeric(f)
    args = [np.random.default_rng(k).standard_normal(3) for k in range(4)]
    want = [np.asarray(f(a)).ravel() for a in args]
    assert wrong_in_threads(lambda k: np.array_equal(numeric(args[k])[0], want[k]),
                            calls=5000) == []
    # a copy (pickle, deepcopy) evaluates through buffers of its own
    import copy
    import pickle

    for other in (copy.deepcopy(numeric), pickle.loads(pickle.dumps(numeric))):
        np.testing.assert_array_equal(other(args[0])[0], want[0])
