"""Import and export of corner picks and calibrations as files (for the command line and for
exchange); the project itself keeps them too. A mixin of :class:`CalibrationTab`."""

from __future__ import annotations

from impress_gui.core.errors import ImpressError
from impress_gui.core.picks import Picks
from impress_gui.ui.calibration_setup import JSON_FILTER


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
