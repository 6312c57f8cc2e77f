"""Tests for ``aeid_struct/cli/user_maps.py``: ``--maps FILE.py`` gives the command line the
maps of an identifier file of the user's own mechanism. Oracles: the library's own
``ae.load(path, maps={name: structure.function})`` on the same record (the printed parameters
are its estimate's), the file's recorded SHA-256 (another Function of the same name is
refused), and the user's file run as ``__main__`` never (its training code would exit)."""

from __future__ import annotations

import ast

import numpy as np
import pytest
from helpers import write_machine

import aeid_struct as ae
from aeid_struct.cli import main
from aeid_struct.cli.errors import InputError
from aeid_struct.cli.user_maps import read_maps


@pytest.fixture(scope="module")
def machine(tmp_path_factory):
    """The user's script and identifier file, and a noisy PRBS record of one plant as CSV."""
    folder = tmp_path_factory.mktemp("machine")
    script, path, structure = write_machine(folder)
    rec = ae.data.records(ae.ParameterFamily(structure), 1, steps=100, dt=0.02,
                          excitation_kind="prbs", seed=5, noise=0.01)
    csv = folder / "rec.csv"
    np.savetxt(csv, np.stack([rec.u[0], rec.y[0]], 1), delimiter=",", header="u,y",
               comments="")
    return script, path, structure, rec, csv


def test_identify_an_identifier_of_ones_own_mechanism(machine, capsys):
    script, path, structure, rec, csv = machine
    with pytest.raises(SystemExit, match=r"user map 'myplant_y0_u0'.*on the command line: "
                                         r"--maps FILE\.py"):
        main(["identify", str(path), "--y", str(csv)])
    assert main(["identify", str(path), "--y", str(csv), "--maps", str(script),
                 "--refine"]) == 0
    out = capsys.readouterr().out
    printed = ast.literal_eval(out.split("physical: ", 1)[1].splitlines()[0])
    ident = ae.load(path, maps={"myplant_y0_u0": structure.function})
    est = ident.identify(rec.y[0], rec.u[0], refine=True)
    for name in ("m", "k", "d"):
        assert printed[name] == pytest.approx(float(est.physical[name]), abs=1e-6)
        # noise 1 %: the refined parameters near the plant's
        assert printed[name] == pytest.approx(float(rec.systems.params[name][0]), rel=0.05)


def test_another_function_of_the_same_name_is_refused_by_its_hash(machine, tmp_path):
    _, path, _, _, csv = machine
    other, _, _ = write_machine(tmp_path, ratio=2.0)       # the same names, another map
    with pytest.raises(SystemExit, match="maps\\['myplant_y0_u0'\\] is not the Function the "
                                         "file was saved with"):
        main(["identify", str(path), "--y", str(csv), "--maps", str(other)])


def test_the_maps_file_is_collected_by_name_and_not_run_as_main(machine):
    script, _, structure, _, _ = machine
    maps = read_maps(str(script))
    assert list(maps) == ["myplant_y0_u0"]
    assert maps["myplant_y0_u0"].serialize() == structure.function.serialize()


@pytest.mark.parametrize("text, match", [
    ("raise KeyError('J3')\n", r"--maps '.*' raised KeyError while it ran: 'J3'"),
    ("import sys\nsys.exit(4)\n", r"exited \(4\) while it ran"),
    ("x = 1\n", "builds no CasADi map at module level"),
    ("import casadi as ca\nx = ca.SX.sym('x')\nf = ca.Function('g', [x], [x])\n"
     "h = ca.Function('g', [x], [2 * x])\n",
     r"two different CasADi Functions are named 'g' \(in 'f' and 'h'\)"),
])
def test_a_bad_maps_file_is_refused_by_name(tmp_path, text, match):
    script = tmp_path / "bad.py"
    script.write_text(text)
    with pytest.raises(InputError, match=match):
        read_maps(str(script))


def test_maps_in_containers_are_found_and_one_function_twice_is_one(tmp_path):
    script = tmp_path / "same.py"
    script.write_text("import casadi as ca\nx = ca.SX.sym('x')\nf = ca.Function('g', [x], [x])\n"
                      "both = {'a': f, 'b': [f, ca.Function('g', [x], [x]), "
                      "(ca.Function('h', [x], [3 * x]),)]}\n")
    maps = read_maps(str(script))
    assert sorted(maps) == ["g", "h"] and float(maps["h"](2.0)) == 6.0


@pytest.mark.parametrize("argv, match", [
    (["PATH", "--y", "CSV", "--maps", "MISSING.py"], r"--maps: file not found: 'MISSING\.py'"),
    (["PATH", "--y", "CSV", "--maps", "CSV"], r"--maps: expected a Python file \(\.py\)"),
    (["leg-stable", "--y", "CSV", "--maps", "SCRIPT"],
     "the shipped identifier 'leg-stable' needs no maps"),
    (["CSV", "--order", "2", "--maps", "SCRIPT"], "--maps applies to an identifier MODEL"),
])
def test_maps_where_it_does_not_belong_is_refused(machine, argv, match):
    script, path, _, _, csv = machine
    files = {"PATH": str(path), "SCRIPT": str(script), "CSV": str(csv)}
    with pytest.raises(SystemExit, match=match):
        main(["identify", *(files.get(a, a) for a in argv)])


def test_track_reads_the_maps_too(machine):
    # the identifier loads (its maps given again) and is then refused for what it is: trained
    # on records from rest, not on windows cut mid-motion
    script, path, _, _, csv = machine
    with pytest.raises(SystemExit, match="must be trained on windows that start mid-motion"):
        main(["track", "--model", str(path), "--maps", str(script), "--y", str(csv)])
