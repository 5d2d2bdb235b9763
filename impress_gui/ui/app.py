"""Application start-up: the QApplication, global pyqtgraph options, and the object graph
(settings, motor panel, main window) built once here and passed in - no singletons.

A terminate signal (SIGTERM) or a closed terminal (SIGHUP) ends the window as closing it does,
motor first: the carriage is sent a stop, the window shuts down without asking questions, and
the process exits with status 128 + the signal's number."""

from __future__ import annotations

import signal
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import QSettings, QSocketNotifier, QTimer
from PySide6.QtGui import QGuiApplication
from PySide6.QtWidgets import QApplication, QMessageBox, QWidget

from impress_gui import __version__
from impress_gui.core.base import codes

ORGANISATION = "IMPREsS"
APPLICATION = "impress-workstation"


def create_app(argv: list[str] | None = None) -> QApplication:
    """The QApplication (reused when one exists), with pyqtgraph's options set once."""
    import pyqtgraph as pg

    from impress_gui.ui import pyside_fix

    pyside_fix.guard()
    app = QApplication.instance()
    if app is None:
        app = _new_application(list(argv if argv is not None else sys.argv[:1]))
    app.setOrganizationName(ORGANISATION)
    app.setApplicationName(APPLICATION)
    app.setApplicationVersion(__version__)
    pg.setConfigOptions(imageAxisOrder="row-major", antialias=True)
    return app


NO_DISPLAY_EXIT = 2


def _new_application(argv: list[str]) -> QApplication:
    """QApplication(argv), but when Qt cannot start its platform (no display, an X server it
    cannot reach, the X11 libraries missing) one coded line on stderr and exit status 2
    instead of Qt's abort (status 134): Qt reports that through its fatal message, which
    the handler installed while the application is made turns into ``E-DISPLAY``. Qt's
    other messages of those moments are passed on to stderr as Qt prints them."""
    import os

    from PySide6.QtCore import QtMsgType, qInstallMessageHandler

    said: list[str] = []

    def handler(mode, _context, message) -> None:
        if mode != QtMsgType.QtFatalMsg:
            said.append(str(message))
            return
        reasons = [m.strip() for m in said if m.strip()] or [str(message).splitlines()[0]]
        sys.stderr.write(
            f"impress: error [{codes.E_DISPLAY}]: the window cannot open: Qt found no display "
            f"it can use ({'; '.join(reasons)}). Start it in a desktop session; see "
            "docs/troubleshooting.md for the libraries Qt needs on Linux. Without a display, "
            "QT_QPA_PLATFORM=offscreen impress gui PROJECT --screenshot out.png --quit-after 1 "
            "makes a picture of the window.\n")
        sys.stderr.flush()
        os._exit(NO_DISPLAY_EXIT)  # Qt aborts when the handler returns

    previous = qInstallMessageHandler(handler)
    try:
        app = QApplication(argv)
    finally:
        qInstallMessageHandler(previous)
        for line in said:
            sys.stderr.write(line + "\n")
    return app


def make_settings(path: str | Path | None = None) -> QSettings:
    """Settings in an explicit INI file (tests, portable installs) or the user's config.

    A file Qt cannot read as INI would be overwritten with the defaults at the first change:
    an explicit one is refused (``E-FORMAT``, the file untouched); the user's own config is
    moved aside (``<name>.unreadable-<time>``, its bytes kept) with a warning on stderr, and
    the window starts with the defaults."""
    from impress_gui.core.base.errors import FormatError

    if path is not None:
        settings = QSettings(str(path), QSettings.Format.IniFormat)
        settings.allKeys()  # reads the file
        if settings.status() != QSettings.Status.NoError:
            raise FormatError(f"{path} is not a readable settings (INI) file: it is left as it "
                              "is; name another file or remove it", code=codes.E_FORMAT)
        return settings
    settings = QSettings(
        QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANISATION, APPLICATION
    )
    settings.allKeys()
    if settings.status() != QSettings.Status.NoError:
        bad = Path(settings.fileName())
        kept = bad.with_name(f"{bad.name}.unreadable-{time.strftime('%Y%m%d-%H%M%S')}")
        try:
            bad.rename(kept)
        except OSError as exc:
            raise FormatError(f"{bad} is not a readable settings (INI) file and cannot be "
                              f"moved aside ({exc.strerror}): it is left as it is; repair or "
                              "remove it", code=codes.E_FORMAT) from None
        print(f"impress: warning [W-SETTINGS]: {bad} was not a readable settings file: it is "
              f"kept as {kept.name}; starting with the default settings", file=sys.stderr)
        settings = QSettings(
            QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANISATION, APPLICATION
        )
    return settings


def build_main_window(
    settings: QSettings,
    with_motor: bool = True,
    port_lister: Callable[[], list[tuple[str, str]]] | None = None,
):
    """Assemble the window: its motor panel (driver in its own thread) and tabs."""
    from impress_gui.ui.main_window import MainWindow

    motor = None
    if with_motor:
        from impress_gui.ui.motor.choices import load_motor_choices
        from impress_gui.ui.motor.panel import MotorPanel

        motor = MotorPanel(settings=load_motor_choices(settings), port_lister=port_lister)
    return MainWindow(settings, motor_panel=motor)


#: the process signals that end the window (SIGHUP: its terminal was closed; not on Windows)
ENDING_SIGNALS: tuple[int, ...] = tuple(
    int(getattr(signal, name)) for name in ("SIGTERM", "SIGHUP") if hasattr(signal, name)
)


def on_process_signals(
    handler: Callable[[int], None], signals: tuple[int, ...] = ENDING_SIGNALS
) -> Callable[[], None]:
    """Call ``handler(signal_number)`` on the GUI thread when the process receives one of
    ``signals``; returns the function that puts the previous handlers back. A signal the
    process was told to ignore (``nohup`` ignores SIGHUP) stays ignored.

    Python runs its signal handlers only between Python instructions, and Qt's event loop may
    run no Python for a long time: the signal's number is written to a socket pair
    (:func:`signal.set_wakeup_fd`) that a :class:`QSocketNotifier` watches, so the handler runs
    within one turn of the event loop."""
    import socket

    reader, writer = socket.socketpair()
    for end in (reader, writer):
        end.setblocking(False)
    previous_fd = signal.set_wakeup_fd(writer.fileno(), warn_on_full_buffer=False)
    previous = {
        number: signal.signal(number, lambda *_: None)
        for number in signals
        if signal.getsignal(number) is not signal.SIG_IGN
    }
    notifier = QSocketNotifier(reader.fileno(), QSocketNotifier.Type.Read)

    def ready() -> None:
        try:
            data = reader.recv(256)
        except (BlockingIOError, InterruptedError):
            return
        for number in dict.fromkeys(data):  # once per signal, in order
            if number in previous:
                handler(number)

    notifier.activated.connect(ready)

    def restore() -> None:
        notifier.setEnabled(False)
        notifier.activated.disconnect(ready)
        for number, old in previous.items():
            signal.signal(number, old)
        signal.set_wakeup_fd(previous_fd)
        reader.close()
        writer.close()

    return restore


def stop_motor_and_shut_down(window) -> None:
    """What a terminate signal does to the window: send the motor a stop at once, then shut
    the window down (which closes the port, stopping the motor again, and joins its thread)
    without asking about unsaved changes."""
    panel = getattr(window, "motor_panel", None)
    if panel is not None and hasattr(panel, "stop"):
        panel.stop()
    window.shutdown()
    window.close()


def grab(window: QWidget):
    """A picture of the window: from the X server's framebuffer when there is one (so open
    message boxes are in it), else rendered by the widget."""
    app = QGuiApplication.instance()
    screen = window.screen() or QGuiApplication.primaryScreen()
    if app is not None and app.platformName() == "xcb" and screen is not None:
        g = window.frameGeometry()
        return screen.grabWindow(0, g.x(), g.y(), g.width(), g.height())
    return window.grab()


def _one_line(text: str) -> str:
    return " ".join(text.split())


class OpenCheck:
    """``impress gui --check``: everything the window reports while it opens a path.

    Collects every error box the window's messenger shows (including internal errors from
    slots), tabs that could not start, a path that did not open, and a project whose
    reconstruction the viewer does not show once loading has finished."""

    def __init__(self, window) -> None:
        self.window = window
        self.problems: list[str] = []
        self.expected_recon: Path | None = None
        window.messenger.shown.connect(self._on_shown)
        for box in list(window.messenger.boxes):  # shown while the window was being built
            if box.icon() == QMessageBox.Icon.Critical:
                self.problems.append(_one_line(f"{box.windowTitle()}: {box.informativeText()}"))
        for title, tab in getattr(window, "extra_tabs", {}).items():
            if getattr(tab, "is_placeholder", False):
                self.problems.append(f"the {title} tab cannot start")

    def _on_shown(self, level: str, text: str) -> None:
        box = self.window.messenger.last_box
        title = box.windowTitle() if box is not None else level
        if level == "error":
            self.problems.append(_one_line(f"{title}: {text}"))
        elif level == "warning":
            print(f"impress gui --check: warning: {_one_line(f'{title}: {text}')}",
                  file=sys.stderr)

    def opened(self, path: str | Path, ok: bool) -> None:
        """After ``window.open_path(path)``: note a refusal and what the viewer should show."""
        if not ok:
            if not self.problems:
                self.problems.append(f"{path}: not opened")
            return
        project = self.window.project
        if project.root is None:
            return  # a video, opened in a new untitled project
        recon_outputs = [o for o in project.outputs if o.get("kind") == "reconstruction"]
        if not recon_outputs:
            return
        try:
            from impress_gui.ui.viewer.tab import latest_reconstruction
        except ImportError as exc:
            self.problems.append(f"the viewer cannot start: {exc}")
            return
        self.expected_recon = latest_reconstruction(project)
        if self.expected_recon is None:
            where = recon_outputs[-1].get("relative_path") or recon_outputs[-1].get("path")
            self.problems.append(f"the project's reconstruction ({where}) is missing")

    def finished(self, still_busy: bool, timeout_s: float) -> None:
        """Loading is over (or timed out): does the viewer show the reconstruction?"""
        if still_busy:
            self.problems.append(f"still loading after {timeout_s:g} s")
            return
        if self.expected_recon is None:
            return
        viewer = getattr(self.window, "extra_tabs", {}).get("Viewer")
        data = getattr(viewer, "data", None)
        folder = getattr(data, "folder", None)
        if data is None or folder is None or Path(folder).resolve() != self.expected_recon.resolve():
            if not self.problems:  # the reason, when there is one, was shown as an error
                self.problems.append(
                    f"the viewer does not show the reconstruction {self.expected_recon}"
                )

    def report(self, path: str | Path | None) -> int:
        if self.problems:
            for problem in self.problems:
                print(f"impress gui --check: FAILED: {problem}", file=sys.stderr)
            return 1
        what = f"opened {path}" if path else "the window started"
        if self.expected_recon is not None:
            what += f"; the viewer shows {self.expected_recon}"
        print(f"check passed: {what}")
        return 0


def save_png(pixmap, path: str | Path) -> bool:
    """Write ``pixmap`` as a PNG file at ``path`` atomically (encoded in memory, then a
    temporary file renamed into place: a failed write leaves what was there); False with the
    reason on stderr when it cannot be written."""
    from PySide6.QtCore import QBuffer, QByteArray, QIODevice

    from impress_gui.core.base.errors import ImpressError
    from impress_gui.core.base.fileio import atomic_write_bytes

    data = QByteArray()
    buf = QBuffer(data)
    buf.open(QIODevice.OpenModeFlag.WriteOnly)
    ok = pixmap.save(buf, "PNG")
    buf.close()
    if not ok:
        print(f"impress gui: error [{codes.E_WRITE}]: the picture for {path} could not be made",
              file=sys.stderr)
        return False
    try:
        atomic_write_bytes(path, bytes(data))
    except ImpressError as exc:
        print(f"impress gui: error [{exc.code}]: {exc}", file=sys.stderr)
        return False
    return True


#: the window's size on a screen that holds it, when none was saved
DEFAULT_SIZE = (1920, 1080)


def place_window(window, settings: QSettings, size: tuple[int, int] | None) -> bool:
    """Size ``window`` before it is shown: ``size`` when given (screenshots, tests); else
    where the user left it last time (``window/geometry`` and the docks' ``window/state``,
    saved when the window closes; Qt keeps a restored window on a screen that is there);
    else :data:`DEFAULT_SIZE`, cut to the screen's free area (a laptop's 1366x768 less its
    panels). True: show it maximized (the default size did not fit)."""
    if size is not None:
        window.resize(*size)
        return False
    geometry = settings.value("window/geometry")
    if geometry is not None and window.restoreGeometry(geometry):
        state = settings.value("window/state")
        if state is not None:
            window.restoreState(state)
        return False
    screen = window.screen() or QGuiApplication.primaryScreen()
    free = screen.availableGeometry() if screen is not None else None
    if QGuiApplication.platformName() in ("offscreen", "minimal"):
        free = None  # no one's screen: a picture of the window at the default size
    w, h = DEFAULT_SIZE
    if free is None or (w <= free.width() and h <= free.height()):
        window.resize(w, h)
        return False
    window.resize(min(w, free.width()), min(h, free.height()))
    window.move(free.topLeft())
    return True


def run_gui(
    path: str | Path | None = None,
    screenshot: str | Path | None = None,
    quit_after_s: float | None = None,
    size: tuple[int, int] | None = None,
    settings_path: str | Path | None = None,
    with_motor: bool = True,
    tab: str | None = None,
    check: bool = False,
    check_timeout_s: float = 120.0,
) -> int:
    """Show the window (on ``path`` if given). ``check``: wait until the path and what it
    holds (the viewer's reconstruction) have loaded, then close; exit status 1 with the
    reasons on stderr if anything failed to open or an error message was shown, else 0."""
    app = create_app()
    scratch = None
    if check and settings_path is None:
        scratch, settings_path = _scratch_settings()
    try:
        return _run_window(app, path, screenshot, quit_after_s, size, make_settings(settings_path),
                           with_motor, tab, check, check_timeout_s)
    finally:
        if scratch is not None:
            scratch.cleanup()


def _scratch_settings():
    """A check (``--check`` without ``--settings``) must not change the user's configuration
    (window geometry, recent files): it runs on a copy of it in a temporary folder, removed
    afterwards; an unreadable configuration is neither copied nor moved aside."""
    import shutil
    import tempfile

    scratch = tempfile.TemporaryDirectory(prefix="impress-check-")
    copy = Path(scratch.name) / "settings.ini"
    user = QSettings(QSettings.Format.IniFormat, QSettings.Scope.UserScope, ORGANISATION,
                     APPLICATION)
    user.allKeys()
    source = Path(user.fileName())
    if user.status() == QSettings.Status.NoError and source.is_file():
        try:
            shutil.copyfile(source, copy)
        except OSError:
            pass
    return scratch, copy


def _run_window(app, path, screenshot, quit_after_s, size, settings, with_motor, tab, check,
                check_timeout_s) -> int:
    window = build_main_window(settings, with_motor=with_motor)
    if place_window(window, settings, size):
        window.showMaximized()
    else:
        window.show()
    checker = OpenCheck(window) if check else None
    previous_hook = sys.excepthook

    def report_bug(kind, value, tb) -> None:
        # a bug in a slot must reach the user as a message (and the log), not only the console
        previous_hook(kind, value, tb)
        text = "".join(traceback.format_exception(kind, value, tb, limit=8))
        window.messenger.error("Internal error", f"internal error: {value!r}", codes.E_INTERNAL, text)

    sys.excepthook = report_bug
    result = {"code": 0}

    def ended_by_signal(number: int) -> None:
        name = signal.Signals(number).name
        print(f"impress gui: {name} received: stopping the motor and closing the window",
              file=sys.stderr)
        result["code"] = 128 + number
        stop_motor_and_shut_down(window)
        app.quit()

    restore_signals = on_process_signals(ended_by_signal)
    if path:
        ok = window.open_path(path)
        if checker is not None:
            checker.opened(path, ok)
    if tab:
        for i in range(window.tabs.count()):
            if window.tabs.tabText(i).lower() == tab.lower():
                window.tabs.setCurrentIndex(i)
    deadline = time.monotonic() + check_timeout_s

    def finish() -> None:
        # a video is still being opened and checked, or a map still loading
        busy = any(getattr(t, "is_busy", lambda: False)() for t in window.all_tabs())
        if busy and (checker is None or time.monotonic() < deadline):
            QTimer.singleShot(200, finish)
            return
        if checker is not None:
            app.processEvents()  # deliver what the last task reported
            checker.finished(busy, check_timeout_s)
        if screenshot:
            app.processEvents()
            if save_png(grab(window), screenshot):
                print(f"screenshot written to {screenshot}")
            else:
                result["code"] = 1
        if checker is not None:
            result["code"] = checker.report(path) or result["code"]
        if quit_after_s is not None or checker is not None:
            window.shutdown()
            window.close()
            app.quit()

    if screenshot or quit_after_s is not None or checker is not None:
        first = quit_after_s if quit_after_s is not None else (0.2 if checker else 0.5)
        QTimer.singleShot(int(1000 * first), finish)
    try:
        code = app.exec()
    finally:
        sys.excepthook = previous_hook
        restore_signals()
    window.shutdown()
    return result["code"] or int(code)
