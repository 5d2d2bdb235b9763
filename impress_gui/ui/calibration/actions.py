"""The calibration tab's actions, each an object given what it uses: import/export of picks and
calibrations as files (:class:`PickFiles`; for the command line and for exchange, the project
keeps them too) and the Calibrate action (:class:`SceneCalibrationAction`: inputs checked, then
the calibration job in the worker). The evidence video, the project and the calibration are the
session's (:class:`~impress_gui.session.session.Session`)."""

from __future__ import annotations

from collections.abc import Callable

from impress_gui.core.base import codes
from impress_gui.core.base.errors import ImpressError
from impress_gui.core.calibration.pick_editor import PickEditor, PickState
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.scene import SceneCalibration, check_picks
from impress_gui.core.formats.provenance import calibration_inputs, input_record
from impress_gui.session.calibration_jobs import calibrate_task
from impress_gui.session.session import Session
from impress_gui.ui.calibration.setup import JSON_FILTER, SetupPanel
from impress_gui.ui.messages import Dialogs, Messenger
from impress_gui.ui.task_bar import TaskBar


class PickFiles:
    """Import and export the corner picks, export the calibration (each logged in the
    project). ``dialogs`` may be replaced (the tab's ``dialogs`` setter does)."""

    def __init__(
        self, messenger: Messenger, dialogs: Dialogs, editor: PickEditor, session: Session
    ) -> None:
        self.messenger, self.dialogs, self.editor, self.session = messenger, dialogs, editor, session

    def _video(self) -> tuple[str, str | None]:
        ev = self.session.evidence
        return ("", None) if ev is None else (str(ev.path), ev.sha256)

    def import_picks(self, path: str | None = None) -> bool:
        path = path or self.dialogs.open_file("Import corner picks", JSON_FILTER)
        if not path:
            return False
        try:
            picks = Picks.load(path)
        except ImpressError as exc:
            self.messenger.exception("Cannot import the picks", exc)
            return False
        _video, sha = self._video()
        if picks.video_sha256 and sha and picks.video_sha256 != sha:
            self.messenger.warning(
                "Picks from another video",
                "These picks were made on a video with a different SHA-256; check every corner.",
            )
        self.editor.import_picks(picks)
        self.session.log("picks imported", {"path": str(path)})
        return True

    def export_picks(self, path: str | None = None) -> bool:
        picks = self.editor.to_picks(*self._video())
        if picks is None:
            self.messenger.error("Nothing to export", "Choose t1 and t2 and mark corners first.")
            return False
        path = path or self.dialogs.save_file("Export corner picks", JSON_FILTER, "picks.json")
        return bool(path) and self._write("picks", path, picks.save)

    def export_calibration(self, path: str | None = None) -> bool:
        cal = self.session.calibration
        if cal is None:
            self.messenger.error("Nothing to export", "Calibrate first.")
            return False
        path = path or self.dialogs.save_file("Export calibration", JSON_FILTER, "calibration.json")
        return bool(path) and self._write("calibration", path, cal.save)

    def _write(self, what: str, path: str, save) -> bool:
        try:
            save(path)
        except (OSError, ImpressError) as exc:
            self.messenger.error(f"The {what} were not written", f"{path}: {exc}", codes.E_WRITE)
            return False
        self.session.log(f"{what} exported", {"path": str(path)})
        return True


CalibratedCallback = Callable[[SceneCalibration, Picks, PickState], None]


class SceneCalibrationAction:
    """The Calibrate action: check the inputs on screen (``setup``, ``editor``) against the
    session's evidence video, then run the calibration job through ``tasks``. The result goes
    to ``on_calibrated(cal, picks, state)``: the calibration, the picks it was made from and the
    editor's state when it started (to tell later whether the picks changed)."""

    def __init__(
        self,
        messenger: Messenger,
        session: Session,
        setup: SetupPanel,
        editor: PickEditor,
        tasks: TaskBar,
        on_calibrated: CalibratedCallback,
    ) -> None:
        self.messenger, self.session, self.setup, self.editor = messenger, session, setup, editor
        self.tasks, self.on_calibrated = tasks, on_calibrated

    def calibrate(self) -> bool:
        intr, target, speed = self.setup.intrinsics, self.setup.target, self.setup.speed_mm_s()
        ev = self.session.evidence
        picks = self.editor.to_picks(str(ev.path) if ev else "", ev.sha256 if ev else None)
        problem = None
        if ev is None:
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
            self.messenger.error("Cannot calibrate yet", problem, codes.E_CALIB_INPUT)
            return False
        try:
            intr.check_image_size(*ev.reader.size)
            check_picks(picks, intr, ev.reader.frame_count)
        except ImpressError as exc:
            self.messenger.exception("Cannot calibrate yet", exc)
            return False
        path, state = ev.path, self.editor.state
        inputs = calibration_inputs(input_record(path, ev.sha256), {"source": intr.source},
                                    target={"name": target.name})

        return self.tasks.run(
            "Calibrating",
            calibrate_task(path, intr, target, picks, speed, inputs),
            lambda cal: self.on_calibrated(cal, picks, state),
            "Calibration failed",
        )
