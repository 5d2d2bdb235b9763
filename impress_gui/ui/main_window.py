"""The workstation window: Calibration, Processing and Viewer tabs, the motor panel in a dock,
the File menu (New, Open, Recent, Save, Save as, Quit), a status bar, and the unsaved-changes
prompt on close.

Tabs other than Calibration are looked up by module: ``impress_gui.ui.processing.tab`` must
define ``ProcessingTab`` and ``impress_gui.ui.viewer.tab`` ``ViewerTab``; until they exist a
labelled placeholder stands in. A tab class is constructed with whichever of the keyword
arguments ``messenger``, ``dialogs`` and ``parent`` it accepts, and may provide
``set_project(project)``, ``commit_to_project()``, ``project_updated()``, ``is_dirty()``,
``shutdown()`` and the signals ``changed()`` and ``status(str)``.
"""

from __future__ import annotations

import contextlib
import importlib
import inspect
import os
from pathlib import Path

from PySide6.QtCore import QSettings, Qt
from PySide6.QtGui import QAction, QCloseEvent, QKeySequence
from PySide6.QtWidgets import (
    QDialog,
    QDockWidget,
    QLabel,
    QMainWindow,
    QMessageBox,
    QTabWidget,
    QVBoxLayout,
    QWidget,
)

from impress_gui import __version__
from impress_gui.core.base.errors import ImpressError
from impress_gui.core.formats.video import VIDEO_SUFFIXES
from impress_gui.core.project.project import PROJECT_FILE, Project, describe_signatures
from impress_gui.core.reconstruction.compiled import prepare_in_background
from impress_gui.ui.calibration.tab import CalibrationTab
from impress_gui.ui.case_dialog import CaseDialog
from impress_gui.ui.messages import Dialogs, Messenger

MAX_RECENT = 8
OPTIONAL_TABS = (
    ("Processing", "impress_gui.ui.processing.tab", "ProcessingTab"),
    ("Viewer", "impress_gui.ui.viewer.tab", "ViewerTab"),
)
Button = QMessageBox.StandardButton


class PlaceholderTab(QWidget):
    def __init__(self, title: str, detail: str = "") -> None:
        super().__init__()
        box = QVBoxLayout(self)
        label = QLabel(
            f"<h2>{title}</h2><p>Coming soon: this part of the workstation is being "
            f"built.</p><p>{detail}</p>"
        )
        label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        label.setWordWrap(True)
        box.addWidget(label)
        self.is_placeholder = True


def make_tab(title: str, module: str, cls_name: str, **kwargs) -> QWidget:
    """The tab class from ``module`` if it is there, else a labelled placeholder."""
    try:
        cls = getattr(importlib.import_module(module), cls_name)
    except ModuleNotFoundError as exc:
        if exc.name != module:
            return PlaceholderTab(title, f"(it cannot start: {exc})")
        return PlaceholderTab(title)
    except (ImportError, AttributeError) as exc:
        return PlaceholderTab(title, f"(it cannot start: {exc})")
    params = inspect.signature(cls).parameters
    accepted = {k: v for k, v in kwargs.items() if k in params}
    return cls(**accepted)


class MainWindow(QMainWindow):
    def __init__(
        self,
        settings: QSettings,
        motor_panel: QWidget | None = None,
        dialogs: Dialogs | None = None,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self.motor_panel = motor_panel
        self._closing_done = False
        try:
            self._build(settings, motor_panel, dialogs)
        except BaseException:
            # the motor panel's worker thread (and any tab's) runs already: stop it before the
            # error goes on, or the thread object is destroyed running (Qt aborts the process)
            self._stop_started_work()
            raise

    def _build(
        self, settings: QSettings, motor_panel: QWidget | None, dialogs: Dialogs | None
    ) -> None:
        # compile the reconstruction kernels in a child process while the user works (the
        # first import would otherwise hold the GIL for seconds in a worker thread)
        prepare_in_background()
        self.settings = settings
        self.project = Project()
        self.dialogs = dialogs or Dialogs(self)
        self.messenger = Messenger(self, log=self._log)
        self.tabs = QTabWidget()
        self.setCentralWidget(self.tabs)
        self.calibration_tab = CalibrationTab(self.messenger, self.dialogs)
        self.tabs.addTab(self.calibration_tab, "Calibration")
        self.extra_tabs: dict[str, QWidget] = {}
        for title, module, cls_name in OPTIONAL_TABS:
            tab = make_tab(title, module, cls_name, messenger=self.messenger, dialogs=self.dialogs)
            self.extra_tabs[title] = tab
            self.tabs.addTab(tab, title)
        for tab in self.all_tabs():
            if hasattr(tab, "changed"):
                tab.changed.connect(self._update_title)
            if hasattr(tab, "status"):
                tab.status.connect(self.show_status)
        self.calibration_tab.calibrated.connect(self._on_calibrated)
        self.calibration_tab.video_changed.connect(lambda _p: self._update_title())
        self.motor_dock: QDockWidget | None = None
        if motor_panel is not None:
            self.motor_dock = QDockWidget("Motor", self)
            self.motor_dock.setObjectName("motor-dock")
            self.motor_dock.setWidget(motor_panel)
            self.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self.motor_dock)
            if hasattr(motor_panel, "error"):
                motor_panel.error.connect(
                    lambda code, msg: self._log("motor error", {"code": code, "message": msg})
                )
        self.project_label = QLabel()
        self.statusBar().addPermanentWidget(self.project_label)
        self._build_menus()
        self.set_project(Project())

    def _stop_started_work(self) -> None:
        """After a failure while the window was being built: stop what already runs."""
        tabs = [getattr(self, "calibration_tab", None), *getattr(self, "extra_tabs", {}).values()]
        for tab in tabs:
            if tab is not None and hasattr(tab, "shutdown"):
                with contextlib.suppress(Exception):
                    tab.shutdown()
        if self.motor_panel is not None and hasattr(self.motor_panel, "shutdown"):
            self.motor_panel.shutdown()
        self._closing_done = True

    # ----- construction -----------------------------------------------------------------------
    def _build_menus(self) -> None:
        m = self.menuBar().addMenu("&File")

        def act(menu, text, slot, shortcut=None, tip=""):
            a = QAction(text, self)
            if shortcut is not None:
                a.setShortcut(shortcut)
            a.setStatusTip(tip)
            a.triggered.connect(lambda _checked=False: slot())
            menu.addAction(a)
            return a

        self.new_action = act(
            m,
            "&New project...",
            self.new_project,
            QKeySequence.StandardKey.New,
            "Start a new case project",
        )
        self.open_action = act(
            m,
            "&Open project...",
            self.open_project,
            QKeySequence.StandardKey.Open,
            "Open a project folder",
        )
        self.recent_menu = m.addMenu("Open &recent")
        self.save_action = act(m, "&Save", self.save_project, QKeySequence.StandardKey.Save)
        self.save_as_action = act(
            m, "Save &as...", self.save_project_as, QKeySequence.StandardKey.SaveAs
        )
        m.addSeparator()
        act(
            m,
            "Open &video...",
            self.calibration_tab.load_video,
            None,
            "Add the scan video to this project",
        )
        act(m, "&Case details...", self.edit_case, None)
        act(
            m,
            "&Verify evidence and log",
            self.verify_integrity,
            None,
            "Re-hash the video and check the project log",
        )
        m.addSeparator()
        act(m, "&Quit", self.close, QKeySequence.StandardKey.Quit)
        view = self.menuBar().addMenu("&View")
        if self.motor_dock is not None:
            view.addAction(self.motor_dock.toggleViewAction())
        tools = self.menuBar().addMenu("&Tools")
        self.validation_action = act(
            tools,
            "Method &validation...",
            self.open_validation,
            None,
            "Run the thesis' accuracy protocol (table 4.1) and write a validation report",
        )
        helpm = self.menuBar().addMenu("&Help")
        act(
            helpm,
            "&About",
            lambda: self.messenger.info(
                "About IMPREsS",
                f"IMPREsS workstation {__version__}\n3D laser scanning of "
                "footwear and tire-track impressions.",
            ),
        )
        self._fill_recent()

    def open_validation(self):
        """Show the method-validation dialog (created on first use)."""
        from impress_gui.ui.validation_dialog import ValidationDialog

        if getattr(self, "validation_dialog", None) is None:
            self.validation_dialog = ValidationDialog(self.messenger, self.dialogs, self)
        self.validation_dialog.show()
        self.validation_dialog.raise_()
        return self.validation_dialog

    def all_tabs(self) -> list[QWidget]:
        return [self.calibration_tab, *self.extra_tabs.values()]

    # ----- state ----------------------------------------------------------------------------------
    def is_dirty(self) -> bool:
        return (
            self.project.dirty
            or self.calibration_tab.dirty
            or any(getattr(t, "is_dirty", lambda: False)() for t in self.extra_tabs.values())
        )

    def _update_title(self) -> None:
        self.setWindowTitle(f"IMPREsS - {self.project.title}[*]")
        self.setWindowModified(self.is_dirty())
        p = self.project
        self.project_label.setText(
            f"case {p.case_id or '-'} | evidence {p.evidence_id or '-'} | "
            f"{p.root if p.root else 'not saved yet'}"
        )

    def show_status(self, text: str) -> None:
        self.statusBar().showMessage(text, 15000)

    def _log(self, action: str, details: dict) -> None:
        self.project.log(action, details)

    def set_project(self, project: Project) -> None:
        self.project = project
        for tab in self.all_tabs():
            if hasattr(tab, "set_project"):
                tab.set_project(project)
        self._update_title()

    def _on_calibrated(self, _cal) -> None:
        for tab in self.extra_tabs.values():
            if hasattr(tab, "project_updated"):
                tab.project_updated()
        self._update_title()

    # ----- File menu --------------------------------------------------------------------------
    def maybe_save(self) -> bool:
        """Ask about unsaved changes; False when the user cancels."""
        if not self.is_dirty():
            return True
        answer = self.messenger.ask(
            "Unsaved changes",
            f"Save the changes to {self.project.title}?",
            Button.Save | Button.Discard | Button.Cancel,
            Button.Save,
        )
        if answer == Button.Save:
            return self.save_project()
        return answer == Button.Discard

    def ask_case_info(self, title: str = "New project") -> dict | None:
        dlg = CaseDialog(None, self, title)
        return dlg.values() if dlg.exec() == QDialog.DialogCode.Accepted else None

    def new_project(self, info: dict | None = None) -> bool:
        if not self.maybe_save():
            return False
        info = info if info is not None else self.ask_case_info()
        if info is None:
            return False
        project = Project(**{k: str(v) for k, v in info.items()})
        project.log("project started", {"case_id": project.case_id})
        self.set_project(project)
        self.show_status("New project: choose Save to give it a folder")
        return True

    def edit_case(self) -> None:
        dlg = CaseDialog(self.project, self, "Case details")
        if dlg.exec() == QDialog.DialogCode.Accepted:
            self.project.set_case_info(**dlg.values())
            self._update_title()

    def open_project(self, path: str | Path | None = None) -> bool:
        """Open a project folder. A damaged or tampered project is refused with its coded
        message and the window keeps the project it had; an unsigned (older) one opens with a
        warning; the key that signed it is named in the status bar."""
        if not self.maybe_save():
            return False
        path = path or self.dialogs.directory("Open a project folder")
        if not path:
            return False
        title = "Cannot open the project"
        try:
            project = Project.load(path)
            # every action is logged: a project whose log cannot be written is not opened
            project.log("project opened", {})
        except ImpressError as exc:
            self.messenger.exception(title, exc)
            return False
        except Exception:  # noqa: BLE001 - whatever the file holds, the window stays up
            self.messenger.error(
                title, f"{path}: the project cannot be read (an internal error)", "E-INTERNAL"
            )
            return False
        previous = self.project
        try:
            self.set_project(project)
        except Exception as exc:  # noqa: BLE001 - a tab refusing the project
            self.messenger.exception(title, exc)
            with contextlib.suppress(Exception):
                self.set_project(previous)
            return False
        self._add_recent(project.root)
        for text in project.warnings:
            self.messenger.warning("Unsigned project", text)
        info = project.signature_info()
        signed = describe_signatures(info).splitlines()[0]
        self.show_status(f"Opened {project.root}. {signed}")
        return True

    def open_path(self, path: str | Path) -> bool:
        """A project folder, a project.json or a video (opened in a new untitled project)."""
        p = Path(path)
        if os.path.isdir(p) or p.name == PROJECT_FILE:
            return self.open_project(p)
        if p.suffix.lower() in VIDEO_SUFFIXES or p.is_file():
            return self.calibration_tab.load_video(p)
        self.messenger.error(
            "Cannot open", f"{p}: no such project folder or video", "E-FILE-MISSING"
        )
        return False

    def save_project(self) -> bool:
        if self.project.root is None:
            return self.save_project_as()
        return self._save(None)

    def save_project_as(self, folder: str | Path | None = None) -> bool:
        folder = folder or self.dialogs.directory("Choose a new, empty folder for the project")
        if not folder:
            return False
        return self._save(Path(folder))

    def _save(self, folder: Path | None) -> bool:
        try:
            for tab in self.all_tabs():
                if hasattr(tab, "commit_to_project"):
                    tab.commit_to_project()
            path = self.project.save(folder)
        except (ImpressError, OSError) as exc:
            self.messenger.exception("The project was not saved", exc)
            return False
        self._add_recent(self.project.root)
        self._update_title()
        self.show_status(f"Saved {path}")
        return True

    def verify_integrity(self) -> bool:
        """Re-hash the evidence and check the saved record (signatures, log, links); report
        the outcome with who signed it."""
        p = self.project
        info = None
        try:
            if p.root is not None:
                info = p.verify()
            if p.video is not None:
                p.check_evidence()
        except ImpressError as exc:
            self.messenger.exception("Integrity check failed", exc)
            return False
        n = info["log_head"].get("entries", 0) if info else 0
        p.log("integrity verified", {"log_entries_at_last_save": n,
                                     "key_fingerprint": info and info["key_fingerprint"]})
        text = (
            f"The project file and the log's {n} entries up to the last save are intact"
            if info else "The project has not been saved yet"
        ) + (" and the video matches its SHA-256." if p.video else ".")
        if info:
            text += "\n\n" + describe_signatures(info)
        self.messenger.info("Integrity verified", text)
        return True

    # ----- recent projects ------------------------------------------------------------------------
    def recent_projects(self) -> list[str]:
        value = self.settings.value("recent_projects", [])
        if isinstance(value, str):
            value = [value]
        return [str(v) for v in (value or [])]

    def _add_recent(self, root: Path | None) -> None:
        if root is None:
            return
        items = [str(root)] + [r for r in self.recent_projects() if r != str(root)]
        self.settings.setValue("recent_projects", items[:MAX_RECENT])
        self.settings.sync()
        self._fill_recent()

    def _fill_recent(self) -> None:
        self.recent_menu.clear()
        items = self.recent_projects()
        for r in items:
            a = self.recent_menu.addAction(r)
            a.triggered.connect(lambda _checked=False, r=r: self.open_project(r))
        self.recent_menu.setEnabled(bool(items))

    # ----- closing ----------------------------------------------------------------------------------
    def closeEvent(self, event: QCloseEvent) -> None:  # noqa: N802 - Qt override
        if self._closing_done:
            event.accept()
            return
        if not self.maybe_save():
            event.ignore()
            return
        self.shutdown()
        event.accept()

    def shutdown(self) -> None:
        """Stop all background work, the motor, and close message boxes. Safe to call twice."""
        if self._closing_done:
            return
        self._closing_done = True
        for tab in self.all_tabs():
            if hasattr(tab, "shutdown"):
                tab.shutdown()
        if self.motor_panel is not None and hasattr(self.motor_panel, "current_settings"):
            from impress_gui.ui.motor.choices import save_motor_choices

            save_motor_choices(self.settings, self.motor_panel.current_settings())
        if self.motor_panel is not None and hasattr(self.motor_panel, "shutdown"):
            self.motor_panel.shutdown()
        if getattr(self, "validation_dialog", None) is not None:
            self.validation_dialog.shutdown()
        self.messenger.close_all()
        self.settings.sync()
