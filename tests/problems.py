"""A registry of test systems with exact answers (in the spirit of torchdiffeq's tests/problems.py).

Every system here is a continuous-time SISO (A, b, c, d) whose response the tests compare with an
independent oracle (scipy's expm / cont2discrete / lsim, python-control's forced_response).
"""

from __future__ import annotations

import numpy as np


def random_system(
    n: int, rng: np.random.Generator, *, stable: bool = True, feedthrough: bool = False
):
    """A random real SISO system of order ``n`` in a random basis.

    Poles are drawn with magnitudes in [0.5, 20] rad/s, as conjugate pairs and real poles; for
    ``stable=False`` one real pole is made positive. A random similarity transform hides the
    structure, so the decoder sees a full ``A``.

    Returns ``A (n, n), b (n,), c (n,), d (float)``.
    """
    poles: list[complex] = []
    while len(poles) < n:
        if n - len(poles) >= 2 and rng.random() < 0.5:
            radius = rng.uniform(0.5, 20.0)
            angle = rng.uniform(0.1, 0.95) * np.pi / 2
            poles += [complex(-radius * np.cos(angle), radius * np.sin(angle))]
            poles += [poles[-1].conjugate()]
        else:
            poles.append(complex(-rng.uniform(0.5, 20.0), 0.0))
    if not stable:
        idx = next(i for i, p in enumerate(poles) if p.imag == 0.0) if any(
            p.imag == 0.0 for p in poles
        ) else None
        if idx is None:
            poles[0], poles[1] = complex(abs(poles[0].real), poles[0].imag), complex(
                abs(poles[1].real), poles[1].imag
            )
        else:
            poles[idx] = complex(abs(poles[idx].real) * 0.5 + 0.5, 0.0)
    den = np.real(np.poly(poles))
    # Bottom-row companion form, then a random well-conditioned basis change.
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1, :] = -den[1:][::-1]
    b = np.zeros(n)
    b[-1] = 1.0
    c = rng.normal(size=n) * np.abs(den[-1]) ** (1.0 / max(n, 1))
    T = rng.normal(size=(n, n)) + 3.0 * np.eye(n)
    Ti = np.linalg.inv(T)
    d = float(rng.normal()) if feedthrough else 0.0
    return T @ A @ Ti, T @ b, c @ Ti, d


def inputs(steps: int, dt: float, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Test excitations on the grid t_k = k*dt: step, ramp, random (Gaussian) and PRBS."""
    t = np.arange(steps) * dt
    prbs = np.repeat(rng.choice([-1.0, 1.0], size=steps // 5 + 1), 5)[:steps]
    return {
        "step": np.ones(steps),
        "ramp": t / max(t[-1], dt),
        "random": rng.normal(size=steps),
        "prbs": prbs,
    }


def modal_system(
    n: int, rng: np.random.Generator, *, stable: bool = True, feedthrough: bool = False
):
    """A random real SISO system of order ``n`` in a well-conditioned random basis.

    Poles as in ``random_system`` (magnitudes in [0.5, 20] rad/s, conjugate pairs and real poles);
    for ``stable=False`` the first pole is real and positive, in [0.5, 12] rad/s (the robot leg's
    rotational pole is +12). ``A = T M T^{-1}`` with ``M`` the real modal form (``lambda`` on the
    diagonal, blocks ``[[delta, omega], [-omega, delta]]``) and ``T = Q1 diag(s) Q2``, ``s`` in
    [1, 3], so ``cond(T) <= 3``.

    Why not ``random_system``: its companion matrix in a random basis reaches ``||A|| ~ 1e6`` at
    ``n = 6``, where the matrix exponential itself is ill-conditioned (scipy's and torch's ``expm``
    then differ from a 50-digit mpmath ``expm`` by up to 1e-4), so no oracle can check a
    simulation to 1e-10 on it. Here ``||A|| <= ~60`` and the oracles agree to ~1e-14.

    Returns ``A (n, n), b (n,), c (n,), d (float)``.
    """
    M = np.zeros((n, n))
    i = 0
    if not stable:
        M[0, 0] = rng.uniform(0.5, 12.0)
        i = 1
    while i < n:
        if n - i >= 2 and rng.random() < 0.5:
            radius = rng.uniform(0.5, 20.0)
            angle = rng.uniform(0.1, 0.95) * np.pi / 2
            delta, omega = -radius * np.cos(angle), radius * np.sin(angle)
            M[i : i + 2, i : i + 2] = [[delta, omega], [-omega, delta]]
            i += 2
        else:
            M[i, i] = -rng.uniform(0.5, 20.0)
            i += 1
    Q1, _ = np.linalg.qr(rng.normal(size=(n, n)))
    Q2, _ = np.linalg.qr(rng.normal(size=(n, n)))
    T = Q1 @ np.diag(rng.uniform(1.0, 3.0, size=n)) @ Q2
    A = T @ M @ np.linalg.inv(T)
    b = rng.normal(size=n)
    c = rng.normal(size=n)
    d = float(rng.normal()) if feedthrough else 0.0
    return A, b, c, d


def pi_loop(noise: float, seed: int, steps: int = 1000, dt: float = 0.05):
    """``1 / (s^2 + 0.8 s + 1)`` under ``u = 1.5 e + 0.8 int e``, ``e = r - y`` with the
    measured (noisy) ``y``, reference steps every 100 samples; the input held between
    samples. A :class:`aeid_struct.Record` with ``intersample="zoh"``."""
    import control

    import aeid_struct as ae

    rng = np.random.default_rng(seed)
    plant = control.tf2ss(control.c2d(control.tf([1.0], [1.0, 0.8, 1.0]), dt, "zoh"))
    A, B, C = (np.asarray(m) for m in (plant.A, plant.B, plant.C))
    r = np.repeat(rng.choice([-1.0, 1.0], steps // 100), 100)
    v = noise * rng.standard_normal(steps)
    x, integral = np.zeros(A.shape[0]), 0.0
    y, u = np.zeros(steps), np.zeros(steps)
    for k in range(steps):
        y[k] = (C @ x).item() + v[k]
        integral += (r[k] - y[k]) * dt
        u[k] = 1.5 * (r[k] - y[k]) + 0.8 * integral
        x = A @ x + B[:, 0] * u[k]
    return ae.Record(y, u, dt, intersample="zoh")


def pi_loop_2x2(noise: float, seed: int, steps: int = 1000, dt: float = 0.05,
                closed: bool = True):
    """Two coupled second-order modes (poles ``-0.4 +- 0.917j``, ``-0.6 +- 1.281j``; two
    inputs, two outputs) under a decentralised PI controller, ``u_j = 1.2 e_j + 0.6 int e_j``,
    ``e = r - y`` with the measured (noisy) ``y``, reference steps every 100 and 80 samples;
    the input held between samples (``closed=False``: the references themselves are the
    inputs). Returns the :class:`aeid_struct.Record` (``intersample="zoh"``) and the true
    continuous poles."""
    import scipy.signal

    import aeid_struct as ae

    A = np.array([[0, 1, 0, 0], [-1.0, -0.8, 0, 0], [0, 0, 0, 1], [0, 0, -2.0, -1.2]])
    B = np.array([[0, 0], [1.0, 0.3], [0, 0], [0.4, 1.5]])
    C = np.array([[1.0, 0, 0.2, 0], [0, 0.1, 1.0, 0]])
    Ad, Bd, Cd, _, _ = scipy.signal.cont2discrete((A, B, C, np.zeros((2, 2))), dt, "zoh")
    rng = np.random.default_rng(seed)
    r = np.stack([np.repeat(rng.choice([-1.0, 1.0], steps // 100 + 1), 100)[:steps],
                  np.repeat(rng.choice([-1.0, 1.0], steps // 80 + 1), 80)[:steps]], axis=1)
    V = noise * rng.standard_normal((steps, 2))
    x, integral = np.zeros(4), np.zeros(2)
    Y, U = np.zeros((steps, 2)), np.zeros((steps, 2))
    for k in range(steps):
        Y[k] = Cd @ x + V[k]
        e = r[k] - Y[k]
        integral += e * dt
        U[k] = 1.2 * e + 0.6 * integral if closed else r[k]
        x = Ad @ x + Bd @ U[k]
    return ae.Record(Y, U, dt, intersample="zoh"), np.linalg.eigvals(A)
