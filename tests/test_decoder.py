"""Tests of aeid_struct.simulation (the decoder) against independent oracles.

Oracles: scipy's ``expm`` of the augmented matrix, ``scipy.signal.cont2discrete(method="foh")`` +
``dlsim``, python-control's continuous-time ``forced_response`` (exact for linearly interpolated
inputs), closed forms (free response ``expm(A t) x0``, the leg's ``cosh`` step response, CCF
stationary value ``d + c_0 / a_0``) and ``control.dcgain``; ``gradcheck`` in float64.

Accuracy is checked on ``problems.modal_system`` (well-conditioned bases, see its docstring):
``max|y - y_oracle| <= 1e-10 max|y_oracle|`` in float64, stable and unstable, orders 1-6.
"""

from __future__ import annotations

import contextlib
import warnings

import control
import numpy as np
import pytest
import scipy.linalg
import scipy.signal
import torch
from helpers import RTOL, rel_max_error
from problems import inputs, modal_system

import aeid_struct as ae
from aeid_struct import simulation as decoder
from aeid_struct.simulation import (
    Discrete,
    denormalise,
    discretise,
    loss,
    normalise,
    record_scale,
    simulate,
    states,
    stationary_value,
)
from aeid_struct.studies.bench_kernels import simulate_fft, simulate_scan

DT = 0.01
STEPS = 200  # 2 s: an unstable pole at +12 rad/s grows by e^24 over the record
ORDERS = [1, 2, 3, 4, 5, 6]
SIGNALS = ["step", "ramp", "random", "prbs"]
METHODS = {
    "chunked": decoder.simulate_batch,
    "fft": simulate_fft,
    "scan": simulate_scan,
    "loop": decoder.simulate_loop,
}


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread():
    """The decoder's tensors are small: one thread is as fast, and immune to the stalls that
    threads waiting for each other suffer on a loaded machine. Restored after this module."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def _system(n, stable, feedthrough=True, salt=0):
    # Seeded by the parameters: each case is the same system on every run and machine.
    rng = np.random.default_rng([n, int(stable), int(feedthrough), salt])
    return modal_system(n, rng, stable=stable, feedthrough=feedthrough)


def _signal(name, steps=STEPS, dt=DT, seed=0):
    return inputs(steps, dt, np.random.default_rng(seed))[name]


def _augmented_expm(A, b, dt):
    n = A.shape[0]
    M = np.zeros((n + 2, n + 2))
    M[:n, :n], M[:n, n], M[n, n + 1] = A * dt, b * dt, 1.0
    E = scipy.linalg.expm(M)
    return E[:n, :n], E[:n, n], E[:n, n + 1]


def _torch(*arrays, dtype=torch.float64):
    return [torch.as_tensor(np.asarray(a), dtype=dtype) for a in arrays]


# ------------------------------------------------------------------------------------------------
# Discretisation (Eq. 10)
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", ORDERS)
@pytest.mark.parametrize("stable", [True, False])
def test_discretise_matches_expm_of_augmented_matrix(n, stable):
    A, b, _, _ = _system(n, stable)
    disc = discretise(A, b, DT)
    Phi, gamma1, gamma2 = _augmented_expm(A, b, DT)
    assert isinstance(disc, Discrete) and disc.dt == DT
    assert disc.Phi.shape == (n, n) and disc.gamma1.shape == disc.gamma2.shape == (n,)
    assert rel_max_error(disc.Phi, Phi) < 1e-13
    assert rel_max_error(disc.gamma1, gamma1) < 1e-13
    assert rel_max_error(disc.gamma2, gamma2) < 1e-13
    # Phi = e^{A dt} on its own, too.
    assert rel_max_error(disc.Phi, scipy.linalg.expm(A * DT)) < 1e-13


@pytest.mark.parametrize("n", ORDERS)
@pytest.mark.parametrize("stable", [True, False])
def test_discretise_relates_to_cont2discrete_foh(n, stable):
    """cont2discrete's FOH system lives in the shifted state xi_k = x_k - gamma2 u_k.

    From x_{k+1} = Phi x_k + gamma1 u_k + gamma2 (u_{k+1} - u_k):
        xi_{k+1} = x_{k+1} - gamma2 u_{k+1} = Phi (xi_k + gamma2 u_k) + (gamma1 - gamma2) u_k
                 = Phi xi_k + (gamma1 - gamma2 + Phi gamma2) u_k,
        y_k = c^T x_k + d u_k = c^T xi_k + (d + c^T gamma2) u_k.
    So Ad = Phi, Bd = gamma1 - gamma2 + Phi gamma2, Cd = c^T, Dd = d + c^T gamma2.
    """
    A, b, c, d = _system(n, stable)
    disc = discretise(A, b, DT)
    Ad, Bd, Cd, Dd, dt = scipy.signal.cont2discrete(
        (A, b[:, None], c[None, :], [[d]]), DT, method="foh"
    )
    assert dt == DT
    assert rel_max_error(disc.Phi, Ad) < 1e-13
    assert rel_max_error(disc.gamma1 - disc.gamma2 + disc.Phi @ disc.gamma2, Bd[:, 0]) < 1e-13
    assert rel_max_error(Cd[0], c) == 0.0
    assert abs(d + c @ disc.gamma2 - Dd[0, 0]) <= 1e-13 * max(1.0, abs(Dd[0, 0]))


def test_discretise_integrator_closed_form():
    """A = 0, b = 1: Phi = 1, gamma1 = int_0^dt ds = dt, gamma2 = (1/dt) int_0^dt s ds = dt/2."""
    disc = discretise(np.zeros((1, 1)), np.ones(1), 0.1)
    np.testing.assert_allclose(disc.Phi, [[1.0]], rtol=1e-15)
    np.testing.assert_allclose(disc.gamma1, [0.1], rtol=1e-15)
    np.testing.assert_allclose(disc.gamma2, [0.05], rtol=1e-15)


def test_discretise_batched_and_torch():
    systems = [_system(3, s, salt=i) for i, s in enumerate([True, False, True])]
    A = np.stack([s[0] for s in systems])
    b = np.stack([s[1] for s in systems])
    disc = discretise(torch.as_tensor(A, dtype=torch.float32), torch.as_tensor(b), DT)
    assert disc.Phi.dtype == torch.float64  # promoted: b came in float64
    assert disc.Phi.shape == (3, 3, 3) and disc.gamma1.shape == (3, 3)
    for i, (Ai, bi, _, _) in enumerate(systems):
        Phi, gamma1, gamma2 = _augmented_expm(np.float32(Ai).astype(float), bi, DT)
        assert rel_max_error(disc.Phi[i], Phi) < 1e-13
        assert rel_max_error(disc.gamma2[i], gamma2) < 1e-13
    # One b shared by the batch.
    shared = discretise(A, b[0], DT)
    assert shared.gamma1.shape == (3, 3)
    assert rel_max_error(shared.gamma1[2], _augmented_expm(A[2], b[0], DT)[1]) < 1e-13


# ------------------------------------------------------------------------------------------------
# Simulation (Eq. 12-13) against the oracles
# ------------------------------------------------------------------------------------------------


def _dlsim(A, b, c, d, u, dt):
    """cont2discrete FOH + dlsim from rest: start at xi_0 = -gamma2 u_0 (DESIGN.md caveat)."""
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete(
        (A, b[:, None], c[None, :], [[d]]), dt, method="foh"
    )
    gamma2 = _augmented_expm(A, b, dt)[2]
    _, y, _ = scipy.signal.dlsim((Ad, Bd, Cd, Dd, dt), u, x0=-gamma2 * u[0])
    return y[:, 0]


def _forced(A, b, c, d, u, dt, x0=0.0):
    sys = control.ss(A, b[:, None], c[None, :], [[d]])
    return control.forced_response(sys, np.arange(len(u)) * dt, u, X0=x0, return_x=True)


@pytest.mark.parametrize("signal", SIGNALS)
@pytest.mark.parametrize("n", ORDERS)
@pytest.mark.parametrize("stable", [True, False], ids=["stable", "unstable"])
def test_simulate_matches_cont2discrete_dlsim(stable, n, signal):
    A, b, c, d = _system(n, stable)
    u = _signal(signal, seed=n)
    y = simulate(A, b, c, d, u, DT)
    assert isinstance(y, np.ndarray) and y.dtype == np.float64 and y.shape == (STEPS,)
    assert rel_max_error(y, _dlsim(A, b, c, d, u, DT)) <= RTOL[np.float64]


@pytest.mark.parametrize("signal", SIGNALS)
@pytest.mark.parametrize("n", ORDERS)
@pytest.mark.parametrize("stable", [True, False], ids=["stable", "unstable"])
def test_simulate_matches_forced_response(stable, n, signal):
    A, b, c, d = _system(n, stable, salt=1)
    u = _signal(signal, seed=10 + n)
    y = simulate(A, b, c, d, u, DT)
    assert rel_max_error(y, _forced(A, b, c, d, u, DT).outputs) <= RTOL[np.float64]


def test_the_dlsim_oracle_needs_the_shifted_start():
    """The DESIGN.md caveat, pinned: dlsim from xi_0 = 0 is wrong for a step (u_0 != 0)."""
    A, b, c, d = _system(2, stable=True)
    u = _signal("step")
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete(
        (A, b[:, None], c[None, :], [[d]]), DT, method="foh"
    )
    _, naive, _ = scipy.signal.dlsim((Ad, Bd, Cd, Dd, DT), u)
    assert rel_max_error(naive[:, 0], simulate(A, b, c, d, u, DT)) > 1e-6


@pytest.mark.parametrize("stable", [True, False], ids=["stable", "unstable"])
@pytest.mark.parametrize("method", list(METHODS))
def test_every_implementation_matches_forced_response(method, stable):
    """Every implementation (default: chunked), all orders, with an initial state too."""
    for n in ORDERS:
        A, b, c, d = _system(n, stable, salt=2)
        u = _signal("random", seed=n)
        x0 = np.random.default_rng(n).normal(size=n)
        expected = _forced(A, b, c, d, u, DT, x0=x0).outputs
        y = METHODS[method](*(t[None] for t in _torch(A, b, c, d, u)), DT, _torch(x0)[0][None])
        assert rel_max_error(y[0].numpy(), expected) <= RTOL[np.float64], n


def test_unstable_leg_step_response_closed_form():
    """Rotational leg subsystem G2 = k / (s^2 - w^2), w = 12 rad/s, over 0.5 s.

    Its step response from rest is y(t) = k / w^2 (cosh(w t) - 1).
    """
    w, k, dt, steps = 12.0, 7.0, 0.005, 101
    A = np.array([[0.0, 1.0], [w**2, 0.0]])
    b, c = np.array([0.0, 1.0]), np.array([k, 0.0])
    t = np.arange(steps) * dt
    y = simulate(A, b, c, 0.0, np.ones(steps), dt)
    assert rel_max_error(y, k / w**2 * (np.cosh(w * t) - 1.0)) <= RTOL[np.float64]


@pytest.mark.parametrize("steps", [1, 2, 3, 5, 17, 64, 65, 127, 1025])
def test_implementations_agree_on_any_length(steps):
    """Odd lengths exercise padding (scan, chunks of K = 1..32 samples, FFT length); 1 sample."""
    A, b, c, d = _system(3, stable=False, salt=3)
    u = np.random.default_rng(steps).normal(size=steps)
    x0 = np.array([0.3, -1.0, 0.5])
    args = [t[None] for t in _torch(A, b, c, d, u)]
    ys = {name: f(*args, DT, _torch(x0)[0][None])[0] for name, f in METHODS.items()}
    assert ys["chunked"].shape == (steps,)
    for name in ("fft", "scan", "loop"):
        assert rel_max_error(ys[name].numpy(), ys["chunked"].numpy()) < 1e-12, name
    np.testing.assert_allclose(ys["chunked"][0].item(), c @ x0 + d * u[0], rtol=1e-13)


# ------------------------------------------------------------------------------------------------
# Batching, broadcasting, numpy/torch, dtypes
# ------------------------------------------------------------------------------------------------


def _batch(count=5, n=3):
    systems = [_system(n, i % 2 == 0, salt=10 + i) for i in range(count)]
    A, b, c = (np.stack([s[j] for s in systems]) for j in range(3))
    d = np.array([s[3] for s in systems])
    u = np.stack([_signal(SIGNALS[i % 4], seed=i) for i in range(count)])
    return A, b, c, d, u


def test_batched_equals_per_system():
    A, b, c, d, u = _batch()
    y = simulate(A, b, c, d, u, DT)
    assert y.shape == (5, STEPS)
    for i in range(5):
        assert rel_max_error(y[i], simulate(A[i], b[i], c[i], d[i], u[i], DT)) < 1e-13


def test_broadcasting_over_systems_and_inputs():
    A, b, c, d, u = _batch()
    # One input for every system.
    y = simulate(A, b, c, d, u[0], DT)
    for i in range(5):
        assert rel_max_error(y[i], simulate(A[i], b[i], c[i], d[i], u[0], DT)) < 1e-13
    # One system for a batch of inputs (and a scalar d, and a batch-1 A).
    y = simulate(A[:1], b[0], c[0], float(d[0]), u, DT)
    assert y.shape == (5, STEPS)
    for i in range(5):
        assert rel_max_error(y[i], simulate(A[0], b[0], c[0], d[0], u[i], DT)) < 1e-13
    # Only d batched: still a batch.
    assert simulate(A[0], b[0], c[0], d, u[0], DT).shape == (5, STEPS)


def test_numpy_and_torch_paths_agree():
    A, b, c, d, u = _batch()
    y_np = simulate(A, b, c, d, u, DT)
    tensors = _torch(A, b, c, d, u)
    y_t = simulate(*tensors, DT)
    assert isinstance(y_t, torch.Tensor) and y_t.dtype == torch.float64
    assert rel_max_error(y_t.numpy(), y_np) == 0.0
    # Mixed: one tensor makes the result a tensor; lists are accepted as arrays.
    y_mixed = simulate(A[0].tolist(), b[0], c[0], tensors[3][0], u[0], DT)
    assert isinstance(y_mixed, torch.Tensor) and y_mixed.shape == (STEPS,)
    assert rel_max_error(y_mixed.numpy(), y_np[0]) < 1e-13


def test_float32_within_tolerance_of_float64():
    """float32 (for training): within RTOL[float32] = 1e-4 of float64, relative to max|y|."""
    A, b, c, d, u = _batch(count=8, n=4)
    A, b, c, d = (x[::2] for x in (A, b, c, d))  # the stable ones
    y64 = simulate(A, b, c, d, u[::2], DT)
    y32 = simulate(*_torch(A, b, c, d, u[::2], dtype=torch.float32), DT)
    assert y32.dtype == torch.float32
    for i in range(len(y64)):
        assert rel_max_error(y32[i].numpy(), y64[i]) <= RTOL[torch.float32]
    assert float(record_scale(y32).min()) > 0


def test_float32_unstable_response_keeps_per_sample_accuracy():
    """Why the default is not the FFT form: over 2 s of a pole at +12 rad/s (growth e^24) the
    early samples are ~1e-13 of max|y|; an FFT convolution's evenly spread float32 rounding
    (~1e-7 max|y|) swamps them, while the default keeps every sample's own relative accuracy."""
    w, k, dt, steps = 12.0, 7.0, 0.005, 401
    A = torch.tensor([[0.0, 1.0], [w**2, 0.0]])
    b, c, u = torch.tensor([0.0, 1.0]), torch.tensor([k, 0.0]), torch.ones(steps)
    exact = k / w**2 * (np.cosh(w * np.arange(steps) * dt) - 1.0)

    def per_sample(y):
        return np.max(np.abs(y[1:] - exact[1:]) / exact[1:])

    assert per_sample(simulate(A, b, c, 0.0, u, dt).double().numpy()) < 5e-4
    y_fft = simulate_fft(A[None], b[None], c[None], torch.zeros(1), u[None], dt)
    assert per_sample(y_fft[0].double().numpy()) > 1.0


def test_scalar_outputs_and_shapes():
    A, b, c, d = _system(2, True)
    assert isinstance(stationary_value(A, b, c, d), np.floating)
    tensor = stationary_value(*_torch(A, b, c, d))
    assert isinstance(tensor, torch.Tensor) and tensor.shape == ()
    assert states(A, b, np.ones(7), DT).shape == (7, 2)
    assert states(A[None], b, np.ones(7), DT).shape == (1, 7, 2)


# ------------------------------------------------------------------------------------------------
# Initial state and states (Eq. 12)
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("n", [1, 2, 4, 6])
@pytest.mark.parametrize("stable", [True, False], ids=["stable", "unstable"])
def test_free_response_is_expm_At_x0(n, stable):
    A, b, c, d = _system(n, stable, salt=4)
    x0 = np.random.default_rng(n).normal(size=n)
    k = np.r_[0:STEPS:7, STEPS - 1]  # every 7th sample and the last: expm is the slow part
    X = states(A, b, np.zeros(STEPS), DT, x0=x0)
    expected = np.stack([scipy.linalg.expm(A * DT * kk) @ x0 for kk in k])
    assert rel_max_error(X[k], expected) <= RTOL[np.float64]
    y = simulate(A, b, c, d, np.zeros(STEPS), DT, x0=x0)
    assert rel_max_error(y[k], expected @ c) <= RTOL[np.float64]


def test_superposition_of_free_and_forced_response():
    A, b, c, d = _system(3, stable=False, salt=5)
    u, x0 = _signal("prbs"), np.array([1.0, -0.5, 2.0])
    both = simulate(A, b, c, d, u, DT, x0=x0)
    parts = simulate(A, b, c, d, u, DT) + simulate(A, b, c, d, np.zeros(STEPS), DT, x0=x0)
    assert rel_max_error(both, parts) < 1e-12


@pytest.mark.parametrize("stable", [True, False], ids=["stable", "unstable"])
def test_states_match_forced_response_states(stable):
    A, b, c, d = _system(4, stable, salt=6)
    u = _signal("random", seed=3)
    response = _forced(A, b, c, d, u, DT)
    X = states(A, b, u, DT)
    assert X.shape == (STEPS, 4)
    assert rel_max_error(X, response.states.T) <= RTOL[np.float64]
    assert rel_max_error(X @ c + d * u, simulate(A, b, c, d, u, DT)) < 1e-12


# ------------------------------------------------------------------------------------------------
# Stationary value (Eq. 4)
# ------------------------------------------------------------------------------------------------


def test_stationary_value_ccf_closed_form_and_dcgain():
    """CCF: G(0) = d + c_0 / a_0."""
    a = np.array([[24.0, 2.2], [6.0, 5.0], [1.0, 0.3]])  # (a_0, a_1) per record
    c = np.array([[1.0, 0.0], [2.0, -1.0], [0.5, 3.0]])
    d = np.array([0.0, 0.7, -1.0])
    A = np.zeros((3, 2, 2))
    A[:, 0, 1], A[:, 1, :] = 1.0, -a
    b = np.array([0.0, 1.0])
    y_inf = stationary_value(A, b, c, d)
    assert y_inf.shape == (3,)
    np.testing.assert_allclose(y_inf, d + c[:, 0] / a[:, 0], rtol=1e-14)
    for i in range(3):
        sys = control.ss(A[i], b[:, None], c[i][None], [[d[i]]])
        np.testing.assert_allclose(y_inf[i], control.dcgain(sys), rtol=1e-13)


@pytest.mark.parametrize("n", ORDERS)
def test_stationary_value_is_the_step_response_limit(n):
    A, b, c, d = _system(n, stable=True, salt=7)
    y_inf = stationary_value(A, b, c, d)
    np.testing.assert_allclose(y_inf, control.dcgain(control.ss(A, b[:, None], c[None], d)))
    # The slowest pole is >= 0.5 rad/s: after 60 s the step response has settled.
    y = simulate(A, b, c, d, np.ones(6001), DT)
    assert abs(y[-1] - y_inf) <= 1e-10 * max(1.0, abs(y_inf))


# ------------------------------------------------------------------------------------------------
# Normalisation (Eq. 15) and loss (Eq. 14)
# ------------------------------------------------------------------------------------------------


def test_record_scale_normalise_denormalise():
    y = np.array([[0.0, 1.0, 4.0, 2.0], [0.0, -3.0, 1.0, -1.0]])
    y_bar = record_scale(y)
    np.testing.assert_array_equal(y_bar, [4.0, 3.0])
    y_tilde = normalise(y, y_bar)
    np.testing.assert_allclose(y_tilde, [[-1.0, -0.5, 1.0, 0.0], [-1.0, -3.0, -1 / 3, -5 / 3]])
    assert y_tilde.min() >= -3.0 and y_tilde.max() <= 1.0  # the range of Eq. 15
    np.testing.assert_allclose(denormalise(y_tilde, y_bar), y, atol=1e-15)
    # Stationary values (batch,) with the records' scales, and torch in -> torch out.
    yinf = torch.tensor([2.0, -1.5])
    np.testing.assert_allclose(normalise(yinf, torch.as_tensor(y_bar)).numpy(), [0.0, -2.0])
    assert record_scale(y[0]) == 4.0 and normalise(2.0, 4.0) == 0.0


def test_loss_hand_computed():
    """Eq. 14 by hand: record 1 SSE 0.25 + 0.5 * 1.0, record 2 SSE 1.0; m + 1 = 3."""
    y_hat = torch.tensor([[0.0, 0.5], [1.0, 1.0]])
    y = torch.tensor([[0.0, 1.0], [1.0, 0.0]])
    yinf_hat, yinf = torch.tensor([1.0, 0.0]), torch.tensor([0.0, 0.0])
    J = loss(y_hat, y, yinf_hat, yinf, gamma=0.5)
    assert J.shape == () and J.dtype == torch.float32
    np.testing.assert_allclose(J.item(), ((0.25 + 0.5) / 3 + 1.0 / 3) / 2, rtol=1e-7)
    np.testing.assert_allclose(loss(y_hat, y).item(), (0.25 / 3 + 1.0 / 3) / 2, rtol=1e-7)
    # One record, numpy in: float64 tensor out.
    J1 = loss(np.array([0.0, 0.5]), np.array([0.0, 1.0]), 1.0, 0.0, gamma=0.5)
    assert J1.dtype == torch.float64 and abs(J1.item() - 0.75 / 3) < 1e-15


# ------------------------------------------------------------------------------------------------
# Gradients (float64 gradcheck)
# ------------------------------------------------------------------------------------------------


def _small_batch(dtype=torch.float64):
    A, b, c, d, u = _batch(count=2, n=2)
    return [t.requires_grad_() for t in _torch(A, b, c, d, u[:, :6], dtype=dtype)]


def test_gradcheck_simulate():
    A, b, c, d, u = _small_batch()
    x0 = torch.tensor([[0.2, -0.1], [0.0, 0.3]], dtype=torch.float64, requires_grad=True)
    def f(A, b, c, d, u, x0):
        return simulate(A, b, c, d, u, DT * 5, x0=x0)

    assert torch.autograd.gradcheck(f, (A, b, c, d, u, x0))


@pytest.mark.parametrize("method", ["fft", "scan", "loop"])
def test_gradcheck_other_implementations(method):
    A, b, c, d, u = _small_batch()
    assert torch.autograd.gradcheck(lambda *a: METHODS[method](*a, DT * 5), (A, b, c, d, u))


def test_gradcheck_discretise_states_stationary_value_loss():
    A, b, c, d, u = _small_batch()

    def disc(A, b):
        out = discretise(A, b, DT * 5)
        return out.Phi, out.gamma1, out.gamma2

    assert torch.autograd.gradcheck(disc, (A, b))
    assert torch.autograd.gradcheck(lambda A, b, u: states(A, b, u, DT * 5), (A, b, u))
    assert torch.autograd.gradcheck(stationary_value, (A, b, c, d))
    y_hat, y = u[:, :3], u[:, 3:].detach().clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda *a: loss(*a, gamma=0.3), (y_hat, y, d, c[:, 0]))
    assert torch.autograd.gradcheck(normalise, (y_hat, d.detach().abs().requires_grad_()))


def test_float32_gradients_are_finite():
    A, b, c, d, u = _small_batch(torch.float32)
    simulate(A, b, c, d, u, DT).square().sum().backward()
    for t in (A, b, c, d, u):
        assert t.grad.dtype == torch.float32 and bool(torch.isfinite(t.grad).all())


def test_public_namespace():
    assert ae.simulate is simulate and ae.discretise is discretise


# ------------------------------------------------------------------------------------------------
# Input validation: every ValueError, pinned by its message
# ------------------------------------------------------------------------------------------------

_A, _b, _c, _d = np.array([[0.0, 1.0], [-4.0, -1.0]]), np.array([0.0, 1.0]), np.ones(2), 0.0
_u = np.ones(20)
_NAN_U = np.ones((2, 20))
_NAN_U[0, 12] = np.nan
_INF_A = np.stack([_A, _A])
_INF_A[1, 1, 0] = np.inf


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"A": np.zeros((3, 2, 4))}, r"A must be square with shape \(batch, n, n\) or \(n, n\); "
                                     r"got \(3, 2, 4\)"),
        ({"A": np.zeros(3)}, r"A must be square .*; got \(3,\)"),
        ({"b": np.ones(3)}, r"b must have shape \(batch, n\) or \(n,\) with n = 2 from A; "
                            r"got \(3,\)"),
        ({"c": np.ones((2, 2, 2))}, r"c must have shape \(batch, n\) .*got \(2, 2, 2\)"),
        ({"d": np.ones((2, 1))}, r"d must be a scalar or have shape \(batch,\); got \(2, 1\)"),
        ({"u": np.ones((1, 2, 3))}, r"u must have shape \(batch, steps\) or \(steps,\) with "
                                    r"steps >= 1; got \(1, 2, 3\)"),
        ({"u": np.ones(0)}, r"u must have shape .*got \(0,\)"),
        ({"x0": np.ones(3)}, r"x0 must have shape \(batch, n\) or \(n,\) with n = 2 from A"),
        ({"A": np.stack([_A] * 4), "u": np.ones((3, 20))},
         r"batch sizes disagree: A has 4, u has 3 \(batched arguments must share one batch "
         r"size, or have 1\)"),
        ({"dt": -0.01}, r"dt must be a positive finite number; got -0.01"),
        ({"dt": 0}, r"dt must be a positive finite number; got 0"),
        ({"dt": float("nan")}, r"dt must be a positive finite number; got nan"),
        ({"dt": float("inf")}, r"dt must be a positive finite number; got inf"),
        ({"dt": "0.01"}, r"dt must be a positive finite number; got '0.01'"),
        ({"dt": None}, r"dt must be a positive finite number; got None"),
        ({"u": _NAN_U}, r"u must be finite; got nan at record 0, sample 12"),
        ({"A": _INF_A}, r"A must be finite; got inf at record 1, row 1, column 0"),
        ({"d": float("nan")}, r"d must be finite; got nan$"),
        ({"x0": np.array([0.0, np.inf])}, r"x0 must be finite; got inf at entry 1"),
        ({"b": np.array([1j, 0])}, r"b must be a real array; got dtype complex128"),
        ({"c": ["a", "b"]}, r"c must be a real array; got dtype <U1"),
        ({"b": torch.ones(2, dtype=torch.float16)},
         r"tensors must be float32 or float64; got torch.float16"),
        ({"b": torch.ones(2, dtype=torch.complex64)}, r"b must be real; got torch.complex64"),
        ({"b": [[1.0, 2.0], [3.0]]}, r"b must be a real array; got list"),
        ({"c": torch.ones(2), "d": torch.zeros((), device="meta")},
         r"all tensors must be on one device; got cpu, meta"),
    ],
)
def test_simulate_rejects(kwargs, match):
    args = {"A": _A, "b": _b, "c": _c, "d": _d, "u": _u, "dt": DT, "x0": None} | kwargs
    with pytest.raises(ValueError, match=match):
        simulate(**args)


def test_states_and_discretise_reject():
    with pytest.raises(ValueError, match=r"A must be square"):
        discretise(np.ones((2, 3)), _b, DT)
    with pytest.raises(ValueError, match=r"dt must be a positive finite number; got -1"):
        discretise(_A, _b, -1)
    with pytest.raises(ValueError, match=r"u must be finite; got nan at sample 3"):
        states(_A, _b, np.array([0.0, 1.0, 2.0, np.nan]), DT)


def test_stationary_value_rejects_singular_A():
    with pytest.raises(ValueError, match=r"A must be invertible \(record 1 of 2\): Eq. 4 has no "
                                         r"finite stationary value for a pole at s = 0"):
        stationary_value(np.stack([_A, np.array([[0.0, 1.0], [0.0, 0.0]])]), _b, _c, _d)
    with pytest.raises(ValueError, match=r"A must be invertible: Eq. 4"):
        stationary_value(np.zeros((2, 2)), _b, _c, _d)
    with pytest.raises(ValueError, match=r"c must have shape"):
        stationary_value(_A, _b, np.ones(3), _d)


def test_record_scale_rejects():
    y = np.ones((8, 5))
    y[3] = 0.0
    with pytest.raises(ValueError, match=r"y must not be all zero \(record 3 of 8\): the "
                                         r"normalisation y_tilde = 2 y / max\|y\| - 1 \(Eq. 15\) "
                                         r"needs max\|y\| > 0"):
        record_scale(y)
    with pytest.raises(ValueError, match=r"y must not be all zero: the normalisation"):
        record_scale(torch.zeros(5))
    with pytest.raises(ValueError, match=r"y must have shape \(batch, steps\) or \(steps,\) with "
                                         r"steps >= 1; got \(1, 2, 3\)"):
        record_scale(np.ones((1, 2, 3)))
    with pytest.raises(ValueError, match=r"y must be finite; got inf at record 1, sample 0"):
        record_scale(np.array([[1.0, 2.0], [np.inf, 0.0]]))


@pytest.mark.parametrize(
    ("y", "y_bar", "match"),
    [
        (np.ones((2, 3)), np.ones(3), r"y_bar must be a scalar or have shape \(2,\) to match y "
                                      r"\(2, 3\); got \(3,\)"),
        (np.ones((2, 3)), np.ones((2, 1)), r"y_bar must be a scalar or have shape \(batch,\); "
                                           r"got \(2, 1\)"),
        (np.ones((2, 3, 1)), 1.0, r"y must have shape \(batch, steps\), \(batch,\) or "
                                  r"\(steps,\); got \(2, 3, 1\)"),
        (np.ones((2, 3)), np.array([1.0, 0.0]), r"y_bar must be positive; got 0.0"),
        (np.ones((2, 3)), np.array([1.0, np.nan]), r"y_bar must be finite; got nan at record 1"),
    ],
)
def test_normalise_rejects(y, y_bar, match):
    with pytest.raises(ValueError, match=match):
        normalise(y, y_bar)


def test_denormalise_rejects():
    with pytest.raises(ValueError, match=r"y_tilde must be finite; got nan at sample 1"):
        denormalise(np.array([0.0, np.nan]), 1.0)


@pytest.mark.parametrize(
    ("args", "kwargs", "match"),
    [
        ((np.ones((2, 3)), np.ones((2, 4))), {}, r"y_hat must have the shape of y \(2, 4\); "
                                                 r"got \(2, 3\)"),
        ((np.ones(3), np.ones(3)), {"gamma": -1.0},
         r"gamma must be a finite number >= 0; got -1.0"),
        ((np.ones(3), np.ones(3)), {"gamma": float("nan")}, r"gamma must be a finite number"),
        ((np.ones(3), np.ones(3)), {"gamma": 0.5}, r"gamma = 0.5 weights the stationary values: "
                                                   r"give yinf_hat and yinf"),
        ((np.ones(3), np.ones(3), 1.0), {}, r"yinf_hat and yinf must be given together"),
        ((np.ones((2, 3)), np.ones((2, 3)), np.ones(3), np.ones(3)), {"gamma": 1.0},
         r"yinf_hat must have shape \(batch,\) with batch = 2 from y; got \(3,\)"),
        ((np.ones(3), np.array([0.0, np.nan, 0.0])), {}, r"y must be finite; got nan at sample 1"),
        ((np.array([np.inf, 0.0, 0.0]), np.ones(3)), {}, r"y_hat must be finite; got inf"),
        ((np.ones(3), np.ones(3), 0.0, np.nan), {}, r"yinf must be finite; got nan"),
        ((np.ones(3), np.ones(3)), {"gamma": "1"}, r"gamma must be a finite number >= 0; got '1'"),
    ],
)
def test_loss_rejects(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        loss(*args, **kwargs)


def test_tensors_on_one_device_and_core_skips_checks():
    # The private core runs without validation (for training loops): a nan passes through.
    A, b, c, d, u = (t[None] for t in _torch(_A, _b, _c, _d, _u))
    u[0, 3] = float("nan")
    assert bool(torch.isnan(decoder.simulate_batch(A, b, c, d, u, DT)).any())


# ------------------------------------------------------------------------------------------------
# The decoder benchmark (aeid_struct.bench, decoder part): a smoke test, tiny sizes
# ------------------------------------------------------------------------------------------------


def test_bench_decoder_smoke():
    from aeid_struct.studies.bench import DecoderTiming, bench_decoder, format_decoder_table

    threads = torch.get_num_threads()
    rows = bench_decoder(batch=4, steps=(5, 9), dtype=torch.float64, repeats=1, threads=1)
    assert torch.get_num_threads() == threads  # restored
    assert [r.steps for r in rows] == [5, 9] and all(isinstance(r, DecoderTiming) for r in rows)
    r = rows[0]
    assert r.dtype == "float64" and r.batch == 4
    assert min(r.default_ms, r.fft_ms, r.scan_ms, r.loop_ms) > 0
    assert r.speedup == pytest.approx(r.loop_ms / r.default_ms)
    table = format_decoder_table(rows).splitlines()
    assert len(table) == 4 and table[0].startswith("| batch | steps | dtype | default")
    with pytest.raises(ValueError, match=r"steps must be a non-empty sequence of integers >= 2"):
        bench_decoder(steps=(1,))
    with pytest.raises(ValueError, match=r"dtype must be torch.float32 or torch.float64"):
        bench_decoder(dtype=torch.float16)
    with pytest.raises(ValueError, match=r"batch must be an integer >= 1; got 0"):
        bench_decoder(batch=0)


# -- the initial state of a record that starts mid-motion ---------------------------------------
@pytest.mark.parametrize("n, stable", [(1, True), (2, True), (3, True), (4, False)])
def test_initial_state_is_exact_for_a_noise_free_record_mid_motion(n, stable):
    # Oracle: python-control's forced_response from the state x0 (a record that does not start
    # from rest); the least-squares initial state must give x0 back and reproduce the record.
    A, b, c, d = _system(n, stable, salt=11)
    rng = np.random.default_rng(n)
    x0 = rng.normal(size=n)
    t = np.arange(120) * 0.02
    u = np.sin(3 * t) + 0.5 * (t > 0.7)
    sys = control.ss(A, b[:, None], c[None, :], d)
    y = control.forced_response(sys, t, u, X0=x0).outputs
    found = decoder.initial_state(A, b, c, d, u, y, 0.02)
    np.testing.assert_allclose(found, x0, rtol=1e-7, atol=1e-9 * np.abs(x0).max())
    assert rel_max_error(ae.simulate(A, b, c, d, u, 0.02, x0=found), y) < 1e-9


def test_initial_state_batches_and_differentiates():
    A, b, c, d = _torch(*_system(2, True, salt=3)[:3], np.array(0.0))
    x0 = torch.tensor([[0.3, -1.0], [2.0, 0.5]], dtype=torch.float64)
    u = torch.linspace(0, 1, 50, dtype=torch.float64).expand(2, 50)
    y = ae.simulate(A, b, c, d, u, 0.05, x0=x0)
    torch.testing.assert_close(decoder.initial_state(A, b, c, d, u, y, 0.05), x0)
    Ag = A.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(
        lambda M: decoder.fit_initial_state(M[None].expand(2, 2, 2), b[None].expand(2, 2),
                                            c[None].expand(2, 2), d.expand(2), u, y, 0.05)[0],
        (Ag,))
    with pytest.raises(ValueError, match=r"y must have as many samples as u \(50\); got 49"):
        decoder.initial_state(A, b, c, d, u, y[:, :49], 0.05)


def test_free_fit_response_is_the_simulation_from_the_fitted_state():
    A, b, c, d = _torch(*_system(3, True, salt=5))
    u = torch.cos(torch.linspace(0, 6, 80, dtype=torch.float64))[None]
    y = torch.randn(1, 80, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    x0, y_hat = decoder.fit_initial_state(A[None], b[None], c[None], d[None], u, y, 0.05)
    torch.testing.assert_close(y_hat, ae.simulate(A[None], b[None], c[None], d[None], u, 0.05,
                                                  x0=x0))
    # the least-squares residual is orthogonal to every free-response column
    O = decoder.free_response(A[None], c[None], 0.05, 80)
    assert (O.mT @ (y - y_hat)[..., None]).abs().max() < 1e-9 * y.abs().max() * O.abs().max()



# ------------------------------------------------------------------------------------------------
# Large |pole| dt and overflow (issue 11): the per-step recursion as the oracle
# ------------------------------------------------------------------------------------------------
# The oracle is Eq. 12-13 stepped one sample at a time in float64 with scipy's expm of the
# augmented FOH matrix (_augmented_expm), independent of the library. Accuracy is per sample,
# relative to the size of the sample's own terms, |c|^T |x_k| + |d u_k| (x_k the oracle's state):
# the plain relative error for a response without cancellation (the issue's example), and still
# meaningful at the zero crossings of an oscillation, where |y_k| itself is ~0. Where the two
# differ most (a real unstable pole, pole dt = 30: 5e-11), it is the oracle's expm: against the
# same recursion in 40-digit mpmath the library is within 1.4e-13 and scipy's expm 4.8e-11.

#: The issue's example: poles -4 and +6 rad/s, y = x_1 (so the measure is |y_k| itself).
_ISSUE = (np.array([[0.0, 1.0], [24.0, 2.0]]), np.array([0.0, 1.0]), np.array([1.0, 0.0]), 0.0)
_OVERFLOW = r"simulate: the response overflows {} \(largest finite {}\) in "


@contextlib.contextmanager
def _no_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield


def _recursion(A, b, c, d, u, dt, x0=None):
    """The oracle: ``y (steps,)``, ``X (steps, n)`` and the per-sample scale ``(steps,)``; past
    float64's range its entries are whatever the arithmetic gives (inf, nan)."""
    Phi, gamma1, gamma2 = _augmented_expm(A, b, dt)
    x = np.zeros(len(b)) if x0 is None else np.asarray(x0, dtype=float)
    X = []
    with np.errstate(all="ignore"):
        for k in range(len(u)):
            X.append(x)
            if k + 1 < len(u):
                x = Phi @ x + gamma1 * u[k] + gamma2 * (u[k + 1] - u[k])
        X = np.array(X)
        return X @ c + d * u, X, np.abs(X) @ np.abs(c) + np.abs(d * u)


def _overflow_point(values) -> int:
    """Index of the first sample (axis 0) with a non-finite entry; the length if none."""
    bad = ~np.isfinite(np.asarray(values, dtype=float))
    bad = bad.reshape(len(bad), -1).any(axis=1)
    return int(np.argmax(bad)) if bad.any() else len(bad)


def _assert_recursion(y, expected, scale, rtol):
    """Where the oracle is finite: within ``rtol`` of each sample's scale; from its first
    non-finite sample on: +inf; never NaN."""
    y = np.asarray(y, dtype=float)
    k = _overflow_point(expected)
    assert not np.isnan(y).any()
    assert np.all(np.isfinite(y[:k])), f"finite oracle, non-finite result before sample {k}"
    err = np.abs(y[:k] - expected[:k]) / np.maximum(scale[:k], 1e-300)
    assert err.max(initial=0.0) <= rtol, (float(err.max()), int(err.argmax()))
    assert np.all(np.isposinf(y[k:])), f"not +inf from sample {k} on"


@pytest.mark.parametrize("dt", [1.0, 5.0, 10.0, 12.0, 15.0])
def test_issue_example_matches_the_per_step_recursion(dt):
    """pole dt = 6 .. 90 over 30 samples. The former shifted-state kernel lost 3e-5 relative
    at dt = 5 and every digit at dt = 10 ([0, 0, 5e58, 0, ..] for [0, 1.9e24, 2.2e50, ..])."""
    A, b, c, d = _ISSUE
    u = np.ones(30)
    expected, _, scale = _recursion(A, b, c, d, u, dt)
    overflows = _overflow_point(expected) < 30
    assert overflows == (dt > 1.0)  # e^(6 dt 29) passes 1.8e308 for dt >= 5
    expect = (pytest.warns(RuntimeWarning, match=_OVERFLOW.format("float64", r"1.8e\+308"))
              if overflows else _no_warning())
    with expect:
        y = simulate(A, b, c, d, u, dt)
    _assert_recursion(y, expected, scale, RTOL[np.float64])
    assert y[0] == 0.0
    if dt == 10.0:
        assert abs(y[1] / 1.90334565e24 - 1.0) < 1e-8 and abs(y[2] / 2.1736348e50 - 1.0) < 1e-7
    # torch float64: the same numbers.
    with pytest.warns(RuntimeWarning) if overflows else _no_warning():
        y_t = simulate(*_torch(A, b, c), d, torch.as_tensor(u), dt)
    np.testing.assert_array_equal(y_t.numpy(), y)


def _poles_system(poles, rng, feedthrough=True):
    """Real (A, b, c, d) with exactly these poles (conjugates implied for complex ones) in a
    basis of condition <= 3, as problems.modal_system builds it."""
    blocks = [np.array([[p.real]]) if p.imag == 0 else
              np.array([[p.real, p.imag], [-p.imag, p.real]]) for p in poles]
    M = scipy.linalg.block_diag(*blocks)
    n = len(M)
    Q1, _ = np.linalg.qr(rng.normal(size=(n, n)))
    Q2, _ = np.linalg.qr(rng.normal(size=(n, n)))
    T = Q1 @ np.diag(rng.uniform(1.0, 3.0, size=n)) @ Q2
    d = float(rng.normal()) if feedthrough else 0.0
    return T @ M @ np.linalg.inv(T), rng.normal(size=n), rng.normal(size=n), d


#: |pole| dt of the grid, from a pole that barely moves in a step to one that grows e^40.
_SIZES = [1e-3, 1e-2, 0.1, 1.0, 3.0, 10.0, 20.0, 30.0, 40.0]
#: Pole patterns scaled by s = |pole| dt / dt (order 3 each, so one batch holds every size).
_KINDS = {
    "stable": lambda s: [complex(-s), complex(-0.3 * s), complex(-0.05 * s)],
    "unstable": lambda s: [complex(s), complex(-0.5 * s), complex(-0.02 * s)],
    "oscillatory": lambda s: [complex(-0.1 * s, s), complex(-0.5 * s)],
    "unstable oscillatory": lambda s: [complex(0.3 * s, s), complex(-s)],
    "undamped": lambda s: [complex(0.0, s), complex(-0.2 * s)],
}


@pytest.mark.parametrize("dt", [0.01, 1.0])
@pytest.mark.parametrize("kind", list(_KINDS))
@pytest.mark.parametrize("backend", ["numpy", "torch"])
def test_grid_of_pole_sizes_in_one_batch_matches_the_recursion(kind, backend, dt):
    """Every |pole| dt from 1e-3 to 40 in one batch, with a random input and initial state: the
    records that overflow (+inf, warned) spoil none of the others, each of which matches the
    per-step recursion to 1e-10 of its own samples' size."""
    rng = np.random.default_rng([len(kind), int(dt * 100), 7])
    systems = [_poles_system(_KINDS[kind](size / dt), rng) for size in _SIZES]
    A, b, c = (np.stack([s[j] for s in systems]) for j in range(3))
    d = np.array([s[3] for s in systems])
    u = rng.normal(size=(len(_SIZES), 30))
    x0 = rng.normal(size=b.shape)
    oracle = [_recursion(A[i], b[i], c[i], d[i], u[i], dt, x0[i]) for i in range(len(_SIZES))]
    overflows = [_overflow_point(r[0]) < 30 for r in oracle]
    args = (A, b, c, d, u) if backend == "numpy" else _torch(A, b, c, d, u)
    start = x0 if backend == "numpy" else _torch(x0)[0]
    expect = pytest.warns(RuntimeWarning, match=rf"in {sum(overflows)} of 9 records") \
        if any(overflows) else _no_warning()
    with expect:
        y = simulate(*args, dt, x0=start)
    y = np.asarray(y)
    for i, (expected, _, scale) in enumerate(oracle):
        _assert_recursion(y[i], expected, scale, RTOL[np.float64])
    # e^(s 29) passes 1.8e308 for the real unstable pole at s = 30 and 40 only.
    assert sum(overflows) == (2 if kind == "unstable" else 0)


@pytest.mark.parametrize("dt", [1.0, 5.0])
def test_states_at_large_pole_dt_match_the_recursion(dt):
    A, b, c, d = _ISSUE
    u = np.sin(np.arange(30.0))
    x0 = np.array([0.5, -3.0])
    _, X_expected, _ = _recursion(A, b, c, d, u, dt, x0)
    k = _overflow_point(X_expected)
    assert (k < 30) == (dt == 5.0)
    with pytest.warns(RuntimeWarning, match=r"states: the response overflows float64") \
            if k < 30 else _no_warning():
        X = states(A, b, u, dt, x0=x0)
    # max-norm per sample: the 2-norm's squares would overflow near 1e308
    err = np.abs(X[:k] - X_expected[:k]).max(axis=1) / np.abs(X_expected[:k]).max(axis=1)
    assert err.max() <= RTOL[np.float64]
    assert np.all(np.isposinf(X[k:])) and not np.isnan(X).any()


# -- overflow: +inf from the first overflowing sample on, a RuntimeWarning, never NaN -----------


def test_overflow_in_one_step_dt_100():
    """pole dt = 600: Phi = e^600 is finite, y_1 ~ 6e258, y_2 ~ e^1200 is not."""
    A, b, c, d = _ISSUE
    expected, _, scale = _recursion(A, b, c, d, np.ones(30), 100.0)
    match = (_OVERFLOW.format("float64", r"1.8e\+308") + r"the record \(from sample 2 of 30; "
             r"its largest pole Re\(p\) = 6 rad/s grows by e\^\(Re\(p\) dt steps\) = e\^1.8e\+04 "
             r"over the record\); those samples are \+inf")
    with pytest.warns(RuntimeWarning, match=match):
        y = simulate(A, b, c, d, np.ones(30), 100.0)
    _assert_recursion(y, expected, scale, RTOL[np.float64])
    assert np.isfinite(y[1]) and y[1] > 6e258


@pytest.mark.parametrize("dtype", ["numpy", torch.float64, torch.float32])
def test_overflow_over_3000_steps_is_inf_not_nan(dtype):
    """3000 samples at dt = 0.5 (pole dt = 3): the former kernel gave 2676 inf and 86 NaN. Now
    the samples before the overflow are the recursion's (float32: to 1e-4) and the rest +inf,
    the same rule for numpy and torch, float64 and float32 (which overflows at 3.4e38)."""
    A, b, c, d = _ISSUE
    u = np.ones(3000)
    cast = (lambda a: a) if dtype == "numpy" else (lambda a: torch.as_tensor(a, dtype=dtype))
    name, largest = ("float32", r"3.4e\+38") if dtype == torch.float32 else ("float64",
                                                                           r"1.8e\+308")
    with pytest.warns(RuntimeWarning, match=_OVERFLOW.format(name, largest)) as caught:
        y = simulate(cast(A), cast(b), cast(c), d, cast(u), 0.5)
    assert len(caught) == 1
    y = np.asarray(y, dtype=float)
    expected, _, scale = _recursion(A, b, c, d, u, 0.5)
    if dtype == torch.float32:
        # The float32 range ends where the true response passes 3.4e38.
        expected = np.where(np.abs(expected) < np.finfo(np.float32).max, expected, np.inf)
    k = _overflow_point(expected)
    assert k == (238 if name == "float64" else 31)
    _assert_recursion(y, expected, scale, RTOL[np.float64 if name == "float64" else np.float32])
    assert np.isposinf(y).sum() == 3000 - k and not np.isnan(y).any()


def test_overflowing_record_leaves_the_batch_alone():
    A, b, c, d = _ISSUE
    stable = _system(2, stable=True, salt=4)
    As, bs, cs = np.stack([stable[0], A, stable[0]]), np.stack([stable[1], b, stable[1]]), \
        np.stack([stable[2], c, stable[2]])
    ds = np.array([stable[3], d, 0.0])
    u = np.ones((3, 300))
    with pytest.warns(RuntimeWarning, match=r"in 1 of 3 records \(the first: record 1, from "
                                            r"sample 238 of 300; "):
        y = simulate(As, bs, cs, ds, u, 0.5)
    for i in (0, 2):
        np.testing.assert_array_equal(y[i], simulate(As[i], bs[i], cs[i], ds[i], u[i], 0.5))
    assert np.isposinf(y[1, 238:]).all() and np.isfinite(y[1, :238]).all()


def test_kernel_overflow_with_a_finite_response_is_exact_and_silent():
    """Pole dt = 200 with b = 1e-300: y_k ~ 1e-302 e^(200 k) stays finite for 7 samples, while
    the chunked kernel's scan squares Phi^2 = e^400 into e^800, which overflows. simulate must
    then give the recursion's finite values, without a warning."""
    A, b, c = np.array([[200.0]]), np.array([1e-300]), np.array([1.0])
    u = np.ones(7)
    kernel = decoder.simulate_batch(*(t[None] for t in _torch(A, b, c, 0.0, u)), 1.0)
    assert not bool(torch.isfinite(kernel).all())  # the fallback is exercised
    expected, _, scale = _recursion(A, b, c, 0.0, u, 1.0)
    assert np.isfinite(expected).all() and expected[-1] > 1e200
    with _no_warning():
        y = simulate(A, b, c, 0.0, u, 1.0)
    _assert_recursion(y, expected, scale, RTOL[np.float64])


def test_states_overflow_rule():
    A, b, _, _ = _ISSUE
    with pytest.warns(RuntimeWarning, match=r"states: the response overflows float32 \(largest "
                                            r"finite 3.4e\+38\) in the record \(from sample "):
        X = states(torch.as_tensor(A, dtype=torch.float32), torch.as_tensor(b).float(),
                   torch.ones(40), 1.0)
    k = _overflow_point(X.numpy())
    assert 10 < k < 40 and torch.isfinite(X[:k]).all()
    assert torch.isposinf(X[k:]).all() and not torch.isnan(X).any()


# -- initial_state where the forced or free response is huge ------------------------------------


def test_initial_state_of_a_fast_unstable_record():
    """pole dt = 30 over 20 samples (y up to ~1e247): the free response's 2-norm overflows
    (the former column scaling gave NaN) and the shifted-state forced response was off by 3e-5;
    the least-squares x0 of a noise-free record is now exact. A stable record shares the
    batch."""
    A = np.array([[[6.0]], [[-0.5]]])
    b, c, d = np.array([[1.0], [2.0]]), np.array([[1.0], [0.5]]), np.array([0.0, 0.3])
    u = np.cos(np.arange(20.0))[None].repeat(2, axis=0)
    x0 = np.array([[0.7], [-1.2]])
    y = np.stack([_recursion(A[i], b[i], c[i], d[i], u[i], 5.0, x0[i])[0] for i in range(2)])
    assert np.isfinite(y).all() and np.abs(y).max() > 1e240
    with _no_warning():
        found = decoder.initial_state(A, b, c, d, u, y, 5.0)
    np.testing.assert_allclose(found, x0, rtol=1e-12)
    found_t = decoder.initial_state(*_torch(A, b, c, d, u, y), 5.0)
    np.testing.assert_allclose(found_t.numpy(), x0, rtol=1e-12)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_initial_state_overflow_rule(dtype):
    """The model's response over the record leaves the range: no finite least-squares x0 in
    that precision, so +inf with the warning (never NaN); the other record is fitted."""
    A = torch.tensor([[[6.0]], [[-0.5]]], dtype=dtype)
    b, c, d = torch.ones(2, 1, dtype=dtype), torch.ones(2, 1, dtype=dtype), torch.zeros(2)
    u = torch.ones(2, 30, dtype=dtype)
    y = simulate(A[1], b[1], c[1], 0.0, u[1], 5.0, x0=torch.tensor([0.4], dtype=dtype))
    name = str(dtype).removeprefix("torch.")
    with pytest.warns(RuntimeWarning, match=rf"initial_state: the response overflows {name} "
                                            r".* in 1 of 2 records \(the first: record 0, from "
                                            r"sample \d+ of 30; .* x0 of those records is \+inf"):
        x0 = decoder.initial_state(A, b, c, d, u, y.expand(2, 30), 5.0)
    assert torch.isposinf(x0[0]).all()
    torch.testing.assert_close(x0[1], torch.tensor([0.4], dtype=dtype), rtol=RTOL[dtype],
                               atol=0.0)


def test_initial_state_rejects_an_unobservable_model():
    """c sees only the first state of a triangular A: the second initial state is not
    determined (the former fit returned NaN silently)."""
    A = np.stack([np.array([[-1.0, 0.0], [1.0, -2.0]]), np.array([[-1.0, 1.0], [0.0, -2.0]])])
    b, c = np.array([0.0, 1.0]), np.array([1.0, 0.0])
    with pytest.raises(ValueError, match=r"A and c must give an observable model \(record 0 of "
                                         r"2\): the free response c\^T e\^\{A k dt\} has rank < n"):
        decoder.initial_state(A, b, c, 0.0, np.ones(50), np.ones((2, 50)), 0.1)


# -- the training path keeps its gradients --------------------------------------------------------


def test_gradcheck_training_decoder_at_large_pole_dt():
    """decoder.simulate_batch (the kernel training calls) in float64 on a batch that mixes
    pole dt = 0.05 and pole dt = 12 (growth e^72 over the record); fit_initial_state (training with
    fitted initial states) at pole dt = 1.5, where its least squares is well-conditioned enough
    for finite differences (at pole dt = 3 they fail, with the former column scaling too)."""
    def batch(growth):
        A = torch.tensor([[[0.0, 1.0], [24.0, 2.0]], [[0.0, 1.0], [-24.0, -2.0]]],
                         dtype=torch.float64)
        A = A * torch.tensor([growth, 0.01], dtype=torch.float64)[:, None, None]
        b = torch.tensor([[0.0, 1.0], [0.3, 1.0]], dtype=torch.float64)
        c = torch.tensor([[1.0, 0.2], [1.0, -0.5]], dtype=torch.float64)
        d = torch.tensor([0.0, 0.4], dtype=torch.float64)
        return tuple(t.requires_grad_() for t in (A, b, c, d))

    u = torch.sin(torch.arange(7.0, dtype=torch.float64))[None].expand(2, 7).contiguous()
    args = batch(2.0)  # poles +12 and -8 rad/s
    # Scaled per record so that every output is O(1) and gradcheck's tolerances mean the same.
    scale = 1.0 / decoder.simulate_batch(*args, u, 1.0).detach().abs().amax(1, keepdim=True)
    assert torch.autograd.gradcheck(lambda *a: decoder.simulate_batch(*a, u, 1.0) * scale, args)
    args = batch(0.25)  # poles +1.5 and -1 rad/s
    y = decoder.simulate_batch(*args, u, 1.0).detach()
    y = 1.001 * y + 0.01 * y.abs().amax(1, keepdim=True) * torch.cos(torch.arange(7.0))
    assert torch.autograd.gradcheck(lambda *a: decoder.fit_initial_state(*a, u, y, 1.0)[1], args)
    assert torch.autograd.gradcheck(lambda *a: decoder.fit_initial_state(*a, u, y, 1.0)[0], args)


def test_simulate_takes_reversed_views():
    """A view with negative strides (``c[::-1]``, ``u[::-1]``) is an ordinary array to numpy;
    torch refuses it, so the boundary copies it (it raised a torch error before)."""
    A = np.array([[0.0, 1.0], [-4.0, -0.4]])
    b = np.array([0.0, 1.0])
    c = np.array([3.0, 1.0])
    u = np.linspace(0.0, 1.0, 50)
    y = ae.simulate(A, b, c[::-1], 0.0, u[::-1], 0.01)
    np.testing.assert_array_equal(y, ae.simulate(A, b, c[::-1].copy(), 0.0, u[::-1].copy(), 0.01))


def test_discrete_foh_is_scipys_first_order_hold():
    """simulation.discrete_foh (the numpy Eq. 10 of the library) against
    scipy.signal.cont2discrete(method="foh"): Ad = Phi, Dd = c^T gamma2 (c = I) and
    Bd = gamma1 - gamma2 + Phi gamma2, one system and a batch, and its complex step."""
    from aeid_struct.simulation import discrete_foh

    rng = np.random.default_rng(11)
    A = rng.standard_normal((4, 3, 3)) - 2.0 * np.eye(3)
    b = rng.standard_normal((4, 3))
    Phi, gamma1, gamma2 = discrete_foh(A, b, 0.07)
    for k in range(4):
        Ad, Bd, _, Dd, _ = scipy.signal.cont2discrete(
            (A[k], b[k][:, None], np.eye(3), np.zeros((3, 1))), 0.07, method="foh")
        np.testing.assert_allclose(Phi[k], Ad, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(gamma2[k], Dd[:, 0], rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(gamma1[k] - gamma2[k] + Phi[k] @ gamma2[k], Bd[:, 0],
                                   rtol=1e-12, atol=1e-14)
        one = discrete_foh(A[k], b[k], 0.07)
        for x, y in zip(one, (Phi[k], gamma1[k], gamma2[k]), strict=True):
            np.testing.assert_array_equal(x, y)
    h = 1e-20
    step = discrete_foh(A[0] + 1j * h * np.eye(3), b[0].astype(complex), 0.07)[0].imag / h
    fd = (discrete_foh(A[0] + 1e-6 * np.eye(3), b[0], 0.07)[0]
          - discrete_foh(A[0] - 1e-6 * np.eye(3), b[0], 0.07)[0]) / 2e-6
    np.testing.assert_allclose(step, fd, rtol=1e-7, atol=1e-10)


def test_numpy_decoder_gives_the_torch_decoders_response_and_initial_state():
    """simulation.simulate_numpy / initial_state_numpy (what an estimate reads where torch is
    not installed) against simulate / initial_state, one system and a batch."""
    from aeid_struct.simulation import (
        initial_state,
        initial_state_numpy,
        simulate,
        simulate_numpy,
    )

    rng = np.random.default_rng(12)
    A = np.stack([np.array([[0.0, 1.0], [-4.0 - k, -0.8]]) for k in range(3)])
    b, c, d = np.tile([0.0, 1.0], (3, 1)), rng.standard_normal((3, 2)), rng.standard_normal(3)
    u, x0 = rng.standard_normal((3, 400)), rng.standard_normal((3, 2))
    want = simulate(A, b, c, d, u, 0.02, x0=x0)
    np.testing.assert_allclose(simulate_numpy(A, b, c, d, u, 0.02, x0=x0), want, rtol=1e-10,
                               atol=1e-12 * np.abs(want).max())
    np.testing.assert_allclose(simulate_numpy(A[1], b[1], c[1], d[1], u[1], 0.02, x0=x0[1]),
                               want[1], rtol=1e-10, atol=1e-12 * np.abs(want).max())
    np.testing.assert_allclose(initial_state_numpy(A, b, c, d, u, want, 0.02), x0, rtol=1e-8)
    np.testing.assert_allclose(initial_state_numpy(A, b, c, d, u, want, 0.02),
                               initial_state(A, b, c, d, u, want, 0.02), rtol=1e-8)
