"""Small widgets shared by the window's panels."""

from __future__ import annotations

from PySide6.QtCore import QSize, Qt
from PySide6.QtGui import QPainter
from PySide6.QtWidgets import QLabel


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
