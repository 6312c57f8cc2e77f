"""The aeid-struct command: each subcommand runs, writes what it says, and rejects bad input."""

import json

import numpy as np
import pytest

from aeid_struct.cli import main


def test_demo_writes_png_and_prints_eq16(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "paper Eq. 16" in out and "controllable canonical form" in out
    png = tmp_path / "leg_step_responses.png"
    assert png.stat().st_size > 10_000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow
def test_leg_pretrained_study(tmp_path, capsys):
    assert main(["leg", "--pretrained", "--validation", "100", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "Table I" in out and "| Step error |" in out
    result = json.loads((tmp_path / "pretrained" / "leg_study.json").read_text())
    for sub in ("stable", "unstable"):
        overall = result["table"][sub]["overall"]
        # the shipped identifiers beat the paper's overall step error by far
        assert overall["step"] < 5e-3
        assert result["table"][sub]["latency_ms"] > 0
    assert (tmp_path / "pretrained" / "fig3_leg_scenario.png").stat().st_size > 10_000


def test_train_then_identify_from_csv(tmp_path, capsys):
    model = tmp_path / "m.aeid"
    assert main(["train", "--structure", "ccf:1:descartes", "--family", "poles:1,0",
                 "--dt", "0.05", "--steps", "40", "--count", "200", "--epochs", "2",
                 "--width", "4", "--dense", "8", "--quiet", "--out", str(model)]) == 0
    assert model.exists()
    t = np.arange(40) * 0.05
    np.savetxt(tmp_path / "y.csv", 1 - np.exp(-2 * t), delimiter=",")
    js = tmp_path / "est.json"
    assert main(["identify", str(model), "--y", str(tmp_path / "y.csv"), "--json", str(js)]) == 0
    est = json.loads(js.read_text())
    assert np.shape(est["A"]) == (1, 1) and "fit_percent" in est


def test_bench_writes_json(tmp_path, capsys):
    js = tmp_path / "bench.json"
    assert main(["bench", "--decoder-only", "--batch", "8", "--steps", "20", "--json",
                 str(js)]) == 0
    rows = json.loads(js.read_text())["decoder"]
    assert len(rows) == 2 and all(r["loop_ms"] > 0 for r in rows)


@pytest.mark.parametrize(
    "argv, match",
    [
        (["train", "--structure", "ccf:x", "--family", "poles:1,0", "--dt", "0.1", "--steps",
          "10", "--out", "x.aeid"], "--structure 'ccf:x' is malformed"),
        (["train", "--structure", "ccf:1", "--family", "springs", "--dt", "0.1", "--steps",
          "10", "--out", "x.aeid"], "--family must be"),
        (["identify", "leg-stable", "--y", "/nonexistent.csv"], "--y must be an existing"),
    ],
)
def test_bad_arguments_exit_with_message(argv, match):
    with pytest.raises(SystemExit, match=match):
        main(argv)


@pytest.mark.slow
def test_leg_fig4_small(tmp_path, capsys):
    assert main(["leg", "--pretrained", "--validation", "20", "--fig4", "--fig4-sizes", "40",
                 "80", "--fig4-seconds", "2", "--quiet", "--out", str(tmp_path)]) == 0
    result = json.loads((tmp_path / "pretrained" / "leg_study.json").read_text())
    assert result["fig4"]["sizes"] == [40, 80]
    assert all(len(v) == 2 and all(e > 0 for e in v)
               for v in result["fig4"]["step_error"].values())
    assert (tmp_path / "pretrained" / "fig4_error_vs_size.png").stat().st_size > 10_000


@pytest.mark.slow
def test_bench_quick_compares_all_methods(tmp_path, capsys):
    js = tmp_path / "bench.json"
    assert main(["bench", "--quick", "--count", "6", "--quiet", "--json", str(js)]) == 0
    out = capsys.readouterr().out
    assert "| stable | 5% | encoder + refine |" in out and "n4sid" in out
    result = json.loads(js.read_text())
    methods = {r["method"] for r in result["identification"]["results"]}
    assert methods == {"encoder", "encoder (noise-trained)", "encoder + refine", "n4sid",
                       "least squares (cold)", "CasADi NLP (cold)"}
    for r in result["identification"]["results"]:
        if r["noise"] == 0.0 and r["method"] == "encoder + refine":
            assert r["step_mean"] < 1e-8 and r["failure_rate"] == 0.0
    assert all(v > 0 for v in result["identification"]["throughput_per_s"].values())


def test_identify_a_joint_identifier_from_one_file_per_record(tmp_path, capsys):
    import torch

    import aeid_struct as ae
    from aeid_struct.encoder import Encoder, EncoderConfig
    from symbolic import leg

    torch.manual_seed(0)
    structure = ae.Physical(leg.joint_map(), bounds={"k": (20, 25), "d": (2, 5), "m": (0.5, 1.5)})
    enc = Encoder(EncoderConfig(steps=(60, 20), pool=(3, 1), outputs=3, features=2, width=4,
                                dense=(8,)))
    ident = ae.Identifier(enc.eval(), structure, dt=(0.05, 0.025), theta_mean=torch.zeros(3),
                          theta_scale=torch.ones(3), scale="feature")
    model = ident.save(tmp_path / "joint.aeid")
    legs = ae.LegFamily(subsystem="joint").systems(**{k: [v] for k, v in leg.SCENARIO.items()})
    files = []
    for r, (steps, dt) in enumerate(((60, 0.05), (20, 0.025))):
        y = ae.simulate(legs.A[0, r], legs.b[0, r], legs.c[0, r], 0.0, np.ones(steps), dt)
        files.append(str(tmp_path / f"y{r}.csv"))
        np.savetxt(files[-1], y, delimiter=",")
    js = tmp_path / "est.json"
    assert main(["identify", str(model), "--y", *files, "--json", str(js)]) == 0
    est = json.loads(js.read_text())
    assert est["records"] == 2 and np.shape(est["A"]) == (2, 2, 2)
    direct = ident.identify([np.loadtxt(f, delimiter=",") for f in files])
    assert est["physical"]["k"] == pytest.approx(direct.physical["k"], rel=1e-12)
    with pytest.raises(SystemExit, match=r"y must be a sequence of 2 records"):
        main(["identify", str(model), "--y", files[0]])
