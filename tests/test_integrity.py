"""Evidence integrity promises (issue 8), each tested on the short simulated flat scan:

- processing refuses a video whose SHA-256 changed since it was added to the project (core
  entry and the processing tab in the window);
- every output carries the input hashes, the parameters and the software version, and the
  exports read back through the hostile-input readers;
- a project.json whose evidence hash was edited to match a swapped video is caught by its
  signature, and even when re-signed with the examiner's own key, against the signed log
  (edits of the log itself: tests/test_project.py; every other tampering case:
  tests/test_case_signing.py);
- outputs are atomic under SIGKILL: killed while decoding, while writing, and between the two
  renames of the folder swap, the previous good result survives byte for byte, nothing that
  looks complete is left, and the next run cleans up (cancel: tests/test_reconstruct.py;
  determinism: tests/test_reconstruct.py).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from impress_gui import __version__
from impress_gui.core.base.errors import IntegrityError
from impress_gui.core.base.fileio import sha256_file
from impress_gui.core.base.outdir import MARK_FILE, mark_bytes, recover_interrupted
from impress_gui.core.formats.readers import read_ply, read_x3p
from impress_gui.core.project.project import PROJECT_FILE, Project
from impress_gui.core.reconstruction.pipeline import process_files
from impress_gui.core.reconstruction.reconstruct import ProcessParams

ROOT = Path(__file__).resolve().parents[1]
FRAMES = ["--frames", "40:100", "--no-texture"]


@pytest.fixture(autouse=True)
def _signing_key_dir(tmp_path_factory, monkeypatch):
    """The examiner's signing key is made in a temporary folder, never in the user's home."""
    monkeypatch.setenv("IMPRESS_KEY_DIR", str(tmp_path_factory.mktemp("keys")))


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.fixture
def evidence(flat_scan, tmp_path) -> Path:
    """A private copy of the scan video (the session's scan stays untouched)."""
    p = tmp_path / "evidence" / "scan.mp4"
    p.parent.mkdir()
    shutil.copyfile(flat_scan / "scan.mp4", p)
    return p


@pytest.fixture(scope="module")
def good(flat_scan, flat_calibration, tmp_path_factory) -> Path:
    """A finished reconstruction (the 'previous good result')."""
    out = tmp_path_factory.mktemp("good") / "recon"
    process_files(
        flat_scan / "scan.mp4",
        flat_calibration,
        out,
        ProcessParams(frame_start=40, frame_stop=100, texture=False),
    )
    return out


def _copy_result(good: Path, tmp_path: Path) -> Path:
    out = tmp_path / "work" / "recon"
    shutil.copytree(good, out)
    return out


# ----- evidence hashes --------------------------------------------------------------------------
def test_processing_refuses_a_changed_evidence_video(evidence, flat_calibration, tmp_path):
    proj = Project(case_id="I-1")
    proj.set_video(evidence)
    proj.save(tmp_path / "case")
    with open(evidence, "ab") as fh:  # still a playable video, but not the evidence
        fh.write(b"\0")
    with pytest.raises(IntegrityError) as err:
        process_files(
            evidence,
            flat_calibration,
            tmp_path / "out",
            ProcessParams(frame_start=40, frame_stop=60),
            expected_video_sha256=proj.video.sha256,
        )
    assert err.value.code == "E-EVIDENCE-CHANGED" and "changed" in str(err.value)
    assert not (tmp_path / "out").exists()
    with pytest.raises(IntegrityError):
        Project.load(tmp_path / "case").check_evidence()


@pytest.mark.qt_log_ignore("propagateSizeHints")
def test_the_processing_tab_refuses_a_changed_video_with_a_message(
    qtbot, evidence, flat_calibration, tmp_path
):
    from measure_scans import guard_pyside_none

    from impress_gui.core.calibration.scene import SceneCalibration
    from impress_gui.ui.messages import Messenger
    from impress_gui.ui.processing.tab import ProcessingTab

    class Dialogs:
        def directory(self, *a, **k):
            return ""

    proj = Project(case_id="I-2")
    proj.set_video(evidence)
    proj.set_calibration(SceneCalibration.load(flat_calibration))
    proj.save(tmp_path / "case")
    guard_pyside_none()
    tab = ProcessingTab(Messenger(None), Dialogs())
    qtbot.addWidget(tab)
    try:
        tab.set_project(proj)
        with open(evidence, "ab") as fh:
            fh.write(b"\0")
        with qtbot.waitSignal(tab.worker.failed, timeout=60_000) as sig:
            assert tab.run(tmp_path / "case" / "recon")
        assert sig.args[0] == "E-EVIDENCE-CHANGED"
        assert "E-EVIDENCE-CHANGED" in tab.messenger.last_text
        assert not (tmp_path / "case" / "recon").exists()
    finally:
        tab.messenger.close_all()
        tab.shutdown()


def test_an_edited_evidence_hash_in_project_json_is_caught_by_the_log(evidence, tmp_path):
    proj = Project(case_id="I-3")
    proj.set_video(evidence)
    proj.save(tmp_path / "case")
    swapped = tmp_path / "other.mp4"
    swapped.write_bytes(b"not the evidence")
    doc = json.loads((tmp_path / "case" / PROJECT_FILE).read_text())
    doc["video"]["path"] = str(swapped)
    doc["video"]["sha256"] = sha256_file(swapped)
    (tmp_path / "case" / PROJECT_FILE).write_text(json.dumps(doc))
    with pytest.raises(IntegrityError) as err:
        Project.load(tmp_path / "case")
    assert err.value.code == "E-PROJECT-TAMPERED" and "changed after it was signed" in str(
        err.value
    )
    # signed again with the examiner's own key: the signed log still has the true hash
    from impress_gui.core.project.signing import sign_head

    (tmp_path / "case" / PROJECT_FILE).write_text(json.dumps(sign_head(doc, proj.signing_key)))
    with pytest.raises(IntegrityError) as err:
        Project.load(tmp_path / "case")
    assert err.value.code == "E-LOG-TAMPERED" and "project.json was edited" in str(err.value)


# ----- what every output carries ------------------------------------------------------------------
def test_every_output_carries_inputs_parameters_and_version(good, flat_scan, flat_calibration):
    meta = json.loads((good / "metadata.json").read_text())
    assert meta["software"] == f"impress {__version__}"
    assert meta["inputs"]["video"]["sha256"] == sha256_file(flat_scan / "scan.mp4")
    assert meta["inputs"]["calibration"]["sha256"] == sha256_file(flat_calibration)
    assert (
        meta["parameters"] == ProcessParams(frame_start=40, frame_stop=100, texture=False).to_json()
    )
    # metadata.json names and hashes every other file of the folder
    others = {p.name for p in good.iterdir()} - {"metadata.json", "run.json"}
    assert set(meta["files"]) == others
    for name in others:
        assert hashlib.sha256((good / name).read_bytes()).hexdigest() == meta["files"][name]
    run = json.loads((good / "run.json").read_text())
    assert run["date_utc"].endswith("Z") and run["python"]
    # the exports name the software version themselves and read back intact
    # ... and the hashes of the video and calibration they were made from
    x3p = read_x3p(good / "heightmap.x3p")
    assert x3p.info["version"] == __version__
    for name in ("video", "calibration"):
        assert f"source {name} sha256: {meta['inputs'][name]['sha256']}" in x3p.info["comment"]
    ply = read_ply(good / "pointcloud.ply")
    assert any(__version__ in c for c in ply.comments) and len(ply.points_mm) > 1000
    for name in ("video", "calibration"):
        assert f"source {name} sha256: {meta['inputs'][name]['sha256']}" in ply.comments
    # the viewer's exports: tests/test_export_provenance.py


# ----- atomic outputs under SIGKILL -------------------------------------------------------------
def _process_cmd(flat_scan, cal, out) -> list[str]:
    return [str(flat_scan / "scan.mp4"), "--calibration", str(cal), "-o", str(out), *FRAMES]


def _leftovers(parent: Path, name: str) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if p.name != name)


def test_killed_while_decoding_leaves_the_previous_result(
    good, flat_scan, flat_calibration, tmp_path
):
    out = _copy_result(good, tmp_path)
    before = _snapshot(out)
    cmd = [
        sys.executable,
        "-m",
        "impress_gui",
        "process",
        *_process_cmd(flat_scan, flat_calibration, out),
    ]
    proc = subprocess.Popen(
        cmd, cwd=ROOT, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True
    )
    try:
        line = proc.stderr.readline()  # the first progress line: processing has started
        assert "%" in line, line
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    assert _snapshot(out) == before
    assert _leftovers(out.parent, out.name) == []


# A child that runs `impress process` and kills itself with SIGKILL at a chosen point of the
# output writer: at its first fsync (every file written into the hidden folder, none renamed),
# or right after the first rename of the swap (the old result moved aside, the new not yet in).
_KILLER = r"""
import os, pathlib, signal, sys
where = sys.argv[1]
if where == "fsync":
    os.fsync = lambda fd: os.kill(os.getpid(), signal.SIGKILL)
else:
    real = pathlib.Path.rename
    def rename(self, target):
        result = real(self, target)
        os.kill(os.getpid(), signal.SIGKILL)
        return result
    pathlib.Path.rename = rename
from impress_gui.cli import main
sys.exit(main(["process", *sys.argv[2:]]))
"""


@pytest.mark.parametrize("where", ["fsync", "swap"])
def test_killed_while_writing_leaves_nothing_that_looks_complete(
    where, good, flat_scan, flat_calibration, tmp_path
):
    out = _copy_result(good, tmp_path)
    before = _snapshot(out)
    r = subprocess.run(
        [sys.executable, "-c", _KILLER, where, *_process_cmd(flat_scan, flat_calibration, out)],
        cwd=ROOT,
        capture_output=True,
        timeout=120,
    )
    assert r.returncode == -signal.SIGKILL, r.stderr.decode()[-2000:]
    left = _leftovers(out.parent, out.name)
    if where == "fsync":
        # the result is untouched; the unfinished one is a hidden, partial-named folder
        assert _snapshot(out) == before
        assert len(left) == 1 and left[0].startswith(".recon.partial-")
    else:
        # killed between the renames: no result in place, the previous one intact aside
        assert not out.exists()
        olds = [n for n in left if n.startswith(".recon.old-")]
        assert len(olds) == 1 and _snapshot(out.parent / olds[0]) == before
        assert all(n.startswith(".") for n in left)
        # the next writer (or an explicit recovery) puts the previous result back first
        done = recover_interrupted(out)
        assert done[0].startswith("restored") and _snapshot(out) == before
        assert _leftovers(out.parent, out.name) == []
        return
    # the next run cleans the stale folder and completes (a hang: pytest-timeout)
    meta = process_files(
        flat_scan / "scan.mp4",
        flat_calibration,
        out,
        ProcessParams(frame_start=40, frame_stop=100, texture=False),
    )
    assert _leftovers(out.parent, out.name) == []
    assert (
        meta["files"]["heightmap.tif"] == hashlib.sha256(before["heightmap.tif"]).hexdigest()
    )  # same inputs, same bytes


def test_a_live_writers_folder_is_not_removed(tmp_path):
    """Another process still writing the same output keeps its hidden folder."""
    out = tmp_path / "recon"
    live = tmp_path / f".recon.partial-{os.getppid()}"
    live.mkdir()
    (live / MARK_FILE).write_bytes(mark_bytes("reconstruction"))
    dead = tmp_path / ".recon.partial-999999999"
    dead.mkdir()
    (dead / MARK_FILE).write_bytes(mark_bytes("reconstruction"))
    recover_interrupted(out)
    assert live.exists() and not dead.exists()


def test_folders_named_like_work_folders_but_not_ours_are_kept(tmp_path, flat_scan,
                                                              flat_calibration):
    """A folder beside the output whose name looks like a work folder or a set-aside result
    (``.NAME.partial-PID``, ``.NAME.old-PID``, PID not running) but which carries no mark of
    the product is someone's data: a run writing NAME leaves it, and its files, as they are
    (the audit of 4 December 2026 found them deleted); a link of that name likewise."""
    out = tmp_path / "recon"
    notes = tmp_path / ".recon.partial-999999991"
    old = tmp_path / ".recon.old-999999992"
    for d, text in ((notes, "notes"), (old, "b")):
        d.mkdir()
        (d / "notes.txt").write_text(text)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "keep.txt").write_text("k")
    (tmp_path / ".recon.partial-999999993").symlink_to(elsewhere, target_is_directory=True)
    assert recover_interrupted(out) == []
    process_files(flat_scan / "scan.mp4", flat_calibration, out,
                  ProcessParams(frame_start=40, frame_stop=60, texture=False))
    assert (notes / "notes.txt").read_text() == "notes"
    assert (old / "notes.txt").read_text() == "b"
    assert (elsewhere / "keep.txt").read_text() == "k"
    assert (out / "heightmap.tif").is_file()
