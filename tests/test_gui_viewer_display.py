"""The viewer's display controls and the ruler's mouse handling, driven through the widgets
(pytest-qt, offscreen) on block A of the simulated `blocks` scan, with what is asserted read
back from the rendered viewport (``grab``) rather than from the widgets' own state:

- texture blending: slider at 0 shows the colour-mapped heights, at 100 the registered
  texture, at 50 their mean;
- colour map: another map in the combo box changes the rendered colours, not the data;
- height range: the spin boxes clip the colours and the colour bar's axis follows;
- hillshade: turning the light by 180 degrees swaps bright and dark walls of the block, the
  elevation sets the brightness of flat ground (sin(elevation));
- the ruler's end dragged with the mouse: lands where it was dropped, the readout follows;
- a ruler placed roughly across a slot (about 0.5 mm off its walls): the profile's step and
  width against the simulator's truth.

(There is no side-by-side texture/heightmap view in the viewer; blending is the only mode.)
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
import pytest
import test_gui_viewer as base
from PySide6.QtCore import QEvent, QPoint, QPointF, Qt
from PySide6.QtGui import QImage, QMouseEvent
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QApplication
from test_gui_viewer import click_map, wait_idle, zoom_to

from impress_gui.core.measure import readings as M

pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]
# the fixtures of test_gui_viewer: the blocks scan and its reconstruction (made once per
# session), the widest slot's truth, a viewer showing the reconstruction
scan, recon, slot, viewer = (
    base.scan,
    base.recon,
    base.slot,
    base.viewer,
)
TOP = 32.0  # block A's top above the calibration's ground (12 mm plate + 20 mm block)


# ----- reading the screen ---------------------------------------------------------------------
def grab(v) -> np.ndarray:
    """The map's viewport as rendered: H x W x 3 bytes."""
    img = v.map.viewport().grab().toImage().convertToFormat(QImage.Format.Format_RGB888)
    h, w, bpl = img.height(), img.width(), img.bytesPerLine()
    buf = np.frombuffer(img.constBits(), np.uint8, count=bpl * h).reshape(h, bpl)
    return buf[:, : w * 3].reshape(h, w, 3).copy()


def cells_in_view(v, x0, x1, y0, y1, step=3):
    """Grid cells (i, j) centred inside the box, every ``step``-th, with their viewport
    pixels (rows, columns)."""
    s = v.data.spec
    j = np.arange(math.ceil((x0 - s.x0_mm) / s.pixel_mm), math.floor((x1 - s.x0_mm) / s.pixel_mm))
    i = np.arange(math.ceil((y0 - s.y0_mm) / s.pixel_mm), math.floor((y1 - s.y0_mm) / s.pixel_mm))
    ii, jj = np.meshgrid(i[::step], j[::step], indexing="ij")
    ii, jj = ii.ravel(), jj.ravel()
    pts = [
        v.map.map_to_viewport(s.x0_mm + b * s.pixel_mm, s.y0_mm + a * s.pixel_mm)
        for a, b in zip(ii, jj, strict=True)
    ]
    return ii, jj, np.array([p.y() for p in pts]), np.array([p.x() for p in pts])


def colour_mapped(h, lo, hi, cmap):
    """What the colour bar's map makes of heights ``h`` over ``(lo, hi)`` (256-entry LUT)."""
    lut = pg.colormap.get(cmap).getLookupTable(nPts=256, alpha=False).astype(np.float64)
    k = np.clip(np.floor((h - lo) / (hi - lo) * 256), 0, 255).astype(int)
    return lut[k]


def show_layer(qtbot, v, key) -> None:
    with qtbot.waitSignal(v.layer_shown, timeout=20000, check_params_cb=lambda k: k == key):
        v.display.layer.setCurrentIndex(v.display.layer.findData(key))
    wait_idle(qtbot, v)


@pytest.fixture
def top_view(qtbot, viewer, slot):
    """Zoomed on the slot and the block's top around it: a few screen pixels per cell, so the
    finest level is displayed and every sampled cell centre is a pixel of its own."""
    y = slot["y"]
    box = (slot["left"] - 8.0, slot["right"] + 8.0, y - 5.0, y + 5.0)
    zoom_to(qtbot, viewer, *box)
    wait_idle(qtbot, viewer)
    assert viewer.map.scalar.shown[0] == 0
    r = viewer.map.vb.viewRect()
    assert viewer.map.vb.viewPixelSize()[0] < viewer.data.spec.pixel_mm / 3
    return box, (r.left(), r.right(), r.top(), r.bottom())


# ----- blending, colour maps, height range --------------------------------------------------
def test_texture_blend_slider_mixes_heightmap_and_texture(qtbot, viewer, top_view):
    v, box = viewer, top_view[0]
    assert v.display.layer_key() == "fused" and v.display.blend.value() == 0
    ii, jj, r, c = cells_in_view(v, *box)
    h = v.data.layers["fused"][ii, jj]
    ok = np.isfinite(h)
    ii, jj, r, c, h = ii[ok], jj[ok], r[ok], c[ok], h[ok]
    assert ok.sum() > 2000
    lo, hi = v.map.levels()
    heights_rgb = colour_mapped(h, lo, hi, v.display.cmap.currentText())
    texture_rgb = v.data.texture_rgb[ii, jj].astype(np.float64)
    # the two pictures differ enough for the check to mean something
    assert np.abs(heights_rgb - texture_rgb).mean() > 40

    def err(expected):
        return np.abs(grab(v)[r, c].astype(np.float64) - expected).mean()

    assert err(heights_rgb) < 2.0 and err(texture_rgb) > 40  # slider at 0: the layer only
    assert not v.map.texture_item.isVisible()
    # the user drags the slider to the end (keyboard: End), then to the middle
    v.display.blend.setFocus()
    QTest.keyClick(v.display.blend, Qt.Key.Key_End)
    assert v.display.blend.value() == 100
    assert err(texture_rgb) < 2.0 and err(heights_rgb) > 40  # the texture only
    v.display.blend.setValue(50)
    assert err((heights_rgb + texture_rgb) / 2) < 3.0  # half and half
    QTest.keyClick(v.display.blend, Qt.Key.Key_Home)
    assert err(heights_rgb) < 2.0
    # blending is display only: the heights measured on do not change
    assert v.measure_height() is v.data.layers["fused"]


def test_colour_map_changes_the_colours_not_the_data(qtbot, viewer, top_view):
    v, box = viewer, top_view[0]
    ii, jj, r, c = cells_in_view(v, *box)
    h = v.data.layers["fused"][ii, jj]
    ok = np.isfinite(h)
    r, c, h = r[ok], c[ok], h[ok]
    before = grab(v)[r, c].astype(np.float64)
    data = v.data.layers["fused"].copy()
    lo, hi = v.map.levels()
    shown = v.map.scalar_item.image.copy()
    rx, ry = box[0] + 3.0, box[2] + 5.0
    readout = v.readout_at(rx, ry)
    assert v.display.cmap.currentText() == "turbo"
    assert np.abs(before - colour_mapped(h, lo, hi, "turbo")).mean() < 2.0
    for name in ("viridis", "magma"):
        with qtbot.waitSignal(v.layer_shown, timeout=20000):
            v.display.cmap.setCurrentIndex(v.display.cmap.findText(name))
        after = grab(v)[r, c].astype(np.float64)
        assert np.abs(after - colour_mapped(h, lo, hi, name)).mean() < 2.0
        assert np.abs(after - before).mean() > 30
        assert v.map.colour_bar.colorMap().name == name
        # the data, the displayed values and the colour range are untouched
        np.testing.assert_array_equal(v.data.layers["fused"], data)
        np.testing.assert_array_equal(v.map.scalar_item.image, shown)
        assert v.map.levels() == (lo, hi)
        assert v.readout_at(rx, ry) == readout


def bar_labels(v) -> list[float]:
    """The numbers written along the colour bar's axis at its current size."""
    axis = v.map.colour_bar.axis
    lo, hi = axis.range
    out = []
    for spacing, values in axis.tickValues(lo, hi, axis.height()):
        out += [float(s) for s in axis.tickStrings(values, 1.0, spacing) if s]
    return sorted(set(out))


def test_height_range_clips_colours_and_moves_the_colour_bar(qtbot, viewer, top_view, slot):
    v, box = viewer, top_view[0]
    cmap = v.display.cmap.currentText()
    lut = pg.colormap.get(cmap).getLookupTable(nPts=256, alpha=False).astype(np.float64)
    old_labels = bar_labels(v)
    # the user types a range over the slot's floor and the block's top: 27 .. 29 mm
    for spin, value in ((v.display.lo, "27"), (v.display.hi, "29")):
        spin.setFocus()
        spin.selectAll()
        QTest.keyClicks(spin, value)
        QTest.keyClick(spin, Qt.Key.Key_Return)
    assert (v.display.lo.value(), v.display.hi.value()) == (27.0, 29.0)
    assert v.map.levels() == (27.0, 29.0)
    assert tuple(v.map.colour_bar.axis.range) == (27.0, 29.0)
    labels = bar_labels(v)
    assert labels != old_labels and len(labels) >= 2
    assert all(27.0 <= x <= 29.0 for x in labels) and min(labels) <= 27.5 and max(labels) >= 28.5
    ii, jj, r, c = cells_in_view(v, *box)
    h = v.data.layers["fused"][ii, jj]
    px = grab(v)[r, c].astype(np.float64)
    top, floor = h > 29.5, h < 26.5  # the block's top (32 mm) and the slot's floor (25.65 mm)
    assert top.sum() > 500 and floor.sum() > 200
    # clipped: above the range the map's last colour, below it the first
    assert np.abs(px[top] - lut[-1]).max() <= 2 and np.abs(px[floor] - lut[0]).max() <= 2
    inside = np.isfinite(h) & (h > 27.05) & (h < 28.95)
    if inside.any():  # (the wall cells in between, if any, follow the map)
        assert np.abs(px[inside] - colour_mapped(h[inside], 27.0, 29.0, cmap)).mean() < 3.0
    # the range is remembered for the layer; Auto gives the percentiles back
    show_layer(qtbot, v, "texture")
    show_layer(qtbot, v, "fused")
    assert v.map.levels() == (27.0, 29.0)
    with qtbot.waitSignal(v.layer_shown, timeout=20000):
        QTest.mouseClick(v.display.auto_button, Qt.MouseButton.LeftButton)
    lo, hi = v.map.levels()
    assert lo < 13.0 and hi > 31.0  # plate and top both inside again
    assert (v.display.lo.value(), v.display.hi.value()) == pytest.approx((lo, hi), abs=0.006)
    assert bar_labels(v)[-1] > 29.0


# ----- hillshade ------------------------------------------------------------------------------
def set_light(qtbot, v, az: float, el: float) -> None:
    v.display.azimuth.setValue(az)
    v.display.elevation.setValue(el)
    qtbot.waitUntil(
        lambda: v._hillshade is not None and v._hillshade[0][2:] == (az, el), timeout=20000
    )
    wait_idle(qtbot, v)


def test_hillshade_light_direction_and_elevation(qtbot, viewer, slot):
    """The walls of the widest slot run along y: the left one falls towards +x (faces +x),
    the right one rises (faces -x). A light from +x (azimuth 90, clockwise from the top of
    the screen; the core's azimuth is the same for 90 and 270) lights
    the left wall and leaves the right one dark; from -x (270) the other way round. Flat
    ground (the block's top, the slot's floor) shows sin(elevation)."""
    v, y = viewer, slot["y"]
    show_layer(qtbot, v, "hillshade")
    zoom_to(qtbot, v, slot["left"] - 3.0, slot["right"] + 3.0, y - 3.0, y + 3.0)
    flat, walls = {}, {}
    for az, el in ((90.0, 35.0), (270.0, 35.0), (90.0, 60.0), (270.0, 60.0)):
        set_light(qtbot, v, az, el)
        assert v.map.rgb.shown[0] == 0
        core = M.hillshade(v.measure_height(), v.data.spec.pixel_mm, az, el)
        img = grab(v)
        for name, x in (("left", slot["left"]), ("right", slot["right"])):
            ii, jj, r, c = cells_in_view(v, x - 0.4, x + 0.4, y - 2.5, y + 2.5, step=1)
            want = np.nan_to_num(core[ii, jj] * 255.0, nan=0.0).astype(np.uint8)
            got = img[r, c]
            # the picture is the core's hillshade of the full-resolution heights, in grey
            assert np.abs(got[:, 0].astype(int) - want).max() <= 1
            assert (got[:, 0] == got[:, 1]).all() and (got[:, 1] == got[:, 2]).all()
            ok = np.isfinite(core[ii, jj])  # (no data is black whatever the light)
            assert ok.sum() > 50  # (the floor beside a wall is partly shadowed)
            walls[name, az, el] = float(got[ok, 0].mean())
        # flat ground: the block's top 1.5 .. 2.5 mm beside the slot, and the slot's floor
        for name, x in (
            ("top", slot["left"] - 2.0),
            ("top", slot["right"] + 2.0),
            ("floor", (slot["left"] + slot["right"]) / 2),
        ):
            ii, jj, r, c = cells_in_view(v, x - 0.5, x + 0.5, y - 2.5, y + 2.5)
            flat.setdefault((name, az, el), []).append(float(np.median(img[r, c, 0])))
    # flat ground: 255 sin(elevation) within 6 grey levels, as the mean of two opposite
    # lights (the reconstructed top and floor are not quite flat next to the walls: one
    # light alone is up to 25 grey levels off, the opposite one off the other way)
    for el in (35.0, 60.0):
        for a, b in zip(
            flat["top", 90.0, el] + flat["floor", 90.0, el],
            flat["top", 270.0, el] + flat["floor", 270.0, el],
            strict=True,
        ):
            assert (a + b) / 2 == pytest.approx(255 * math.sin(math.radians(el)), abs=6)
    # the sign of the response to the slope flips with the light: a bright wall turns dark.
    # Both walls are mostly gaps in the fused map (0.7 mm wide at the right one: no data, black
    # whatever the light); the cells within 0.4 mm are the edges beside them, falling into the
    # slot - which the truth does not (the block's top is flat up to the wall): how far they
    # fall is the reconstruction's edge error, and shrinks as it improves. With the soil seen
    # unlit subtracted (the default since 2026-12-04) the top 0.2-0.5 mm from the right wall
    # falls 0.03 mm where it fell 0.09 (its error there 0.043 -> 0.028 mm): 48 grey levels
    # between the two lights at 35 degrees elevation and 29 at 60 (126 and 77 before), 27
    # below and 21 above flat ground at 35; the left one's foot is shadowed and the top beside
    # it tilts against the wall: 16 grey levels. The margins ask for the sign, clearly.
    for el, right in ((35.0, 25), (60.0, 12)):
        assert walls["right", 270.0, el] > walls["right", 90.0, el] + right
        assert walls["left", 90.0, el] > walls["left", 270.0, el] + 8
    f = 255 * math.sin(math.radians(35.0))
    assert walls["right", 90.0, 35.0] < f - 12 and walls["right", 270.0, 35.0] > f + 10


# ----- ruler: dragging an end, and a rough placement -----------------------------------------
def drag(widget, start: QPoint, end: QPoint, steps: int = 8) -> None:
    """A left-button drag as the window system delivers it: every move carries the held
    button (QTest.mouseMove does not say which buttons are down), at a hand's pace."""
    left, none = Qt.MouseButton.LeftButton, Qt.MouseButton.NoButton

    def send(kind, pos, button, buttons):
        p = QPointF(pos)
        ev = QMouseEvent(
            kind, p, widget.mapToGlobal(p), button, buttons, Qt.KeyboardModifier.NoModifier
        )
        QApplication.sendEvent(widget, ev)

    send(QEvent.Type.MouseButtonPress, start, left, left)
    for k in range(1, steps + 1):
        QTest.qWait(20)  # pyqtgraph drops moves less than 10 ms apart (mouseRateLimit)
        send(QEvent.Type.MouseMove, start + (end - start) * (k / steps), none, left)
    QTest.qWait(20)
    send(QEvent.Type.MouseButtonRelease, end, left, none)


def mm_per_px(v) -> float:
    return float(v.map.vb.viewPixelSize()[0])


def test_dragging_a_ruler_end_moves_it_and_updates_the_distance(qtbot, viewer, slot):
    v, y = viewer, slot["y"]
    zoom_to(qtbot, v, slot["left"] - 10.0, slot["right"] + 10.0, y - 8.0, y + 8.0)
    QTest.mouseClick(v.tools.mode_buttons["ruler"], Qt.MouseButton.LeftButton)
    p0, p1 = (slot["left"] - 5.0, y), (slot["right"] + 5.0, y)
    click_map(v, *p0)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        click_map(v, *p1)
    tol = 1.5 * mm_per_px(v)  # clicks land on whole screen pixels
    assert tol < 0.05
    (a0, a1), (b0, b1) = v.ruler_points()
    assert (a0, a1, b0, b1) == pytest.approx((*p0, *p1), abs=tol)
    length0 = v.profile.length_mm
    # drag the end point 4 mm to the right and 3 mm up with the mouse
    target = (p1[0] + 4.0, p1[1] + 3.0)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        drag(v.map.viewport(), v.map.map_to_viewport(b0, b1), v.map.map_to_viewport(*target))
    (c0, c1), (d0, d1) = v.ruler_points()
    assert (c0, c1) == pytest.approx((a0, a1), abs=1e-9)  # the other end stayed
    assert (d0, d1) == pytest.approx(target, abs=tol)
    true_xy = math.hypot(target[0] - p0[0], target[1] - p0[1])
    r = v.ruler_result()
    assert r.xy_mm == pytest.approx(true_xy, abs=2 * tol)
    assert f"xy {r.xy_mm:.3f} mm" in v.tools.ruler_text.text()
    assert f"xy {r.xy_mm:.3f} mm" in v.map.ruler_label.toPlainText()
    # the profile follows the new segment, computed on the full-resolution heights
    assert v.profile.length_mm == pytest.approx(r.xy_mm, abs=1e-9) and v.profile.length_mm > length0
    core = M.line_profile(
        v.measure_height(), v.data.spec, (c0, c1), (d0, d1), v.tools.width.value()
    )
    np.testing.assert_array_equal(v.profile.height_mm, core.height_mm)
    # the start end too, dragged 1.5 mm right and 1 mm down (still on the block's top)
    start = (c0 + 1.5, c1 - 1.0)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        drag(v.map.viewport(), v.map.map_to_viewport(c0, c1), v.map.map_to_viewport(*start))
    (e0, e1), (f0, f1) = v.ruler_points()
    assert (e0, e1) == pytest.approx(start, abs=tol) and (f0, f1) == pytest.approx((d0, d1))
    assert v.ruler_result().xy_mm == pytest.approx(
        math.hypot(target[0] - start[0], target[1] - start[1]), abs=2 * tol
    )
    # the start is on the block's top, the end on the floor of the next slot: dz is minus
    # the slots' depth (0.25 mm: two 0.5 mm readouts carry the reconstruction's errors)
    r = v.ruler_result()
    assert r.start.height_mm == pytest.approx(TOP, abs=0.25)
    assert r.dz_mm == pytest.approx(-slot["depth"], abs=0.25)


def test_rough_ruler_across_a_slot_reports_its_step_and_width(qtbot, viewer, slot):
    """The analyst clicks roughly (about 0.5 mm off) beside the widest slot and eyeballs the
    bands on the profile; the step (B - A) is the slot's depth within 0.1 mm, the walls where
    the profile crosses half depth within 0.15 mm of the truth, the width within 0.2 mm."""
    v, y = viewer, slot["y"]
    zoom_to(qtbot, v, slot["left"] - 10.0, slot["right"] + 10.0, y - 8.0, y + 8.0)
    v.tools.width.setFocus()
    v.tools.width.selectAll()
    QTest.keyClicks(v.tools.width, "2")
    QTest.keyClick(v.tools.width, Qt.Key.Key_Return)
    assert v.tools.width.value() == 2.0
    QTest.mouseClick(v.tools.mode_buttons["ruler"], Qt.MouseButton.LeftButton)
    p0 = (slot["left"] - 4.5 + 0.47, y + 0.52)  # not on any true position
    p1 = (slot["right"] + 4.5 - 0.44, y - 0.38)
    click_map(v, *p0)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        click_map(v, *p1)
    (x0, y0), (x1, y1) = v.ruler_points()
    length = math.hypot(x1 - x0, y1 - y0)
    ux = (x1 - x0) / length  # cos of the ruler's angle to the slot's walls' normal
    assert 0.99 < ux < 1.0
    # where the analyst puts the bands on the plotted profile: the top left of the slot
    # (0.3 .. 3.0 mm) and the floor (inside the dip, away from its walls)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        v.profile_plot.regions["A"].setRegion((0.3, 3.0))
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        v.profile_plot.regions["B"].setRegion((5.0, 9.5))
    s = v.step
    assert (s.a.start_mm, s.a.end_mm, s.b.start_mm, s.b.end_mm) == (0.3, 3.0, 5.0, 9.5)
    assert f"Step B - A: {s.difference_mm:+.3f}" in v.tools.step_text.text()
    # the profile is the core's on the full-resolution heights
    core = M.line_profile(v.data.layers["fused"], v.data.spec, (x0, y0), (x1, y1), 2.0)
    np.testing.assert_array_equal(v.profile.height_mm, core.height_mm)
    assert -s.difference_mm == pytest.approx(slot["depth"], abs=0.1)
    assert s.a.mean_mm == pytest.approx(TOP, abs=0.25) and s.a.sd_mm < 0.1 and s.b.sd_mm < 0.1
    level = s.a.mean_mm + s.difference_mm / 2
    w = M.width_at_level(v.profile, level, around_mm=(s.b.start_mm + s.b.end_mm) / 2)
    left_x, right_x = x0 + w.left_mm * ux, x0 + w.right_mm * ux
    assert left_x == pytest.approx(slot["left"], abs=0.15)
    assert right_x == pytest.approx(slot["right"], abs=0.15)
    assert w.width_mm * ux == pytest.approx(slot["width"], abs=0.2)
    # kept as a measurement with the values shown
    m = v.add_ruler_measurement("slot 1, rough")
    assert m["values"]["step_mm"] == pytest.approx(s.difference_mm, abs=1e-4)
    assert m["values"]["xy_mm"] == pytest.approx(length, abs=1e-4)
