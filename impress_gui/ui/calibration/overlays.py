"""What the calibration tab draws over a frame: the target as the calibration placed it, and
the laser stripes the detector finds with the calibration's settings (computed off the GUI
thread, newest frame only)."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QObject

from impress_gui.core.calibration.planes import calibration_stripe_params
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.calibration.target import TargetModel
from impress_gui.core.reconstruction.stripes import detect
from impress_gui.ui.frame_view import FrameView
from impress_gui.ui.worker import LatestOnly

STRIPE_CACHE = 48


def fitted_target_px(cal: SceneCalibration, target: TargetModel, time_s: float) -> np.ndarray:
    """Pixels ``(6, 2)`` of the fitted target's corners A-F in the frame at ``time_s``. The
    target's pose was fitted with the travel implied by its size, so that speed places it."""
    travel = cal.implied_speed_mm_s * (time_s - cal.t_ref_s)
    return cal.project_rail(cal.corners_fit_mm(target), travel)


def stripe_rows(rgb: np.ndarray) -> dict[str, np.ndarray]:
    """Each laser's stripe rows in a frame as the calibration's detector finds them (so a
    stripe the overlay shows is one the plane fit can use)."""
    return {name: res.rows for name, res in detect(rgb, calibration_stripe_params()).items()}


class Overlays(QObject):
    def __init__(self, view: FrameView, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.view = view
        self.frame = -1
        self._rows: dict[int, dict[str, np.ndarray]] = {}
        self._show_stripes = True
        self.worker = LatestOnly(self, "stripes")
        self.worker.finished.connect(self._on_rows)

    def update(
        self,
        frame: int,
        rgb: np.ndarray | None,
        time_s: float | None,
        cal: SceneCalibration | None,
        target: TargetModel | None,
        show_target: bool,
        show_stripes: bool,
    ) -> None:
        self.frame, self._show_stripes = frame, show_stripes
        uv = None
        if show_target and cal is not None and target is not None and time_s is not None:
            uv = fitted_target_px(cal, target, time_s)
        self.view.set_reprojection(uv)
        if not show_stripes or rgb is None:
            self.view.set_stripes(None)
        elif frame in self._rows:
            self.view.set_stripes(self._rows[frame])
        else:
            self.view.set_stripes(None)
            self.worker.submit(lambda progress, cancel: (frame, stripe_rows(rgb)))

    def clear(self) -> None:
        self._rows.clear()
        self.frame = -1

    def _on_rows(self, result) -> None:
        frame, rows = result
        self._rows[frame] = rows
        while len(self._rows) > STRIPE_CACHE:
            self._rows.pop(next(iter(self._rows)))
        if frame == self.frame and self._show_stripes:
            self.view.set_stripes(rows)

    def shutdown(self) -> None:
        self.worker.shutdown()
