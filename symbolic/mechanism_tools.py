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

    def channels(self, specs: Sequence[tuple], **operating) -> casadi.Function:
        """The CCFs (paper Eq. 5) of several channels of one record as one map, record after
        record: the map of a physical structure of ``R`` records
        (``aeid_struct.Physical(mechanism, channels=...)``).

        Parameters
        ----------
        specs : sequence of (output, input) or (output, input, states)
            The channels, as :meth:`channel` takes them; all of one order.
        **operating
            ``u, q, guess, known`` as :meth:`linearise`.

        Returns
        -------
        casadi.Function
            ``'<name>_y<i>u<j>_y<k>u<l>..'``: the free parameters by name -> ``A1, B1, C1, D1,
            .., AR, .., DR``.

        Raises
        ------
        ValueError
            A malformed channel, or channels of different orders.
        """
        maps = []
        for spec in specs:
            out, inp, *rest = spec
            maps.append(self.channel(out, inp, states=rest[0] if rest else None, **operating))
        orders = [f.size_out("A")[0] for f in maps]
        if len(set(orders)) != 1:
            raise ValueError(f"channels must have one order (one encoder output per record); "
                             f"got orders {orders} for {[tuple(s[:2]) for s in specs]}: give "
                             "states= of the same size, or all states")
        names = maps[0].name_in()
        kind = casadi.SX if all(f.is_a("SXFunction") for f in maps) else casadi.MX
        symbols = [kind.sym(k) for k in names]
        outs, labels = [], []
        for r, f in enumerate(maps, start=1):
            outs += list(f(*symbols))
            labels += [f"{k}{r}" for k in "ABCD"]
        tag = "_".join(f"y{s[0]}u{s[1]}" for s in specs)
        return casadi.Function(f"{self.name}_{tag}", symbols, outs, names, labels)

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
