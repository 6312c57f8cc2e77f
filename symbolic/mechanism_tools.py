"""What a :class:`~symbolic.mechanism.Mechanism` gives to other tools and questions: C code of
its maps, a numerical simulation of the nonlinear model (CasADi's ``cvodes``), and the
identifiability report of chosen channels (``symbolic.identifiability``). A mixin of the class,
apart from the derivation it reads (``mechanism.py``)."""

from __future__ import annotations

import pathlib
from collections.abc import Mapping, Sequence

import casadi
import numpy as np

from .codegen import generate_c

__all__ = ["MechanismTools"]


class MechanismTools:
    """C code, simulation and identifiability of a mechanism (module docstring); mixed into
    ``Mechanism``, whose ``x, u, p, f, h``, ``names`` and maps it reads."""

    def generate_c(self, directory: str | pathlib.Path, *, channels: Sequence[tuple] = (),
                   **operating) -> pathlib.Path:
        """The dynamics, the linearisation and the named channels as one C file.

        Parameters
        ----------
        directory : str or Path
        channels : sequence of (output, input) or (output, input, states)
        **operating
            As :meth:`linearise`.

        Returns
        -------
        pathlib.Path
            ``directory / "<name>.c"`` (``symbolic.codegen.generate_c``).
        """
        functions = [self.dynamics(), self.linearise(**operating)]
        for spec in channels:
            out, inp, *rest = spec
            functions.append(self.channel(out, inp, states=rest[0] if rest else None,
                                          **operating))
        return generate_c(directory, functions, name=self.name)

    def simulate(self, parameters: Mapping[str, float], u, dt: float, *, x0=None) -> np.ndarray:
        """The nonlinear model's outputs under ``u`` held between samples, by CasADi's
        ``cvodes`` integrator (the oracle of the linearisation: a small excitation about the
        equilibrium stays near the linear model).

        Parameters
        ----------
        parameters : dict str -> float
            Every parameter's value.
        u : (N, m) array, or (N,) for one input
            The inputs, each held for one step (absolute, not deviations).
        dt : float
        x0 : (n,) array, optional
            The state at the first sample; zeros by default.

        Returns
        -------
        (N, p) array
            ``y`` at each sample, before that sample's input acts.
        """
        return _integrate(self, parameters, u, dt, x0)

    def identifiability(self, bounds: Mapping[str, tuple[float, float]], **options):
        """Which parameters chosen channels determine (``symbolic.identifiability``).

        Parameters
        ----------
        bounds : dict name -> (low, high)
            The box of every parameter not in ``known``.
        **options
            ``known``, ``inputs``, ``outputs``, ``points``, ``seed`` and the operating point
            (``u``, ``q``, ``guess``) of :func:`symbolic.identifiability.identifiability`.

        Returns
        -------
        IdentifiabilityReport
        """
        from .identifiability import identifiability

        return identifiability(self, bounds, **options)


def _integrate(self, parameters, u, dt, x0) -> np.ndarray:
    """``Mechanism.simulate`` of the Mechanism ``self``."""
    n, m, _ = self.shape
    missing = sorted(set(self.names) - set(parameters))
    if missing:
        raise ValueError(f"parameters must give every parameter; missing {missing}")
    p = np.array([float(parameters[k]) for k in self.names])
    u = np.asarray(u, dtype=float)
    if u.ndim == 1 and m == 1:
        u = u[:, None]
    if u.ndim != 2 or u.shape[1] != m or u.shape[0] < 1 or not np.isfinite(u).all():
        raise ValueError(f"u must be finite (N, {m}) numbers, one column per input; got shape "
                         f"{u.shape}")
    if isinstance(dt, bool) or not (isinstance(dt, (int, float)) and dt > 0):
        raise ValueError(f"dt must be a positive number; got {dt!r}")
    x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).ravel()
    if x.shape != (n,):
        raise ValueError(f"x0 must be {n} numbers, the state (q, dq); got shape {x.shape}")
    up = casadi.vertcat(self.u, self.p)
    step = casadi.integrator(f"{self.name}_step", "cvodes",
                             {"x": self.x, "p": up, "ode": self.f}, 0.0, float(dt),
                             {"abstol": 1e-12, "reltol": 1e-12})
    run = step.mapaccum(u.shape[0])
    xs = np.array(run(x0=x, p=np.vstack([u.T, np.repeat(p[:, None], u.shape[0], 1)]))["xf"])
    states = np.hstack([x[:, None], xs[:, :-1]])
    h = casadi.Function("h", [self.x, self.u, self.p], [self.h])
    return np.array(h.map(u.shape[0])(states, u.T, np.repeat(p[:, None], u.shape[0], 1))).T
