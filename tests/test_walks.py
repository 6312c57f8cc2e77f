"""The walk of one record (docs/architecture.md, "One record's walk"): at the level of the
function that runs a path's stages (check, start, fit, result), the library modules it calls,
in order, each entered once; shared kernels (records, structures, simulation, the encoder's
configuration, the normalised model the generic stages hand each other) and attribute access
(a descriptor's ``__get__``) are called, not stages, and are left out.
A stage that went back to a module it had left (a record entering ``generic/polish.py`` five
times) fails here with the walk it took."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import aeid_struct as ae

KERNELS = ("aeid_struct.records", "aeid_struct.structures", "aeid_struct.simulation",
           "aeid_struct.metrics", "aeid_struct.encoder", "aeid_struct.generic.normalised")
#: attribute access, not a call of a stage (``ident.head`` is a descriptor of ``head``)
DESCRIPTORS = ("__get__", "__set__", "__getattr__")


def walk(root: str, call) -> list[str]:
    """The modules that functions of module ``root`` call while ``call()`` runs, consecutive
    repeats merged, kernels and attribute access left out."""
    seen: list[str] = []

    def profile(frame, event, arg):
        if event != "call" or frame.f_back is None:
            return
        module = frame.f_globals.get("__name__", "")
        if (frame.f_back.f_globals.get("__name__", "") != root or module == root
                or not module.startswith("aeid_struct") or module.startswith(KERNELS)
                or frame.f_code.co_name in DESCRIPTORS):
            return
        if not seen or seen[-1] != module:
            seen.append(module)

    sys.setprofile(profile)
    try:
        call()
    finally:
        sys.setprofile(None)
    return [m.removeprefix("aeid_struct.") for m in seen]


@pytest.fixture(scope="module")
def any_record():
    rng = np.random.default_rng(0)
    u = np.repeat(rng.choice([-1.0, 1.0], 80), 10)
    A, b, c = np.array([[0.0, 1.0], [-4.0, -0.8]]), np.array([0.0, 1.0]), np.array([2.0, 0.0])
    y = ae.simulate(A, b, c, 0.0, u, 0.05) + 0.3 + 0.01 * rng.normal(size=800)
    return ae.Record(y, u, 0.05)


@pytest.mark.parametrize(("refine", "stages"), [
    # the refined model's residuals are tested for feedback, then the one pass runs on the
    # first 70 % of the record at its delay (the hold-out: no delay search) and its rule
    # (generic.holdout) judges it before the result; every model's lightly damped modes are
    # checked against the record (multi.excitation)
    (True, ["generic.boundary", "generic.delay", "generic.windows", "generic.scoring",
            "generic.polish", "generic.feedback", "generic.boundary", "generic.windows",
            "generic.classical", "generic.scoring", "generic.polish", "generic.holdout",
            "multi.excitation", "generic.result"]),
    (False, ["generic.boundary", "generic.delay", "generic.windows", "generic.classical",
             "generic.scoring", "generic.polish", "multi.excitation", "generic.result"]),
])
def test_any_record_walks_check_start_fit_result_once(any_record, refine, stages):
    ae.identify(any_record, order=2, refine=refine)          # warm: loading is not the walk
    got = walk("aeid_struct.generic.pipeline",
               lambda: ae.identify(any_record, order=2, refine=refine))
    assert got == stages
    # one_call asks multi whether the record has several channels or experiments (no), then
    # runs the pipeline of one channel
    assert walk("aeid_struct.generic.one_call",
                lambda: ae.identify(any_record, order=2, refine=refine)) == [
        "multi.experiments", "generic.pipeline"]


def test_a_leg_record_with_refine_walks_each_module_once():
    ident = ae.load_pretrained("leg-stable-any")
    rec = ae.data.records(ae.LegFamily(subsystem="stable"), 1, steps=ident.steps, dt=ident.dt,
                          excitation_kind="prbs", seed=3, warmup=200, noise=0.01)
    record = ae.Record(rec.y[0], rec.u[0], ident.dt)
    ident.identify(record, refine=True)
    # the identifier: check (its call, and records: a kernel), the head's converged form, then
    # the one pass that every back end walks
    assert walk("aeid_struct.identification.identifier",
                lambda: ident.identify(record, refine=True)) == ["identification.checks",
                                                                 "identification.head",
                                                                 "identification.one_pass"]
    # one pass: start (the back end's model), fit (the head), result (the Estimate)
    assert walk("aeid_struct.identification.one_pass",
                lambda: ident.identify(record, refine=True)) == [
        "identification.forward", "identification.head", "estimates.estimate"]
    # the torch back end of one record: the numpy pass
    assert walk("aeid_struct.identification.forward",
                lambda: ident.identify(record, refine=True)) == ["identification.fast_path"]


def test_a_leg_record_without_a_head_is_polished_after_forward():
    ident = ae.load_pretrained("leg-stable")
    rec = ae.data.records(ae.LegFamily(subsystem="stable"), 1, steps=ident.steps, dt=ident.dt,
                          seed=3, noise=0.01)
    record = ae.Record(rec.y[0], None, ident.dt)
    assert walk("aeid_struct.identification.identifier",
                lambda: ident.identify(record, refine=True)) == ["identification.checks",
                                                                 "identification.one_pass",
                                                                 "identification.polish"]
