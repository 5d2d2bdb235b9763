"""The calibration tab's input and output: the worker tasks that open the scan video
(each on its own video object), the Calibrate action (inputs checked, then the core in the
worker), and the import/export of picks and calibrations as files (for the command line and for
exchange; the project keeps them too)."""

from __future__ import annotations

from pathlib import Path

from impress_gui.core.calib_aids import propose_calibration_frames
from impress_gui.core.calibration import SceneCalibration, calibrate_scene, check_picks
from impress_gui.core.errors import ImpressError, InputError
from impress_gui.core.picks import Picks
from impress_gui.core.progress import CancelToken, ProgressCallback, sub_progress
from impress_gui.core.project import Project, hash_file
from impress_gui.core.video import VideoSource, open_video
from impress_gui.ui.calibration_setup import JSON_FILTER


def open_evidence(
    path: Path, progress: ProgressCallback, cancel: CancelToken, project: Project | None = None
) -> tuple[VideoSource, str]:
    """Open the scan video and fingerprint it (worker thread). With ``project``, check the
    video against the SHA-256 recorded there first (IntegrityError when it changed)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(
            f"{path} is a folder; open the scan's video file (its SHA-256 is recorded as evidence)",
            code="E-VIDEO-OPEN",
        )
    if project is not None:
        digest = project.check_evidence(sub_progress(progress, 0.0, 0.9), cancel)
        return open_video(path), digest
    video = open_video(path)
    try:
        return video, hash_file(path, sub_progress(progress, 0.05, 1.0), cancel)
    except BaseException:
        video.close()
        raise


def propose_task(path: Path):
    def task(progress: ProgressCallback, cancel: CancelToken) -> dict[str, int]:
        with open_video(path) as video:
            return propose_calibration_frames(video, progress=progress, cancel=cancel)

    return task


def calibrate_task(path: Path, intr, target, picks: Picks, speed_mm_s: float, inputs: dict):
    def task(progress: ProgressCallback, cancel: CancelToken):
        with open_video(path) as video:
            return calibrate_scene(
                video,
                intr,
                target,
                picks,
                speed_mm_s,
                progress=progress,
                cancel=cancel,
                inputs=inputs,
            )

    return task


def checkerboard_task(source: Path, board: tuple[int, int] = (9, 6), square_mm: float = 25.0):
    """Camera intrinsics from checkerboard views: ``source`` is a video file or a folder of
    images, ``board`` the inner corners (columns, rows)."""

    def task(progress: ProgressCallback, cancel: CancelToken):
        from impress_gui.core.intrinsics_cal import calibrate_camera

        return calibrate_camera(Path(source), board, square_mm, progress=progress, cancel=cancel)

    return task


class CalibrationFiles:
    """Needs ``messenger``, ``dialogs``, ``editor``, ``project``, ``video_path``,
    ``video_sha256`` and ``calibration`` from the tab."""

    def import_picks(self, path: str | None = None) -> bool:
        path = path or self.dialogs.open_file("Import corner picks", JSON_FILTER)
        if not path:
            return False
        try:
            picks = Picks.load(path)
        except ImpressError as exc:
            self.messenger.exception("Cannot import the picks", exc)
            return False
        if picks.video_sha256 and self.video_sha256 and picks.video_sha256 != self.video_sha256:
            self.messenger.warning(
                "Picks from another video",
                "These picks were made on a video with a different SHA-256; check every corner.",
            )
        self.editor.import_picks(picks)
        self.project.log("picks imported", {"path": str(path)})
        return True

    def export_picks(self, path: str | None = None) -> bool:
        picks = self.editor.to_picks(str(self.video_path or ""), self.video_sha256)
        if picks is None:
            self.messenger.error("Nothing to export", "Choose t1 and t2 and mark corners first.")
            return False
        path = path or self.dialogs.save_file("Export corner picks", JSON_FILTER, "picks.json")
        return bool(path) and self._write("picks", path, picks.save)

    def export_calibration(self, path: str | None = None) -> bool:
        if self.calibration is None:
            self.messenger.error("Nothing to export", "Calibrate first.")
            return False
        path = path or self.dialogs.save_file("Export calibration", JSON_FILTER, "calibration.json")
        return bool(path) and self._write("calibration", path, self.calibration.save)

    def _write(self, what: str, path: str, save) -> bool:
        try:
            save(path)
        except (OSError, ImpressError) as exc:
            self.messenger.error(f"The {what} were not written", f"{path}: {exc}", "E-WRITE")
            return False
        self.project.log(f"{what} exported", {"path": str(path)})
        return True


class SceneCalibrationRuns:
    """The tab's Calibrate action (mixed into the tab). Needs ``setup``, ``editor``, ``video``,
    ``video_path``, ``video_sha256``, ``project``, ``results``, ``messenger``, ``status``,
    ``calibrated``, ``_run``, ``_mark_dirty`` and ``_refresh``."""

    def calibrate(self) -> bool:
        intr, target, speed = self.setup.intrinsics, self.setup.target, self.setup.speed_mm_s()
        picks = self.editor.to_picks(str(self.video_path), self.video_sha256)
        problem = None
        if self.video is None:
            problem = "Load the scan video first."
        elif intr is None:
            problem = "Camera intrinsics are missing: load, enter or calibrate them."
        elif target is None:
            problem = "Choose the target model."
        elif speed <= 0:
            problem = "Enter the rail speed of this scan (mm/s)."
        elif picks is None:
            problem = "Choose the frames t1 and t2 and mark the six corners in each."
        if problem:
            self.messenger.error("Cannot calibrate yet", problem, "E-CALIB-INPUT")
            return False
        try:
            intr.check_image_size(*self.video.size)
            check_picks(picks, intr, self.video.frame_count)
        except ImpressError as exc:
            self.messenger.exception("Cannot calibrate yet", exc)
            return False
        path, state = self.video_path, self.editor.state
        inputs = {
            "video": {"path": str(path), "sha256": self.video_sha256},
            "intrinsics": {"source": intr.source},
            "target": {"name": target.name},
        }

        return self._run(
            "Calibrating",
            calibrate_task(path, intr, target, picks, speed, inputs),
            lambda cal: self._on_calibrated(cal, picks, state),
            "Calibration failed",
        )

    def _on_calibrated(self, cal: SceneCalibration, picks: Picks, state) -> None:
        self.calibration, self._cal_state = cal, state
        self.project.set_picks(picks)
        self.project.set_calibration(cal)
        self.results.show_calibration(cal)
        self._mark_dirty()
        self._refresh()
        self.calibrated.emit(cal)
        self.status.emit(
            f"Calibrated: roll {cal.roll_deg:+.3f} deg, tilt {cal.tilt_deg:+.3f} "
            f"deg, reprojection RMS {cal.reprojection_rms_px:.2f} px"
        )
        if cal.warnings:
            self.messenger.warning("Check the calibration", "\n\n".join(cal.warnings))
