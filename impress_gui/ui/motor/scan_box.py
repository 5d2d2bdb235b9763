"""The motor panel's "Scan" box: speed preset and speed, start and end positions with the
short / long presets, the jog step, and a line that says what the scan will do or why it cannot.

Pure widgets, no motor I/O: :class:`~impress_gui.ui.motor.panel.MotorPanel` reads the values.
The rail's speeds, lengths and limits (travel, maximum speed) come from
:mod:`impress_gui.hardware.rail`; the scan is checked with the driver's own checks
(:mod:`impress_gui.hardware.motor_limits`), so what the box accepts the driver does too.
"""

from __future__ import annotations

from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QWidget,
)

from impress_gui.hardware.motor_limits import check_speed_mm_s
from impress_gui.hardware.motor_status import MotorRangeError
from impress_gui.hardware.rail import (
    CUSTOM,
    SPEED_PRESETS_MM_S,
    RailLimits,
    check_scan,
    speed_preset_for,
)
from impress_gui.hardware.units import MotorUnits

ERROR_STYLE = "QLabel { color: #c62828; }"


def _spin(low: float, high: float, value: float, suffix: str, decimals: int = 2) -> QDoubleSpinBox:
    spin = QDoubleSpinBox(minimum=low, maximum=high, decimals=decimals, suffix=suffix)
    spin.setValue(value)
    return spin


class ScanSettingsBox(QGroupBox):
    """See the module docstring. ``changed`` fires on any edit."""

    changed = Signal()

    def __init__(
        self,
        units: MotorUnits,
        *,
        speed_preset: str | None,
        speed_mm_s: float,
        start_mm: float,
        end_mm: float,
        jog_step_mm: float,
        short_scan_mm: float,
        long_scan_mm: float,
        limits: RailLimits,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__("Scan", parent)
        self._units, self.limits, self.travel_mm = units, limits, limits.travel_mm
        self.custom_speed_mm_s = speed_mm_s
        form = QFormLayout(self)

        self.speed_preset_combo = QComboBox()
        for name, value in SPEED_PRESETS_MM_S.items():
            self.speed_preset_combo.addItem(f"{name} ({value:g} mm/s)", name)
        self.speed_preset_combo.addItem(CUSTOM, CUSTOM)
        self.speed_spin = _spin(0.1, limits.max_speed_mm_s, speed_mm_s, " mm/s", decimals=4)
        self.speed_note = QLabel("")
        self.start_spin = _spin(-5000.0, 5000.0, start_mm, " mm")
        self.end_spin = _spin(-5000.0, 5000.0, end_mm, " mm")
        self.short_button = QPushButton(f"Short ({short_scan_mm / 10:g} cm)")
        self.long_button = QPushButton(f"Long ({long_scan_mm / 10:g} cm)")
        for button, length in ((self.short_button, short_scan_mm), (self.long_button, long_scan_mm)):
            button.setToolTip(f"End position = start position + {length:g} mm")
            button.clicked.connect(lambda _=False, n=length: self.fill_length(n))
        presets = QHBoxLayout()
        presets.addWidget(self.short_button)
        presets.addWidget(self.long_button)
        self.range_label = QLabel("")
        self.range_label.setWordWrap(True)
        self.jog_spin = _spin(0.1, 1000.0, jog_step_mm, " mm")

        form.addRow("Speed preset", self.speed_preset_combo)
        form.addRow("Scan speed", self.speed_spin)
        form.addRow("", self.speed_note)
        form.addRow("Start position", self.start_spin)
        form.addRow("End position", self.end_spin)
        form.addRow("Length presets", presets)
        form.addRow("", self.range_label)
        form.addRow("Jog step", self.jog_spin)

        preset = speed_preset if speed_preset is not None else speed_preset_for(speed_mm_s)
        self.choose_speed_preset(preset)
        self.speed_preset_combo.currentIndexChanged.connect(
            lambda _i: self.choose_speed_preset(str(self.speed_preset_combo.currentData()))
        )
        self.speed_spin.valueChanged.connect(self._on_speed_edited)
        for spin in (self.start_spin, self.end_spin, self.jog_spin):
            spin.valueChanged.connect(self._refresh)
        self._refresh()

    # ----------------------------------------------------------------- values

    def speed_preset(self) -> str:
        return str(self.speed_preset_combo.currentData())

    def speed_mm_s(self) -> float:
        return float(self.speed_spin.value())

    def check(self) -> int:
        """Raise the coded refusal if the scan cannot run (start or end outside the travel:
        ``E-MOTOR-LIMIT``; end equal to start: ``E-MOTOR-RANGE``; a speed outside the rail's
        range: ``E-MOTOR-SPEED``); else return the speed value ``S`` the motor will run at."""
        check_scan(self.start_spin.value(), self.end_spin.value(), self.travel_mm)
        return check_speed_mm_s(self.speed_mm_s(), self._units, self.limits)

    def problem(self) -> str:
        """Why a scan from start to end cannot run, or ``""``."""
        try:
            self.check()
        except MotorRangeError as exc:
            return str(exc)
        return ""

    # ----------------------------------------------------------------- edits

    def choose_speed_preset(self, name: str) -> None:
        """Select a preset (``slow``, ``medium``, ``fast``) or ``custom`` (the spin box editable)."""
        index = self.speed_preset_combo.findData(name)
        if index < 0:
            raise ValueError(f"unknown speed preset {name!r}")
        self.speed_preset_combo.blockSignals(True)
        self.speed_preset_combo.setCurrentIndex(index)
        self.speed_preset_combo.blockSignals(False)
        custom = name == CUSTOM
        self.speed_spin.blockSignals(True)
        self.speed_spin.setValue(self.custom_speed_mm_s if custom else SPEED_PRESETS_MM_S[name])
        self.speed_spin.blockSignals(False)
        self.speed_spin.setEnabled(custom)
        self._refresh()

    def fill_length(self, length_mm: float) -> None:
        """The short / long presets: end position = start position + ``length_mm``."""
        self.end_spin.setValue(self.start_spin.value() + length_mm)

    def _on_speed_edited(self, value: float) -> None:
        if self.speed_preset() == CUSTOM:
            self.custom_speed_mm_s = value
        self._refresh()

    def _refresh(self) -> None:
        try:
            units = check_speed_mm_s(self.speed_mm_s(), self._units, self.limits)
        except MotorRangeError:
            units = 0
        actual = self._units.units_to_speed_mm_s(units)
        self.speed_note.setText(f"motor runs at {actual:.2f} mm/s (S = {units})" if units else "")
        problem = self.problem()
        if problem:
            self.range_label.setStyleSheet(ERROR_STYLE)
            self.range_label.setText(f"Cannot scan: {problem}.")
        else:
            length = abs(self.end_spin.value() - self.start_spin.value())
            minutes, seconds = divmod(round(length / actual), 60) if units else (0, 0)
            self.range_label.setStyleSheet("")
            self.range_label.setText(f"runs {length:g} mm in about {minutes} min {seconds:02d} s")
        self.changed.emit()
