"""The calibration tab: load the scan, choose t1/t2, mark corners A-F, calibrate, judge the fit.

The tab gathers inputs and shows results; every number comes from the core
(:func:`~impress_gui.core.calibration.scene.calibrate_scene`,
:func:`~impress_gui.core.calibration.aids.refine_corner`,
:func:`~impress_gui.core.calibration.aids.propose_calibration_frames`). Long work runs in one
:class:`~impress_gui.ui.worker.Worker`, each task on its own open video (the session's evidence
reader is used by the GUI thread only). The project, the evidence video and the calibration are
the :class:`~impress_gui.session.session.Session`'s: the tab changes them through it and follows
its signals; the actions are small objects given what they use
(:class:`~impress_gui.ui.calibration.actions.PickFiles`,
:class:`~impress_gui.ui.calibration.actions.SceneCalibrationAction`,
:class:`~impress_gui.ui.calibration.checkerboard_dialog.CheckerboardAction`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6.QtCore import QSettings, Qt, Signal
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (
    QHBoxLayout,
    QMessageBox,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.base.errors import ImpressError
from impress_gui.core.calibration.aids import refine_corner
from impress_gui.core.calibration.pick_editor import FRAMES, PickEditor, PickState
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.video import VideoSource
from impress_gui.core.project.project import Project
from impress_gui.session.calibration_jobs import open_evidence, propose_task
from impress_gui.session.session import Evidence, Session
from impress_gui.ui.calibration.actions import PickFiles, SceneCalibrationAction
from impress_gui.ui.calibration.checkerboard_dialog import (
    VIDEO_FILTER,
    CheckerboardAction,
    CheckerboardDialog,
)
from impress_gui.ui.calibration.overlays import Overlays
from impress_gui.ui.calibration.results import CalibrationResults, changed_inputs
from impress_gui.ui.calibration.setup import SetupPanel, checkerboard_available
from impress_gui.ui.calibration.widgets import ROLE, CalibrationSidebar, FrameNavigator
from impress_gui.ui.frame_view import FRAME_COLOURS, FrameView
from impress_gui.ui.messages import Dialogs, Messenger
from impress_gui.ui.task_bar import TaskBar


class CalibrationTab(QWidget):
    """A view over a :class:`~impress_gui.session.session.Session`: the project, the evidence
    video (its reader and frame cache) and the calibration are the session's; the tab holds
    only what is on screen (the picks being edited, the inputs, the frame shown) and follows the
    session's signals. Without ``session`` it makes its own."""

    changed = Signal()  # something the project keeps changed
    status = Signal(str)  # a line for the status bar
    video_changed = Signal(str)  # path of the video shown ("" for none)
    busy_changed = Signal(bool)
    calibrated = Signal(object)  # SceneCalibration

    def __init__(
        self,
        messenger: Messenger,
        dialogs: Dialogs | None = None,
        parent: QWidget | None = None,
        settings: QSettings | None = None,
        session: Session | None = None,
    ) -> None:
        super().__init__(parent)
        self.messenger = messenger
        self._dialogs = dialogs or Dialogs(self)
        self._own_session = session is None
        self.session = session if session is not None else Session()
        self.proposal: dict[str, int] | None = None
        self.current_frame = 0
        self.dirty = False  # inputs on screen not yet in the project
        self._loading = False  # showing a project: its values are not edits
        self._rgb: np.ndarray | None = None
        self._cal_state: PickState | None = None  # the picks the calibration shown was made from
        self._cal_of: SceneCalibration | None = None  # ... and that calibration
        self._reset_picks = False  # a new video replaces the project's: its picks go
        self.editor = PickEditor()
        self.tasks = TaskBar(messenger, self, name="calibration-task")
        self.tasks.status.connect(self.status)
        self.tasks.busy_changed.connect(self.busy_changed)
        self.tasks.busy_changed.connect(lambda _b: self._refresh())
        self._build_ui()
        self.files = PickFiles(messenger, self._dialogs, self.editor, self.session)
        self.scene = SceneCalibrationAction(
            messenger, self.session, self.setup, self.editor, self.tasks, self._on_calibrated
        )
        self.checkerboard = CheckerboardAction(
            messenger, self._dialogs, settings, self.session, self.setup, self.tasks,
            self.status.emit, self,
        )
        self.editor.on_change = self._on_picks_changed
        s = self.session
        s.project_changed.connect(self._on_project_changed)
        s.evidence_changed.connect(self._on_evidence_changed)
        s.calibration_changed.connect(self._on_calibration_changed)
        self._show_project(s.project)
        if s.evidence is not None:
            self._on_evidence_changed(s.evidence)
        else:
            self._open_project_video(s.project)

    # ----- the session's state, as the tab's (read-only) ------------------------------------------
    @property
    def project(self) -> Project:
        return self.session.project

    @property
    def calibration(self) -> SceneCalibration | None:
        return self.session.calibration

    @property
    def video(self) -> VideoSource | None:
        ev = self.session.evidence
        return None if ev is None else ev.reader

    @property
    def video_path(self) -> Path | None:
        ev = self.session.evidence
        return None if ev is None else ev.path

    @property
    def video_sha256(self) -> str | None:
        ev = self.session.evidence
        return None if ev is None else ev.sha256

    @property
    def checkerboard_dialog(self) -> CheckerboardDialog | None:
        return self.checkerboard.dialog

    @property
    def settings(self) -> QSettings | None:
        """Where the checkerboard dialog's answers are remembered (None: nowhere)."""
        return self.checkerboard.settings

    @settings.setter
    def settings(self, settings: QSettings | None) -> None:
        self.checkerboard.settings = settings

    @property
    def dialogs(self) -> Dialogs:
        return self._dialogs

    @dialogs.setter
    def dialogs(self, dialogs: Dialogs) -> None:
        """The file choosers of the tab and of its actions and inputs."""
        self._dialogs = self.files.dialogs = self.checkerboard.dialogs = dialogs
        self.setup.dialogs = dialogs

    # ----- layout -----------------------------------------------------------------------------
    def _build_ui(self) -> None:
        outer = QHBoxLayout(self)
        split = QSplitter(Qt.Orientation.Horizontal)
        outer.addWidget(split)
        left = QWidget()
        lv = QVBoxLayout(left)
        self.view = FrameView()
        self.view.clicked.connect(self.on_view_clicked)
        self.view.corner_moved.connect(self._on_corner_moved)
        lv.addWidget(self.view, 1)
        self.nav = FrameNavigator()
        self.nav.frame_requested.connect(self.show_frame)
        self.nav.fit_requested.connect(self.view.fit)
        lv.addWidget(self.nav)
        lv.addWidget(self.tasks)
        split.addWidget(left)
        self.overlays = Overlays(self.view, self)
        self.setup = SetupPanel(self.messenger, self._dialogs)
        self.setup.changed.connect(self._on_setup_changed)
        self.setup.checkerboard_requested.connect(self.calibrate_camera)
        if checkerboard_available():
            self.setup.checkerboard_button.setToolTip(
                "Calibrate the camera from a video or a folder of images of a checkerboard "
                "(the board's inner corners and square size are asked first)"
            )
        # the result under the frame, always in sight (in the sidebar it was below the fold
        # of a 1080-line screen); the sidebar keeps an empty place for it
        self.results = CalibrationResults()
        lv.insertWidget(lv.indexOf(self.tasks), self.results)
        self.sidebar = sb = CalibrationSidebar(self.setup, QWidget())
        split.addWidget(sb)
        split.setStretchFactor(0, 3)
        split.setStretchFactor(1, 1)
        split.setCollapsible(0, False)
        split.setCollapsible(1, False)
        self.video_label, self.load_video_button = sb.video_label, sb.load_video_button
        self.frames, self.corners, self.loupe = sb.frames, sb.corners, sb.corners.loupe
        self.calibrate_button, self.export_cal_button = sb.calibrate_button, sb.export_cal_button
        self.overlay_target, self.overlay_stripes = sb.overlay_target, sb.overlay_stripes
        self.load_video_button.clicked.connect(lambda: self.load_video())
        self.frames.find_button.clicked.connect(self.propose_frames)
        self.frames.go_requested.connect(self.go_to_pick)
        self.frames.use_requested.connect(lambda w: self.editor.set_frame(w, self.current_frame))
        self.view.hovered.connect(lambda u, v: self.loupe.set_centre((u, v)))
        c = self.corners
        c.undo_snap_button.clicked.connect(self.editor.undo)
        c.undo_button.clicked.connect(self.editor.undo)
        c.redo_button.clicked.connect(self.editor.redo)
        c.clear_button.clicked.connect(self.clear_current)
        c.import_button.clicked.connect(lambda: self.import_picks())
        c.export_button.clicked.connect(lambda: self.export_picks())
        self.calibrate_button.clicked.connect(self.calibrate)
        self.export_cal_button.clicked.connect(lambda: self.export_calibration())
        for check in (self.overlay_target, self.overlay_stripes):
            check.toggled.connect(lambda _on: self._refresh_overlays())
        ctx = Qt.ShortcutContext.WidgetWithChildrenShortcut
        QShortcut(QKeySequence.StandardKey.Undo, self, self.editor.undo, context=ctx)
        QShortcut(QKeySequence.StandardKey.Redo, self, self.editor.redo, context=ctx)

    # ----- project ----------------------------------------------------------------------------
    def set_project(self, project: Project) -> None:
        """Open ``project`` in the session; the tab shows its state as the session announces
        it (and opens and re-hashes its video in the worker)."""
        self.session.open_project(project)

    def _on_project_changed(self, project: Project) -> None:
        self.shutdown_tasks()
        self._show_project(project)
        self._open_project_video(project)

    def _show_project(self, project: Project) -> None:
        """Show a project's state: its inputs, picks and calibration, no video yet."""
        self._show_no_video()
        self.proposal = None
        self.frames.proposal_label.setText("")
        self._loading = True
        try:
            if project.target is not None:
                self.setup.add_target(project.target, select=True)
            self.setup.set_intrinsics(project.intrinsics, announce=False)
            speed = project.calibration_settings.get("speed_mm_s")
            if speed is None and project.calibration is not None:
                speed = project.calibration.speed_mm_s
            self.setup.set_speed(speed)
            self.editor.on_change = None
            if project.picks is not None:
                self.editor.load_picks(project.picks)
            else:
                self.editor.reset()
        finally:
            self.editor.on_change = self._on_picks_changed
            self._loading = False
        cal = project.calibration
        self._cal_of, self._cal_state = cal, (self.editor.state if cal is not None else None)
        self.results.show_calibration(cal)
        self.dirty = False
        self._refresh()

    def _open_project_video(self, project: Project) -> None:
        """Re-hash the project's video against its record and open it (in the worker)."""
        if project.video is None:
            return
        path = project.video_path()

        self._run(
            "Checking and opening the evidence video",
            lambda progress, cancel: open_evidence(path, progress, cancel, project),
            lambda res: self._adopt_video(path, *res, new=False),
            "The evidence video cannot be used",
        )

    def commit_to_project(self) -> None:
        """Copy what the tab holds into the project (before saving)."""
        p = self.project
        if self.video_path is not None:
            picks = self.editor.to_picks(str(self.video_path), self.video_sha256)
            if picks != p.picks:
                p.set_picks(picks)
        if self.setup.intrinsics is not p.intrinsics:
            p.set_intrinsics(self.setup.intrinsics)
        target = self.setup.target
        if target is not None and (p.target is None or p.target.to_json() != target.to_json()):
            p.set_target(target)
        if self.setup.speed_mm_s() > 0:
            p.set_calibration_settings(
                {**p.calibration_settings, "speed_mm_s": self.setup.speed_mm_s()}
            )
        self.dirty = False

    def _mark_dirty(self) -> None:
        if self._loading:
            return
        self.dirty = True
        self.changed.emit()

    def is_dirty(self) -> bool:
        """The tab holds inputs not yet in the project (``commit_to_project`` copies them)."""
        return self.dirty

    # ----- long tasks -------------------------------------------------------------------------
    def is_busy(self) -> bool:
        return self.tasks.is_busy()

    def _run(self, what: str, fn, on_done, fail_title: str) -> bool:
        return self.tasks.run(what, fn, on_done, fail_title)

    def shutdown_tasks(self) -> None:
        self.tasks.shutdown()
        self.overlays.shutdown()

    def shutdown(self) -> None:
        """Stop the tab's work and stop following the session (a session the tab made is
        closed; one it was given is its owner's to close)."""
        self.shutdown_tasks()
        s = self.session
        s.project_changed.disconnect(self._on_project_changed)
        s.evidence_changed.disconnect(self._on_evidence_changed)
        s.calibration_changed.disconnect(self._on_calibration_changed)
        if self._own_session:
            s.close()

    # ----- actions (see actions.py and checkerboard_dialog.py) ----------------------------------
    def import_picks(self, path: str | None = None) -> bool:
        return self.files.import_picks(path)

    def export_picks(self, path: str | None = None) -> bool:
        return self.files.export_picks(path)

    def export_calibration(self, path: str | None = None) -> bool:
        return self.files.export_calibration(path)

    def calibrate(self) -> bool:
        return self.scene.calibrate()

    def calibrate_camera(self) -> CheckerboardDialog | None:
        return self.checkerboard.calibrate_camera()

    def _on_calibrated(self, cal: SceneCalibration, picks: Picks, state: PickState) -> None:
        self._cal_of, self._cal_state = cal, state
        self.session.set_calibration(cal, picks)
        self._mark_dirty()
        self._refresh()
        self.calibrated.emit(cal)
        self.status.emit(
            f"Calibrated: roll {cal.roll_deg:+.3f} deg, tilt {cal.tilt_deg:+.3f} "
            f"deg, reprojection RMS {cal.reprojection_rms_px:.2f} px"
        )
        if cal.warnings:
            self.messenger.warning("Check the calibration", "\n\n".join(cal.warnings))

    def _on_calibration_changed(self, cal: SceneCalibration | None) -> None:
        if cal is not self._cal_of:  # made elsewhere: judged against the picks on screen
            self._cal_of, self._cal_state = cal, (self.editor.state if cal is not None else None)
        self.results.show_calibration(cal)
        self._refresh()

    # ----- video ------------------------------------------------------------------------------
    def load_video(self, path: str | Path | None = None) -> bool:
        path = path or self.dialogs.open_file("Open the scan video", VIDEO_FILTER)
        if not path:
            return False
        p = Path(path)
        marked = any(self.editor.count(f) for f in FRAMES) or self.calibration is not None
        if self.video_path is not None and marked:
            answer = self.messenger.ask(
                "Replace the video?",
                f"Open {p.name} instead of {self.video_path.name}? If it is a different "
                "video, the corners and the calibration made on this one are cleared.",
            )
            if answer != QMessageBox.StandardButton.Yes:
                return False

        return self._run(
            f"Opening {p.name}",
            lambda progress, cancel: open_evidence(p, progress, cancel),
            lambda res: self._adopt_video(p, *res, new=True),
            "Cannot open the video",
        )

    def _adopt_video(self, path: Path, video: VideoSource, sha: str, new: bool) -> None:
        """Make the opened ``video`` the session's evidence reader (``new``: chosen by the user
        for this project; another video than the project's clears the picks too)."""
        p = self.project
        self._reset_picks = new and not (p.video is not None and p.video.sha256 == sha)
        try:
            self.session.adopt_evidence(path, video, sha, new)
        except BaseException:
            ev = self.session.evidence
            if ev is None or ev.reader is not video:
                video.close()
            raise
        finally:
            self._reset_picks = False
        if new:
            self._mark_dirty()

    def _on_evidence_changed(self, ev: Evidence | None) -> None:
        if ev is None:
            self._show_no_video()
            return
        if self._reset_picks:  # the session cleared the project's picks for this video
            self._reset_picks = False
            self.editor.reset()
        video = ev.reader
        w, h = video.size
        self.video_label.setText(
            f"{ev.path}\n{w}x{h}, {video.fps:.3f} frames/s, "
            f"{video.frame_count} frames\nSHA-256 {ev.sha256[:16]}..."
        )
        self.setup.set_video_size(video.size)
        self.nav.set_range(video.frame_count)
        start = self.editor.state.t1 if self.editor.state.t1 is not None else 0
        self.go_to_frame(min(start, video.frame_count - 1))
        self.video_changed.emit(str(ev.path))
        self.status.emit(f"Video {ev.path.name}: {video.frame_count} frames")

    def _show_no_video(self) -> None:
        self.overlays.clear()
        self._rgb = None
        self.view.set_frame(None)
        self.loupe.set_image(None)
        self.video_label.setText("No video loaded.")
        self.video_changed.emit("")

    def go_to_frame(self, k: int) -> None:
        """Show frame ``k`` now (the slider and the number follow)."""
        self.nav.set_frame(k)
        self.show_frame(k)

    def show_frame(self, k: int) -> None:
        video = self.video
        if video is None:
            return
        try:
            rgb = self.session.frame(int(k))
        except ImpressError as exc:
            self.messenger.exception(f"Cannot show frame {k}", exc)
            return
        self.current_frame, self._rgb = int(k), rgb
        self.view.set_frame(rgb)
        self.loupe.set_image(rgb)
        t = video.times_s
        self.nav.time_label.setText(f"{t[k]:.2f} s / {t[-1]:.2f} s")
        self._refresh()

    def go_to_pick(self, which: str) -> None:
        k = self.editor.state.frame(which)
        if k is not None and self.video is not None:
            self.go_to_frame(k)

    # ----- corners ------------------------------------------------------------------------------
    def on_view_clicked(self, u: float, v: float) -> None:
        if self.video is None:
            self.messenger.warning("No video", "Load the scan video before marking corners.")
            return
        if not self.view.contains(u, v):
            w, h = self.video.size
            self.messenger.warning(
                "Outside the image",
                f"The click at ({u:.1f}, {v:.1f}) is outside the {w}x{h} "
                "image; no corner was marked.",
            )
            return
        which = self.editor.which_for_frame(self.current_frame)
        if which is None:
            free = next((f for f in FRAMES if self.editor.state.frame(f) is None), None)
            if free is None:
                s = self.editor.state
                self.messenger.warning(
                    "Not a calibration frame",
                    f"Frame {self.current_frame} is neither t1 ({s.t1}) nor t2 ({s.t2}). Go to "
                    "t1 or t2 to mark corners there, or press 'Use this frame'.",
                )
                return
            self.editor.set_frame(free, self.current_frame)
            which = free
        if self.editor.next_corner(which) is None:
            self.messenger.warning(
                "All corners are marked",
                f"All six corners are marked in {which}. Drag a corner to "
                "move it, or use Undo or Clear frame.",
            )
            return
        name = self.editor.place(which, (u, v))
        msg = f"{name} marked in {which} at ({u:.1f}, {v:.1f})"
        if self.corners.snap_check.isChecked() and self._rgb is not None:
            ref = refine_corner(self._rgb, (u, v))
            if ref.accepted and ref.moved_px >= 0.01:
                self.editor.snap(which, name, ref.uv_px)
                msg += f"; snapped {ref.moved_px:.2f} px to the corner (Undo snap keeps the click)"
            else:
                msg += "; no clear corner nearby, the click is kept"
        self.status.emit(msg)

    def _on_corner_moved(self, name: str, u: float, v: float) -> None:
        which = self.editor.which_for_frame(self.current_frame)
        if which is None:
            return
        if not self.view.contains(u, v):
            self.messenger.warning(
                "Outside the image",
                f"Corner {name} cannot be moved outside the image; it stays where it was.",
            )
            self._refresh()
            return
        self.editor.move(which, name, (u, v))
        self.status.emit(f"{name} moved to ({u:.1f}, {v:.1f}) in {which}")

    def clear_current(self) -> None:
        which = self.editor.which_for_frame(self.current_frame)
        if which is not None:
            self.editor.clear(which)

    def _on_picks_changed(self) -> None:
        self._mark_dirty()
        self._refresh()

    def _check_stale(self) -> None:
        """Say so when the inputs on screen are no longer those of the calibration shown."""
        setup = self.setup
        changed = changed_inputs(
            self.calibration,
            self.editor.state != self._cal_state,
            setup.speed_mm_s(),
            setup.intrinsics,
            setup.target,
        )
        what = ", ".join(changed)
        self.results.set_stale(
            bool(changed), f"{what[:1].upper()}{what[1:]} changed since this calibration."
        )

    def _on_setup_changed(self) -> None:
        self._mark_dirty()
        self._refresh()

    # ----- computations -------------------------------------------------------------------------
    def propose_frames(self) -> bool:
        if self.video_path is None:
            self.messenger.error("No video", "Load the scan video first.")
            return False
        path = self.video_path

        return self._run(
            "Finding t1 and t2",
            propose_task(path),
            self._on_proposal,
            "Cannot find the calibration frames",
        )

    def _on_proposal(self, out: dict[str, int]) -> None:
        self.proposal = out
        self.frames.proposal_label.setText(f"proposed: t1 = {out['t1']}, t2 = {out['t2']}")
        for which in FRAMES:
            if self.editor.count(which) == 0:
                self.editor.set_frame(which, out[which])
        self.go_to_pick("t1")

    # ----- display ----------------------------------------------------------------------------
    def _refresh(self) -> None:
        self._check_stale()
        s, busy, has_video = self.editor.state, self.tasks.is_busy(), self.video is not None
        which = self.editor.which_for_frame(self.current_frame) if has_video else None
        self.frames.show_frames({f: s.frame(f) for f in FRAMES}, has_video, busy)
        self.nav.role_label.setText(ROLE[which] if which else "")
        self.nav.role_label.setToolTip(ROLE[which] if which else "")  # cut on a narrow window
        corners = s.corners(which) if which else {}
        self.view.set_corners(
            corners,
            s.raw(which) if which else {},
            FRAME_COLOURS[which] if which else FRAME_COLOURS["t1"],
        )
        self.corners.show_state(self.editor, which, has_video)
        self.corners.diagram.set_target(self.setup.target)
        self.load_video_button.setEnabled(not busy)
        self.setup.checkerboard_button.setEnabled(not busy and checkerboard_available())
        self.calibrate_button.setEnabled(has_video and not busy)
        self.export_cal_button.setEnabled(self.calibration is not None)
        self._refresh_overlays()

    def _refresh_overlays(self) -> None:
        k, has_video = self.current_frame, self.video is not None
        self.overlays.update(
            k,
            self._rgb,
            float(self.video.times_s[k]) if has_video else None,
            self.calibration,
            self.setup.target,
            self.overlay_target.isChecked(),
            self.overlay_stripes.isChecked(),
        )
