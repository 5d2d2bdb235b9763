"""The motor panel's choices (speed preset, custom speed, start/end, jog step) and the rail's
limits (travel, maximum speed) kept in the window's QSettings between sessions.

The limits are the ``[rail]`` group of the settings file (``travel_mm``, ``max_speed_mm_s``):
a technician sets them there for a rail other than the thesis' 1770 mm one. They are checked
like any rail setting (:class:`~impress_gui.hardware.rail.RailLimits`); a group that is not a
usable setting is ignored whole, and the default limits apply.
"""

from __future__ import annotations

from dataclasses import replace

from PySide6.QtCore import QSettings

from impress_gui.hardware.motor_status import MotorError
from impress_gui.hardware.rail import SPEED_PRESETS_MM_S, RailLimits
from impress_gui.ui.motor.panel import MotorPanelSettings

_KEYS = ("speed_preset", "speed_mm_s", "start_mm", "end_mm", "jog_step_mm")
_RAIL_KEYS = ("travel_mm", "max_speed_mm_s")


def load_rail_limits(settings: QSettings, default: RailLimits | None = None) -> RailLimits:
    """The rail's limits saved in ``settings`` (missing keys take ``default``'s values)."""
    base = default or RailLimits()
    saved = {key: settings.value(f"rail/{key}") for key in _RAIL_KEYS}
    found = {key: value for key, value in saved.items() if value is not None}
    if not found:
        return base
    try:
        return RailLimits.from_dict({**base.to_dict(), **found})
    except MotorError:
        return base


def load_motor_choices(settings: QSettings) -> MotorPanelSettings:
    """The panel's starting settings with the choices and rail limits saved last time (values
    that are missing or out of range are ignored)."""
    base = MotorPanelSettings()
    found: dict = {}
    limits = load_rail_limits(settings, base.motor.limits)
    try:
        found["motor"] = replace(base.motor, limits=limits)
    except MotorError:  # e.g. a travel the controller cannot count with these units
        limits = base.motor.limits
    preset = settings.value("motor/speed_preset")
    if isinstance(preset, str) and (preset in SPEED_PRESETS_MM_S or preset == "custom"):
        found["speed_preset"] = preset
    travel = limits.travel_mm
    for key, lo, hi in (
        ("speed_mm_s", 0.05, limits.max_speed_mm_s),
        ("start_mm", 0.0, travel),
        ("end_mm", 0.0, travel),
        ("jog_step_mm", 0.01, travel),
    ):
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
    for key, value in choices.motor.limits.to_dict().items():
        settings.setValue(f"rail/{key}", value)
