"""System families, excitations and simulated records, against closed forms and python-control."""

import control
import numpy as np
import pytest

from aeid_struct.training import EXCITATIONS, LegFamily, PoleFamily, excitation, records


def test_leg_family_closed_forms():
    fam = LegFamily(subsystem="stable")
    s = fam.systems(k=[20.0, 24.23], d=[2.0, 2.24], m=[0.5, 1.01])
    k, d, m = s.params["k"], s.params["d"], s.params["m"]
    np.testing.assert_allclose(s.A[:, 1, 0], -k / m, rtol=1e-14)
    np.testing.assert_allclose(s.A[:, 1, 1], -d / m, rtol=1e-14)
    np.testing.assert_allclose(s.c[:, 0], 1 / m, rtol=1e-14)
    np.testing.assert_allclose(s.b, [[0, 1], [0, 1]])
    un = LegFamily(subsystem="unstable").systems(k=[24.23], d=[2.24], m=[1.01])
    L = 0.8 - 1.01 * 9.81 / 24.23
    np.testing.assert_allclose(un.A[0, 1], [9.81 / L, 0.0], rtol=1e-14)
    np.testing.assert_allclose(un.c[0], [1 / (1.01 * L**2), 0.0], rtol=1e-14)


def test_leg_family_sampling_in_ranges_and_seeded():
    fam = LegFamily(subsystem="unstable")
    a = fam.sample(200, np.random.default_rng(3))
    b = fam.sample(200, np.random.default_rng(3))
    np.testing.assert_array_equal(a.A, b.A)
    for name, (lo, hi) in fam.ranges.items():
        assert np.all((a.params[name] >= lo) & (a.params[name] <= hi))
    # every unstable leg has exactly one positive real pole
    poles = np.linalg.eigvals(a.A)
    assert np.all(np.sum(poles.real > 0, axis=1) == 1)


def test_pole_family_poles_and_gain():
    fam = PoleFamily(real=1, pairs=1, decay=(1, 2), freq=(3, 4), gain=(0.5, 0.6))
    s = fam.sample(50, np.random.default_rng(0))
    for A, b, c, d in zip(s.A, s.b, s.c, s.d, strict=True):
        p = np.linalg.eigvals(A)
        assert np.all((-p.real >= 1 - 1e-9) & (-p.real <= 2 + 1e-9))
        assert np.sum(np.abs(p.imag) > 1e-9) == 2
        gain = control.dcgain(control.ss(A, b.reshape(3, 1), c.reshape(1, 3), [[d]]))
        assert 0.5 - 1e-9 <= gain <= 0.6 + 1e-9


def test_records_match_python_control_and_noise_level():
    fam = LegFamily(subsystem="stable")
    rec = records(fam, 20, steps=300, dt=0.01, noise=0.05, seed=1)
    t = np.arange(300) * 0.01
    for i in range(3):
        s = control.ss(rec.systems.A[i], rec.systems.b[i].reshape(2, 1),
                       rec.systems.c[i].reshape(1, 2), [[rec.systems.d[i]]])
        y = control.forced_response(s, t, rec.u[i]).outputs
        np.testing.assert_allclose(rec.y_clean[i], y, atol=1e-9 * np.abs(y).max())
    rel = (rec.y - rec.y_clean) / np.abs(rec.y_clean).max(axis=1, keepdims=True)
    assert rel.std() == pytest.approx(0.05, rel=0.05)
    clean = records(fam, 20, steps=300, dt=0.01, noise=0.0, seed=1)
    np.testing.assert_array_equal(clean.y, clean.y_clean)
    ranged = records(fam, 400, steps=50, dt=0.01, noise=(0.0, 0.1), seed=1)
    assert ranged.noise.min() >= 0 and ranged.noise.max() <= 0.1
    assert ranged.noise.std() > 0.02


@pytest.mark.parametrize("kind", EXCITATIONS)
def test_excitations(kind):
    rng = np.random.default_rng(0)
    u = excitation(kind, 8, 200, 0.01, rng)
    assert u.shape == (8, 200) and np.all(np.isfinite(u))
    assert np.all(np.abs(u).max(axis=1) > 0)
    if kind == "step":
        np.testing.assert_array_equal(u, 1.0)
    if kind == "prbs":
        assert set(np.unique(u)) <= {-1.0, 1.0}
        for row in u:   # every level is held for at least 3 samples (the last run may be cut)
            changes = np.flatnonzero(np.diff(row) != 0)
            assert np.all(np.diff(np.r_[-1, changes]) >= 3)
    if kind in ("multisine", "noise"):
        np.testing.assert_allclose(np.abs(u).max(axis=1), 1.0)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: LegFamily(subsystem="middle"),
         "subsystem must be 'stable', 'unstable' or 'joint'"),
        (lambda: LegFamily(ranges={"k": (20, 25), "d": (2, 5)}), "ranges must name exactly"),
        (lambda: LegFamily(ranges={"k": (25, 20), "d": (2, 5), "m": (0.5, 1.5)}),
         r"ranges\['k'\] must satisfy lo <= hi"),
        (lambda: PoleFamily(real=0, pairs=0), "real \\+ pairs must be at least 1"),
        (lambda: excitation("chirp", 1, 10, 0.1, np.random.default_rng()), "kind must be one of"),
        (lambda: records(PoleFamily(), 0, steps=10, dt=0.1), "count must be a positive integer"),
    ],
)
def test_errors(make, match):
    with pytest.raises(ValueError, match=match):
        make()


@pytest.mark.parametrize("sub, names", [("stable", ("k", "d", "m")), ("unstable", ("k", "m"))])
def test_leg_family_inverse_round_trips(sub, names):
    fam = LegFamily(subsystem=sub)
    inverse = fam.inverse()
    assert tuple(inverse.name_out()) == names
    out = fam.map()(k=22.0, d=3.3, m=0.9)
    back = inverse(A=out["A"], B=out["B"], C=out["C"], D=out["D"])
    for name, value in {"k": 22.0, "d": 3.3, "m": 0.9}.items():
        if name in names:
            assert float(back[name]) == pytest.approx(value, rel=1e-12)


def test_joint_leg_records_are_both_subsystems_on_their_own_grids():
    fam = LegFamily(subsystem="joint")
    rec = records(fam, 3, steps=(300, 100), dt=(0.01, 0.005), noise=0.01, seed=2)
    assert rec.systems.records == 2 and rec.systems.A.shape == (3, 2, 2, 2)
    assert [y.shape for y in rec.y] == [(3, 300), (3, 100)] and rec.dt == (0.01, 0.005)
    for r, (sub, dt) in enumerate((("stable", 0.01), ("unstable", 0.005))):
        single = LegFamily(subsystem=sub).systems(**rec.systems.params)
        np.testing.assert_allclose(rec.systems.A[:, r], single.A, rtol=1e-14)
        # each record is the subsystem's step response (python-control as the oracle)
        t = np.arange(rec.y[r].shape[1]) * dt
        sys = control.ss(single.A[0], single.b[0][:, None], single.c[0][None], 0.0)
        ref = control.forced_response(sys, t, np.ones_like(t)).outputs
        np.testing.assert_allclose(rec.y_clean[r][0], ref, rtol=1e-8, atol=1e-10 * abs(ref).max())
        level = (rec.y[r] - rec.y_clean[r]).std(axis=1) / abs(rec.y_clean[r]).max(axis=1)
        assert np.all((level > 0.005) & (level < 0.02))
    alone = rec.record(1)
    assert alone.dt == 0.005 and alone.systems.A.shape == (3, 2, 2)
    np.testing.assert_array_equal(alone.y, rec.y[1])
    with pytest.raises(ValueError, match=r"r must be a record index in \[0, 2\); got 2"):
        rec.record(2)
    sub = rec.take([0, 2])
    assert len(sub) == 2 and sub.y[1].shape == (2, 100)
    np.testing.assert_array_equal(sub.y[0][1], rec.y[0][2])
    with pytest.raises(ValueError, match=r"steps and dt must be tuples of 2 entries"):
        records(fam, 3, steps=300, dt=0.01)


def test_warmup_records_start_mid_motion_with_their_true_state():
    # Oracle: python-control's forced_response from the recorded initial state over the window.
    fam = LegFamily(subsystem="stable")
    rec = records(fam, 3, steps=100, dt=0.01, excitation_kind="prbs", seed=5, warmup=150)
    assert rec.x0.shape == (3, 2) and np.all(np.abs(rec.x0).max(axis=1) > 0)
    t = np.arange(100) * 0.01
    for i in range(3):
        sys = control.ss(rec.systems.A[i], rec.systems.b[i][:, None], rec.systems.c[i][None], 0.0)
        ref = control.forced_response(sys, t, rec.u[i], X0=rec.x0[i]).outputs
        np.testing.assert_allclose(rec.y_clean[i], ref, rtol=1e-8, atol=1e-10 * abs(ref).max())
    assert rec.take([1]).x0.shape == (1, 2)
    assert records(fam, 2, steps=50, dt=0.01).x0 is None


def test_mixed_windows_step_inside_the_window():
    # A step drawn in the first quarter of warmup + window would have settled before the window
    # opens (a constant input, a flat record). Every mixed window must see its input change.
    fam = LegFamily(subsystem="stable")
    rec = records(fam, 400, steps=300, dt=0.01, excitation_kind="mix", seed=3, warmup=200)
    # constant only where the step falls on the window's first sample (1 in 75 step records)
    assert np.mean(np.ptp(rec.u, axis=1) == 0) < 0.02
    steps = np.ptp(rec.u, axis=1)[np.all(np.diff(rec.u, axis=1)[:, 75:] == 0, axis=1)]
    assert len(steps) > 50     # the step records: each steps in the window's first quarter
    u0 = excitation("mix", 400, 500, 0.01, np.random.default_rng(3))
    assert np.mean(np.ptp(u0[:, 200:], axis=1) == 0) > 0.15   # without first=: flat windows
    with pytest.raises(ValueError, match=r"warmup must be a non-negative integer; got -1"):
        records(fam, 2, steps=50, dt=0.01, warmup=-1)


def test_one_grid_rule_for_training_settings_and_records():
    from aeid_struct.simulation import simulate
    from aeid_struct.training import TrainConfig, grids

    assert grids(300, 0.01) == ((300, 0.01),)
    assert grids([150, 50], [0.02, 0.01], records=2) == ((150, 0.02), (50, 0.01))
    assert TrainConfig(dt=(0.02, 0.01), steps=[150, 50]).grids == ((150, 0.02), (50, 0.01))
    # Why at least two samples: a one-sample response of a strictly proper system from rest is
    # y_0 = c^T x_0 + d u_0 = 0 (closed form), nothing to identify and max|y| = 0 for Eq. 15.
    A, b, c = np.array([[-2.0]]), np.array([1.0]), np.array([3.0])
    assert simulate(A, b, c, 0.0, np.ones(1), 0.05).tolist() == [0.0]
    # the shortest grid works for both; one sample is refused by both with the same words
    assert records(PoleFamily(real=1, pairs=0), 3, steps=2, dt=0.05).y.shape == (3, 2)
    assert TrainConfig(dt=0.05, steps=2).grids == ((2, 0.05),)
    for make in (lambda: TrainConfig(dt=0.05, steps=1),
                 lambda: records(PoleFamily(real=1, pairs=0), 3, steps=1, dt=0.05)):
        with pytest.raises(ValueError, match=r"steps must be an integer >= 2.*; got 1"):
            make()
    cases = [
        ((300, 1), (0.01, 0.01), None, r"steps must be an integer >= 2 \(or a tuple of them, "
                                       r"one per record\); got \(300, 1\)"),
        (300, True, None, r"dt must be a positive finite number .*; got True"),
        (300, float("nan"), 1, r"dt must be a positive finite number; got nan"),
        ((300, 300), (0.01,), None, r"dt and steps must have one entry per record alike"),
        ((), (), None, r"dt and steps must have one entry per record alike; got dt=\(\)"),
        (300, 0.01, 2, r"steps and dt must be tuples of 2 entries \(one per record\)"),
        ((300, 300), (0.01, 0.01), 1, r"steps and dt must be single numbers for a family of "
                                      r"one record"),
        ((300, 2.5), (0.01, 0.01), 2, r"steps must be an integer >= 2 in each of the 2 entries"),
        (300.0, 0.01, None, r"steps must be an integer >= 2 .*; got 300.0"),
    ]
    for steps, dt, count, match in cases:
        with pytest.raises(ValueError, match=match):
            grids(steps, dt, count)


def test_step_excitation_is_the_unit_step_of_a_record_without_input():
    from aeid_struct.records import unit_step

    u = unit_step((2, 5))
    assert u.dtype == np.float64 and u.shape == (2, 5) and np.all(u == 1.0)
    assert unit_step(4).tolist() == [1.0] * 4
    np.testing.assert_array_equal(excitation("step", 2, 5, 0.1, np.random.default_rng(0)), u)
