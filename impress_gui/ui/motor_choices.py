"""The motor panel's choices (speed preset, custom speed, start/end, jog step) kept in the
window's QSettings between sessions."""

from __future__ import annotations

from dataclasses import replace

from PySide6.QtCore import QSettings

from impress_gui.hardware.rail import RAIL_TRAVEL_MM, SPEED_PRESETS_MM_S
from impress_gui.ui.motor_panel import MotorPanelSettings

_KEYS = ("speed_preset", "speed_mm_s", "start_mm", "end_mm", "jog_step_mm")


def load_motor_choices(settings: QSettings) -> MotorPanelSettings:
    """The panel's starting settings with the choices saved last time (values that are
    missing or out of range are ignored)."""
    base = MotorPanelSettings()
    found: dict = {}
    preset = settings.value("motor/speed_preset")
    if isinstance(preset, str) and (preset in SPEED_PRESETS_MM_S or preset == "custom"):
        found["speed_preset"] = preset
    for key, lo, hi in (("speed_mm_s", 0.05, 100.0), ("start_mm", 0.0, RAIL_TRAVEL_MM),
                        ("end_mm", 0.0, RAIL_TRAVEL_MM), ("jog_step_mm", 0.01, RAIL_TRAVEL_MM)):
        try:
            value = float(settings.value(f"motor/{key}"))
        except (TypeError, ValueError):
            continue
        if lo <= value <= hi:
            found[key] = value
    return replace(base, **found)


def save_motor_choices(settings: QSettings, choices: MotorPanelSettings) -> None:
    for key in _KEYS:
        value = getattr(choices, key)
        if value is not None:
            settings.setValue(f"motor/{key}", value)
