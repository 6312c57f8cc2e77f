"""The robot-leg study's main job: each run writes into a folder of its own kind and says which
run made its outputs; a time budget that fits too few epochs trains on to a floor and warns."""

import functools
import hashlib
import json
import re
from datetime import datetime, timezone
from pathlib import Path

import pytest

import aeid_struct
from aeid_struct.cli import main
from aeid_struct.studies import leg_paper as study
from aeid_struct.training import UndertrainedWarning

SHIPPED = Path(aeid_struct.__file__).parent / "pretrained"


def _sha256(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


@pytest.fixture
def tiny_training(monkeypatch):
    """The study's networks and settings on 200 records instead of 10^4 (seconds, not
    minutes); everything else as the main job runs it."""
    monkeypatch.setattr(study, "train_leg", functools.partial(study.train_leg, count=200))


def test_study_training_config_floors_a_time_budget_only():
    timed = study.training_config("stable", seconds=150.0, min_epochs=100, target_loss=1e-5)
    assert (timed.seconds, timed.min_epochs, timed.target_loss) == (150.0, 100, 1e-5)
    assert timed.threads == 1 and timed.epochs == 100_000
    counted = study.training_config("stable", seconds=150.0, epochs=7, min_epochs=100)
    assert (counted.seconds, counted.epochs, counted.min_epochs) == (None, 7, 1)
    # the main job's floors leave a quiet machine's epochs alone (150 s at ~0.9 s per epoch)
    assert all(60 <= v <= 120 for v in study.MIN_EPOCHS.values())


@pytest.mark.slow
def test_pretrained_run_writes_its_own_folder_and_names_its_identifiers(tmp_path):
    # an earlier trained run beside it, and stale outputs in the folder this run writes to
    trained = tmp_path / "trained"
    trained.mkdir()
    (trained / "leg-stable.aeid").write_bytes(b"an earlier run's identifier")
    (trained / "leg_study.json").write_text('{"earlier": true}')
    folder = tmp_path / "pretrained"
    folder.mkdir()
    for name in ("fig4_error_vs_size.png", "leg-stable.aeid", "leg_study.json"):
        (folder / name).write_bytes(b"stale")
    (folder / "notes.txt").write_text("the user's own file")

    result = study.run(pretrained=True, seconds=300.0, seed=0, out=tmp_path, validation=20,
                       progress=False, command="aeid-struct leg --pretrained")

    # the earlier trained run is untouched; this run's folder holds this run's files only
    assert (trained / "leg-stable.aeid").read_bytes() == b"an earlier run's identifier"
    assert (trained / "leg_study.json").read_text() == '{"earlier": true}'
    assert sorted(p.name for p in folder.iterdir()) == ["fig3_leg_scenario.png",
                                                        "leg_study.json", "notes.txt"]
    run = result["run"]
    assert run["files"] == [str(folder / "fig3_leg_scenario.png"),
                            str(folder / "leg_study.json")]
    assert json.loads((folder / "leg_study.json").read_text()) == json.loads(json.dumps(result))
    assert run["command"] == "aeid-struct leg --pretrained" and run["budget"] is None
    assert run["folder"] == str(folder) and run["seed"] == 0
    date = datetime.fromisoformat(run["date"])
    assert date.tzinfo == timezone.utc
    # which identifiers: the shipped names and the SHA-256 of the files they were read from
    for sub in ("stable", "unstable"):
        assert run["identifiers"][sub] == {
            "shipped": f"leg-{sub}-ccf", "sha256": _sha256(SHIPPED / f"leg-{sub}-ccf.aeid")}
    assert result["train_epochs"] == {"stable": 0, "unstable": 0}
    assert result["warnings"] == []


@pytest.mark.slow
def test_trained_run_records_its_identifier_files_and_the_pretrained_run_leaves_them(
        tmp_path, tiny_training):
    result = study.run(pretrained=False, seconds=300.0, epochs=2, seed=3, out=tmp_path,
                       validation=20, progress=False, command="aeid-struct leg --epochs 2")
    folder = tmp_path / "trained"
    names = ["leg-stable.aeid", "leg-unstable.aeid", "fig3_leg_scenario.png",
             "leg_study.json"]
    assert result["run"]["files"] == [str(folder / n) for n in names]
    assert sorted(p.name for p in folder.iterdir()) == sorted(names)
    assert result["train_epochs"] == {"stable": 2, "unstable": 2}
    assert result["run"]["budget"] == {"epochs": 2} and result["warnings"] == []
    for sub in ("stable", "unstable"):
        entry = result["run"]["identifiers"][sub]
        path = folder / f"leg-{sub}.aeid"
        assert entry["file"] == str(path) and entry["sha256"] == _sha256(path)
        assert entry["trained"] == f"leg-{sub}" and entry["epochs"] == 2
        saved = aeid_struct.Identifier.load(path)
        assert saved.meta["train"]["best_holdout_loss"] == entry["best_holdout_loss"]
        assert saved.meta["command"] == "aeid-struct leg --epochs 2"
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    study.run(pretrained=True, seconds=300.0, seed=0, out=tmp_path, validation=20,
              progress=False)
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    # a trained run without saving leaves no identifier of an earlier run beside its results
    again = study.run(pretrained=False, seconds=300.0, epochs=1, seed=3, out=tmp_path,
                      validation=20, progress=False, save=False)
    assert sorted(p.name for p in folder.iterdir()) == ["fig3_leg_scenario.png",
                                                        "leg_study.json"]
    assert again["run"]["identifiers"]["stable"]["file"] is None


@pytest.mark.slow
def test_time_budget_too_small_trains_to_the_floor_and_the_command_warns(
        tmp_path, tiny_training, monkeypatch, capsys):
    # 2 ms cannot hold one epoch: the floor (2 epochs here) applies, and the held-out loss
    # of a 2-epoch run is far above any target a full run reaches
    monkeypatch.setattr(study, "MIN_EPOCHS", {"stable": 2, "unstable": 2})
    monkeypatch.setattr(study, "TARGET_LOSS", {"stable": 1e-9, "unstable": 1e-9})
    with pytest.warns(UndertrainedWarning) as caught:
        result = study.run(pretrained=False, seconds=0.004, seed=0, out=tmp_path,
                           validation=20, progress=False)
    assert result["train_epochs"] == {"stable": 2, "unstable": 2}
    notes = result["warnings"]
    assert [str(w.message) for w in caught] == notes and len(notes) == 4
    for i, sub in enumerate(("stable", "unstable")):
        best = result["run"]["identifiers"][sub]["best_holdout_loss"]
        assert re.fullmatch(rf"leg-{sub}: the 0.002 s training budget fit only 1 epoch "
                            r"\([0-9.]+ s each; a busy machine\?\); the run trained on to "
                            r"min_epochs=2, [0-9.]+ s in all", notes[2 * i])
        assert notes[2 * i + 1].startswith(
            f"leg-{sub}: best held-out loss {best:.3e} after 2 epochs (the 0.002 s budget, ")
        assert "is above the expected 1.000e-09: the identifier is under-trained" \
            in notes[2 * i + 1]
    assert result["run"]["budget"] == {"seconds": 0.004, "min_epochs": {"stable": 2,
                                                                        "unstable": 2},
                                       "target_loss": {"stable": 1e-9, "unstable": 1e-9}}

    # the command prints every warning beside the table, and every file it wrote
    capsys.readouterr()
    assert main(["leg", "--seconds", "0.004", "--validation", "20", "--quiet", "--out",
                 str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count("WARNING (under-trained): leg-") == 4
    assert "stable: training" in out and ", 2 epochs, identification" in out
    folder = tmp_path / "trained"
    written = [folder / n for n in ("leg-stable.aeid", "leg-unstable.aeid",
                                    "fig3_leg_scenario.png", "leg_study.json")]
    assert "\nwrote " + ", ".join(map(str, written)) + "\n" in out
    assert all(p.is_file() for p in written)
