"""What the GUI tests share: the file choosers answered by the test, and the main window
opened (and closed again) on the offscreen platform, optionally on a reconstruction in its
viewer."""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path


class FakeDialogs:
    """File choosers answered by the test: set ``answer`` before the action ("" = the user
    cancelled). ``asked`` lists the choosers' titles, ``filters`` the file types they offered."""

    def __init__(self, answer: str = "") -> None:
        self.answer = answer
        self.asked: list[str] = []
        self.filters: list[str] = []

    def _ask(self, title: str, filters: str | None = None) -> str:
        self.asked.append(title)
        if filters is not None:
            self.filters.append(filters)
        return self.answer

    def open_file(self, title, filters, start=""):
        return self._ask(title, filters)

    def save_file(self, title, filters, start=""):
        return self._ask(title, filters)

    def directory(self, title, start=""):
        return self._ask(title)


@contextmanager
def main_window(qtbot, tmp_path: Path, size: tuple[int, int] | None = None):
    """The workstation's main window (its settings in ``tmp_path``, no motor panel), shown
    and exposed; shut down and closed afterwards."""
    from impress_gui.ui.app import build_main_window, make_settings

    w = build_main_window(make_settings(tmp_path / "settings.ini"), with_motor=False)
    try:
        if size is not None:
            w.resize(*size)
        w.show()
        qtbot.waitExposed(w)
        yield w
    finally:
        close_window(w)


def close_window(w) -> None:
    """Stop the window's background tasks, close its message boxes, shut it down (unsaved
    work is dropped without asking) and close it."""
    w.viewer_tab.tasks.shutdown()
    w.messenger.close_all()
    w.shutdown()
    w.close()
    w.deleteLater()


def open_in_viewer(qtbot, window, recon: Path, timeout_ms: int = 30000):
    """The window's viewer tab, current, showing the reconstruction folder ``recon`` (loaded,
    idle), its file choosers a :class:`FakeDialogs`."""
    v = window.viewer_tab
    window.tabs.setCurrentWidget(v)
    with qtbot.waitSignal(v.loaded, timeout=timeout_ms):
        v.open_reconstruction(recon)
    qtbot.waitUntil(lambda: not v.is_busy(), timeout=timeout_ms)
    v.actions.dialogs = FakeDialogs()
    return v
