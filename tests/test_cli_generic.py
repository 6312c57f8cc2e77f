"""``aeid-struct identify RECORD --order N``: any SISO record through the shipped generic
identifiers, end to end (CSV and .npy files, printout, JSON, figure), and its one-line errors."""

import json
import re

import numpy as np
import pytest
import scipy.signal
from problems import pi_loop

import aeid_struct as ae
from aeid_struct.cli import generic_names, main, shipped_names
from aeid_struct.cli.identify_any import transfer_function
from aeid_struct.simulation import fit_initial

# The simulated lab system: order 2 with a zero, lightly damped, sampled at DT, an output
# offset, an input delay of DELAY samples, a random staircase input, 1 % noise.
DT, STEPS, DELAY, OFFSET = 0.05, 800, 4, 1.5
WN, ZETA = 3.0, 0.3
A_TRUE = np.array([[0.0, 1.0], [-WN ** 2, -2 * ZETA * WN]])
B_TRUE, C_TRUE, D_TRUE = np.array([0.0, 1.0]), np.array([2 * WN ** 2, 1.0]), 0.0


def _record(seed=1, noise=0.01):
    """``(t, u, y)`` of the lab system (time starts at 10 s: mid-experiment)."""
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.uniform(-1.0, 1.0, STEPS // 40), 40)
    delayed = np.concatenate([np.zeros(DELAY), u[:-DELAY]])
    y = ae.simulate(A_TRUE, B_TRUE, C_TRUE, D_TRUE, delayed, DT) + OFFSET
    y = y + noise * np.std(y) * rng.standard_normal(STEPS)
    return 10.0 + DT * np.arange(STEPS), u, y


def _write_csv(path, header, columns):
    rows = "\n".join(",".join(f"{v:.17g}" for v in row) for row in np.column_stack(columns))
    path.write_text(header + "\n" + rows + "\n")
    return str(path)


def _refused(argv, capsys) -> str:
    """Run ``argv``; it must end with status 2 and exactly one ``aeid-struct: error:`` line."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0] == f"aeid-struct: error: {exit_info.value}"
    return lines[0]


def test_the_help_lists_leg_and_generic_identifiers_apart(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["identify", "--help"])
    assert exit_info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    # the generic identifiers are named where --order is explained, the leg ones where MODEL is
    assert "generic identifiers (generic-1, generic-2, generic-3, generic-4)" in text
    assert "shipped leg identifier: " + ", ".join(shipped_names()) in text
    assert generic_names() == ["generic-1", "generic-2", "generic-3", "generic-4"]
    assert not set(generic_names()) & set(shipped_names())
    for option in ("--order", "--dt", "--no-refine", "--delay", "--max-delay", "--structure",
                   "--stable", "--figure", "--json"):
        assert option in text


def test_transfer_function_matches_scipy():
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 4):
        A = rng.standard_normal((n, n))
        b, c, d = rng.standard_normal(n), rng.standard_normal(n), float(rng.standard_normal())
        num, den = transfer_function(A, b, c, d)
        num_s, den_s = scipy.signal.ss2tf(A, b[:, None], c[None, :], [[d]])
        np.testing.assert_allclose(den, den_s, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(num, num_s[0], rtol=1e-9, atol=1e-10)


def test_identify_a_csv_record_end_to_end(tmp_path, capsys):
    t, u, y = _record()
    csv = _write_csv(tmp_path / "lab.csv", "t [s],u [V],y [K]", [t, u, y])
    js, png = tmp_path / "out" / "estimate.json", tmp_path / "compare.png"
    assert main(["identify", csv, "--order", "2", "--json", str(js), "--figure", str(png)]) == 0
    out = capsys.readouterr().out
    result = json.loads(js.read_text())
    # the record as read: dt from the t column, the input from the u column
    assert result["dt"] == pytest.approx(DT, rel=1e-12) and result["steps"] == STEPS
    assert result["input"] == "the u column" and result["order"] == 2
    assert result["delay_samples"] == DELAY and result["delay_estimated"] is True
    assert result["delay_seconds"] == pytest.approx(DELAY * DT, rel=1e-12)
    assert result["refined"] is True and result["fit_percent"] > 95.0
    # the model fitted on the first 70 % predicts the rest as well as it fits the whole record
    assert result["holdout_fit_percent"] > result["fit_percent"] - 3.0
    assert "hold-out: fitted on the first 70 %" in out and "does not determine" not in out
    # against the truth: the poles within 2 %, the offset within 2 % of its value
    poles = np.sort_complex(np.linalg.eigvals(np.array(result["A"])))
    true_poles = np.sort_complex(np.linalg.eigvals(A_TRUE))
    assert np.max(np.abs(poles - true_poles) / np.abs(true_poles)) < 0.02
    assert result["offset"] == pytest.approx(OFFSET, rel=0.02)
    # the true model's own fit on this noisy record (initial state and offset fitted): the
    # estimate cannot be much worse than the truth
    truth = fit_initial(A_TRUE, B_TRUE, C_TRUE, D_TRUE, y, u, DT, delay=DELAY, offset=True)
    assert result["fit_percent"] > truth.fit - 0.5
    # the transfer function is the state-space model's (scipy's ss2tf as the oracle)
    A, b, c = (np.array(result[k]) for k in ("A", "b", "c"))
    num_s, den_s = scipy.signal.ss2tf(A, b[:, None], c[None, :], [[result["d"]]])
    np.testing.assert_allclose(result["denominator"], den_s, rtol=1e-9)
    np.testing.assert_allclose(result["numerator"], num_s[0], rtol=1e-8, atol=1e-10)
    # the CLI is the library's one call on the same record
    direct = ae.identify(ae.Record(y, u, DT, t0=10.0), order=2)
    np.testing.assert_allclose(A, direct.A, rtol=1e-9)
    np.testing.assert_allclose(result["x0"], direct.x0, rtol=1e-9, atol=1e-12)
    assert result["fit_percent"] == pytest.approx(direct.fit, rel=1e-9)
    # the printout carries the model, the delay in samples and seconds, x0, offset, fit, time
    for line in ("A =", "b =", "transfer function", f"delay: {DELAY} samples = 0.2 s",
                 f"initial state x0 (at sample {DELAY}) =", "output offset =",
                 f"fit: {result['fit_percent']:.2f} %", "time: ", f"wrote {js}"):
        assert line in out, line
    # the compare figure, and its fit (MATLAB's compare) equal to the estimate's
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000
    assert result["figure"]["fit_percent"] == pytest.approx(result["fit_percent"], abs=1e-6)


def test_identify_npy_files_with_known_delay_mcf_and_no_refinement(tmp_path, capsys):
    _, u, y = _record(seed=2)
    np.save(tmp_path / "y.npy", y)
    np.save(tmp_path / "u.npy", u)
    js = tmp_path / "e.json"
    assert main(["identify", str(tmp_path / "y.npy"), "--u", str(tmp_path / "u.npy"), "--dt",
                 str(DT), "--order", "2", "--delay", str(DELAY), "--structure", "mcf",
                 "--no-refine", "--json", str(js)]) == 0
    out = capsys.readouterr().out
    result = json.loads(js.read_text())
    assert result["delay_samples"] == DELAY and result["delay_estimated"] is False
    assert result["refined"] is False and result["structure"].startswith("MCF(")
    assert result["input"] == f"--u {tmp_path / 'u.npy'}"
    assert "not refined (--no-refine)" in out and f"delay: {DELAY} samples = 0.2 s (given)" in out
    direct = ae.identify(ae.Record(y, u, DT), order=2, delay=DELAY, structure="mcf",
                         refine=False)
    np.testing.assert_allclose(result["A"], direct.A, rtol=1e-9, atol=1e-12)
    # the encoder alone on its own kind of record: a usable model (the refinement makes it exact)
    assert result["fit_percent"] > 80.0


def test_order_auto_reports_the_searched_orders_and_applies_the_rule(tmp_path, capsys):
    t, u, y = _record(seed=3)
    csv = _write_csv(tmp_path / "lab.csv", "t,u,y", [t, u, y])
    js = tmp_path / "e.json"
    assert main(["identify", csv, "--order", "auto", "--no-refine", "--json", str(js)]) == 0
    result = json.loads(js.read_text())
    fits = {int(n): f for n, f in result["order_fits"].items()}
    # the orders from 1 until three in a row improve on none before them by ORDER_TOLERANCE
    top = max(fits)
    assert sorted(fits) == list(range(1, top + 1)) and 4 <= top < 8
    assert max(fits[n] for n in range(top - 2, top + 1)) <= max(
        fits[n] for n in range(1, top - 2)) + ae.generic.ORDER_TOLERANCE
    best = max(fits.values())
    # ae.identify's rule: the smallest order within ORDER_TOLERANCE points of the best
    assert result["order"] == min(n for n, f in fits.items()
                                  if f >= best - ae.generic.ORDER_TOLERANCE)
    assert "selected by validation fit (order 1: " in capsys.readouterr().out


def _bad_files(tmp_path) -> dict:
    t, u, y = _record()
    f = {"lab.csv": _write_csv(tmp_path / "lab.csv", "t,u,y", [t, u, y]),
         "y.csv": _write_csv(tmp_path / "y.csv", "y", [y]),
         "u2.csv": _write_csv(tmp_path / "u2.csv", "u", [u[:100]]),
         "short.csv": _write_csv(tmp_path / "short.csv", "t,u,y", [t[:12], t[:12], y[:12]]),
         "batch.csv": str(tmp_path / "batch.csv"), "folder": str(tmp_path)}
    np.savetxt(f["batch.csv"], np.vstack([y, y]), delimiter=",")
    return f


GENERIC_ERRORS = [
    # 9 is one above generic.MAX_ORDER, which the parser writes out (it imports no torch)
    (["{lab.csv}", "--order", str(ae.generic.MAX_ORDER + 1)],
     r"identify: argument --order: expected an order 1-8 or auto; got '9'"),
    (["{lab.csv}", "--order", "two"], r"argument --order: expected an order .*; got 'two'"),
    (["{y.csv}", "--order", "2"], r"--dt: RECORD '.*y.csv' has no t column; give its sample "
                                  r"time by --dt DT"),
    (["{lab.csv}", "--order", "2", "--dt", "0.1"], r"--dt 0.1 s disagrees with the t column of "
                                                   r"RECORD '.*lab.csv' \(sampled every 0.05 s\)"),
    (["{lab.csv}", "--order", "2", "--dt", "-1"], r"argument --dt: expected a finite number > 0"),
    (["{lab.csv}", "--order", "2", "--delay", "799"], r"--delay must be at most 798 samples for "
                                                      r"RECORD"),
    (["{lab.csv}", "--order", "2", "--delay", "-1"], r"argument --delay: expected an integer "
                                                     r">= 0; got '-1'"),
    (["{lab.csv}", "--order", "2", "--max-delay", "x"], r"argument --max-delay: expected an "
                                                        r"integer >= 0; got 'x'"),
    (["{lab.csv}", "--order", "2", "--structure", "ocf"], r"argument --structure: invalid "
                                                          r"choice: 'ocf'"),
    (["{lab.csv}", "--order", "2", "--figure", "{folder}"], r"--figure '.*' is a folder; "
                                                            r"expected the PNG file to write"),
    (["{lab.csv}", "--order", "2", "--y", "{y.csv}"], r"identify: --y applies to an identifier "
                                                      r"MODEL, not to --order"),
    (["{lab.csv}", "--order", "2", "--refine", "--allow-outside"], r"identify: --refine, "
                                                                   r"--allow-outside apply to "
                                                                   r"an identifier MODEL"),
    (["{lab.csv}", "--order", "2", "--starts", "3"], r"identify: --starts applies to an "
                                                     r"identifier MODEL"),
    (["{lab.csv}", "--order", "2", "--u", "{y.csv}"], r"--u '.*y.csv' and the u column of "
                                                      r"RECORD '.*lab.csv': give the input once"),
    (["{y.csv}", "--order", "2", "--dt", "0.05", "--u", "{u2.csv}"],
     r"--u file '.*u2.csv' holds \(100,\) values; expected one input of 800 samples"),
    (["{batch.csv}", "--order", "2", "--dt", "0.05"], r"RECORD file '.*batch.csv' holds 2 rows "
                                                      r"of 800 values; expected one record"),
    (["{short.csv}", "--order", "2"], r"identify .*short.csv --order 2: the record has 12 "
                                      r"samples; a model of order 2 needs at least 16 \(twice "
                                      r"its 8 fitted parameters\)"),
    (["/nonexistent.csv", "--order", "1", "--dt", "1"], r"RECORD: file not found: "
                                                        r"'/nonexistent.csv'"),
    # the two uses do not mix: generic options with an identifier, a record without --order
    (["leg-stable", "--y", "{y.csv}", "--dt", "0.1", "--no-refine"],
     r"identify: --dt, --no-refine apply to the generic identifiers: give --order N"),
    (["leg-stable", "--y", "{y.csv}", "--stable"],
     r"identify: --stable applies to the generic identifiers: give --order N"),
    (["{lab.csv}"], r"identify: '.*lab.csv' is a record file: identify it with the generic "
                    r"identifiers by --order N \(or --order auto\)"),
    (["generic-2", "--y", "{y.csv}"], r"model 'generic-2' is a generic identifier \(any system, "
                                      r"any sample time\), not an identifier of one record "
                                      r"grid: identify a record with it by 'aeid-struct "
                                      r"identify RECORD --order 2 --dt DT'"),
]


@pytest.mark.parametrize("argv, match", GENERIC_ERRORS,
                         ids=[" ".join(a[1:]) or a[0] for a, _ in GENERIC_ERRORS])
def test_generic_identify_errors_are_one_line(tmp_path, capsys, argv, match):
    files = _bad_files(tmp_path)
    filled = [re.sub(r"\{([^}]+)\}", lambda hit: files[hit.group(1)], a) for a in argv]
    line = _refused(["identify", *filled], capsys)
    assert re.search(match, line), line


def test_transfer_function_against_scipy_and_at_a_tiny_gain():
    rng = np.random.default_rng(3)
    A, b, c, d = rng.standard_normal((4, 4)), rng.standard_normal(4), rng.standard_normal(4), 0.7
    num, den = transfer_function(A, b, c, d)
    ref_num, ref_den = scipy.signal.ss2tf(A, b[:, None], c[None], [[d]])
    np.testing.assert_allclose(num, ref_num[0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(den, ref_den, rtol=1e-12)
    # 2e-200 / (s^2 + 2 s + 5): linear in c, no cancellation against the denominator
    num, den = transfer_function([[0.0, 1.0], [-5.0, -2.0]], [0.0, 1.0], [2e-200, 0.0], 0.0)
    assert num.tolist() == [0.0, 0.0, 2e-200] and den.tolist() == [1.0, 2.0, 5.0]


def test_identify_a_held_record_with_intersample_zoh(tmp_path, capsys):
    """A DAC-held input (Rao-Garnier, PRBS held 7 samples, scipy's zero-order-hold oracle):
    --intersample zoh gives the system's transfer function; without it the model is the
    first-order hold's, with a spurious high-order numerator; a trained identifier refuses it."""
    num, den, dt = [-6400.0, 1600.0], [1.0, 5.0, 408.0, 416.0, 1600.0], 0.01
    u = np.repeat(np.random.default_rng(0).integers(0, 2, 160) * 2.0 - 1.0, 7)[:1000]
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete(scipy.signal.tf2ss(num, den), dt,
                                                   method="zoh")
    y = scipy.signal.dlsim((Ad, Bd, Cd, Dd, dt), u)[1][:, 0]
    csv = _write_csv(tmp_path / "held.csv", "t,u,y", [dt * np.arange(1000), u, y])
    js = tmp_path / "held.json"
    assert main(["identify", csv, "--order", "4", "--intersample", "zoh", "--json",
                 str(js)]) == 0
    assert "held between samples" in capsys.readouterr().out
    out = json.loads(js.read_text())
    assert out["intersample"] == "zoh"
    np.testing.assert_allclose(out["denominator"], den, rtol=1e-6)
    np.testing.assert_allclose(out["numerator"], [0.0, 0.0, 0.0, *num], atol=1e-5 * 6400)
    assert main(["identify", csv, "--order", "4", "--json", str(js)]) == 0
    assert abs(json.loads(js.read_text())["numerator"][2]) > 1.0
    assert "--intersample applies to the generic identifiers" in _refused(
        ["identify", "leg-stable", "--y", csv, "--intersample", "zoh"], capsys)


def test_identify_a_closed_loop_record_says_so(tmp_path, capsys):
    """A PI loop's record (tests/test_feedback.py): the JSON carries the feedback test, the
    printout and a warning say the record looks closed-loop and the model has no feedthrough;
    an open-loop record's test is in the JSON too, not detected."""
    record = pi_loop(0.1, 0)
    csv = _write_csv(tmp_path / "loop.csv", "t,u,y",
                     [record.dt * np.arange(record.steps), record.u, record.y])
    js = tmp_path / "loop.json"
    with pytest.warns(ae.FeedbackWarning):
        assert main(["identify", csv, "--order", "2", "--intersample", "zoh", "--json",
                     str(js)]) == 0
    assert "closed loop: the residuals are correlated with later inputs" in (
        capsys.readouterr().out)
    out = json.loads(js.read_text())
    assert out["feedback"]["detected"] is True and out["feedback"]["refit"] == "no feedthrough"
    assert out["d"] == 0.0
    t, u, y = _record()
    csv = _write_csv(tmp_path / "lab.csv", "t [s],u [V],y [K]", [t, u, y])
    assert main(["identify", csv, "--order", "2", "--json", str(js)]) == 0
    assert "closed loop" not in capsys.readouterr().out
    assert json.loads(js.read_text())["feedback"]["detected"] is False


def test_identify_says_which_modes_the_record_does_not_determine(tmp_path, capsys):
    """Order 4 for bench-generic's record of order 3 under a smooth input (tests/
    test_excitation.py): the printout names the mode (its frequency, from the model's own
    eigenvalues) and ``--order auto``, the JSON carries it; the lab record's JSON has none."""
    from aeid_struct.studies import generic_bench as gb

    record = gb._case_records(4, 0.05, 400, 8, 20_261_123 + 4000 + 500 + 400)[7][0]
    csv = _write_csv(tmp_path / "smooth.csv", "t,u,y",
                     [record.dt * np.arange(record.steps), record.u, record.y])
    js = tmp_path / "smooth.json"
    with pytest.warns(ae.UnexcitedModeWarning):
        assert main(["identify", csv, "--order", "4", "--json", str(js)]) == 0
    printed = capsys.readouterr().out
    assert "not determined by the record" in printed and "--order auto" in printed
    out = json.loads(js.read_text())
    assert len(out["unexcited"]) == 1
    poles = np.linalg.eigvals(np.asarray(out["A"]))
    assert np.min(np.abs(poles.imag - out["unexcited"][0]["frequency_rad_s"])) < 1e-9
    assert out["unexcited"][0]["gain"] > 10
    t, u, y = _record()
    csv = _write_csv(tmp_path / "lab.csv", "t [s],u [V],y [K]", [t, u, y])
    assert main(["identify", csv, "--order", "2", "--json", str(js)]) == 0
    assert "not determined" not in capsys.readouterr().out
    assert json.loads(js.read_text())["unexcited"] == []


def _two_by_two(seed=0, steps=800, dt=0.05):
    """``(t, U (steps, 2), Y (steps, 2), A)`` of a 2x2 order-2 system with 1 % noise, the
    second input one sample late (scipy-expm FOH simulation through ``ae.simulate``)."""
    rng = np.random.default_rng(seed)
    U = np.repeat(rng.choice([-1.0, 1.0], (steps // 10, 2)), 10, axis=0)
    A = np.array([[0.0, 1.0], [-4.0, -0.8]])
    B, C = np.array([[0.0, 1.0], [1.0, 0.5]]), np.array([[1.0, 0.0], [0.5, 1.0]])
    late = np.concatenate([[0.0], U[:-1, 1]])
    Y = np.column_stack([ae.simulate(A, B[:, 0], C[i], 0.0, U[:, 0], dt)
                         + ae.simulate(A, B[:, 1], C[i], 0.0, late, dt) for i in range(2)])
    Y = Y + 0.01 * Y.std(axis=0) * rng.standard_normal(Y.shape) + np.array([0.3, -1.0])
    return dt * np.arange(steps), U, Y, A


def test_identify_a_record_of_two_inputs_and_two_outputs(tmp_path, capsys):
    """Numbered columns: one model A (2, 2), B (2, 2), C (2, 2), D (2, 2) with a delay per
    input and an offset per output, the library's call on the same arrays."""
    t, U, Y, A = _two_by_two()
    csv = _write_csv(tmp_path / "plant.csv", "t [s],u1 [V],u2 [V],y1,y2",
                     [t, U[:, 0], U[:, 1], Y[:, 0], Y[:, 1]])
    js, png = tmp_path / "plant.json", tmp_path / "plant.png"
    assert main(["identify", csv, "--order", "2", "--json", str(js), "--figure",
                 str(png)]) == 0
    out = capsys.readouterr().out
    result = json.loads(js.read_text())
    assert (result["outputs"], result["inputs"], result["order"]) == (2, 2, 2)
    assert np.shape(result["B"]) == (2, 2) and np.shape(result["D"]) == (2, 2)
    assert result["delay_samples"] == [0, 1]
    np.testing.assert_allclose(result["offset"], [0.3, -1.0], atol=0.02)
    assert min(result["fit_percent"]) > 97.0
    assert result["unexcited"] == []
    poles = np.sort_complex(np.linalg.eigvals(np.array(result["A"])))
    np.testing.assert_allclose(poles, np.sort_complex(np.linalg.eigvals(A)), rtol=0.02)
    direct = ae.identify(ae.Record(Y, U, 0.05), order=2)
    np.testing.assert_allclose(result["fit_percent"], direct.fit, rtol=1e-9)
    for line in ("2 outputs, 2 inputs", "observer form of y", "B =", "D =",
                 "delay per input: u1: 0 samples", "u2: 1 samples = 0.05 s",
                 "output offsets = y1:", "fit: y1:", "wrote"):
        assert line in out, line
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_identify_stable_holds_the_model_stable(tmp_path, capsys):
    """--stable: the library's stable=True (a stable plant: the constraint changes nothing,
    nothing to report); one channel goes to the modal form; a plant with a pole at +0.5 (ae's
    FOH simulation) comes back stable, and the JSON and the printout say its best model is
    not."""
    t, U, Y, _ = _two_by_two()
    csv = _write_csv(tmp_path / "plant.csv", "t,u1,u2,y1,y2",
                     [t, U[:, 0], U[:, 1], Y[:, 0], Y[:, 1]])
    js = tmp_path / "plant.json"
    assert main(["identify", csv, "--order", "2", "--stable", "--json", str(js)]) == 0
    result = json.loads(js.read_text())
    assert result["stable"] is True and result["unstable"] is None
    assert np.all(np.linalg.eigvals(np.array(result["A"])).real < 0)
    direct = ae.identify(ae.Record(Y, U, 0.05), order=2, stable=True)
    np.testing.assert_allclose(result["fit_percent"], direct.fit, rtol=1e-9)
    y = ae.simulate(np.array([[0.0, 1.0], [-4.0, -0.8]]), np.array([0.0, 1.0]),
                    np.array([1.0, 0.0]), 0.0, U[:, 0], 0.05)
    one = _write_csv(tmp_path / "one.csv", "t,u,y", [t, U[:, 0], y])
    assert main(["identify", one, "--order", "2", "--stable", "--json", str(js)]) == 0
    assert json.loads(js.read_text())["structure"].startswith("MCF(")
    A = np.array([[0.5, 0.0], [0.0, -2.0]])
    u = U[:300, 0]
    Y = np.column_stack([ae.simulate(A, np.ones(2), c, 0.0, u, 0.05)
                         for c in ([1.0, 1.0], [1.0, -0.5])])
    Y = Y + 0.01 * Y.std(axis=0) * np.random.default_rng(1).standard_normal(Y.shape)
    grows = _write_csv(tmp_path / "grows.csv", "t,u,y1,y2", [t[:300], u, Y[:, 0], Y[:, 1]])
    capsys.readouterr()
    with pytest.warns(ae.StableOnlyWarning, match=r"best model is unstable"):
        assert main(["identify", grows, "--order", "2", "--stable", "--json", str(js)]) == 0
    result = json.loads(js.read_text())
    assert max(result["unstable"]["poles_real"]) == pytest.approx(0.5, abs=0.01)
    assert np.all(np.linalg.eigvals(np.array(result["A"])).real < 0)
    assert "held stable: the record's best model is unstable" in capsys.readouterr().out


def test_numbered_columns_refused_where_they_do_not_fit(tmp_path, capsys):
    t, U, Y, _ = _two_by_two(steps=300)
    gap = _write_csv(tmp_path / "gap.csv", "t,u1,u3,y", [t, U[:, 0], U[:, 1], Y[:, 0]])
    assert "the u columns are numbered [1, 3]" in _refused(
        ["identify", gap, "--order", "2"], capsys)
    mixed = _write_csv(tmp_path / "mixed.csv", "t,u,u1,y", [t, U[:, 0], U[:, 1], Y[:, 0]])
    assert "expected one unnumbered u column" in _refused(
        ["identify", mixed, "--order", "2"], capsys)
    two = _write_csv(tmp_path / "two.csv", "t,u1,u2,y1,y2",
                     [t, U[:, 0], U[:, 1], Y[:, 0], Y[:, 1]])
    u = _write_csv(tmp_path / "u.csv", "u", [U[:, 0]])
    assert "give the inputs as its numbered columns" in _refused(
        ["identify", two, "--order", "2", "--u", u], capsys)
    assert "identify it with --order N" in _refused(
        ["identify", "leg-stable-any", "--y", two], capsys)
