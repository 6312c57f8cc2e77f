"""Build notebooks/06_several_channels.ipynb from the cells below (nbformat).

    python notebooks/make_06.py              # write the notebook without outputs
    python notebooks/make_06.py --execute    # also run it in full mode (no AEID_FAST) in a
                                             # temporary directory and store the outputs

Run with PYTHONPATH pointing at the repository root, so that the kernel (which inherits the
environment) imports this checkout's ``aeid_struct``.
"""

from __future__ import annotations

from pathlib import Path

from make_03 import main  # the same builder and full-mode runner (temporary directory)

HERE = Path(__file__).resolve().parent
TARGET = HERE / "06_several_channels.ipynb"

CELLS = [
    ("md", r"""# 06 · Several inputs and outputs, several experiments, an integrating plant

**Problem.** A process engineer logs two outputs (two temperatures of a heated plate) answering
two inputs (two heater powers), while the plant runs: no rest at the start, sensor offsets, a
transport delay on one heater, noise. A second experiment was logged on another day. A
positioning axis (input torque, output position) integrates: its model has a pole at zero.

`ae.identify` takes all of it in the same call: a record of `p` outputs and `m` inputs gives one
model `A (n, n), B (n, m), C (p, n), D (p, m)` with a delay per input; a list of records gives
one model with each record's own initial state and offsets. Set `AEID_FAST=1` for shorter
records."""),
    ("code", r"""import os
import time

import control
import numpy as np
import scipy.signal
from IPython.display import Image, display

import aeid_struct as ae
from aeid_struct import baselines

FAST = os.environ.get("AEID_FAST") == "1"
rng = np.random.default_rng(2026)
dt = 0.5
steps = 600 if FAST else 1500


def run(system, delays, steps, noise, seed):
    A, B, C, D = system
    r = np.random.default_rng(seed)
    m, p = B.shape[1], C.shape[0]
    U = np.repeat(r.choice([0.0, 1.0], size=(steps // 20 + 1, m)), 20, axis=0)[:steps]
    Ud = np.stack([np.concatenate([np.zeros(d), U[: steps - d, j]])
                   for j, d in enumerate(delays)], axis=1)
    _, Y, _ = scipy.signal.lsim((A, B, C, D), Ud, np.arange(steps) * dt,
                                X0=r.normal(size=A.shape[0]), interp=True)
    Y = Y.reshape(steps, p) + np.array([20.0, 21.5])[:p]
    return ae.Record(Y + noise * Y.std(axis=0) * r.normal(size=Y.shape), U, dt)"""),
    ("md", r"""## Two heaters, two temperatures

A plate with three thermal modes (time constants of 5-50 s), coupled: each heater warms both
sensors, the far one later. The second heater's power reaches the plate 4 samples late."""),
    ("code", r"""A = np.array([[-0.02, 0.01, 0.0], [0.01, -0.05, 0.02], [0.0, 0.02, -0.2]])
B = np.array([[0.02, 0.0], [0.0, 0.01], [0.05, 0.08]])
C = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5]])
D = np.zeros((2, 2))
plate = (A, B, C, D)
estimation = run(plate, [0, 4], steps, 0.02, 1)
validation = run(plate, [0, 4], steps, 0.02, 2)
t0 = time.perf_counter()
est = ae.identify(estimation, order=3)
print(f"identified in {time.perf_counter() - t0:.2f} s; delay per input {est.delay.tolist()}")
print("poles", np.round(np.sort(np.linalg.eigvals(est.A).real), 4),
      "true", np.round(np.sort(np.linalg.eigvals(A).real), 4))
cmp = ae.compare(est, validation)
print(cmp)
for name, method in (("n4sid", baselines.n4sid), ("least squares", baselines.least_squares)):
    other = method(estimation.with_delay(4), order=3)
    print(f"{name:14s} validation fit {np.round(ae.compare(other, validation, delay=[4, 4]).fit, 2)}")
cmp.figure("plate_compare.png", y_label="temperature [K]")
display(Image("plate_compare.png"))"""),
    ("md", r"""n4sid and least squares are given one delay for both inputs (a `Record` carries one);
`ae.identify` found each input's own. The model is in the observer form of one reference output
(`est.info["reference"]`): its row of `C` is `e_1`, the other rows and `B` carry the rest."""),
    ("md", r"""## Two experiments, one model

A second record of the same plate, logged separately (another initial temperature, other
offsets). Identified together, each record keeps its own initial state and offsets."""),
    ("code", r"""second = run(plate, [0, 4], steps // 2, 0.02, 3)
both = ae.identify([estimation, second], order=3)
print("fit per record and output:", np.round(both.fit, 2))
print("offsets per record:", [np.round(o, 2).tolist() for o in both.offset])
print("validation:", ae.compare(both, validation))"""),
    ("md", r"""## An integrating plant

A positioning axis of order 4: torque to position, `4 / (s (s + 2))` times a compliance mode
`100 / (s^2 + 4 s + 100)`. Its
output drifts with the integral of the input: the model has a pole at zero, and the input keeps
its level (a constant torque is a ramp, not an offset)."""),
    ("code", r"""G = control.tf([4.0], [1.0, 2.0, 0.0]) * control.tf([100.0], [1.0, 4.0, 100.0])
axis = control.ss(G)
t = np.arange(400 if FAST else 1000) * 0.02
r = np.random.default_rng(4)
u = np.repeat(r.normal(size=len(t) // 10 + 1), 10)[: len(t)]
y = control.forced_response(axis, t, u).outputs
record = ae.Record(y + 0.01 * y.std() * r.normal(size=len(t)), u, 0.02)
est = ae.identify(record, order=4)
print("poles", np.round(np.sort_complex(np.linalg.eigvals(est.A)), 3))
print("true ", np.round(np.sort_complex(control.poles(axis)), 3))
print(f"fit {est.fit:.2f} %")"""),
]


if __name__ == "__main__":
    main(cells_source=CELLS, target=TARGET)
