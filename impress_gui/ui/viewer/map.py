"""The map of the viewer: a layer (heights with a colour bar in mm, or an RGB image), the
texture blended over it, the ruler, levelling marks and the saved measurements.

View coordinates are rail-frame millimetres. The map is shown as the camera sees the ground
from above, exactly as ``texture.png`` is stored: grid row 0 at the top, the row index (y,
the carriage's direction of motion, +Y) increasing downwards, x to the right; a label above
the map says so. Scene -> view mapping goes through the ViewBox (``mapSceneToView``), which
knows the inversion, so clicks, the ruler and the readout name the cell under the cursor.

Wheel: zoom; drag the background: pan; right click: show all. In a placing mode (ruler,
marker, levelling points) a left click emits ``clicked(x_mm, y_mm)`` instead.
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QPoint, QPointF, QRectF, Qt, Signal
from PySide6.QtWidgets import QWidget

from impress_gui.core.formats.writers import contribution_png
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.ui.frame_view import PassiveScatter
from impress_gui.ui.viewer.image import LodImage

RULER_PEN = (255, 255, 255)
BAND_COLOURS = {"A": (60, 140, 255), "B": (255, 150, 30)}
MARK_COLOUR = (255, 60, 220)
CROSSHAIR_PEN = (0, 255, 255)
#: the orientation and the rail's direction, shown above the map (and in the figures)
RAIL_TEXT = "Seen from above as the camera sees it · x → · rail motion (+y) ↓"
X_LABEL = "x (mm)"
Y_LABEL = "y (mm), increasing downwards: rail motion"
#: what the contribution layer's codes mean (the codes of ``grid.fuse``)
CONTRIBUTION_MEANING = {
    1: "green laser only",
    2: "red laser only",
    3: "both lasers, agreeing (weighted mean)",
    4: "both, disagreeing (nearer one kept)",
    0: "no data",
}
#: the contribution layer's colours (RGB, as drawn) and their meaning, for its legends
CONTRIBUTION_LEGEND: tuple[tuple[tuple[int, int, int], str], ...] = tuple(
    (tuple(int(v) for v in contribution_png(np.array([code]))[0]), text)
    for code, text in CONTRIBUTION_MEANING.items()
)


def legend_html(entries=CONTRIBUTION_LEGEND, heading: str = "Which laser measured the cell") -> str:
    """A legend as rich text: a coloured square and its meaning per line."""
    rows = "".join(
        f"<tr><td style='background-color: rgb{tuple(c)}; border: 1px solid #777'>"
        f"&nbsp;&nbsp;&nbsp;&nbsp;</td><td>&nbsp;{text}</td></tr>"
        for c, text in entries
    )
    return f"<b>{heading}</b><table cellspacing='2'>{rows}</table>"


class _MapViewBox(pg.ViewBox):
    def __init__(self, on_click) -> None:
        super().__init__(lockAspect=True, invertY=True, enableMenu=False)
        self._on_click = on_click
        self.placing = False

    def mouseClickEvent(self, ev) -> None:  # noqa: N802 - pyqtgraph override
        if ev.button() == Qt.MouseButton.LeftButton and self.placing:
            ev.accept()
            p = self.mapSceneToView(ev.scenePos())
            self._on_click(float(p.x()), float(p.y()))
        elif ev.button() == Qt.MouseButton.RightButton:
            ev.accept()
            self.autoRange(padding=0.02)
        else:
            super().mouseClickEvent(ev)


class MapView(pg.GraphicsLayoutWidget):
    hovered = Signal(float, float)
    left_map = Signal()
    clicked = Signal(float, float)
    ruler_moved = Signal()  # while dragging
    ruler_finished = Signal()
    region_finished = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setBackground("k")
        self.vb = _MapViewBox(self.clicked.emit)
        self.direction_label = self.addLabel(
            RAIL_TEXT, row=0, col=0, justify="left", color=(230, 230, 230), size="9pt"
        )
        self.plot = self.addPlot(row=1, col=0, viewBox=self.vb)
        self.plot.setLabel("bottom", X_LABEL)
        self.plot.setLabel("left", Y_LABEL)
        self.plot.showGrid(x=False, y=False)
        self.scalar_item = pg.ImageItem(axisOrder="row-major")
        self.rgb_item = pg.ImageItem(axisOrder="row-major")
        self.texture_item = pg.ImageItem(axisOrder="row-major")
        for z, item in enumerate((self.scalar_item, self.rgb_item, self.texture_item)):
            item.setZValue(z - 10)
            self.plot.addItem(item)
        self.scalar = LodImage(self.scalar_item, self.vb, "layer")
        self.rgb = LodImage(self.rgb_item, self.vb, "rgb-layer")
        self.texture = LodImage(self.texture_item, self.vb, "texture", delay_ms=600)
        self.colour_bar = pg.ColorBarItem(
            values=(0.0, 1.0),
            colorMap=pg.colormap.get("turbo"),
            label="height (mm)",
            interactive=True,
            rounding=0.01,
        )
        self.colour_bar.setImageItem(self.scalar_item, insert_in=self.plot)
        self.colour_bar.sigLevelsChanged.connect(self._on_bar_levels)
        self.spec: GridSpec | None = None
        # ruler
        self.ruler: pg.LineSegmentROI | None = None
        self.ruler_label = pg.TextItem(color=RULER_PEN, anchor=(0.5, 1.2), fill=(0, 0, 0, 160))
        self.ruler_label.setZValue(30)
        self.width_lines = pg.PlotCurveItem(
            pen=pg.mkPen(RULER_PEN, width=1, style=Qt.PenStyle.DashLine), connect="pairs"
        )
        self.band_lines = {
            k: pg.PlotCurveItem(pen=pg.mkPen(c, width=5)) for k, c in BAND_COLOURS.items()
        }
        for item in (self.ruler_label, self.width_lines, *self.band_lines.values()):
            item.setZValue(25)
            self.plot.addItem(item)
        self.ruler_label.hide()
        # levelling marks and region
        self.level_points = PassiveScatter(
            symbol="t", size=14, pen=pg.mkPen("w"), brush=pg.mkBrush(255, 220, 0)
        )
        self.level_points.setZValue(26)
        self.plot.addItem(self.level_points)
        self.level_labels: list[pg.TextItem] = []
        self.region: pg.RectROI | None = None
        # saved measurements
        self.saved_items: list = []
        # the cursor's place, drawn when another view shows the same ground (side by side)
        pen = pg.mkPen(CROSSHAIR_PEN, width=1)
        self.cross_lines = (pg.InfiniteLine(angle=90, movable=False, pen=pen),
                            pg.InfiniteLine(angle=0, movable=False, pen=pen))
        for line in self.cross_lines:
            line.setZValue(40)
            line.hide()
            self.plot.addItem(line, ignoreBounds=True)
        self.scene().sigMouseMoved.connect(self._on_mouse_moved)

    # ----- layers -----------------------------------------------------------------------------
    def set_spec(self, spec: GridSpec | None, fit: bool = True) -> None:
        self.spec = spec
        if spec is not None and fit:
            self.fit()

    def full_rect(self) -> QRectF:
        s = self.spec
        h, w = s.shape
        return QRectF(
            s.x0_mm - s.pixel_mm / 2, s.y0_mm - s.pixel_mm / 2, w * s.pixel_mm, h * s.pixel_mm
        )

    def fit(self) -> None:
        if self.spec is not None:
            self.vb.setRange(self.full_rect(), padding=0.02)

    def show_scalar(
        self, arr: np.ndarray, levels: tuple[float, float], cmap: str, label: str = "height (mm)"
    ) -> None:
        self.rgb.set_data(None, None)
        self.colour_bar.setColorMap(pg.colormap.get(cmap))
        # shown before it is labelled: an axis labelled while hidden keeps a width of 0 and
        # its label is drawn over the bar
        self.colour_bar.show()
        self.colour_bar.setLabel("left", label)
        self.colour_bar.setLevels(levels)
        self.scalar.set_data(arr, self.spec, levels)

    def show_rgb(self, rgb: np.ndarray, nearest: bool = False) -> None:
        self.scalar.set_data(None, None)
        self.colour_bar.hide()
        self.rgb.set_data(rgb, self.spec, nearest=nearest)

    def set_levels(self, levels: tuple[float, float]) -> None:
        """Colour range of the height layer: the bar and every crop shown from now on (the
        bar's ``setLevels`` does not emit ``sigLevelsChanged`` in pyqtgraph 0.14, so the map
        is told directly)."""
        levels = (float(levels[0]), float(levels[1]))
        self.colour_bar.setLevels(levels)
        self.scalar.set_colour_levels(levels)

    def levels(self) -> tuple[float, float]:
        lo, hi = self.colour_bar.levels()
        return float(lo), float(hi)

    def _on_bar_levels(self, *_args) -> None:  # the user drags the bar's handles
        self.scalar.set_colour_levels(self.levels())

    def set_texture(self, rgb: np.ndarray | None, opacity: float) -> None:
        self.texture.set_data(rgb, self.spec if rgb is not None else None)
        self.set_texture_opacity(opacity)

    def set_texture_opacity(self, opacity: float) -> None:
        self.texture_item.setOpacity(opacity)
        self.texture_item.setVisible(opacity > 0)

    def is_busy(self) -> bool:
        return any(lod.is_building() for lod in (self.scalar, self.rgb, self.texture))

    def shutdown(self) -> None:
        for lod in (self.scalar, self.rgb, self.texture):
            lod.shutdown()

    def set_placing(self, on: bool) -> None:
        self.vb.placing = on
        self.setCursor(Qt.CursorShape.CrossCursor if on else Qt.CursorShape.ArrowCursor)

    # ----- ruler ------------------------------------------------------------------------------
    def set_ruler(self, p0, p1) -> None:
        if self.ruler is None:
            self.ruler = pg.LineSegmentROI(
                [p0, p1], pen=pg.mkPen(RULER_PEN, width=2), hoverPen=pg.mkPen("y", width=2)
            )
            self.ruler.setZValue(28)
            self.ruler.sigRegionChanged.connect(lambda *_: self.ruler_moved.emit())
            self.ruler.sigRegionChangeFinished.connect(lambda *_: self.ruler_finished.emit())
            self.plot.addItem(self.ruler)
        else:
            self.ruler.blockSignals(True)
            self.ruler.setPos(0, 0)
            h0, h1 = self.ruler.getHandles()
            self.ruler.movePoint(h0, QPointF(*p0), finish=False)
            self.ruler.movePoint(h1, QPointF(*p1), finish=False)
            self.ruler.blockSignals(False)
        self.ruler_moved.emit()
        self.ruler_finished.emit()

    def ruler_points(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        if self.ruler is None:
            return None
        pts = [self.ruler.mapToParent(h.pos()) for h in self.ruler.getHandles()]
        return (pts[0].x(), pts[0].y()), (pts[1].x(), pts[1].y())

    def clear_ruler(self) -> None:
        if self.ruler is not None:
            self.plot.removeItem(self.ruler)
            self.ruler = None
        self.ruler_label.hide()
        self.width_lines.setData([], [])
        for item in self.band_lines.values():
            item.setData([], [])

    def decorate_ruler(
        self, text: str, width_mm: float, bands: dict[str, tuple[float, float]] | None
    ) -> None:
        """Label the ruler, draw its averaging width and the reference bands along it."""
        pts = self.ruler_points()
        if pts is None:
            return
        (x0, y0), (x1, y1) = pts
        length = math.hypot(x1 - x0, y1 - y0)
        ux, uy = ((x1 - x0) / length, (y1 - y0) / length) if length > 0 else (1.0, 0.0)
        self.ruler_label.setText(text)
        self.ruler_label.setPos((x0 + x1) / 2, (y0 + y1) / 2)
        self.ruler_label.show()
        if width_mm > 0:
            nx, ny = -uy * width_mm / 2, ux * width_mm / 2
            xs = [x0 + nx, x1 + nx, x0 - nx, x1 - nx]
            ys = [y0 + ny, y1 + ny, y0 - ny, y1 - ny]
            self.width_lines.setData(xs, ys)
        else:
            self.width_lines.setData([], [])
        for name, item in self.band_lines.items():
            band = (bands or {}).get(name)
            if band is None:
                item.setData([], [])
                continue
            a, b = band
            item.setData([x0 + ux * a, x0 + ux * b], [y0 + uy * a, y0 + uy * b])

    # ----- levelling --------------------------------------------------------------------------
    def set_level_points(self, pts: list[tuple[float, float]]) -> None:
        for t in self.level_labels:
            self.plot.removeItem(t)
        self.level_labels.clear()
        self.level_points.setData([p[0] for p in pts], [p[1] for p in pts])
        for k, (x, y) in enumerate(pts, 1):
            t = pg.TextItem(f"P{k}", color=(255, 220, 0), anchor=(0, 1))
            t.setPos(x, y)
            t.setZValue(26)
            self.plot.addItem(t)
            self.level_labels.append(t)

    def show_region(self, rect: QRectF | None) -> None:
        if rect is None:
            if self.region is not None:
                self.plot.removeItem(self.region)
                self.region = None
            return
        if self.region is None:
            self.region = pg.RectROI(
                [rect.x(), rect.y()],
                [rect.width(), rect.height()],
                pen=pg.mkPen((255, 220, 0), width=2),
                removable=False,
            )
            self.region.setZValue(24)
            self.region.sigRegionChangeFinished.connect(lambda *_: self.region_finished.emit())
            self.plot.addItem(self.region)
        else:
            self.region.setPos((rect.x(), rect.y()), finish=False)
            self.region.setSize((rect.width(), rect.height()), finish=False)

    def region_rect(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        if self.region is None:
            return None
        p, s = self.region.pos(), self.region.size()
        return (p.x(), p.x() + s.x()), (p.y(), p.y() + s.y())

    # ----- saved measurements -------------------------------------------------------------------
    def show_measurements(self, measurements: list[dict], selected: int | None = None) -> None:
        for item in self.saved_items:
            self.plot.removeItem(item)
        self.saved_items.clear()
        for k, m in enumerate(measurements, 1):
            pts = m.get("points_mm") or []
            if not pts:
                continue
            colour = (255, 255, 0) if selected == k - 1 else MARK_COLOUR
            label = f"{k}" + (f": {m['label']}" if m.get("label") else "")
            if len(pts) >= 2:
                line = pg.PlotCurveItem(
                    [p[0] for p in pts], [p[1] for p in pts], pen=pg.mkPen(colour, width=2)
                )
                line.setZValue(22)
                self.plot.addItem(line)
                self.saved_items.append(line)
            mark = PassiveScatter(
                [pts[0][0]],
                [pts[0][1]],
                symbol="o",
                size=9,
                pen=pg.mkPen("k"),
                brush=pg.mkBrush(colour),
            )
            text = pg.TextItem(label, color=colour, anchor=(-0.15, 1.1), fill=(0, 0, 0, 140))
            text.setPos(pts[0][0], pts[0][1])
            for item in (mark, text):
                item.setZValue(23)
                self.plot.addItem(item)
                self.saved_items.append(item)

    # ----- the linked cursor --------------------------------------------------------------------
    def set_crosshair(self, x_mm: float | None, y_mm: float | None = None) -> None:
        """Draw the cursor's crosshair at ``(x_mm, y_mm)`` (None: hide it)."""
        for line, v in zip(self.cross_lines, (x_mm, y_mm)):
            if x_mm is None:
                line.hide()
            else:
                line.setValue(v)
                line.show()

    def crosshair(self) -> tuple[float, float] | None:
        """Where the crosshair is drawn (None when hidden)."""
        vx, hy = self.cross_lines
        return (float(vx.value()), float(hy.value())) if vx.isVisible() else None

    # ----- mapping and events -------------------------------------------------------------------
    def map_to_viewport(self, x_mm: float, y_mm: float) -> QPoint:
        """Viewport pixel where the map point ``(x_mm, y_mm)`` is drawn (tests, scripts)."""
        return self.mapFromScene(self.vb.mapViewToScene(QPointF(x_mm, y_mm)))

    def _on_mouse_moved(self, scene_pos: QPointF) -> None:
        if self.spec is None or not self.vb.sceneBoundingRect().contains(scene_pos):
            self.left_map.emit()
            return
        p = self.vb.mapSceneToView(scene_pos)
        self.hovered.emit(float(p.x()), float(p.y()))

    def leaveEvent(self, ev) -> None:  # noqa: N802 - Qt override
        self.left_map.emit()
        super().leaveEvent(ev)
