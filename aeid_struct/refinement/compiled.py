r"""The separable Levenberg-Marquardt of ``levenberg.gauss_newton`` compiled
to C, one record per call: the identifiers' head and the refinement without numpy's
per-operation overhead.

The problem and the iterations are those of the numpy path (``batched.py``): the projected cost
``V(alpha) = ||P_perp t||^2 / N`` of a partly fixed bottom-row CCF, Kaufman's Jacobian
``J = P_perp d(t - M z)/d alpha`` (``z`` held), damped steps
``(J^T J + lambda diag(J^T J)) step = -J^T r`` kept when they lower the cost, the damping
divided or multiplied by ten, and with a tolerance the same stopping rule. The differences are
in the last digits: the Jacobian is exact (forward derivatives carried through the recursion)
where numpy takes a forward difference; the exponential of Eq. 10 is Pade [13/13]
(``simulation.expm``) with the squarings chosen at run time (as ``record.py``) where numpy uses
Taylor; the columns of the linear part are scaled by their norms, and the small systems are
solved by Cholesky.

*The graph* of one record (the iterations as one ``casadi.Function`` per pattern and ``N``)
is built in ``compiled_graph.py``; this module compiles it, keeps it for the process and runs
the records through it: the seam between the symbolic graph and the compiler, its cache and
the numbers.

*Compiled, or not at all.* The graph is written to C (``symbolic.codegen``) in a fresh private
folder (``tempfile.mkdtemp``), compiled with the system C compiler, loaded, and the folder
removed: compiled code lives only in this process and is never read from a file that another
user could write (docs/architecture.md, "Model files are data, never code"). Without a
compiler, with ``AEID_STRUCT_COMPILE=0`` in the environment, with :data:`ENABLED` set to False,
or when a build fails, :func:`gauss_newton_rows` returns None and ``gauss_newton`` runs the
numpy path; so it does for a record whose compiled result is not finite.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading

import casadi
import numpy as np

from aeid_struct.refinement import batched
from aeid_struct.refinement.compiled_graph import MAX_ITERATIONS, graph
from aeid_struct.structures import Numeric
from symbolic.codegen import compile_c, generate_c

__all__ = ["ENABLED", "ENV", "MAX_ITERATIONS", "available", "clear", "gauss_newton_rows",
           "solver"]

#: Set to False to keep every call on the numpy path (tests of the fallback, debugging).
ENABLED = True
#: The environment variable that disables compilation when it is "0" (read at each call).
ENV = "AEID_STRUCT_COMPILE"

_LOCK = threading.Lock()
_CACHE: dict = {}


def available() -> bool:
    """Whether compiled solvers may be used: not disabled, and a C compiler on ``PATH``.

    Returns
    -------
    bool
    """
    if not ENABLED or os.environ.get(ENV, "1") == "0":
        return False
    if "compiler" not in _CACHE:       # a PATH search costs more than a compiled solve
        _CACHE["compiler"] = (shutil.which("gcc") or shutil.which("cc")) is not None
    return _CACHE["compiler"]


def clear() -> None:
    """Forget every compiled solver (the next call compiles again)."""
    with _LOCK:
        _CACHE.clear()


# ---------------------------------------------------------------------------------------------
# Compiling and calling
# ---------------------------------------------------------------------------------------------
def _compile(function: casadi.Function) -> casadi.Function:
    """``function`` compiled to C and loaded back, built in a private folder that is removed
    after loading (RuntimeError when the compiler fails)."""
    folder = tempfile.mkdtemp(prefix="aeid-gn-")
    try:
        c_file = generate_c(folder, [function], name="gn_record")
        return compile_c(c_file, [function.name()])[function.name()]
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def solver(pattern, N: int):
    """The compiled one-record solver of ``pattern`` and ``N`` samples, built on first use and
    kept for the process; None when compilation is unavailable or failed.

    Parameters
    ----------
    pattern : Pattern
    N : int
        Samples of the records.

    Returns
    -------
    Numeric or None
        ``(alpha0 (nf,), y (N,), u (N,), q) -> [out (3 n + 5,)]`` with
        ``q = [dt, iterations, tol, stop]`` and ``out = [a; c; d; x0; y_offset; cost;
        accepted; done]``.
    """
    if not available():
        return None
    key = (pattern, int(N))
    with _LOCK:
        if key not in _CACHE:
            try:
                _CACHE[key] = Numeric(_compile(graph(pattern, int(N))))
            except (RuntimeError, OSError):
                _CACHE[key] = None      # no second try in this process: numpy serves it
        return _CACHE[key]


def gauss_newton_rows(pattern, alpha: np.ndarray, y: np.ndarray, u: np.ndarray, dt: float,
                      iterations: int, tol: float | None, fallback):
    """:func:`~aeid_struct.refinement.gauss_newton`, record by record through the compiled
    solver.

    Parameters
    ----------
    pattern : Pattern
    alpha : (B, nf) array
    y, u : (B, N) arrays
    dt : float
    iterations : int
    tol : float or None
    fallback : callable
        ``fallback(rows) -> SeparableFit`` of the records ``rows`` (an index array) by the
        numpy path: those whose compiled result is not finite (a start or trial the graph's
        squarings do not cover, an overflow), for which numpy's own handling holds.

    Returns
    -------
    SeparableFit or None
        None where the compiled path does not serve the call (disabled, no compiler, a failed
        build, more than :data:`MAX_ITERATIONS` iterations).
    """
    B, N = y.shape
    linear = pattern.free_c.size or pattern.d is None or pattern.initial or pattern.offset
    if iterations > MAX_ITERATIONS or not linear:
        return None
    f = solver(pattern, N)
    if f is None:
        return None
    n = pattern.n
    # the numeric buffer reads each row's memory as it lies
    alpha, y, u = (np.ascontiguousarray(v, dtype=np.float64) for v in (alpha, y, u))
    q = np.array([dt, iterations, 0.0 if tol is None else tol, tol is not None], dtype=float)
    out = np.empty((B, 3 * n + 5))
    with _LOCK:                        # one numeric buffer per solver
        for i in range(B):
            out[i] = f(alpha[i], y[i], u[i], q)[0]
    fit = batched.SeparableFit(
        a=out[:, :n], c=out[:, n: 2 * n], d=out[:, 2 * n], initial=out[:, 2 * n + 1: 3 * n + 1],
        y_offset=out[:, 3 * n + 1], cost=out[:, 3 * n + 2],
        iterations=out[:, 3 * n + 3].astype(int), converged=out[:, 3 * n + 4] > 0.5)
    rows = np.flatnonzero(~np.isfinite(out).all(axis=1))
    if rows.size:
        other = fallback(rows)
        for name in ("a", "c", "d", "x0", "y_offset", "cost", "iterations", "converged"):
            getattr(fit, name)[rows] = getattr(other, name)
    return fit
