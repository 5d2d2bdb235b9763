"""The viewer tab driven through its widgets (pytest-qt, offscreen) on block A of the simulated
`blocks` scan: a ruler placed with mouse clicks across the widest slot (6.35 mm wide and deep),
its length and the step height between two reference bands within 0.1 mm of the truth; the
profile measured on the full-resolution map whatever the zoom; the exported profile CSV equal
to the core's profile; layers, cursor readout and levelling; measurements kept in the project
through save and reopen; exports, the report and the 3D view."""

from __future__ import annotations

import json
import math
import re

import cv2
import numpy as np
import pytest
import tifffile
from measure_scans import blocks_recon, blocks_scan, guard_pyside_none, rail_y, truth
from PySide6.QtCore import QPoint, QRectF, Qt
from PySide6.QtTest import QTest

from impress_gui.core.measure import readings as M
from impress_gui.core.project.project import Project
from impress_gui.ui import pyside_fix
from impress_gui.ui.messages import Messenger
from impress_gui.ui.viewer.tab import ViewerTab

pyside_fix.guard()
guard_pyside_none()
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]
STEP = 6.35


class FakeDialogs:
    def __init__(self) -> None:
        self.answer = ""

    def open_file(self, title, filters, start=""):
        return self.answer

    save_file = open_file

    def directory(self, title, start=""):
        return self.answer


@pytest.fixture(scope="module")
def scan(request, tmp_path_factory):
    return blocks_scan(request.config, tmp_path_factory)


@pytest.fixture(scope="module")
def recon(request, tmp_path_factory):
    return blocks_recon(request.config, tmp_path_factory)


@pytest.fixture(scope="module")
def slot(scan):
    """The widest slot of block A: its walls (x, mm) and the rail y of the block's centre."""
    f = next(f for f in truth(scan)["features"] if f["kind"] == "slot")
    left = f["centre_a_mm"] - f["width_mm"] / 2
    return {
        "left": left,
        "right": left + f["width_mm"],
        "width": f["width_mm"],
        "depth": f["depth_mm"],
        "y": rail_y(scan, 190.0),
    }


def make_viewer(qtbot, project: Project | None = None) -> ViewerTab:
    v = ViewerTab(Messenger(None), FakeDialogs())
    qtbot.addWidget(v)
    v.resize(1500, 950)
    v.show()
    qtbot.waitExposed(v)
    if project is not None:
        with qtbot.waitSignal(v.loaded, timeout=30000):
            v.set_project(project)
    return v


@pytest.fixture
def viewer(qtbot, recon):
    v = make_viewer(qtbot)
    with qtbot.waitSignal(v.loaded, timeout=30000):
        v.open_reconstruction(recon)
    yield v
    v.shutdown()
    v.messenger.close_all()


def wait_idle(qtbot, v: ViewerTab) -> None:
    qtbot.waitUntil(lambda: not v.is_busy(), timeout=30000)


def click_map(v: ViewerTab, x_mm: float, y_mm: float) -> None:
    pt = v.map.map_to_viewport(x_mm, y_mm)
    QTest.mouseClick(
        v.map.viewport(), Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, pt
    )


def zoom_to(qtbot, v: ViewerTab, x0: float, x1: float, y0: float, y1: float) -> None:
    v.map.vb.setRange(QRectF(x0, y0, x1 - x0, y1 - y0), padding=0)
    qtbot.waitUntil(lambda: v.map.vb.viewRect().contains(QRectF(x0, y0, x1 - x0, y1 - y0)))


def test_ruler_across_the_slot_reads_its_width_and_depth(qtbot, viewer, slot):
    v, y = viewer, slot["y"]
    zoom_to(qtbot, v, slot["left"] - 8, slot["right"] + 8, y - 6, y + 6)
    QTest.mouseClick(v.tools.mode_buttons["ruler"], Qt.MouseButton.LeftButton)
    assert v.mode == "ruler" and v.map.vb.placing
    click_map(v, slot["left"], y)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        click_map(v, slot["right"], y)
    r = v.ruler_result()
    assert r.xy_mm == pytest.approx(slot["width"], abs=0.1)  # clicked on the true walls
    assert f"xy {r.xy_mm:.3f} mm" in v.tools.ruler_text.text()
    assert v.map.ruler_label.isVisible() and "xy" in v.map.ruler_label.toPlainText()

    # the depth: a longer ruler from the block's top across the slot, 10 mm wide average
    v.tools.width.setValue(10.0)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        v.set_ruler((slot["left"] - 5.0, y), (slot["right"] + 5.0, y))
    a, b = (1.0, 4.5), (5.6, 5.0 + slot["width"] - 0.6)  # top beside the slot; its floor
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        v.set_bands(a, b)
    s = v.step
    assert -s.difference_mm == pytest.approx(slot["depth"], abs=0.1)
    assert s.a.sd_mm < 0.1 and s.b.sd_mm < 0.1
    assert f"{s.difference_mm:+.3f} mm (SD {s.sd_mm:.3f})" in v.tools.step_text.text()
    assert v.profile_plot.labels["A"].isVisible() and v.map.band_lines["B"].xData is not None
    # the left wall's foot is in view: the profile's edge lies where the ruler says (0.2 mm:
    # the 10 mm wide average spans the reconstructed wall's wobble along y; see test_measure
    # for the wall on a narrow profile)
    edges = M.level_crossings(v.profile, s.a.mean_mm + s.difference_mm / 2)
    assert np.abs(edges - 5.0).min() < 0.2
    m = v.add_ruler_measurement("slot 1")
    assert m["values"]["step_mm"] == pytest.approx(s.difference_mm, abs=1e-4)
    assert m["params"]["bands_mm"]["A"] == list(a) or tuple(m["params"]["bands_mm"]["A"]) == a


def test_profile_uses_full_resolution_data_at_any_zoom(qtbot, viewer, slot):
    v, y = viewer, slot["y"]
    p0, p1 = (slot["left"] - 30.0, y + 3.0), (slot["right"] + 40.0, y - 2.0)
    v.tools.width.setValue(2.0)
    for rect in (v.map.full_rect(), QRectF(p0[0], y - 5, 20, 10)):
        v.map.vb.setRange(rect, padding=0)
        with qtbot.waitSignal(v.profile_changed, timeout=10000):
            v.set_ruler(p0, p1)
        core = M.line_profile(v.data.height_mm, v.data.spec, p0, p1, 2.0)
        np.testing.assert_array_equal(v.profile.height_mm, core.height_mm)
    assert v.map.scalar.shown[0] == 0  # zoomed in: the finest level is displayed
    v.map.fit()
    assert v.map.scalar.shown[0] > 0  # zoomed out: a coarser level is displayed ...
    shown = v.map.scalar_item.image
    assert shown.size < v.data.height_mm.size / 4  # ... and not the full map


def test_exported_profile_csv_matches_the_core_profile(qtbot, viewer, slot, tmp_path):
    v, y = viewer, slot["y"]
    p0, p1 = (slot["left"] - 5.0, y - 1.0), (slot["right"] + 12.0, y + 1.5)
    v.tools.width.setValue(1.5)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        v.set_ruler(p0, p1)
    with qtbot.waitSignal(v.tasks.done, timeout=10000):
        assert v.actions.export_profile_csv(tmp_path / "profile.csv")
    d, h = M.read_profile_csv((tmp_path / "profile.csv").read_text())
    core = M.line_profile(v.data.height_mm, v.data.spec, p0, p1, 1.5)
    np.testing.assert_allclose(d, core.distance_mm, atol=1e-4)
    np.testing.assert_allclose(h, core.height_mm, atol=1e-4)  # NaN where no data, in both
    assert np.isnan(h).sum() == np.isnan(core.height_mm).sum()
    v.dialogs.answer = str(tmp_path / "profile.png")
    with qtbot.waitSignal(v.tasks.done, timeout=10000):
        QTest.mouseClick(v.exports.buttons["profile_png"], Qt.MouseButton.LeftButton)
    img = cv2.imread(str(tmp_path / "profile.png"))
    assert img is not None and img.shape[0] > 100
    assert v.project.outputs[-1]["kind"] == "profile-png"


def test_layers_readout_and_levelling(qtbot, viewer, slot):
    v, y = viewer, slot["y"]
    for key in ("green", "red", "difference", "contribution", "texture", "hillshade", "fused"):
        with qtbot.waitSignal(
            v.layer_shown, timeout=20000, check_params_cb=lambda k, key=key: k == key
        ):
            v.display.set_layer(key)
        assert v.map.colour_bar.isVisible() == (key in ("fused", "green", "red", "difference"))
    v.tools.radius.setValue(2.0)
    zoom_to(qtbot, v, -60, 60, y - 40, y + 40)
    # hovering: the readout is the core's at the position under the cursor
    QTest.mouseMove(v.map.viewport(), v.map.map_to_viewport(28.5, y + 10.0))
    text = v.tools.readout.text()
    got = re.match(r"x (-?[\d.]+) mm, y (-?[\d.]+) mm: height (-?[\d.]+) mm", text)
    assert got, text
    x_mm, y_mm, z_mm = (float(g) for g in got.groups())
    assert abs(x_mm - 28.5) < 10 and abs(y_mm - y - 10.0) < 10
    core = M.readout(v.data.height_mm, v.data.spec, x_mm, y_mm, 2.0)  # (x, y rounded)
    assert z_mm == pytest.approx(core.height_mm, abs=0.02)
    hole = (
        np.argwhere(~np.isfinite(v.data.height_mm[::50, ::50]))[
            len(np.argwhere(~np.isfinite(v.data.height_mm[::50, ::50]))) // 2
        ]
        * 50
    )
    hx = v.data.spec.x0_mm + hole[1] * 0.1
    hy = v.data.spec.y0_mm + hole[0] * 0.1
    v.tools.radius.setValue(0.0)
    v.show_readout(hx, hy)
    assert "no data" in v.tools.readout.text()
    # level on three points of the plate around the block (a triangle around the reading, as
    # an examiner would pick them): the top is 20 mm above it. (Three points on one side of
    # the block, 5 mm apart across the scan, extrapolated 40 mm to the reading, multiplied
    # the readouts' 0.02-0.1 mm errors by about 9: 19.66-19.83 mm against 19.96-19.97 here.)
    v.tools.radius.setValue(2.0)
    QTest.mouseClick(v.tools.mode_buttons["level3"], Qt.MouseButton.LeftButton)
    picks = ((-55.0, y - 35.0), (55.0, y - 35.0), (55.0, y + 35.0))
    for x, yy in picks:
        if (x, yy) == picks[-1]:
            with qtbot.waitSignal(v.levelled_changed, timeout=20000):
                click_map(v, x, yy)
        else:
            click_map(v, x, yy)
    assert v.plane is not None and v.plane.tilt_deg < 1.0
    # (three 2 mm readouts carry the reconstruction's errors: 0.15 mm; see test_measure)
    assert v.readout_at(28.5, y + 10.0).height_mm == pytest.approx(20.0, abs=0.15)
    assert "Levelled (three points)" in v.tools.level_text.text()
    # a region fit, then levelling off again
    with qtbot.waitSignal(v.levelled_changed, timeout=20000):
        assert v.level_region((-75.0, 75.0), (y - 55.0, y - 25.0))
    assert v.plane.n > 100_000 and v.map.region is not None
    assert v.readout_at(28.5, y + 10.0).height_mm == pytest.approx(20.0, abs=0.25)
    with qtbot.waitSignal(v.levelled_changed, timeout=20000):
        QTest.mouseClick(v.tools.clear_level_button, Qt.MouseButton.LeftButton)
    assert v.plane is None and v.readout_at(28.5, y + 10.0).height_mm > 31.0


def test_measurements_survive_save_and_reopen(qtbot, recon, slot, tmp_path):
    project = Project(case_id="C-42", evidence_id="E-7")
    project.add_output(recon / "metadata.json", "reconstruction")
    project.save(tmp_path / "case")
    v = make_viewer(qtbot, project)
    try:
        y = slot["y"]
        with qtbot.waitSignal(v.profile_changed, timeout=10000):
            v.set_ruler((slot["left"] - 5.0, y), (slot["right"] + 5.0, y))
        ruler = v.add_ruler_measurement("slot 1 depth")
        zoom_to(qtbot, v, -40, 40, y - 20, y + 20)
        QTest.mouseClick(v.tools.mode_buttons["marker"], Qt.MouseButton.LeftButton)
        click_map(v, 10.0, y + 5.0)
        click_map(v, -10.0, y - 5.0)
        assert [m["kind"] for m in project.measurements] == ["ruler", "annotation", "annotation"]
        assert v.table.table.rowCount() == 3 and len(v.map.saved_items) > 0
        # edit a label in the list, delete the second marker
        v.table.table.item(1, 2).setText("heel nick")
        v.table.table.item(1, 4).setText("checked twice")
        v.table.table.selectRow(2)
        QTest.mouseClick(v.table.delete_button, Qt.MouseButton.LeftButton)
        assert [m["label"] for m in project.measurements] == ["slot 1 depth", "heel nick"]
        assert project.dirty
        v.dialogs.answer = str(tmp_path / "measurements.csv")
        with qtbot.waitSignal(v.tasks.done, timeout=10000):
            QTest.mouseClick(v.table.export_button, Qt.MouseButton.LeftButton)
        rows = [  # after the provenance lines (tests/test_export_provenance.py)
            r
            for r in (tmp_path / "measurements.csv").read_text().splitlines()
            if not r.startswith("#")
        ]
        assert len(rows) == 3 and "heel nick" in rows[2] and "checked twice" in rows[2]
        project.save()
        saved = [dict(m) for m in project.measurements]
    finally:
        v.shutdown()
    reopened = Project.load(tmp_path / "case")
    assert reopened.measurements == saved
    log = [
        json.loads(line)["action"]
        for line in (tmp_path / "case" / "log.jsonl").read_text().splitlines()
    ]
    assert log.count("measurement added") == 3 and "measurement edited" in log
    assert "measurement deleted" in log
    v2 = make_viewer(qtbot, reopened)
    try:
        assert v2.table.table.rowCount() == 2
        assert v2.table.table.item(1, 2).text() == "heel nick"
        assert v2.table.table.item(0, 3).text().startswith(f"xy {ruler['values']['xy_mm']:.3f}")
        v2.table.table.selectRow(0)
        with qtbot.waitSignal(v2.profile_changed, timeout=10000):
            QTest.mouseClick(v2.table.show_button, Qt.MouseButton.LeftButton)
        (a0, a1), (b0, b1) = v2.ruler_points()
        assert (a0, a1) == pytest.approx(tuple(ruler["points_mm"][0]), abs=1e-3)
        assert v2.ruler_result().xy_mm == pytest.approx(ruler["values"]["xy_mm"], abs=1e-3)
    finally:
        v2.shutdown()


def test_exports_report_and_3d_view(qtbot, viewer, slot, tmp_path):
    v, y = viewer, slot["y"]
    v.project.case_id = "C-99"
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        v.set_ruler((slot["left"] - 5.0, y), (slot["right"] + 5.0, y))
    v.add_ruler_measurement("slot")
    for name, action in (
        ("h.tif", v.actions.export_tiff),
        ("h.x3p", v.actions.export_x3p),
        ("p.ply", v.actions.export_ply),
        ("fig.png", v.actions.export_png),
        ("report.html", v.actions.export_report),
    ):
        with qtbot.waitSignal(
            v.tasks.done, timeout=60000, check_params_cb=lambda _w, outcome: outcome == "finished"
        ):
            assert action(tmp_path / name)
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "h.tif"), v.data.height_mm)
    assert (tmp_path / "h.x3p").read_bytes()[:2] == b"PK"
    assert (tmp_path / "p.ply").read_bytes().startswith(b"ply\n")
    fig = cv2.imread(str(tmp_path / "fig.png"))
    assert fig is not None and fig.shape[1] > 1000
    html = (tmp_path / "report.html").read_text()
    for text in (
        "C-99",
        "slot",
        "sha256",
        "Calibration",
        "data:image/png;base64",
        v.data.metadata["files"]["heightmap.tif"],
    ):
        assert text in html
    kinds = [o["kind"] for o in v.project.outputs]
    assert kinds[-5:] == ["heightmap-tiff", "x3p", "ply", "figure-png", "report-html"]
    win = v.actions.open_3d()
    with qtbot.waitSignal(win.rendered, timeout=20000):
        pass
    assert "Software rendering" in win.message.text() and win.view.pixmap() is not None
    frames = win.frames
    with qtbot.waitSignal(win.rendered, timeout=20000):
        start = win.view.rect().center()
        QTest.mousePress(win.view, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, start)
        ev_pos = start + QPoint(40, 10)
        QTest.mouseMove(win.view, ev_pos)
        QTest.mouseRelease(
            win.view, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, ev_pos
        )
    assert win.frames > frames and not math.isclose(win.azimuth, 200.0)


def test_the_case_report_as_pdf(qtbot, viewer, slot, tmp_path):
    """The case report as a PDF (issue 21, item 12), read back with pypdf (not ours): real text
    with the case, the measurement and the heightmap's SHA-256, the figures embedded, the
    parameters as readable rows (no Python dict), recorded as an output."""
    import pypdf

    v, y = viewer, slot["y"]
    v.project.case_id = "C-PDF-7"
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        v.set_ruler((slot["left"] - 5.0, y), (slot["right"] + 5.0, y))
    v.add_ruler_measurement("slot width")
    with qtbot.waitSignal(
        v.tasks.done, timeout=60000, check_params_cb=lambda _w, outcome: outcome == "finished"
    ):
        assert v.actions.export_report_pdf(tmp_path / "report")
    path = tmp_path / "report.pdf"
    reader = pypdf.PdfReader(path)
    # the words as laid out (table cells wrap; the extracted text has spaces where lines broke)
    text = "".join("".join(page.extract_text() for page in reader.pages).split())
    assert "C-PDF-7" in text and "slotwidth" in text
    assert v.data.metadata["files"]["heightmap.tif"][:16] in text
    assert "{'" not in text
    assert sum(len(page.images) for page in reader.pages) >= 2  # the map and the profile
    assert reader.metadata.title == "IMPREsS report C-PDF-7"
    assert v.project.outputs[-1]["kind"] == "report-pdf"
