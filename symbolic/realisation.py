r"""The controllable canonical form of any SISO realisation, in CasADi (paper Eq. 5).

The bottom-row CCF of ``docs/architecture.md``: ones on the superdiagonal, last row
``(-a_0, ..., -a_{n-1})``, ``b = e_n``, ``c = (c_0, ..., c_{n-1})``, realising

    G(s) = (c_{n-1} s^{n-1} + ... + c_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0) + d.

:func:`ccf` reaches it from *any* realisation ``(A, b, c, d)`` of any order through the
characteristic polynomial and the Markov parameters ``h_i = c A^{i-1} b``. For ``n >= 3`` the
system is first brought to controller-Hessenberg form by Householder reflections; the
characteristic polynomial then comes from La Budde's recursion (division-free, so exact for
symbolic input), and the Markov parameters from triangular Krylov vectors. For ``n <= 2`` the
formulas are used as they are, so the symbolic leg maps stay plain rational expressions.

This is the library's one model -> CCF conversion: ``symbolic.leg`` uses it on SX expressions,
and ``aeid_struct.structures`` evaluates :func:`coefficients_function` on batches of numeric
models. Run ``python -m symbolic.realisation`` to check it against a transfer function typed
in by hand.
"""

from __future__ import annotations

import functools
import operator
from typing import NamedTuple

import casadi

__all__ = ["CCFRealisation", "ccf", "coefficients_function"]

# =============================================================================
# The canonical form
# =============================================================================


class CCFRealisation(NamedTuple):
    """A SISO system in bottom-row controllable canonical form (paper Eq. 5).

    A NamedTuple rather than a dataclass so that ``A, b, c, d = ccf(...)`` unpacks like the maths.

    Attributes
    ----------
    A : (n, n)  ones on the superdiagonal, last row ``(-a_0, ..., -a_{n-1})``
    b : (n, 1)  ``e_n``
    c : (1, n)  ``(c_0, ..., c_{n-1})``
    d : (1, 1)  feedthrough
    """

    A: casadi.SX | casadi.MX | casadi.DM
    b: casadi.SX | casadi.MX | casadi.DM
    c: casadi.SX | casadi.MX | casadi.DM
    d: casadi.SX | casadi.MX | casadi.DM


def _reflector(x):
    """Householder reflector ``P = I - 2 v v^T / (v^T v)`` with ``P x = -sign(x_0) |x| e_1``.

    ``v = x + sign(x_0) |x| e_1`` (the sign avoids cancellation; ``sign(0) = +1``). For ``x = 0``
    nothing needs reflecting and ``P = I``: the guarded ``1 / (v^T v)`` is then 0.
    """
    r = x.shape[0]
    alpha = casadi.if_else(x[0] >= 0, 1, -1) * casadi.norm_2(x)
    v = casadi.vertcat(x[0] + alpha, x[1:])
    vv = casadi.dot(v, v)
    return casadi.DM.eye(r) - 2 * casadi.if_else(vv > 0, 1 / vv, 0) * casadi.mtimes(v, v.T)


def _controller_hessenberg(A, b, c):
    """Orthogonal ``Q`` with ``Q^T b = beta e_1`` and ``Q^T A Q`` upper Hessenberg.

    One reflector aligns ``b`` with ``e_1``; then, column by column, reflectors acting on rows and
    columns ``k+1..n`` (so they leave ``e_1`` alone) zero ``A`` below its subdiagonal. Returns
    ``(Q^T A Q, Q^T b, c Q)``, the same system in the controller-Hessenberg basis, where the Krylov
    vectors ``H^i e_1`` are upper triangular.
    """
    n = A.shape[0]
    P = _reflector(b)
    A, b, c = casadi.mtimes([P, A, P]), casadi.mtimes(P, b), casadi.mtimes(c, P)
    for k in range(n - 2):
        P = casadi.diagcat(casadi.DM.eye(k + 1), _reflector(A[k + 1 :, k]))
        A, c = casadi.mtimes([P, A, P]), casadi.mtimes(c, P)
    return A, b, c


def _charpoly_hessenberg(H):
    """``[a_0, ..., a_{n-1}]`` of ``det(sI - H) = s^n + a_{n-1} s^{n-1} + ... + a_0``, H Hessenberg.

    La Budde's recursion over the leading principal submatrices (1-based indices):
    ``p_0 = 1``, ``p_i(s) = (s - h_ii) p_{i-1}(s)
    - sum_{m=1}^{i-1} h_{i-m,i} (prod_{j=i-m+1}^{i} h_{j,j-1}) p_{i-m-1}(s)``.
    Division-free, so exact for symbolic ``H``; numerically as accurate as eigenvalue-based
    ``numpy.poly``/``control.ss2tf`` on the tests' ill-conditioned systems.
    """
    n = H.shape[0]
    p = [[1]]  # p[i][j]: coefficient of s^j in p_i
    for i in range(1, n + 1):
        prev = p[i - 1]
        new = [-H[i - 1, i - 1] * prev[0]]
        new += [prev[j - 1] - H[i - 1, i - 1] * prev[j] for j in range(1, i)] + [prev[i - 1]]
        product = 1
        for m in range(1, i):
            product = product * H[i - m, i - m - 1]
            for j, coeff in enumerate(p[i - m - 1]):
                new[j] = new[j] - H[i - m - 1, i - 1] * product * coeff
        p.append(new)
    return p[n][:n]


def ccf(A, b, c, d) -> CCFRealisation:
    r"""Bottom-row controllable canonical form of the SISO system ``(A, b, c, d)``, any order n.

    ``det(sI - A) = s^n + a_{n-1} s^{n-1} + ... + a_0`` gives the last row of ``A``. With the
    Markov parameters ``h_i = c A^{i-1} b``, the numerator of
    ``c (sI - A)^{-1} b = N(s) / det(sI - A)`` is ``N(s) = sum_j c_j s^j`` with

        c_{n-j} = sum_{i=1}^{j} a_{n-j+i} h_i,   j = 1..n   (a_n = 1),

    read off from ``N(s) = det(sI - A) * sum_{i>=1} h_i s^{-i}``. The result realises
    ``G(s) = (c_{n-1} s^{n-1} + ... + c_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0) + d``.

    Numerics. For ``n >= 3`` the system is first brought to controller-Hessenberg form by
    Householder reflections (``Q^T b = beta e_1``, ``Q^T A Q`` upper Hessenberg); the characteristic
    polynomial then comes from La Budde's recursion and the Markov parameters from triangular
    Krylov vectors. Faddeev-LeVerrier and Markov parameters in the original basis are exact in
    exact arithmetic too, but in an ill-conditioned basis they lost up to all digits (n = 5, 6)
    where this route stays as accurate as ``control.ss2tf``. For ``n <= 2`` every matrix is already
    Hessenberg and the formulas are used as they are, so the symbolic leg maps stay plain rational
    expressions and a CCF input comes back unchanged (to rounding).

    Parameters
    ----------
    A : (n, n) casadi SX, MX or DM (NumPy arrays are converted to DM)
    b : n elements (column or row)
    c : n elements (column or row)
    d : 1 element

    Returns
    -------
    CCFRealisation
        ``A (n, n), b (n, 1), c (1, n), d (1, 1)``, of the symbolic type of the inputs (SX if any
        input is SX, else MX if any is MX, else DM).
    """
    A, b, c, d = (x if isinstance(x, casadi.SX | casadi.MX) else casadi.DM(x) for x in (A, b, c, d))
    n = A.shape[0]
    if A.shape[1] != n or n == 0:
        raise ValueError(f"A must be square (n, n) with n >= 1; got {A.shape}")
    for name, value in (("b", b), ("c", c)):
        if value.numel() != n or 1 not in value.shape:
            raise ValueError(
                f"{name} must be a vector with n={n} elements; got shape {value.shape}"
            )
    if d.numel() != 1:
        raise ValueError(f"d must be a scalar (1 element); got shape {d.shape}")
    kinds = {type(x) for x in (A, b, c, d)}
    if casadi.SX in kinds and casadi.MX in kinds:
        raise TypeError("ccf: do not mix SX and MX inputs")
    kind = casadi.SX if casadi.SX in kinds else casadi.MX if casadi.MX in kinds else casadi.DM
    b, c = casadi.reshape(b, n, 1), casadi.reshape(c, 1, n)
    if n >= 3:
        A, b, c = _controller_hessenberg(A, b, c)

    a = _charpoly_hessenberg(A) + [1]  # a[0..n], monic
    markov, krylov = [], b
    for _ in range(n):  # h_1 .. h_n
        markov.append(casadi.mtimes(c, krylov))
        krylov = casadi.mtimes(A, krylov)
    num = [sum(a[n - j + i] * markov[i - 1] for i in range(1, j + 1)) for j in range(1, n + 1)]
    coeffs = num[::-1]  # num[j-1] is c_{n-j}; reverse to (c_0, ..., c_{n-1})

    last_row = -casadi.horzcat(*a[:n])
    shift = casadi.horzcat(casadi.DM.zeros(n - 1, 1), casadi.DM.eye(n - 1))
    A_c = casadi.vertcat(kind(shift), last_row) if n > 1 else kind(last_row)
    b_c = kind(casadi.DM.eye(n)[:, n - 1])
    c_c = kind(casadi.horzcat(*coeffs))
    return CCFRealisation(A_c, b_c, c_c, kind(d))


# =============================================================================
# A named Function for numeric batches
# =============================================================================


def coefficients_function(n: int) -> casadi.Function:
    """The CCF coefficients of any order-``n`` realisation as a named SX Function.

    :func:`ccf` applied to symbolic ``A, b, c`` (``d`` does not enter the coefficients), built
    once per order and cached; ``Function.map`` evaluates it on a batch of numeric models.

    Parameters
    ----------
    n : int
        The order, ``>= 1``.

    Returns
    -------
    casadi.Function
        ``'ccf_coefficients'``: ``A (n, n), b (n, 1), c (n, 1)`` -> ``a (n, 1)``
        ``= (a_0, ..., a_{n-1})`` of ``det(sI - A) = s^n + a_{n-1} s^{n-1} + ... + a_0`` and
        ``num (n, 1) = (c_0, ..., c_{n-1})``, the numerator of ``c^T (sI - A)^{-1} b``.

    Raises
    ------
    ValueError
        If ``n`` is not an integer ``>= 1``.
    """
    try:
        order = operator.index(n)   # int and numpy integers, not floats or bools
    except TypeError:
        order = 0
    if isinstance(n, bool) or order < 1:
        raise ValueError(f"n must be an integer >= 1; got {n!r}")
    return _coefficients_function(order)


@functools.lru_cache(maxsize=32)
def _coefficients_function(n: int) -> casadi.Function:
    A, b, c = casadi.SX.sym("A", n, n), casadi.SX.sym("b", n), casadi.SX.sym("c", n)
    A_c, _, c_c, _ = ccf(A, b, c, casadi.SX(0.0))
    return casadi.Function(
        "ccf_coefficients", [A, b, c], [-A_c[n - 1, :].T, c_c.T], ["A", "b", "c"], ["a", "num"]
    )


# =============================================================================
# Self-check: python -m symbolic.realisation
# =============================================================================


def _self_check() -> None:
    import numpy as np

    # G(s) = (2 s^2 + 3 s + 4) / (s^3 + 6 s^2 + 11 s + 6) in a random basis T: the CCF must
    # give back the coefficients typed in, whatever T.
    a, num = np.array([6.0, 11.0, 6.0]), np.array([4.0, 3.0, 2.0])
    A_c = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], -a])
    T = np.random.default_rng(0).normal(size=(3, 3)) + 3 * np.eye(3)
    Ti = np.linalg.inv(T)
    out = ccf(T @ A_c @ Ti, T @ np.array([0.0, 0.0, 1.0]), num @ Ti, 0.5)
    print("G(s) = (2 s^2 + 3 s + 4) / (s^3 + 6 s^2 + 11 s + 6) + 0.5 in a random basis")
    print("  ccf: A =\n", np.array(out.A), "\n  c =", np.array(out.c), " d =", float(out.d))
    f = coefficients_function(3)
    print(f"  {f.name()}: {f.n_instructions()} SX instructions")
    coeffs = f(T @ A_c @ Ti, T @ np.array([0.0, 0.0, 1.0]), num @ Ti)
    assert np.allclose(np.array(out.A)[-1], -a, rtol=1e-12, atol=1e-12)
    assert np.allclose(np.array(out.c).ravel(), num, rtol=1e-12, atol=1e-12)
    assert np.allclose(np.array(coeffs[0]).ravel(), a, rtol=1e-12)
    assert np.allclose(np.array(coeffs[1]).ravel(), num, rtol=1e-12)
    print("\nAll checks passed.")


if __name__ == "__main__":
    _self_check()
