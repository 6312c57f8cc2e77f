r"""Your own mechanism, from its Lagrangian to the linear models the identifiers learn, in CasADi.

An engineer writes what they know of their machine: generalised coordinates ``q`` and velocities
``dq``, inputs ``u``, named physical parameters ``p``, the Lagrangian ``L(q, dq, u, p) = T - V``,
optionally a Rayleigh dissipation ``R(q, dq, p)`` and generalised forces ``Q(q, dq, u, p)``, and
the measured outputs ``y(q, dq, u, p)``. :class:`Mechanism` derives the rest.

Equations of motion (Euler-Lagrange with dissipation and forces)::

    d/dt dL/ddq - dL/dq = Q - dR/ddq
    M(q, dq) ddq = Q - dR/ddq + dL/dq - (d/dq dL/ddq) dq,     M = d^2 L / ddq^2

solved for ``ddq`` symbolically (``casadi.solve``), so that with the state ``x = (q, dq)``::

    xdot = f(x, u, p) = (dq, ddq),        y = h(x, u, p).

Equilibrium at an operating input ``u_e``: ``dq = 0`` and ``ddq = 0``, i.e. the generalised
forces balance, ``Q - dR/ddq + dL/dq = 0`` at ``dq = 0``. The user names it (numbers or
expressions of the parameters), or a CasADi rootfinder solves it where it is isolated (its
Jacobian is regular); a rigid-body mode has a family of equilibria and is refused with the
instruction to name one.

Linearisation (paper Eq. 16 for the robot leg) at ``(x_e, u_e)``::

    A = df/dx,  B = df/du,  C = dh/dx,  D = dh/du,

a ``casadi.Function`` of the parameters by name with outputs ``A, B, C, D``; the linear
model's state, input and output are deviations from the equilibrium. :meth:`Mechanism.channel`
is the bottom-row CCF (paper Eq. 5) of one input-output channel (``symbolic.realisation.ccf``),
of a decoupled subsystem where ``states`` names its states, the map a physical structure's
encoder output goes through. :meth:`Mechanism.generate_c` writes them as C.

Run ``python -m symbolic.mechanism`` to derive the robot leg of paper Sec. IV with this class
and check it against ``symbolic.slip``.
"""

from __future__ import annotations

import keyword
from collections.abc import Mapping, Sequence

import casadi
import numpy as np

from .mechanism_checks import (
    channel_indices,
    checked_expression,
    checked_known,
    checked_parameters,
    checked_vector,
)
from .mechanism_tools import MechanismTools
from .realisation import ccf

__all__ = ["Mechanism", "euler_lagrange"]

def euler_lagrange(L, R, Q, q, dq, u) -> tuple[casadi.SX, casadi.SX, casadi.SX]:
    """The equations of motion ``M ddq = Q - dR/ddq + dL/dq - (d/dq dL/ddq) dq`` (module
    docstring), by CasADi's derivatives.

    Parameters
    ----------
    L, R : casadi.SX (1, 1)
        Lagrangian and Rayleigh dissipation.
    Q : casadi.SX (nq, 1)
        Generalised forces.
    q, dq, u : casadi.SX
        Coordinates, velocities, inputs (symbols).

    Returns
    -------
    M : casadi.SX (nq, nq)
        The mass matrix ``d^2 L / ddq^2``.
    balance : casadi.SX (nq, 1)
        The right-hand side; zero at rest on an equilibrium.
    ddq : casadi.SX (nq, 1)
        ``M^{-1} balance``, solved symbolically.

    Raises
    ------
    ValueError
        ``dL/ddq`` depends on ``u`` (``du/dt`` would enter the equations of motion).
    """
    momentum = casadi.gradient(L, dq)
    if casadi.depends_on(momentum, u):
        raise ValueError("lagrangian: dL/ddq depends on u, which would put du/dt in the "
                         "equations of motion; let u enter through the potential or forces")
    M = casadi.jacobian(momentum, dq)
    balance = (Q - casadi.gradient(R, dq) + casadi.gradient(L, q)
               - casadi.jtimes(momentum, q, dq))
    return M, balance, casadi.solve(M, balance)


class Mechanism(MechanismTools):
    """A mechanism from its Lagrangian (module docstring): equations of motion, equilibrium,
    linearisation, per-channel canonical maps and C code. CasADi only; no torch.

    Parameters
    ----------
    q, dq : casadi.SX (nq, 1)
        Generalised coordinates and their velocities, symbols.
    u : casadi.SX (m, 1)
        Inputs, symbols.
    parameters : dict str -> casadi.SX
        Physical parameters by name, scalar symbols (``{"k": casadi.SX.sym("k")}``).
    lagrangian : casadi.SX (1, 1)
        ``L(q, dq, u, p) = T - V``; ``u`` enters through ``V`` or ``forces``, not ``T``.
    outputs : casadi.SX (p, 1)
        The measured outputs ``y(q, dq, u, p)``.
    dissipation : casadi.SX (1, 1), optional
        Rayleigh's ``R(q, dq, p)``; its force is ``-dR/ddq``.
    forces : casadi.SX (nq, 1), optional
        Generalised forces ``Q(q, dq, u, p)``, by virtual work.
    name : str
        A C identifier, the prefix of the Functions' names.

    Raises
    ------
    ValueError
        An argument not of its kind, a reserved name, undeclared symbols, ``u`` in ``T``.
    """

    def __init__(self, *, q, dq, u, parameters: Mapping, lagrangian, outputs,
                 dissipation=None, forces=None, name: str = "mechanism") -> None:
        if not (isinstance(name, str) and name.isidentifier() and not keyword.iskeyword(name)):
            raise ValueError(f"name must be a C identifier; got {name!r}")
        self.name = name
        self.q = checked_vector("q", q)
        self.dq = checked_vector("dq", dq, q.numel())
        self.u = checked_vector("u", u)
        self.parameters = checked_parameters(parameters)
        self.p = casadi.vertcat(*self.parameters.values())
        every = casadi.vertcat(self.q, self.dq, self.u, self.p)
        if not every.is_valid_input():
            raise ValueError("q, dq, u and the parameters must be distinct symbols")
        self.lagrangian = checked_expression("lagrangian", lagrangian, every, (1, 1))
        self.outputs = checked_expression("outputs", outputs, every)
        if self.outputs.size2() != 1:
            raise ValueError(f"outputs must be a column vector; got shape {self.outputs.shape}")
        no_u = casadi.vertcat(self.q, self.dq, self.p)
        self.dissipation = checked_expression(
            "dissipation", 0 if dissipation is None else dissipation, no_u, (1, 1))
        nq = self.q.numel()
        self.forces = checked_expression(
            "forces", casadi.SX.zeros(nq, 1) if forces is None else forces, every, (nq, 1))
        self.M, self.balance, ddq = euler_lagrange(self.lagrangian, self.dissipation,
                                                   self.forces, self.q, self.dq, self.u)
        self.x = casadi.vertcat(self.q, self.dq)
        self.f = casadi.vertcat(self.dq, ddq)
        self.h = self.outputs

    @property
    def names(self) -> tuple[str, ...]:
        """The parameters' names, in the order of ``parameters``."""
        return tuple(self.parameters)

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(n, m, p)``: states ``2 nq``, inputs, outputs."""
        return self.x.numel(), self.u.numel(), self.h.numel()

    def dynamics(self) -> casadi.Function:
        """``xdot = f(x, u, p)`` and ``y = h(x, u, p)``.

        Returns
        -------
        casadi.Function
            ``'<name>_dynamics'``: ``x (n), u (m)``, the parameters by name ->
            ``xdot (n), y (p)``.
        """
        return casadi.Function(f"{self.name}_dynamics", [self.x, self.u, *self.parameters.values()],
                               [self.f, self.h], ["x", "u", *self.names], ["xdot", "y"])

    # -- equilibrium ---------------------------------------------------------------------------
    def equilibrium(self, *, u=None, q=None, guess=None) -> casadi.Function:
        """The rest point ``(x_e, u_e)`` at the operating input ``u_e`` (module docstring).

        Parameters
        ----------
        u : (m,) numbers or casadi.SX of the parameters, optional
            The operating input; zeros by default.
        q : (nq,) numbers or casadi.SX of the parameters, optional
            The equilibrium's coordinates, named by the user (required for a rigid-body mode);
            solved when omitted: symbolically where the forces at rest are affine in ``q``,
            else by a Newton rootfinder from ``guess``.
        guess : (nq,) numbers, optional
            The rootfinder's start (zeros by default); it finds the equilibrium nearest to it.

        Returns
        -------
        casadi.Function
            ``'<name>_equilibrium'``: the parameters by name -> ``x_eq (n), u_eq (m)``.

        Raises
        ------
        ValueError
            ``u``, ``q`` or ``guess`` of the wrong size or in other symbols; a rootfinder asked
            for where the equilibria are not isolated (a rigid-body mode).
        """
        nq, m = self.q.numel(), self.u.numel()
        params = list(self.parameters.values())
        u_e = checked_expression("u", casadi.SX.zeros(m, 1) if u is None else casadi.vec(
            casadi.SX(u) if isinstance(u, casadi.SX) else casadi.SX(casadi.DM(u))), self.p, (m, 1))
        if q is not None:
            q_e = checked_expression("q", casadi.vec(casadi.SX(q) if isinstance(q, casadi.SX)
                                              else casadi.SX(casadi.DM(q))), self.p, (nq, 1))
            x_e = casadi.vertcat(q_e, casadi.SX.zeros(nq, 1))
            return casadi.Function(f"{self.name}_equilibrium", params, [x_e, u_e],
                                   list(self.names), ["x_eq", "u_eq"])
        return _rest_point(self, u_e, guess)

    # -- linearisation -------------------------------------------------------------------------
    def linearise(self, *, u=None, q=None, guess=None,
                  known: Mapping[str, float] | None = None) -> casadi.Function:
        """The Jacobian linearisation at the equilibrium (module docstring; paper Eq. 16).

        Parameters
        ----------
        u, q, guess
            The operating point, as :meth:`equilibrium`.
        known : dict str -> float, optional
            Parameters held at known values (gravity, a rest length): not inputs of the result.

        Returns
        -------
        casadi.Function
            ``'<name>_linearisation'``: the other parameters by name -> ``A (n, n), B (n, m),
            C (p, n), D (p, m)``, the state ``x = (q, dq)``.

        Raises
        ------
        ValueError
            As :meth:`equilibrium`; ``known`` naming no parameter or a value that is not a
            finite number.
        """
        eq = self.equilibrium(u=u, q=q, guess=guess)
        jac = casadi.Function("jacobians", [self.x, self.u, self.p], [
            casadi.jacobian(self.f, self.x), casadi.jacobian(self.f, self.u),
            casadi.jacobian(self.h, self.x), casadi.jacobian(self.h, self.u)])
        free, values = self.free(known)
        kind = casadi.SX if eq.is_a("SXFunction") else casadi.MX
        symbols = {n: kind.sym(n) for n in free}
        p = casadi.vertcat(*(symbols[n] if n in symbols else values[n] for n in self.names))
        x_e, u_e = eq.call([p[i] for i in range(len(self.names))])
        A, B, C, D = jac(x_e, u_e, p)
        return casadi.Function(f"{self.name}_linearisation", list(symbols.values()),
                               [A, B, C, D], list(free), ["A", "B", "C", "D"])

    def free(self, known: Mapping[str, float] | None) -> tuple[tuple[str, ...], dict]:
        """The parameters not in ``known``, and ``known`` checked as floats.

        Parameters
        ----------
        known : dict str -> float or None

        Returns
        -------
        free : tuple of str
        values : dict str -> float
        """
        return checked_known(self.names, known)

    def channel(self, output: int = 0, input: int = 0, *, states: Sequence[int] | None = None,
                **operating) -> casadi.Function:
        """The bottom-row CCF (paper Eq. 5) of one channel of the linearisation: the map from
        the parameters into the structure an encoder outputs.

        Parameters
        ----------
        output, input : int
            The channel: ``y[output]`` from ``u[input]``.
        states : sequence of int, optional
            The states of a decoupled subsystem (the leg's translation, ``(l, dl)``): its
            ``A[s, s], B[s, input], C[output, s]``; all ``n`` states by default (a transfer
            function of order ``n``, with common factors where the channel does not see every
            mode).
        **operating
            ``u, q, guess, known`` as :meth:`linearise`.

        Returns
        -------
        casadi.Function
            ``'<name>_y<output>_u<input>'``: the free parameters by name -> ``A, B, C, D`` of
            the CCF.
        """
        s = channel_indices(self.shape, output, input, states)
        lin = self.linearise(**operating)
        kind = casadi.SX if lin.is_a("SXFunction") else casadi.MX
        symbols = [kind.sym(lin.name_in(i)) for i in range(lin.n_in())]
        A, B, C, D = lin(*symbols)
        realised = ccf(A[s, s], B[s, input], C[output, s], D[output, input])
        return casadi.Function(f"{self.name}_y{output}_u{input}", symbols, list(realised),
                               lin.name_in(), ["A", "B", "C", "D"])


def _rest_point(self, u_e: casadi.SX, guess) -> casadi.Function:
    """The solved equilibrium of the Mechanism ``self`` (``equilibrium`` without ``q``): one
    symbolic solve where the forces at rest are affine in ``q``, else a Newton rootfinder."""
    nq = self.q.numel()
    start = np.zeros(nq) if guess is None else np.asarray(guess, dtype=float).ravel()
    if start.shape != (nq,) or not np.isfinite(start).all():
        raise ValueError(f"guess must be {nq} finite numbers (one per coordinate of q); got "
                         f"{guess!r}")
    rest = casadi.substitute(self.balance, self.dq, casadi.SX.zeros(nq, 1))
    rest = casadi.substitute(rest, self.u, u_e)
    jac = casadi.Function("j", [self.q, self.p], [casadi.jacobian(rest, self.q)])
    probe = np.random.default_rng(0).uniform(0.5, 2.0, self.p.numel())
    J = np.array(jac(start, probe))
    if casadi.jacobian(rest, self.q).nnz() == 0 or np.linalg.matrix_rank(J) < nq:
        raise ValueError(f"{self.name} has no isolated equilibrium at this input (the forces "
                         "at rest do not pin every coordinate: a rigid-body mode); name one: "
                         "equilibrium(q=...) or linearise(q=...)")
    gradient = casadi.jacobian(rest, self.q)
    if not casadi.depends_on(gradient, self.q):
        # forces affine in q (a linear mechanism): the rest point is one symbolic solve, so the
        # maps stay SX (exact, fast to evaluate, C code without a rootfinder)
        q_e = casadi.solve(gradient, -casadi.substitute(rest, self.q, casadi.SX.zeros(nq, 1)))
        x_e = casadi.vertcat(q_e, casadi.SX.zeros(nq, 1))
        return casadi.Function(f"{self.name}_equilibrium", list(self.parameters.values()),
                               [x_e, u_e], list(self.names), ["x_eq", "u_eq"])
    residual = casadi.Function("residual", [self.q, self.p], [rest])
    solver = casadi.rootfinder(f"{self.name}_rest", "newton", residual,
                               {"abstol": 1e-13, "max_iter": 100, "error_on_fail": True})
    p = casadi.MX.sym("p", self.p.numel())
    q_e = solver(casadi.DM(start), p)
    u_mx = casadi.Function("u_e", [self.p], [u_e])(p)
    x_e = casadi.vertcat(q_e, casadi.MX.zeros(nq, 1))
    inner = casadi.Function("eq", [p], [x_e, u_mx])
    symbols = [casadi.MX.sym(n) for n in self.names]
    x_out, u_out = inner(casadi.vertcat(*symbols))
    return casadi.Function(f"{self.name}_equilibrium", symbols, [x_out, u_out],
                           list(self.names), ["x_eq", "u_eq"])
