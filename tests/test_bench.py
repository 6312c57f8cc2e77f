"""The identification benchmark's table: every column defined under it (what a failure is, by
baselines.failure's rules), '-' for a parameter the subsystem does not contain, no bare nan."""

import inspect
import math

import pytest

from aeid_struct import baselines
from aeid_struct.studies.bench import (
    IDENTIFICATION_LEGEND,
    bench_identification,
    format_identification_table,
)


def _row(subsystem, method, params, *, step_mean=1e-4, failure_rate=0.0, speedup=None):
    row = {"subsystem": subsystem, "noise": 0.05, "method": method, "count": 20,
           "step_mean": step_mean, "step_median": math.inf if math.isnan(step_mean) else 2e-4,
           "params_median": params, "failure_rate": failure_rate, "median_ms": 0.4,
           "p95_ms": 0.6}
    if speedup is not None:
        row["encoder_speedup"] = speedup
    return row


def _cells(line):
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_table_marks_missing_parameters_and_empty_averages():
    bench = {"results": [
        _row("stable", "encoder", {"k": 0.006, "d": 0.009, "m": 0.01}),
        _row("unstable", "encoder", {"k": 4.11, "m": 11.43}),
        _row("unstable", "n4sid", {"k": math.nan, "m": math.nan}, step_mean=math.nan,
             failure_rate=1.0, speedup=12.2),
    ], "throughput_per_s": {"stable": 7e4}}
    text = format_identification_table(bench)
    assert "nan" not in text.lower()
    lines = text.splitlines()
    header = _cells(lines[0])
    stable, unstable, failed = (_cells(line) for line in lines[2:5])
    assert all(len(c) == len(header) for c in (stable, unstable, failed))
    col = {name: header.index(name) for name in
           ("Δk % (median, ok)", "Δd %", "Δm %", "step error (mean, ok)", "failures")}
    assert [stable[col[c]] for c in ("Δk % (median, ok)", "Δd %", "Δm %")] == \
        ["0.006", "0.009", "0.010"]
    assert [unstable[col[c]] for c in ("Δk % (median, ok)", "Δd %", "Δm %")] == \
        ["4.110", "-", "11.430"]
    assert failed[col["Δk % (median, ok)"]] == "n/a" and failed[col["Δd %"]] == "-"
    assert failed[col["step error (mean, ok)"]] == "n/a"
    assert failed[col["failures"]] == "100.0%" and failed[-1] == "12.2x"
    assert text.endswith(IDENTIFICATION_LEGEND)
    assert IDENTIFICATION_LEGEND not in format_identification_table(bench, legend=False)


def test_legend_defines_every_column_and_states_the_failure_rule():
    header = format_identification_table({"results": [], "throughput_per_s": {}}) \
        .splitlines()[0]
    for column in ("noise", "step error", "mean, ok", "median, all", "Δk / Δd / Δm",
                   "failures", "median / p95 ms", "baseline / encoder time",
                   "encoder + refine"):
        assert column in IDENTIFICATION_LEGEND, column
    assert "failures" in header and "Δd %" in header
    assert "baselines.failure" in IDENTIFICATION_LEGEND
    # the threshold the legend states is the one the rule applies
    tol = inspect.signature(baselines.failure).parameters["step_tol"].default
    assert f"step error above {tol:g}" in IDENTIFICATION_LEGEND
    assert '"-": the subsystem does not contain the parameter' in IDENTIFICATION_LEGEND


@pytest.mark.slow
def test_bench_rows_of_the_rotational_leg_show_no_d():
    bench = bench_identification(count=2, noises=(0.0,), subsystems=("unstable",),
                                 progress=False)
    assert all("d" not in r["params_median"] and set(r["params_median"]) == {"k", "m"}
               for r in bench["results"])
    lines = format_identification_table(bench, legend=False).splitlines()
    header = _cells(lines[0])
    rows = [_cells(line) for line in lines[2: 2 + len(bench["results"])]]
    assert len(rows) == 6 and all(r[header.index("Δd %")] == "-" for r in rows)
    assert "nan" not in "\n".join(lines).lower()
    # noise-free: the refinement is exact, its k and m errors print as 0.000
    refine = next(r for r in rows if r[2] == "encoder + refine")
    assert refine[header.index("Δk % (median, ok)")] == "0.000"
    # the roofline: the encoder's FLOPs counted by torch against the closed form below, the
    # achieved rate a fraction of the measured peak
    from aeid_struct.identification import load_pretrained
    from aeid_struct.studies.roofline import encoder_flops

    assert bench["encoder_flops_per_record"]["unstable"] == encoder_flops(
        load_pretrained("leg-unstable"))
    assert 1e9 < bench["matmul_peak_flops"] < 1e14
    assert "% of the measured fp32 matmul peak" in "\n".join(lines)


def test_encoder_flops_are_the_layers_multiply_adds():
    """A one-layer encoder's FLOPs in closed form: the convolution's 2 k c_in c_out per output
    sample and the dense layers' 2 m n (torch's counter counts matrix products and
    convolutions, not the activations)."""
    from types import SimpleNamespace

    import torch

    from aeid_struct.encoder import Encoder, EncoderConfig
    from aeid_struct.studies.roofline import encoder_flops

    cfg = EncoderConfig(steps=40, outputs=3, width=4, kernel=5, depth=1, dense=(6,))
    enc = Encoder(cfg)
    convs = [m for m in enc.modules() if isinstance(m, torch.nn.Conv1d)]
    linears = [m for m in enc.modules() if isinstance(m, torch.nn.Linear)]
    expected = 0
    for m in convs:          # each convolution's output length, from the module itself
        length = m(torch.zeros(1, m.in_channels, 40)).shape[-1]
        expected += 2 * m.kernel_size[0] * m.in_channels * m.out_channels * length
    expected += sum(2 * m.in_features * m.out_features for m in linears)
    assert encoder_flops(SimpleNamespace(encoder=enc), batch=8) == expected
