"""A progress line with a Cancel button that runs one long core task at a time through the
:class:`~impress_gui.ui.worker.Worker` and routes its outcome: the result to a callback, a
failure to a readable message box (and the project log), a cancel to the status line."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from PySide6.QtCore import Signal
from PySide6.QtWidgets import QHBoxLayout, QProgressBar, QPushButton, QWidget

from impress_gui.core.base.errors import ImpressError
from impress_gui.ui.common_widgets import ElidedLabel
from impress_gui.ui.messages import Messenger
from impress_gui.ui.worker import Task, Worker


class TaskBar(QWidget):
    busy_changed = Signal(bool)
    status = Signal(str)
    done = Signal(str, str)  # what, outcome ("finished", "failed", "cancelled")

    def __init__(
        self, messenger: Messenger, parent: QWidget | None = None, name: str = "task"
    ) -> None:
        super().__init__(parent)
        self.messenger = messenger
        self.worker = Worker(self, name=name)
        self.worker.progress.connect(self._on_progress)
        self.worker.finished.connect(self._on_finished)
        self.worker.failed.connect(self._on_failed)
        self.worker.cancelled.connect(self._on_cancelled)
        self._pending: tuple[str, Callable[[Any], None], str] | None = None
        row = QHBoxLayout(self)
        row.setContentsMargins(0, 0, 0, 0)
        self.label = ElidedLabel("")  # a long message shortened, not the window widened
        self.bar = QProgressBar()
        self.bar.setRange(0, 1000)
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setToolTip("Stop this operation; nothing is changed")
        self.cancel_button.clicked.connect(self.cancel)
        row.addWidget(self.label)
        row.addWidget(self.bar, 1)
        row.addWidget(self.cancel_button)
        self.hide()

    @property
    def what(self) -> str:
        return self._pending[0] if self._pending else ""

    def is_busy(self) -> bool:
        return self._pending is not None

    def run(self, what: str, fn: Task, on_done: Callable[[Any], None], fail_title: str) -> bool:
        """Start ``fn(progress, cancel)``; refused (with a note) while another task runs."""
        if self._pending is not None:
            self.messenger.info("Busy", f"Wait for '{self.what}' to finish, or cancel it.")
            return False
        self._pending = (what, on_done, fail_title)
        self.label.setText(what)
        self.bar.setValue(0)
        self.show()
        self.worker.start(fn)
        self.busy_changed.emit(True)
        self.status.emit(f"{what}...")
        return True

    def cancel(self) -> None:
        self.worker.cancel()

    def shutdown(self) -> None:
        """Cancel and join the running task without delivering its outcome."""
        if self._pending is not None:
            self.worker.shutdown()
            self._end()

    def _end(self) -> tuple[str, Callable[[Any], None], str]:
        pending, self._pending = self._pending, None
        self.hide()
        self.busy_changed.emit(False)
        return pending

    def _on_progress(self, fraction: float, message: str) -> None:
        self.bar.setValue(int(1000 * max(0.0, min(1.0, fraction))))
        self.label.setText(f"{self.what}: {message}")

    def _on_finished(self, result: Any) -> None:
        what, on_done, fail_title = self._end()
        try:
            on_done(result)
        except ImpressError as exc:
            self.messenger.exception(fail_title, exc)
            self.done.emit(what, "failed")
            return
        self.done.emit(what, "finished")

    def _on_failed(self, code: str, message: str) -> None:
        what, _on_done, fail_title = self._end()
        self.messenger.error(fail_title, message, code)
        self.status.emit(f"{what}: failed [{code}]")
        self.done.emit(what, "failed")

    def _on_cancelled(self) -> None:
        what, *_ = self._end()
        self.status.emit(f"{what}: cancelled; nothing was changed")
        self.done.emit(what, "cancelled")
