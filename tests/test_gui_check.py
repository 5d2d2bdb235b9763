"""``impress gui PATH --check`` (what packaging/smoke_test.sh relies on): exit status 0 when the
project and its reconstruction opened, 1 with the reason on stderr when anything failed."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from PySide6.QtGui import QImage

from impress_gui.core.project.project import PROJECT_FILE
from impress_gui.sim.sample import make_sample


@pytest.fixture(scope="module")
def built_sample(tmp_path_factory) -> tuple[Path, Path]:
    """(the small sample's project folder, a copy of the whole sample as built): built once."""
    base = tmp_path_factory.mktemp("sample")
    project = make_sample(base / "sample", workers=1, small=True)
    shutil.copytree(project.parent, base / "pristine", symlinks=True)
    return project, base / "pristine"


@pytest.fixture
def sample_project(built_sample) -> Path:
    """The small sample as make_sample left it, for each test that asks: put back from the
    copy (the check logs into the project; a test damages it) where it was built, as the
    project names its files by their absolute paths (a copy elsewhere would show the
    original's reconstruction). One build instead of one per test: most of a minute each."""
    project, pristine = built_sample
    shutil.rmtree(project.parent)
    shutil.copytree(pristine, project.parent, symlinks=True)
    return project


def run_check(path: Path, tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "HOME": str(tmp_path)}
    cmd = [sys.executable, "-m", "impress_gui", "gui", str(path), "--check", "--no-motor",
           "--settings", str(tmp_path / "settings.ini"), *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)


def test_check_passes_on_the_sample_and_takes_the_screenshot(sample_project, tmp_path):
    shot = tmp_path / "window.png"
    res = run_check(sample_project, tmp_path, "--tab", "viewer", "--screenshot", str(shot))
    assert res.returncode == 0, res.stderr
    recon = sample_project / "reconstruction"
    assert f"check passed: opened {sample_project}; the viewer shows {recon}" in res.stdout
    assert "FAILED" not in res.stderr and "Traceback" not in res.stderr
    img = QImage(str(shot))
    assert (img.width(), img.height()) == (1920, 1080)


def test_check_fails_on_a_corrupt_project_json(tmp_path):
    folder = tmp_path / "broken"
    folder.mkdir()
    (folder / PROJECT_FILE).write_text("{not json")
    res = run_check(folder, tmp_path)
    assert res.returncode == 1
    assert "FAILED: Cannot open the project:" in res.stderr
    assert "not valid JSON" in res.stderr and "E-JSON" in res.stderr
    assert "check passed" not in res.stdout


def test_check_fails_when_the_reconstruction_cannot_be_shown(sample_project, tmp_path):
    project = sample_project
    recon = project / "reconstruction"
    (recon / "heightmap.tif").write_bytes(b"not a TIFF")
    res = run_check(project, tmp_path)
    assert res.returncode == 1
    assert "FAILED: Cannot open the reconstruction:" in res.stderr

    # a project whose listed reconstruction has gone: nothing to show, no box, still a failure
    moved = tmp_path / "moved-away"
    recon.rename(moved)
    res = run_check(project, tmp_path)
    assert res.returncode == 1
    assert "FAILED: the project's reconstruction" in res.stderr and "is missing" in res.stderr


def test_check_fails_on_a_missing_path(tmp_path):
    res = run_check(tmp_path / "nowhere", tmp_path)
    assert res.returncode != 0
    assert "no such project folder or video" in res.stderr


def test_check_without_it_a_broken_project_still_exits_0(tmp_path):
    """Why the option exists: without --check the window shows a box and exits 0."""
    folder = tmp_path / "broken"
    folder.mkdir()
    (folder / PROJECT_FILE).write_text(json.dumps({"format": "impress.project", "version": 7}))
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "HOME": str(tmp_path)}
    cmd = [sys.executable, "-m", "impress_gui", "gui", str(folder), "--no-motor", "--quit-after",
           "0.3", "--settings", str(tmp_path / "settings.ini")]
    assert subprocess.run(cmd, capture_output=True, timeout=60, env=env).returncode == 0
    res = run_check(folder, tmp_path)
    assert res.returncode == 1 and "version 7 is not supported" in res.stderr


def _gui(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "HOME": str(tmp_path)}
    cmd = [sys.executable, "-m", "impress_gui", "gui", *args, "--no-motor", "--quit-after", "0.5",
           "--settings", str(tmp_path / "settings.ini")]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)


def test_screenshot_never_replaces_evidence(tmp_path):
    # a hostile-input audit: `--screenshot` pointed at the video it opened left it 0 bytes; a
    # .png name inside the opened reconstruction replaced a result's picture
    video = tmp_path / "scan.mp4"
    video.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    notes = tmp_path / "notes.png"  # not a picture, whatever its name says
    notes.write_text("case notes\n")
    recon = tmp_path / "recon"
    recon.mkdir()
    view = recon / "heightmap_color.png"
    view.write_bytes(b"\x89PNG\r\n\x1a\n" + b"x" * 100)
    before = {p: p.read_bytes() for p in (video, notes, view)}
    cases = [((str(video), "--screenshot", str(video)), "E-USAGE"),
             ((str(video), "--screenshot", str(notes)), "E-OUTPUT-EXISTS"),
             ((str(recon), "--screenshot", str(view)), "E-OUTPUT-HOLDS-INPUT")]
    for args, code in cases:
        res = _gui(tmp_path, *args)
        assert res.returncode != 0 and code in res.stderr, (args, res.stderr)
        assert "Traceback" not in res.stderr
    assert {p: p.read_bytes() for p in before} == before
    # an earlier screenshot (a PNG picture) is replaced by the new one
    old = tmp_path / "old.png"
    old.write_bytes(b"\x89PNG\r\n\x1a\n" + b"y" * 100)
    res = _gui(tmp_path, "--screenshot", str(old))
    assert res.returncode == 0, res.stderr
    img = QImage(str(old))
    assert img.width() > 0 and not [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]


def test_an_unreadable_settings_file_is_not_overwritten(tmp_path):
    # a hostile-input audit: `--settings bad.ini` replaced a malformed file with the defaults
    bad = tmp_path / "settings.ini"
    bad.write_bytes(b"[[[broken\n\x00")
    res = _gui(tmp_path)
    assert res.returncode != 0 and "E-FORMAT" in res.stderr and "Traceback" not in res.stderr
    assert bad.read_bytes() == b"[[[broken\n\x00"
    # the user's own settings: moved aside (its bytes kept), the window starts with defaults
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "HOME": str(tmp_path),
           "XDG_CONFIG_HOME": str(tmp_path / "config")}
    own = tmp_path / "config" / "IMPREsS" / "impress-workstation.ini"
    own.parent.mkdir(parents=True)
    own.write_bytes(b"not an ini")
    res = subprocess.run([sys.executable, "-m", "impress_gui", "gui", "--no-motor",
                          "--quit-after", "0.5"], capture_output=True, text=True, timeout=120,
                         env=env)
    assert res.returncode == 0, res.stderr
    assert "W-SETTINGS" in res.stderr
    kept = [p for p in own.parent.iterdir() if p.name.startswith(own.name + ".unreadable-")]
    assert len(kept) == 1 and kept[0].read_bytes() == b"not an ini"


def test_check_leaves_the_users_configuration_as_it_was(sample_project, tmp_path):
    """``--check`` without ``--settings`` (a smoke test on an analyst's machine) reads the
    user's configuration but writes nothing into it: the recent projects and what the window
    remembers stay as they were, and no file is made beside it."""
    config = tmp_path / "config"
    user = config / "IMPREsS" / "impress-workstation.ini"
    user.parent.mkdir(parents=True)
    before = "[General]\nsomething_of_the_user=42\n"
    user.write_text(before)
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "HOME": str(tmp_path),
           "XDG_CONFIG_HOME": str(config), "IMPRESS_KEY_DIR": str(tmp_path / "keys")}
    cmd = [sys.executable, "-m", "impress_gui", "gui", str(sample_project), "--no-motor"]
    res = subprocess.run([*cmd, "--check"], capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stderr
    assert f"check passed: opened {sample_project}" in res.stdout
    assert user.read_text() == before
    assert sorted(p.name for p in config.rglob("*")) == ["IMPREsS", user.name]
    # the same without --check records the project among the recent ones (so the check's
    # copy is what kept the configuration as it was)
    res = subprocess.run([*cmd, "--quit-after", "1"], capture_output=True, text=True,
                         timeout=120, env=env)
    assert res.returncode == 0, res.stderr
    assert user.read_text() != before and "something_of_the_user=42" in user.read_text()
