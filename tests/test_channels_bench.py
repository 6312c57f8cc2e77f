"""The several-channel benchmark rows (studies.channels_bench): a small run scores real models
against the true one, and its table and JSON carry every row."""

import json

import numpy as np

from aeid_struct.studies import channels_bench


def test_a_small_run_scores_the_methods_against_the_true_model(tmp_path):
    rows = channels_bench.bench_channels(cases=("1x1, 3 experiments", "2x2, 200 samples"),
                                         count=2, progress=None)
    by = {(r.case, r.index, r.method): r for r in rows}
    for case in ("1x1, 3 experiments", "2x2, 200 samples"):
        for i in range(2):
            true = by[(case, i, "true")].fit
            assert 90.0 < true < 100.0
            assert by[(case, i, "refined")].fit > true - 1.0
            assert by[(case, i, "one pass")].fit > by[(case, i, "refined")].fit - 1.0
    assert (("1x1, 3 experiments", 0, "n4sid") not in by)      # one record only
    assert np.isfinite(by[("2x2, 200 samples", 0, "n4sid")].fit)
    table = channels_bench.format_channels(rows)
    assert "1x1, 3 experiments" in table and "2x2, 200 samples" in table
    path = channels_bench.write_channels(rows, tmp_path / "rows.json")
    assert len(json.loads(path.read_text())["rows"]) == len(rows)


def test_an_unknown_row_is_refused_by_name():
    import pytest

    with pytest.raises(ValueError, match="cases must be among"):
        channels_bench.bench_channels(cases=("4x4",), count=1, progress=None)


def test_the_coloured_row_holds_the_output_error_fit_near_the_true_model():
    # a low-pass input and AR(1) noise (pole 0.95): the output-error fit is consistent for
    # coloured noise, so refined stays near the true model's validation fit
    rows = channels_bench.bench_channels(cases=("2x2 coloured, low-pass",), count=1,
                                         progress=None)
    by = {r.method: r for r in rows}
    assert 90.0 < by["true"].fit < 100.0
    assert by["refined"].fit > by["true"].fit - 1.0
    assert {r.method for r in rows} == set(channels_bench.METHODS)
