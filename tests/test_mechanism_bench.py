"""studies.mechanism_bench and ``aeid-struct bench-mechanism``: a mechanism's report, an
identifier trained through the user's API, and every method on the same records.

Oracle: the true parameters of noise-free records (the refinement and the cold grey-box fit
reach them), and the closed-form identifiability of a lever of unknown ratio (rank 3 of 4).
"""

from __future__ import annotations

import json
import math

from aeid_struct.cli import main


def test_bench_mechanism_cli_trains_measures_and_writes_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    assert main(["bench-mechanism", "--seconds", "3", "--records", "2", "--noise", "0",
                 "--cases", "lever (r known)", "lever (r unknown)", "--json", str(out),
                 "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "refined is" in printed and "r not identifiable" in printed
    rows = json.loads(out.read_text())
    assert [row["name"] for row in rows] == ["lever (r known)", "lever (r unknown)"]
    known, unknown = rows
    assert unknown["identifiability"]["rank"] == 3 and unknown["identifiability"]["fix"] == ["r"]
    assert "levels" not in unknown
    level = known["levels"][0]
    assert set(level["errors"]) == {"encoder", "one pass", "refined", "refined x4",
                                    "cold grey-box x4", "n4sid"}
    assert max(level["errors"]["refined"]) < 1e-5
    assert max(level["errors"]["refined x4"]) < 1e-5
    assert max(level["errors"]["cold grey-box x4"]) < 1e-5
    assert level["ms"]["refined"] > 0 and level["speedup refined vs cold"] > 0
    # noise-free: refined and the cold fit both at the record's optimum (the truth), the one
    # pass's cost above it by round-off at most
    cost = level["cost"]
    assert cost["refined at the best"] == 1.0 and cost["cold at the best"] == 1.0
    assert cost["refined x4 at the best"] == 1.0 and level["ms"]["refined x4"] > 0
    assert abs(cost["one pass excess median"]) < 1e-3
    assert "cost over refined's" in printed
    # the cold fit iterates from each of its 4 starts (scipy counts a Jacobian per iteration)
    assert level["iterations"]["cold grey-box x4"] >= 4
    assert math.isfinite(level["iterations"]["refined"])  # also where refine ran no fit
    assert "iterations (median)" in printed


def test_bench_mechanism_measures_a_mechanism_of_two_outputs():
    from aeid_struct.studies.mechanism_bench import bench_mechanism

    rows = bench_mechanism(seconds=3, noises=(0.0,), records=2, timed=1,
                           cases=["cart-pole, both outputs"], progress=None)
    (row,) = rows
    assert row["identifiability"]["rank"] == 4
    assert row["identifiability"]["identifiable"] == ["M", "m", "l", "b"]
    level = row["levels"][0]
    # noise-free: the joint refinement reaches the truth; n4sid has no row for two channels
    assert max(level["errors"]["refined"]) < 1e-5
    assert all(e != e for e in level["errors"]["n4sid"])          # NaN: not measured
    assert level["failed"]["n4sid"] == 2 and level["ms"]["cold grey-box x4"] > 0
    # several channels: refine runs the joint fit from the one pass (at least the iteration
    # that finds it converged), the cold fit from each of its 4 starts
    assert level["iterations"]["refined"] >= 1 and level["iterations"]["cold grey-box x4"] >= 4


def test_the_help_names_every_case():
    from aeid_struct.cli.parser import build_parser
    from aeid_struct.studies.mechanism_bench import CASES

    text = " ".join(build_parser()._subparsers._group_actions[0].choices[
        "bench-mechanism"].format_help().split())
    for case in CASES:
        assert f"'{case.name}'" in text
