"""Build notebooks/02_partial_knowledge.ipynb from the cells below (nbformat).

    python notebooks/make_02.py              # write the notebook without outputs
    python notebooks/make_02.py --execute    # also run it in full mode (no AEID_FAST) in a
                                             # temporary directory and store the outputs

Run with the repository's environment, so that the kernel (which inherits it) imports this
checkout's ``aeid_struct``. ``AEID_CACHE`` names a directory of trained identifiers to reuse.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = Path(__file__).resolve().parent
TARGET = HERE / "02_partial_knowledge.ipynb"

CELLS = [
    ("md", r"""# 02 · Partial knowledge: what the structure knows, the encoder need not learn

**Problem.** An engineer rarely knows nothing about the system in front of them. For the robot
leg of the paper (Nagel & Huber, Sec. IV) the model is known up to three numbers — stiffness *k*,
damping *d*, mass *m* — and sometimes one of them is known too (the leg carries a known load).
The paper claims that the structured decoder can use such knowledge, but never shows it. Here we
measure it: identifiers that know progressively more about the leg are trained with the same
budget and scored on the same 500 fresh legs, noise-free and with 5 % measurement noise.

The sharpest case is the **unstable rotational subsystem**. A free CCF cannot know that its
damping coefficient a₁ is zero; with noise, a free fit lands on parameters that no leg has (a
negative or complex mass). We show what fixing elements, physical parameters and identifying
both subsystems **jointly** (one encoder, two records in, one (k, d, m) out) do about it.

Set `AEID_FAST=1` to run it in about a minute (the test suite does): a few hundred records and
two epochs per identifier, 50 validation legs — it shows the mechanics, not the answer. In full
mode the 24 trainings take about 40 minutes on one core; with `AEID_CACHE=<dir>` the trained
identifiers are kept there and reused (this notebook's outputs come from such a cache)."""),
    ("code", r"""import os
import time

import matplotlib.pyplot as plt
import numpy as np
import torch
from IPython.display import Markdown, display

import aeid_struct as ae
from aeid_struct import evaluation, studies
from symbolic import leg

knowledge = studies.knowledge     # the leg's partial-knowledge identifiers

FAST = os.environ.get("AEID_FAST") == "1"
torch.set_num_threads(1)                  # the budget below is measured on one core
COUNT = 300 if FAST else 10_000           # simulated records per training (20 % held out)
EPOCHS = 2 if FAST else 50
VALIDATION = 50 if FAST else 500          # fresh legs, each with both records
CACHE = None if FAST else os.environ.get("AEID_CACHE", "identifiers-02")
START = time.perf_counter()
print("fast mode" if FAST else "full mode", f"- {COUNT} records x {EPOCHS} epochs per "
      f"identifier, {VALIDATION} validation legs, cache: {CACHE}")"""),
    ("md", r"""## The maths: three ways to know something

The leg's two subsystems (derived by `symbolic.leg` from the Lagrangian, paper Eq. 16) in
controllable canonical form (paper Eq. 5):

$$G_1(s) = \frac{c_1 s + c_0}{s^2 + a_1 s + a_0}:\ a_0 = \frac{k}{m},\ a_1 = \frac{d}{m},\
c_0 = \frac{1}{m},\ c_1 = 0; \qquad
G_2(s):\ a_0 = -\frac{g}{L},\ a_1 = 0,\ c_0 = \frac{1}{m L^2},\ c_1 = 0,\ L = l_0 - \frac{m g}{k}.$$

1. **Fixed elements.** `CCF(2).fixed(a1=0.0)` removes a₁ from the encoder's output: the raw
   parameter vector θ has one column fewer, and every decoded model has a₁ = 0 exactly.
2. **Physical parameters.** `Physical(leg.stable_map(), bounds=...)` makes the encoder output
   k, d, m directly, each as $p = p_{lo} + (p_{hi} - p_{lo})\,\sigma(\theta)$ within its range,
   mapped to (A, b, c, d) by the CasADi function (differentiable through CasADi's own
   derivatives). Every estimate is then a leg — valid parameters by construction.
3. **Several records, one parameter set.** `Physical(leg.joint_map(), ...)` outputs one (k, d, m)
   for both subsystems; the encoder reads both records (each normalised by Eq. 15, pooled to a
   common length, stacked as channels) and the loss is Eq. 14 averaged over the two records.
   The stable record pins k/m, d/m and m; the unstable one adds a second look at k and m.

A known mass is a fixed element in either form: `.fixed(c1=0, c0=1/m)` in CCF, `.fixed(m=m)` in
physical parameters."""),
    ("code", r"""variants = knowledge.variants()
rows = ["| identifier | structure | encoder outputs | knows |", "|---|---|---|---|"]
for v in variants.values():
    rows.append(f"| {v.name} | `{v.structure!r}` | {', '.join(v.structure.free_names)} "
                f"| {v.known} |")
display(Markdown("\n".join(rows)))"""),
    ("md", r"""## Training: the same budget for every identifier

Each identifier is trained unsupervised (loss Eq. 14 on Eq. 15-normalised records) on simulated
step responses of legs from its family, with the study's encoder (three convolutions and a
shortcut, two dense layers of 48, records pooled to 50 samples) and the same record count,
epochs and seed. Two of each: one on noise-free records, one with measurement noise drawn per
record and epoch from 0-6 % (for noisy measurements). With a cache directory, trained
identifiers are saved and reused (`knowledge.train_variant(..., cache=...)`)."""),
    ("code", r"""idents = {}
for noisy in (False, True):
    for name, v in variants.items():
        t0 = time.perf_counter()
        idents[name, noisy] = knowledge.train_variant(v, noisy=noisy, count=COUNT, epochs=EPOCHS,
                                                      cache=CACHE)
        train = idents[name, noisy].meta["train"]
        print(f"{name:30s} {'noisy' if noisy else 'clean'}: {train['epochs']} epochs, "
              f"best held-out loss {train['best_holdout_loss']:.2e}, "
              f"{train['seconds']:.0f} s training ({time.perf_counter() - t0:.1f} s here)")"""),
    ("md", r"""### One leg, both records

The joint identifier takes the two records of one leg (the paper's scenario, each a step
response on its own grid, measured with 5 % noise) and returns one (k, d, m):"""),
    ("code", r"""joint = idents["joint / physical", True]
legs = ae.LegFamily(subsystem="joint").systems(**{k: [v] for k, v in leg.SCENARIO.items()})
rng = np.random.default_rng(0)
records_ = []
for r, (steps, dt) in enumerate(zip(joint.steps, joint.dt, strict=True)):
    y = ae.simulate(legs.A[0, r], legs.b[0, r], legs.c[0, r], legs.d[0, r], np.ones(steps), dt)
    records_.append(y + 0.05 * np.abs(y).max() * rng.normal(size=steps))
est = joint.identify(records_)
print("true:      ", {k: round(v, 3) for k, v in leg.SCENARIO.items()})
print("identified:", {k: round(float(v), 3) for k, v in est.physical.items()},
      f"in {1e3 * est.seconds:.1f} ms; fit per record {np.round(est.fit, 1)} %")"""),
    ("md", r"""## Validation: the same legs for everyone

500 fresh legs (another seed) with both records; single-subsystem identifiers read their own
record of each leg, joint ones read both. Noise-free records go to the noise-free-trained
identifiers, records with 5 % noise (std relative to max|y|) to the noise-trained ones. The
known-mass identifiers are scored on legs of that mass (m = 1.01 kg), where the others are scored
too, for reference."""),
    ("code", r"""val = {noisy: knowledge.validation(VALIDATION, noise=0.05 if noisy else 0.0)
       for noisy in (False, True)}
val_m = {noisy: knowledge.validation(VALIDATION, noise=0.05 if noisy else 0.0, known_mass=True)
         for noisy in (False, True)}
scores, scores_m = {}, {}
for (name, noisy), ident in idents.items():
    v = variants[name]
    if "m known" not in name:
        scores[name, noisy] = knowledge.evaluate(v, ident, val[noisy])
    scores_m[name, noisy] = knowledge.evaluate(v, ident, val_m[noisy])
COLUMNS = ("step_mean", "step_median", "valid_share", "k_mean", "d_mean", "m_mean")
MEDIANS = ("step_median", "valid_share", "k_mean", "k_median", "m_mean", "m_median")


def show(title, table_scores, noisy, columns=COLUMNS):
    picked = [s for (name, n), group in table_scores.items() if n == noisy for s in group]
    display(Markdown(f"**{title}, {'5 % noise' if noisy else 'noise-free'}** "
                     f"(Δ: absolute % error over the valid estimates)\n\n"
                     + evaluation.table(picked, columns)))


for noisy in (False, True):
    show("Paper ranges", scores, noisy)"""),
    ("md", r"""### Reading the tables

* **valid k,d,m** is the share of estimates whose physical parameters are finite and positive
  (an actual leg). Physical structures are valid by construction; canonical ones are converted
  by the CasADi inverse of the CCF map and may not be.
* The unstable subsystem does not contain d, so its d column is empty (its physical identifiers
  hold d at the middle of its range, which says nothing).
* A joint identifier appears twice, once per record: the step errors are those of each decoded
  subsystem; the parameter errors are the same (one parameter set)."""),
    ("code", r"""fig = evaluation.knowledge_bars(
    {("noise-free" if not n else "5 % noise"): [s for (name, nn), g in scores.items() if nn == n
                                               for s in g[:1]] for n in (False, True)},
    parameters=("k", "d", "m"), path="partial_knowledge.png")
plt.show()"""),
    ("md", r"""## The classical fit with the same knowledge

The numbers quoted in the issue that motivated this notebook came from output-error least squares
(`baselines.least_squares`, scipy, exact FOH simulation, from a generic start) on the unstable
subsystem: with a₁ free, invalid parameters on 39 % of legs at 5 % noise; with a₁ fixed, k / m
errors of 15 / 25 %. Here least squares runs in each single-subsystem structure on the first
legs of the validation set (`knowledge.least_squares(variant)` wraps it behind an identifier's
interface), beside the encoder on the same legs."""),
    ("code", r"""LS_COUNT = 10 if FAST else 100
ls_names = ["stable / CCF", "stable / physical", "unstable / CCF", "unstable / CCF a1=0",
            "unstable / CCF a1=0 c1=0", "unstable / physical"]
ls_scores = {}
for noisy in (False, True):
    legs = val[noisy].take(np.arange(LS_COUNT))
    for name in ls_names:
        v = variants[name]
        ls_scores[name, noisy] = (
            knowledge.evaluate(v, knowledge.least_squares(v), legs, label="least squares")
            + knowledge.evaluate(v, idents[name, noisy], legs, label="encoder"))
for noisy in (False, True):
    show(f"Least squares vs encoder, first {LS_COUNT} legs", ls_scores, noisy, MEDIANS)"""),
    ("md", r"""## A known mass

Legs of mass 1.01 kg. The identifiers that know it have one output fewer; the general ones are
shown on the same legs for reference."""),
    ("code", r"""for noisy in (False, True):
    show("m = 1.01 kg", scores_m, noisy)
print(f"notebook time: {time.perf_counter() - START:.0f} s")"""),
    ("md", r"""## Conclusion

Measured in the full run above (10⁴ records × 50 epochs per identifier, 500 legs; least squares on
the first 100):

* **Every encoder estimate was a valid leg** (finite, positive k, d, m) in every table, also for
  the free CCF of the unstable subsystem at 5 % noise, where least squares in the same structure
  returned invalid parameters for 24 % of the legs (3 % with a₁ fixed) and median k / m errors of
  340 / 790 % (25 / 42 % with a₁ fixed).
* **The stable (translational) record determines k, d, m.** A free CCF with Descartes' constraint
  already gets 0.02 / 0.17 / 0.38 % noise-free and 0.33 / 1.6 / 2.1 % at 5 % noise; fixing the
  known c₁ = 0 or a known mass helps a little more. Physical parameters give the same accuracy at
  5 % noise (0.56 / 1.8 / 1.9 %) but train slower: noise-free they are ~10× behind at this budget
  (held-out loss 3.7e-5 against 2e-6), because the record's shape depends on k/m and d/m, which
  the CCF outputs directly.
* **The unstable (rotational) record alone does not pin k and m under noise.** Noise-free, the
  structure decides: fixing a₁ = 0 and c₁ = 0 cuts the errors 15× (3.3 / 3.8 % → 0.21 / 0.24 %).
  At 5 % noise every structure errs by 9-16 % (k) and 20-28 % (m), close to the spread of the
  prior ranges; the least-squares optimum itself is off by 6 / 14 % in the physical structure.
  G₂ sees k and m only through L = l₀ − m g / k and m L², and k follows from L with an error gain
  of up to 3. A known mass fixes this: k within 0.39 % at 5 % noise.
* **Joint identification** from both records gives 0.70 / 2.7 / 2.2 % at 5 % noise, 20× better in
  k than the unstable record alone and as good as the stable record alone in k and m (d, seen
  only by the stable record, is 1.6× worse: the encoder now shares its capacity with the second
  record).

**Which structure for which case.** For the physical parameters of the leg, identify from the
stable record with `CCF(2, descartes=True).fixed(c1=0.0)` and the CasADi inverse — the most
accurate, valid in every case here; use `Physical(leg.stable_map(), ...)` when the parameters must
stay inside known bounds by construction (noisy records, estimates fed to a controller), at a
modest cost in accuracy. When both records come anyway, the joint physical identifier gives one
consistent (k, d, m). Never take k and m from the unstable record alone unless the mass is known
(`Physical(leg.unstable_map(), ...).fixed(d=..., m=m)`); noise-free, fix what the physics says is
zero (`CCF(2).fixed(a1=0.0, c1=0.0)`). For CCF against MCF, see notebook 03."""),
]


def build() -> nbformat.NotebookNode:
    nb = new_notebook()
    nb.cells = [new_markdown_cell(src) if kind == "md" else new_code_cell(src)
                for kind, src in CELLS]
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                 "language": "python"}
    nb.metadata["language_info"] = {"name": "python"}
    return nb


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--execute", action="store_true", help="run in full mode, keep outputs")
    args = parser.parse_args()
    nb = build()
    if args.execute:
        from nbclient import NotebookClient

        os.environ.pop("AEID_FAST", None)
        # Without MPLBACKEND the kernel picks the inline backend and the figures are stored as
        # PNG outputs (with MPLBACKEND=Agg they would be dropped).
        os.environ.pop("MPLBACKEND", None)
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            NotebookClient(nb, timeout=7200, kernel_name="python3",
                           resources={"metadata": {"path": tmp}}).execute()
            print(f"executed in {time.perf_counter() - t0:.0f} s")
    nbformat.write(nb, TARGET)
    print(f"wrote {TARGET}")


if __name__ == "__main__":
    main()
