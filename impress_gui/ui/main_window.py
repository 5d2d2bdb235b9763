"""The workstation window: Calibration, Processing and Viewer tabs over one working session
(:class:`~impress_gui.session.session.Session`), the motor panel in a dock, the File menu (New,
Open, Recent, Save, Save as, Quit), a status bar, and the unsaved-changes prompt on close.

The window owns the session and hands it to each tab; the tabs follow the session's signals
(a project opened, the evidence video, the calibration, a reconstruction made), so the window
broadcasts nothing and no tab reaches into another. Every tab offers the same small interface
(:class:`Tab`).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path
from typing import Protocol

from PySide6.QtCore import QSettings, Qt, SignalInstance
from PySide6.QtGui import QAction, QCloseEvent, QKeySequence
from PySide6.QtWidgets import (
    QDialog,
    QDockWidget,
    QMainWindow,
    QMessageBox,
    QTabWidget,
    QWidget,
)

from impress_gui import __version__
from impress_gui.core.base import codes
from impress_gui.core.base.errors import ImpressError
from impress_gui.core.formats.video import VIDEO_SUFFIXES
from impress_gui.core.project.project import PROJECT_FILE, Project, describe_signatures
from impress_gui.core.reconstruction.compiled import prepare_in_background
from impress_gui.session.session import Session
from impress_gui.ui.calibration.tab import CalibrationTab
from impress_gui.ui.case_dialog import CaseDialog
from impress_gui.ui.common_widgets import ElidedLabel
from impress_gui.ui.compare.panel import ComparePanel
from impress_gui.ui.messages import Dialogs, Messenger
from impress_gui.ui.motor.panel import MotorPanel
from impress_gui.ui.processing.tab import ProcessingTab
from impress_gui.ui.viewer.tab import ViewerTab

MAX_RECENT = 8
Button = QMessageBox.StandardButton


class Tab(Protocol):
    """What the window asks of each tab (besides being a QWidget built over the session)."""

    changed: SignalInstance  # something the project keeps changed
    status: SignalInstance  # a line for the status bar

    def commit_to_project(self) -> None: ...  # copy what the tab holds into the project
    def is_dirty(self) -> bool: ...  # holds changes not yet in the project
    def shutdown(self) -> None: ...  # stop its background work (safe twice)


class MainWindow(QMainWindow):
    def __init__(
        self,
        settings: QSettings,
        motor_panel: MotorPanel | None = None,
        dialogs: Dialogs | None = None,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self.motor_panel = motor_panel
        self.validation_dialog = None
        self._closing_done = False
        self._tabs: list = []
        self.session = Session()
        try:
            self._build(settings, motor_panel, dialogs)
        except BaseException:
            # the motor panel's worker thread (and any tab's) runs already: stop it before the
            # error goes on, or the thread object is destroyed running (Qt aborts the process)
            self._stop_started_work()
            raise

    def _build(
        self, settings: QSettings, motor_panel: MotorPanel | None, dialogs: Dialogs | None
    ) -> None:
        # compile the reconstruction kernels in a child process while the user works (the
        # first import would otherwise hold the GIL for seconds in a worker thread)
        prepare_in_background()
        self.settings = settings
        self.dialogs = dialogs or Dialogs(self)
        self.messenger = Messenger(self, log=self._log)
        self.tabs = QTabWidget()
        self.setCentralWidget(self.tabs)
        s = self.session
        self.calibration_tab = CalibrationTab(self.messenger, self.dialogs, settings=settings,
                                              session=s)
        self._tabs.append(self.calibration_tab)
        self.processing_tab = ProcessingTab(messenger=self.messenger, dialogs=self.dialogs,
                                            session=s)
        self._tabs.append(self.processing_tab)
        self.viewer_tab = ViewerTab(messenger=self.messenger, dialogs=self.dialogs, session=s)
        self._tabs.append(self.viewer_tab)
        self.compare_tab = ComparePanel(session=s)
        self._tabs.append(self.compare_tab)
        # the tabs after the first, by title
        self.extra_tabs: dict[str, QWidget] = {"Processing": self.processing_tab,
                                               "Viewer": self.viewer_tab,
                                               "Compare": self.compare_tab}
        for title, tab in (("Calibration", self.calibration_tab), *self.extra_tabs.items()):
            self.tabs.addTab(tab, title)
            tab.changed.connect(self._update_title)
            tab.status.connect(self.show_status)
        s.changed.connect(self._update_title)
        s.status.connect(self.show_status)
        s.evidence_changed.connect(lambda _e: self._update_title())
        self._front_on_load = False
        s.reconstruction_added.connect(self._on_reconstruction_added)
        self.viewer_tab.loaded.connect(self._on_viewer_loaded)
        self.motor_dock: QDockWidget | None = None
        if motor_panel is not None:
            self.motor_dock = QDockWidget("Motor", self)
            self.motor_dock.setObjectName("motor-dock")
            self.motor_dock.setWidget(motor_panel)
            self.addDockWidget(Qt.DockWidgetArea.RightDockWidgetArea, self.motor_dock)
            motor_panel.error.connect(
                lambda code, msg: self._log("motor error", {"code": code, "message": msg})
            )
        self.project_label = ElidedLabel()
        self.statusBar().addPermanentWidget(self.project_label)
        self._build_menus()
        self.set_project(Project())

    @property
    def project(self) -> Project:
        return self.session.project

    def _stop_started_work(self) -> None:
        """After a failure while the window was being built: stop what already runs."""
        for tab in self._tabs:
            with contextlib.suppress(Exception):
                tab.shutdown()
        if self.motor_panel is not None:
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
        export = m.addMenu("&Export")
        # the viewer's digital cast (its own action: enabled with the viewer's exports)
        export.addAction(self.viewer_tab.cast_action)
        m.addSeparator()
        act(m, "&Quit", self.close, QKeySequence.StandardKey.Quit)
        self._build_edit_menu(act)
        view = self.menuBar().addMenu("&View")
        self.side_action = act(
            view, "Heightmap and texture &side by side", self.toggle_side_by_side,
            QKeySequence("S"), "Viewer: the texture beside the map, pan, zoom and cursor linked",
        )
        self.side_action.setCheckable(True)
        self.viewer_tab.side_by_side_changed.connect(self.side_action.setChecked)
        if self.motor_dock is not None:
            view.addAction(self.motor_dock.toggleViewAction())
        self._build_measure_menu(act)
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

    def _build_edit_menu(self, act) -> None:
        """Edit > Undo / Redo of the viewer's edits (measurements, annotations, levelling),
        named after the step they undo; active while the viewer is in front (the calibration
        tab's corners have their own undo under the same keys)."""
        menu = self.menuBar().addMenu("&Edit")
        stack = self.viewer_tab.undo_stack
        self.undo_action = act(menu, "&Undo", stack.undo, QKeySequence.StandardKey.Undo,
                               "Undo the viewer's last edit")
        self.redo_action = act(menu, "&Redo", stack.redo, QKeySequence.StandardKey.Redo,
                               "Redo the viewer's edit undone last")
        for signal in (stack.indexChanged, stack.cleanChanged, stack.canUndoChanged,
                       stack.canRedoChanged, stack.undoTextChanged, stack.redoTextChanged):
            signal.connect(lambda *_: self._update_undo_actions())
        self.tabs.currentChanged.connect(lambda _i: self._update_undo_actions())
        self._update_undo_actions()

    def _update_undo_actions(self) -> None:
        try:
            stack = self.viewer_tab.undo_stack
            front = self.tabs.currentWidget() is self.viewer_tab
        except RuntimeError:  # the window is being destroyed (its stack empties last)
            return
        for action, word, can, text in (
            (self.undo_action, "&Undo", stack.canUndo(), stack.undoText()),
            (self.redo_action, "&Redo", stack.canRedo(), stack.redoText()),
        ):
            action.setText(f"{word} {text}" if can and text else word)
            action.setEnabled(front and can)

    # the viewer's tools, one key each (listed in the Measure menu; a text field being edited
    # keeps its letters)
    TOOL_KEYS = (
        ("pan", "&Pan", "P"),
        ("ruler", "&Ruler", "R"),
        ("marker", "&Marker", "M"),
        ("level3", "&Level: 3 points", "L"),
        ("region", "Level: re&gion", "G"),
    )

    def _build_measure_menu(self, act) -> None:
        menu = self.menuBar().addMenu("&Measure")
        self.tool_actions: dict[str, QAction] = {}
        for key, text, shortcut in self.TOOL_KEYS:
            self.tool_actions[key] = act(
                menu, text, lambda key=key: self.use_viewer_tool(key), QKeySequence(shortcut),
                f"Viewer: {text.replace('&', '')} tool",
            )
        menu.addSeparator()
        self.fit_action = act(menu, "Zoom to &fit", self.zoom_viewer_to_fit, QKeySequence("F"),
                              "Viewer: show the whole map")

    def use_viewer_tool(self, key: str) -> None:
        """Bring the viewer to the front with its tool ``key`` (pan, ruler, marker, level3,
        region) chosen."""
        self.tabs.setCurrentWidget(self.viewer_tab)
        self.viewer_tab.set_mode(key)

    def toggle_side_by_side(self) -> None:
        """The viewer in front, its texture shown beside the map (or no longer)."""
        self.tabs.setCurrentWidget(self.viewer_tab)
        self.viewer_tab.set_side_by_side(self.side_action.isChecked())

    def zoom_viewer_to_fit(self) -> None:
        self.tabs.setCurrentWidget(self.viewer_tab)
        self.viewer_tab.map.fit()

    def open_validation(self):
        """Show the method-validation dialog (created on first use)."""
        from impress_gui.ui.validation_dialog import ValidationDialog

        if self.validation_dialog is None:
            self.validation_dialog = ValidationDialog(self.messenger, self.dialogs, self)
        self.validation_dialog.show()
        self.validation_dialog.raise_()
        return self.validation_dialog

    def all_tabs(self) -> list[Tab]:
        return list(self._tabs)

    # ----- state ----------------------------------------------------------------------------------
    def is_dirty(self) -> bool:
        return self.project.dirty or any(tab.is_dirty() for tab in self._tabs)

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
        """Open ``project`` in the session (the tabs follow)."""
        self.session.open_project(project)
        self._update_title()

    def _on_reconstruction_added(self, _folder) -> None:
        """A reconstruction was made or opened: bring the viewer to the front once it shows it."""
        self._front_on_load = True

    def _on_viewer_loaded(self) -> None:
        if self._front_on_load:
            self._front_on_load = False
            self.tabs.setCurrentWidget(self.viewer_tab)

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
        if answer != Button.Discard:
            return False
        try:
            removed = self.project.discard_unsaved()
        except (ImpressError, OSError) as exc:
            self.messenger.exception("The unsaved results were not removed", exc)
            return False
        if removed:
            self.show_status(f"Discarded; removed {', '.join(removed)}")
        return True

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
                title, f"{path}: the project cannot be read (an internal error)", codes.E_INTERNAL
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
            "Cannot open", f"{p}: no such project folder or video", codes.E_FILE_MISSING
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
            for tab in self._tabs:
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
        # where the user left the window and its docks, for the next start (app.place_window)
        self.settings.setValue("window/geometry", self.saveGeometry())
        self.settings.setValue("window/state", self.saveState())
        for tab in self._tabs:
            tab.shutdown()
        if self.motor_panel is not None:
            from impress_gui.ui.motor.choices import save_motor_choices

            save_motor_choices(self.settings, self.motor_panel.current_settings())
        if self.motor_panel is not None:
            self.motor_panel.shutdown()
        if self.validation_dialog is not None:
            self.validation_dialog.shutdown()
        self.session.close()
        self.messenger.close_all()
        self.settings.sync()
