"""The software 3D view draws the axes of the right-handed export frame (x across the rail,
y = -rail y, z up) labelled in mm, and a scale bar (issue 21, item 9): the axes' projected
ends put x to the right and y up the screen seen from above as the camera sees the ground
(azimuth 180), turned - never mirrored - at every azimuth; z towards the eye from above and
up the screen from the side; the scale bar's length is the image's true scale; the window
shows them over the surface."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6.QtGui import QImage

from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.ui import pyside_fix
from impress_gui.ui.viewer.view3d import (
    AXIS_COLOURS,
    BACKGROUND,
    Surface3DWindow,
    nice_length,
    render_surface,
)

pyside_fix.guard()
pytestmark = pytest.mark.qt_log_ignore("propagateSizeHints")

SPEC = GridSpec(-20.0, 100.0, 0.2, (300, 200))  # 40 mm across (x), 60 mm along the rail


def surface() -> np.ndarray:
    h = np.zeros(SPEC.shape, np.float32)
    h[40:120, 30:90] = 3.0  # a block in the map's upper left
    return h


def render(azimuth: float, elevation: float, **kw) -> tuple[np.ndarray, dict]:
    axes: dict = {}
    img = render_surface(surface(), SPEC, None, azimuth, elevation, size=(600, 500),
                         axes=axes, **kw)
    return img, axes


def direction(axes: dict, name: str) -> np.ndarray:
    """The axis on screen, as (right, up) pixels from the origin."""
    (u0, v0), (u1, v1) = axes["origin"], axes["ends"][name]
    return np.array([u1 - u0, v0 - v1])


def test_axes_from_above_as_the_camera_sees_the_ground():
    img, axes = render(180.0, 90.0)
    length = axes["length_mm"]
    assert length == nice_length(0.3 * 60.0) == 10.0
    assert axes["labels"] == {"x": "x 10 mm", "y": "y 10 mm", "z": "z 10 mm"}
    px = axes["scale_bar"]["px"] / axes["scale_bar"]["mm"]  # image pixels per mm
    x, y, z = (direction(axes, k) for k in "xyz")
    assert x == pytest.approx([length * px, 0.0], abs=1.0)  # x to the right
    assert y == pytest.approx([0.0, length * px], abs=1.0)  # y (= -rail y) up the screen
    assert np.hypot(*z) < 1.0  # z points at the eye
    # the origin is the surface's lowest corner: x smallest, rail y largest = bottom left
    lit = np.abs(img.astype(int) - BACKGROUND).sum(axis=2) > 30
    rows, cols = np.flatnonzero(lit.any(axis=1)), np.flatnonzero(lit.any(axis=0))
    assert axes["origin"] == pytest.approx((cols[0], rows[-1]), abs=6.0)  # < 1 mm
    # the scale bar is the image's scale: the surface is 40 x 60 mm on screen (its drawn
    # edge spreads by a splat of about a pixel on each side)
    assert cols[-1] - cols[0] + 1 == pytest.approx(40.0 * px, rel=0.04)
    assert rows[-1] - rows[0] + 1 == pytest.approx(60.0 * px, rel=0.04)


@pytest.mark.parametrize("azimuth", [0.0, 90.0, 180.0, 270.0, 200.0])
def test_the_axes_turn_with_the_view_never_mirrored(azimuth):
    _img, axes = render(azimuth, 90.0)
    x, y = direction(axes, "x"), direction(axes, "y")
    # seen from above a right-handed frame keeps y a quarter turn anticlockwise of x
    cross = x[0] * y[1] - x[1] * y[0]
    assert cross > 0.9 * np.hypot(*x) * np.hypot(*y)
    if azimuth == 0.0:
        assert x[0] < 0 and y[1] < 0  # from beyond the top edge: turned by half a turn


def test_z_goes_up_the_screen_seen_from_the_side_with_its_exaggeration():
    _img, axes = render(180.0, 30.0, exaggeration=2.0)
    z = direction(axes, "z")
    assert z[1] > 0 and abs(z[0]) < 1.0
    assert axes["labels"]["z"] == "z 10 mm (x2)"
    px = axes["scale_bar"]["px"] / axes["scale_bar"]["mm"]
    assert z[1] == pytest.approx(2 * 10.0 * px * np.cos(np.radians(30.0)), abs=1.5)


def to_array(img: QImage) -> np.ndarray:
    img = img.convertToFormat(QImage.Format.Format_RGB888)
    h, w, bpl = img.height(), img.width(), img.bytesPerLine()
    buf = np.frombuffer(img.constBits(), np.uint8, count=bpl * h).reshape(h, bpl)
    return buf[:, : w * 3].reshape(h, w, 3).copy()


def test_the_window_draws_the_axes_and_the_scale_bar_over_the_surface(qtbot):
    win = Surface3DWindow(surface(), SPEC, None)
    qtbot.addWidget(win)
    win.resize(800, 700)
    win.azimuth, win.elevation = 180.0, 90.0
    with qtbot.waitSignal(win.rendered, timeout=20000):
        win.show()
    qtbot.waitUntil(lambda: not win.worker.is_running(), timeout=20000)
    if win.view.pixmap().size() != win.view.size():  # resized while rendering
        with qtbot.waitSignal(win.rendered, timeout=20000):
            win.request()
    shot = to_array(win.view.grab().toImage())
    a = win.overlay
    for name in "xy":
        (u0, v0), (u1, v1) = a.axes["origin"], a.axes["ends"][name]
        mid = a.to_widget(((u0 + u1) / 2, (v0 + v1) / 2))
        patch = shot[int(mid.y()) - 1: int(mid.y()) + 2, int(mid.x()) - 1: int(mid.x()) + 2]
        want = np.array(AXIS_COLOURS[name])
        assert np.abs(patch.reshape(-1, 3).astype(int) - want).sum(axis=1).min() < 60, name
    # the scale bar: white pixels along it
    bar = a.axes["scale_bar"]
    at = a.to_widget(bar["at"])
    row = shot[int(at.y()) - 1: int(at.y()) + 2, int(at.x()): int(at.x() + bar["px"])]
    assert (row.min(axis=2) > 200).any(axis=0).mean() > 0.9
    win.shutdown()
