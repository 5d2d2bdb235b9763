"""The one adapter that runs long core work off the GUI thread.

A core task is a callable ``fn(progress, cancel) -> result`` following the core's contract
(:mod:`impress_gui.core.base.progress`): it reports ``progress(fraction, message)``, checks the
:class:`CancelToken` and raises :class:`Cancelled` when asked to stop.

:class:`Worker` runs one such task on its own ``QThread`` and reports on the GUI thread with the
signals ``progress(float, str)``, ``finished(object)``, ``failed(str code, str message)`` and
``cancelled()``. Exactly one of the last three is emitted per run, after the thread has ended,
so a receiver never sees a thread still running. :class:`LatestOnly` runs interactive
recomputations: a new request supersedes (cancels and silences) the one still running.
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QObject, QThread, Signal

from impress_gui.core.base import codes
from impress_gui.core.base.errors import Cancelled, ImpressError
from impress_gui.core.base.progress import CancelToken, ProgressCallback

Task = Callable[[ProgressCallback, CancelToken], Any]
PROGRESS_INTERVAL_S = 0.05


class _Runner(QThread):
    progressed = Signal(float, str)

    def __init__(self, fn: Task, token: CancelToken, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._fn, self._token = fn, token
        self.outcome: tuple[str, Any] = ("cancelled", None)
        self._last = 0.0

    def _progress(self, fraction: float, message: str) -> None:
        now = time.monotonic()
        if fraction >= 1.0 or now - self._last >= PROGRESS_INTERVAL_S:
            self._last = now
            self.progressed.emit(float(fraction), str(message))

    def run(self) -> None:
        try:
            result = self._fn(self._progress, self._token)
        except Cancelled:
            self.outcome = ("cancelled", None)
        except ImpressError as exc:
            self.outcome = ("failed", (exc.code, str(exc)))
        except MemoryError:
            self.outcome = ("failed", (codes.E_MEMORY, "not enough memory for this operation"))
        except Exception as exc:  # noqa: BLE001 - a bug must reach the user, not kill the thread
            tb = traceback.format_exc(limit=6)
            self.outcome = ("failed", (codes.E_INTERNAL, f"internal error: {exc!r}\n\n{tb}"))
        else:
            self.outcome = ("cancelled", None) if self._token.cancelled else ("finished", result)


class Worker(QObject):
    """Run one core task at a time on a worker thread; see the module docstring."""

    progress = Signal(float, str)
    finished = Signal(object)
    failed = Signal(str, str)
    cancelled = Signal()

    def __init__(
        self, fn: Task | None = None, parent: QObject | None = None, name: str = ""
    ) -> None:
        super().__init__(parent)
        self._fn = fn
        self.name = name
        self._runner: _Runner | None = None
        self._token = CancelToken()

    def is_running(self) -> bool:
        return self._runner is not None

    def start(self, fn: Task | None = None) -> None:
        """Start ``fn`` (or the task given at construction). Refused while one is running."""
        if self._runner is not None:
            raise RuntimeError(f"{self.name or 'worker'} is already running")
        fn = fn or self._fn
        if fn is None:
            raise RuntimeError("no task to run")
        self._token = CancelToken()
        runner = _Runner(fn, self._token, self)
        runner.setObjectName(f"impress-{self.name or 'worker'}")
        runner.progressed.connect(self.progress)
        runner.finished.connect(self._on_thread_finished)
        self._runner = runner
        runner.start()

    def cancel(self) -> None:
        """Ask the running task to stop; ``cancelled`` follows when it has."""
        self._token.cancel()

    def wait(self, timeout_ms: int = 30_000) -> bool:
        """Block until the thread ends (shutdown only; the signal still follows)."""
        return self._runner is None or self._runner.wait(timeout_ms)

    def shutdown(self, timeout_ms: int = 30_000) -> None:
        """Cancel and join; emit nothing more. Safe to call twice."""
        runner = self._runner
        if runner is None:
            return
        self._token.cancel()
        runner.wait(timeout_ms)
        runner.finished.disconnect(self._on_thread_finished)
        runner.progressed.disconnect(self.progress)
        self._runner = None
        runner.deleteLater()

    def _on_thread_finished(self) -> None:
        runner = self._runner
        if runner is None:
            return
        runner.wait()
        self._runner = None
        kind, value = runner.outcome
        runner.deleteLater()
        if kind == "finished":
            self.finished.emit(value)
        elif kind == "failed":
            self.failed.emit(*value)
        else:
            self.cancelled.emit()


class LatestOnly(QObject):
    """Interactive recomputation: each :meth:`submit` supersedes the previous request; only the
    newest request's result is delivered (``finished``/``failed``)."""

    finished = Signal(object)
    failed = Signal(str, str)

    def __init__(self, parent: QObject | None = None, name: str = "latest") -> None:
        super().__init__(parent)
        self.name = name
        self._current: Worker | None = None
        self._stale: list[Worker] = []

    def submit(self, fn: Task) -> None:
        if self._current is not None:
            old = self._current
            old.cancel()
            old.finished.disconnect(self.finished)
            old.failed.disconnect(self.failed)
            self._stale.append(old)
        w = Worker(fn, self, self.name)
        w.finished.connect(self.finished)
        w.failed.connect(self.failed)
        for sig in (w.finished, w.failed, w.cancelled):
            sig.connect(lambda *_, w=w: self._done(w))
        self._current = w
        w.start()

    def is_running(self) -> bool:
        return self._current is not None or bool(self._stale)

    def _done(self, w: Worker) -> None:
        if w is self._current:
            self._current = None
        elif w in self._stale:
            self._stale.remove(w)
        w.deleteLater()

    def shutdown(self) -> None:
        for w in [*self._stale, *([self._current] if self._current else [])]:
            w.shutdown()
        self._stale.clear()
        self._current = None
