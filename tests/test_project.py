"""The scan project folder: round trip, evidence integrity, the hash-chained log, damage."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from impress_gui.core.base.errors import (
    Cancelled,
    FormatError,
    ImpressError,
    InputError,
    IntegrityError,
)
from impress_gui.core.base.fileio import sha256_file
from impress_gui.core.base.progress import CancelToken
from impress_gui.core.calibration.geometry import Intrinsics
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.target import default_target
from impress_gui.core.project.project import (
    LOG_FILE,
    PROJECT_FILE,
    Project,
    append_log,
    create_project,
    read_log,
    verify_log,
)


@pytest.fixture(autouse=True)
def _signing_key_dir(tmp_path_factory, monkeypatch):
    """The examiner's signing key is made in a temporary folder, never in the user's home."""
    monkeypatch.setenv("IMPRESS_KEY_DIR", str(tmp_path_factory.mktemp("keys")))


@pytest.fixture
def evidence(tmp_path: Path) -> Path:
    p = tmp_path / "evidence" / "scan.mp4"
    p.parent.mkdir()
    p.write_bytes(b"\x00\x01fake video bytes" * 1000)
    p.chmod(0o444)
    return p


def _intrinsics() -> Intrinsics:
    k = np.array([[800.0, 0, 320], [0, 800.0, 180], [0, 0, 1]])
    return Intrinsics(k, np.array([-0.1, 0.02, 0, 0, 0]), (640, 360), source="test")


def _picks(video: str) -> Picks:
    c1 = {c: (10.0 + 20 * i, 30.0 + 7 * i) for i, c in enumerate("ABCDEF")}
    c2 = {c: (x, y - 40) for c, (x, y) in c1.items()}
    return Picks(video, 5, 50, c1, c2, video_sha256="ab" * 32)


def test_round_trip_keeps_everything(tmp_path, evidence):
    proj = create_project(
        tmp_path / "case1",
        case_id="2024-117",
        evidence_id="EV-3",
        examiner="J. Doe",
        notes="left shoe, garden bed",
    )
    before = evidence.read_bytes()
    proj.set_video(evidence)
    proj.set_intrinsics(_intrinsics())
    proj.set_target(default_target())
    proj.set_picks(_picks(str(evidence)))
    proj.set_processing({"method": "combined", "grid_mm": 0.1})
    proj.set_calibration_settings({"speed_mm_s": 13.138})
    out = tmp_path / "case1" / "height.tif"
    out.write_bytes(b"tiff")
    proj.add_output(out, "heightmap")
    proj.add_measurement({"kind": "length", "value_mm": 281.5})
    assert proj.dirty
    proj.save()
    assert not proj.dirty

    again = Project.load(tmp_path / "case1")
    assert (again.case_id, again.evidence_id, again.examiner, again.notes) == (
        "2024-117",
        "EV-3",
        "J. Doe",
        "left shoe, garden bed",
    )
    assert again.video.sha256 == sha256_file(evidence)
    assert again.video.size_bytes == len(before)
    assert again.video_path() == evidence.resolve()
    np.testing.assert_array_equal(again.intrinsics.camera_matrix, _intrinsics().camera_matrix)
    assert again.target.name == default_target().name
    assert again.picks == proj.picks
    assert again.processing == {"method": "combined", "grid_mm": 0.1}
    assert again.calibration_settings == {"speed_mm_s": 13.138}
    assert (
        again.outputs[0]["kind"] == "heightmap"
        and again.outputs[0]["relative_path"] == "height.tif"
    )
    assert again.measurements == [{"kind": "length", "value_mm": 281.5}]
    # the evidence is referenced, never copied or modified
    assert evidence.read_bytes() == before
    assert not any(p.suffix == ".mp4" for p in (tmp_path / "case1").iterdir())
    again.check_evidence()


def test_log_records_who_what_when_in_a_chain(tmp_path, evidence):
    proj = create_project(tmp_path / "p", case_id="C")
    proj.set_video(evidence)
    proj.save()
    entries = read_log(tmp_path / "p" / LOG_FILE)
    actions = [e["action"] for e in entries]
    assert actions[0] == "project created" and "video added" in actions
    assert actions[-1] == "project saved"
    for e in entries:
        assert e["time_utc"].endswith("Z") and e["user"] and e["software"].startswith("impress ")
    assert [e["seq"] for e in entries] == list(range(1, len(entries) + 1))
    assert verify_log(tmp_path / "p" / LOG_FILE) == len(entries)


def test_untitled_project_keeps_its_log_until_first_save(tmp_path, evidence):
    proj = Project(case_id="X")
    proj.set_video(evidence)
    proj.log("note", {"text": "before saving"})
    assert proj.log_file is None
    proj.save(tmp_path / "later")
    actions = [e["action"] for e in read_log(tmp_path / "later" / LOG_FILE)]
    assert actions[:3] == ["project created", "video added", "note"]
    assert Project.load(tmp_path / "later").video.relative_path == "../evidence/scan.mp4"


@pytest.mark.parametrize("edit", ["change", "delete-middle", "swap", "truncate", "partial"])
def test_an_edited_log_is_detected(tmp_path, edit):
    log = tmp_path / LOG_FILE
    for i in range(5):
        append_log(log, f"action {i}", {"i": i})
    lines = log.read_bytes().splitlines(keepends=True)
    if edit == "change":
        lines[2] = lines[2].replace(b'"i": 2', b'"i": 7')
    elif edit == "delete-middle":
        del lines[1]
    elif edit == "swap":
        lines[1], lines[2] = lines[2], lines[1]
    elif edit == "truncate":
        lines = lines[:-1]
    elif edit == "partial":
        lines[-1] = lines[-1][:-5]
    log.write_bytes(b"".join(lines))
    head = None
    if edit == "truncate":
        head = {"entries": 5, "sha256": "0" * 64}
    with pytest.raises(IntegrityError) as err:
        verify_log(log, head)
    assert err.value.code == "E-LOG-TAMPERED"


def test_editing_the_last_log_entry_is_detected_through_the_saved_head(tmp_path):
    proj = create_project(tmp_path / "p", case_id="C")
    log = tmp_path / "p" / LOG_FILE
    lines = log.read_bytes().splitlines(keepends=True)
    lines[-1] = lines[-1].replace(b"project saved", b"project opened")
    log.write_bytes(b"".join(lines))
    with pytest.raises(IntegrityError) as err:
        Project.load(proj.root)
    assert err.value.code == "E-LOG-TAMPERED"
    assert Project.load(proj.root, verify=False).case_id == "C"


def test_changed_or_missing_evidence_is_reported(tmp_path, evidence):
    proj = create_project(tmp_path / "p")
    proj.set_video(evidence)
    proj.save()
    evidence.chmod(0o644)
    evidence.write_bytes(evidence.read_bytes()[:-1] + b"!")
    with pytest.raises(IntegrityError) as err:
        Project.load(proj.root).check_evidence()
    assert err.value.code == "E-EVIDENCE-CHANGED"
    evidence.unlink()
    with pytest.raises(IntegrityError) as err:
        proj.check_evidence()
    assert err.value.code == "E-EVIDENCE-MISSING"


def test_hashing_can_be_cancelled(tmp_path, evidence):
    proj = Project()
    token = CancelToken()
    token.cancel()
    with pytest.raises(Cancelled):
        proj.set_video(evidence, cancel=token)
    assert proj.video is None and not proj.dirty


@pytest.mark.parametrize(
    "content, needle",
    [
        (b"", "not valid JSON"),
        (b'{"format": "impress.project", "version": 1', "not valid JSON"),
        (b"[1, 2]", "expected a JSON object"),
        (b'{"format": "impress.picks", "version": 1}', "not a impress.project file"),
        (b'{"format": "impress.project", "version": 9}', "version 9 is not supported"),
        (b'{"format": "impress.project", "version": 1, "case_id": 5}', "case_id must be text"),
        (b'{"format": "impress.project", "version": 1, "video": {"path": "x"}}', "video.sha256"),
        (
            b'{"format": "impress.project", "version": 1, "intrinsics": {"image_size": [1]}}',
            "intrinsics",
        ),
        (b'{"format": "impress.project", "version": 1, "outputs": {}}', "outputs must be"),
    ],
)
def test_a_damaged_project_file_gives_a_clear_format_error(tmp_path, content, needle):
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / PROJECT_FILE).write_bytes(content)
    with pytest.raises(FormatError) as err:
        Project.load(folder)
    assert needle in str(err.value)
    assert str(folder / PROJECT_FILE) in str(err.value)


def test_not_a_project_folder(tmp_path):
    with pytest.raises(FormatError, match="not a project folder"):
        Project.load(tmp_path)


def test_save_is_atomic_and_refuses_to_overwrite_another_project(tmp_path, monkeypatch):
    proj = create_project(tmp_path / "p", case_id="first")
    good = (tmp_path / "p" / PROJECT_FILE).read_bytes()

    def broken_replace(src, dst):
        raise OSError("disk full")

    proj.case_id = "second"
    with monkeypatch.context() as m, pytest.raises(ImpressError) as err:
        m.setattr("os.replace", broken_replace)
        proj.save()
    assert err.value.code == "E-WRITE"
    assert read_log(tmp_path / "p" / LOG_FILE)[-1]["action"] == "project save failed"
    assert (tmp_path / "p" / PROJECT_FILE).read_bytes() == good
    assert not [p for p in (tmp_path / "p").iterdir() if p.name.endswith(".partial")]
    other = Project(case_id="other")
    with pytest.raises(InputError) as err:
        other.save(tmp_path / "p")
    assert err.value.code == "E-PROJECT-EXISTS"
    assert json.loads((tmp_path / "p" / PROJECT_FILE).read_text())["case_id"] == "first"
    assert Project.load(tmp_path / "p").case_id == "first"  # the failed save left it intact


def test_non_json_values_are_refused(tmp_path):
    proj = Project()
    with pytest.raises(FormatError):
        proj.set_processing({"x": float("nan")})
    assert proj.processing == {}
