"""User-facing messages: readable, non-blocking message boxes, also written to the project log.

One :class:`Messenger` is made by the application and passed to the widgets that report to the
user. Errors and warnings open a non-modal box (never a nested ``exec`` loop), so the GUI keeps
running and tests can read ``last_box.text()``. Questions
(:meth:`Messenger.ask`) need an answer and block; tests replace ``ask``.
"""

from __future__ import annotations

import html
from collections.abc import Callable

from PySide6.QtCore import QObject, Qt, Signal
from PySide6.QtWidgets import QMessageBox, QWidget

from impress_gui.core.base import codes
from impress_gui.core.base.errors import ImpressError

LogSink = Callable[[str, dict], None]
MAX_BOXES = 5
TRACEBACK_MARK = "\n\nTraceback"


class Messenger(QObject):
    """Shows messages and records them. ``shown(level, text)`` fires for each one."""

    shown = Signal(str, str)

    def __init__(self, parent_widget: QWidget | None = None, log: LogSink | None = None) -> None:
        super().__init__(parent_widget)
        self.parent_widget = parent_widget
        self.log = log
        self.boxes: list[QMessageBox] = []

    @property
    def last_box(self) -> QMessageBox | None:
        return self.boxes[-1] if self.boxes else None

    @property
    def last_text(self) -> str:
        """The last box's title and message, as plain text."""
        box = self.last_box
        return "" if box is None else f"{box.windowTitle()}\n{box.informativeText()}"

    def error(self, title: str, message: str, code: str = "", details: str = "") -> QMessageBox:
        """Report a failure; ``code`` (E-...) is shown so it can be looked up in the docs.
        A traceback after the message (internal errors) goes into the box's details."""
        if TRACEBACK_MARK in message and not details:
            message, details = message.split(TRACEBACK_MARK, 1)
            details = "Traceback" + details
        text = f"{message}\n\n[{code}]" if code else message
        if self.log is not None:
            self._log("error shown", {"title": title, "code": code, "message": message})
        return self._show(QMessageBox.Icon.Critical, "error", title, text, details)

    def exception(self, title: str, exc: BaseException) -> QMessageBox:
        code = exc.code if isinstance(exc, ImpressError) else codes.E_INTERNAL
        return self.error(title, str(exc) or type(exc).__name__, code)

    def warning(self, title: str, message: str) -> QMessageBox:
        if self.log is not None:
            self._log("warning shown", {"title": title, "message": message})
        return self._show(QMessageBox.Icon.Warning, "warning", title, message)

    def info(self, title: str, message: str) -> QMessageBox:
        return self._show(QMessageBox.Icon.Information, "info", title, message)

    def ask(
        self,
        title: str,
        message: str,
        buttons: QMessageBox.StandardButton = (
            QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No
        ),
        default: QMessageBox.StandardButton = QMessageBox.StandardButton.No,
    ) -> QMessageBox.StandardButton:
        """A question that needs an answer before going on (blocking)."""
        box = QMessageBox(QMessageBox.Icon.Question, title, message, buttons, self.parent_widget)
        box.setDefaultButton(default)
        return QMessageBox.StandardButton(box.exec())

    def close_all(self) -> None:
        for box in self.boxes:
            box.close()
            box.deleteLater()
        self.boxes.clear()

    def _log(self, action: str, details: dict) -> None:
        try:
            self.log(action, details)
        except (OSError, ImpressError):
            pass  # the message itself must still reach the user

    def _show(
        self, icon: QMessageBox.Icon, level: str, title: str, text: str, details: str = ""
    ) -> QMessageBox:
        box = QMessageBox(icon, title, "", QMessageBox.StandardButton.Ok, self.parent_widget)
        # the title is repeated as a heading: some window managers show no title bar
        box.setTextFormat(Qt.TextFormat.RichText)
        box.setText(f"<b>{html.escape(title)}</b>")
        box.setInformativeText(text)
        box.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        if details:
            box.setDetailedText(details)
        box.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose, False)
        box.finished.connect(lambda _r, b=box: self._forget(b))
        self.boxes.append(box)
        while len(self.boxes) > MAX_BOXES:
            old = self.boxes.pop(0)
            old.close()
            old.deleteLater()
        box.setWindowModality(Qt.WindowModality.NonModal)
        box.show()
        self.shown.emit(level, text)
        return box

    def _forget(self, box: QMessageBox) -> None:
        # keep the last one readable (tests, status); drop older closed boxes
        if box in self.boxes and box is not self.last_box:
            self.boxes.remove(box)
            box.deleteLater()


class Dialogs:
    """File choosers in one place, so tests (and scripted use) can replace them."""

    def __init__(self, parent: QWidget | None = None) -> None:
        self.parent = parent

    def open_file(self, title: str, filters: str, start: str = "") -> str:
        from PySide6.QtWidgets import QFileDialog

        return QFileDialog.getOpenFileName(self.parent, title, start, filters)[0]

    def save_file(self, title: str, filters: str, start: str = "") -> str:
        from PySide6.QtWidgets import QFileDialog

        return QFileDialog.getSaveFileName(self.parent, title, start, filters)[0]

    def directory(self, title: str, start: str = "") -> str:
        from PySide6.QtWidgets import QFileDialog

        return QFileDialog.getExistingDirectory(self.parent, title, start)
