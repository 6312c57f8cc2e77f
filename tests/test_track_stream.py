"""Tests for ``aeid_struct/cli/track_stream.py`` (``aeid-struct track --y``) and
``studies.wear.stream_study``: a measured stream of the shipped drive train (two angles, one
torque) tracked window by window, and its refusals; with ``physical_head.centred``, the
encoder's view of an integrating mechanism's records.

Oracles: the drive train's own linearisation simulated with a drifting stiffness
(``studies.wear.drifting``, checked against the nonlinear model in tests/test_mechanism.py),
the true parameters, and ``Identifier.identify`` of each window for the tracker's estimates.
"""

from __future__ import annotations

import csv
import json
import re

import numpy as np
import pytest

import aeid_struct as ae
from aeid_struct.cli import main
from aeid_struct.studies.wear import drifting
from symbolic import mechanisms

TRUTH = {"J1": 0.03, "J2": 0.1, "k": 150.0, "c": 0.2, "b": 0.05}
DT, N = 0.005, 900


def _stream(k_end: float = 150.0, seed: int = 0):
    """``u (N,), y (N, 2)``: PRBS torque, both angles from rest, k held for 400 samples, then
    ramping to ``k_end`` over 300."""
    rng = np.random.default_rng(seed)
    ends = np.cumsum(rng.integers(3, 13, size=N))
    u = rng.choice([-1.0, 1.0], size=N)[np.searchsorted(ends, np.arange(N), side="right")]
    ramp = np.clip((np.arange(N) - 400) / 300, 0.0, 1.0)
    p = {k: np.full(N, v) for k, v in TRUTH.items()}
    p["k"] = TRUTH["k"] + (k_end - TRUTH["k"]) * ramp
    y = np.stack([drifting(mechanisms.drive_train(), p, u, DT, output=o, q=[0, 0])
                  for o in (0, 1)], axis=1)
    return u, y


def _files(tmp_path, u, y, *, columns: bool = True):
    t = DT * np.arange(len(u))
    names = []
    for o in range(y.shape[1]):
        path = tmp_path / f"y{o}.csv"
        data = np.stack([t, u, y[:, o]], 1) if columns else y[:, o, None]
        np.savetxt(path, data, delimiter=",", header="t,u,y" if columns else "", comments="")
        names.append(str(path))
    return names


@pytest.fixture(scope="module")
def drive_train():
    return ae.load_pretrained("drive-train")


def test_a_measured_stream_is_tracked_with_a_mechanism_identifier(tmp_path, capsys,
                                                                   drive_train):
    u, y = _stream(k_end=100.0)
    files = _files(tmp_path, u, y)
    out = tmp_path / "out"
    # seven windows: the light smoothing (a physical structure's default is heavier), so that
    # the spring's fall shows within them
    assert main(["track", "--model", "drive-train", "--y", *files, "--baseline", "2",
                 "--hop", "100", "--median", "3", "--smoothing", "0.7", "--engine",
                 "identifier", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "stream: 900 samples at dt = 0.005 s (4.5 s), 2 outputs, 1 input" in text
    assert re.search(r"alarm \(J1, J2, k, c, b beyond their limits, 5 % of the reference or 6 "
                     r"standard errors of a window where larger, for 3 windows\): raised at "
                     r"t = ", text)
    # noise-free, a window's standard errors are nil: every limit is the threshold
    assert re.search(r"\nk +[0-9.e+-]+ +[0-9.e+-]+ +-?[0-9.]+ % +5\.00 %\n", text)
    with (out / "track.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 7 and rows[0]["t"] == repr(299 * DT)
    # each window's estimate is the identifier's own on that window (its whole head: a
    # measured stream is not capped at the wear scenario's one iteration); noise-free, the truth
    # where the stiffness holds over the window (the first two)
    for i, row in enumerate(rows):
        window = slice(100 * i, 100 * i + 300)
        est = drive_train.identify((y[window, 0], y[window, 1]), (u[window], u[window]))
        for k in TRUTH:
            assert float(row[k]) == pytest.approx(est.physical[k], rel=1e-9)
            if i < 2:
                assert float(row[k]) == pytest.approx(TRUTH[k], rel=1e-4)
    summary = json.loads((out / "track.json").read_text())
    assert summary["window"] == 300 and summary["hop"] == 100 and summary["alarm_time_s"] > 0
    assert summary["parameters"]["k"]["drift"] < -0.2          # the spring weakened by 33 %
    assert abs(summary["parameters"]["J2"]["drift"]) < 0.05    # the load did not change
    assert summary["sigmas"] == 6.0
    assert {p["limit"] for p in summary["parameters"].values()} == {0.05}
    assert (out / "track.png").stat().st_size > 10_000


def test_an_integrating_record_is_read_the_same_at_any_offset(drive_train):
    # a constant is a free response of the drive train's rigid-body mode: the encoder reads
    # each angle less its first sample, and the fitted initial state absorbs the rest
    u, y = _stream()
    window = slice(300, 600)
    ys, us = (y[window, 0], y[window, 1]), (u[window], u[window])
    moved = tuple(v + 40.0 for v in ys)
    head = drive_train.head
    try:
        drive_train.head = None
        a, b = drive_train.identify(ys, us), drive_train.identify(moved, us)
        for k in TRUTH:
            assert b.physical[k] == pytest.approx(a.physical[k], rel=1e-5)
    finally:
        drive_train.head = head
    a, b = drive_train.identify(ys, us), drive_train.identify(moved, us)
    for k in TRUTH:
        assert b.physical[k] == pytest.approx(a.physical[k], rel=1e-6)
        assert b.physical[k] == pytest.approx(TRUTH[k], rel=1e-4)


@pytest.mark.parametrize("argv, match", [
    (["--y", "{y0}"], r"--y: this identifier reads 2 outputs \(one stream file each\); got 1"),
    (["--y", "{y0}", "{y1}", "--u", "{y0}"], r"--u and a u column in a --y file: give the "
                                              r"input once"),
    (["--y", "{b0}", "{b1}"], r"--u: give the stream's input \(1 file\), or a u column"),
    (["--y", "{s0}", "{s1}"], r"track: y and u must be streams of one length of at least one "
                              r"window \(300 samples\); got 200 and 200"),
    (["--y", "{y0}", "{y1}", "--model", "cart-pole"], r"track --model cart-pole: identifier "
                                                       r"must be trained on windows that start "
                                                       r"mid-motion"),
])
def test_a_stream_is_refused_with_a_reason(tmp_path, capsys, argv, match):
    u, y = _stream()
    names = {}
    for tag, (uu, yy, columns) in {"y": (u, y, True), "b": (u, y, False),
                                   "s": (u[:200], y[:200], True)}.items():
        sub = tmp_path / tag
        sub.mkdir()
        for o, f in enumerate(_files(sub, uu, yy, columns=columns)):
            names[f"{tag}{o}"] = f
    argv = [a.format(**names) for a in argv]
    if "--model" not in argv:
        argv = ["--model", "drive-train", *argv]
    with pytest.raises(SystemExit) as stop:
        main(["track", *argv, "--out", str(tmp_path / "out")])
    assert stop.value.code == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert re.search(match, line), line
