r"""The inverses of the robot leg's maps (paper Sec. IV): the CCF (paper Eq. 5) of a subsystem of
Eq. 16, or of both, -> the physical parameters ``(k, d, m)``. They are the backward half of
``symbolic.leg``, a module apart from the maps (``symbolic.leg_maps``) because they are a
derivation of their own that uses no part of the maps: closed forms read off the informative CCF
entries and, for both subsystems together, a generalised least-squares combination.

The informative entries are ``a_0 = -A[1, 0]``, ``a_1 = -A[1, 1]`` and ``c_0 = C[0, 0]``. The
inverses are pure expressions, so data outside the physical domain give negative or NaN
parameters rather than an error. ``l0`` and ``g`` are fixed when an inverse is built, as for the
maps. SX throughout, as the maps.

The inverses are registered with ``symbolic.named.named`` under ``symbolic.leg.<name>``, not under
this module's name: that is the name model files hold (``{"map": "symbolic.leg.stable_inverse",
...}``), and ``symbolic.leg`` re-exports the inverses so that it keeps resolving.
"""

from __future__ import annotations

import casadi

from .named import named
from .slip import L0, G, check_constant

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
