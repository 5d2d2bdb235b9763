"""The calibration tab's actions: import/export of picks and calibrations as files (for the
command line and for exchange; the project keeps them too) and the Calibrate action (inputs
checked, then the calibration job in the worker)."""

from __future__ import annotations

from impress_gui.core.base.errors import ImpressError
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.scene import SceneCalibration, check_picks
from impress_gui.session.calibration_jobs import calibrate_task
from impress_gui.ui.calibration.setup import JSON_FILTER


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
