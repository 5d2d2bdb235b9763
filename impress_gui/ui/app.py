"""Application start-up: the QApplication, global pyqtgraph options, and the object graph
(settings, motor panel, main window) built once here and passed in - no singletons."""

from __future__ import annotations

import sys
import traceback
from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import QSettings, QTimer
from PySide6.QtGui import QGuiApplication
from PySide6.QtWidgets import QApplication, QWidget

from impress_gui import __version__

ORGANISATION = "IMPREsS"
APPLICATION = "impress-workstation"


def create_app(argv: list[str] | None = None) -> QApplication:
    """The QApplication (reused when one exists), with pyqtgraph's options set once."""
    import pyqtgraph as pg

    from impress_gui.ui import pyside_fix

    pyside_fix.guard()
    app = QApplication.instance()
    if app is None:
        app = QApplication(list(argv if argv is not None else sys.argv[:1]))
    app.setOrganizationName(ORGANISATION)
    app.setApplicationName(APPLICATION)
    app.setApplicationVersion(__version__)
    pg.setConfigOptions(imageAxisOrder="row-major", antialias=True)
    return app


def make_settings(path: str | Path | None = None) -> QSettings:
    """Settings in an explicit INI file (tests, portable installs) or the user's config."""
    if path is not None:
        return QSettings(str(path), QSettings.Format.IniFormat)
    return QSettings(
        QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANISATION, APPLICATION
    )


def build_main_window(
    settings: QSettings,
    with_motor: bool = True,
    port_lister: Callable[[], list[tuple[str, str]]] | None = None,
):
    """Assemble the window: its motor panel (driver in its own thread) and tabs."""
    from impress_gui.ui.main_window import MainWindow

    motor = None
    if with_motor:
        from impress_gui.ui.motor_panel import MotorPanel

        motor = MotorPanel(port_lister=port_lister)
    return MainWindow(settings, motor_panel=motor)


def grab(window: QWidget):
    """A picture of the window: from the X server's framebuffer when there is one (so open
    message boxes are in it), else rendered by the widget."""
    app = QGuiApplication.instance()
    screen = window.screen() or QGuiApplication.primaryScreen()
    if app is not None and app.platformName() == "xcb" and screen is not None:
        g = window.frameGeometry()
        return screen.grabWindow(0, g.x(), g.y(), g.width(), g.height())
    return window.grab()


def run_gui(
    path: str | Path | None = None,
    screenshot: str | Path | None = None,
    quit_after_s: float | None = None,
    size: tuple[int, int] = (1920, 1080),
    settings_path: str | Path | None = None,
    with_motor: bool = True,
    tab: str | None = None,
) -> int:
    app = create_app()
    window = build_main_window(make_settings(settings_path), with_motor=with_motor)
    window.resize(*size)
    window.show()
    previous_hook = sys.excepthook

    def report_bug(kind, value, tb) -> None:
        # a bug in a slot must reach the user as a message (and the log), not only the console
        previous_hook(kind, value, tb)
        text = "".join(traceback.format_exception(kind, value, tb, limit=8))
        window.messenger.error("Internal error", f"internal error: {value!r}", "E-INTERNAL", text)

    sys.excepthook = report_bug
    if path:
        window.open_path(path)
    if tab:
        for i in range(window.tabs.count()):
            if window.tabs.tabText(i).lower() == tab.lower():
                window.tabs.setCurrentIndex(i)
    result = {"code": 0}

    def finish() -> None:
        # a video is still being opened and checked, or a map still loading
        if any(getattr(t, "is_busy", lambda: False)() for t in window.all_tabs()):
            QTimer.singleShot(200, finish)
            return
        if screenshot:
            app.processEvents()
            if not grab(window).save(str(screenshot)):
                print(f"impress gui: cannot write {screenshot}", file=sys.stderr)
                result["code"] = 1
            else:
                print(f"screenshot written to {screenshot}")
        if quit_after_s is not None:
            window.shutdown()
            window.close()
            app.quit()

    if screenshot or quit_after_s is not None:
        QTimer.singleShot(int(1000 * (quit_after_s or 0.5)), finish)
    try:
        code = app.exec()
    finally:
        sys.excepthook = previous_hook
    window.shutdown()
    return result["code"] or int(code)
