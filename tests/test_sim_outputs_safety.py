"""What ``impress simulate`` and the sample cache may replace (a hostile-input audit found a
user's notes inside a simulation's ``frames`` folder deleted on a re-run, an unmarked folder of
a lab's own files adopted as an old simulation and replaced whole, and ``demo --cache`` deleting
a project folder it had not made); the bitrate and a target's faces range-checked."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from impress_gui import cli
from impress_gui.core.base.errors import FormatError, ImpressError
from impress_gui.core.calibration.target import MAX_FACES, TargetModel, default_target

#: a coarse, fast scene (0.5 mm grid, 40 mm/s: 58 frames): what is checked is the folder, not
#: the frames (the default 0.1 mm grid at 13 mm/s rendered 150 frames, 7 s a run)
TINY = ["--preset", "flat", "--format", "frames", "--resolution", "160x90", "--length-mm", "60",
        "--speed", "40", "--grid-mm", "0.5"]


def _sim(out: Path, capsys, *more: str) -> tuple[int, str]:
    rc = cli.main(["simulate", str(out), *TINY, *more])
    return rc, capsys.readouterr().err


@pytest.fixture(scope="module")
def tiny_sim(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim") / "s"
    assert cli.main(["simulate", str(out), *TINY]) == 0
    return out


def _tree(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_notes_inside_a_simulations_frames_folder_are_not_deleted(tiny_sim, tmp_path, capsys):
    sim = tmp_path / "s"
    shutil.copytree(tiny_sim, sim)
    (sim / "frames" / "case_notes.txt").write_text("mine\n")
    before = _tree(sim)
    rc, err = _sim(sim, capsys)
    assert rc != 0 and "E-OUTPUT-NOT-EMPTY" in err and "Traceback" not in err
    assert _tree(sim) == before
    # without the notes the same folder is a simulation to replace
    (sim / "frames" / "case_notes.txt").unlink()
    rc, err = _sim(sim, capsys)
    assert rc == 0, err


def test_a_lab_folder_with_simulator_names_is_not_adopted(tiny_sim, tmp_path, capsys):
    lab = tmp_path / "lab"
    lab.mkdir()
    (lab / "scan.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 the real scan")
    (lab / "picks.json").write_text('{"picked": "by the examiner"}')
    (lab / "truth.json").write_text('{"notes": "our own ground truth"}')
    before = _tree(lab)
    rc, err = _sim(lab, capsys)
    assert rc != 0 and "E-OUTPUT-NOT-EMPTY" in err
    assert _tree(lab) == before
    # a simulator's truth.json whose video hash is not the video's is not adopted either
    doc = json.loads((tiny_sim / "truth.json").read_text())
    (lab / "truth.json").write_text(json.dumps(doc))
    before = _tree(lab)
    rc, err = _sim(lab, capsys)
    assert rc != 0 and _tree(lab) == before


def test_an_old_unmarked_simulation_is_still_replaced(tiny_sim, tmp_path, capsys):
    old = tmp_path / "old"
    shutil.copytree(tiny_sim, old)
    for mark in old.glob(".impress-output*"):
        mark.unlink()
    rc, err = _sim(old, capsys)
    assert rc == 0, err


def test_the_sample_cache_is_not_rebuilt_over_a_foreign_project(tmp_path):
    from impress_gui.sim.sample import make_sample

    cache = tmp_path / "cache"
    (cache / "project").mkdir(parents=True)
    (cache / "project" / "case_notes.txt").write_text("mine\n")
    (cache / "sample.json").write_text('{"mine": true}')
    before = _tree(cache)
    with pytest.raises(ImpressError) as e:
        make_sample(cache, workers=1, small=True)
    assert e.value.code == "E-OUTPUT-NOT-EMPTY"
    assert _tree(cache) == before


def test_bitrate_and_target_faces_are_range_checked(tmp_path, capsys):
    rc, err = _sim(tmp_path / "b", capsys, "--bitrate-mbit", "-1")
    assert rc == 2 and "E-SIM-OPTION" in err and "Traceback" not in err
    assert not (tmp_path / "b").exists()
    doc = default_target().to_json()
    doc["faces"] = doc["faces"] * (MAX_FACES // len(doc["faces"]) + 1)
    with pytest.raises(FormatError, match="faces"):
        TargetModel.from_json(doc)
