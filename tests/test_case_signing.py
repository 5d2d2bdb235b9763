"""The signed case record (issue 16 items 5 and 6): every log entry and the project file are
signed with the examiner's Ed25519 key; tampering, unknown keys, links out of the project and
malformed files are refused with a code and a plain message; a second examiner's key is
recorded and shown; unsigned version 1 projects open with a warning and are signed from their
next save. (The window's side: tests/test_case_signing_gui.py.)"""

from __future__ import annotations

import json
import os
import re
import stat
from pathlib import Path

import pytest

from impress_gui.core.base.errors import FormatError, ImpressError, IntegrityError
from impress_gui.core.project.log import GENESIS, log_tail
from impress_gui.core.project.project import (
    LOG_FILE,
    PROJECT_FILE,
    Project,
    append_log,
    create_project,
    describe_signatures,
    read_log,
)
from impress_gui.core.project.signing import (
    KEY_DIR_ENV,
    KEY_FILE,
    SigningKey,
    key_dir,
    load_or_create_key,
    sign_head,
)

PYTHON_WORDS = re.compile(
    r"<class|NoneType|Errno|Traceback|\w+Error\b|\((str|int|float|dict|list|bool)\)"
)


@pytest.fixture(autouse=True)
def keys(tmp_path, monkeypatch) -> Path:
    """This examiner's key folder: a temporary one, never the user's home."""
    folder = tmp_path / "keys"
    monkeypatch.setenv(KEY_DIR_ENV, str(folder))
    return folder


@pytest.fixture
def evidence(tmp_path: Path) -> Path:
    p = tmp_path / "evidence" / "scan.mp4"
    p.parent.mkdir()
    p.write_bytes(b"\x00\x01fake video bytes" * 100)
    return p


@pytest.fixture
def case(tmp_path, evidence) -> Path:
    """A saved, signed project with a video, an output inside its folder and a measurement."""
    proj = create_project(tmp_path / "case", case_id="2024-117", examiner="J. Doe")
    proj.set_video(evidence)
    out = tmp_path / "case" / "recon" / "metadata.json"
    out.parent.mkdir()
    out.write_text("{}")
    proj.add_output(out, "reconstruction")
    proj.add_measurement({"kind": "ruler", "label": "heel", "points_mm": [[0, 0], [1, 2]],
                          "values": {"xy_mm": 2.236}})
    proj.save()
    return tmp_path / "case"


# ----- helpers that play the attacker ---------------------------------------------------------
def _doc(case: Path) -> dict:
    return json.loads((case / PROJECT_FILE).read_text())


def _write_doc(case: Path, doc: dict) -> None:
    (case / PROJECT_FILE).write_text(json.dumps(doc))


def _edit(case: Path, change) -> None:
    doc = _doc(case)
    change(doc)
    _write_doc(case, doc)


def _lines(case: Path) -> list[dict]:
    return [json.loads(line) for line in (case / LOG_FILE).read_text().splitlines()]


def _rechain(case: Path, entries: list[dict], fix_head: bool = False) -> None:
    """Write entries back with every later hash recomputed (the issue's attack)."""
    import hashlib

    prev, data = GENESIS, b""
    for i, e in enumerate(entries):
        e["seq"], e["prev_sha256"] = i + 1, prev
        line = (json.dumps(e, sort_keys=True) + "\n").encode()
        prev = hashlib.sha256(line).hexdigest()
        data += line
    (case / LOG_FILE).write_bytes(data)
    if fix_head:
        _edit(case, lambda d: d.update(log_head={"entries": len(entries), "sha256": prev}))


def _edit_log_line(case: Path) -> None:
    entries = _lines(case)
    entries[1]["details"]["case_id"] = "forged"
    _rechain(case, entries)


def _edit_log_line_and_head(case: Path) -> None:
    entries = _lines(case)
    entries[1]["details"]["case_id"] = "forged"
    _rechain(case, entries, fix_head=True)


def _truncate_log(case: Path) -> None:
    _rechain(case, _lines(case)[:-1])


def _delete_log_and_empty_head(case: Path) -> None:
    (case / LOG_FILE).unlink()
    _edit(case, lambda d: d.update(log_head={}))


def _swap_log_lines(case: Path) -> None:
    lines = (case / LOG_FILE).read_bytes().splitlines(keepends=True)
    lines[1], lines[2] = lines[2], lines[1]
    (case / LOG_FILE).write_bytes(b"".join(lines))


def _strip_signatures(case: Path) -> None:
    entries = _lines(case)
    for e in entries:
        for k in ("public_key", "key_fingerprint", "signature"):
            e.pop(k)
    _rechain(case, entries)


def _append_by_stranger(case: Path) -> None:
    append_log(case / LOG_FILE, "evidence re-examined", {}, key=SigningKey.generate())


def _resign_by_stranger(case: Path) -> None:
    doc = _doc(case)
    doc["examiner"] = "M. Allory"
    _write_doc(case, sign_head(doc, SigningKey.generate()))


def _downgrade_to_v1(case: Path) -> None:
    doc = _doc(case)
    doc["examiner"] = "M. Allory"
    doc["version"] = 1
    for k in ("signing", "head_signature"):
        doc.pop(k)
    _write_doc(case, doc)


def _link_project_file(case: Path) -> None:
    other = case.parent / "elsewhere.json"
    (case / PROJECT_FILE).rename(other)
    (case / PROJECT_FILE).symlink_to(other)


def _link_log(case: Path) -> None:
    outside = case.parent / "outside.log"
    (case / LOG_FILE).rename(outside)
    (case / LOG_FILE).symlink_to(outside)


def _link_output_folder_out(case: Path) -> None:
    target = case.parent / "somewhere"
    (case / "recon").rename(target)
    (case / "recon").symlink_to(target)


def _link_evidence(case: Path) -> None:
    video = Path(_doc(case)["video"]["path"])
    real = video.with_name("real.mp4")
    video.rename(real)
    video.symlink_to(real)


def _project_file_is_a_folder(case: Path) -> None:
    (case / PROJECT_FILE).unlink()
    (case / PROJECT_FILE).mkdir()


def _project_file_is_a_fifo(case: Path) -> None:
    (case / PROJECT_FILE).unlink()
    os.mkfifo(case / PROJECT_FILE)


def _log_is_a_folder(case: Path) -> None:
    (case / LOG_FILE).unlink()
    (case / LOG_FILE).mkdir()


def _huge_project_file(case: Path) -> None:
    with open(case / PROJECT_FILE, "r+b") as fh:  # sparse: nothing is read before the check
        fh.truncate(60 * 1024 * 1024)


def _not_utf8(case: Path) -> None:
    (case / PROJECT_FILE).write_bytes(b'{"format": "impress.project", "case_id": "\xff\xfe"}')


def _log_not_utf8(case: Path) -> None:
    with open(case / LOG_FILE, "ab") as fh:
        fh.write(b"\xff\xfe garbage\n")


def _v2_log_head_abc(case: Path) -> None:
    _edit(case, lambda d: d.update(log_head={"entries": "abc"}))


def _remove_head_signature(case: Path) -> None:
    _edit(case, lambda d: d.pop("head_signature"))


def _signing_is_a_list(case: Path) -> None:
    _edit(case, lambda d: d.update(signing=[]))


# (damage, expected code): every case must be refused with exactly this code
TAMPERING = [
    ("edit examiner", lambda c: _edit(c, lambda d: d.update(examiner="M. Allory")),
     "E-PROJECT-TAMPERED"),
    ("edit a measurement",
     lambda c: _edit(c, lambda d: d["measurements"][0]["values"].update(xy_mm=9.9)),
     "E-PROJECT-TAMPERED"),
    ("edit the video path", lambda c: _edit(c, lambda d: d["video"].update(path="/tmp/x.mp4")),
     "E-PROJECT-TAMPERED"),
    ("output at /etc/shadow",
     lambda c: _edit(c, lambda d: d["outputs"][0].update(path="/etc/shadow")),
     "E-PROJECT-TAMPERED"),
    ("log line edited and re-chained", _edit_log_line, "E-LOG-TAMPERED"),
    ("log line edited, re-chained, head fixed", _edit_log_line_and_head, "E-PROJECT-TAMPERED"),
    ("log truncated and re-chained", _truncate_log, "E-LOG-TAMPERED"),
    ("log deleted", lambda c: (c / LOG_FILE).unlink(), "E-LOG-TAMPERED"),
    ("log deleted and head emptied", _delete_log_and_empty_head, "E-PROJECT-TAMPERED"),
    ("log lines swapped", _swap_log_lines, "E-LOG-TAMPERED"),
    ("log signatures stripped", _strip_signatures, "E-LOG-TAMPERED"),
    ("entry appended by an unknown key", _append_by_stranger, "E-SIGNATURE"),
    ("project re-signed by an unknown key", _resign_by_stranger, "E-SIGNATURE"),
    ("head signature removed", _remove_head_signature, "E-SIGNATURE"),
    ("signing section a list", _signing_is_a_list, "E-SIGNATURE"),
    ("downgraded to unsigned version 1", _downgrade_to_v1, "E-PROJECT-TAMPERED"),
    ("log_head entries 'abc' (signed file)", _v2_log_head_abc, "E-PROJECT-TAMPERED"),
    ("project.json a link", _link_project_file, "E-PROJECT-LINK"),
    ("log.jsonl a link", _link_log, "E-PROJECT-LINK"),
    ("output folder a link out", _link_output_folder_out, "E-PROJECT-LINK"),
    ("evidence video a link", _link_evidence, "E-PROJECT-LINK"),
    ("project.json a folder", _project_file_is_a_folder, "E-NOT-A-FILE"),
    ("project.json a FIFO", _project_file_is_a_fifo, "E-NOT-A-FILE"),
    ("log.jsonl a folder", _log_is_a_folder, "E-NOT-A-FILE"),
    ("project.json huge", _huge_project_file, "E-TOO-LARGE"),
    ("project.json not UTF-8", _not_utf8, "E-JSON"),
    ("log line not UTF-8", _log_not_utf8, "E-LOG-TAMPERED"),
]


@pytest.mark.parametrize("damage, code", [t[1:] for t in TAMPERING],
                         ids=[t[0] for t in TAMPERING])
def test_tampering_and_damage_are_refused_with_their_code(case, damage, code):
    damage(case)
    with pytest.raises(ImpressError) as err:
        Project.load(case)
    assert err.value.code == code, str(err.value)
    assert isinstance(err.value, (FormatError, IntegrityError))
    assert not PYTHON_WORDS.search(str(err.value)), str(err.value)


# ----- malformed unsigned (version 1) files: every field's type is checked -----------------------
V1 = {"format": "impress.project", "version": 1, "case_id": "C", "log_head": {}}
MALFORMED = [
    ({"log_head": {"entries": "abc"}}, "log_head.entries"),
    ({"log_head": {"entries": 3, "sha256": 7}}, "log_head.sha256"),
    ({"log_head": []}, "log_head must be"),
    ({"examiner": ["J. Doe"]}, "examiner must be text"),
    ({"created_utc": 5}, "created_utc must be text"),
    ({"video": []}, "video must be an object"),
    ({"video": {"path": "rel.mp4", "sha256": "a" * 64, "size_bytes": 3}}, "absolute"),
    ({"video": {"path": "/v.mp4\u0000", "sha256": "a" * 64, "size_bytes": 3}}, "video needs"),
    ({"video": {"path": "/v.mp4", "sha256": "z" * 64, "size_bytes": 3}}, "video.sha256"),
    ({"video": {"path": "/v.mp4", "sha256": "a" * 64, "size_bytes": True}}, "size_bytes"),
    ({"outputs": {"path": "/x"}}, "outputs must be"),
    ({"outputs": [1]}, "outputs[0] must be an object"),
    ({"outputs": [{"path": "/x", "kind": "k", "sha256": "a" * 64, "relative_path": "/abs"}]},
     "relative to the project"),
    ({"measurements": [{"points_mm": "x"}]}, "points_mm"),
    ({"measurements": [{"label": {"a": 1}}]}, "label must be text"),
    ({"measurements": [{"params": {"width_mm": "wide"}}]}, "width_mm"),
    ({"calibration_settings": {"speed_mm_s": "fast"}}, "speed_mm_s"),
    ({"processing": {"rois": {"a": 5}}}, "rois"),
    ({"processing": []}, "processing must be"),
    ({"intrinsics": {"image_size": "abc"}}, "intrinsics"),
    ({"intrinsics": []}, "intrinsics must be an object"),
    ({"picks": {"t1": 1}}, "picks"),
    ({"calibration": {"roll_deg": "x"}}, "calibration"),
]


@pytest.mark.parametrize("fields, needle", MALFORMED, ids=[str(m[0])[:40] for m in MALFORMED])
def test_a_malformed_field_gives_a_plain_format_error(tmp_path, fields, needle):
    folder = tmp_path / "p"
    folder.mkdir()
    (folder / PROJECT_FILE).write_text(json.dumps(V1 | fields))
    with pytest.raises(FormatError) as err:
        Project.load(folder)
    text = str(err.value)
    assert needle in text and str(folder / PROJECT_FILE) in text
    assert err.value.code.startswith("E-")
    assert not PYTHON_WORDS.search(text), text


# ----- round trips ---------------------------------------------------------------------------------
def test_round_trip_every_entry_and_the_file_are_signed(case, keys):
    proj = Project.load(case)
    info = proj.signature_info()
    key = load_or_create_key()
    assert info["signed"] and info["algorithm"] == "Ed25519"
    assert info["key_fingerprint"] == key.fingerprint and info["public_key"] == key.public_key
    assert info["head_signature"] and info["this_installation_key"] == key.fingerprint
    assert info["keys"][0]["this_installation"]
    assert info["log_head"]["entries"] == len(read_log(case / LOG_FILE))
    assert info["unsigned_log_entries"] == 0
    assert [r["key_fingerprint"] for r in info["log_signers"]] == [key.fingerprint]
    for e in read_log(case / LOG_FILE):
        assert e["key_fingerprint"] == key.fingerprint and e["signature"]
    assert _doc(case)["version"] == 2 and not proj.warnings
    # log, save and reload: still verified
    proj.set_case_info(notes="second visit")
    proj.save()
    again = Project.load(case)
    assert again.notes == "second visit" and again.measurements[0]["label"] == "heel"
    assert again.verify()["key_fingerprint"] == key.fingerprint
    assert "this installation's key" in describe_signatures(again.signature_info())
    # the key: made once, readable by this user only, in the folder given
    assert (keys / KEY_FILE).is_file()
    assert stat.S_IMODE((keys / KEY_FILE).stat().st_mode) == 0o600
    assert stat.S_IMODE(keys.stat().st_mode) == 0o700


def test_the_key_folder_follows_the_environment(tmp_path, monkeypatch):
    monkeypatch.delenv(KEY_DIR_ENV)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "xdg"))
    assert key_dir() == tmp_path / "xdg" / "IMPREsS" / "keys"
    monkeypatch.setenv(KEY_DIR_ENV, str(tmp_path / "k"))
    assert key_dir() == tmp_path / "k"


@pytest.mark.parametrize("damage", ["world-readable", "link", "garbage", "folder"])
def test_an_unsafe_or_damaged_key_is_refused_before_anything_is_written(tmp_path, keys, damage):
    key = load_or_create_key()
    if damage == "world-readable":
        (keys / KEY_FILE).chmod(0o644)
    elif damage == "link":
        (keys / KEY_FILE).rename(tmp_path / "stolen.pem")
        (keys / KEY_FILE).symlink_to(tmp_path / "stolen.pem")
    elif damage == "garbage":
        (keys / KEY_FILE).write_bytes(b"not a key")
    else:
        (keys / KEY_FILE).unlink()
        (keys / KEY_FILE).mkdir()
    with pytest.raises(IntegrityError) as err:
        create_project(tmp_path / "p")
    assert err.value.code == "E-KEY" and str(keys / KEY_FILE) in str(err.value)
    assert not PYTHON_WORDS.search(str(err.value))
    assert not (tmp_path / "p" / LOG_FILE).exists()
    if damage == "world-readable":
        assert "chmod 600" in str(err.value)
    assert key.fingerprint  # the good key was made first


def test_save_never_signs_over_a_log_changed_behind_its_back(case):
    proj = Project.load(case)
    good = (case / PROJECT_FILE).read_bytes()
    _edit_log_line(case)
    proj.set_case_info(notes="after the edit")
    with pytest.raises(IntegrityError) as err:
        proj.save()
    assert err.value.code == "E-LOG-TAMPERED"
    assert (case / PROJECT_FILE).read_bytes() == good


def test_a_tampered_project_can_be_inspected_but_not_saved(case):
    _edit(case, lambda d: d.update(examiner="M. Allory"))
    proj = Project.load(case, verify=False)
    assert proj.examiner == "M. Allory"
    with pytest.raises(IntegrityError) as err:
        proj.save()
    assert err.value.code == "E-PROJECT-TAMPERED"


# ----- other examiners' keys ---------------------------------------------------------------------
def test_another_examiners_key_is_recorded_and_shown(case, tmp_path, monkeypatch):
    first = load_or_create_key().fingerprint
    monkeypatch.setenv(KEY_DIR_ENV, str(tmp_path / "keys-b"))
    second = load_or_create_key().fingerprint
    proj = Project.load(case)  # signed by A: B may open it
    assert proj.signature_info()["key_fingerprint"] == first
    assert not proj.signature_info()["keys"][0]["this_installation"]
    proj.log("project opened", {})  # B's first entry: B's key is recorded in the file first
    assert {k["fingerprint"] for k in _doc(case)["signing"]["keys"]} == {first, second}
    proj.set_case_info(notes="checked by B")
    proj.save()
    monkeypatch.setenv(KEY_DIR_ENV, str(tmp_path / "keys"))  # A opens it again
    again = Project.load(case)
    info = again.signature_info()
    assert info["key_fingerprint"] == second and again.notes == "checked by B"
    runs = info["log_signers"]
    assert [r["key_fingerprint"] for r in runs] == [first, second]  # the key change shows
    added = [e for e in read_log(case / LOG_FILE) if e["action"] == "signing key added"]
    assert added[0]["key_fingerprint"] == second and runs[1]["from_seq"] == added[0]["seq"]
    text = describe_signatures(info)
    assert f"changes at log entry {runs[1]['from_seq']}" in text and second in text


def test_a_file_re_signed_with_a_forgers_own_listed_key_is_caught_by_the_log(case):
    stranger = SigningKey.generate()
    doc = _doc(case)
    doc["examiner"] = "M. Allory"
    doc["signing"]["keys"] = [{"public_key": stranger.public_key,
                               "fingerprint": stranger.fingerprint, "user": "x",
                               "added_utc": ""}]
    _write_doc(case, sign_head(doc, stranger))
    with pytest.raises(IntegrityError) as err:  # the examiner's signed log names their key
        Project.load(case)
    assert err.value.code == "E-SIGNATURE"


def test_a_record_rewritten_whole_with_another_key_says_so(case):
    """Whoever rewrites every entry and the file with a key of their own makes a consistent
    record (no signature scheme inside the folder can prevent that): it is reported as signed
    by that key, not by this installation's, and its fingerprint differs from the one the
    case's reports carry (:meth:`Project.signature_info`)."""
    stranger = SigningKey.generate()
    log = case / LOG_FILE
    entries = _lines(case)
    log.unlink()
    for e in entries:
        append_log(log, e["action"], e["details"], user=e["user"], time_utc=e["time_utc"],
                   key=stranger)
    n, head = log_tail(log)
    doc = _doc(case)
    doc["examiner"] = "M. Allory"
    doc["log_head"] = {"entries": n, "sha256": head}
    doc["signing"]["keys"] = [{"public_key": stranger.public_key,
                               "fingerprint": stranger.fingerprint, "user": "x",
                               "added_utc": ""}]
    _write_doc(case, sign_head(doc, stranger))
    info = Project.load(case).signature_info()
    assert info["key_fingerprint"] == stranger.fingerprint != load_or_create_key().fingerprint
    assert not any(k["this_installation"] for k in info["keys"])
    assert "this installation" not in describe_signatures(info)


# ----- links: nothing is written outside the project ---------------------------------------------
def test_a_log_that_becomes_a_link_is_never_written_through(case, tmp_path):
    proj = Project.load(case)
    outside = tmp_path / "outside.log"
    outside.write_bytes(b"someone else's file\n")
    (case / LOG_FILE).rename(tmp_path / "real.log")
    (case / LOG_FILE).symlink_to(outside)
    with pytest.raises(IntegrityError) as err:
        proj.log("measurement added", {"x": 1})
    assert err.value.code == "E-PROJECT-LINK"
    with pytest.raises(IntegrityError):
        proj.save()
    assert outside.read_bytes() == b"someone else's file\n"
    with pytest.raises(IntegrityError) as err:
        Project.load(case)
    assert err.value.code == "E-PROJECT-LINK"


def test_a_hard_linked_log_is_not_appended_to(case, tmp_path):
    proj = Project.load(case)
    before = (case / LOG_FILE).read_bytes()
    os.link(case / LOG_FILE, tmp_path / "other-name.log")
    with pytest.raises(IntegrityError) as err:
        proj.log("x", {})
    assert err.value.code == "E-PROJECT-LINK"
    assert (tmp_path / "other-name.log").read_bytes() == before


def test_a_project_folder_replaced_by_a_link_is_not_written(case, tmp_path):
    proj = Project.load(case)
    case.rename(tmp_path / "moved")
    (tmp_path / "decoy").mkdir()
    case.symlink_to(tmp_path / "decoy")
    with pytest.raises(IntegrityError) as err:
        proj.log("x", {})
    assert err.value.code == "E-PROJECT-LINK"
    assert list((tmp_path / "decoy").iterdir()) == []


def test_an_output_outside_the_project_is_kept_only_as_recorded(tmp_path, evidence):
    """An export to another folder stays a recorded (signed) output; an edit of it is not."""
    proj = create_project(tmp_path / "case")
    export = tmp_path / "usb" / "h.ply"
    export.parent.mkdir()
    export.write_bytes(b"ply\n")
    proj.add_output(export, "ply")
    proj.save()
    assert Project.load(tmp_path / "case").outputs[0]["path"] == str(export)
    export.unlink()
    export.symlink_to("/etc/hostname")
    with pytest.raises(IntegrityError) as err:
        Project.load(tmp_path / "case")
    assert err.value.code == "E-PROJECT-LINK"


# ----- version 1 (unsigned) projects ---------------------------------------------------------------
def _v1_project(folder: Path, evidence: Path, outputs: list | None = None) -> Path:
    """A project as the previous version wrote it: unsigned log, version 1 file."""
    folder.mkdir()
    log = folder / LOG_FILE
    append_log(log, "project created", {"case_id": "OLD"})
    append_log(log, "video added", {"path": str(evidence), "sha256": "ab" * 32})
    for o in outputs or []:
        append_log(log, "output written", o)
    append_log(log, "project saved", {})
    n, head = log_tail(log)
    doc = V1 | {
        "case_id": "OLD", "examiner": "J. Doe", "outputs": outputs or [],
        "video": {"path": str(evidence), "relative_path": "../evidence/scan.mp4",
                  "sha256": "ab" * 32, "size_bytes": 3, "added_utc": ""},
        "log_head": {"entries": n, "sha256": head},
    }
    (folder / PROJECT_FILE).write_text(json.dumps(doc))
    return folder


def test_an_unsigned_project_opens_with_a_warning_and_is_signed_from_its_next_save(
    tmp_path, evidence
):
    folder = _v1_project(tmp_path / "old", evidence)
    proj = Project.load(folder)
    assert len(proj.warnings) == 1 and "E-PROJECT-UNSIGNED" in proj.warnings[0]
    assert not proj.signature_info()["signed"]
    assert describe_signatures(proj.signature_info()).startswith("Not signed")
    proj.log("project opened", {})
    proj.save()
    again = Project.load(folder)
    info = again.signature_info()
    assert not again.warnings and info["signed"] and info["unsigned_log_entries"] == 3
    assert info["log_signers"][0] == {"from_seq": 1, "to_seq": 3, "key_fingerprint": None}
    actions = [e["action"] for e in read_log(folder / LOG_FILE)]
    assert "project signed" in actions
    assert "entries 1-3: unsigned" in describe_signatures(info)


def test_an_unsigned_project_with_an_output_the_log_never_wrote_is_refused(tmp_path, evidence):
    shadow = {"path": "/etc/shadow", "relative_path": None, "kind": "reconstruction",
              "sha256": "cd" * 32, "created_utc": ""}
    folder = _v1_project(tmp_path / "old", evidence)
    _edit(folder, lambda d: d.update(outputs=[shadow]))
    with pytest.raises(IntegrityError) as err:
        Project.load(folder)
    assert err.value.code == "E-PROJECT-TAMPERED"


def test_an_unsigned_project_whose_video_paths_disagree_is_refused(tmp_path, evidence):
    folder = _v1_project(tmp_path / "old", evidence)
    _edit(folder, lambda d: d["video"].update(relative_path="../../../etc/shadow"))
    with pytest.raises(IntegrityError) as err:
        Project.load(folder)
    assert err.value.code == "E-PROJECT-PATH"


def test_an_unsigned_project_with_a_deleted_log_is_refused(tmp_path, evidence):
    folder = _v1_project(tmp_path / "old", evidence)
    (folder / LOG_FILE).unlink()
    _edit(folder, lambda d: d.update(log_head={}))
    with pytest.raises(IntegrityError) as err:
        Project.load(folder)
    assert err.value.code == "E-LOG-TAMPERED"
