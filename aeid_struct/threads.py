"""One BLAS and OpenMP thread inside the library's identifications of single records.

An identification of one record is hundreds of small linear-algebra calls (a few windows through
a small network, projections of a few dozen regressors, Levenberg-Marquardt steps of a few
parameters). A multi-threaded BLAS wakes, synchronises and parks its threads on every one of
them; with the thread counts an ordinary install chooses (OpenBLAS and torch's OpenMP at one
thread per core) that overhead, not the arithmetic, set the time of a call on the project's
2-core machines (``aeid-struct bench-generic`` prints its timings and the thread settings they
ran under). The entry points that identify single records (:func:`aeid_struct.identify`,
:func:`aeid_struct.compare`, ``GenericIdentifier.identify``, ``multi.identify``, the classical
baselines) run under :func:`one_thread`; training and the trained leg identifiers' batched
passes, whose large matrix products do gain from threads, do not.

Each call limits the pools of the thread it runs in and restores them when it returns (nested
calls leave them to the outermost); calls from several Python threads, interleaved, leave the
caller's counts as they were (tests/test_threads.py). Measured with the OpenBLAS of numpy's and
scipy's wheels: a limit set from a thread other than the main one changed neither the counts
OpenBLAS reported there nor the time of a call, so the gain is the main thread's.
"""

from __future__ import annotations

import functools
import threading

import threadpoolctl

__all__ = ["one_thread", "settings"]

_state = threading.local()      # .inside: a limited call is running in this thread


@functools.cache
def _controller() -> threadpoolctl.ThreadpoolController:
    # created at the first call, when numpy's, scipy's and torch's thread pools are loaded
    # (a controller knows the libraries loaded when it is made); ~14 us a call afterwards
    # against ~2 ms for threadpoolctl.threadpool_limits, which makes a controller every time
    return threadpoolctl.ThreadpoolController()


def one_thread(fn):
    """Decorate ``fn`` to run with every BLAS and OpenMP pool of its thread at one thread
    (the module docstring says why), the caller's thread counts restored when it returns.

    Parameters
    ----------
    fn : callable

    Returns
    -------
    callable
        ``fn``'s signature and docstring.
    """

    @functools.wraps(fn)
    def limited(*args, **kwargs):
        if getattr(_state, "inside", False):
            return fn(*args, **kwargs)
        limiter = _controller().limit(limits=1)
        _state.inside = True
        try:
            return fn(*args, **kwargs)
        finally:
            _state.inside = False
            limiter.restore_original_limits()

    return limited


def settings() -> str:
    """The thread settings timings ran under, in one line: every BLAS and OpenMP pool's
    count (threadpoolctl), torch's intra-op threads and the environment variables that set
    them, so that a benchmark's output says what it measured.

    Returns
    -------
    str
    """
    import os

    import torch

    pools = ", ".join(f"{p['internal_api']} {p['num_threads']}"
                      + (f" ({p['architecture']})" if p.get("architecture") else "")
                      for p in threadpoolctl.ThreadpoolController().info())
    env = ", ".join(f"{k}={os.environ[k]}" for k in (
        "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_CORETYPE",
        "OPENBLAS_L2_SIZE") if k in os.environ) or "none set"
    return (f"threads: {pools}; torch {torch.get_num_threads()}; environment: {env}; "
            f"single-record identifications at one BLAS thread (aeid_struct.threads)")
