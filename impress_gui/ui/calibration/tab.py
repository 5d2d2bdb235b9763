"""The calibration tab: load the scan, choose t1/t2, mark corners A-F, calibrate, judge the fit.

The tab gathers inputs and shows results; every number comes from the core
(:func:`~impress_gui.core.calibration.scene.calibrate_scene`,
:func:`~impress_gui.core.calibration.aids.refine_corner`,
:func:`~impress_gui.core.calibration.aids.propose_calibration_frames`). Long work runs in one
:class:`~impress_gui.ui.worker.Worker`, each task on its own open video (the tab's video object
is used by the GUI thread only).
"""

from __future__ import annotations

from collections import OrderedDict
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
from impress_gui.core.calibration.pick_editor import FRAMES, PickEditor
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.video import VideoSource
from impress_gui.core.project.project import Project
from impress_gui.session.calibration_jobs import open_evidence, propose_task
from impress_gui.ui.calibration.actions import CalibrationFiles, SceneCalibrationRuns
from impress_gui.ui.calibration.checkerboard_dialog import VIDEO_FILTER, CheckerboardRuns
from impress_gui.ui.calibration.overlays import Overlays
from impress_gui.ui.calibration.results import CalibrationResults, changed_inputs
from impress_gui.ui.calibration.setup import SetupPanel, checkerboard_available
from impress_gui.ui.calibration.widgets import ROLE, CalibrationSidebar, FrameNavigator
from impress_gui.ui.frame_view import FRAME_COLOURS, FrameView
from impress_gui.ui.messages import Dialogs, Messenger
from impress_gui.ui.task_bar import TaskBar

FRAME_CACHE = 12


class CalibrationTab(CalibrationFiles, SceneCalibrationRuns, CheckerboardRuns, QWidget):
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
    ) -> None:
        super().__init__(parent)
        self.messenger, self.dialogs = messenger, dialogs or Dialogs(self)
        self.settings = settings  # None: the window's settings (see _settings)
        self.checkerboard_dialog = None
        self.project = Project()
        self.video: VideoSource | None = None
        self.video_path: Path | None = None
        self.video_sha256: str | None = None
        self.calibration: SceneCalibration | None = None
        self.proposal: dict[str, int] | None = None
        self.current_frame = 0
        self.dirty = False
        self._rgb: np.ndarray | None = None
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cal_state = None
        self.editor = PickEditor()
        self.tasks = TaskBar(messenger, self, name="calibration-task")
        self.tasks.status.connect(self.status)
        self.tasks.busy_changed.connect(self.busy_changed)
        self.tasks.busy_changed.connect(lambda _b: self._refresh())
        self._build_ui()
        self.editor.on_change = self._on_picks_changed
        self._refresh()

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
        self.setup = SetupPanel(self.messenger, self.dialogs)
        self.setup.changed.connect(self._on_setup_changed)
        self.setup.checkerboard_requested.connect(self.calibrate_camera)
        if checkerboard_available():
            self.setup.checkerboard_button.setToolTip(
                "Calibrate the camera from a video or a folder of images of a checkerboard "
                "(the board's inner corners and square size are asked first)"
            )
        self.results = CalibrationResults()
        self.sidebar = sb = CalibrationSidebar(self.setup, self.results)
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
        """Show a project's state (its video is opened and re-hashed in the worker)."""
        self.shutdown_tasks()
        self._close_video()
        self.project = project
        self.calibration = project.calibration
        self.proposal = None
        self.frames.proposal_label.setText("")
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
        self.editor.on_change = self._on_picks_changed
        self._cal_state = self.editor.state if self.calibration is not None else None
        self.results.show_calibration(self.calibration)
        self.dirty = False
        self._refresh()
        if project.video is not None:
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
        self.dirty = True
        self.changed.emit()

    # ----- long tasks -------------------------------------------------------------------------
    def is_busy(self) -> bool:
        return self.tasks.is_busy()

    def _run(self, what: str, fn, on_done, fail_title: str) -> bool:
        return self.tasks.run(what, fn, on_done, fail_title)

    def shutdown_tasks(self) -> None:
        self.tasks.shutdown()
        self.overlays.shutdown()

    def shutdown(self) -> None:
        self.shutdown_tasks()
        self._close_video()

    # ----- video ------------------------------------------------------------------------------
    def load_video(self, path: str | Path | None = None) -> bool:
        path = path or self.dialogs.open_file("Open the scan video", VIDEO_FILTER)
        if not path:
            return False
        p = Path(path)
        marked = any(self.editor.count(f) for f in FRAMES) or self.calibration is not None
        if self.video is not None and marked:
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
        self._close_video()
        self.video, self.video_path, self.video_sha256 = video, Path(path).resolve(), sha
        if new:
            same = self.project.video is not None and self.project.video.sha256 == sha
            self.project.set_video(path, sha256=sha)
            if not same:
                self.editor.reset()
                self.calibration = None
                self._cal_state = None
                self.project.set_picks(None)
                self.project.set_calibration(None)
                self.results.show_calibration(None)
            self._mark_dirty()
        w, h = video.size
        self.video_label.setText(
            f"{self.video_path}\n{w}x{h}, {video.fps:.3f} frames/s, "
            f"{video.frame_count} frames\nSHA-256 {sha[:16]}..."
        )
        self.setup.set_video_size(video.size)
        self.nav.set_range(video.frame_count)
        start = self.editor.state.t1 if self.editor.state.t1 is not None else 0
        self.go_to_frame(min(start, video.frame_count - 1))
        self.video_changed.emit(str(self.video_path))
        self.status.emit(f"Video {self.video_path.name}: {video.frame_count} frames")

    def _close_video(self) -> None:
        if self.video is not None:
            self.video.close()
        self.video = self.video_path = self.video_sha256 = None
        self._cache.clear()
        self.overlays.clear()
        self._rgb = None
        self.view.set_frame(None)
        self.loupe.set_image(None)
        self.video_label.setText("No video loaded.")
        self.video_changed.emit("")

    def _read(self, k: int) -> np.ndarray:
        if k in self._cache:
            self._cache.move_to_end(k)
            return self._cache[k]
        rgb = self.video.read(k)
        self._cache[k] = rgb
        while len(self._cache) > FRAME_CACHE:
            self._cache.popitem(last=False)
        return rgb

    def go_to_frame(self, k: int) -> None:
        """Show frame ``k`` now (the slider and the number follow)."""
        self.nav.set_frame(k)
        self.show_frame(k)

    def show_frame(self, k: int) -> None:
        if self.video is None:
            return
        try:
            rgb = self._read(int(k))
        except ImpressError as exc:
            self.messenger.exception(f"Cannot show frame {k}", exc)
            return
        self.current_frame, self._rgb = int(k), rgb
        self.view.set_frame(rgb)
        self.loupe.set_image(rgb)
        t = self.video.times_s
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
