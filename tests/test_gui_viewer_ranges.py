"""The viewer's colour range and the profile's reference bands, driven through the real widgets
(pytest-qt, offscreen) on small synthetic maps (issue 21 items 2 and 10):

- a range typed in the spin boxes stays on the map when the view is zoomed (a new crop of the
  map is uploaded) and when the map is levelled, until Auto;
- the automatic range is the 1..99 percentiles of the evidence area: the calibration target
  is left out when the reconstruction's calibration says where it is, and a small target is
  outside the percentiles anyway;
- the profile's reference bands give no step until the user has placed both.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pyqtgraph as pg
import pytest
from PySide6.QtCore import QEvent, QPoint, QPointF, Qt
from PySide6.QtGui import QImage, QMouseEvent, QWheelEvent
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QApplication
from recon_data import recon_data_from_arrays

from impress_gui.core.measure import readings as M
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.ui import pyside_fix
from impress_gui.ui.messages import Messenger
from impress_gui.ui.viewer.tab import ViewerTab

pyside_fix.guard()
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]


def make_viewer(qtbot, data: M.ReconData) -> ViewerTab:
    v = ViewerTab(Messenger(None))
    qtbot.addWidget(v)
    v.resize(1500, 950)
    v.show()
    qtbot.waitExposed(v)
    with qtbot.waitSignal(v.loaded, timeout=20000):
        v.set_data(data)
    wait_idle(qtbot, v)
    return v


def wait_idle(qtbot, v: ViewerTab) -> None:
    qtbot.waitUntil(lambda: not v.is_busy(), timeout=20000)


def close(v: ViewerTab) -> None:
    v.shutdown()
    v.messenger.close_all()


def type_value(spin, text: str) -> None:
    spin.setFocus()
    spin.selectAll()
    QTest.keyClicks(spin, text)
    QTest.keyClick(spin, Qt.Key.Key_Return)


def wheel(widget, notches: int = 1) -> None:
    """Mouse-wheel notches (positive: away from the user, zoom in) at the widget's centre."""
    pos = QPointF(widget.rect().center())
    ev = QWheelEvent(pos, QPointF(widget.mapToGlobal(pos.toPoint())), QPoint(0, 0),
                     QPoint(0, 120 * notches), Qt.MouseButton.NoButton,
                     Qt.KeyboardModifier.NoModifier, Qt.ScrollPhase.NoScrollPhase, False)
    QApplication.sendEvent(widget, ev)


def grab(widget) -> np.ndarray:
    img = widget.grab().toImage().convertToFormat(QImage.Format.Format_RGB888)
    h, w, bpl = img.height(), img.width(), img.bytesPerLine()
    buf = np.frombuffer(img.constBits(), np.uint8, count=bpl * h).reshape(h, bpl)
    return buf[:, : w * 3].reshape(h, w, 3).copy()


def colour_of(h: float, lo: float, hi: float, cmap: str) -> np.ndarray:
    lut = pg.colormap.get(cmap).getLookupTable(nPts=256, alpha=False).astype(float)
    return lut[int(np.clip(np.floor((h - lo) / (hi - lo) * 256), 0, 255))]


# ----- a typed range ----------------------------------------------------------------------------
@pytest.fixture
def tilted(qtbot):
    """A 240 x 160 mm map (0.1 mm cells, so the display uses a coarser pyramid level until
    zoomed in), a plane tilted by 0.02 mm/mm in x with a 3 mm deep rectangular hollow."""
    spec = GridSpec(0.0, 0.0, 0.1, (2400, 1600))
    x = spec.xs()[None, :].astype(np.float32)
    h = np.repeat(0.02 * x, spec.shape[0], axis=0)
    h[900:1500, 500:1100] -= 3.0
    v = make_viewer(qtbot, recon_data_from_arrays(spec, h))
    yield v
    close(v)


def test_a_typed_range_stays_through_zoom_and_levelling_until_auto(qtbot, tilted):
    v = tilted
    auto = v.map.levels()
    assert auto != (-9.0, 1.0)
    type_value(v.display.lo, "-9")
    type_value(v.display.hi, "1")
    assert v.map.levels() == (-9.0, 1.0)
    assert tuple(float(x) for x in v.map.scalar_item.getLevels()) == (-9.0, 1.0)
    # the user scrolls: a new crop of the map (a finer pyramid level) is shown
    crops, level = v.map.scalar.crops, v.map.scalar.shown[0]
    for _ in range(6):
        wheel(v.map.viewport(), 1)
        if v.map.scalar.shown[0] != level:
            break
    assert v.map.scalar.crops > crops and v.map.scalar.shown[0] < level
    wait_idle(qtbot, v)
    assert tuple(float(x) for x in v.map.scalar_item.getLevels()) == (-9.0, 1.0)
    assert v.map.levels() == (-9.0, 1.0)
    assert (v.display.lo.value(), v.display.hi.value()) == (-9.0, 1.0)
    # and on screen: the cell under the centre has the colour of its height in -9..1
    centre = v.map.viewport().rect().center()
    p = v.map.vb.mapSceneToView(v.map.mapToScene(centre))
    s = v.data.spec
    i, j = round((p.y() - s.y0_mm) / s.pixel_mm), round((p.x() - s.x0_mm) / s.pixel_mm)
    want = colour_of(float(v.data.height_mm[i, j]), -9.0, 1.0, v.display.cmap.currentText())
    got = grab(v.map.viewport())[centre.y(), centre.x()].astype(float)
    assert np.abs(got - want).max() <= 6, (got, want)
    # levelling (a region on the plane) keeps the typed range
    with qtbot.waitSignal(v.levelled_changed, timeout=20000):
        assert v.level_region((10.0, 40.0), (10.0, 40.0))
    wait_idle(qtbot, v)
    assert v.plane is not None and abs(v.plane.a - 0.02) < 1e-3
    assert v.map.levels() == (-9.0, 1.0)
    assert tuple(float(x) for x in v.map.scalar_item.getLevels()) == (-9.0, 1.0)
    assert (v.display.lo.value(), v.display.hi.value()) == (-9.0, 1.0)
    # Auto gives the automatic range of the levelled map back: the plane at 0, the hollow -3
    with qtbot.waitSignal(v.layer_shown, timeout=20000):
        QTest.mouseClick(v.display.auto_button, Qt.MouseButton.LeftButton)
    lo, hi = v.map.levels()
    assert lo == pytest.approx(-3.0, abs=0.05) and hi == pytest.approx(0.0, abs=0.05)
    assert (v.display.lo.value(), v.display.hi.value()) == (lo, hi)


# ----- the automatic range ----------------------------------------------------------------------
TARGET_MM = 40.0


def scene_with_target(target_cells: tuple[slice, slice]) -> tuple[GridSpec, np.ndarray]:
    """Ground at 0 mm (+- 0.02), a hollow 0 .. -4 mm deep over a third of the map, and the
    40 mm calibration target over ``target_cells``."""
    spec = GridSpec(-50.0, -20.0, 0.1, (1000, 800))
    rng = np.random.default_rng(3)
    h = rng.normal(0.0, 0.01, spec.shape).astype(np.float32)
    rows = np.arange(spec.shape[0])[:, None]
    h[:, 400:700] -= np.clip((rows - 100) / 200.0, 0.0, 4.0)[:, :1].astype(np.float32)
    h[target_cells] = TARGET_MM
    return spec, h


def test_the_automatic_range_leaves_out_the_calibration_target(qtbot, tmp_path):
    # the target over 12 % of the map: no percentile would keep it out
    spec, h = scene_with_target((slice(50, 450), slice(20, 260)))
    xs, ys = spec.xs(), spec.ys()
    # the calibration the reconstruction was made with: the target's corners in the rail frame
    x0, x1, y0, y1 = xs[20], xs[259], ys[50], ys[449]
    corners = {"A": [x0, y0, 10], "B": [x0, y1, 10], "C": [(x0 + x1) / 2, y1, 40],
               "D": [x1, y1, 40], "E": [x1, y0, 40], "F": [(x0 + x1) / 2, y0, 40]}
    cal = tmp_path / "scan.calibration.json"
    cal.write_text(json.dumps({"format": "impress.calibration", "corners_parallax_mm": corners}))
    meta = {"inputs": {"calibration": {"path": str(cal),
                                       "sha256": hashlib.sha256(cal.read_bytes()).hexdigest()}}}
    v = make_viewer(qtbot, recon_data_from_arrays(spec, h, metadata=meta))
    try:
        lo, hi = v.map.levels()
        assert lo == pytest.approx(-4.0, abs=0.1) and hi == pytest.approx(0.0, abs=0.1)
        assert (v.display.lo.value(), v.display.hi.value()) == (lo, hi)
    finally:
        close(v)
    # a calibration file that is not the one recorded (another SHA-256) is not trusted: the
    # percentiles alone then see the big target
    cal.write_text(json.dumps({"corners_parallax_mm": {k: [0, 0, 0] for k in corners}}))
    v = make_viewer(qtbot, recon_data_from_arrays(spec, h, metadata=meta))
    try:
        assert v.map.levels()[1] == pytest.approx(TARGET_MM, abs=0.1)
    finally:
        close(v)


def test_the_automatic_range_is_robust_to_a_small_target(qtbot):
    # the target over 0.8 % of the map and its place unknown: the 1..99 percentiles leave it out
    spec, h = scene_with_target((slice(10, 90), slice(10, 90)))
    assert 0.005 < (h == TARGET_MM).mean() < 0.01
    v = make_viewer(qtbot, recon_data_from_arrays(spec, h))
    try:
        lo, hi = v.map.levels()
        assert lo == pytest.approx(-4.0, abs=0.1) and hi < 0.1
    finally:
        close(v)


# ----- the profile's bands ----------------------------------------------------------------------
def drag(widget, start: QPoint, end: QPoint, steps: int = 6) -> None:
    """Press, move with the button held, release (pyqtgraph's mouse-rate limit lifted)."""
    rate = pg.getConfigOption("mouseRateLimit")
    pg.setConfigOption("mouseRateLimit", -1)
    left, none = Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier

    def send(kind, pos, button, buttons):
        ev = QMouseEvent(kind, QPointF(pos), QPointF(widget.mapToGlobal(pos)), button, buttons,
                         none)
        QApplication.sendEvent(widget, ev)

    try:
        send(QEvent.Type.MouseButtonPress, start, left, left)
        for f in np.linspace(0, 1, steps + 1)[1:]:
            pos = start + QPoint(round(f * (end.x() - start.x())),
                                 round(f * (end.y() - start.y())))
            send(QEvent.Type.MouseMove, pos, Qt.MouseButton.NoButton, left)
        send(QEvent.Type.MouseButtonRelease, end, left, Qt.MouseButton.NoButton)
    finally:
        pg.setConfigOption("mouseRateLimit", rate)


def profile_point(v: ViewerTab, d_mm: float, z_mm: float) -> QPoint:
    pp = v.profile_plot
    return pp.mapFromScene(pp.getPlotItem().vb.mapViewToScene(QPointF(d_mm, z_mm)))


def test_no_step_is_shown_until_both_bands_are_placed(qtbot):
    """A 2 mm step along x: the ruler across it; the default bands print nothing; the user
    drags A onto the low side (still nothing), then B onto the high side: the step."""
    spec = GridSpec(0.0, 0.0, 0.1, (300, 400))
    h = np.zeros(spec.shape, np.float32)
    h[:, 200:] = 2.0
    v = make_viewer(qtbot, recon_data_from_arrays(spec, h))
    try:
        v.set_mode("ruler")
        # the first click starts the ruler (no profile, nothing to wait for: waiting for one
        # took the signal's whole 10 s timeout), the second ends it and brings the profile
        QTest.mouseClick(v.map.viewport(), Qt.MouseButton.LeftButton,
                         Qt.KeyboardModifier.NoModifier, v.map.map_to_viewport(5.0, 15.0))
        with qtbot.waitSignal(v.profile_changed, timeout=10000):
            QTest.mouseClick(v.map.viewport(), Qt.MouseButton.LeftButton,
                             Qt.KeyboardModifier.NoModifier, v.map.map_to_viewport(35.0, 15.0))
        assert v.profile is not None and v.profile.length_mm == pytest.approx(30.0, abs=0.1)
        pp = v.profile_plot

        def nothing_shown() -> None:
            assert v.step is None
            assert "Step B - A" not in v.tools.step_text.text()
            assert "±" not in v.tools.step_text.text()
            assert "bold" not in v.tools.step_text.styleSheet()
            assert not pp.labels["A"].isVisible() and not pp.labels["B"].isVisible()
            assert not pp.means["A"].isVisible() and not pp.means["B"].isVisible()

        nothing_shown()
        # the bands are offered (faint, "drag A", "drag B") but not drawn on the map
        assert pp.regions["A"].isVisible() and pp.hints["A"].isVisible()
        assert "drag band A and B" in v.tools.step_text.text()
        assert all(len(v.map.band_lines[k].getData()[0]) == 0 for k in ("A", "B"))
        # (the plot shows the whole profile once it has been laid out and painted)
        vb = pp.getPlotItem().vb
        qtbot.waitUntil(lambda: vb.viewRange()[0][1] > 29.0 and vb.viewRange()[1][1] > 1.9)
        # A: from its default place (3 .. 9 mm) onto the low side, 6 .. 12 mm
        a0, a1 = pp.regions["A"].getRegion()
        with qtbot.waitSignal(v.profile_changed, timeout=10000):
            drag(pp.viewport(), profile_point(v, (a0 + a1) / 2, 1.0),
                 profile_point(v, (a0 + a1) / 2 + 3.0, 1.0))
        assert "A" in pp.placed and not pp.hints["A"].isVisible()
        nothing_shown()
        assert "drag band B" in v.tools.step_text.text()
        # B: from 13.5 .. 16.5 mm onto the high side, 20 .. 26 mm (drag, then its edges)
        b0, b1 = pp.regions["B"].getRegion()
        with qtbot.waitSignal(v.profile_changed, timeout=10000):
            drag(pp.viewport(), profile_point(v, (b0 + b1) / 2, 1.0),
                 profile_point(v, 23.0, 1.0))
        assert v.step is not None and pp.bands_placed()
        s = v.step
        assert s.a.end_mm < 14.5 and s.b.start_mm > 15.5  # each band on its own side
        assert s.difference_mm == pytest.approx(2.0, abs=0.01)
        assert f"Step B - A: {s.difference_mm:+.3f}" in v.tools.step_text.text()
        assert pp.labels["A"].isVisible() and pp.labels["B"].isVisible()
        assert len(v.map.band_lines["B"].getData()[0]) == 2
        # a new ruler offers the bands again: nothing until they are placed
        with qtbot.waitSignal(v.profile_changed, timeout=10000):
            v.set_ruler((5.0, 5.0), (25.0, 25.0))
        nothing_shown()
    finally:
        close(v)
