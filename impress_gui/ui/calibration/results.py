"""What a scene calibration found, laid out so a user can judge it: warnings first, then one
line with the numbers that decide (pose, fit, speed check, planes, worst corner), then the
details (each value in full and the corners' residuals) behind a Details button, so that the
whole result fits on a 1920x1080 screen without scrolling."""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QTableWidget,
    QTableWidgetItem,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.calibration.geometry import Intrinsics
from impress_gui.core.calibration.scene import PLANE_WARN_MM, SceneCalibration
from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel

WARN_STYLE = (
    "background: #fff1c2; color: #5a3b00; border: 2px solid #e0a000; "
    "border-radius: 4px; padding: 6px; font-weight: bold"
)
STALE_STYLE = (
    "background: #ffe0e0; color: #700000; border: 2px solid #c00000; "
    "border-radius: 4px; padding: 6px; font-weight: bold"
)
RESIDUAL_WARN_MM = 0.5


def changed_inputs(
    cal: SceneCalibration | None,
    picks_changed: bool,
    speed_mm_s: float,
    intrinsics: Intrinsics | None,
    target: TargetModel | None,
) -> list[str]:
    """Which inputs on screen differ from those the calibration ``cal`` was made with."""
    if cal is None:
        return []
    changed = ["the corner picks"] if picks_changed else []
    if abs(speed_mm_s - cal.speed_mm_s) > 1e-9:
        changed.append("the rail speed")
    if intrinsics is None or intrinsics.to_json() != cal.intrinsics.to_json():
        changed.append("the intrinsics")
    name = cal.inputs.get("target", {}).get("name") if isinstance(cal.inputs, dict) else None
    if name and target is not None and target.name != name:
        changed.append("the target model")
    return changed


def fmt_vanishing_point(vp: np.ndarray) -> str:
    if abs(vp[2]) < 1e-12:
        return f"at infinity, direction ({vp[0]:.3f}, {vp[1]:.3f})"
    return f"({vp[0]:.1f}, {vp[1]:.1f}) px"


def summary_line(cal: SceneCalibration) -> str:
    """The numbers that decide whether a calibration is good, on one line."""
    diff = 100 * (cal.implied_speed_mm_s / cal.speed_mm_s - 1)
    planes = ", ".join(
        f"{name} {f.rms_mm:.3f} mm" for name, f in cal.planes.items() if f is not None
    ) or "none fitted"
    worst = max(cal.corner_residuals_mm, default=float("nan"))
    return (
        f"Roll {cal.roll_deg:+.3f}°, tilt {cal.tilt_deg:+.3f}°, turn about the motion axis "
        f"{cal.cross_tilt_deg:+.3f}° (levelled); reprojection RMS "
        f"{cal.reprojection_rms_px:.3f} px; worst corner {worst:.3f} mm; speed check "
        f"{diff:+.2f} %; plane fit RMS: {planes}"
    )


class CalibrationResults(QGroupBox):
    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Calibration result", parent)
        box = QVBoxLayout(self)
        self.stale_label = QLabel("")
        self.stale_label.setWordWrap(True)
        self.stale_label.setStyleSheet(STALE_STYLE)
        self.stale_label.hide()
        box.addWidget(self.stale_label)
        self.warnings_label = QLabel("")
        self.warnings_label.setWordWrap(True)
        self.warnings_label.setStyleSheet(WARN_STYLE)
        self.warnings_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.warnings_label.hide()
        box.addWidget(self.warnings_label)
        self.empty_label = QLabel(
            "Not calibrated yet: mark the six corners in t1 and t2, then press Calibrate."
        )
        self.empty_label.setWordWrap(True)
        box.addWidget(self.empty_label)
        # the numbers that decide, on one line; the rest behind Details
        head = QHBoxLayout()
        self.summary_label = QLabel("")
        self.summary_label.setWordWrap(True)
        self.summary_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.details_button = QToolButton()
        self.details_button.setText("Details")
        self.details_button.setCheckable(True)
        self.details_button.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextBesideIcon)
        self.details_button.setArrowType(Qt.ArrowType.RightArrow)
        self.details_button.setToolTip("Each value in full and the residual of each corner")
        self.details_button.toggled.connect(self.show_details)
        head.addWidget(self.summary_label, 1)
        head.addWidget(self.details_button, 0, Qt.AlignmentFlag.AlignTop)
        box.addLayout(head)
        self.details = QWidget()
        dbox = QVBoxLayout(self.details)
        dbox.setContentsMargins(0, 0, 0, 0)
        form = QFormLayout()
        form.setVerticalSpacing(2)
        self.values: dict[str, QLabel] = {}
        for key, title in (
            ("roll", "Roll"),
            ("tilt", "Tilt"),
            ("vp", "Vanishing point"),
            ("rms", "Reprojection RMS"),
            ("speed", "Rail speed"),
            ("green", "Green plane"),
            ("red", "Red plane"),
        ):
            lab = QLabel("-")
            lab.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
            lab.setWordWrap(True)
            form.addRow(title, lab)
            self.values[key] = lab
        dbox.addLayout(form)
        self.table = QTableWidget(1, len(CORNER_NAMES))
        self.table.setHorizontalHeaderLabels(list(CORNER_NAMES))
        self.table.setVerticalHeaderLabels(["residual (mm)"])
        self.table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Stretch)
        self.table.setEditTriggers(QTableWidget.EditTrigger.NoEditTriggers)
        self.table.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.table.setVerticalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.table.setFixedHeight(
            self.table.horizontalHeader().sizeHint().height()
            + self.table.verticalHeader().defaultSectionSize()
            + 2 * self.table.frameWidth()
        )
        self.table.setToolTip(
            "Distance of each corner (by motion parallax) from the fitted target model, in mm"
        )
        dbox.addWidget(self.table)
        box.addWidget(self.details)
        self.details.hide()
        self.show_calibration(None)

    def show_details(self, on: bool) -> None:
        """Show (or fold away) each value in full and the corners' residuals."""
        if self.details_button.isChecked() != on:
            self.details_button.setChecked(on)  # toggled comes back here
            return
        self.details_button.setArrowType(
            Qt.ArrowType.DownArrow if on else Qt.ArrowType.RightArrow
        )
        self.details.setVisible(on and self._cal is not None)

    def show_calibration(self, cal: SceneCalibration | None) -> None:
        self._cal = cal
        self.empty_label.setVisible(cal is None)
        self.table.setVisible(cal is not None)
        self.summary_label.setVisible(cal is not None)
        self.details_button.setVisible(cal is not None)
        self.details.setVisible(cal is not None and self.details_button.isChecked())
        self.set_stale(False)
        if cal is None:
            for lab in self.values.values():
                lab.setText("-")
            self.summary_label.setText("")
            self.warnings_label.hide()
            return
        self.summary_label.setText(summary_line(cal))
        v = self.values
        v["roll"].setText(f"{cal.roll_deg:+.3f} deg")
        v["tilt"].setText(f"{cal.tilt_deg:+.3f} deg")
        v["vp"].setText(fmt_vanishing_point(cal.vanishing_point_px))
        v["rms"].setText(f"{cal.reprojection_rms_px:.3f} px (12 picks)")
        diff = 100 * (cal.implied_speed_mm_s / cal.speed_mm_s - 1)
        v["speed"].setText(
            f"entered {cal.speed_mm_s:.4f} mm/s; implied by the target "
            f"{cal.implied_speed_mm_s:.4f} mm/s ({diff:+.2f} %)"
        )
        v["speed"].setStyleSheet("color: #b00000; font-weight: bold" if abs(diff) > 1 else "")
        for name in ("green", "red"):
            f = cal.planes.get(name)
            if f is None:
                v[name].setText("not fitted")
                continue
            ground = getattr(f, "ground_points", 0)  # any object with a plane fit's fields
            v[name].setText(
                f"RMS {f.rms_mm:.3f} mm over {f.n_points} points in "
                f"{len(f.frames)} frames (faces at "
                f"{', '.join(f'{h:g}' for h in f.heights_mm)} mm"
                + (f"; {ground} on the ground beside it)" if ground else ")")
            )
            v[name].setToolTip(getattr(f, "ground_note", ""))
            v[name].setStyleSheet(
                "color: #b00000; font-weight: bold" if f.rms_mm > PLANE_WARN_MM else ""
            )
        for i, r in enumerate(cal.corner_residuals_mm):
            item = QTableWidgetItem(f"{r:.3f}")
            item.setTextAlignment(Qt.AlignmentFlag.AlignCenter)
            if r > RESIDUAL_WARN_MM:
                item.setForeground(Qt.GlobalColor.red)
            self.table.setItem(0, i, item)
        if cal.warnings:
            self.warnings_label.setText("Warning:\n" + "\n".join(f"- {w}" for w in cal.warnings))
            self.warnings_label.show()
        else:
            self.warnings_label.hide()

    def set_stale(self, stale: bool, reason: str = "") -> None:
        self.stale_label.setText(
            f"{reason} This result no longer matches; calibrate again." if stale else ""
        )
        self.stale_label.setVisible(stale)

    def summary(self) -> dict[str, str]:
        """The displayed values (for tests and the status line)."""
        return {k: lab.text() for k, lab in self.values.items()}
