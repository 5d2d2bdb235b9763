"""The processing tab: the project's video and calibration in, a reconstruction out.

The analyst sets the parameters (frame range, regions of interest dragged on the frame,
detection method and threshold, grid), checks the detected stripe points of both lasers on
any frame (and, for the lookup-table methods, the learned background tables), then runs
:func:`impress_gui.core.reconstruction.pipeline.run_reconstruction` in the background on the
calibration in memory, with progress, frames/s, time remaining and Cancel. The outputs are
written into the project folder (``reconstructions/<date-time>``) and added to the session
(:meth:`~impress_gui.session.session.Session.add_reconstruction`: recorded in the project; the
viewer follows the session and shows them).

The tab is a view over a :class:`~impress_gui.session.session.Session`: the project, the
calibration and the evidence video (frames through :meth:`Session.frame`, on the GUI thread
only) are the session's, and the tab follows its signals. While the session has no evidence
video (the tab on its own, or before the calibration tab has checked the project's video) the
tab opens the project's video itself, for the preview only. Background work never touches a
reader of the GUI thread: the stripe preview gets the frame as an RGB array, and the lookup
tables and the reconstruction open readers of their own.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.base.errors import ImpressError
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.video import VideoSource, open_video
from impress_gui.core.project.project import Project
from impress_gui.core.reconstruction.reconstruct import laser_rois
from impress_gui.core.reconstruction.stripes import LASERS, BackgroundLUT, StripeParams, detect
from impress_gui.session.processing_jobs import learn_lut, new_output_folder, reconstruct_into
from impress_gui.session.session import Evidence, Session
from impress_gui.ui.calibration.widgets import FrameNavigator
from impress_gui.ui.common_widgets import SidePanelScroll
from impress_gui.ui.frame_view import STRIPE_COLOURS, FrameView
from impress_gui.ui.messages import Dialogs, Messenger
from impress_gui.ui.processing.panels import LutView, ParamsPanel, RunPanel
from impress_gui.ui.worker import LatestOnly, Worker

CAL_FILTER = "Scene calibration (*.json)"


class ProcessingTab(QWidget):
    changed = Signal()
    status = Signal(str)
    reconstructed = Signal(str)  # the output folder, once written and recorded
    preview_ready = Signal(int)  # frame whose detected stripes are shown
    growing = Signal(object)  # partial heightmap from the running reconstruction
    growing_grid = Signal(object)  # its GridSpec, when the core sends one (before the map)
    lut_ready = Signal()

    def __init__(
        self,
        messenger: Messenger | None = None,
        dialogs: Dialogs | None = None,
        parent: QWidget | None = None,
        session: Session | None = None,
    ) -> None:
        super().__init__(parent)
        self.messenger = messenger or Messenger(self)
        self.dialogs = dialogs or Dialogs(self)
        self._own_session = session is None
        self.session = session if session is not None else Session()
        # a reader of the tab's own on the project's video, for the preview only while the
        # session has no evidence video (closed as soon as it has one)
        self._reader: VideoSource | None = None
        self._reader_path: Path | None = None
        self._shown_cal: SceneCalibration | None = None  # the calibration the regions are of
        self.current_frame = 0
        self.lut: BackgroundLUT | None = None
        self._lut_key: tuple | None = None
        self.last_stripes: dict[str, np.ndarray] | None = None
        self.last_output: Path | None = None
        self._rgb: np.ndarray | None = None
        self._out: Path | None = None
        self.worker = Worker(self, name="processing")
        self.worker.progress.connect(lambda f, m: self.run_panel.progress(f, m))
        self.growing.connect(lambda a: self.run_panel.show_growing(a))
        self.growing_grid.connect(lambda spec: self.run_panel.growing.set_grid(spec))
        self.worker.finished.connect(self._on_finished)
        self.worker.failed.connect(self._on_failed)
        self.worker.cancelled.connect(self._on_cancelled)
        self.previewer = LatestOnly(self, "stripe-preview")
        self.previewer.finished.connect(self._on_preview)
        self.previewer.failed.connect(
            lambda code, msg: self.stripe_label.setText(f"Preview failed [{code}]: {msg}")
        )
        self._build_ui()
        s = self.session
        s.project_changed.connect(self._on_project_changed)
        s.evidence_changed.connect(self._on_evidence_changed)
        s.calibration_changed.connect(self._on_calibration_changed)
        self._show_project(s.project)

    # ----- the session's state, as the tab's (read-only) --------------------------------------
    @property
    def project(self) -> Project:
        return self.session.project

    @property
    def calibration(self) -> SceneCalibration | None:
        return self.session.calibration

    @property
    def video(self) -> VideoSource | None:
        """The reader frames are shown from: the session's evidence reader, else the tab's own."""
        ev = self.session.evidence
        return ev.reader if ev is not None else self._reader

    @property
    def video_path(self) -> Path | None:
        ev = self.session.evidence
        return ev.path if ev is not None else self._reader_path

    # ----- layout -----------------------------------------------------------------------------
    def _build_ui(self) -> None:
        outer = QHBoxLayout(self)
        split = QSplitter(Qt.Orientation.Horizontal)
        outer.addWidget(split)
        left = QWidget()
        lv = QVBoxLayout(left)
        lv.setContentsMargins(0, 0, 0, 0)
        self.view = FrameView()
        lv.addWidget(self.view, 1)
        self.nav = FrameNavigator()
        self.nav.frame_requested.connect(self.show_frame)
        self.nav.fit_requested.connect(self.view.fit)
        lv.addWidget(self.nav)
        self.stripe_label = QLabel("")
        lv.addWidget(self.stripe_label)
        self.lut_view = LutView()
        self.lut_view.setMaximumHeight(300)
        self.lut_view.hide()
        lv.addWidget(self.lut_view)
        split.addWidget(left)
        self.regions: dict[str, pg.LinearRegionItem] = {}
        for name in LASERS:
            r = pg.LinearRegionItem(
                values=(0, 1),
                orientation="horizontal",
                brush=pg.mkBrush(*STRIPE_COLOURS[name], 35),
                pen=pg.mkPen(STRIPE_COLOURS[name], width=1.5),
            )
            r.setZValue(3)
            r.sigRegionChangeFinished.connect(lambda _r, n=name: self._on_region_dragged(n))
            self.view.vb.addItem(r)
            self.regions[name] = r

        side = QWidget()
        sv = QVBoxLayout(side)
        ig = QGroupBox("Inputs (from the project)")
        il = QVBoxLayout(ig)
        self.video_label = QLabel("Video: none (add it in the Calibration tab)")
        self.cal_label = QLabel("Calibration: none")
        for lab in (self.video_label, self.cal_label):
            lab.setWordWrap(True)
            lab.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
            il.addWidget(lab)
        self.load_cal_button = QPushButton("Use a calibration file...")
        self.load_cal_button.clicked.connect(lambda: self.load_calibration())
        il.addWidget(self.load_cal_button)
        sv.addWidget(ig)
        self.params = ParamsPanel()
        self.params.changed.connect(self._on_params_changed)
        self.params.default_frames.clicked.connect(self.default_frames)
        sv.addWidget(self.params)
        pg_ = QGroupBox("Preview")
        pl = QVBoxLayout(pg_)
        self.show_stripes = QCheckBox("Show the detected stripe points on the frame")
        self.show_stripes.setChecked(True)
        self.show_stripes.toggled.connect(lambda _on: self.request_preview())
        self.lut_button = QPushButton("Show the background lookup tables")
        self.lut_button.setCheckable(True)
        self.lut_button.toggled.connect(self._on_lut_toggled)
        pl.addWidget(self.show_stripes)
        pl.addWidget(self.lut_button)
        sv.addWidget(pg_)
        self.run_panel = RunPanel()
        self.run_panel.run_button.clicked.connect(lambda: self.run())
        self.run_panel.cancel_button.clicked.connect(self.cancel)
        sv.addWidget(self.run_panel)
        sv.addStretch(1)
        # never narrower than the panels (at 1366 pixels their right edges were cut off)
        scroll = SidePanelScroll(side, min_width=440)
        split.addWidget(scroll)
        split.setStretchFactor(0, 3)
        split.setStretchFactor(1, 1)

    # ----- project ----------------------------------------------------------------------------
    def set_project(self, project: Project) -> None:
        """Open ``project`` in the session (the tab follows the session's signals)."""
        self.session.open_project(project)

    def project_updated(self) -> None:
        """The project was changed without the session's signals: show its video (when none
        is shown) and its calibration again."""
        path = self.project.video_path()
        if (
            self.session.evidence is None
            and path is not None
            and path.exists()
            and (self.video is None or path.resolve() != self.video_path)
        ):
            self.open_video(path)
        self._show_calibration()

    def _on_project_changed(self, project: Project) -> None:
        self.shutdown_tasks()
        self._close_reader()
        self._show_no_video()
        self._show_project(project)

    def _show_project(self, project: Project) -> None:
        """The project's parameters and video (the session's evidence, else a reader of the
        tab's own on the project's video)."""
        self._shown_cal = project.calibration
        if project.processing:
            self.params.set_params(project.processing)
        if self.session.evidence is not None:
            self._show_video()
        else:
            path = project.video_path()
            if path is not None and path.exists():
                self.open_video(path)
        self._refresh()

    def _on_evidence_changed(self, ev: Evidence | None) -> None:
        if ev is None:  # the session's video was closed (the tab's own reader stays)
            if self._reader is None:
                self._show_no_video()
            self._refresh()
            return
        own = self._reader
        same = (
            own is not None
            and self._reader_path == ev.path
            and (own.frame_count == ev.reader.frame_count and own.size == ev.reader.size)
        )
        self._close_reader()
        if same:
            # the session now holds the video the tab had opened for itself: the frame shown,
            # the parameters and the lookup tables stay
            self._refresh()
            return
        self._show_no_video()
        self._show_video()
        self._refresh()

    def _on_calibration_changed(self, cal: SceneCalibration | None) -> None:
        if cal is not self._shown_cal:  # (a project just opened is shown with its own)
            self._show_calibration()

    def _show_calibration(self) -> None:
        """The session's calibration: its regions of interest, the stripes found with them."""
        self._shown_cal = self.calibration
        self._update_rois()
        self._refresh()
        self.request_preview()

    def commit_to_project(self) -> None:
        doc = self.params.params().to_json()
        if doc != {k: self.project.processing.get(k) for k in doc}:
            self.project.set_processing({**self.project.processing, **doc})

    def is_dirty(self) -> bool:
        return False

    def is_busy(self) -> bool:
        return self.worker.is_running() or self.previewer.is_running()

    def is_running(self) -> bool:
        return self.worker.is_running()

    def shutdown_tasks(self) -> None:
        self.worker.shutdown()
        self.previewer.shutdown()

    def shutdown(self) -> None:
        """Stop the tab's work and stop following the session (a session the tab made is
        closed; one it was given is its owner's to close). Safe twice."""
        self.shutdown_tasks()
        s = self.session
        s.project_changed.disconnect(self._on_project_changed)
        s.evidence_changed.disconnect(self._on_evidence_changed)
        s.calibration_changed.disconnect(self._on_calibration_changed)
        self._close_reader()
        if self._own_session:
            s.close()

    # ----- inputs ------------------------------------------------------------------------------
    def open_video(self, path: str | Path) -> None:
        """Open a reader of the tab's own on ``path`` for the preview, while the session has
        no evidence video (read-only; the evidence hash is the calibration tab's and the
        project's business, and the run checks it again)."""
        self._close_reader()
        self._show_no_video()
        try:
            reader = open_video(path)
        except ImpressError as exc:
            self.messenger.exception("Cannot open the video", exc)
            return
        self._reader, self._reader_path = reader, Path(path).resolve()
        self._show_video()

    def _show_video(self) -> None:
        """A video to show (the session's or the tab's own): its range, frame and regions."""
        video, path = self.video, self.video_path
        if video is None:
            return
        n, (w, h) = video.frame_count, video.size
        self.params.set_frame_count(n)
        self.params.set_image_height(h)
        self.nav.set_range(n)
        self.default_frames()
        self.video_label.setText(f"Video: {path}\n{w}x{h}, {video.fps:.3f} frames/s, {n} frames")
        self._update_rois()
        self.go_to_frame(self.params.frame_start.value())

    def _close_reader(self) -> None:
        if self._reader is not None:
            self._reader.close()
        self._reader = self._reader_path = None

    def _show_no_video(self) -> None:
        self.lut, self._lut_key = None, None
        self._rgb = None
        self.view.set_frame(None)
        self.view.set_stripes(None)
        self.video_label.setText("Video: none (add it in the Calibration tab)")

    def load_calibration(self, path: str | Path | None = None) -> bool:
        path = path or self.dialogs.open_file("Use a scene calibration", CAL_FILTER)
        if not path:
            return False
        try:
            cal = SceneCalibration.load(path)
        except ImpressError as exc:
            self.messenger.exception("Cannot use this calibration", exc)
            return False
        self.session.set_calibration(cal)  # the tab follows: regions, preview
        self.changed.emit()
        return True

    def default_frames(self) -> None:
        if self.video is None:
            return
        n, half = self.video.frame_count, int(round(0.5 * self.video.fps))
        start = min(n - 1, half)
        self.params.frame_start.setValue(start)
        self.params.frame_stop.setValue(max(start + 1, n - half))

    # ----- frames, regions and preview ---------------------------------------------------------
    def go_to_frame(self, k: int) -> None:
        self.nav.set_frame(k)
        self.show_frame(k)

    def show_frame(self, k: int) -> None:
        video = self.video
        if video is None:
            return
        try:
            # GUI thread: the session's frame cache over its one reader, else the tab's reader
            rgb = (
                self.session.frame(int(k))
                if self.session.evidence is not None
                else video.read(int(k))
            )
        except ImpressError as exc:
            self.messenger.exception(f"Cannot show frame {k}", exc)
            return
        self.current_frame, self._rgb = int(k), rgb
        self.view.set_frame(rgb)
        self.nav.time_label.setText(f"{video.times_s[k]:.2f} s")
        self.request_preview()

    def current_rois(self) -> dict[str, tuple[int, int]] | None:
        if self.params.auto_rois.isChecked():
            if self.calibration is None or self.video is None:
                return None
            try:
                return laser_rois(
                    self.calibration,
                    self.video.size,
                    (self.params.h_lo.value(), self.params.h_hi.value()),
                )
            except ImpressError as exc:
                self.stripe_label.setText(f"No automatic regions: {exc}")
                return None
        return self.params.rois()

    def _update_rois(self) -> None:
        rois = self.current_rois()
        auto = self.params.auto_rois.isChecked()
        for name, r in self.regions.items():
            r.setVisible(rois is not None)
            r.setMovable(not auto)
            if rois is not None:
                r.blockSignals(True)
                r.setRegion(rois[name])
                r.blockSignals(False)
        if rois is not None and auto:
            self.params.show_rois(rois)

    def _on_region_dragged(self, name: str) -> None:
        if self.params.auto_rois.isChecked():
            return
        a, b = self.regions[name].getRegion()
        a, b = int(round(a)), int(round(b))
        self.params.show_rois({name: (a - a % 2, b + b % 2)})
        self._on_params_changed()

    def _on_params_changed(self) -> None:
        self._update_rois()
        self.request_preview()
        if self.lut_button.isChecked():
            self._on_lut_toggled(True)

    def request_preview(self) -> None:
        """Detect both stripes on the shown frame with the current parameters, in the
        background (newer requests supersede older ones)."""
        rois = self.current_rois()
        if self.video is None or rois is None or not self.show_stripes.isChecked():
            self.view.set_stripes(None)
            return
        p = self.params.params()
        sp = StripeParams(method=p.method, rois=rois, min_peak=p.min_peak, subpixel=p.subpixel)
        try:
            sp.validate(self.video.size[1])
        except ImpressError as exc:
            self.stripe_label.setText(str(exc))
            return
        k, rgb = self.current_frame, self._rgb
        if rgb is None:
            return
        key = (p.frame_start, p.frame_stop, tuple(sorted(rois.items())))
        cached = self.lut if key == self._lut_key else None
        need_lut = p.method in ("lut", "combined") or self.lut_button.isChecked()
        path = self.video_path

        # off the GUI thread: the frame as an RGB array and the video's path (the tables are
        # learned through a reader of their own), never a reader of the GUI thread
        def task(_progress, cancel):
            table = cached
            if table is None and need_lut:
                table = learn_lut(path, p.frame_start, p.frame_stop, rois, p.lut_frames, cancel)
            found = detect(rgb, sp, table if p.method != "hue" else None)
            return k, key, table, {n: r.rows for n, r in found.items()}

        self.previewer.submit(task)

    def _on_preview(self, result) -> None:
        k, key, table, rows = result
        if table is not None:
            self.lut, self._lut_key = table, key
            if self.lut_button.isChecked():
                self.lut_view.set_tables(table.tables)
                self.lut_ready.emit()
        if k != self.current_frame:
            return
        self.last_stripes = rows
        self.view.set_stripes(rows if self.show_stripes.isChecked() else None)
        w = self.video.size[0] if self.video else 1
        found = ", ".join(
            f"{n} {int(np.isfinite(r).sum())} of {w} columns" for n, r in rows.items()
        )
        self.stripe_label.setText(f"Detected on frame {k}: {found}")
        self.preview_ready.emit(k)

    def _on_lut_toggled(self, on: bool) -> None:
        self.lut_view.setVisible(on)
        if on and self.lut is not None:
            self.lut_view.set_tables(self.lut.tables)
            self.lut_ready.emit()
        elif on:
            self.request_preview()  # learns the tables on the way

    # ----- run --------------------------------------------------------------------------------
    def output_folder(self) -> Path | None:
        """``<project>/reconstructions/recon-<date-time>``; a chosen folder for a project
        that has not been saved yet."""
        if self.project.root is not None:
            return new_output_folder(self.project.root / "reconstructions")
        chosen = self.dialogs.directory(
            "Choose a folder for the reconstruction (or save the project first)"
        )
        return new_output_folder(Path(chosen)) if chosen else None

    def run(self, out_dir: str | Path | None = None) -> bool:
        """Start the reconstruction; False (with a message) when inputs are missing."""
        video, cal = self.video_path, self.calibration
        if video is None or cal is None:
            self.messenger.warning(
                "Cannot run",
                "The project needs its video and a "
                "calibration (Calibration tab, or 'Use a calibration "
                "file').",
            )
            return False
        params = self.params.params()
        try:
            params.validate()
        except ImpressError as exc:
            self.messenger.exception("Check the parameters", exc)
            return False
        out = Path(out_dir) if out_dir else self.output_folder()
        if out is None:
            return False
        cal_path = out.parent / f"{out.name}.calibration.json"
        fps = self.video.fps if self.video is not None else None
        ref, ref_path = self.project.video, self.project.video_path()
        # the evidence registered in the project: refuse to process it once it has changed
        expected = ref.sha256 if ref and ref_path and ref_path.resolve() == video else None

        growing, grid = self.growing, self.growing_grid

        def preview(height, spec=None) -> None:  # the core's preview callback, on its thread
            if spec is not None:
                grid.emit(spec)
            growing.emit(height)

        def task(progress, cancel):
            return reconstruct_into(
                video,
                cal,
                cal_path,
                out,
                params,
                fps,
                progress,
                cancel,
                expected_video_sha256=expected,
                preview=preview,  # queued to the GUI thread
            )

        self.run_panel.output_label.setText(f"Output: {out}")
        xy = np.asarray(cal.corners_parallax_mm, float)[:, :2]
        self.run_panel.growing.set_target(
            (xy[:, 0].min(), xy[:, 0].max(), xy[:, 1].min(), xy[:, 1].max())
        )
        self.run_panel.start()
        self._out = out
        self.worker.start(task)
        self.status.emit(f"Reconstructing into {out}...")
        self._refresh()
        return True

    def cancel(self) -> None:
        self.worker.cancel()

    def _on_finished(self, result) -> None:
        meta, sha = result
        out = self._out
        # the frame loop's own rate (the bar's estimate needs two progress messages, and a
        # short run may send only one)
        self.run_panel.stop(
            "finished", meta.get("run", {}).get("timings", {}).get("frames_per_second")
        )
        self._refresh()
        self.project.set_processing(self.params.params().to_json() | {"output": str(out)})
        self.last_output = out
        # recorded in the project; the viewer follows the session and shows it
        self.session.add_reconstruction(out, sha)
        self.changed.emit()
        warnings = meta.get("warnings") or []
        stats = meta.get("stats", {})
        self.status.emit(
            f"Reconstruction written to {out} ({stats.get('cells_fused', 0)} "
            f"cells with data)" + (f"; {len(warnings)} warning(s)" if warnings else "")
        )
        if warnings:
            self.messenger.warning("Reconstruction warnings", "\n".join(warnings))
        self.reconstructed.emit(str(out))

    def _on_failed(self, code: str, message: str) -> None:
        self.run_panel.stop("failed")
        self._refresh()
        self.messenger.error("The reconstruction failed", message, code)
        self.status.emit(f"Reconstruction failed [{code}]")

    def _on_cancelled(self) -> None:
        self.run_panel.stop("cancelled")
        self._refresh()
        self.status.emit("Reconstruction cancelled; nothing was written")

    def _refresh(self) -> None:
        cal = self.calibration
        if cal is None:
            self.cal_label.setText(
                "Calibration: none - calibrate in the Calibration tab or use a calibration file"
            )
        else:
            self.cal_label.setText(
                f"Calibration: roll {cal.roll_deg:.2f}°, tilt "
                f"{cal.tilt_deg:.2f}°, speed {cal.speed_mm_s:.4f} mm/s, "
                f"reprojection RMS {cal.reprojection_rms_px:.2f} px"
            )
        busy = self.worker.is_running()
        self.run_panel.run_button.setEnabled(
            not busy and self.video is not None and cal is not None
        )
        self.run_panel.cancel_button.setEnabled(busy)
        self.params.setEnabled(not busy)
