"""A small drawing of the calibration target seen from the camera: the order of corners A-F,
which are marked, and which one to click next."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QPointF, QRectF, QSize, Qt
from PySide6.QtGui import QBrush, QColor, QPainter, QPen, QPolygonF
from PySide6.QtWidgets import QSizePolicy, QWidget

from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel


class TargetDiagram(QWidget):
    def __init__(self, target: TargetModel | None = None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.target = target
        self.marked: set[str] = set()
        self.next_name: str | None = "A"
        self.setMinimumSize(QSize(150, 150))
        self.setSizePolicy(QSizePolicy.Policy.Preferred, QSizePolicy.Policy.Fixed)
        self.setToolTip(
            "Corners of the L target as the camera sees it (scan direction up).\n"
            "Darker = higher step. Click the corners in this order: A, B, C, D, E, F."
        )

    def sizeHint(self) -> QSize:  # noqa: N802 - Qt override
        return QSize(220, 160)

    def set_target(self, target: TargetModel | None) -> None:
        self.target = target
        self.update()

    def set_state(self, marked: set[str], next_name: str | None) -> None:
        self.marked, self.next_name = set(marked), next_name
        self.update()

    def paintEvent(self, ev) -> None:  # noqa: N802 - Qt override
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        p.fillRect(self.rect(), self.palette().base())
        if self.target is None:
            p.drawText(self.rect(), Qt.AlignmentFlag.AlignCenter, "no target model")
            p.end()
            return
        corners = self.target.corner_array()
        faces = self.target.top_faces()
        xy = np.concatenate([corners[:, :2]] + [f.vertices_mm[:, :2] for f in faces])
        lo, hi = xy.min(0), xy.max(0)
        margin = 26.0
        scale = min(
            (self.width() - 2 * margin) / max(hi[0] - lo[0], 1e-9),
            (self.height() - 2 * margin) / max(hi[1] - lo[1], 1e-9),
        )

        def to_w(x: float, y: float) -> QPointF:  # y (scan direction) points up on screen
            return QPointF(
                margin + (x - lo[0]) * scale, self.height() - margin - (y - lo[1]) * scale
            )

        heights = [f.vertices_mm[0, 2] for f in faces]
        zmin, zmax = min(heights), max(heights)
        for face in sorted(faces, key=lambda f: f.vertices_mm[0, 2]):
            z = face.vertices_mm[0, 2]
            shade = 210 - int(90 * (z - zmin) / max(zmax - zmin, 1e-9))
            poly = QPolygonF([to_w(x, y) for x, y in face.vertices_mm[:, :2]])
            p.setBrush(QBrush(QColor(shade, shade, shade + 10)))
            p.setPen(QPen(QColor(60, 60, 60), 1))
            p.drawPolygon(poly)
            c = face.vertices_mm[:, :2].mean(0)
            p.setPen(QColor(40, 40, 40))
            p.drawText(
                QRectF(to_w(*c) - QPointF(30, 8), QSize(60, 16)),
                Qt.AlignmentFlag.AlignCenter,
                f"{z:g} mm",
            )
        p.setPen(QPen(QColor(80, 80, 80), 1, Qt.PenStyle.DashLine))
        arrow_x = self.width() - 10
        p.drawLine(QPointF(arrow_x, self.height() - margin), QPointF(arrow_x, margin))
        p.drawLine(QPointF(arrow_x, margin), QPointF(arrow_x - 4, margin + 8))
        p.drawLine(QPointF(arrow_x, margin), QPointF(arrow_x + 4, margin + 8))
        for name, (x, y, _z) in zip(CORNER_NAMES, corners):
            q = to_w(x, y)
            is_next = name == self.next_name
            if name in self.marked:
                p.setBrush(QBrush(QColor(255, 200, 0)))
            else:
                p.setBrush(QBrush(QColor(255, 255, 255)))
            p.setPen(
                QPen(QColor(220, 0, 200) if is_next else QColor(40, 40, 40), 3 if is_next else 1)
            )
            r = 9 if is_next else 6
            p.drawEllipse(q, r, r)
            off = QPointF(-20 if x <= (lo[0] + hi[0]) / 2 else 8, 16 if y <= lo[1] + 1 else -8)
            font = p.font()
            font.setBold(is_next)
            p.setFont(font)
            p.setPen(QColor(220, 0, 200) if is_next else self.palette().text().color())
            p.drawText(q + off, name)
        p.end()
