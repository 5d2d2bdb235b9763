"""The heightmap and the texture side by side with linked pan, zoom and cursor (issue 21,
item 13), driven through the real widgets (pytest-qt, offscreen) on a small synthetic map:
the button shows the texture in a second view; a wheel zoom in either view and a pan of the
map give both views the same range; the cursor over either draws the crosshair at the same
place in both and the readout gives the height under it."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6.QtCore import QPoint, QPointF, QRectF, Qt
from PySide6.QtGui import QWheelEvent
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QApplication
from recon_data import recon_data_from_arrays

from impress_gui.core.measure import readings as M
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.ui import pyside_fix
from impress_gui.ui.app import build_main_window, make_settings
from impress_gui.ui.messages import Messenger
from impress_gui.ui.viewer.tab import ViewerTab

pyside_fix.guard()
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]


def scene():
    """60 x 40 mm, 0.1 mm cells: heights rising 0.05 mm/mm in x; a texture with a white
    square on dark grey."""
    spec = GridSpec(0.0, 0.0, 0.1, (400, 600))
    x = spec.xs()[None, :].astype(np.float32)
    h = np.repeat(0.05 * x, spec.shape[0], axis=0)
    tex = np.full((*spec.shape, 3), 60, np.uint8)
    tex[100:200, 100:300] = 255
    return recon_data_from_arrays(spec, h, texture_rgb=tex)


@pytest.fixture
def viewer(qtbot):
    v = ViewerTab(Messenger(None))
    qtbot.addWidget(v)
    v.resize(1600, 950)
    v.show()
    qtbot.waitExposed(v)
    with qtbot.waitSignal(v.loaded, timeout=20000):
        v.set_data(scene())
    qtbot.waitUntil(lambda: not v.is_busy(), timeout=20000)
    yield v
    v.shutdown()
    v.messenger.close_all()


def wheel(widget, notches: int = 1) -> None:
    pos = QPointF(widget.rect().center())
    ev = QWheelEvent(pos, QPointF(widget.mapToGlobal(pos.toPoint())), QPoint(0, 0),
                     QPoint(0, 120 * notches), Qt.MouseButton.NoButton,
                     Qt.KeyboardModifier.NoModifier, Qt.ScrollPhase.NoScrollPhase, False)
    QApplication.sendEvent(widget, ev)


def ranges(view) -> list[float]:
    (x0, x1), (y0, y1) = view.vb.viewRange()
    return [x0, x1, y0, y1]


def test_side_by_side_links_pan_zoom_and_cursor(qtbot, viewer):
    v = viewer
    assert not v.texture_map.isVisible()
    QTest.mouseClick(v.display.side_button, Qt.MouseButton.LeftButton)
    assert v.is_side_by_side() and v.texture_map.isVisible()
    qtbot.waitUntil(lambda: v.texture_map.rgb_item.image is not None, timeout=10000)
    # the two views are as wide as each other, the texture drawn in the second
    qtbot.waitUntil(lambda: v.texture_map.vb.screenGeometry().size()
                    == v.map.vb.screenGeometry().size(), timeout=5000)
    w0 = v.map.vb.screenGeometry().width()
    assert v.map.scalar_item.image is not None  # the heightmap stays in the first

    # zoom with the wheel over the texture: the map follows
    before = ranges(v.map)
    wheel(v.texture_map.viewport(), 2)
    qtbot.waitUntil(lambda: ranges(v.map) != before, timeout=5000)
    assert ranges(v.map)[1] - ranges(v.map)[0] < before[1] - before[0]  # zoomed in
    assert ranges(v.texture_map) == pytest.approx(ranges(v.map), abs=0.05)
    # pan the map: the texture follows
    v.map.vb.setRange(QRectF(20.0, 10.0, 12.0, 8.0), padding=0)
    qtbot.waitUntil(lambda: ranges(v.texture_map) == pytest.approx(ranges(v.map), abs=0.05),
                    timeout=5000)
    # the view's centre is the asked rectangle's (the locked aspect widens one axis, by how
    # much depends on the panels' widths)
    r = ranges(v.map)
    cx, cy = (r[0] + r[1]) / 2, (r[2] + r[3]) / 2
    assert cx == pytest.approx(26.0, abs=0.5) and cy == pytest.approx(14.0, abs=0.5)

    # the cursor over the texture: the crosshair at the same place on the map, the readout
    # the height there
    x, y = 26.0, 14.0
    QTest.mouseMove(v.texture_map.viewport(), v.texture_map.map_to_viewport(x, y))
    qtbot.waitUntil(lambda: v.map.crosshair() is not None, timeout=5000)
    px = (ranges(v.map)[1] - ranges(v.map)[0]) / w0  # mm per screen pixel
    hx, hy = v.map.crosshair()
    assert (hx, hy) == pytest.approx((x, y), abs=2 * px)
    assert v.texture_map.crosshair() == pytest.approx((hx, hy))
    r = M.readout(v.data.layers["fused"], v.data.spec, hx, hy, v.tools.radius.value())
    assert f"height {r.height_mm:.3f} mm" in v.tools.readout.text()
    # and over the map: the texture's crosshair follows
    QTest.mouseMove(v.map.viewport(), v.map.map_to_viewport(22.0, 12.0))
    qtbot.waitUntil(lambda: v.texture_map.crosshair() is not None
                    and abs(v.texture_map.crosshair()[0] - 22.0) < 2 * px, timeout=5000)
    assert v.texture_map.crosshair()[1] == pytest.approx(12.0, abs=2 * px)

    # off again: one view, no crosshair
    QTest.mouseClick(v.display.side_button, Qt.MouseButton.LeftButton)
    assert not v.texture_map.isVisible() and v.map.crosshair() is None


def test_the_view_menu_lists_side_by_side_with_its_key(qtbot, tmp_path):
    w = build_main_window(make_settings(tmp_path / "settings.ini"), with_motor=False)
    try:
        w.show()
        qtbot.waitExposed(w)
        w.activateWindow()  # a window's keys work while it is the active one
        qtbot.waitUntil(lambda: QApplication.activeWindow() is w, timeout=5000)
        menus = {a.text().replace("&", ""): a.menu() for a in w.menuBar().actions()}
        act = next(a for a in menus["View"].actions() if "side by side" in a.text())
        assert act.shortcut().toString() == "S" and act.isCheckable()
        w.tabs.setCurrentWidget(w.calibration_tab)
        QTest.keyClick(w.tabs.currentWidget(), Qt.Key.Key_S)
        qtbot.waitUntil(lambda: w.viewer_tab.is_side_by_side(), timeout=2000)
        assert w.tabs.currentWidget() is w.viewer_tab and act.isChecked()
        QTest.mouseClick(w.viewer_tab.display.side_button, Qt.MouseButton.LeftButton)
        assert not act.isChecked()
    finally:
        w.shutdown()
        w.close()
        w.deleteLater()
