"""The online benchmark: its scenario construction against closed forms, and the command in its
quick form (the full run's numbers are in pretrained/README.md)."""

import json
import math

import numpy as np
import pytest

import aeid_struct as ae
from aeid_struct.studies.bench_online import bench_excitation, format_tables
from aeid_struct.studies.online_flags import _outside_family

RANGES = {"k": (19.0, 27.0), "d": (1.5, 5.5), "m": (0.5, 1.5)}


@pytest.mark.parametrize("f", [0.1, 0.3])
def test_outside_legs_lie_f_beyond_one_bound_and_inside_otherwise(f):
    params = _outside_family(RANGES, "d", f, 200, np.random.default_rng(0))
    d = params["d"]
    assert np.all(np.isclose(d, 5.5 * (1 + f)) | np.isclose(d, 1.5 * (1 - f)))
    assert 0.3 < np.mean(d > 5.5) < 0.7                      # both sides
    for p in ("k", "m"):
        lo, hi = RANGES[p]
        assert np.all((params[p] >= lo) & (params[p] <= hi))


def test_excitation_rows_refine_to_the_truth_on_clean_records():
    ident = ae.load_pretrained("leg-unstable-any")
    ident.head = None                  # the encoder alone, then the CasADi refinement
    rows = bench_excitation(ident, ae.LegFamily(subsystem="unstable"), kinds=("multisine",),
                            noises=(0.0,), count=4)
    (row,) = rows
    assert row["kind"] == "multisine" and row["count"] == 4
    assert row["refined"]["k"] < 1e-6 and row["refined"]["m"] < 1e-6
    assert row["refined"]["step_error"] < 1e-10 and row["refined"]["failures"] == 0.0
    assert row["encoder"]["step_error"] > row["refined"]["step_error"]
    assert "| multisine | 0 % |" in format_tables({"excitation": {"u": rows}})


@pytest.mark.slow
def test_bench_online_quick_runs_and_writes_the_targets(tmp_path, capsys):
    from aeid_struct.cli import main

    out = tmp_path / "b.json"
    assert main(["bench-online", "--quick", "--quiet", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    for heading in ("### Tracker", "### Latency", "### Arbitrary excitation: leg-stable-any",
                    "### Arbitrary excitation: leg-unstable-any",
                    "### Out-of-range flags: leg-stable-window", "Measured: update"):
        assert heading in text
    result = json.loads(out.read_text())
    t = result["targets"]
    # the update time is measured and reported (a benchmark's number, not asserted here)
    assert np.isfinite(t["update_ms_median"]) and t["update_ms_median"] > 0
    assert 0 < t["k_rms_percent_mean"] < 20
    assert 0.0 <= t["false_flags_max"] <= 1.0
    assert {r["engine"] for r in result["tracker"]} == {"onnx", "identifier"}
    assert {"Identifier.identify", "torch.export program", "ONNX file (onnxruntime)"} \
        <= set(result["latency"])


def test_tables_keep_every_parameter_in_its_place_and_define_their_columns():
    from aeid_struct.studies.bench_online import LEGENDS

    stage = {"step_error": 1e-3, "failures": 0.05, "ms": 2.0}
    rows = [{"kind": "prbs", "noise": 0.01, "count": 20,
             "encoder": {"k": 4.0, "m": 11.0, **stage},
             "refined": {"k": math.nan, "m": 0.5, **stage}}]
    flags = [{"noise": 0.0, "beyond": 0.3, "count": 20, "flagged": 0.9,
              "before": {"k": 1.0, "d": 2.0, "m": 3.0}, "after": {"k": 0.1, "m": 0.3}}]
    text = format_tables({"excitation": {"leg-unstable-any": rows}, "flags": {"w": flags}})
    # the rotational leg has no d: "4.00 / - / 11.00", never "4.00 / 11.00" (read as k and d)
    assert "| prbs | 1 % | 4.00 / - / 11.00 |" in text
    assert "| n/a / - / 0.500 |" in text
    assert "| 1.00 / 2.00 / 3.00 | 0.10 / - / 0.30 |" in text
    assert "nan" not in text.lower()
    assert LEGENDS["excitation"] in text and LEGENDS["flags"] in text
    assert "'-': the subsystem does not contain the parameter" in LEGENDS["excitation"]


def test_tracker_rows_report_the_update_percentile_and_the_head_lowers_k_error():
    from aeid_struct.identification import Head
    from aeid_struct.studies.bench_online import bench_tracker

    ident = ae.load_pretrained("leg-stable-window")
    rows = {}
    for name, head in (("encoder", None), ("head", Head(iterations=1, fixed={"c1": 0.0}))):
        ident.head = head
        (rows[name],) = bench_tracker(ident, seconds=30.0, seeds=(1,), engines=("onnx",))
    for r in rows.values():
        assert 0 < r["latency_ms"] <= r["latency_p95_ms"]
    assert rows["head"]["rms"]["k"] < 0.5 * rows["encoder"]["rms"]["k"]
    text = format_tables({"tracker": list(rows.values())})
    assert "update ms median / p95" in text
    assert f"{rows['head']['latency_ms']:.3f} / {rows['head']['latency_p95_ms']:.3f} |" in text
