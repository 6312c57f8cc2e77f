"""generic.feedback: the closed-loop test of ``ae.identify`` (residuals against later,
prewhitened inputs). Oracles: the plain correlation coefficient of white signals (numpy), a PI
loop simulated sample by sample around a python-control ZOH discretisation, open-loop records
of the generic family."""

import warnings

import numpy as np
import pytest
from problems import pi_loop, pi_loop_2x2

import aeid_struct as ae
from aeid_struct.generic import FeedbackWarning, feedback_test
from aeid_struct.training import GenericFamily


@pytest.mark.parametrize("seed", [0, 1])
def test_closed_loop_record_is_flagged(seed):
    record = pi_loop(0.05, seed)
    with pytest.warns(FeedbackWarning, match="closed-loop"):
        est = ae.identify(record, order=2)
    found = est.info["feedback"]
    assert found["detected"] and found["statistic"] > 2 * found["bound"]
    assert found["lag"] == 1            # the controller acts on the sample it measured


def test_closed_loop_refit_without_feedthrough_removes_the_bias():
    """Under a controller acting on the sample it measures, a free ``d`` takes up the noise
    fed back through ``u_k``: the default structure is identified again without it, and its
    poles are unbiased (10 % white noise, 4 records: the mean error against the true
    ``-0.4 +- 0.9165j``); a structure the caller names keeps its ``d``, flagged."""
    true = -0.4 - 0.9165j
    default, kept = [], []
    for seed in range(4):
        record = pi_loop(0.1, seed)
        with pytest.warns(FeedbackWarning, match="no direct feedthrough"):
            est = ae.identify(record, order=2)
        assert est.d == 0.0 and est.info["feedback"]["refit"] == "no feedthrough"
        default.append(np.sort_complex(np.linalg.eigvals(est.A))[0] - true)
        with pytest.warns(FeedbackWarning, match="takes up the noise"):
            named = ae.identify(record, order=2, structure=ae.CCF(2, feedthrough=True))
        assert "refit" not in named.info["feedback"] and named.d != 0.0
        kept.append(np.sort_complex(np.linalg.eigvals(named.A))[0] - true)
    assert abs(np.mean(default)) < 0.01
    assert abs(np.mean(kept)) > 0.02


def test_open_loop_records_are_not_flagged():
    rng = np.random.default_rng(3)
    tested = 0
    for order, kind in [(1, {}), (2, {}), (3, {}), (2, {"integrating": 1.0})]:
        family = GenericFamily(order=order, max_delay=5, noise=(0.01, 0.1), offset=0.5, **kind)
        for steps in (400, 1000):
            recs = family.records(1, steps, rng)
            with warnings.catch_warnings():
                warnings.simplefilter("error", FeedbackWarning)
                est = ae.identify(ae.Record(recs.y[0], recs.u[0], 0.01), order=order)
            found = est.info["feedback"]
            assert found is not None and not found["detected"]
            tested += 1
    assert tested == 8


def test_statistic_is_the_correlation_of_white_signals():
    """With a white input the prewhitening leaves it (nearly) as it is: the statistic is
    ``|corr(e_k, u_{k+3})| sqrt(N)`` at lag 3 where ``u`` carries ``e`` three samples late."""
    rng = np.random.default_rng(0)
    N = 4000
    e, w = rng.standard_normal(N), rng.standard_normal(N)
    u = w.copy()
    u[3:] += 0.3 * e[:-3]
    found = feedback_test(e, np.zeros(N), u)
    rho = np.corrcoef(e[:-3], u[3:])[0, 1]
    assert found["lag"] == 3 and found["detected"]
    assert found["statistic"] == pytest.approx(abs(rho) * np.sqrt(N), rel=0.05)
    # the same signals without the feedback path: no detection
    assert not feedback_test(e, np.zeros(N), w)["detected"]


def test_nothing_to_test():
    rng = np.random.default_rng(1)
    y, u = rng.standard_normal(200), rng.standard_normal(200)
    assert feedback_test(y[:60], np.zeros(60), u[:60]) is None          # too short
    assert feedback_test(y, np.zeros(200), np.ones(200)) is None        # constant input
    assert feedback_test(y, y + 1e-6 * u, u) is None                    # residual ~ 0
    # samples without a model output (before the delay) are left out with their input
    y_hat = np.zeros(200)
    y_hat[:150] = np.nan
    assert feedback_test(y, y_hat, u) is None
    with pytest.raises(ValueError, match=r"y, y_hat and u must be \(steps,\) arrays"):
        feedback_test(y, y_hat, u[:100])


def test_the_one_pass_is_not_tested():
    est = ae.identify(pi_loop(0.05, 0), order=2, refine=False)
    assert est.info["feedback"] is None


def test_warnings_name_the_callers_line():
    """The warnings of ae.identify point at the caller, however deep in the library they are
    raised (the thread limit's wrapper, the pipeline, the fit stage)."""
    with pytest.warns(FeedbackWarning) as caught:
        ae.identify(pi_loop(0.05, 0), order=2)
    assert caught[0].filename == __file__


def test_closed_loop_several_channels_are_identified_without_feedthrough():
    """A 2x2 plant under decentralised PI control (10 % white noise): the free D takes up the
    noise fed back and biases the poles (mean absolute error over two records 0.079
    measured); the test of every output against every input finds the loop, and the model
    identified again without D has the true poles (0.0055 measured)."""
    from aeid_struct.multi import identify as identify_multi

    free, refit = [], []
    for seed in range(2):
        record, true = pi_loop_2x2(0.1, seed)
        true = np.sort_complex(true)
        with pytest.warns(FeedbackWarning, match=r"closed-loop: .*\(output \d against input "
                                                 r"\d\).*no direct feedthrough \(D = 0\)"):
            est = ae.identify(record, order=4)
        found = est.info["feedback"]
        assert found["detected"] and found["refit"] == "no feedthrough"
        assert found["statistic"] > 2 * found["bound"] and found["lag"] == 1
        np.testing.assert_array_equal(est.D, np.zeros((2, 2)))
        refit.append(np.abs(np.sort_complex(np.linalg.eigvals(est.A)) - true).mean())
        plain = identify_multi(record, 4)           # the same fit with a free D, untested
        assert np.abs(plain.D).max() > 0.02
        free.append(np.abs(np.sort_complex(np.linalg.eigvals(plain.A)) - true).mean())
    assert np.mean(refit) < 0.03 and np.mean(free) > 3 * np.mean(refit)


def test_open_loop_several_channels_are_not_flagged():
    record, _ = pi_loop_2x2(0.05, 0, closed=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FeedbackWarning)
        est = ae.identify(record, order=4)
    found = est.info["feedback"]
    assert found is not None and not found["detected"] and "refit" not in found
    assert (found["output"], found["input"]) in {(i, j) for i in range(2) for j in range(2)}


def test_feedback_channels_is_the_pairwise_test_at_a_shared_false_alarm_rate():
    """Oracle: feedback_test on each pair at alpha / (R p m) (Bonferroni); the pair reported
    is the one furthest above its bound."""
    from scipy.stats import norm

    from aeid_struct.generic.feedback import FEEDBACK_ALPHA, FEEDBACK_LAGS, feedback_channels

    rng = np.random.default_rng(0)
    U = rng.standard_normal((600, 3))
    e = rng.standard_normal((600, 2))
    # output 1's residual drives input 2 one sample later: a loop from y_1 to u_2
    U[1:, 2] += 0.8 * e[:-1, 1]
    Y_hat = rng.standard_normal((600, 2))
    Y = Y_hat + e
    found = feedback_channels([Y], [Y_hat], [U])
    assert found["detected"] and (found["output"], found["input"], found["record"]) == (1, 2, 0)
    want = feedback_test(Y[:, 1], Y_hat[:, 1], U[:, 2], alpha=FEEDBACK_ALPHA / 6)
    assert found == want | {"record": 0, "output": 1, "input": 2}
    assert found["bound"] == pytest.approx(norm.ppf(1 - FEEDBACK_ALPHA / 6 / (2 * FEEDBACK_LAGS)))
