r"""The robot leg's maps (paper Sec. IV): physical parameters ``(k, d, m)`` -> the bottom-row CCF
(paper Eq. 5) of each SISO subsystem of Eq. 16. They are the forward half of ``symbolic.leg``, a
module apart from the inverses (``symbolic.leg_inverses``) because the two halves are separate
derivations that share nothing but the model's constants: a map composes ``subsystems()`` with
``ccf()``, an inverse reads closed forms off the CCF's entries.

Eq. 16 decouples into the stable translational subsystem ``G1 = (1/m) / (s^2 + (d/m) s + k/m)``
(input ``F``, output ``l``) and the unstable rotational one ``G2 = (1/(m L^2)) / (s^2 - g/L)``
(input ``tau``, output ``theta``), ``L = l0 - m g / k`` (``symbolic.slip``). ``l0`` and ``g`` are
fixed when a map is built so that every map shares the signature ``(k, d, m)``. Outputs are
capitalised because CasADi forbids an output ``d`` next to the input ``d``. SX throughout: the
expressions are small and scalar-heavy, SX expands symbolic solves exactly and generates compact C.

The maps are registered with ``symbolic.named.named`` under ``symbolic.leg.<name>``, not under
this module's name: that is the name model files hold (``{"map": "symbolic.leg.stable_map",
...}``), and ``symbolic.leg`` re-exports the maps so that it keeps resolving.
"""

from __future__ import annotations

import casadi

from .named import named
from .realisation import ccf
from .slip import L0, G, check_constant, subsystems

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
