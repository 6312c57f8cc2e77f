"""The one-pass study of ``aeid-struct bench`` in its quick form: the structure of its rows,
tables and JSON, and its numbers against the simulated truth (the noise-free records are fitted
exactly by the least-squares optimum, so every method that reaches it has ~0 error)."""

import json
import math

import numpy as np
import pytest

import aeid_struct as ae
from aeid_struct.identification import Head
from aeid_struct.studies import onepass_bench as ob
from aeid_struct.studies.onepass_tables import ONEPASS_LEGEND, format_onepass_tables


@pytest.fixture(scope="module")
def quick():
    return ob.bench_onepass(quick=True, names=("leg-stable-any",), kinds=("prbs",),
                            progress=False)


def _cells(line):
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_rows_hold_every_method_on_the_same_records(quick):
    entry = quick["identifiers"]["leg-stable-any"]
    assert entry["subsystem"] == "stable" and entry["head"]["fixed"] == {"c1": 0.0}
    rows = entry["rows"]
    assert [(r["kind"], r["noise"]) for r in rows] == [("prbs", 0.0), ("prbs", 0.01)]
    for r in rows:
        assert list(r["methods"]) == list(ob.METHODS)
        for name, m in r["methods"].items():
            assert set(m["median"]) == {"k", "d", "m"}, name
            assert m["records"] == (r["timed"] if name in ob.BASELINES else r["count"])
            assert m["ms"] > 0 and 0.0 <= m["failures"] <= 1.0
        for name in ("encoder", "one pass", "encoder + refine"):
            assert r["methods"][name]["per_s"] > 0
        # the reported time ratio is the ratio of the reported times
        assert math.isclose(r["ls_over_one_pass"], r["methods"]["least squares (cold)"]["ms"]
                            / r["methods"]["one pass"]["ms"])


def test_one_pass_is_at_the_optimum_where_the_encoder_alone_is_not(quick):
    free, noisy = quick["identifiers"]["leg-stable-any"]["rows"]
    enc, one, opt = (free["methods"][m]["median"] for m in ("encoder", "one pass",
                                                              "encoder + refine"))
    # noise-free: the simulated leg is the least-squares optimum; the encoder alone misses it
    assert max(one.values()) < 1e-3 and max(opt.values()) < 1e-6
    assert max(enc.values()) > 1.0
    # a second method: the cold least squares reaches the same truth on these records
    assert max(free["methods"]["least squares (cold)"]["median"].values()) < 1e-4
    assert all(v is None for v in free["vs_optimum"]["one pass"].values())
    # 1 % noise: the optimum no worse than the one pass, both far better than the encoder
    enc, one, opt = (noisy["methods"][m]["median"] for m in ("encoder", "one pass",
                                                               "encoder + refine"))
    for p in ("k", "d", "m"):
        assert 0 < opt[p] <= 1.1 * one[p] + 0.01 and one[p] < 1.0 < enc[p], p
        assert math.isclose(noisy["vs_optimum"]["one pass"][p], one[p] / opt[p])
        assert math.isclose(noisy["vs_optimum"]["encoder"][p], enc[p] / opt[p])
    t = quick["targets"]["leg-stable-any"]
    assert t["noise_free_max_percent"] == max(one for one in
                                              free["methods"]["one pass"]["median"].values())
    assert t["noise_free_met"] is True and t["ls_over_one_pass_min"] > 0


def test_tables_show_every_method_and_define_their_columns(quick):
    text = format_onepass_tables(quick)
    assert "nan" not in text.lower() and text.endswith(ONEPASS_LEGEND)
    lines = text.splitlines()
    acc = next(i for i, s in enumerate(lines) if s.startswith("### leg-stable-any: accuracy"))
    head = quick["identifiers"]["leg-stable-any"]["head"]
    assert f"head: {head['iterations']} iterations, fixed c1 = 0" in lines[acc]
    header = _cells(lines[acc + 2])
    assert header[:2] == ["input", "noise"] and len(header) == 2 + len(ob.METHODS) + 2
    free = _cells(lines[acc + 4])
    assert free[:2] == ["prbs", "0 %"] and free[-1] == "- / - / -"
    assert free[header.index("one pass k / d / m %")] == "0.000 / 0.000 / 0.000"
    t = next(i for i, s in enumerate(lines) if s.startswith("### leg-stable-any: time"))
    theader = _cells(lines[t + 2])
    assert "LS cold / one pass" in theader and "one pass rec/s" in theader
    assert _cells(lines[t + 4])[theader.index("LS cold / one pass")].endswith("x")
    for column in ("input", "noise", "k / d / m %", "[n % fail]", "encoder / optimum", "ms",
                   "LS cold / one pass", "rec/s"):
        assert column in ONEPASS_LEGEND, column
    assert json.loads(json.dumps(quick)) == quick        # JSON as it is


def test_rotational_leg_rows_show_no_d():
    rows = [{"kind": "steps", "noise": 0.01, "count": 4, "timed": 2, "batch": 8,
             "methods": {m: {"median": {"k": 1.5, "m": 2.5}, "failures": 0.0, "records": 4,
                             "ms": 1.0, "per_s": 10.0} for m in ob.METHODS[:3]},
             "vs_optimum": {"encoder": {"k": 2.0, "m": None}, "one pass": {"k": 1.0, "m": 1.0}}}]
    rows[0]["methods"]["one pass"]["failures"] = 0.25
    result = {"settings": {"count": 4, "timed": 2, "batch": 8},
              "identifiers": {"leg-unstable-any": {"subsystem": "unstable", "rows": rows,
                                                   "head_in_file": True,
                                                   "head": {"iterations": 2, "fixed": {}}}}}
    text = format_onepass_tables(result, legend=False)
    line = next(s for s in text.splitlines() if s.startswith("| steps | 1 % |"))
    cells = _cells(line)
    assert cells[2:5] == ["1.500 / 2.500", "1.500 / 2.500 [25 % fail]", "1.500 / 2.500"]
    assert cells[-2:] == ["2.00 / -", "1.00 / 1.00"]
    assert "stored in the file" in text and ONEPASS_LEGEND not in text


def test_a_file_head_is_kept_and_a_missing_one_is_added():
    ident = ae.load_pretrained("leg-unstable-any")
    ident.head = None
    headed = ob.with_head(ident, "unstable")
    assert headed is not ident and ident.head is None
    assert headed.head == Head(iterations=ob.HEAD_ITERATIONS, fixed={"a1": 0.0, "c1": 0.0})
    own = Head(iterations=2, fixed={"a1": 0.0, "c1": 0.0})
    ident.head = own
    assert ob.with_head(ident, "unstable") is ident and ident.head is own
    alone = ob.encoder_alone(ident)
    assert alone.head is None and ident.head is own
    y = np.linspace(0.0, 1.0, ident.steps) ** 2
    np.testing.assert_array_equal(alone.identify(y, np.ones_like(y)).A,
                                  ob.encoder_alone(headed).identify(y, np.ones_like(y)).A)
    family = ob.leg_family(ident, "unstable")
    lo, hi = ident.meta["training_range"]["physical"]["k"][:2]
    assert family.ranges["k"] == (lo, hi)


@pytest.mark.parametrize("kw, match", [
    ({"names": ("leg-stable",)}, "names must be some of"),
    ({"kinds": ("sine",)}, "kinds must be some of"),
    ({"count": 4, "timed": 5}, r"timed must be <= count \(4\)"),
    ({"batch": 0}, "batch must be a positive integer"),
])
def test_bad_arguments_name_what_is_wrong(kw, match):
    with pytest.raises(ValueError, match=match):
        ob.bench_onepass(progress=False, **kw)


def test_bench_command_runs_the_study_alone_and_writes_it(tmp_path, capsys):
    from aeid_struct.cli import main

    js = tmp_path / "bench.json"
    assert main(["bench", "--onepass-only", "--quick", "--quiet", "--identifiers",
                 "leg-unstable-any", "--kinds", "steps", "--noise", "0.01", "--records", "6",
                 "--timed", "3", "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert "### leg-unstable-any: accuracy" in out and "Decoder" not in out
    result = json.loads(js.read_text())
    assert set(result) == {"onepass"}
    (row,) = result["onepass"]["identifiers"]["leg-unstable-any"]["rows"]
    assert row["count"] == 6 and row["timed"] == 3 and row["noise"] == 0.01
    assert set(row["methods"]["n4sid"]["median"]) == {"k", "m"}
    with pytest.raises(SystemExit, match="exclude each other"):
        main(["bench", "--onepass-only", "--decoder-only"])
