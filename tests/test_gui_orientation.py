"""What is on screen is the map as stored, not its mirror image (issue 21 item 1).

Maps are shown as the camera sees the ground from above, exactly as ``texture.png`` is stored:
grid row 0 at the top, the row index (y, the rail's direction of motion) increasing downwards,
x to the right. A chiral scene - a raised letter F, which no flip or half turn maps onto itself -
is put into a heightmap and a texture; the test reads back what is drawn (the real widgets'
rendered pixels, and the Figure PNG decoded by OpenCV) and compares it with the array and with
its mirror images and half turn: the array as stored must match, the others must not. Then the
measurements: a marker and a ruler placed where the screen shows the letter read the letter's
cells.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from PySide6.QtCore import QPoint, QPointF, QRectF, Qt
from PySide6.QtGui import QImage
from PySide6.QtTest import QTest
from recon_data import recon_data_from_arrays

from impress_gui.core.formats.figures import png_bytes
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.ui import pyside_fix
from impress_gui.ui.messages import Messenger
from impress_gui.ui.processing.panels import RunPanel
from impress_gui.ui.viewer.tab import ViewerTab
from impress_gui.ui.viewer.view3d import BACKGROUND, Surface3DWindow

pyside_fix.guard()
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]
LETTER_MM = 5.0
SPEC = GridSpec(x0_mm=-30.0, y0_mm=100.0, pixel_mm=0.1, shape=(600, 400))


def letter_f(shape=SPEC.shape) -> np.ndarray:
    """A boolean F: its stem on the left, its bars pointing right, the long bar at the top
    (row 0 side). Mirrored left-right it points left; upside down its long bar is at the
    bottom; a half turn does both."""
    h, w = shape
    m = np.zeros(shape, bool)
    m[int(0.12 * h) : int(0.88 * h), int(0.2 * w) : int(0.36 * w)] = True  # stem
    m[int(0.12 * h) : int(0.24 * h), int(0.2 * w) : int(0.82 * w)] = True  # long top bar
    m[int(0.46 * h) : int(0.56 * h), int(0.2 * w) : int(0.64 * w)] = True  # short middle bar
    return m


def variants(mask: np.ndarray) -> dict[str, np.ndarray]:
    return {
        "as stored": mask,
        "flipped vertically": mask[::-1],
        "flipped horizontally": mask[:, ::-1],
        "turned by 180 degrees": mask[::-1, ::-1],
    }


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def assert_shows_as_stored(seen: np.ndarray, truth: np.ndarray, where: str) -> None:
    """``seen``: the letter's mask read from the picture, resampled to the array's shape."""
    scores = {k: iou(seen, v) for k, v in variants(truth).items()}
    assert scores["as stored"] > 0.85, f"{where}: {scores}"
    for k, s in scores.items():
        if k != "as stored":
            assert s < 0.6, f"{where} shows the letter {k}: {scores}"


def to_array(img: QImage) -> np.ndarray:
    img = img.convertToFormat(QImage.Format.Format_RGB888)
    h, w, bpl = img.height(), img.width(), img.bytesPerLine()
    buf = np.frombuffer(img.constBits(), np.uint8, count=bpl * h).reshape(h, bpl)
    return buf[:, : w * 3].reshape(h, w, 3).copy()


def map_region(rgb: np.ndarray, shape) -> np.ndarray:
    """The part of a screen picture covered by the map (everything not the black background),
    resampled to the grid's shape."""
    lit = rgb.astype(int).sum(axis=2) > 40
    # (rows and columns mostly lit: the axes' tick marks along the edges do not count)
    per_row, per_col = lit.sum(axis=1), lit.sum(axis=0)
    rows = np.flatnonzero(per_row > 0.3 * per_row.max())
    cols = np.flatnonzero(per_col > 0.3 * per_col.max())
    crop = rgb[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    return cv2.resize(crop, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def grab_view_box(v: ViewerTab) -> np.ndarray:
    """The rendered pixels inside the map's view box (no axes, no colour bar)."""
    full = to_array(v.map.viewport().grab().toImage())
    r = v.map.mapFromScene(v.map.vb.sceneBoundingRect()).boundingRect()
    return full[r.top() + 2 : r.bottom() - 1, r.left() + 2 : r.right() - 1]


@pytest.fixture
def scene():
    mask = letter_f()
    height = np.where(mask, LETTER_MM, 0.0).astype(np.float32)
    texture = np.empty((*SPEC.shape, 3), np.uint8)
    texture[:] = (140, 20, 20)
    texture[mask] = (250, 250, 250)
    return mask, height, texture


@pytest.fixture
def viewer(qtbot, scene):
    mask, height, texture = scene
    v = ViewerTab(Messenger(None))
    qtbot.addWidget(v)
    v.resize(1500, 950)
    v.show()
    qtbot.waitExposed(v)
    with qtbot.waitSignal(v.loaded, timeout=20000):
        v.set_data(recon_data_from_arrays(SPEC, height, texture_rgb=texture))
    qtbot.waitUntil(lambda: not v.is_busy(), timeout=20000)
    yield v
    v.shutdown()
    v.messenger.close_all()


def show_layer(qtbot, v: ViewerTab, key: str) -> None:
    with qtbot.waitSignal(v.layer_shown, timeout=20000, check_params_cb=lambda k: k == key):
        v.display.layer.setCurrentIndex(v.display.layer.findData(key))
    qtbot.waitUntil(lambda: not v.is_busy(), timeout=20000)


def test_the_viewer_shows_the_heightmap_and_texture_as_stored(qtbot, viewer, scene):
    v, (mask, _height, _texture) = viewer, scene
    assert v.display.layer_key() == "fused"
    seen = map_region(grab_view_box(v), mask.shape)
    # the letter's cells are at the top of the colour map (turbo: dark red), the ground at the
    # bottom (dark blue-violet)
    letter = (seen[..., 0] > 100) & (seen[..., 2] < 80)
    assert_shows_as_stored(letter, mask, "the viewer's heightmap")
    show_layer(qtbot, v, "texture")
    seen = map_region(grab_view_box(v), mask.shape)
    assert_shows_as_stored(seen.min(axis=2) > 180, mask, "the viewer's texture")
    # row 0 is at the top of the screen and the y axis says so: its values grow downwards
    top = v.map.map_to_viewport(0.0, SPEC.y0_mm)
    bottom = v.map.map_to_viewport(0.0, SPEC.y0_mm + 50.0)
    assert bottom.y() > top.y()
    assert "rail motion" in v.map.plot.getAxis("left").labelText
    assert "rail motion" in v.map.direction_label.text and v.map.direction_label.isVisible()


def test_measurements_read_the_cells_under_the_screen_pixels(qtbot, viewer):
    """A marker clicked where the screen shows the letter reads the letter's height, one
    clicked on the ground above it reads the ground; a ruler from that ground straight down
    the screen into the letter's long bar rises where the screen shows the bar's edge."""
    v = viewer
    box = v.map.mapFromScene(v.map.vb.sceneBoundingRect()).boundingRect()
    full = to_array(v.map.viewport().grab().toImage())
    letter = (full[..., 0] > 100) & (full[..., 2] < 80)
    letter[: box.top() + 4] = letter[box.bottom() - 4 :] = False
    letter[:, : box.left() + 4] = letter[:, box.right() - 4 :] = False
    rows, cols = np.nonzero(letter)
    r_top = int(rows.min())  # the long bar's upper edge on screen
    c = int(cols[rows == r_top + 10].max()) - 10  # near the bar's right end: only the bar
    on_bar, on_ground = QPoint(c, r_top + 10), QPoint(c, r_top - 25)
    v.set_mode("marker")
    for where, want in ((on_bar, LETTER_MM), (on_ground, 0.0)):
        n = len(v.project.measurements)
        QTest.mouseClick(v.map.viewport(), Qt.MouseButton.LeftButton,
                         Qt.KeyboardModifier.NoModifier, where)
        assert len(v.project.measurements) == n + 1
        assert v.project.measurements[-1]["values"]["height_mm"] == pytest.approx(want, abs=0.01)
    v.set_mode("ruler")
    end = QPoint(c, r_top + 20)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        for where in (on_ground, end):
            QTest.mouseClick(v.map.viewport(), Qt.MouseButton.LeftButton,
                             Qt.KeyboardModifier.NoModifier, where)
    (x0, y0), (x1, y1) = v.ruler_points()
    assert y1 > y0 and abs(x1 - x0) < 0.2  # down the screen is +y in the grid
    d, hgt = np.asarray(v.profile.distance_mm), np.asarray(v.profile.height_mm)
    assert hgt[d < 1.0].max() < 0.01 and hgt[d > d[-1] - 1.0].min() > LETTER_MM - 0.01
    px_per_mm = (end.y() - on_ground.y()) / d[-1]
    edge_px = d[np.argmax(hgt > LETTER_MM / 2)] * px_per_mm
    assert abs(edge_px - (r_top - on_ground.y())) <= 2.0


def test_the_figure_png_shows_the_map_as_stored(qtbot, viewer, scene):
    """The figure the viewer exports (File > Export figure), decoded from its PNG bytes."""
    v, (mask, height, _texture) = viewer, scene
    fig = cv2.imdecode(np.frombuffer(png_bytes(v.actions.figure_maker()()), np.uint8),
                       cv2.IMREAD_COLOR)[..., ::-1]
    lut = np.asarray(v.map.colour_bar.colorMap().getLookupTable(nPts=256), np.uint8)[:, :3]
    lo, hi = v.map.levels()
    colours = lut[np.clip(((height - lo) / (hi - lo) * 255), 0, 255).astype(int)]
    # the map is in the figure pixel for pixel; mirrored or turned it is not
    scores = {}
    for name, m in variants(np.arange(mask.size).reshape(mask.shape)).items():
        want = colours.reshape(-1, 3)[m.ravel()].reshape(colours.shape)
        res = cv2.matchTemplate(fig.astype(np.float32), want.astype(np.float32),
                                cv2.TM_SQDIFF)
        scores[name] = float(res.min() / want.size)
    assert scores["as stored"] < 4.0, scores  # (mean squared difference per channel)
    assert all(s > 100 for k, s in scores.items() if k != "as stored"), scores


def test_the_processing_preview_shows_the_map_as_stored(qtbot, scene):
    mask, height, _texture = scene
    panel = RunPanel()
    qtbot.addWidget(panel)
    panel.resize(700, 900)
    panel.show()
    qtbot.waitExposed(panel)
    spec = GridSpec(SPEC.x0_mm, SPEC.y0_mm, SPEC.pixel_mm, SPEC.shape)
    panel.growing.set_grid(spec)
    panel.show_growing(height)
    qtbot.waitUntil(lambda: panel.growing.isVisible())
    g = panel.growing
    vb = g.getPlotItem().getViewBox()
    full = to_array(g.viewport().grab().toImage())
    r = g.mapFromScene(vb.sceneBoundingRect()).boundingRect()
    seen = map_region(full[r.top() + 2 : r.bottom() - 1, r.left() + 2 : r.right() - 1],
                      mask.shape)
    letter = (seen[..., 0] > 100) & (seen[..., 2] < 80)
    assert_shows_as_stored(letter, mask, "the processing tab's preview")
    assert "rail motion" in g.getPlotItem().getAxis("left").labelText
    assert g.getPlotItem().getAxis("left").labelUnits == "" and "mm" in g.getPlotItem().getAxis(
        "bottom").labelText
    # the axes are the grid's millimetres: row 0's edge at the top
    top = vb.mapViewToScene(QPointF(0.0, SPEC.y0_mm))
    bottom = vb.mapViewToScene(QPointF(0.0, SPEC.y0_mm + 50.0))
    assert bottom.y() > top.y()
    assert vb.viewRect().contains(QRectF(SPEC.x0_mm, SPEC.y0_mm, 39.0, 59.0))


def test_the_3d_view_is_turned_never_mirrored(qtbot, scene):
    """The software 3D view, from straight above at azimuth 180, is the camera's view; from
    azimuth 0 the same picture turned by 180 degrees (a rotation, not a reflection)."""
    mask, height, texture = scene
    win = Surface3DWindow(height, SPEC, texture)
    qtbot.addWidget(win)
    win.resize(700, 800)
    win.elevation = 90.0
    for azimuth, want in ((180.0, mask), (0.0, mask[::-1, ::-1])):
        win.azimuth = azimuth
        with qtbot.waitSignal(win.rendered, timeout=20000):
            if win.isVisible():
                win.request()
            else:
                win.show()
        qtbot.waitUntil(lambda: not win.worker.is_running(), timeout=20000)
        shown = to_array(win.view.pixmap().toImage())
        lit = np.abs(shown.astype(int) - BACKGROUND).sum(axis=2) > 30
        rows, cols = np.flatnonzero(lit.any(axis=1)), np.flatnonzero(lit.any(axis=0))
        crop = shown[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
        seen = cv2.resize(crop, (mask.shape[1], mask.shape[0]), interpolation=cv2.INTER_AREA)
        assert_shows_as_stored(seen.min(axis=2) > 150, want, f"the 3D view at {azimuth}")
    win.shutdown()


def test_the_hillshade_light_comes_from_where_the_panel_says(qtbot, viewer):
    """The light's azimuth is clockwise from the top of the screen: from the top (0) the wall
    of the letter's long bar that faces the top of the screen is lit and the one facing the
    bottom is dark; from the bottom (180) the other way round."""
    v = viewer
    mask = letter_f()
    rows = np.flatnonzero(mask[:, int(0.7 * mask.shape[1])])
    top_i, bottom_i = rows[0], rows[-1]  # the long bar's first and last rows at that column
    j = int(0.7 * mask.shape[1])
    s = SPEC
    x = s.x0_mm + j * s.pixel_mm
    y0, y1 = s.y0_mm + (top_i - 20) * s.pixel_mm, s.y0_mm + (bottom_i + 20) * s.pixel_mm
    v.map.vb.setRange(QRectF(x - 3.0, y0, 6.0, y1 - y0), padding=0)
    show_layer(qtbot, v, "hillshade")
    for azimuth, lit_wall in ((0.0, "top"), (180.0, "bottom")):
        v.display.azimuth.setValue(azimuth)
        qtbot.waitUntil(lambda a=azimuth: v._hillshade is not None
                        and v._hillshade[0][2] == a, timeout=20000)
        qtbot.waitUntil(lambda: not v.is_busy(), timeout=20000)
        img = to_array(v.map.viewport().grab().toImage()).mean(axis=2)

        def brightness(i: float, img=img) -> float:
            p = v.map.map_to_viewport(x, s.y0_mm + i * s.pixel_mm)
            return float(img[p.y() - 1 : p.y() + 2, p.x() - 1 : p.x() + 2].mean())

        # the walls: half a cell outside the bar's first row and inside its last (central
        # differences put the slope on both cells of an edge)
        top, bottom = brightness(top_i - 0.5), brightness(bottom_i + 0.5)
        flat = brightness((top_i + bottom_i) / 2)
        assert abs(flat - 255 * np.sin(np.radians(35.0))) < 6
        lit, dark = (top, bottom) if lit_wall == "top" else (bottom, top)
        assert lit > flat + 20 and dark < flat - 20, (azimuth, top, flat, bottom)
