"""The user's measured record ``ae.Record`` (issue 14 deliver 1): validation once, the time
axis, detrending, the estimation/validation split and the delay alignment.

Oracles: hand-computed numbers on short records, and ``numpy.polyfit`` for the linear trend.
"""

from __future__ import annotations

import numpy as np
import pytest

import aeid_struct as ae
from aeid_struct.records import Record

Y = np.array([1.0, 3.0, 2.0, 6.0])
U = np.array([0.0, 1.0, 1.0, 2.0])


def _record(**kw):
    return Record(Y, U, 0.5, **{"name": "lab", **kw})


def test_top_level_name_is_the_records_class():
    assert ae.Record is Record
    assert "Record" in ae.__all__


def test_arrays_are_read_only_float64_copies():
    y = [1, 2, 3]                                       # ints in, float64 out
    u = np.array([1.0, 0.0, 1.0])
    r = Record(y, u, 0.1)
    assert r.y.dtype == np.float64 and r.u.dtype == np.float64
    np.testing.assert_array_equal(r.y, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="read-only"):
        r.y[0] = 5.0
    with pytest.raises(ValueError, match="read-only"):
        r.u[0] = 5.0
    u[0] = 7.0                                          # the caller's array is not shared
    assert r.u[0] == 1.0


def test_defaults_unit_step_and_unknown_delay():
    r = Record([0.0, 1.0, 2.0])
    np.testing.assert_array_equal(r.u, [1.0, 1.0, 1.0])
    assert (r.dt, r.delay, r.name, r.t0, r.y_offset, r.u_offset) == (1.0, None, "", 0.0, 0.0,
                                                                     0.0)


def test_steps_time_axis_len_and_repr():
    r = _record(t0=2.0, delay=1, y_offset=0.25)
    assert r.steps == 4 and len(r) == 4
    np.testing.assert_array_equal(r.t, [2.0, 2.5, 3.0, 3.5])
    assert repr(r) == ("Record(name='lab', steps=4, dt=0.5, delay=1, y_offset=0.25, "
                       "u_offset=0)")


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"y": [1.0]}, r"y must have shape \(steps,\) or \(steps, outputs\) with steps >= 2.*\(1,\)"),
    ({"y": np.ones((2, 3))}, r"y must have shape \(steps,\).*\(2, 3\)"),
    ({"y": [1.0, np.nan, 2.0]}, "y must be finite; got nan at sample 1"),
    ({"y": [1.0 + 1j, 2.0]}, "y must be real; got a complex array"),
    ({"y": ["a", "b"]}, "y must be an array of real numbers"),
    ({"y": None}, "y must be an array of real numbers; got None"),
    ({"u": [1.0, 2.0]}, "u must have as many samples as y \\(4\\); got 2"),
    ({"u": [1.0, np.inf, 0.0, 1.0]}, "u must be finite; got inf at sample 1"),
    ({"u": np.array([1, 2, 3, 4]) * 1j}, "u must be real"),
    ({"dt": 0.0}, "dt must be a positive finite number; got 0.0"),
    ({"dt": "0.1"}, "dt must be a positive finite number; got '0.1'"),
    ({"delay": 4}, "delay must be >= 0 and < steps = 4; got 4"),
    ({"delay": -1}, "delay must be >= 0 and < steps = 4; got -1"),
    ({"delay": 1.0}, "delay must be None \\(unknown\\) or an integer number of samples; got 1.0"),
    ({"delay": True}, "delay must be None"),
    ({"name": 3}, "name must be a str; got int"),
    ({"t0": np.nan}, "t0 must be a finite number; got nan"),
    ({"y_offset": "1"}, "y_offset must be a finite number; got '1'"),
    ({"u_offset": np.inf}, "u_offset must be a finite number; got inf"),
])
def test_bad_arguments_are_named(kwargs, match):
    args = {"y": Y, "u": U, "dt": 0.5, **kwargs}
    with pytest.raises(ValueError, match=match):
        Record(args.pop("y"), args.pop("u"), args.pop("dt"), **args)


def test_frozen():
    r = _record()
    with pytest.raises(AttributeError):
        r.dt = 2.0


def test_detrend_mean():
    r = _record(y_offset=1.0, u_offset=-1.0).detrend("mean")
    # mean(Y) = 3, mean(U) = 1
    np.testing.assert_allclose(r.y, [-2.0, 0.0, -1.0, 3.0], atol=1e-15)
    np.testing.assert_allclose(r.u, [-1.0, 0.0, 0.0, 1.0], atol=1e-15)
    assert (r.y_offset, r.u_offset) == (4.0, 0.0)
    assert (r.dt, r.name, r.t0) == (0.5, "lab", 0.0)
    assert _record().detrend().y_offset == 3.0          # "mean" is the default


def test_detrend_initial():
    r = _record().detrend("initial")
    np.testing.assert_array_equal(r.y, [0.0, 2.0, 1.0, 5.0])
    np.testing.assert_array_equal(r.u, [0.0, 1.0, 1.0, 2.0])
    assert (r.y_offset, r.u_offset) == (1.0, 0.0)


def test_detrend_linear_removes_the_least_squares_line():
    # Y on k = 0..3: slope = sum (k - 1.5)(y - 3) / sum (k - 1.5)^2 = 7 / 5 = 1.4,
    # intercept = 3 - 1.4 * 1.5 = 0.9
    r = _record().detrend("linear")
    line = 0.9 + 1.4 * np.arange(4)
    np.testing.assert_allclose(r.y, Y - line, atol=1e-14)
    np.testing.assert_allclose(np.polyfit(np.arange(4), r.y, 1), [0.0, 0.0], atol=1e-14)
    np.testing.assert_allclose(r.u, U - 1.0, atol=1e-15)
    assert r.y_offset == pytest.approx(0.9, abs=1e-14) and r.u_offset == 1.0
    # the offsets accumulate over detrends
    assert r.detrend("initial").y_offset == pytest.approx(0.9 + 0.1, abs=1e-14)


def test_detrend_bad_kind():
    with pytest.raises(ValueError, match=r"kind must be one of \('mean', 'initial', 'linear'\); "
                                         r"got 'quadratic'"):
        _record().detrend("quadratic")


def test_split_by_fraction_and_index():
    r = Record(np.arange(10.0), np.arange(10.0) * 2, 0.1, name="run", t0=1.0, delay=1,
               y_offset=0.5, u_offset=-0.5)
    est, val = r.split(0.7)
    np.testing.assert_array_equal(est.y, np.arange(7.0))
    np.testing.assert_array_equal(val.u, [14.0, 16.0, 18.0])
    assert val.t0 == pytest.approx(1.7) and est.t0 == 1.0
    np.testing.assert_allclose(np.concatenate([est.t, val.t]), r.t, atol=1e-15)
    assert (est.name, val.name) == ("run (estimation)", "run (validation)")
    for part in (est, val):
        assert (part.dt, part.delay, part.y_offset, part.u_offset) == (0.1, 1, 0.5, -0.5)
    est, val = r.split(at=3)
    assert (est.steps, val.steps) == (3, 7)
    est, val = r.split()                                # default: halves
    assert (est.steps, val.steps) == (5, 5)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"fraction": 0.0}, r"fraction must be in \(0, 1\); got 0.0"),
    ({"fraction": 1.5}, r"fraction must be in \(0, 1\); got 1.5"),
    ({"fraction": "half"}, "fraction must be a finite number; got 'half'"),
    ({"fraction": 0.05}, r"each part at least 2 samples .*at must be in \[2, 8\]; got 0"),
    ({"at": 9}, r"at must be in \[2, 8\]; got 9"),
    ({"at": 2.0}, "at must be an integer sample index; got 2.0"),
])
def test_split_bad_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Record(np.arange(10.0)).split(**kwargs)


def test_split_keeps_more_samples_than_the_delay():
    with pytest.raises(ValueError, match=r"at least 4 samples \(steps = 10, delay = 3\)"):
        Record(np.arange(10.0), delay=3).split(at=3)


def test_shifted_pairs_y_late_with_u_early():
    r = Record([1.0, 2.0, 3.0, 4.0, 5.0], [10.0, 20.0, 30.0, 40.0, 50.0], 0.5, t0=1.0,
               delay=2, y_offset=0.1)
    s = r.shifted()
    np.testing.assert_array_equal(s.y, [3.0, 4.0, 5.0])
    np.testing.assert_array_equal(s.u, [10.0, 20.0, 30.0])
    assert (s.delay, s.t0, s.dt, s.y_offset) == (0, 2.0, 0.5, 0.1)
    s = r.shifted(1)                                    # an explicit delay wins
    np.testing.assert_array_equal(s.y, [2.0, 3.0, 4.0, 5.0])
    np.testing.assert_array_equal(s.u, [10.0, 20.0, 30.0, 40.0])
    np.testing.assert_array_equal(r.shifted(0).y, r.y)


@pytest.mark.parametrize(("delay", "match"), [
    (None, r"delay must be given: the record's delay is unknown \(None\)"),
    (4, r"delay must be an integer in \[0, 3\] \(2 samples left\); got 4"),
    (-1, r"delay must be an integer in \[0, 3\].*got -1"),
    (1.5, r"delay must be an integer in \[0, 3\].*got 1.5"),
])
def test_shifted_bad_delay(delay, match):
    with pytest.raises(ValueError, match=match):
        Record(np.arange(5.0)).shifted(delay)


def test_with_delay_sets_and_checks_the_delay():
    r = _record()
    assert r.with_delay(2).delay == 2 and r.delay is None
    assert r.with_delay(2).with_delay(None).delay is None
    np.testing.assert_array_equal(r.with_delay(3).y, Y)
    with pytest.raises(ValueError, match="delay must be >= 0 and < steps = 4; got 7"):
        r.with_delay(7)


def test_exact_scale_is_a_power_of_two_only_outside_the_safe_range():
    from aeid_struct.records import exact_scale

    assert exact_scale(np.array([0.3, -2.0])) == 1.0
    assert exact_scale(np.zeros(4)) == 1.0
    for peak in (1e-200, 3e-30, 7e25, 1e300):
        s = exact_scale(np.array([peak, -peak / 3]))
        mantissa, _ = np.frexp(s)
        assert mantissa == 0.5 and 0.5 <= peak / s <= 1.0 if abs(np.log2(peak)) > 64 else s == 1


def test_units_carry_the_same_digits_and_the_removed_level():
    from aeid_struct.records import Units, exact_scale

    rng = np.random.default_rng(0)
    y, u = rng.standard_normal(50) * 1e-200, rng.standard_normal(50) * 1e200 + 1e205
    rec = Record(y, u, 0.1, y_offset=3e-200)
    units = Units.of(rec)
    # the output's mean is within its variation (kept), the input's level far above it
    assert units.y_level == 0.0 and units.u_level == np.mean(u)
    assert units.sy == exact_scale(y) < 1e-190 and units.su == exact_scale(u - np.mean(u))
    s = units.apply(rec)
    np.testing.assert_array_equal(s.y * units.sy, y)             # exact: only exponents move
    np.testing.assert_array_equal(s.u * units.su, u - units.u_level)
    assert s.y_offset * units.sy == 3e-200 and s.u_offset * units.su == units.u_level
    ordinary = Record(np.linspace(0, 1, 9), np.arange(9.0), 1.0)
    assert Units.of(ordinary).identity and Units.of(ordinary).apply(ordinary) is ordinary


def test_a_column_is_one_channel_and_several_channels_are_kept():
    y = np.linspace(0, 1, 20)
    assert Record(y[:, None], y[::-1, None], 0.1).y.shape == (20,)
    rec = Record(np.stack([y, y**2], 1), np.stack([y[::-1], np.sin(y), y], 1), 0.1,
                 y_offset=[1.0, 2.0], u_offset=0.5)
    assert (rec.outputs, rec.inputs, rec.Y.shape, rec.U.shape) == (2, 3, (20, 2), (20, 3))
    np.testing.assert_array_equal(rec.u_offset, [0.5, 0.5, 0.5])
    one = rec.channel(1, 1)
    assert (one.outputs, one.inputs, one.y_offset, one.u_offset) == (1, 1, 2.0, 0.5)
    np.testing.assert_array_equal(one.y, y**2)
    np.testing.assert_array_equal(one.u, np.sin(y))
    with pytest.raises(ValueError, match=r"^input must be an integer in \[0, 3\) \(the record "
                                         r"has 3 inputs\); got 3"):
        rec.channel(0, 3)
    with pytest.raises(ValueError, match=r"^y must have shape \(steps,\) or \(steps, outputs\) "
                                         r"with more samples than outputs; got shape \(2, 20\)"):
        Record(np.stack([y, y]), None, 0.1)
    with pytest.raises(ValueError, match=r"^y_offset must be a number or a \(2,\) array"):
        Record(np.stack([y, y], 1), y, 0.1, y_offset=[1.0, 2.0, 3.0])


def test_detrend_works_per_channel():
    k = np.arange(50.0)
    y = np.stack([3.0 + 0.5 * k + np.sin(k), -2.0 + np.cos(k)], 1)
    u = np.stack([np.sin(0.3 * k) + 4.0, np.cos(0.2 * k)], 1)
    rec = Record(y, u, 0.1)
    for kind in ("mean", "initial", "linear"):
        many = rec.detrend(kind)
        for i in range(2):
            one = rec.channel(i, i).detrend(kind)
            np.testing.assert_allclose(many.Y[:, i], one.y, rtol=0, atol=1e-12)
            np.testing.assert_allclose(many.U[:, i], one.u, rtol=0, atol=1e-12)
            assert many.y_offset[i] == pytest.approx(one.y_offset, abs=1e-12)
            assert many.u_offset[i] == pytest.approx(one.u_offset, abs=1e-12)


def test_identifiers_of_one_channel_refuse_several_by_name():
    y = np.random.default_rng(0).normal(size=(60, 2))
    rec = Record(y, y[:, 0], 0.1)
    with pytest.raises(ValueError, match=r"^ae.load\(...\).identify identifies one output from "
                                         r"one input; the record has 2 outputs and 1 inputs"):
        rec.require_siso("ae.load(...).identify")
    rec.channel(1).require_siso("x")
    with pytest.raises(ValueError, match=r"^y is constant \(output 1\)"):
        Record(np.stack([y[:, 0], np.ones(60)], 1), y[:, 1], 0.1).require_informative()


def test_require_informative_names_the_constant_signal():
    y = np.linspace(0, 1, 20)
    Record(y, y[::-1], 0.1).require_informative()
    with pytest.raises(ValueError, match=r"^y is constant \(every sample is 2\.5\)"):
        Record(np.full(20, 2.5), y, 0.1).require_informative()
    with pytest.raises(ValueError, match=r"^u is constant over the whole record"):
        Record(y, np.ones(20), 0.1).require_informative()


def test_denormalise_scales_the_output_elements_by_the_gain_exactly():
    from aeid_struct.records import denormalise

    c = np.array([[1.0, 2.0], [3.0, -4.0]])
    d = np.array([0.5, -0.25])
    el = np.array([[7.0, 1.0, 2.0, 0.5], [8.0, 3.0, -4.0, -0.25]])     # a0, c0, c1, d
    output = np.array([False, True, True, True])
    gain = np.array([1e-44, 3.0])
    c2, d2, el2 = denormalise(c, d, el, gain, output)
    np.testing.assert_array_equal(c2, c * gain[:, None])
    np.testing.assert_array_equal(d2, d * gain)
    np.testing.assert_array_equal(el2[:, 0], el[:, 0])                  # a0 is not an output
    np.testing.assert_array_equal(el2[:, 1:], el[:, 1:] * gain[:, None])
    assert el2[0, 1] == 1e-44            # a product: el * (1 + (gain - 1)) would give 0 here
    big = denormalise(c, d, el, np.array([1e308, 1.0]), output)[0]
    assert np.isinf(big[0, 1]) and big[1, 1] == -4.0                   # left to the check
