r"""The robot leg of paper Sec. IV: maps from its physical parameters to canonical forms and back.

The model and its derivation (Lagrangian, equations of motion, equilibrium, the linearisation of
paper Eq. 16, the two SISO subsystems) are in ``symbolic.slip``, re-exported here. Eq. 16
decouples into the stable translational subsystem ``G1 = (1/m) / (s^2 + (d/m) s + k/m)`` (input
``F``, output ``l``) and the unstable rotational one ``G2 = (1/(m L^2)) / (s^2 - g/L)`` (input
``tau``, output ``theta``), ``L = l0 - m g / k``. This module gathers what the physical
structures need, under the names that the library and model files use:

* **Maps** ``(k, d, m) -> (A, B, C, D)``: the bottom-row CCF of each subsystem (paper Eq. 5,
  ``symbolic.realisation.ccf``), ``l0`` and ``g`` fixed when a map is built so that every map
  shares the signature ``(k, d, m)``; defined in ``symbolic.leg_maps``, re-exported here.
* **Inverses** CCF -> ``(k, d, m)``: closed forms from the informative CCF entries
  (``a_0 = -A[1, 0]``, ``a_1 = -A[1, 1]``, ``c_0 = C[0, 0]``); pure expressions, so data outside
  the physical domain give negative or NaN parameters rather than an error; defined in
  ``symbolic.leg_inverses``, re-exported here.
* **C code** of the maps and inverses (``symbolic.codegen``), here: it needs both halves.

The maps and inverses are registered with ``symbolic.named.named``: a model file names them
(``{"map": "symbolic.leg.stable_map", "args": {"l0": 0.8, "g": 9.81}}``) instead of holding their
code (``docs/architecture.md``, *Model files*). Those names resolve through this module, which is
why it re-exports the maps and inverses rather than only pointing at their modules.

Run ``python -m symbolic.leg`` to print the derivation and check it (assertions at the end): the
check round-trips the paper's scenario through the maps and the inverses, so it lives here.
"""

from __future__ import annotations

import pathlib
import shutil

import casadi

from . import codegen
from .leg_inverses import joint_inverse as joint_inverse
from .leg_inverses import stable_inverse as stable_inverse
from .leg_inverses import unstable_inverse as unstable_inverse
from .leg_maps import joint_map as joint_map
from .leg_maps import stable_map as stable_map
from .leg_maps import unstable_map as unstable_map
from .realisation import CCFRealisation as CCFRealisation
from .realisation import ccf as ccf
from .slip import L0 as L0
from .slip import PARAMETERS as PARAMETERS
from .slip import RANGES as RANGES
from .slip import SCENARIO as SCENARIO
from .slip import G as G
from .slip import check_derivation
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
