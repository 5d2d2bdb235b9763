"""A zoomable video-frame view with clickable, draggable corner markers, overlays and a loupe.

View coordinates are image pixels in the picks' convention: ``(0, 0)`` is the centre of the
top-left pixel, x to the right, y down (the image item covers ``[-0.5, w - 0.5]``). The wheel
zooms, dragging the background pans, dragging a marker moves that corner.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QPoint, QPointF, QRectF, QSize, Qt, Signal
from PySide6.QtGui import QColor, QImage, QPainter, QPen
from PySide6.QtWidgets import QSizePolicy, QWidget

FRAME_COLOURS = {"t1": (255, 230, 0), "t2": (0, 220, 255)}
STRIPE_COLOURS = {"green": (80, 255, 80), "red": (255, 70, 70)}
REPROJ_COLOUR = (255, 0, 255)
# target outline: A-B-C-D-E-F-A and the riser edge C-F
OUTLINE = ((0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0), (2, 5))


class PassiveScatter(pg.ScatterPlotItem):
    """A scatter drawn for information only (the fitted target's corners, the original click
    of a snapped corner, levelling marks): pyqtgraph's ScatterPlotItem accepts a left click on
    any of its symbols and so swallows it; this one lets the click go on to the view (marking
    a corner) or to what lies under it."""

    def mouseClickEvent(self, ev) -> None:  # noqa: N802 - pyqtgraph override
        ev.ignore()


class _ClickViewBox(pg.ViewBox):
    """A ViewBox whose left click reports the image position instead of doing nothing."""

    def __init__(self, on_click) -> None:
        super().__init__(lockAspect=True, invertY=True, enableMenu=False)
        self._on_click = on_click

    def mouseClickEvent(self, ev) -> None:  # noqa: N802 - pyqtgraph override
        if ev.button() == Qt.MouseButton.LeftButton:
            ev.accept()
            p = self.mapSceneToView(ev.scenePos())
            self._on_click(float(p.x()), float(p.y()))
        elif ev.button() == Qt.MouseButton.RightButton:
            ev.accept()
            self.autoRange(padding=0.02)


class FrameView(pg.GraphicsView):
    clicked = Signal(float, float)  # image position of a left click
    corner_moved = Signal(str, float, float)  # a marker dragged to a new position (finished)
    hovered = Signal(float, float)  # image position under the cursor
    left = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent, background="k")
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.vb = _ClickViewBox(self.clicked.emit)
        self.setCentralItem(self.vb)
        self.image = pg.ImageItem(axisOrder="row-major")
        self.vb.addItem(self.image)
        self.size_px: tuple[int, int] | None = None
        self.markers: dict[str, pg.TargetItem] = {}
        self._marker_colour = FRAME_COLOURS["t1"]
        self.stripes = {
            n: pg.PlotCurveItem(pen=pg.mkPen(c, width=1.5)) for n, c in STRIPE_COLOURS.items()
        }
        for item in self.stripes.values():
            item.setZValue(5)
            self.vb.addItem(item)
        self.reproj_lines = pg.PlotCurveItem(
            pen=pg.mkPen(REPROJ_COLOUR, width=1.5, style=Qt.PenStyle.DashLine), connect="pairs"
        )
        self.reproj_points = PassiveScatter(
            symbol="o", size=11, brush=None, pen=pg.mkPen(REPROJ_COLOUR, width=1.5)
        )
        self.raw_points = PassiveScatter(
            symbol="x", size=9, pen=pg.mkPen("w"), brush=pg.mkBrush("w")
        )
        self.snap_lines = pg.PlotCurveItem(pen=pg.mkPen("w", width=1), connect="pairs")
        for z, item in enumerate(
            (self.reproj_lines, self.reproj_points, self.snap_lines, self.raw_points)
        ):
            item.setZValue(6 + z)
            self.vb.addItem(item)
        self.scene().sigMouseMoved.connect(self._on_mouse_moved)
        self.setCursor(Qt.CursorShape.CrossCursor)

    # ----- content ----------------------------------------------------------------------------
    def set_frame(self, rgb: np.ndarray | None) -> None:
        if rgb is None:
            self.image.clear()
            self.size_px = None
            return
        h, w = rgb.shape[:2]
        first = self.size_px != (w, h)
        self.image.setImage(rgb, autoLevels=False, levels=(0, 255))
        self.image.setRect(QRectF(-0.5, -0.5, w, h))
        self.size_px = (w, h)
        if first:
            self.fit()

    def fit(self) -> None:
        if self.size_px is not None:
            w, h = self.size_px
            self.vb.setRange(QRectF(-0.5, -0.5, w, h), padding=0.01)

    def zoom_around(self, u: float, v: float, span_px: float = 24.0) -> None:
        """Zoom in on image position ``(u, v)``, showing about ``span_px`` pixels across."""
        self.vb.setRange(QRectF(u - span_px / 2, v - span_px / 2, span_px, span_px), padding=0)

    def contains(self, u: float, v: float) -> bool:
        if self.size_px is None:
            return False
        w, h = self.size_px
        return -0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5

    def set_corners(
        self,
        corners: dict[str, tuple[float, float]],
        raw: dict[str, tuple[float, float]] | None = None,
        colour: tuple[int, int, int] = FRAME_COLOURS["t1"],
    ) -> None:
        """Show the marked corners (draggable) and, for snapped ones, the original click."""
        if colour != self._marker_colour:
            for name in list(self.markers):
                self.vb.removeItem(self.markers.pop(name))
            self._marker_colour = colour
        for name in list(self.markers):
            if name not in corners:
                self.vb.removeItem(self.markers.pop(name))
        for name, (u, v) in corners.items():
            m = self.markers.get(name)
            if m is None:
                m = pg.TargetItem(
                    pos=(u, v),
                    size=16,
                    symbol="crosshair",
                    pen=pg.mkPen(colour),
                    hoverPen=pg.mkPen("m", width=2),
                    movable=True,
                    label=name,
                    labelOpts={"color": colour, "offset": (10, -12)},
                )
                m.setZValue(20)
                m.sigPositionChangeFinished.connect(lambda item, n=name: self._on_dragged(n, item))
                self.vb.addItem(m)
                self.markers[name] = m
            elif (m.pos().x(), m.pos().y()) != (u, v):
                m.setPos(u, v)
        raw = {k: p for k, p in (raw or {}).items() if k in corners}
        if raw:
            pts = np.array(list(raw.values()))
            self.raw_points.setData(pts[:, 0], pts[:, 1])
            seg = np.array([[raw[k], corners[k]] for k in raw]).reshape(-1, 2)
            self.snap_lines.setData(seg[:, 0], seg[:, 1])
        else:
            self.raw_points.setData([], [])
            self.snap_lines.setData([], [])

    def set_reprojection(self, uv: np.ndarray | None) -> None:
        """The fitted target's corners A-F ``(6, 2)`` reprojected into this frame."""
        if uv is None:
            self.reproj_lines.setData([], [])
            self.reproj_points.setData([], [])
            return
        seg = np.array([[uv[i], uv[j]] for i, j in OUTLINE]).reshape(-1, 2)
        self.reproj_lines.setData(seg[:, 0], seg[:, 1])
        self.reproj_points.setData(uv[:, 0], uv[:, 1])

    def set_stripes(self, rows: dict[str, np.ndarray] | None) -> None:
        """Detected stripe rows per laser (one row per image column, NaN where none)."""
        for name, item in self.stripes.items():
            r = None if rows is None else rows.get(name)
            if r is None or not np.isfinite(r).any():
                item.setData([], [])
                continue
            r = np.asarray(r, float)
            # join neighbouring columns only where the stripe is continuous
            link = np.isfinite(r[:-1]) & np.isfinite(r[1:])
            link[link] = np.abs(np.diff(r)[link]) <= 2.0
            keep = np.isfinite(r)
            cols = np.flatnonzero(keep)
            connect = np.append(link[cols[:-1]] & (np.diff(cols) == 1), False)
            item.setData(cols.astype(float), r[keep], connect=connect)

    # ----- mapping (tests, loupe) ---------------------------------------------------------------
    def map_to_viewport(self, u: float, v: float) -> QPoint:
        """Viewport pixel where the image position ``(u, v)`` is drawn."""
        scene = self.vb.mapViewToScene(QPointF(u, v))
        return self.mapFromScene(scene)

    def pixels_per_image_pixel(self) -> float:
        a = self.vb.mapViewToScene(QPointF(0, 0))
        b = self.vb.mapViewToScene(QPointF(1, 0))
        return float(b.x() - a.x())

    # ----- events -------------------------------------------------------------------------
    def _on_mouse_moved(self, scene_pos: QPointF) -> None:
        if self.size_px is None:
            return
        p = self.vb.mapSceneToView(scene_pos)
        if self.contains(p.x(), p.y()):
            self.hovered.emit(float(p.x()), float(p.y()))
        else:
            self.left.emit()

    def _on_dragged(self, name: str, item: pg.TargetItem) -> None:
        p = item.pos()
        self.corner_moved.emit(name, float(p.x()), float(p.y()))

    def leaveEvent(self, ev) -> None:  # noqa: N802 - Qt override
        self.left.emit()
        super().leaveEvent(ev)


class Loupe(QWidget):
    """A magnified view of the pixels around a point, with a crosshair and the nearby marks."""

    def __init__(self, parent: QWidget | None = None, radius_px: int = 10) -> None:
        super().__init__(parent)
        self.radius_px = radius_px
        self.setMinimumSize(QSize(168, 168))
        self.setSizePolicy(QSizePolicy.Policy.Fixed, QSizePolicy.Policy.Fixed)
        self._rgb: np.ndarray | None = None
        self.centre: tuple[float, float] | None = None
        self._marks: dict[str, tuple[float, float]] = {}
        self._clicks: dict[str, tuple[float, float]] = {}
        self.setToolTip("Magnified view around the cursor")

    def sizeHint(self) -> QSize:  # noqa: N802 - Qt override
        return QSize(168, 168)

    def set_image(self, rgb: np.ndarray | None) -> None:
        self._rgb = rgb
        self.update()

    def set_marks(
        self,
        marks: dict[str, tuple[float, float]],
        clicks: dict[str, tuple[float, float]] | None = None,
    ) -> None:
        """Corners to draw, and the original clicks of snapped ones (white x)."""
        self._marks = dict(marks)
        self._clicks = dict(clicks or {})
        self.update()

    def set_centre(self, centre: tuple[float, float] | None) -> None:
        self.centre = centre
        self.update()

    def crop(self) -> tuple[np.ndarray, int, int] | None:
        """The pixels shown: ``(patch, first column, first row)``, padded black at the edges."""
        if self._rgb is None or self.centre is None:
            return None
        r = self.radius_px
        cu, cv = int(round(self.centre[0])), int(round(self.centre[1]))
        h, w = self._rgb.shape[:2]
        patch = np.zeros((2 * r + 1, 2 * r + 1, 3), np.uint8)
        r0, r1, c0, c1 = max(0, cv - r), min(h, cv + r + 1), max(0, cu - r), min(w, cu + r + 1)
        if r0 < r1 and c0 < c1:
            patch[r0 - (cv - r) : r1 - (cv - r), c0 - (cu - r) : c1 - (cu - r)] = self._rgb[
                r0:r1, c0:c1
            ]
        return patch, cu - r, cv - r

    def paintEvent(self, ev) -> None:  # noqa: N802 - Qt override
        p = QPainter(self)
        p.fillRect(self.rect(), QColor(20, 20, 20))
        got = self.crop()
        if got is None:
            p.setPen(QColor(160, 160, 160))
            p.drawText(self.rect(), Qt.AlignmentFlag.AlignCenter, "loupe\n(move over the frame)")
            p.end()
            return
        patch, x0, y0 = got
        n = patch.shape[0]
        img = QImage(np.ascontiguousarray(patch).data, n, n, 3 * n, QImage.Format.Format_RGB888)
        side = min(self.width(), self.height())
        s = side / n
        p.drawImage(QRectF(0, 0, side, side), img)

        def to_w(u: float, v: float) -> QPointF:
            return QPointF((u - x0 + 0.5) * s, (v - y0 + 0.5) * s)

        for name, (u, v) in self._marks.items():
            q = to_w(u, v)
            if 0 <= q.x() <= side and 0 <= q.y() <= side:
                p.setPen(QPen(QColor(255, 230, 0), 1.5))
                p.drawEllipse(q, 5, 5)
                p.drawText(q + QPointF(7, -7), name)
        p.setPen(QPen(QColor(255, 255, 255), 1.5))
        for u, v in self._clicks.values():
            q = to_w(u, v)
            p.drawLine(q + QPointF(-4, -4), q + QPointF(4, 4))
            p.drawLine(q + QPointF(-4, 4), q + QPointF(4, -4))
        c = to_w(*self.centre)
        p.setPen(QPen(QColor(255, 0, 255), 1))
        p.drawLine(QPointF(c.x(), 0), QPointF(c.x(), side))
        p.drawLine(QPointF(0, c.y()), QPointF(side, c.y()))
        p.setPen(QColor(230, 230, 230))
        p.drawText(
            QRectF(4, side - 18, side - 8, 16),
            Qt.AlignmentFlag.AlignLeft,
            f"({self.centre[0]:.1f}, {self.centre[1]:.1f})  x{s:.0f}",
        )
        p.end()
