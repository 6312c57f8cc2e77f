"""The generic families in normalised time (issue 14, deliver 3): records against scipy's FOH
simulation from the returned initial state, poles against the eigenvalues, the configured
distributions counted, the argument checks, and the properties each normalised-time excitation
claims."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from aeid_struct.training.excitation import GENERIC_EXCITATIONS, generic_excitation
from aeid_struct.training.generic_family import GenericFamily, GenericSystems


def _lsim(A, b, c, d, u, x0, dt=1.0):
    """scipy's FOH simulation (``interp=True``) of one system from ``x0``."""
    t = np.arange(u.size) * dt
    _, y, _ = scipy.signal.lsim((A, b[:, None], c[None, :], d), u, t, X0=x0, interp=True)
    return y


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_records_are_the_foh_response_from_x0(order):
    family = GenericFamily(order=order, max_delay=6, offset=0.3, noise=(0.01, 0.05))
    rec = family.records(24, 300, np.random.default_rng(order))
    s = rec.systems
    assert rec.y.shape == rec.y_clean.shape == rec.u.shape == rec.u_plant.shape == (24, 300)
    assert rec.x0.shape == (24, order) and rec.offsets.shape == (24, 2)
    for i in range(24):
        truth = _lsim(s.A[i], s.b[i], s.c[i], s.d[i], rec.u_plant[i], rec.x0[i])
        np.testing.assert_allclose(rec.y_clean[i] - rec.offsets[i, 1], truth, rtol=0, atol=1e-9)
        D = s.delay[i]
        # the delayed input: the plant sees the measured input (less its offset) D samples late
        np.testing.assert_allclose(rec.u_plant[i, D:], (rec.u[i] - rec.offsets[i, 0])[:300 - D],
                                   rtol=0, atol=1e-15)
    # c and d were scaled so that the clean output has std 1 before the offset
    np.testing.assert_allclose(rec.y_clean.std(axis=1), 1.0, rtol=1e-12)
    # the noise is white with the drawn relative level (std of 300 samples: within 25 %)
    ratio = (rec.y - rec.y_clean).std(axis=1) / rec.noise
    assert np.all(np.abs(ratio - 1) < 0.25) and np.all((rec.noise >= 0.01) & (rec.noise <= 0.05))
    assert np.any(s.delay > 0) and np.all((s.delay >= 0) & (s.delay <= 6))


def test_records_start_mid_motion_and_given_systems_are_used():
    family = GenericFamily(order=2, preroll=(50, 50))
    systems = family.sample(8, np.random.default_rng(0))
    rec = family.records(8, 200, np.random.default_rng(1), systems=systems)
    assert np.all(np.linalg.norm(rec.x0, axis=1) > 0)
    np.testing.assert_array_equal(rec.systems.A, systems.A)
    # the same systems up to the scale of the output
    scale = systems.c[:, :1] / rec.systems.c[:, :1]
    np.testing.assert_allclose(rec.systems.c * scale, systems.c, rtol=1e-12, atol=0)
    np.testing.assert_allclose(rec.systems.d * scale[:, 0], systems.d, rtol=1e-12, atol=0)


def test_at_dt_is_the_same_samples_at_another_sample_time():
    rec = GenericFamily(order=3).records(4, 200, np.random.default_rng(5))
    phys = rec.at(0.08)
    s, p = rec.systems, phys.systems
    np.testing.assert_allclose(p.A, s.A / 0.08, rtol=1e-15)
    np.testing.assert_allclose(p.b, s.b / 0.08, rtol=1e-15)
    np.testing.assert_allclose(p.poles, s.poles / 0.08, rtol=1e-15)
    assert p.dt == 0.08 and np.array_equal(p.c, s.c) and np.array_equal(phys.y, rec.y)
    for i in range(4):
        truth = _lsim(p.A[i], p.b[i], p.c[i], p.d[i], rec.u_plant[i], rec.x0[i], dt=0.08)
        np.testing.assert_allclose(rec.y_clean[i] - rec.offsets[i, 1], truth, atol=1e-9)
    np.testing.assert_allclose(p.at(1.0).A, s.A, rtol=1e-14)
    with pytest.raises(ValueError, match="dt must be a positive"):
        s.at(0.0)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_poles_are_the_eigenvalues_and_in_the_band(order):
    s = GenericFamily(order=order).sample(400, np.random.default_rng(10 + order))
    assert isinstance(s, GenericSystems) and s.poles.shape == (400, order)
    np.testing.assert_array_equal(s.b, np.tile(np.eye(order)[-1], (400, 1)))
    for A, poles in zip(s.A, s.poles, strict=True):
        for found in (np.linalg.eigvals(A), np.roots(np.r_[1.0, -A[-1, ::-1]])):
            gap = np.abs(found[:, None] - poles[None, :]).min(axis=0) / np.abs(poles)
            assert gap.max() < 1e-9
    assert np.all(s.poles.real < 0)
    # a real pole of an odd order: magnitude in the band
    if order % 2:
        last = -s.poles[:, -1].real
        assert np.all((last >= 0.005) & (last <= 2.5)) and np.all(s.poles[:, -1].imag == 0)


def test_distributions_as_configured():
    n, N = 4, 2000
    family = GenericFamily(order=n, damping=(0.01, 0.9), real_fraction=0.3, feedthrough=0.2,
                           max_delay=3)
    s = family.sample(N, np.random.default_rng(3))
    # relative degree: the highest nonzero numerator coefficient, uniform in 1..n
    top = np.array([np.flatnonzero(c).max() for c in s.c])
    counts = np.bincount(n - top, minlength=n + 1)[1:]
    assert np.all(np.abs(counts - N / n) < 5 * np.sqrt(N * 0.25 * 0.75)), counts
    # the gain's sign (leading numerator coefficient): either with probability 1/2
    positive = np.sum(s.c[np.arange(N), top] > 0)
    assert abs(positive - N / 2) < 5 * np.sqrt(N / 4), positive
    # feedthrough share, and |d| in 0.2..1
    has_d = s.d != 0
    assert abs(has_d.sum() - 0.2 * N) < 5 * np.sqrt(N * 0.16)
    assert np.all((np.abs(s.d[has_d]) >= 0.2) & (np.abs(s.d[has_d]) <= 1.0))
    # damping < 1: a pair is real only when drawn so (real_fraction per pair)
    real_pairs = np.sum(s.poles[:, [0, 2]].imag == 0)
    assert abs(real_pairs - 0.3 * 2 * N) < 5 * np.sqrt(2 * N * 0.21), real_pairs
    # delays uniform in 0..3
    assert np.all(np.abs(np.bincount(s.delay, minlength=4) - N / 4) < 5 * np.sqrt(N * 3 / 16))
    # the numerator's zeros include right-half-plane ones (non-minimum phase)
    zeros = [np.roots(c[: t + 1][::-1]) for c, t in zip(s.c, top, strict=True) if t > 0]
    assert 0.1 < np.mean([np.any(z.real > 0) for z in zeros]) < 0.6
    # without zeros: all-pole, relative degree n
    allpole = GenericFamily(order=3, zeros=False).sample(200, np.random.default_rng(0))
    assert np.all(allpole.c[:, 1:] == 0) and np.all(allpole.c[:, 0] != 0)


def test_numerator_scaled_to_peak_gain_one():
    s = GenericFamily(order=2, zeros=True).sample(50, np.random.default_rng(8))
    w = np.logspace(-4, np.log10(np.pi), 2000)
    for i in range(50):
        _, h = scipy.signal.freqs(s.c[i, ::-1], np.r_[1.0, -s.A[i, -1, ::-1]], worN=w)
        # the scaling grid is coarser than this one (with each |pole| added): a peak between its
        # points may stand a little above 1
        assert 0.9 < np.abs(h).max() < 1.05


def test_deterministic_for_a_seed():
    family = GenericFamily(order=4, max_delay=4, offset=0.1)
    r1 = family.records(16, 128, np.random.default_rng(42))
    r2 = family.records(16, 128, np.random.default_rng(42))
    r3 = family.records(16, 128, np.random.default_rng(43))
    for name in ("y", "y_clean", "u", "u_plant", "x0", "noise", "offsets"):
        np.testing.assert_array_equal(getattr(r1, name), getattr(r2, name))
    np.testing.assert_array_equal(r1.systems.A, r2.systems.A)
    assert not np.array_equal(r1.y, r3.y)


@pytest.mark.parametrize("field, value, match", [
    ("order", 0, "order must be an integer in 1..8"),
    ("order", 9, "order must be an integer in 1..8"),
    ("order", True, "order must be an integer in 1..8"),
    ("band", (0.0, 1.0), "band must have lo > 0"),
    ("band", (2.0, 1.0), "band must satisfy lo <= hi"),
    ("band", "ab", "band must be a"),
    ("damping", (-0.1, 1.0), "damping must have lo > 0"),
    ("real_fraction", 1.5, "real_fraction must be a number in"),
    ("zeros", 1, "zeros must be a bool"),
    ("feedthrough", -0.1, "feedthrough must be a number in"),
    ("max_delay", -1, "max_delay must be an integer >= 0"),
    ("max_delay", 1.5, "max_delay must be an integer >= 0"),
    ("noise", (-0.1, 0.1), "noise must have lo >= 0"),
    ("noise", (np.nan, 0.1), "noise must satisfy"),
    ("excitations", ("prbs", "ramp"), "excitations must be a non-empty tuple"),
    ("excitations", (), "excitations must be a non-empty tuple"),
    ("excitations", "prbs", "excitations must be a non-empty tuple"),
    ("preroll", (-1, 3), "preroll must be a"),
    ("preroll", (0.5, 3), "preroll must be a"),
    ("offset", -1.0, "offset must be a finite number >= 0"),
    ("offset", float("inf"), "offset must be a finite number >= 0"),
    ("integrating", 1.5, "integrating must be a number in"),
    ("unstable", -0.1, "unstable must be a number in"),
    ("growth", (0.0, 0.01), "growth must have lo > 0"),
])
def test_bad_fields_raise_naming_the_field(field, value, match):
    with pytest.raises(ValueError, match=match):
        GenericFamily(**({"order": 2} | {field: value}))


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_integrating_and_unstable_shares(order):
    family = GenericFamily(order=order, integrating=0.3, unstable=0.4, growth=(1e-3, 4e-3))
    s = family.sample(3000, np.random.default_rng(order))
    top = s.poles.real.max(axis=1)
    integ, unst = top == 0.0, top > 0
    assert abs(integ.mean() - 0.3) < 0.04 and abs(unst.mean() - 0.4) < 0.04
    # the unstable real parts are in the growth range, every other pole is stable, one per
    # system (a pair counts once)
    assert np.all((top[unst] >= 1e-3) & (top[unst] <= 4e-3))
    rest = np.sort(s.poles.real, axis=1)[:, : order - 2 if order > 1 else 0]
    assert np.all(rest < 0)
    if order >= 2:                                   # both a real and a growing oscillation
        growing = s.poles[unst][np.arange(unst.sum()), np.argmax(s.poles[unst].real, axis=1)]
        assert 0.4 < np.mean(growing.imag != 0) < 0.6
    for i in range(0, 3000, 97):                     # the CCF has these poles
        np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(s.A[i])),
                                   np.sort_complex(s.poles[i]), atol=1e-9)
    rec = family.records(40, 500, np.random.default_rng(9))
    assert np.isfinite(rec.y).all()
    np.testing.assert_allclose(rec.y_clean.std(axis=1), 1.0, rtol=1e-12)
    for i in range(5):                               # still the FOH response from x0
        truth = _lsim(rec.systems.A[i], rec.systems.b[i], rec.systems.c[i], rec.systems.d[i],
                      rec.u_plant[i], rec.x0[i])
        np.testing.assert_allclose(rec.y_clean[i], truth, rtol=0, atol=1e-7)


def test_stable_family_draws_as_before_the_shares():
    # the shares draw nothing unless asked: the shipped identifiers' held-out windows and the
    # benchmark's systems are the same draws
    rng = np.random.default_rng(5)
    y = GenericFamily(order=3, unstable=0.0).records(3, 100, rng).y
    assert y.sum() == pytest.approx(-491.05258273499425, rel=1e-12)   # before the shares


def test_shares_must_sum_to_at_most_one():
    with pytest.raises(ValueError, match="integrating \\+ unstable must be at most 1"):
        GenericFamily(order=2, integrating=0.6, unstable=0.5)


def test_bad_arguments_of_sample_and_records():
    family = GenericFamily(order=2)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="count must be a positive integer"):
        family.sample(0, rng)
    with pytest.raises(ValueError, match="rng must be a numpy.random.Generator"):
        family.sample(3, 1)
    with pytest.raises(ValueError, match="steps must be an integer >= 2"):
        family.records(3, 1, rng)
    other = GenericFamily(order=3).sample(3, rng)
    with pytest.raises(ValueError, match="systems must be GenericSystems of 3 systems of order 2"):
        family.records(3, 100, rng, systems=other)
    with pytest.raises(ValueError, match="systems must be GenericSystems of 4 systems"):
        family.records(4, 100, rng, systems=family.sample(3, rng))
    with pytest.raises(ValueError, match=r"normalised time \(dt = 1\)"):
        family.records(3, 100, rng, systems=family.sample(3, rng).at(0.1))


# ---------------------------------------------------------------------------------------------
# the normalised-time excitations
# ---------------------------------------------------------------------------------------------

def _runs(row):
    """Lengths and values of the runs of equal samples of one row."""
    change = np.flatnonzero(np.diff(row) != 0) + 1
    edges = np.r_[0, change, row.size]
    return np.diff(edges), row[edges[:-1]]


def test_prbs_is_plus_minus_one_on_a_clock():
    u = generic_excitation("prbs", 50, 1000, np.random.default_rng(0))
    assert set(np.unique(u)) == {-1.0, 1.0}
    for row in u:
        lengths, _ = _runs(row)
        inner = lengths[1:-1]               # the first and last runs are cut by the record
        assert inner.size >= 3 and np.all(inner % inner.min() == 0)


def test_staircase_is_piecewise_constant_with_uniform_levels():
    u = generic_excitation("staircase", 200, 1000, np.random.default_rng(1))
    levels, holds = [], []
    for row in u:
        lengths, values = _runs(row)
        levels.append(values)
        holds.append(np.median(lengths))
    levels = np.concatenate(levels)
    assert np.all(np.abs(levels) <= 1.0)
    assert abs(levels.mean()) < 0.05 and abs(levels.var() - 1 / 3) < 0.03
    # holds spread over 1..steps/8 samples (log-uniform mean): short and long staircases
    assert min(holds) <= 2 and max(holds) >= 50


def test_multisine_stays_in_its_band():
    lo, hi = 0.2, 0.4
    u = generic_excitation("multisine", 20, 4096, np.random.default_rng(2), band=(lo, hi))
    assert np.allclose(np.abs(u).max(axis=1), 1.0)
    power = np.abs(np.fft.rfft(u * np.hanning(4096), axis=1)) ** 2
    w = np.linspace(0, np.pi, power.shape[1])
    inside = (w > 0.9 * lo) & (w < 1.1 * hi)
    assert np.all(power[:, inside].sum(axis=1) / power.sum(axis=1) > 0.999)


def test_chirp_frequency_increases():
    u = generic_excitation("chirp", 10, 4000, np.random.default_rng(3), band=(0.02, 0.5))
    assert np.all(np.abs(u) <= 1.0)
    for row in u:
        # zero crossings, linearly interpolated: the half periods shrink along the record
        k = np.flatnonzero(np.sign(row[:-1]) != np.sign(row[1:]))
        crossing = k + row[k] / (row[k] - row[k + 1])
        half = np.diff(crossing)
        assert half.size > 10 and np.all(np.diff(half) < 0.05)


def test_chirp_holds_its_start_frequency_before_first():
    u = generic_excitation("chirp", 5, 3000, np.random.default_rng(4), first=1500,
                           band=(0.05, 0.5))
    for row in u:
        k = np.flatnonzero(np.sign(row[:1499]) != np.sign(row[1:1500]))
        crossing = k + row[k] / (row[k] - row[k + 1])
        assert np.ptp(np.diff(crossing)) < 0.05       # one frequency before the sweep


def test_filtered_noise_is_low_pass():
    u = generic_excitation("filtered", 40, 4096, np.random.default_rng(5), band=(0.05, 0.05))
    white = np.random.default_rng(6).normal(size=(40, 4096))
    w = np.linspace(0, np.pi, 4096 // 2 + 1)
    for x, most in ((u, 0.1), (white, None)):
        power = np.abs(np.fft.rfft(x, axis=1)) ** 2
        high = power[:, w > 1.0].sum(axis=1) / power.sum(axis=1)
        if most is None:
            assert np.all(high > 0.5)                    # white noise: most power above 1
        else:
            assert np.all(high < most)
    assert np.allclose(np.abs(u).max(axis=1), 1.0)


def test_step_is_one_step_of_random_level_in_the_record():
    u = generic_excitation("step", 300, 400, np.random.default_rng(7), first=100)
    for row in u:
        lengths, values = _runs(row)
        assert values.size == 2 and abs(values[0]) <= 1.0
        assert 0.5 <= abs(values[1] - values[0]) <= 1.0 + 1e-15
        assert 100 <= lengths[0] < 100 + 150
    jumps = u[:, -1] - u[:, 0]
    assert 0.35 < np.mean(jumps > 0) < 0.65


@pytest.mark.parametrize("kind", GENERIC_EXCITATIONS)
def test_excitations_deterministic_and_shaped(kind):
    a = generic_excitation(kind, 7, 300, np.random.default_rng(9), first=50)
    b = generic_excitation(kind, 7, 300, np.random.default_rng(9), first=50)
    assert a.shape == (7, 300) and np.array_equal(a, b) and np.all(np.isfinite(a))
    assert generic_excitation(kind, 0, 300, np.random.default_rng(9)).shape == (0, 300)


@pytest.mark.parametrize("kwargs, match", [
    ({"kind": "ramp"}, "kind must be one of"),
    ({"count": -1}, "count must be an integer >= 0"),
    ({"steps": 0}, "steps must be a positive integer"),
    ({"first": 300}, "first must be an integer in"),
    ({"band": (0.1, 4.0)}, r"band must satisfy 0 < lo <= hi <= pi"),
    ({"band": (0.0, 1.0)}, r"band must satisfy 0 < lo <= hi <= pi"),
    ({"rng": 0}, "rng must be a numpy.random.Generator"),
])
def test_generic_excitation_bad_arguments(kwargs, match):
    args = {"kind": "prbs", "count": 2, "steps": 300, "rng": np.random.default_rng(0)} | kwargs
    with pytest.raises(ValueError, match=match):
        generic_excitation(**args)
