"""Small widgets shared by the window's panels."""

from __future__ import annotations

from PySide6.QtCore import QSize, Qt
from PySide6.QtGui import QPainter
from PySide6.QtWidgets import QLabel, QScrollArea, QWidget


class ElidedLabel(QLabel):
    """A one-line label that gives way on a narrow window: its text is shortened in the middle
    (a long project path keeps its start and its end) where it does not fit, the whole of it
    in the tooltip. A plain QLabel asks for its whole text's width: a deep project folder in
    the status bar, or a long progress message, made the window wider than a laptop's screen
    (and a window does not narrow again by itself)."""

    def setText(self, text: str) -> None:  # noqa: N802 - Qt override
        super().setText(text)
        self.setToolTip(text)

    def minimumSizeHint(self) -> QSize:  # noqa: N802 - Qt override
        return QSize(min(super().minimumSizeHint().width(), 80), super().minimumSizeHint().height())

    def paintEvent(self, event) -> None:  # noqa: N802 - Qt override
        painter = QPainter(self)
        rect = self.contentsRect()
        shown = self.fontMetrics().elidedText(self.text(), Qt.TextElideMode.ElideMiddle,
                                              rect.width())
        painter.drawText(rect, int(self.alignment()), shown)


class SidePanelScroll(QScrollArea):
    """A tab's side panels in a scroll area that scrolls only vertically and is never
    narrower than its panels need: its (minimum) width is the panels' minimum width plus the
    vertical scroll bar and the frame (and at least ``min_width``), so nothing is cut off at
    the right (the panels were 440 px wide in a 414 px viewport at 1920x1080: the step's
    uncertainty line, the spin boxes' arrows and the group boxes' right edges were
    clipped)."""

    def __init__(self, panel: QWidget, min_width: int = 430,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.min_width = min_width
        self.setWidget(panel)
        self.setWidgetResizable(True)
        self.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)

    def _chrome(self) -> int:
        """What the scroll area takes of its width besides the panel."""
        return self.verticalScrollBar().sizeHint().width() + 2 * self.frameWidth()

    def minimumSizeHint(self) -> QSize:
        hint = super().minimumSizeHint()
        w = self.widget()
        need = 0 if w is None else w.minimumSizeHint().width() + self._chrome()
        return QSize(max(hint.width(), self.min_width, need), hint.height())

    def sizeHint(self) -> QSize:
        hint = super().sizeHint()
        return QSize(max(hint.width(), self.minimumSizeHint().width()), hint.height())
