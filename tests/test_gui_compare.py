"""The Compare panel driven through its real widgets with pytest-qt: two reconstruction folders
of the simulator's true shoe relief (0.2 mm grid; B turned, shifted and with the cut), compared,
the threshold changed, the views switched, the folder written, and a bad input's coded error."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PySide6.QtCore import Qt

from impress_gui.sim.scenes import ShoeCut, shoe_relief

pytest.importorskip("open3d")
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_threads")]

POSE = {"rotate_deg": -12.0, "shift_x_mm": -6.0, "shift_y_mm": 5.0}


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    from test_compare import truth_surface, write_recon

    root = tmp_path_factory.mktemp("gui-compare")
    a = write_recon(root / "a", truth_surface(shoe_relief(0.2, 1)), step=1)
    b = write_recon(root / "b", truth_surface(shoe_relief(0.2, 1, POSE, ShoeCut())), step=1)
    return a, b


@pytest.fixture
def panel(qtbot):
    from impress_gui.ui.compare.panel import ComparePanel

    p = ComparePanel()
    qtbot.addWidget(p)
    yield p
    p.shutdown()


def test_compare_panel_compares_outlines_and_writes(panel, folders, qtbot, tmp_path):
    a, b = folders
    qtbot.keyClicks(panel.a_edit, str(a))
    qtbot.keyClicks(panel.b_edit, str(b))
    with qtbot.waitSignals([panel.compared, panel.status], timeout=120_000) as blocker:
        qtbot.mouseClick(panel.compare_button, Qt.MouseButton.LeftButton)
    cmp = panel.comparison
    assert cmp is not None and not panel.is_dirty()
    # B was turned by -12 deg in the rail frame (X towards Y), i.e. +12 deg seen from above in
    # the export frame (y = -rail Y); B -> A turns it back: -12 deg
    assert abs(cmp.registration.rotation_deg() - (-12.0)) < 0.05
    assert "residual RMS" in panel.result_label.text()
    assert panel.image.image is not None and panel.image.image.shape == cmp.diff.shape
    n_before = len(cmp.regions)
    with qtbot.waitSignal(panel.outlined, timeout=30_000) as blocker:
        panel.threshold_spin.setValue(1.5)
    assert blocker.args[0] < n_before
    assert "above 1.5 mm" in panel.result_label.text()
    for k in range(panel.view_combo.count()):
        panel.view_combo.setCurrentIndex(k)
        assert panel.image.image is not None
    # side by side: B on the right, pan and zoom linked, one cursor in both
    assert panel.view_combo.currentText().startswith("A | B")
    assert panel.plot_b.isVisibleTo(panel)
    assert panel.image_b.image.shape == cmp.b_on_a.shape
    panel.view_box.setRange(xRange=(100, 300), yRange=(200, 400), padding=0)
    assert np.allclose(panel.view_box_b.viewRange(), panel.view_box.viewRange())
    panel.set_cursor(150.0, 250.0)
    for c in panel.cursors:
        assert list(c.getData()[0]) == [150.0] and list(c.getData()[1]) == [250.0]
    panel.view_combo.setCurrentIndex(3)  # B over A
    assert panel.overlay.isVisible() and not panel.plot_b.isVisibleTo(panel)
    panel.opacity_slider.setValue(20)
    assert abs(panel.overlay.opacity() - 0.2) < 1e-6
    panel.flicker_check.setChecked(True)
    qtbot.waitUntil(lambda: panel.flicker_ticks >= 2, timeout=5_000)
    assert panel.overlay.opacity() in (0.0, 1.0)
    panel.flicker_check.setChecked(False)
    assert abs(panel.overlay.opacity() - 0.2) < 1e-6
    # a profile across the cut (A's frame is the shoe's own: the cut at (15, -230) along
    # (cos 30, -sin 30)), given by two clicks' worth of points: B (with the ridge) is 0.5 mm
    # above A at the middle, the two agree at the ends
    cx, cy = 15.0, -230.0
    across = np.array([np.sin(np.radians(30.0)), np.cos(np.radians(30.0))])
    c0, r0 = panel.mm_to_view(cx, cy)
    assert np.allclose(panel.view_to_mm(c0, r0), (cx, cy), atol=1e-9)
    panel.add_profile_point(*(np.array([cx, cy]) - 2.0 * across))
    with qtbot.waitSignal(panel.profiled, timeout=5_000) as blocker:
        panel.add_profile_point(*(np.array([cx, cy]) + 2.0 * across))
    prof = blocker.args[0]
    rise = prof.b_mm - prof.a_mm
    mid = np.abs(prof.distance_mm - 2.0) < 0.15
    assert abs(np.nanmax(rise[mid]) - 0.5) < 0.1
    assert np.all(np.abs(rise[prof.distance_mm < 1.0]) < 0.05)
    xs, ys = panel.curve_b.getData()
    assert len(xs) == len(prof.distance_mm)
    # the difference along A's normal by default; vertical chosen: measured again without
    # registering again, the map is A - B itself and its 95th percentile larger (the walls)
    assert cmp.metric == "normal" == panel.difference_metric()
    assert "along A's surface normal" in panel.result_label.text()
    panel.view_combo.setCurrentIndex(0)
    with qtbot.waitSignal(panel.compared, timeout=60_000) as blocker:
        panel.metric_combo.setCurrentIndex(panel.metric_combo.findData("vertical"))
    vert = blocker.args[0]
    assert vert is panel.comparison and vert.metric == "vertical"
    assert vert.registration is cmp.registration and vert.b_on_a is cmp.b_on_a
    ok = np.isfinite(vert.diff)
    assert np.array_equal(vert.diff[ok], (cmp.a.height_mm - cmp.b_on_a)[ok])
    assert vert.stats.p95_abs_mm > cmp.stats.p95_abs_mm
    assert "vertical" in panel.result_label.text()
    assert panel.shown_image() is vert.diff
    flip = cmp.a.y_step_mm > 0
    shown = np.asarray(panel.image.image)
    assert np.array_equal(shown, vert.diff[::-1] if flip else vert.diff, equal_nan=True)
    out = tmp_path / "cmp"
    with qtbot.waitSignal(panel.written, timeout=120_000):
        panel.write_to(out)
    doc = json.loads((out / "compare.json").read_text())
    assert doc["parameters"]["threshold_mm"] == 1.5
    assert doc["parameters"]["metric"] == doc["difference"]["metric"] == "vertical"
    assert np.allclose(doc["registration"]["matrix_b_to_a"], cmp.registration.matrix,
                       atol=1e-6)
    # the report also as PDF, read back by pypdf (not written here): the registration's figures
    from pypdf import PdfReader

    text = " ".join(" ".join(page.extract_text().split())
                    for page in PdfReader(out / "report.pdf").pages)
    assert "IMPREsS comparison report" in text
    assert f"{doc['registration']['residual_rms_mm']:.4f}" in text


def test_compare_panel_reports_a_coded_error(panel, folders, qtbot, tmp_path):
    panel.a_edit.setText(str(folders[0]))
    panel.b_edit.setText(str(tmp_path / "nowhere"))
    with qtbot.waitSignal(panel.failed, timeout=30_000) as blocker:
        panel.compare_button.click()
    assert blocker.args[0] == "E-COMPARE-INPUT"
    assert "[E-COMPARE-INPUT]" in panel.status_label.text()
    assert panel.compare_button.isEnabled()


def test_compare_panel_takes_clicked_point_pairs(panel, folders, qtbot):
    """Pick pairs: A and B shown side by side, three pairs clicked (here: given as the points
    a click lands on), Compare uses them for the coarse step."""
    from impress_gui.sim.scenes import ShoePose

    panel.a_edit.setText(str(folders[0]))
    panel.b_edit.setText(str(folders[1]))
    with qtbot.waitSignal(panel.loaded, timeout=60_000):
        panel.pairs_check.setChecked(True)
    assert panel.plot_b.isVisibleTo(panel) and panel.image_b.image is not None
    for u, v in ((0.0, 180.0), (30.0, 330.0), (-30.0, 380.0)):
        xa, ya = ShoePose.of(None).to_rail(u, v)
        xb, yb = ShoePose.of(POSE).to_rail(u, v)
        panel.add_pair_point("a", float(xa) + 0.4, float(-ya))
        panel.add_pair_point("b", float(xb), float(-yb) - 0.4)
    assert len(panel.pairs) == 3 and "used by Compare" in panel.pairs_label.text()
    assert len(panel.pair_marks[0].getData()[0]) == 3
    # a real click on the left map starts a fourth pair at the cell clicked
    from PySide6.QtCore import QPointF

    panel.resize(900, 900)
    panel.show()
    qtbot.waitExposed(panel)
    panel.view_box.autoRange(padding=0.02)
    col, row = 300.0, 500.0
    scene = panel.view_box.mapViewToScene(QPointF(col + 0.5, row + 0.5))
    qtbot.mouseClick(panel.plot.viewport(), Qt.MouseButton.LeftButton,
                     pos=panel.plot.mapFromScene(scene))
    assert panel._pending.get("a") is not None
    s = panel.surfaces[0]
    x, y = s.xy(row, col)  # A's rows from the top: y_step < 0 for a reconstruction
    assert np.hypot(panel._pending["a"][0] - x, panel._pending["a"][1] - y) < 2 * s.pixel_mm
    assert len(panel.pair_marks[0].getData()[0]) == 4  # the pending click is marked too
    panel._pending.clear()
    with qtbot.waitSignal(panel.compared, timeout=120_000) as blocker:
        panel.compare_button.click()
    reg = blocker.args[0].registration
    assert reg.coarse["method"].startswith("point pairs") and reg.coarse["pairs"] == 3
    assert abs(reg.rotation_deg() - (-12.0)) < 0.05
    assert not panel.pairs_check.isChecked()
    panel.clear_pairs()
    assert panel.pairs == [] and panel.params().registration.pairs is None


def test_a_written_comparison_goes_into_the_case_record(folders, qtbot, tmp_path):
    """With a case open, writing the comparison adds its record to the case's outputs (path,
    SHA-256) and logs which scans were compared (their hashes), the registration and the
    parameters; the saved project's log, read back, says so."""
    import hashlib

    from impress_gui.core.project.log import read_log
    from impress_gui.core.project.project import Project
    from impress_gui.session.session import Session
    from impress_gui.ui.compare.panel import ComparePanel

    project = Project()
    project.save(tmp_path / "case")
    session = Session(project)
    panel = ComparePanel(session=session)
    qtbot.addWidget(panel)
    try:
        panel.a_edit.setText(str(folders[0]))
        panel.b_edit.setText(str(folders[1]))
        with qtbot.waitSignal(panel.compared, timeout=120_000):
            panel.compare_button.click()
        out = tmp_path / "cmp"
        with qtbot.waitSignals([panel.written, panel.changed], timeout=120_000):
            panel.write_to(out)
    finally:
        panel.shutdown()
    record = out / "compare.json"
    entry = [o for o in project.outputs if o["kind"] == "comparison"]
    assert len(entry) == 1 and entry[0]["path"] == str(record.resolve())
    assert entry[0]["sha256"] == hashlib.sha256(record.read_bytes()).hexdigest()
    project.save()
    logged = [e for e in read_log(project.log_file) if e.get("action") == "comparison"]
    assert len(logged) == 1
    details = logged[0]["details"]
    doc = json.loads(record.read_text())
    assert details["inputs"] == doc["inputs"]
    assert details["registration"]["matrix_b_to_a"] == doc["registration"]["matrix_b_to_a"]
    assert details["parameters"]["threshold_mm"] == doc["parameters"]["threshold_mm"]
    assert details["difference"]["metric"] == doc["difference"]["metric"] == "normal"
    assert details["difference"]["p95_abs_mm"] == doc["difference"]["p95_abs_mm"]


def test_the_window_has_the_compare_tab_over_its_session(qtbot, tmp_path, folders):
    """The Compare tab is in the window, built over the window's session (so its comparisons
    go into the open case), and stops with the window."""
    from impress_gui.ui.app import build_main_window, make_settings

    window = build_main_window(make_settings(tmp_path / "settings.ini"), with_motor=False)
    qtbot.addWidget(window)
    try:
        titles = [window.tabs.tabText(i) for i in range(window.tabs.count())]
        assert "Compare" in titles
        tab = window.tabs.widget(titles.index("Compare"))
        assert tab is window.compare_tab and tab.session is window.session
        window.tabs.setCurrentWidget(tab)
        tab.a_edit.setText(str(folders[0]))
        tab.b_edit.setText(str(folders[1]))
        with qtbot.waitSignal(tab.compared, timeout=120_000):
            tab.compare_button.click()
        assert tab.comparison is not None
    finally:
        window.shutdown()
