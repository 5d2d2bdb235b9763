"""The workstation window: tabs, motor dock, menus; projects saved and reopened with the same
state; corrupt projects, changed evidence and errors reported in the window and the log;
the unsaved-changes prompt; ``impress gui`` rendering offscreen."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from gui_helpers import FakeDialogs
from PySide6.QtGui import QImage
from PySide6.QtWidgets import QMessageBox
from test_gui_calibration import calibrate, load_video, render_scan, set_inputs

from impress_gui.core.base.errors import CalibrationError
from impress_gui.core.project.project import LOG_FILE, PROJECT_FILE, read_log
from impress_gui.ui import pyside_fix
from impress_gui.ui.app import build_main_window, make_settings
from impress_gui.ui.messages import Messenger
from impress_gui.ui.motor.panel import MotorPanel
from impress_gui.ui.worker import LatestOnly, Worker

pyside_fix.guard()
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_threads")]
Button = QMessageBox.StandardButton
CASE = {"case_id": "2024-00117", "evidence_id": "EV-3", "examiner": "J. Doe", "notes": "left shoe"}


@pytest.fixture(scope="session")
def scan(tmp_path_factory) -> Path:
    return render_scan(tmp_path_factory)


@pytest.fixture
def make_window(qtbot, tmp_path):
    made = []

    def make():
        w = build_main_window(make_settings(tmp_path / "settings.ini"), port_lister=lambda: [])
        w.dialogs = w.calibration_tab.dialogs = w.calibration_tab.setup.dialogs = FakeDialogs()
        qtbot.addWidget(w)
        w.resize(1700, 1000)
        w.show()
        qtbot.waitExposed(w)
        made.append(w)
        return w

    yield make
    for w in made:
        w.shutdown()


@pytest.fixture
def window(make_window):
    return make_window()


def calibrated_project(qtbot, window, scan: Path, video: Path | None = None):
    """New case, video loaded, the simulator's picks imported, calibrated."""
    assert window.new_project(CASE)
    tab = window.calibration_tab
    load_video(qtbot, tab, video or scan / "scan.mp4")
    assert tab.import_picks(str(scan / "picks.json"))
    truth = json.loads((scan / "truth.json").read_text())
    set_inputs(tab, scan, truth["speed_mm_s"])
    tab.go_to_pick("t2")
    return calibrate(qtbot, tab)


def test_window_has_tabs_motor_dock_menus_and_status(window):
    titles = [window.tabs.tabText(i) for i in range(window.tabs.count())]
    assert titles == ["Calibration", "Processing", "Viewer", "Compare"]
    for tab in window.extra_tabs.values():
        if getattr(tab, "is_placeholder", False):
            assert "Coming soon" in tab.findChildren(type(window.project_label))[0].text()
    assert isinstance(window.motor_dock.widget(), MotorPanel)
    file_menu = window.menuBar().actions()[0].menu()
    texts = [a.text().replace("&", "") for a in file_menu.actions() if a.text()]
    for wanted in (
        "New project...",
        "Open project...",
        "Open recent",
        "Save",
        "Save as...",
        "Quit",
    ):
        assert wanted in texts
    assert "not saved yet" in window.project_label.text()
    assert window.windowTitle().startswith("IMPREsS - Untitled")


def test_long_paths_and_messages_do_not_widen_the_window(qtbot, window):
    """A project in a deep folder (the status bar) and a long progress message (a tab's task
    line) are shortened on screen, whole in the label's text and tooltip; the window's
    minimum width stays what its panels need and fits a 1366-pixel laptop screen (a plain
    label widened the window to 1387 pixels while the sample's reconstruction loaded, and
    more with a longer path), motor panel included."""
    before = window.minimumSizeHint().width()
    assert before <= 1300, before
    deep = "/media/analyst/EVIDENCE-2026-0412/" + "/".join(["subfolder"] * 40)
    window.project_label.setText(f"case A | evidence B | {deep}")
    window.viewer_tab.tasks.label.setText(f"loading the reconstruction {deep}/reconstruction")
    window.viewer_tab.tasks.show()
    qtbot.wait(50)
    assert window.minimumSizeHint().width() <= before
    assert window.project_label.text().endswith(deep)
    assert window.project_label.toolTip().endswith(deep)
    assert window.viewer_tab.tasks.label.text().endswith("/reconstruction")
    # the whole of the motor panel scrolls below STOP on a short window
    panel = window.motor_dock.widget()
    assert window.motor_dock.minimumSizeHint().height() < 400
    assert panel.scroll_area.isAncestorOf(panel.log_view)
    assert not panel.scroll_area.isAncestorOf(panel.stop_button)


def test_save_and_reopen_restores_the_same_state(qtbot, make_window, scan, tmp_path):
    first = make_window()
    cal = calibrated_project(qtbot, first, scan)
    tab = first.calibration_tab
    assert first.is_dirty() and first.isWindowModified()
    folder = tmp_path / "case-117"
    assert first.save_project_as(folder)
    assert not first.is_dirty() and not first.isWindowModified()
    assert (folder / PROJECT_FILE).exists()
    actions = [e["action"] for e in read_log(folder / LOG_FILE)]
    for wanted in (
        "project created",
        "project started",
        "video added",
        "picks imported",
        "corner picks set",
        "calibration set",
        "project saved",
    ):
        assert wanted in actions
    assert first.recent_projects()[0] == str(folder)

    second = make_window()
    with qtbot.waitSignal(
        second.calibration_tab.video_changed, timeout=15000, check_params_cb=lambda p: p != ""
    ):
        assert second.open_project(folder)
    tab2 = second.calibration_tab
    assert second.project.case_id == CASE["case_id"] and second.project.examiner == "J. Doe"
    assert tab2.video_path == tab.video_path and tab2.video_sha256 == tab.video_sha256
    assert tab2.editor.state.corners_t1 == tab.editor.state.corners_t1
    assert tab2.editor.state.corners_t2 == tab.editor.state.corners_t2
    assert (tab2.editor.state.t1, tab2.editor.state.t2) == (
        tab.editor.state.t1,
        tab.editor.state.t2,
    )
    assert tab2.calibration.roll_deg == cal.roll_deg
    assert tab2.calibration.tilt_deg == cal.tilt_deg
    np.testing.assert_array_equal(tab2.calibration.corner_residuals_mm, cal.corner_residuals_mm)
    assert tab2.results.summary() == tab.results.summary()
    assert not tab2.results.stale_label.isVisible()
    assert tab2.setup.speed_mm_s() == tab.setup.speed_mm_s()
    np.testing.assert_array_equal(
        tab2.setup.intrinsics.camera_matrix, tab.setup.intrinsics.camera_matrix
    )
    assert tab2.setup.target.name == tab.setup.target.name
    assert tab2.current_frame == tab.editor.state.t1
    assert not second.is_dirty()
    assert tab2.view.reproj_points.getData()[0] is not None
    assert len(tab2.view.reproj_points.getData()[0]) == 6
    assert second.verify_integrity()
    assert "intact" in second.messenger.last_text


@pytest.mark.parametrize(
    "damage, needle",
    [
        ("{not json", "not valid JSON"),
        ('{"format": "impress.project", "version": 7}', "version 7 is not supported"),
        ('{"format": "impress.project", "version": 1, "picks": {"t1": 1}}', "picks"),
        ("tamper-log", "E-LOG-TAMPERED"),
    ],
)
def test_a_corrupt_project_shows_a_message_and_changes_nothing(
    qtbot, window, tmp_path, damage, needle
):
    assert window.new_project({"case_id": "current"})
    current = window.project
    folder = tmp_path / "broken"
    if damage == "tamper-log":
        window.save_project_as(folder)
        current = window.project
        log = folder / LOG_FILE
        lines = log.read_bytes().splitlines(keepends=True)
        lines[0] = lines[0].replace(b"project created", b"project deleted")
        log.write_bytes(b"".join(lines))
    else:
        folder.mkdir()
        (folder / PROJECT_FILE).write_text(damage)
    assert not window.open_project(folder)
    text = window.messenger.last_text
    assert needle in text and str(folder) in text
    assert window.messenger.last_box.windowTitle() == "Cannot open the project"
    assert window.project is current and window.project.case_id == "current"


def test_errors_are_shown_in_the_window_and_written_to_the_log(qtbot, window, tmp_path):
    assert window.new_project({"case_id": "E1"})
    folder = tmp_path / "p"
    assert window.save_project_as(folder)
    bad = tmp_path / "notes.mp4"
    bad.write_text("not a video")
    with qtbot.waitSignal(window.calibration_tab.tasks.done, timeout=10000):
        window.open_path(bad)
    assert "not a readable video" in window.messenger.last_text
    entry = read_log(folder / LOG_FILE)[-1]
    assert entry["action"] == "error shown"
    assert entry["details"]["code"] == "E-VIDEO-OPEN"
    assert "not a readable video" in entry["details"]["message"]


def test_a_changed_evidence_video_is_refused_when_the_project_opens(
    qtbot, make_window, scan, tmp_path
):
    evidence = tmp_path / "evidence" / "scan.mp4"
    evidence.parent.mkdir()
    shutil.copy(scan / "scan.mp4", evidence)
    first = make_window()
    assert first.new_project(CASE)
    load_video(qtbot, first.calibration_tab, evidence)
    assert first.save_project_as(tmp_path / "case")
    with open(evidence, "ab") as fh:
        fh.write(b"\0")
    second = make_window()
    with qtbot.waitSignal(second.calibration_tab.tasks.done, timeout=15000) as blocker:
        assert second.open_project(tmp_path / "case")
    assert blocker.args[1] == "failed"
    text = second.messenger.last_text
    assert "has changed since it was added" in text and "E-EVIDENCE-CHANGED" in text
    assert second.calibration_tab.video is None
    assert "E-EVIDENCE-CHANGED" in json.dumps(read_log(tmp_path / "case" / LOG_FILE)[-1])


def test_unsaved_changes_prompt_on_close(qtbot, window, tmp_path):
    asked = []
    answers = iter([Button.Cancel, Button.Save])

    def ask(title, message, buttons=None, default=None):
        asked.append(message)
        return next(answers)

    window.messenger.ask = ask
    assert not window.is_dirty()
    window.calibration_tab.setup.speed_spin.setValue(5.2552)
    assert window.is_dirty() and window.isWindowModified()
    assert not window.close()  # cancelled: the window stays
    assert window.isVisible() and asked == ["Save the changes to Untitled?"]
    window.dialogs.answer = str(tmp_path / "saved-on-close")
    assert window.close()
    assert not window.isVisible()
    saved = json.loads((tmp_path / "saved-on-close" / PROJECT_FILE).read_text())
    assert saved["calibration_settings"]["speed_mm_s"] == 5.2552


def test_recent_projects_are_remembered_in_the_settings(qtbot, window, tmp_path):
    for name in ("a", "b"):
        assert window.new_project({"case_id": name})
        assert window.save_project_as(tmp_path / name)
    assert window.recent_projects()[:2] == [str(tmp_path / "b"), str(tmp_path / "a")]
    actions = window.recent_menu.actions()
    assert [a.text() for a in actions[:2]] == [str(tmp_path / "b"), str(tmp_path / "a")]
    actions[1].trigger()
    assert window.project.case_id == "a"
    assert "recent_projects" in (tmp_path / "settings.ini").read_text()


def _run_impress(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "HOME": str(tmp_path)}
    cmd = [sys.executable, "-m", "impress_gui", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=env)


def test_impress_gui_renders_a_screenshot_offscreen_and_quits(scan, tmp_path):
    shot = tmp_path / "window.png"
    res = _run_impress(
        [
            "gui",
            str(scan / "scan.mp4"),
            "--screenshot",
            str(shot),
            "--quit-after",
            "0.3",
            "--settings",
            str(tmp_path / "s.ini"),
        ],
        tmp_path,
    )
    assert res.returncode == 0, res.stderr
    img = QImage(str(shot))
    assert (img.width(), img.height()) == (1920, 1080)
    assert "Fatal" not in res.stderr and "Traceback" not in res.stderr


def test_plain_impress_opens_the_window(monkeypatch):
    import impress_gui.ui.app as app
    from impress_gui.cli import main

    calls = []
    monkeypatch.setattr(app, "run_gui", lambda *a, **k: calls.append((a, k)) or 0)
    assert main([]) == 0
    assert calls == [
        (
            (None,),
            {
                "screenshot": None,
                "quit_after_s": None,
                "size": None,  # as last closed, else fitted to the screen
                "settings_path": None,
                "with_motor": True,
                "tab": None,
            },
        )
    ]


def test_worker_reports_failures_by_code_and_keeps_tracebacks_out_of_sight(qtbot):
    worker = Worker(name="test")

    def refuses(progress, cancel):
        raise CalibrationError("corners C and D coincide", code="E-PICKS")

    with qtbot.waitSignal(worker.failed, timeout=5000) as blocker:
        worker.start(refuses)
    assert blocker.args == ["E-PICKS", "corners C and D coincide"]

    def buggy(progress, cancel):
        progress(0.5, "half way")
        return {}["missing"]

    with qtbot.waitSignal(worker.failed, timeout=5000) as blocker:
        worker.start(buggy)
    code, message = blocker.args
    assert code == "E-INTERNAL" and "KeyError" in message and "Traceback" in message
    messenger = Messenger(None)
    box = messenger.error("Calibration failed", message, code)
    assert "Traceback" not in box.informativeText() and "KeyError" in box.detailedText()
    assert not worker.is_running()
    messenger.close_all()


def test_latest_only_delivers_just_the_newest_request(qtbot):
    release = threading.Event()

    def job(i):
        def run(progress, cancel):
            while not release.wait(0.005):
                cancel.check()
            cancel.check()
            return i

        return run

    latest = LatestOnly(name="test")
    results = []
    latest.finished.connect(results.append)
    for i in range(3):
        latest.submit(job(i))
    release.set()
    qtbot.waitUntil(lambda: not latest.is_running(), timeout=5000)
    assert results == [2]


def test_motor_choices_are_kept_between_sessions(make_window):
    first = make_window()
    box = first.motor_panel.scan_box
    box.speed_preset_combo.setCurrentIndex(box.speed_preset_combo.findData("fast"))
    box.end_spin.setValue(812.5)
    first.shutdown()
    second = make_window()
    box2 = second.motor_panel.scan_box
    assert box2.speed_preset_combo.currentData() == "fast"
    assert second.motor_panel.speed_spin.value() == pytest.approx(13.138, abs=0.01)
    assert box2.end_spin.value() == pytest.approx(812.5)


def test_discard_removes_the_unsaved_reconstruction_and_says_so_in_the_log(window, tmp_path,
                                                                          monkeypatch):
    """Closing with Discard (issue 21, item 12): a reconstruction made since the last save
    (~300 MB at 1080p) does not stay in the project; one saved before stays. The log is
    append-only: what was done stays recorded, followed by the discard."""
    assert window.new_project(CASE)
    folder = tmp_path / "case"
    assert window.save_project_as(folder)
    p = window.project

    def fake_reconstruction(name: str) -> Path:
        out = folder / "reconstructions" / name
        out.mkdir(parents=True)
        (out / "metadata.json").write_text("{}")
        (out / "heightmap.tif").write_bytes(b"x" * 1000)
        (folder / "reconstructions" / f"{name}.calibration.json").write_text("{}")
        p.add_output(out / "metadata.json", "reconstruction")
        return out

    kept = fake_reconstruction("recon-saved")
    assert window.save_project()
    unsaved = fake_reconstruction("recon-unsaved")
    assert window.is_dirty()
    monkeypatch.setattr(window.messenger, "ask", lambda *a, **k: QMessageBox.StandardButton.Discard)
    assert window.maybe_save()
    assert kept.is_dir() and not unsaved.exists()
    assert not (folder / "reconstructions" / "recon-unsaved.calibration.json").exists()
    log = read_log(folder / LOG_FILE)
    assert log[-1]["action"] == "unsaved changes discarded"
    assert log[-1]["details"]["removed"] == ["reconstructions/recon-unsaved",
                                             "reconstructions/recon-unsaved.calibration.json"]
    assert not window.project.dirty
