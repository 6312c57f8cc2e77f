"""Tests for a record of a mechanism in which several inputs move at once
(``Physical(mechanism, outputs=..., inputs=...)``): the channels of each output summed
(``structures/mechanical.grid_specs``, ``Physical.groups``), their response and initial state
(``simulation.summed_response``, ``training.objective.decoded_output``), their simulated records
(``training.datasets``), the joint fit over outputs (``refinement/joint.py``'s ``groups``), the
head, the refinement and the estimate's response.

Oracles: python-control's ``forced_response`` of the mechanism's whole linearisation
(``Mechanism.linearise``: both inputs, both outputs, linear interpolation between samples: the
first-order hold) from a known state, the mechanism's own one-channel maps
(``Mechanism.channel``), the true parameters of noise-free records, and
``scipy.optimize.least_squares`` on a residual built from python-control with the initial
state by ``numpy.linalg.lstsq``.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
import torch

import aeid_struct as ae
from aeid_struct.identification import Head
from aeid_struct.identification.physical_head import physical_head
from aeid_struct.refinement import fit_joint, joint_residual
from aeid_struct.simulation import simulate_numpy, summed_response
from aeid_struct.training.objective import decoded_output
from symbolic import mechanisms

#: The coupled masses' box (``symbolic.mechanisms.coupled_masses``: a force on each mass).
BOX = {n: (0.5, 2.0) for n in ("m1", "m2", "k1", "k2", "c1", "c2")}
NAMES = tuple(BOX)
DT, STEPS = 0.05, 160
GRID = dict(steps=(STEPS,) * 4, dt=(DT,) * 4)
POINT = np.array([0.8, 1.4, 1.1, 0.7, 0.9, 1.3])


@pytest.fixture(scope="module")
def coupled():
    return ae.Physical(mechanisms.coupled_masses(), bounds=BOX, outputs=[0, 1], inputs=[0, 1])


def _whole(p):
    """The mechanism's two-input, two-output linearisation at ``p`` as a python-control
    system (the oracle: no channel, no CCF)."""
    out = mechanisms.coupled_masses().linearise()(**dict(zip(NAMES, p, strict=True)))
    return control.ss(*(np.array(out[k]) for k in "ABCD"))


def _measured(p, u, x0):
    """Both outputs of the whole linearisation from ``x0`` under ``u (2, steps)``."""
    return control.forced_response(_whole(p), DT * np.arange(u.shape[1]), u, X0=x0).outputs


def test_the_channels_are_every_output_of_every_input_summed_per_output(coupled):
    assert coupled.records == 4
    assert coupled.channels == ((0, 0), (0, 1), (1, 0), (1, 1))
    assert coupled.groups == (0, 0, 1, 1)
    assert ae.ParameterFamily(coupled).shared_outputs == (0, 0, 1, 1)
    assert ae.ParameterFamily(coupled).shared_inputs == (0, 1, 0, 1)
    # each record's map is the mechanism's own channel
    point = dict(zip(NAMES, POINT, strict=True))
    out = coupled.function(**point)
    for r, (o, i) in enumerate(coupled.channels, start=1):
        one = mechanisms.coupled_masses().channel(o, i)(**point)
        for k in "ABCD":
            np.testing.assert_allclose(np.array(out[f"{k}{r}"]), np.array(one[k]),
                                       rtol=1e-12, atol=1e-12)
    # one output of two inputs: one group; two outputs of one input: none (nothing sums)
    one_output = ae.Physical(mechanisms.coupled_masses(), bounds=BOX, outputs=[1],
                             inputs=[0, 1])
    assert one_output.groups == (1, 1)
    assert ae.Physical(mechanisms.coupled_masses(), bounds=BOX, outputs=[0, 1],
                       inputs=[0]).groups is None


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"outputs": [0, 1]}, "give both"),
    ({"outputs": [0, 1], "inputs": [0, 1], "channels": [(0, 0)]}, "neither channel"),
    ({"outputs": [0, 1], "inputs": [0, 1], "experiments": True}, "neither channel"),
    ({"outputs": [0, 0], "inputs": [0, 1]}, "outputs must be a non-empty sequence of distinct"),
    ({"outputs": [0, 1], "inputs": []}, "inputs must be a non-empty sequence"),
    ({"outputs": [0, 1], "inputs": [0, 1.0]}, "inputs must be a non-empty sequence"),
    ({"outputs": "01", "inputs": [0, 1]}, "outputs must be a non-empty sequence"),
])
def test_bad_outputs_and_inputs_are_refused_by_name(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ae.Physical(mechanisms.coupled_masses(), bounds=BOX, **kwargs)


def test_a_casadi_map_takes_no_outputs_or_inputs(coupled):
    with pytest.raises(ValueError, match="outputs= and inputs= read a symbolic.Mechanism"):
        ae.Physical(coupled.function, bounds=BOX, outputs=[0], inputs=[0])


def test_a_coupled_record_split_by_channel_is_refused_with_the_way_to_sum_it():
    with pytest.raises(ValueError, match=r"y\[0\] also answers u\[1\].*outputs=\[\.\.\.\], "
                                         r"inputs=\[\.\.\.\]"):
        ae.Physical(mechanisms.coupled_masses(), bounds=BOX, channels=[(0, 0), (1, 1)])


def test_a_parameter_no_output_of_the_inputs_sees_is_refused():
    # the lever's ratio r and mass m appear only as r / m from its one force
    lever = mechanisms.lever()
    box = {"m": (0.5, 2.0), "k": (10.0, 50.0), "d": (0.5, 3.0), "r": (0.5, 2.0)}
    with pytest.raises(ValueError, match="cannot determine"):
        ae.Physical(lever, bounds=box, outputs=[0], inputs=[0])


def test_the_summed_response_and_its_initial_state_match_python_control(coupled):
    rng = np.random.default_rng(3)
    u = rng.normal(size=(2, STEPS))
    x0 = rng.normal(size=4)
    y = _measured(POINT, u, x0)
    rest = _measured(POINT, u, np.zeros(4))
    ph = physical_head(coupled, True)
    models = ph.at(POINT[None])
    for o in (0, 1):
        group = [models[2 * o], models[2 * o + 1]]
        y_hat, states = summed_response(group, [u[0], u[1]], y[o], DT, True, x0=True)
        scale = np.abs(y[o]).max()
        np.testing.assert_allclose(y_hat[0], y[o], atol=1e-9 * scale)
        # from rest: the channels' responses sum to the whole model's
        np.testing.assert_allclose(summed_response(group, [u[0], u[1]], y[o], DT, False)[0][0],
                                   rest[o], atol=1e-10 * np.abs(rest[o]).max())
        # the channels' initial states reproduce the fitted response, each simulated alone
        alone = sum(simulate_numpy(A[0], b[0], c[0], float(d[0]), u[i], DT, x0=s[0])
                    for i, ((A, b, c, d), s) in enumerate(zip(group, states, strict=True)))
        np.testing.assert_allclose(alone, y_hat[0], atol=1e-9 * scale)


def test_training_decodes_a_summed_output_from_its_initial_state(coupled):
    """``decoded_output`` (torch, float64): the channels from rest summed plus the free
    response in the span of the shared poles is the whole model's output from any state."""
    rng = np.random.default_rng(4)
    u = rng.normal(size=(2, STEPS))
    x0 = rng.normal(size=4)
    y = _measured(POINT, u, x0)
    models = physical_head(coupled, True).at(POINT[None])
    for o in (0, 1):
        systems = [tuple(torch.from_numpy(np.ascontiguousarray(v)) for v in models[r])
                   for r in (2 * o, 2 * o + 1)]
        us = [torch.from_numpy(u[i][None]) for i in (0, 1)]
        y_hat, _ = decoded_output(systems, us, torch.from_numpy(y[o][None]), DT, initial=True)
        np.testing.assert_allclose(y_hat[0].numpy(), y[o], atol=1e-8 * np.abs(y[o]).max())


def test_simulated_records_hold_each_output_once(coupled):
    family = ae.ParameterFamily(coupled)
    rec = ae.data.records(family, 3, **GRID, excitation_kind="prbs", seed=2, noise=0.02)
    # the records of one output are one measurement; the records of one input one signal
    assert rec.y[0] is rec.y[1] and rec.y[2] is rec.y[3]
    assert np.shares_memory(rec.u[0], rec.u[2]) and np.shares_memory(rec.u[1], rec.u[3])
    assert not np.array_equal(rec.u[0], rec.u[1])
    for k in range(3):
        p = np.array([rec.systems.params[n][k] for n in NAMES])
        clean = _measured(p, np.stack([rec.u[0][k], rec.u[1][k]]), np.zeros(4))
        for r, o in enumerate((0, 0, 1, 1)):
            np.testing.assert_allclose(rec.y_clean[r][k], clean[o],
                                       atol=1e-10 * np.abs(clean[o]).max())
        noise = rec.y[0][k] - rec.y_clean[0][k]
        np.testing.assert_allclose(np.std(noise), 0.02 * np.abs(clean[0]).max(), rtol=0.3)


def _oracle_residual(p, y, u, initial=True):
    """Both outputs' weighted residuals by python-control and the initial state of the whole
    linearisation by least squares (``y (2, steps)``, ``u (2, steps)``)."""
    system = _whole(p)
    forced = control.forced_response(system, DT * np.arange(y.shape[1]), u).outputs
    Phi = scipy.linalg.expm(system.A * DT)
    parts = []
    for o in (0, 1):
        e = y[o] - forced[o]
        if initial:
            O = np.stack([system.C[o] @ np.linalg.matrix_power(Phi, k)
                          for k in range(y.shape[1])])
            e = e - O @ np.linalg.lstsq(O, e, rcond=None)[0]
        parts.append(e * 2.0 / (np.abs(y[o]).max() * np.sqrt(y.shape[1] + 1)))
    return np.concatenate(parts)


def test_the_joint_residual_and_optimum_over_outputs_match_scipy(coupled):
    family = ae.ParameterFamily(coupled)
    rec = ae.data.records(family, 2, **GRID, excitation_kind="prbs", seed=5, noise=0.03,
                          warmup=40)
    ph = physical_head(coupled, True)
    for k in range(2):
        ys, us = [y[k] for y in rec.y], [u[k] for u in rec.u]
        y, u = np.stack([ys[0], ys[2]]), np.stack([us[0], us[1]])
        truth = np.array([rec.systems.params[n][k] for n in NAMES])
        np.testing.assert_allclose(
            joint_residual(ph.at, truth, ys, us, (DT,) * 4, True, groups=ph.groups),
            _oracle_residual(truth, y, u), atol=1e-9)
        fit = fit_joint(ph.at, truth[None], [v[k: k + 1] for v in rec.y],
                        [v[k: k + 1] for v in rec.u], (DT,) * 4, lower=ph.lo, upper=ph.hi,
                        initial=True, groups=ph.groups)
        oracle = scipy.optimize.least_squares(
            lambda p, y=y, u=u: _oracle_residual(p, y, u), truth, bounds=(ph.lo, ph.hi),
            x_scale=ph.hi - ph.lo, xtol=1e-12, ftol=1e-12, gtol=1e-12)
        assert fit.cost[0] <= 2 * oracle.cost * (1 + 1e-7)
        np.testing.assert_allclose(fit.p[0], oracle.x, rtol=1e-4)


@pytest.fixture(scope="module")
def trained(coupled):
    family = ae.ParameterFamily(coupled)
    ident = ae.train(coupled, family, ae.TrainConfig(**GRID, epochs=3, count=400,
                                                     excitation="prbs", warmup=60,
                                                     initial="fitted", progress=False))
    ident.head = Head(iterations=5)
    return ident, family


def test_one_record_of_both_forces_is_identified_and_refined_to_the_truth(trained, tmp_path):
    ident, family = trained
    rec = ae.data.records(family, 3, **GRID, excitation_kind="prbs", seed=8, warmup=60)
    truth = np.stack([rec.systems.params[k] for k in NAMES], 1)
    refined = ident.identify(rec.y, rec.u, refine=True)
    assert refined.info["refine"] == "joint"
    np.testing.assert_allclose(np.stack([refined.physical[k] for k in NAMES], 1), truth,
                               rtol=1e-7)
    # its response: each record's is its output's, the measured one (noise-free)
    for r in range(4):
        np.testing.assert_allclose(refined.y_hat[r], rec.y[r],
                                   atol=1e-8 * np.abs(rec.y[r]).max())
    np.testing.assert_allclose(refined.fit, 100.0, atol=1e-5)
    # the same as one measured Record of two outputs and two inputs
    k = 1
    record = ae.Record(y=np.stack([rec.y[0][k], rec.y[2][k]], 1),
                       u=np.stack([rec.u[0][k], rec.u[1][k]], 1), dt=DT)
    one = ident.identify(record, refine=True)
    for j, name in enumerate(NAMES):
        assert one.physical[name] == pytest.approx(truth[k, j], rel=1e-7)
        assert np.isfinite(one.info["std"][name])
    again = ae.load(ident.save(tmp_path / "coupled_together.aeid"),
                    maps={coupled_name(ident): ident.structure.function})
    again.head = Head(iterations=5)
    assert again.structure.groups == (0, 0, 1, 1)
    a, b = again.identify(rec.y, rec.u), ident.identify(rec.y, rec.u)
    for name in NAMES:
        np.testing.assert_array_equal(a.physical[name], b.physical[name])


def coupled_name(ident) -> str:
    return ident.structure.function.name()


def test_the_standard_errors_cover_the_truth_at_noise(trained):
    """At 2 % noise the refined parameters lie within a few standard errors of the truth, and
    the errors count one initial state per output, not per channel."""
    ident, family = trained
    rec = ae.data.records(family, 6, **GRID, excitation_kind="prbs", seed=9, noise=0.02,
                          warmup=60)
    truth = np.stack([rec.systems.params[k] for k in NAMES], 1)
    refined = ident.identify(rec.y, rec.u, refine=True)
    got = np.stack([refined.physical[k] for k in NAMES], 1)
    std = np.stack([refined.info["std"][k] for k in NAMES], 1)
    assert np.isfinite(std).all()
    z = np.abs(got - truth) / std
    # a normal's |z| exceeds 4 with probability 6e-5; allow one parameter of 36 beyond it
    assert np.sum(z > 4) <= 1


def test_the_training_loss_sums_each_outputs_channels(trained, monkeypatch):
    """Eq. 14 over the two outputs is zero where the encoder returns the true channels
    (noise-free windows mid-motion, initial state fitted), and not where one output's two
    channels are swapped."""
    from aeid_struct.training.objective import batch_loss

    ident, family = trained
    rec = ae.data.records(family, 3, **GRID, excitation_kind="prbs", seed=12, warmup=60)
    truth = tuple(torch.tensor(getattr(rec.systems, k)) for k in "Abcd")
    swapped = tuple(x[:, [1, 0, 2, 3]] for x in truth)
    y, u = [torch.tensor(v) for v in rec.y], [torch.tensor(v) for v in rec.u]
    losses = []
    for systems in (truth, swapped):
        monkeypatch.setattr(ident, "forward", lambda y, u, raw=False, systems=systems: (
            systems, None, torch.zeros(3, len(NAMES))))
        losses.append(float(batch_loss(ident, y, u, torch.zeros(3, 4), 0.0)))
    assert losses[0] < 1e-16
    assert losses[1] > 1e-3


def test_the_summed_separable_fit_recovers_every_channels_coefficients(coupled):
    """``refinement.fit_summed`` from a denominator 10 % off: noise-free, the common
    denominator and every channel's numerator come out as the mechanism's own CCFs."""
    from aeid_struct.refinement import fit_summed
    from aeid_struct.simulation import output_groups

    family = ae.ParameterFamily(coupled)
    rec = ae.data.records(family, 2, **GRID, excitation_kind="prbs", seed=13, warmup=50)
    ph = physical_head(coupled, True)
    truth = [ph.systems(np.array([rec.systems.params[k][i] for k in NAMES])) for i in range(2)]
    a_true = np.stack([t[0][4] for t in truth])
    fit = fit_summed(ph.patterns, output_groups(ph.groups, 4), a_true * 1.1, rec.y, rec.u,
                     (DT,) * 4, iterations=40, initial=True)
    np.testing.assert_allclose(fit.a, a_true, rtol=1e-7)
    for i in range(2):
        for r in range(4):
            c_true = truth[i][r][2]
            np.testing.assert_allclose(fit.c[i, r], c_true, atol=1e-7 * np.abs(c_true).max())
            assert fit.d[i, r] == pytest.approx(truth[i][r][3], abs=1e-9)
    assert np.all(fit.cost < 1e-20)


def test_a_stream_of_both_forces_is_tracked_window_by_window(trained):
    """The tracker splits each window of a ``(k, 2)`` / ``(k, 2)`` stream into the four
    channels; each update is the identifier's estimate of that window, and on a noise-free
    stream of one machine the refined windows return its parameters."""
    from aeid_struct.online import Tracker, TrackerConfig

    ident, _ = trained
    rng = np.random.default_rng(14)
    u = np.repeat(rng.choice([-1.0, 1.0], (2, 60)), 8, axis=1)[:, :400]
    y = _measured(POINT, u, np.zeros(4))
    tracker = Tracker(ident, TrackerConfig(hop=80, baseline=2, iterations=None),
                      engine="identifier")
    assert tracker.width == (2, 2)
    updates = tracker.feed(y.T, u.T)
    assert len(updates) == 4 and all(up.error is None for up in updates)
    for j, up in enumerate(updates):
        end = STEPS + 80 * j
        window = ident.identify(tuple(y[o, end - STEPS: end] for o, _ in ident.structure.channels),
                                tuple(u[i, end - STEPS: end] for _, i in ident.structure.channels))
        assert up.estimate == {k: float(v) for k, v in window.physical.items()}
        refined = ident.identify(
            tuple(y[o, end - STEPS: end] for o, _ in ident.structure.channels),
            tuple(u[i, end - STEPS: end] for _, i in ident.structure.channels), refine=True)
        np.testing.assert_allclose([refined.physical[k] for k in NAMES], POINT, rtol=1e-6)


def test_the_head_states_are_the_decoders(coupled):
    """``refinement.summed.Kernel`` (Markov parameters and one FFT) against the decoder's
    exact response from rest (``simulation.simulate_numpy``): each channel's output is its
    numerator over those states; its free response against ``e_1^T expm(A k dt)``."""
    from aeid_struct.refinement.summed import Kernel

    rng = np.random.default_rng(15)
    u = rng.normal(size=STEPS)
    models = physical_head(coupled, False).at(np.stack([POINT, POINT[::-1]]))
    for A, b, c, d in models:
        kernel = Kernel(A, b, DT, STEPS)
        X = kernel.forced(u)
        for k in range(2):
            y = simulate_numpy(A[k], b[k], c[k], float(d[k]), u, DT)
            np.testing.assert_allclose(X[k] @ c[k] + d[k] * u, y, atol=1e-12 * np.abs(y).max())
            for step in (0, 1, 57, STEPS - 1):
                np.testing.assert_allclose(kernel.free[k, step],
                                           scipy.linalg.expm(A[k] * DT * step)[0], rtol=1e-10,
                                           atol=1e-13)


def test_fresh_records_of_a_data_parallel_run_sum_each_output(coupled):
    """``training.distributed.row_records`` (fresh records drawn row by row under torchrun)
    sums each output's channels as ``training.records`` does."""
    from aeid_struct.training.distributed import row_records

    family = ae.ParameterFamily(coupled)
    config = ae.TrainConfig(**GRID, excitation="prbs", progress=False)
    rec = row_records(family, config, 1, np.array([3, 7]))
    for k in range(2):
        p = np.array([rec.systems.params[n][k] for n in NAMES])
        clean = _measured(p, np.stack([rec.u[0][k], rec.u[1][k]]), np.zeros(4))
        for r, o in enumerate((0, 0, 1, 1)):
            np.testing.assert_allclose(rec.y[r][k], clean[o], atol=1e-10 * np.abs(clean[o]).max())


def test_a_shared_discretisation_is_reused_only_for_equal_systems(coupled):
    """``summed_response``'s cache: the channels of one mechanism (equal ``A, b``) share one
    discretisation, and a system of other parameters is not given it."""
    rng = np.random.default_rng(16)
    u = rng.normal(size=STEPS)
    ph = physical_head(coupled, True)
    first, other = ph.at(POINT[None]), ph.at(POINT[::-1][None])
    cache = []
    shared = [summed_response([m], [u], u, DT, True, cache=cache)[0]
              for m in (first[0], first[2], other[0])]
    assert len(cache) == 2
    for got, m in zip(shared, (first[0], first[2], other[0]), strict=True):
        np.testing.assert_array_equal(got, summed_response([m], [u], u, DT, True)[0])


def test_each_output_is_measured_once_and_no_draw_is_thrown_away():
    """``training.datasets.one_per_output``: ``measure`` runs for each output's first record
    only, in record order, and the output's other records share its result; without groups
    every record is measured in turn (the draws of measuring each)."""
    from aeid_struct.training.datasets import one_per_output

    calls = []

    def measure(r):
        calls.append(r)
        return np.full(3, float(r))

    out = one_per_output(measure, 4, (0, 0, 1, 1))
    assert calls == [0, 2]
    assert [v[0] for v in out] == [0.0, 0.0, 2.0, 2.0] and out[0] is out[1]
    calls.clear()
    out = one_per_output(measure, 3, None)
    assert calls == [0, 1, 2] and [v[0] for v in out] == [0.0, 1.0, 2.0]
