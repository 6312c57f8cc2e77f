"""``aeid-struct demo``: the robot-leg model derived with CasADi (paper Eq. 16), both subsystems
in controllable canonical form (Eq. 5) and their exact FOH unit-step responses (Eq. 10-13)."""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aeid_struct.cli.errors import InputError


@dataclass(frozen=True)
class _Response:
    """One subsystem's unit-step response for the demo figure: ``t, y (steps,)``."""

    title: str
    step: str       # the input that steps, with its unit
    output: str     # the output's quantity and unit (the axis label)
    t: np.ndarray
    y: np.ndarray


def _demo_figure(responses: list[_Response], params: dict[str, float]):
    """The demo's figure: one panel per subsystem, quantities with units, a title that says
    what produced it. A ``matplotlib.figure.Figure`` (no pyplot state)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.4))
    axes = fig.subplots(1, len(responses))
    for ax, r in zip(np.atleast_1d(axes), responses, strict=True):
        ax.plot(r.t, r.y)
        ax.set_title(f"{r.title}\nresponse to a unit step of {r.step}", fontsize=10)
        ax.set_xlabel("time t [s]")
        ax.set_ylabel(r.output)
        ax.set_xlim(r.t[0], r.t[-1])
        ax.grid(True, alpha=0.3)
    fig.suptitle("aeid-struct demo: robot leg linearised by CasADi (paper Eq. 16), exact FOH "
                 f"simulation (Eq. 10-13); k = {params['k']:g} N/m, d = {params['d']:g} kg/s, "
                 f"m = {params['m']:g} kg", fontsize=10)
    fig.tight_layout()
    return fig




def run_demo(args: argparse.Namespace) -> int:
    """The ``demo`` subcommand: print the linearisation and both subsystems, write the PNG.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments of ``aeid-struct demo`` (``k, d, m``, the grids, ``out``).

    Returns
    -------
    int
        0.

    Raises
    ------
    InputError
        ``k, m`` that leave no upright equilibrium, or an ``--out`` that cannot be written.
    """
    import aeid_struct as ae
    from symbolic import leg

    out = Path(args.out)
    params = {"k": args.k, "d": args.d, "m": args.m}
    # The rotational subsystem is linearised about the upright leg at the length where the
    # spring carries the weight, L = l0 - m g / k (symbolic.leg): it must be a positive length.
    if not leg.L0 - args.m * leg.G / args.k > 0:
        raise InputError(
            f"demo: --k and --m must let the spring carry the weight (l0 - m g / k > 0 with "
            f"l0 = {leg.L0} m, g = {leg.G} m/s^2, i.e. k > {args.m * leg.G / leg.L0:.4g} N/m "
            f"for m = {args.m:g} kg); got k = {args.k:g} N/m")
    np.set_printoptions(precision=4, suppress=True)

    t0 = time.perf_counter()
    lin = leg.linearisation()(**params, l0=leg.L0, g=leg.G)
    A, B = np.array(lin["A"]), np.array(lin["B"])
    print(f"Robot leg (spring-loaded inverted pendulum), k={args.k} N/m, d={args.d} kg/s, "
          f"m={args.m} kg, l0={leg.L0} m, g={leg.G} m/s^2")
    print(f"Linearisation at the upright equilibrium by CasADi Jacobians (paper Eq. 16), "
          f"derived in {time.perf_counter() - t0:.2f} s:")
    print("A =\n", A)
    print("B =\n", B)

    # (title, map, dt, steps, the input that steps, the output with its unit)
    systems = [
        ("translational subsystem G1 (stable)", leg.stable_map(), args.dt_stable,
         args.steps_stable, "the leg force F [N]", "leg length deflection l - L [m]"),
        ("rotational subsystem G2 (unstable)", leg.unstable_map(), args.dt_unstable,
         args.steps_unstable, "the hip torque tau [N m]",
         "leg angle deflection theta - pi/2 [rad]"),
    ]
    responses = []
    for title, f, dt, steps, step, output in systems:
        ccf = f(**params)
        Ac, bc = np.array(ccf["A"]), np.array(ccf["B"])[:, 0]
        cc, dc = np.array(ccf["C"])[0], float(np.array(ccf["D"])[0, 0])
        y = ae.simulate(Ac, bc, cc, dc, np.ones(steps), dt)
        print(f"\n{title} in controllable canonical form (paper Eq. 5):")
        print("A =\n", Ac)
        print("b =", bc, " c =", cc, " d =", dc)
        print(f"poles: {np.linalg.eigvals(Ac)}")
        print(f"unit-step response: {steps} samples, dt = {dt} s, y[-1] = {y[-1]:.6g}")
        responses.append(_Response(title, step, output, np.arange(steps) * dt, y))
    fig = _demo_figure(responses, params)
    png = out / "leg_step_responses.png"
    try:
        out.mkdir(parents=True, exist_ok=True)
        fig.savefig(png, dpi=120, metadata={"Title": fig.get_suptitle()})
    except OSError as err:
        raise InputError(f"demo: --out {args.out!r}: cannot write {png} "
                         f"({err.strerror or err})") from None
    print(f"\nwrote {png}")
    return 0

