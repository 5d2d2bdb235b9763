"""The one contract for long work: a progress callback and a cancel token.

Core tasks take ``progress: ProgressCallback | None`` (fraction in [0, 1], message) and a
:class:`CancelToken`; they call :meth:`CancelToken.check` often and raise
:class:`~impress_gui.core.base.errors.Cancelled` when asked to stop.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from impress_gui.core.base.errors import Cancelled

ProgressCallback = Callable[[float, str], None]


class CancelToken:
    """Thread-safe cancellation flag shared between a task and whoever started it."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def cancel(self) -> None:
        self._event.set()

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        if self._event.is_set():
            raise Cancelled("cancelled by the user")


def sub_progress(
    progress: ProgressCallback | None, start: float, end: float
) -> ProgressCallback | None:
    """Map a stage's own 0..1 progress onto the slice ``[start, end]`` of the parent's range."""
    if progress is None:
        return None

    def _cb(fraction: float, message: str) -> None:
        progress(start + (end - start) * min(max(fraction, 0.0), 1.0), message)

    return _cb


def report(progress: ProgressCallback | None, fraction: float, message: str) -> None:
    if progress is not None:
        progress(fraction, message)
