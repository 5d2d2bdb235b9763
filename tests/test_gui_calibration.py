"""The calibration tab driven through its real widgets (pytest-qt, offscreen) on a simulated scan:
corners clicked with mouse events at their true pixel positions, calibration compared with the
simulator's truth, snapping and undo, cancel, and bad input that must change nothing."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from gui_helpers import FakeDialogs
from PySide6.QtCore import QEvent, QPoint, QPointF, Qt
from PySide6.QtGui import QMouseEvent
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QApplication, QMessageBox

from impress_gui.core.calibration.target import CORNER_NAMES
from impress_gui.ui import pyside_fix
from impress_gui.ui.app import make_settings
from impress_gui.ui.calibration.tab import CalibrationTab
from impress_gui.ui.messages import Messenger

pyside_fix.guard()
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_threads")]
_SCANS: dict[str, Path] = {}


def render_scan(factory) -> Path:
    """A 320x180, 15 frames/s simulated scan of the flat preset (made once per session)."""
    if "flat" not in _SCANS or not (_SCANS["flat"] / "scan.mp4").exists():
        out = factory.mktemp("sim") / "flat"
        cmd = [
            sys.executable,
            "-m",
            "impress_gui",
            "simulate",
            str(out),
            "--preset",
            "flat",
            "--length-mm",
            "100",
            "--resolution",
            "320x180",
            "--fps",
            "15",
            "--grid-mm",
            "0.5",
        ]
        subprocess.run(cmd, check=True, capture_output=True, timeout=120)
        _SCANS["flat"] = out
    return _SCANS["flat"]


@pytest.fixture(scope="session")
def scan(tmp_path_factory) -> Path:
    return render_scan(tmp_path_factory)


@pytest.fixture(scope="session")
def truth(scan) -> dict:
    return json.loads((scan / "truth.json").read_text())


@pytest.fixture(scope="session")
def true_picks(scan) -> dict:
    return json.loads((scan / "picks.json").read_text())


@pytest.fixture
def tab(qtbot, tmp_path):
    messenger = Messenger(None)
    settings = make_settings(tmp_path / "settings.ini")
    widget = CalibrationTab(messenger, FakeDialogs(), settings=settings)
    qtbot.addWidget(widget)
    widget.resize(1600, 900)
    widget.show()
    qtbot.waitExposed(widget)
    yield widget
    widget.shutdown()
    messenger.close_all()


# ----- helpers (also used by test_gui_window) ----------------------------------------------------
def load_video(qtbot, tab, path, timeout=15000) -> None:
    with qtbot.waitSignal(tab.video_changed, timeout=timeout, check_params_cb=lambda p: p != ""):
        tab.load_video(path)


def click_image(qtbot, tab, u: float, v: float, button=Qt.MouseButton.LeftButton) -> None:
    """A real mouse click on the view's viewport where image pixel (u, v) is drawn."""
    pt = tab.view.map_to_viewport(u, v)
    QTest.mouseClick(tab.view.viewport(), button, Qt.KeyboardModifier.NoModifier, pt)


def drag(widget, start: QPoint, end: QPoint, steps: int = 6) -> None:
    """Press, move with the button held, release (QTest.mouseMove carries no buttons). The
    moves come faster than a hand's, so pyqtgraph's mouse-rate limit is lifted meanwhile."""
    import pyqtgraph as pg

    rate = pg.getConfigOption("mouseRateLimit")
    pg.setConfigOption("mouseRateLimit", -1)
    left, none = Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier

    def send(kind, pos, button, buttons):
        p = QPointF(pos)
        ev = QMouseEvent(kind, p, QPointF(widget.mapToGlobal(pos)), button, buttons, none)
        QApplication.sendEvent(widget, ev)

    send(QEvent.Type.MouseButtonPress, start, left, left)
    for f in np.linspace(0, 1, steps + 1)[1:]:
        pos = start + QPoint(round(f * (end.x() - start.x())), round(f * (end.y() - start.y())))
        send(QEvent.Type.MouseMove, pos, Qt.MouseButton.NoButton, left)
    send(QEvent.Type.MouseButtonRelease, end, left, Qt.MouseButton.NoButton)
    pg.setConfigOption("mouseRateLimit", rate)


def mark_corners(qtbot, tab, picks: dict, which: str, names=CORNER_NAMES, zoom=True) -> None:
    """Click the corners at their true positions, zoomed in on each as a careful user does."""
    tab.go_to_frame(picks[which])
    for name in names:
        uv = picks[f"corners_{which}"][name]
        if zoom:
            tab.view.zoom_around(*uv, span_px=16)
        click_image(qtbot, tab, *uv)
    tab.view.fit()


def set_inputs(tab, scan: Path, speed: float) -> None:
    assert tab.setup.load_intrinsics_file(str(scan / "intrinsics.json"))
    assert tab.setup.load_target_file(str(scan / "target.json"))
    tab.setup.speed_spin.setValue(speed)


def calibrate(qtbot, tab, timeout=20000):
    with qtbot.waitSignal(tab.calibrated, timeout=timeout) as blocker:
        QTest.mouseClick(tab.calibrate_button, Qt.MouseButton.LeftButton)
    return blocker.args[0]


# ----- tests -------------------------------------------------------------------------------------
def test_click_corners_and_calibrate_matches_truth(qtbot, tab, scan, truth, true_picks):
    load_video(qtbot, tab, scan / "scan.mp4")
    assert tab.video.frame_count == truth["frame_count"]
    assert tab.corners.snap_check.isChecked()  # on by default; here the clicks must land right
    box = tab.corners.snap_check
    QTest.mouseClick(box, Qt.MouseButton.LeftButton, pos=QPoint(8, box.height() // 2))
    assert not box.isChecked()
    tab.view.zoom_around(100, 100, span_px=16)
    resolution = 0.5 / tab.view.pixels_per_image_pixel()
    assert resolution < 0.02
    mark_corners(qtbot, tab, true_picks, "t1")
    mark_corners(qtbot, tab, true_picks, "t2")
    s = tab.editor.state
    assert (s.t1, s.t2) == (true_picks["t1"], true_picks["t2"])
    for which in ("t1", "t2"):
        got = np.array([s.corners(which)[c] for c in CORNER_NAMES])
        want = np.array([true_picks[f"corners_{which}"][c] for c in CORNER_NAMES])
        assert np.abs(got - want).max() < resolution + 1e-6
    set_inputs(tab, scan, truth["speed_mm_s"])
    cal = calibrate(qtbot, tab)
    assert abs(cal.roll_deg - truth["roll_deg"]) < 0.1
    assert abs(cal.tilt_deg - truth["tilt_deg"]) < 0.1
    assert abs(cal.implied_speed_mm_s / truth["speed_mm_s"] - 1) < 0.01
    # the numbers are on screen, and the project holds them
    shown = tab.results.summary()
    assert f"{cal.roll_deg:+.3f} deg" == shown["roll"]
    assert f"{cal.tilt_deg:+.3f} deg" == shown["tilt"]
    assert "implied by the target" in shown["speed"] and "RMS" in shown["green"]
    assert tab.results.table.item(0, 0).text() == f"{cal.corner_residuals_mm[0]:.3f}"
    assert tab.project.calibration is cal and tab.project.picks.t1 == true_picks["t1"]
    # the fitted target is drawn where the corners are, in this frame (t2)
    x, y = tab.view.reproj_points.getData()
    want = np.array([true_picks["corners_t2"][c] for c in CORNER_NAMES])
    assert np.abs(np.column_stack([x, y]) - want).max() < 1.0
    assert tab.export_cal_button.isEnabled()
    assert not tab.results.stale_label.isVisible()
    # changing an input afterwards flags the result as out of date
    tab.setup.speed_spin.setValue(5.2552)
    assert tab.results.stale_label.isVisible()
    assert "The rail speed changed since this calibration" in tab.results.stale_label.text()
    tab.setup.speed_spin.setValue(truth["speed_mm_s"])
    assert not tab.results.stale_label.isVisible()


def test_snap_is_visible_and_undoable_and_drag_moves_a_corner(qtbot, tab, scan, true_picks):
    load_video(qtbot, tab, scan / "scan.mp4")
    assert tab.corners.snap_check.isChecked()  # on by default (the snap declines when unsure)
    t1 = true_picks["t1"]
    tab.go_to_frame(t1)
    true_a = np.array(true_picks["corners_t1"]["A"])
    rough = true_a + (1.6, -1.2)
    click_image(qtbot, tab, *rough)
    s = tab.editor.state
    assert s.t1 == t1
    snapped, raw = np.array(s.corners_t1["A"]), np.array(s.raw_t1["A"])
    assert np.linalg.norm(snapped - true_a) < np.linalg.norm(raw - true_a)
    assert np.linalg.norm(snapped - true_a) < 1.5  # the core's accuracy at 320x180
    # the click is shown beside the snapped corner, and the snap can be undone
    assert len(tab.view.raw_points.getData()[0]) == 1
    assert tab.corners.undo_snap_button.isEnabled()
    QTest.mouseClick(tab.corners.undo_snap_button, Qt.MouseButton.LeftButton)
    assert np.allclose(tab.editor.state.corners_t1["A"], raw)
    assert len(tab.view.raw_points.getData()[0]) == 0
    QTest.mouseClick(tab.corners.redo_button, Qt.MouseButton.LeftButton)
    assert np.allclose(tab.editor.state.corners_t1["A"], snapped)
    # drag the marker to a new place with the mouse
    start = tab.view.map_to_viewport(*snapped)
    end = tab.view.map_to_viewport(snapped[0] + 6, snapped[1] + 4)
    drag(tab.view.viewport(), start, end)
    moved = np.array(tab.editor.state.corners_t1["A"])
    assert np.allclose(moved, snapped + (6, 4), atol=0.5)
    assert tab.editor.undo_label == "move A in t1"
    # clear the frame, then undo brings the corner back
    QTest.mouseClick(tab.corners.clear_button, Qt.MouseButton.LeftButton)
    assert tab.editor.count("t1") == 0 and not tab.view.markers
    tab.editor.undo()
    assert np.allclose(tab.editor.state.corners_t1["A"], moved)


def test_cancel_a_running_operation_changes_nothing(qtbot, tab, scan):
    load_video(qtbot, tab, scan / "scan.mp4")
    before = tab.editor.state
    with qtbot.waitSignal(tab.tasks.worker.progress, timeout=10000):
        QTest.mouseClick(tab.frames.find_button, Qt.MouseButton.LeftButton)
    assert tab.is_busy() and tab.tasks.cancel_button.isVisible()
    assert not tab.calibrate_button.isEnabled()
    with qtbot.waitSignal(tab.tasks.done, timeout=10000) as blocker:
        QTest.mouseClick(tab.tasks.cancel_button, Qt.MouseButton.LeftButton)
    assert blocker.args[1] == "cancelled"
    assert not tab.is_busy() and not tab.tasks.isVisible()
    assert tab.proposal is None and tab.editor.state == before
    assert tab.messenger.last_box is None
    # and it runs to the end when left alone: t1/t2 are proposed and the view jumps to t1
    with qtbot.waitSignal(tab.tasks.done, timeout=15000) as blocker:
        tab.propose_frames()
    assert blocker.args[1] == "finished"
    assert tab.editor.state.t1 == tab.proposal["t1"] == tab.current_frame
    assert tab.editor.state.t2 == tab.proposal["t2"]


def test_frames_can_be_scrubbed_with_the_slider_and_number(qtbot, tab, scan):
    load_video(qtbot, tab, scan / "scan.mp4")
    tab.nav.spin.setValue(17)
    qtbot.waitUntil(lambda: tab.current_frame == 17, timeout=3000)
    tab.nav.slider.setValue(100)
    qtbot.waitUntil(lambda: tab.current_frame == 100, timeout=3000)
    assert tab.nav.spin.value() == 100
    assert tab.nav.time_label.text().startswith(f"{tab.video.times_s[100]:.2f} s")


@pytest.mark.parametrize(
    "kind, needle", [("text", "not a readable video"), ("empty", "file is empty")]
)
def test_a_bad_video_shows_a_message_and_keeps_the_loaded_one(
    qtbot, tab, scan, tmp_path, kind, needle
):
    load_video(qtbot, tab, scan / "scan.mp4")
    tab.go_to_frame(40)
    click_image(qtbot, tab, 100.0, 100.0)
    state, path = tab.editor.state, tab.video_path
    bad = tmp_path / "bad.mp4"
    bad.write_bytes(b"" if kind == "empty" else b"this is a text file, not a video\n" * 50)
    questions = []
    answers = iter([QMessageBox.StandardButton.No, QMessageBox.StandardButton.Yes])
    tab.messenger.ask = lambda title, text, *a: questions.append(text) or next(answers)
    assert not tab.load_video(bad)  # "No": nothing happens
    assert not tab.is_busy() and tab.messenger.last_box is None
    with qtbot.waitSignal(tab.tasks.done, timeout=10000):
        assert tab.load_video(bad)
    assert len(questions) == 2 and "the corners and the calibration" in questions[0]
    assert needle in tab.messenger.last_text
    assert "[E-VIDEO-" in tab.messenger.last_text
    assert tab.video_path == path and tab.video is not None
    assert tab.editor.state == state and tab.current_frame == 40
    assert tab.project.video.path == str(path)


def test_a_click_outside_the_image_shows_a_message_and_marks_nothing(qtbot, tab, scan):
    load_video(qtbot, tab, scan / "scan.mp4")
    tab.go_to_frame(30)
    assert tab.view.viewport().rect().contains(tab.view.map_to_viewport(100.0, -8.0))
    click_image(qtbot, tab, 100.0, -8.0)
    assert "outside the 320x180 image" in tab.messenger.last_text
    assert tab.editor.state.t1 is None and tab.editor.count("t1") == 0
    assert not tab.editor.can_undo()


def test_calibrating_with_five_corners_explains_what_is_missing(
    qtbot, tab, scan, truth, true_picks
):
    load_video(qtbot, tab, scan / "scan.mp4")
    tab.corners.snap_check.setChecked(False)
    mark_corners(qtbot, tab, true_picks, "t1")
    mark_corners(qtbot, tab, true_picks, "t2", names=CORNER_NAMES[:5])
    set_inputs(tab, scan, truth["speed_mm_s"])
    QTest.mouseClick(tab.calibrate_button, Qt.MouseButton.LeftButton)
    text = tab.messenger.last_text
    assert "corners F are not marked in frame t2" in text and "E-PICKS-INCOMPLETE" in text
    assert not tab.is_busy()
    assert tab.calibration is None and tab.project.calibration is None
    assert "Not calibrated yet" in tab.results.empty_label.text()
    assert tab.results.empty_label.isVisible()


def test_calibrating_without_speed_or_video_says_so(qtbot, tab, scan):
    QTest.mouseClick(tab.calibrate_button, Qt.MouseButton.LeftButton)  # disabled: no video
    assert tab.messenger.last_box is None
    assert tab.calibrate() is False
    assert "Load the scan video first" in tab.messenger.last_text
    load_video(qtbot, tab, scan / "scan.mp4")
    tab.setup.load_intrinsics_file(str(scan / "intrinsics.json"))
    assert tab.calibrate() is False
    assert "Enter the rail speed" in tab.messenger.last_text


def test_a_bad_intrinsics_file_is_refused_with_its_reason(qtbot, tab, tmp_path):
    bad = tmp_path / "intr.json"
    bad.write_text('{"format": "impress.intrinsics", "version": 1, "image_size": [0, 5]}')
    assert not tab.setup.load_intrinsics_file(str(bad))
    assert "image_size must be [width, height]" in tab.messenger.last_text
    assert tab.setup.intrinsics is None


# ----- checkerboard calibration from the tab -------------------------------------------------------
@pytest.fixture(scope="session")
def board_views(board_views):
    """20 views of a 9x6 board with 25 mm squares through the simulator's 640x360 camera (the
    set tests/test_calibrate_camera.py checks the core with: conftest's ``board_views``, made
    once per run), and the true intrinsics."""
    from impress_gui.sim.rig import default_intrinsics

    return board_views, default_intrinsics(640, 360)


def open_checkerboard_dialog(qtbot, tab):
    QTest.mouseClick(tab.setup.checkerboard_button, Qt.MouseButton.LeftButton)
    dlg = tab.checkerboard_dialog
    assert dlg is not None
    qtbot.waitExposed(dlg)
    return dlg


def fill_checkerboard_dialog(qtbot, tab, dlg, folder: Path, board, square_mm) -> None:
    QTest.mouseClick(dlg.folder_radio, Qt.MouseButton.LeftButton)
    tab.dialogs.answer = str(folder)
    QTest.mouseClick(dlg.browse_button, Qt.MouseButton.LeftButton)
    assert tab.dialogs.asked[-1] == "Folder of checkerboard images"
    assert dlg.path_edit.text() == str(folder)
    for spin, value in ((dlg.cols_spin, board[0]), (dlg.rows_spin, board[1])):
        spin.lineEdit().selectAll()
        QTest.keyClicks(spin, str(value))
    dlg.square_spin.lineEdit().selectAll()
    QTest.keyClicks(dlg.square_spin, f"{square_mm:g}")
    assert dlg.request().board == tuple(board) and dlg.request().square_mm == square_mm


def test_checkerboard_dialog_calibrates_the_camera_and_remembers_its_answers(
    qtbot, tab, board_views
):
    from test_calibrate_camera import DIST_PX, F_REL, PP_PX, check_against_truth

    folder, truth = board_views
    assert "folder of images" in tab.setup.checkerboard_button.toolTip()
    dlg = open_checkerboard_dialog(qtbot, tab)
    assert dlg.video_radio.isChecked()  # first use: a video, 9x6, 25 mm
    assert (dlg.cols_spin.value(), dlg.rows_spin.value(), dlg.square_spin.value()) == (9, 6, 25)
    # the video chooser in video mode; OK with no source, or a folder as a video, is refused
    tab.dialogs.answer = ""
    QTest.mouseClick(dlg.browse_button, Qt.MouseButton.LeftButton)
    assert tab.dialogs.asked[-1] == "Checkerboard video"
    QTest.mouseClick(dlg.ok_button, Qt.MouseButton.LeftButton)
    assert dlg.isVisible() and dlg.error_label.isVisible()
    assert "Choose the checkerboard video" in dlg.error_label.text()
    dlg.path_edit.setText(str(folder))
    QTest.mouseClick(dlg.ok_button, Qt.MouseButton.LeftButton)
    assert dlg.isVisible() and "is a folder" in dlg.error_label.text() and not tab.is_busy()
    # a folder of images, 9x6 inner corners, 25 mm squares
    fill_checkerboard_dialog(qtbot, tab, dlg, folder, (9, 6), 25.0)
    with qtbot.waitSignal(tab.tasks.done, timeout=30000) as blocker:
        QTest.mouseClick(dlg.ok_button, Qt.MouseButton.LeftButton)
    assert blocker.args[1] == "finished", tab.messenger.last_text
    assert not dlg.isVisible()
    intr = tab.setup.intrinsics
    assert intr is not None and "9x6 inner corners, 25 mm squares" in intr.source
    check_against_truth(intr, truth, F_REL, PP_PX, DIST_PX)
    assert f"{intr.fx:.1f} px" in tab.setup.intrinsics_label.text()
    assert tab.dirty
    tab.commit_to_project()
    assert tab.project.intrinsics is intr
    # the answers are remembered for next time
    again = open_checkerboard_dialog(qtbot, tab)
    assert again is not dlg and again.folder_radio.isChecked()
    assert again.path_edit.text() == str(folder)
    assert (again.cols_spin.value(), again.rows_spin.value(), again.square_spin.value()) == (
        9,
        6,
        25.0,
    )
    QTest.mouseClick(
        again.buttons.button(again.buttons.StandardButton.Cancel), Qt.MouseButton.LeftButton
    )
    assert not again.isVisible() and not tab.is_busy()


def test_checkerboard_with_the_wrong_board_size_says_too_few_boards(qtbot, tab, board_views):
    folder, _truth = board_views
    dlg = open_checkerboard_dialog(qtbot, tab)
    fill_checkerboard_dialog(qtbot, tab, dlg, folder, (8, 6), 25.0)
    with qtbot.waitSignal(tab.tasks.done, timeout=30000) as blocker:
        QTest.mouseClick(dlg.ok_button, Qt.MouseButton.LeftButton)
    assert blocker.args[1] == "failed"
    box = tab.messenger.last_box
    assert box is not None and box.isVisible()
    text = tab.messenger.last_text
    assert text.startswith("Checkerboard calibration failed")
    assert "found the 8x6 board (inner corners) in" in text and "at least 8 are needed" in text
    assert "[E-TOO-FEW-BOARDS]" in text
    assert "Traceback" not in text and not box.detailedText()
    assert tab.setup.intrinsics is None and not tab.is_busy()


# ----- marking aids and result display (docs/calibration-guide.md) ------------------------------
def hover(qtbot, tab, u: float, v: float) -> None:
    """The mouse moved (no button) to where image pixel (u, v) is drawn (after a pause longer
    than pyqtgraph's mouse-rate limit, which drops moves closer than 10 ms together)."""
    qtbot.wait(30)
    vp = tab.view.viewport()
    pos = QPointF(tab.view.map_to_viewport(u, v))
    ev = QMouseEvent(
        QEvent.Type.MouseMove,
        pos,
        QPointF(vp.mapToGlobal(pos.toPoint())),
        Qt.MouseButton.NoButton,
        Qt.MouseButton.NoButton,
        Qt.KeyboardModifier.NoModifier,
    )
    QApplication.sendEvent(vp, ev)


def test_the_loupe_magnifies_the_pixels_under_the_cursor(qtbot, tab, scan, true_picks):
    load_video(qtbot, tab, scan / "scan.mp4")
    tab.go_to_frame(true_picks["t1"])
    loupe, rgb = tab.loupe, tab.video.read(true_picks["t1"])
    assert loupe.isVisible() and loupe.centre is None
    for u, v in (true_picks["corners_t1"]["A"], (40.0, 150.0)):
        hover(qtbot, tab, u, v)
        assert loupe.centre is not None
        assert np.allclose(loupe.centre, (u, v), atol=0.5 / tab.view.pixels_per_image_pixel())
        patch, x0, y0 = loupe.crop()
        cu, cv = round(loupe.centre[0]), round(loupe.centre[1])
        r = loupe.radius_px
        assert (x0, y0) == (cu - r, cv - r)
        assert np.array_equal(patch, rgb[cv - r : cv + r + 1, cu - r : cu + r + 1])
        # what is painted: those pixels eight times enlarged, the crosshair on the cursor
        img = loupe.grab().toImage()
        side = min(loupe.width(), loupe.height())
        s = side / (2 * r + 1)
        assert round(s) == 8
        for du, dv in ((-4, -5), (3, -6), (-6, 2)):
            c = img.pixelColor(int((r + du + 0.5) * s), int((r + dv + 0.5) * s))
            want = rgb[cv + dv, cu + du].astype(int)
            assert np.abs(np.array([c.red(), c.green(), c.blue()]) - want).max() <= 2
        cx = int((loupe.centre[0] - x0 + 0.5) * s)
        c = img.pixelColor(cx, 3)
        assert (c.red(), c.green(), c.blue()) == (255, 0, 255)


def test_the_diagram_shows_the_corner_to_click_next(qtbot, tab, scan, true_picks):
    load_video(qtbot, tab, scan / "scan.mp4")
    diagram = tab.corners.diagram
    assert diagram.isVisible() and diagram.target is tab.setup.target
    tab.corners.snap_check.setChecked(False)
    tab.go_to_frame(true_picks["t1"])
    assert diagram.next_name == "A" and diagram.marked == set()
    before = diagram.grab().toImage()
    for i, name in enumerate(CORNER_NAMES):
        click_image(qtbot, tab, *true_picks["corners_t1"][name])
        done = set(CORNER_NAMES[: i + 1])
        nxt = CORNER_NAMES[i + 1] if i + 1 < len(CORNER_NAMES) else None
        assert diagram.marked == done and diagram.next_name == nxt
        if nxt:
            assert tab.corners.instruction.text() == f"t1: click corner {nxt}."
        if name == "A":  # the ring moved from A to B: the drawing changed
            assert diagram.grab().toImage() != before
    assert tab.corners.instruction.text() == "All six corners marked in t1."
    tab.editor.undo()
    assert diagram.next_name == "F" and "F" not in diagram.marked


def true_ground_rows(truth: dict, name: str, width: int) -> np.ndarray:
    """Per image column, the row where the simulator's laser plane meets the flat ground (NaN
    outside the image); the plane is fixed to the camera, so every frame has the same line."""
    from impress_gui.sim.simulate import SimConfig, make_rig

    rig = make_rig(SimConfig(**truth["config"]))
    nrm, d = rig.laser(name).plane.normal, rig.laser(name).plane.offset_mm
    z = rig.standoff_mm
    direction = np.cross(nrm, [0.0, 0.0, 1.0])
    p0 = np.array([0.0, (d - nrm[2] * z) / nrm[1], z])
    pts = p0 + np.linspace(-400, 400, 20001)[:, None] * direction / np.linalg.norm(direction)
    uv = rig.intrinsics.project(pts @ rig.rotation)
    order = np.argsort(uv[:, 0])
    cols = np.arange(width, dtype=float)
    return np.interp(cols, uv[order, 0], uv[order, 1], left=np.nan, right=np.nan)


def n_points(curve) -> int:
    x = curve.getData()[0]
    return 0 if x is None else len(x)


def test_the_detected_stripes_are_drawn_where_the_lasers_are(qtbot, tab, scan, truth, true_picks):
    load_video(qtbot, tab, scan / "scan.mp4")
    assert tab.overlay_stripes.isChecked()
    tab.go_to_frame(true_picks["t1"])
    curves = tab.view.stripes
    qtbot.waitUntil(lambda: all(n_points(curves[n]) for n in curves), timeout=10000)
    w = tab.video.size[0]
    for name in ("green", "red"):
        x, y = curves[name].getData()
        want = true_ground_rows(truth, name, w)[np.round(x).astype(int)]
        err = np.abs(y - want)
        # most columns see the stripe on the ground; in t1 the green one also crosses the target
        assert len(x) > 0.5 * w
        assert np.median(err) < 0.25 and np.mean(err < 0.5) > 0.6, (name, np.median(err))
    # where the green stripe crosses the target it is drawn on the target, off the ground line
    x, y = curves["green"].getData()
    assert np.sum(np.abs(y - true_ground_rows(truth, "green", w)[x.astype(int)]) > 2) > 20
    # the overlay can be switched off and on
    tab.overlay_stripes.setChecked(False)
    assert all(n_points(curves[n]) == 0 for n in curves)
    tab.overlay_stripes.setChecked(True)
    assert all(n_points(curves[n]) for n in curves)


def test_a_calibration_warning_is_shown_in_the_window(qtbot, tab, scan, truth, true_picks):
    load_video(qtbot, tab, scan / "scan.mp4")
    tab.corners.snap_check.setChecked(False)
    mark_corners(qtbot, tab, true_picks, "t1")
    mark_corners(qtbot, tab, true_picks, "t2")
    wrong = round(truth["speed_mm_s"] * 1.03, 3)  # 3 % too fast, as in the guide
    set_inputs(tab, scan, wrong)
    cal = calibrate(qtbot, tab)
    assert cal.warnings and any("speed" in w for w in cal.warnings)
    label = tab.results.warnings_label
    assert label.isVisible()
    for w in cal.warnings:
        assert w in label.text()
    # and in a message box on top of the window
    box = tab.messenger.last_box
    assert box is not None and box.isVisible() and box.icon() == QMessageBox.Icon.Warning
    assert box.windowTitle() == "Check the calibration" and cal.warnings[0] in box.informativeText()


def test_corners_can_be_marked_again_on_the_fitted_target_after_clear_frame(
    qtbot, tab, scan, truth, true_picks
):
    """Issue 21 item 3: once calibrated, 'Show the fitted target' (on by default) draws a
    circle on each corner; a click there must still mark the corner (the circles used to take
    the click and nothing happened), e.g. after 'Clear frame'."""
    load_video(qtbot, tab, scan / "scan.mp4")
    mark_corners(qtbot, tab, true_picks, "t1")
    mark_corners(qtbot, tab, true_picks, "t2")
    set_inputs(tab, scan, truth["speed_mm_s"])
    calibrate(qtbot, tab)
    assert tab.overlay_target.isChecked()
    tab.go_to_frame(true_picks["t2"])
    QTest.mouseClick(tab.corners.clear_button, Qt.MouseButton.LeftButton)
    assert tab.editor.count("t2") == 0 and not tab.view.markers
    # the fitted target's circles lie on the corners, where the user clicks
    x, y = tab.view.reproj_points.getData()
    fitted = np.column_stack([x, y])
    want = np.array([true_picks["corners_t2"][c] for c in CORNER_NAMES])
    assert len(fitted) == 6 and np.abs(fitted - want).max() < 1.0
    for k, name in enumerate(CORNER_NAMES):
        tab.view.zoom_around(*fitted[k], span_px=16)
        assert len(tab.view.reproj_points.pointsAt(QPointF(*fitted[k]))) > 0  # on a circle
        click_image(qtbot, tab, *fitted[k])
        assert tab.editor.count("t2") == k + 1, f"the click on {name} was ignored"
    tab.view.fit()
    got = np.array([tab.editor.state.corners("t2")[c] for c in CORNER_NAMES])
    assert np.abs(got - want).max() < 1.5
    assert set(tab.view.markers) == set(CORNER_NAMES)


def test_the_intrinsics_dialog_takes_a_rolling_shutters_readout(qtbot, tab):
    """The camera's shutter is entered with the lens and shown in the setup's summary: not
    given (the calibration estimates a readout from the picks), a global shutter (recorded as
    readout 0) or a rolling shutter's readout (the field is open only then)."""
    from impress_gui.ui.calibration.setup import IntrinsicsDialog

    dlg = IntrinsicsDialog(None, (1920, 1080), tab)
    qtbot.addWidget(dlg)
    assert dlg.shutter_combo.currentText().startswith("not given")
    assert not dlg.readout_spin.isEnabled()
    assert dlg.intrinsics().readout_ms is None  # estimated from the picks by the calibration
    panel = tab.setup
    dlg.shutter_combo.setCurrentIndex(dlg.shutter_combo.findData("global"))
    assert not dlg.readout_spin.isEnabled()
    glob = dlg.intrinsics()
    assert glob.readout_ms == 0.0 and glob.line_time_s == 0.0
    panel.set_intrinsics(glob)
    assert "global shutter" in panel.intrinsics_label.text()
    back = IntrinsicsDialog(glob, None, tab)
    qtbot.addWidget(back)
    assert back.shutter() == "global" and back.intrinsics().readout_ms == 0.0
    dlg.shutter_combo.setCurrentIndex(dlg.shutter_combo.findData("rolling"))
    assert dlg.readout_spin.isEnabled()
    dlg.readout_spin.setValue(27.5)
    intr = dlg.intrinsics()
    assert intr.readout_ms == 27.5 and intr.line_time_s == pytest.approx(0.0275 / 1079)
    panel.set_intrinsics(intr)
    assert "rolling shutter 27.5 ms" in panel.intrinsics_label.text()
    again = IntrinsicsDialog(intr, None, tab)
    qtbot.addWidget(again)
    assert again.shutter() == "rolling"
    assert again.readout_spin.value() == 27.5
