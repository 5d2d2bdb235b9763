"""The window and damaged or tampered projects (issue 16 item 6): opening one shows its coded
error and the window keeps running with the project it had; an unsigned project opens with a
warning; a failure while the window is built stops the motor's thread first; ``impress gui``
on a damaged project never aborts."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from PySide6.QtWidgets import QMessageBox

from impress_gui.core.project.log import log_tail
from impress_gui.core.project.project import LOG_FILE, PROJECT_FILE, append_log
from impress_gui.core.project.signing import KEY_DIR_ENV
from impress_gui.ui import pyside_fix
from impress_gui.ui.app import build_main_window, make_settings

pyside_fix.guard()
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_threads")]
V1 = {"format": "impress.project", "version": 1, "case_id": "BAD"}


@pytest.fixture(autouse=True)
def keys(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv(KEY_DIR_ENV, str(tmp_path / "keys"))
    return tmp_path / "keys"


@pytest.fixture
def window(qtbot, tmp_path):
    w = build_main_window(make_settings(tmp_path / "settings.ini"), port_lister=lambda: [])
    qtbot.addWidget(w)
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.shutdown()


def _damaged(folder: Path, damage: str) -> Path:
    folder.mkdir()
    file = folder / PROJECT_FILE
    if damage == "entries-abc":
        file.write_text(json.dumps(V1 | {"log_head": {"entries": "abc"}}))
    elif damage == "list-for-object":
        file.write_text(json.dumps(V1 | {"video": ["a", "b"]}))
    elif damage == "not-utf8":
        file.write_bytes(b'{"format": "impress.project", "version": 1, "notes": "\xff"}')
    elif damage == "folder":
        file.mkdir()
    elif damage == "fifo":
        os.mkfifo(file)
    return folder


@pytest.mark.parametrize(
    "damage, code",
    [
        ("entries-abc", "E-FORMAT"),
        ("list-for-object", "E-FORMAT"),
        ("not-utf8", "E-JSON"),
        ("folder", "E-NOT-A-FILE"),
        ("fifo", "E-NOT-A-FILE"),
        ("tampered", "E-PROJECT-TAMPERED"),
    ],
)
def test_a_damaged_project_shows_its_code_and_the_window_keeps_running(
    qtbot, window, tmp_path, damage, code
):
    assert window.new_project({"case_id": "current"})
    current = window.project
    folder = tmp_path / "bad"
    if damage == "tampered":
        assert window.new_project({"case_id": "to tamper"})
        assert window.save_project_as(folder)
        doc = json.loads((folder / PROJECT_FILE).read_text())
        doc["examiner"] = "M. Allory"
        (folder / PROJECT_FILE).write_text(json.dumps(doc))
        current = window.project
    else:
        _damaged(folder, damage)
    assert not window.open_project(folder)
    box = window.messenger.last_box
    assert box.windowTitle() == "Cannot open the project"
    assert box.icon() == QMessageBox.Icon.Critical
    assert f"[{code}]" in window.messenger.last_text and str(folder) in window.messenger.last_text
    assert "Traceback" not in window.messenger.last_text
    assert window.project is current
    # the window goes on working: a new project, saved and reopened
    assert window.new_project({"case_id": "next"})
    assert window.save_project_as(tmp_path / "next")
    assert window.open_project(tmp_path / "next") and window.project.case_id == "next"
    assert window.motor_panel._thread.isRunning()


def test_an_unexpected_failure_while_loading_is_shown_not_raised(qtbot, window, tmp_path,
                                                                 monkeypatch):
    from impress_gui.ui import main_window

    def buggy_load(path):
        raise ValueError("invalid literal for int() with base 10: 'abc'")

    monkeypatch.setattr(main_window.Project, "load", buggy_load)
    (tmp_path / "p").mkdir()
    assert not window.open_project(tmp_path / "p")
    assert "[E-INTERNAL]" in window.messenger.last_text
    assert "ValueError" not in window.messenger.last_text and "int()" not in (
        window.messenger.last_text
    )


def test_an_unsigned_project_opens_with_a_warning_and_signing_is_shown(qtbot, window, tmp_path):
    folder = tmp_path / "old"
    folder.mkdir()
    append_log(folder / LOG_FILE, "project created", {"case_id": "OLD"})
    append_log(folder / LOG_FILE, "project saved", {})
    n, head = log_tail(folder / LOG_FILE)
    (folder / PROJECT_FILE).write_text(json.dumps(V1 | {"log_head": {"entries": n,
                                                                      "sha256": head}}))
    assert window.open_project(folder)
    assert window.messenger.last_box.windowTitle() == "Unsigned project"
    assert "E-PROJECT-UNSIGNED" in window.messenger.last_text
    assert "Not signed" in window.statusBar().currentMessage()
    assert window.save_project()
    assert window.verify_integrity()
    assert "Project file signed by key SHA256:" in window.messenger.last_text
    assert "this installation's key" in window.messenger.last_text


def test_the_case_dialog_names_the_signing_key(qtbot, window, tmp_path):
    from impress_gui.ui.case_dialog import CaseDialog

    assert window.new_project({"case_id": "C"})
    dlg = CaseDialog(window.project, window)
    qtbot.addWidget(dlg)
    assert "Signed when saved" in dlg.signature.text()
    assert window.save_project_as(tmp_path / "c")
    dlg2 = CaseDialog(window.project, window)
    qtbot.addWidget(dlg2)
    fp = window.project.signature_info()["key_fingerprint"]
    assert fp in dlg2.signature.text()


def test_a_failure_while_the_window_is_built_stops_the_motor_thread(qtbot, tmp_path, monkeypatch):
    from impress_gui.ui import main_window
    from impress_gui.ui.motor.panel import MotorPanel

    panel = MotorPanel(port_lister=lambda: [])
    qtbot.addWidget(panel)
    assert panel._thread.isRunning()

    def broken_tab(*args, **kwargs):
        raise RuntimeError("a tab could not be built")

    monkeypatch.setattr(main_window, "CalibrationTab", broken_tab)
    with pytest.raises(RuntimeError):
        main_window.MainWindow(make_settings(tmp_path / "s.ini"), motor_panel=panel)
    assert not panel._thread.isRunning()


def _impress_gui(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "HOME": str(tmp_path),
           KEY_DIR_ENV: str(tmp_path / "keys")}
    cmd = [sys.executable, "-m", "impress_gui", "gui", *args,
           "--settings", str(tmp_path / "s.ini")]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)


@pytest.mark.parametrize("damage", ["entries-abc", "fifo"])
def test_impress_gui_on_a_damaged_project_does_not_abort(tmp_path, damage):
    bad = _damaged(tmp_path / "bad", damage)
    res = _impress_gui([str(bad), "--quit-after", "0.5"], tmp_path)
    assert res.returncode != -6 and res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr and "QThread: Destroyed" not in res.stderr
    checked = _impress_gui([str(bad), "--check"], tmp_path)
    assert checked.returncode == 1, checked.stderr
    assert "Cannot open the project" in checked.stderr and "[E-" in checked.stderr
    assert "Traceback" not in checked.stderr and "QThread: Destroyed" not in checked.stderr
