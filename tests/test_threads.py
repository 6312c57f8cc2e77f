"""threads: one BLAS and OpenMP thread inside single-record identifications, the caller's
thread counts restored after (threadpoolctl's own report as the oracle), also under concurrent
calls from several Python threads."""

import threading
import time

import numpy as np
import pytest
from threadpoolctl import ThreadpoolController

import aeid_struct as ae
from aeid_struct import baselines
from aeid_struct.threads import one_thread


def _counts() -> set:
    return {(pool["internal_api"], pool["num_threads"])
            for pool in ThreadpoolController().info()}


@one_thread
def _inside(seconds=0.0):
    time.sleep(seconds)
    return _counts()


def test_one_thread_inside_and_the_callers_counts_after():
    with ThreadpoolController().limit(limits=2):
        before = _counts()
        assert {n for _, n in before} == {2}
        assert {n for _, n in _inside()} == {1}
        assert _counts() == before


def test_concurrent_calls_restore_the_callers_counts():
    """Calls from several Python threads entering and leaving interleaved (the second enters
    while the first is inside and leaves after it), one from the caller's thread among them:
    the caller's counts are its own again when all have returned."""
    with ThreadpoolController().limit(limits=2):
        before = _counts()
        seen = []
        threads = [threading.Thread(target=lambda s=s: seen.append(_inside(s)))
                   for s in (0.2, 0.4, 0.1)]
        for t in threads:
            t.start()
            time.sleep(0.05)
        assert {n for _, n in _inside()} == {1}      # the caller's thread, meanwhile
        for t in threads:
            t.join()
        assert len(seen) == 3 and _counts() == before


def test_an_exception_inside_restores_the_counts():
    @one_thread
    def fails():
        raise ValueError("inside")

    with ThreadpoolController().limit(limits=2):
        before = _counts()
        with pytest.raises(ValueError, match="inside"):
            fails()
        assert _counts() == before


@pytest.mark.parametrize("entry", [ae.identify, ae.compare, baselines.n4sid,
                                   baselines.least_squares, ae.generic.GenericIdentifier.identify,
                                   ae.multi.identify])
def test_entry_points_run_under_the_limit(entry):
    # the wrapper one_thread returns (not merely some decorator's functools.wraps)
    assert entry.__code__ is one_thread(lambda: None).__code__


def test_identify_under_the_limit_is_the_same_estimate():
    rng = np.random.default_rng(0)
    u = np.repeat(rng.choice([-1.0, 1.0], 60), 10)
    A, b, c = np.array([[0.0, 1.0], [-4.0, -0.8]]), np.array([0.0, 1.0]), np.array([2.0, 0.0])
    y = ae.simulate(A, b, c, 0.0, u, 0.05) + 0.01 * rng.normal(size=600)
    record = ae.Record(y, u, 0.05)
    with ThreadpoolController().limit(limits=2):
        limited = ae.identify(record, order=2)
        free = ae.identify.__wrapped__(record, order=2)
    np.testing.assert_allclose(limited.A, free.A, rtol=1e-10)
    np.testing.assert_allclose(limited.y_hat, free.y_hat, rtol=1e-10, atol=1e-12)
