r"""The robot leg of paper Sec. IV: maps from its physical parameters to canonical forms and back.

The model and its derivation (Lagrangian, equations of motion, equilibrium, the linearisation of
paper Eq. 16, the two SISO subsystems) are in ``symbolic.slip``, re-exported here. Eq. 16
decouples into the stable translational subsystem ``G1 = (1/m) / (s^2 + (d/m) s + k/m)`` (input
``F``, output ``l``) and the unstable rotational one ``G2 = (1/(m L^2)) / (s^2 - g/L)`` (input
``tau``, output ``theta``), ``L = l0 - m g / k``. This module turns them into what the physical
structures need:

* **Maps** ``(k, d, m) -> (A, B, C, D)``: the bottom-row CCF of each subsystem (paper Eq. 5,
  ``symbolic.realisation.ccf``), ``l0`` and ``g`` fixed when a map is built so that every map
  shares the signature ``(k, d, m)``. Outputs are capitalised because CasADi forbids an output
  ``d`` next to the input ``d``.
* **Inverses** CCF -> ``(k, d, m)``: closed forms from the informative CCF entries
  (``a_0 = -A[1, 0]``, ``a_1 = -A[1, 1]``, ``c_0 = C[0, 0]``); pure expressions, so data outside
  the physical domain give negative or NaN parameters rather than an error.
* **C code** of the maps and inverses (``symbolic.codegen``).

The maps and inverses are registered with ``symbolic.named.named``: a model file names them
(``{"map": "symbolic.leg.stable_map", "args": {"l0": 0.8, "g": 9.81}}``) instead of holding their
code (``docs/architecture.md``, *Model files*). SX throughout: the expressions are small and
scalar-heavy, SX expands symbolic solves exactly and generates compact C.

Run ``python -m symbolic.leg`` to print the derivation and check it (assertions at the end).
"""

from __future__ import annotations

import pathlib
import shutil

import casadi

from . import codegen
from .named import named
from .realisation import CCFRealisation as CCFRealisation
from .realisation import ccf as ccf
from .slip import L0 as L0
from .slip import PARAMETERS as PARAMETERS
from .slip import RANGES as RANGES
from .slip import SCENARIO as SCENARIO
from .slip import G as G
from .slip import check_constant, check_derivation
from .slip import dynamics as dynamics
from .slip import eq16 as eq16
from .slip import equilibrium as equilibrium
from .slip import lagrangian as lagrangian
from .slip import linearisation as linearisation
from .slip import subsystems as subsystems

#: The Functions that ``generate_c`` writes and ``compile_c`` loads.
CODEGEN_FUNCTIONS = (
    "stable_map",
    "unstable_map",
    "joint_map",
    "stable_inverse",
    "unstable_inverse",
    "joint_inverse",
)


# =============================================================================
# Maps: physical parameters (k, d, m) -> CCF of each subsystem
# =============================================================================


def _subsystem_map(name: str, index: int, l0: float, g: float) -> casadi.Function:
    l0, g = check_constant("l0", l0), check_constant("g", g)
    k, d, m = (casadi.SX.sym(s) for s in ("k", "d", "m"))
    sub = subsystems()(k=k, d=d, m=m, l0=l0, g=g)
    A, B, C, D = ccf(*(sub[f"{s}{index}"] for s in "ABCD"))
    return casadi.Function(name, [k, d, m], [A, B, C, D], ["k", "d", "m"], ["A", "B", "C", "D"])


@named("symbolic.leg.stable_map")
def stable_map(l0: float = L0, g: float = G) -> casadi.Function:
    """``(k, d, m)`` -> CCF of the translational subsystem ``G1 = (1/m) / (s^2 + (d/m) s + k/m)``.

    Derived by ``ccf()`` from ``subsystems()``: ``a_0 = k/m``, ``a_1 = d/m``, ``c_0 = 1/m``,
    ``c_1 = 0``, ``D = 0``. ``G1`` depends on neither ``l0`` nor ``g``; they are accepted (and
    validated) so that both maps are built alike.

    Parameters
    ----------
    l0 : float
        Rest length of the leg spring, m (finite, positive).
    g : float
        Gravitational acceleration, m/s^2 (finite, positive).

    Returns
    -------
    casadi.Function
        ``'stable_map'``: scalars ``k, d, m`` -> ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)``.

    Raises
    ------
    TypeError
        If a constant is not a real number.
    ValueError
        If a constant is not finite and positive.
    """
    return _subsystem_map("stable_map", 1, l0, g)


@named("symbolic.leg.unstable_map")
def unstable_map(l0: float = L0, g: float = G) -> casadi.Function:
    """``(k, d, m)`` -> CCF of the rotational subsystem ``G2 = (1/(m L^2)) / (s^2 - g/L)``.

    Derived by ``ccf()`` from ``subsystems()``: ``a_0 = -g/L``, ``a_1 = 0``, ``c_0 = 1/(m L^2)``,
    ``c_1 = 0``, ``D = 0``, with ``L = l0 - m g / k``. ``G2`` does not depend on ``d``: the damper
    acts along the leg only, so ``d`` is unidentifiable from the rotational subsystem. The input is
    kept so that both maps share the signature ``(k, d, m)``.

    Parameters
    ----------
    l0 : float
        Rest length of the leg spring, m (finite, positive).
    g : float
        Gravitational acceleration, m/s^2 (finite, positive).

    Returns
    -------
    casadi.Function
        ``'unstable_map'``: scalars ``k, d, m`` -> ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)``.

    Raises
    ------
    TypeError
        If a constant is not a real number.
    ValueError
        If a constant is not finite and positive.
    """
    return _subsystem_map("unstable_map", 2, l0, g)


@named("symbolic.leg.joint_map")
def joint_map(l0: float = L0, g: float = G) -> casadi.Function:
    """``(k, d, m)`` -> the CCFs of both subsystems: one parameter set, two records.

    The map of a jointly identified leg (one encoder reads the stable and the unstable record and
    outputs one ``(k, d, m)``): ``stable_map`` and ``unstable_map`` side by side, outputs numbered
    by record (1 = translational ``G1``, 2 = rotational ``G2``), as ``joint_inverse`` reads them.

    Parameters
    ----------
    l0 : float
        Rest length of the leg spring, m (finite, positive).
    g : float
        Gravitational acceleration, m/s^2 (finite, positive).

    Returns
    -------
    casadi.Function
        ``'joint_map'``: scalars ``k, d, m`` -> ``A1 (2, 2), B1 (2, 1), C1 (1, 2), D1 (1, 1),
        A2, B2, C2, D2``.

    Raises
    ------
    TypeError
        If a constant is not a real number.
    ValueError
        If a constant is not finite and positive.
    """
    k, d, m = (casadi.SX.sym(s) for s in ("k", "d", "m"))
    outs = [*stable_map(l0, g)(k, d, m), *unstable_map(l0, g)(k, d, m)]
    names = [f"{s}{r}" for r in (1, 2) for s in "ABCD"]
    return casadi.Function("joint_map", [k, d, m], outs, ["k", "d", "m"], names)


# =============================================================================
# Inverses: CCF -> physical parameters
# =============================================================================


def _ccf_symbols(suffix: str = "") -> tuple[list[casadi.SX], list[str]]:
    """Input symbols ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)`` of a second-order CCF."""
    shapes = {"A": (2, 2), "B": (2, 1), "C": (1, 2), "D": (1, 1)}
    names = [f"{s}{suffix}" for s in shapes]
    symbols = [casadi.SX.sym(n, *shape) for n, shape in zip(names, shapes.values(), strict=True)]
    return symbols, names


@named("symbolic.leg.stable_inverse")
def stable_inverse(l0: float = L0, g: float = G) -> casadi.Function:
    """CCF of ``G1`` -> ``(k, d, m)``: ``m = 1/c_0``, ``k = a_0 m``, ``d = a_1 m``.

    ``a_0 = -A[1, 0]``, ``a_1 = -A[1, 1]``, ``c_0 = C[0, 0]``; ``B``, ``D`` and ``c_1`` are ignored.
    ``l0`` and ``g`` do not enter (validated only, for a uniform signature).

    Parameters
    ----------
    l0 : float
        Rest length of the leg spring, m (finite, positive).
    g : float
        Gravitational acceleration, m/s^2 (finite, positive).

    Returns
    -------
    casadi.Function
        ``'stable_inverse'``: ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)`` -> scalars ``k, d, m``.

    Raises
    ------
    TypeError
        If a constant is not a real number.
    ValueError
        If a constant is not finite and positive.
    """
    check_constant("l0", l0)
    check_constant("g", g)
    (A, B, C, D), names = _ccf_symbols()
    a0, a1, c0 = -A[1, 0], -A[1, 1], C[0, 0]
    m = 1 / c0
    return casadi.Function(
        "stable_inverse", [A, B, C, D], [a0 * m, a1 * m, m], names, ["k", "d", "m"]
    )


@named("symbolic.leg.unstable_inverse")
def unstable_inverse(l0: float = L0, g: float = G) -> casadi.Function:
    """CCF of ``G2`` -> ``(k, m)``: ``L = -g/a_0``, ``m = 1/(c_0 L^2)``, ``k = m g / (l0 - L)``.

    ``a_0 = -A[1, 0]``, ``c_0 = C[0, 0]``; ``a_1``, ``c_1``, ``B`` and ``D`` are ignored. ``d`` has
    no output: ``G2`` does not depend on it.

    Parameters
    ----------
    l0 : float
        Rest length of the leg spring, m (finite, positive).
    g : float
        Gravitational acceleration, m/s^2 (finite, positive).

    Returns
    -------
    casadi.Function
        ``'unstable_inverse'``: ``A (2, 2), B (2, 1), C (1, 2), D (1, 1)`` -> scalars ``k, m``.

    Raises
    ------
    TypeError
        If a constant is not a real number.
    ValueError
        If a constant is not finite and positive.
    """
    l0, g = check_constant("l0", l0), check_constant("g", g)
    (A, B, C, D), names = _ccf_symbols()
    a0, c0 = -A[1, 0], C[0, 0]
    L = -g / a0
    m = 1 / (c0 * L**2)
    k = m * g / (l0 - L)
    return casadi.Function("unstable_inverse", [A, B, C, D], [k, m], names, ["k", "m"])


@named("symbolic.leg.joint_inverse")
def joint_inverse(l0: float = L0, g: float = G, *, unstable_noise: float = 1.0) -> casadi.Function:
    r"""Both subsystems' CCFs -> ``(k, d, m)``, combining what each says about ``k`` and ``m``.

    What the data say. The stable CCF gives ``omega^2 = k/m = a_0^{(1)}``, ``d/m = a_1^{(1)}`` and
    ``m = 1/c_0^{(1)}``. The unstable CCF gives ``L = -g/a_0^{(2)}`` and ``m L^2 = 1/c_0^{(2)}``,
    i.e. again ``omega^2 = g / (l0 - L)`` and ``m = 1/(c_0^{(2)} L^2)``. So ``omega^2`` and ``m``
    are each measured twice; ``d`` only once (``d = a_1^{(1)} m``).

    Combination. In log space, ``y_s = (log a_0^{(1)}, -log c_0^{(1)})`` and
    ``y_u = (log(g/(l0 - L)), -log(c_0^{(2)} L^2))`` both estimate ``theta = (log omega^2, log m)``.
    Model each informative coefficient with an independent relative error, ``sigma`` for the stable
    and ``unstable_noise * sigma`` for the unstable subsystem. To first order (delta method) the
    stable pair is then uncorrelated with covariance ``sigma^2 I`` and the unstable pair has

        Sigma_u = (unstable_noise sigma)^2 [[r^2, -2r], [-2r, 5]],   r = L / (l0 - L),

    (``d log(g/(l0-L)) = -r d log a_0``, ``d log(m) = 2 d log a_0 - d log c_0``). The
    minimum-variance (generalised least squares) estimate is the information-weighted mean

        theta = (I + W_u)^{-1} (y_s + W_u y_u),   W_u = sigma^2 Sigma_u^{-1},

    then ``m = exp(theta_2)``, ``k = exp(theta_1) m`` and ``d = a_1^{(1)} m``.

    Why this one. (i) For exact data ``y_s = y_u = theta``, so it round-trips exactly, like any
    consistent combination. (ii) It is well conditioned: the matrix solved, ``I + W_u``, is
    symmetric with eigenvalues ``>= 1`` (``W_u`` is positive semi-definite), so the solve cannot
    blow up however degenerate ``G2``'s information is, and the stable subsystem alone keeps every
    parameter identifiable. (iii) It avoids the
    poorly conditioned route "``k`` and ``m`` from ``G2`` alone", whose relative sensitivity to
    ``a_0^{(2)}`` is ``r`` for ``k/m`` (up to 3 in the study's ranges) and 2 for ``m``, while it
    still uses ``G2`` where it is informative (``r`` small: ``omega^2`` is then nearly insensitive
    to ``L``). (iv) ``unstable_noise`` states how much less one trusts ``G2`` (the paper's
    identified unstable models are markedly worse, Table I); ``unstable_noise -> inf`` recovers
    ``stable_inverse``.

    Parameters
    ----------
    l0 : float
        Rest length of the leg spring of the maps that produced the data, m.
    g : float
        Gravitational acceleration of those maps, m/s^2.
    unstable_noise : float
        Relative error of the unstable coefficients over that of the stable ones (positive);
        1.0 trusts both alike.

    Returns
    -------
    casadi.Function
        ``'joint_inverse'``: ``A1 (2, 2), B1 (2, 1), C1 (1, 2), D1 (1, 1), A2, B2, C2, D2`` ->
        scalars ``k, d, m``. Needs ``L = -g/a_0^{(2)}`` with ``L < l0``, ``L != 0``, and positive
        ``a_0^{(1)}, c_0^{(1)}, c_0^{(2)}`` (NaN otherwise).

    Raises
    ------
    TypeError
        If a constant is not a real number.
    ValueError
        If a constant is not finite and positive.
    """
    l0, g = check_constant("l0", l0), check_constant("g", g)
    unstable_noise = check_constant("unstable_noise", unstable_noise)
    (A1, B1, C1, D1), names1 = _ccf_symbols("1")
    (A2, B2, C2, D2), names2 = _ccf_symbols("2")

    a0_s, a1_s, c0_s = -A1[1, 0], -A1[1, 1], C1[0, 0]
    a0_u, c0_u = -A2[1, 0], C2[0, 0]
    L = -g / a0_u
    y_s = casadi.vertcat(casadi.log(a0_s), -casadi.log(c0_s))
    y_u = casadi.vertcat(casadi.log(g / (l0 - L)), -casadi.log(c0_u * L**2))

    r = L / (l0 - L)
    # W_u = Sigma_u^{-1} sigma^2 = [[5, 2r], [2r, r^2]] / (r^2 unstable_noise^2): the closed-form
    # inverse of [[r^2, -2r], [-2r, 5]], whose determinant is r^2.
    W_u = casadi.vertcat(
        casadi.horzcat(5 / r**2, 2 / r), casadi.horzcat(2 / r, 1)
    ) / unstable_noise**2
    theta = casadi.solve(casadi.SX.eye(2) + W_u, y_s + casadi.mtimes(W_u, y_u))
    m = casadi.exp(theta[1])
    k = casadi.exp(theta[0]) * m
    d = a1_s * m
    return casadi.Function(
        "joint_inverse",
        [A1, B1, C1, D1, A2, B2, C2, D2],
        [k, d, m],
        names1 + names2,
        ["k", "d", "m"],
    )


# =============================================================================
# Code generation
# =============================================================================


def generate_c(
    directory: str | pathlib.Path, *, l0: float = L0, g: float = G, name: str = "leg_maps"
) -> pathlib.Path:
    """Write the maps and inverses (``CODEGEN_FUNCTIONS``) into one C file.

    Parameters
    ----------
    directory : str or pathlib.Path
        Where to write (created if missing).
    l0, g : float
        The constants baked into the generated functions.
    name : str
        The file's stem; the file is ``directory / f"{name}.c"``.

    Returns
    -------
    pathlib.Path
        The C file (``symbolic.codegen.generate_c``).

    Raises
    ------
    ValueError
        If ``name`` is not a C identifier, ``directory`` not a folder path, or a constant not
        finite and positive.
    """
    builders = {
        "stable_map": stable_map,
        "unstable_map": unstable_map,
        "joint_map": joint_map,
        "stable_inverse": stable_inverse,
        "unstable_inverse": unstable_inverse,
        "joint_inverse": joint_inverse,
    }
    functions = [builders[fname](l0=l0, g=g) for fname in CODEGEN_FUNCTIONS]
    return codegen.generate_c(directory, functions, name=name)


def compile_c(
    c_file: str | pathlib.Path, *, compiler: str | None = None
) -> dict[str, casadi.Function]:
    """Compile a file from :func:`generate_c` to a shared library and load its functions.

    Parameters
    ----------
    c_file : str or pathlib.Path
        The C file; the library is written next to it with the suffix ``.so``.
    compiler : str, optional
        The C compiler's path; by default ``gcc``, else ``cc``, from ``PATH``.

    Returns
    -------
    dict[str, casadi.Function]
        ``CODEGEN_FUNCTIONS`` name -> ``casadi.external`` Function, with the same input and
        output names as the SX original.

    Raises
    ------
    FileNotFoundError
        If ``c_file`` is not an existing file.
    RuntimeError
        If no C compiler is found, or compilation fails (the message carries the compiler's
        output).
    """
    return codegen.compile_c(c_file, CODEGEN_FUNCTIONS, compiler=compiler)


# =============================================================================
# Self-check: python -m symbolic.leg
# =============================================================================


def _self_check() -> None:
    import tempfile

    import numpy as np

    check_derivation()
    fs, fu = stable_map(), unstable_map()
    cs, cu = fs(**SCENARIO), fu(**SCENARIO)
    for label, sys in (("stable G1", cs), ("unstable G2", cu)):
        print(f"  {label}: A = {np.array(sys['A']).tolist()}, C = {np.array(sys['C']).tolist()}")
    back_s = stable_inverse()(**cs)
    back_u = unstable_inverse()(**cu)
    sub = {f"{s}1": v for s, v in cs.items()} | {f"{s}2": v for s, v in cu.items()}
    back_j = joint_inverse()(**sub)
    for label, back in (("stable", back_s), ("unstable", back_u), ("joint", back_j)):
        print(f"  {label}_inverse: " + ", ".join(f"{n} = {float(v):.6g}" for n, v in back.items()))

    compiled_ok = True
    if shutil.which("gcc") or shutil.which("cc"):
        with tempfile.TemporaryDirectory() as tmp:
            compiled = compile_c(generate_c(tmp))
            compiled_ok = np.allclose(
                np.array(compiled["stable_map"](**SCENARIO)["A"]), np.array(cs["A"]), rtol=1e-14
            )
        print("  generated C, compiled and loaded: agrees with SX:", compiled_ok)

    L = L0 - SCENARIO["m"] * G / SCENARIO["k"]
    expected_s = [[0, 1], [-SCENARIO["k"] / SCENARIO["m"], -SCENARIO["d"] / SCENARIO["m"]]]
    assert np.allclose(np.array(cs["A"]), expected_s, rtol=1e-14, atol=1e-14)
    assert np.allclose(np.array(cu["A"]), [[0, 1], [G / L, 0]], rtol=1e-14, atol=1e-14)
    assert np.isclose(float(cu["C"][0, 0]), 1 / (SCENARIO["m"] * L**2), rtol=1e-14)
    for name, value in SCENARIO.items():
        assert np.isclose(float(back_s[name]), value, rtol=1e-13), name
        assert np.isclose(float(back_j[name]), value, rtol=1e-13), name
        if name != "d":
            assert np.isclose(float(back_u[name]), value, rtol=1e-13), name
    assert compiled_ok
    print("\nAll checks passed.")


if __name__ == "__main__":
    _self_check()
