"""Shared test utilities: tolerances by dtype and small numeric helpers."""

from __future__ import annotations

import numpy as np
import torch

#: Relative tolerances for comparisons against an independent oracle, by dtype.
RTOL = {torch.float64: 1e-10, torch.float32: 1e-4, np.float64: 1e-10, np.float32: 1e-4}


def rel_max_error(actual, expected) -> float:
    """max|actual - expected| / max|expected|: the decoder's accuracy measure (DESIGN.md)."""
    actual = np.asarray(actual, dtype=np.float64)
    expected = np.asarray(expected, dtype=np.float64)
    scale = max(float(np.max(np.abs(expected))), 1e-300)
    return float(np.max(np.abs(actual - expected))) / scale


def tf_coeffs(A, b, c, d=0.0):
    """Transfer function (num, den) of one SISO system, from python-control's ss2tf."""
    import control

    A = np.atleast_2d(np.asarray(A, dtype=np.float64))
    n = A.shape[0]
    sys = control.ss(A, np.reshape(b, (n, 1)), np.reshape(c, (1, n)), np.reshape(d, (1, 1)))
    tf = control.ss2tf(sys)
    num = np.atleast_1d(np.squeeze(tf.num[0][0]))
    den = np.atleast_1d(np.squeeze(tf.den[0][0]))
    # Normalise to a monic denominator and pad the numerator to the denominator's length.
    num, den = num / den[0], den / den[0]
    num = np.concatenate([np.zeros(len(den) - len(num)), num])
    return num, den


def companion(den):
    """The bottom-row controllable canonical form ``A (n, n), b = e_n`` of a monic denominator
    (highest power first), written out: the test oracles' CCF (paper Eq. 5)."""
    n = len(den) - 1
    A = np.zeros((n, n))
    A[:-1, 1:] = np.eye(n - 1)
    A[-1] = -np.asarray(den[1:], float)[::-1]
    return A, np.eye(n)[-1]


def torchrun(args, *, cwd, env, timeout=240):
    """``python -m torch.distributed.run ARGS`` in a session of its own, as
    ``subprocess.run(..., capture_output=True, text=True)`` does, and afterwards every process
    of that session killed: a rank stuck in a collective after its peer died outlived the test
    run (found orphaned an hour later)."""
    import os
    import signal
    import subprocess
    import sys

    cmd = [sys.executable, "-m", "torch.distributed.run", *map(str, args)]
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def wrong_in_threads(check, threads: int = 4, calls: int = 400) -> list[int]:
    """Run ``check(k)`` (True when thread ``k``'s result is its own) ``calls`` times in each of
    ``threads`` threads at once, switching threads between any two bytecodes; the threads that
    got a wrong result (an empty list where none did)."""
    import sys
    import threading

    wrong = []

    def work(k):
        for _ in range(calls):
            if not check(k):
                wrong.append(k)
                return

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        running = [threading.Thread(target=work, args=(k,)) for k in range(threads)]
        for t in running:
            t.start()
        for t in running:
            t.join()
    finally:
        sys.setswitchinterval(interval)
    return wrong


#: A user's own mechanism, as a user writes it: a mass on a spring and damper pushed through a
#: lever of known ratio, its structure built at module level, training under ``__main__``.
MACHINE = '''
import casadi as ca
import aeid_struct as ae
from symbolic.mechanism import Mechanism

x, v, F = ca.SX.sym("x"), ca.SX.sym("v"), ca.SX.sym("F")
m, k, d = ca.SX.sym("m"), ca.SX.sym("k"), ca.SX.sym("d")
plant = Mechanism(q=x, dq=v, u=F, parameters={"m": m, "k": k, "d": d},
                  lagrangian=0.5 * m * v**2 - 0.5 * k * x**2, dissipation=0.5 * d * v**2,
                  forces=RATIO * F, outputs=x, name="myplant")
structure = ae.Physical(plant, bounds={"m": (0.5, 2.0), "k": (10.0, 50.0), "d": (0.5, 3.0)})

if __name__ == "__main__":
    raise SystemExit("training code: never run by --maps")
'''


def write_machine(folder, ratio: float = 1.5):
    """Write ``machine.py`` (:data:`MACHINE`) in ``folder``; train and save a small identifier of
    its structure (``myplant.aeid``, 100 samples at dt = 0.02).

    Returns
    -------
    script : pathlib.Path
    path : pathlib.Path
        The identifier file (``None`` when ``ratio`` is not 1.5: only the script is written).
    structure : aeid_struct.Physical
        The structure the script builds, built here in the same way.
    """
    import runpy
    from pathlib import Path

    import aeid_struct as ae

    script = Path(folder) / "machine.py"
    script.write_text(MACHINE.replace("RATIO", repr(ratio)))
    structure = runpy.run_path(str(script), run_name="helpers")["structure"]
    if ratio != 1.5:
        return script, None, structure
    ident = ae.train(structure, ae.ParameterFamily(structure), ae.TrainConfig(
        steps=100, dt=0.02, epochs=1, count=100, excitation="prbs", noise=(0.0, 0.03),
        progress=False, seed=0))
    return script, ident.save(Path(folder) / "myplant.aeid"), structure
