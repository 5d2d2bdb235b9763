"""The scanner's rail (Qt-free): its travel and speed limits, the thesis' scan speeds and scan
lengths, and the check of a scan's start and end positions.

Positions are millimetres from home along the scan direction, as everywhere in the motor code.
:class:`RailLimits` is the rail's setting that the driver enforces on every move (see
:mod:`impress_gui.hardware.motor_limits`); it travels in
:class:`~impress_gui.hardware.motor_link.MotorConfig` and is saved with the window's motor
settings. The window takes the speeds from here. The simulator (``impress_gui.sim``) keeps its
own copy: it models the physical rail independently of the software that drives it (and its
source is the key of the benchmarks' cached renders); the values must stay equal, which
``tests/test_motor_panel.py`` checks.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import asdict, dataclass

from impress_gui.hardware.motor_status import (
    MotorLimitError,
    MotorRangeError,
    MotorSettingsError,
    MotorValueError,
)

#: the rail's usable travel, mm from home (the 1.77 m rail of the thesis)
RAIL_TRAVEL_MM = 1770.0
#: the longest travel a rail setting may have, mm
MAX_RAIL_TRAVEL_MM = 10_000.0
#: the fastest the carriage may be driven, mm/s: the highest speed the rest of the software
#: accepts for the rail (the simulator's and the window's limit). The thesis' scans run at
#: 1.3 to 13.1 mm/s and the panel moves to a scan's start at 20 mm/s.
RAIL_MAX_SPEED_MM_S = 100.0
#: the highest maximum speed a rail setting may have, mm/s
MAX_RAIL_SPEED_MM_S = 1000.0
#: how far a position given in mm may lie outside the travel and still count as its end
POSITION_TOLERANCE_MM = 0.005

#: the rail's three scan speeds (the thesis' slow, medium and fast), mm/s
SPEED_PRESETS_MM_S: dict[str, float] = {"slow": 1.3138, "medium": 5.2552, "fast": 13.138}
CUSTOM = "custom"

#: the scan lengths of the hardware buttons: short run (shoe) and long run (tire), mm
SCAN_LENGTHS_MM: dict[str, float] = {"short": 500.0, "long": 1700.0}


def _setting(name: str, value: object, low: float, high: float, unit: str) -> None:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise MotorSettingsError(f"the rail's {name} must be a number of {unit}, got {value!r}")
    number = float(value)
    if not (math.isfinite(number) and low < number <= high):
        raise MotorSettingsError(
            f"the rail's {name} must be more than {low:g} and at most {high:g} {unit}, "
            f"got {number:g}"
        )


@dataclass(frozen=True)
class RailLimits:
    """What the driver lets the carriage do on this rail.

    ``travel_mm``: the usable travel, mm from home: every target must lie within 0 to
    ``travel_mm`` (the thesis' rail: 1770 mm). Set it smaller for a shorter rail, or to keep
    the carriage clear of an end stop. ``max_speed_mm_s``: the fastest move, mm/s. The slowest
    is the motor's own: one speed unit (see :class:`~impress_gui.hardware.units.MotorUnits`).
    Invalid values raise :class:`MotorSettingsError` (``E-MOTOR-SETTINGS``).
    """

    travel_mm: float = RAIL_TRAVEL_MM
    max_speed_mm_s: float = RAIL_MAX_SPEED_MM_S

    def __post_init__(self) -> None:
        _setting("travel", self.travel_mm, 0.0, MAX_RAIL_TRAVEL_MM, "mm")
        _setting("maximum speed", self.max_speed_mm_s, 0.0, MAX_RAIL_SPEED_MM_S, "mm/s")

    def to_dict(self) -> dict[str, float]:
        """The settings as plain numbers (for a settings file); :meth:`from_dict` reads them."""
        return {k: float(v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: Mapping[str, object]) -> RailLimits:
        """Limits from saved settings: missing keys take the defaults, numbers may be text."""
        unknown = sorted(set(data) - {"travel_mm", "max_speed_mm_s"})
        if unknown:
            raise MotorSettingsError(f"unknown rail setting(s): {', '.join(unknown)}")
        values: dict[str, float] = {}
        for key, raw in data.items():
            try:
                values[key] = float(raw)  # type: ignore[arg-type]
            except (TypeError, ValueError):
                raise MotorSettingsError(
                    f"the rail setting {key} is not a number: {raw!r}"
                ) from None
        return cls(**values)


def speed_preset_for(speed_mm_s: float) -> str:
    """The name of the preset with this speed, or ``"custom"``."""
    for name, value in SPEED_PRESETS_MM_S.items():
        if math.isclose(speed_mm_s, value, rel_tol=0.0, abs_tol=5e-5):
            return name
    return CUSTOM


def check_scan(start_mm: float, end_mm: float, travel_mm: float = RAIL_TRAVEL_MM) -> None:
    """Raise if a scan from ``start_mm`` to ``end_mm`` cannot run: ``E-MOTOR-VALUE`` for a
    position that is not a number, ``E-MOTOR-LIMIT`` for one outside the travel,
    ``E-MOTOR-RANGE`` for an end equal to the start."""
    for what, value in (("start", start_mm), ("end", end_mm)):
        if not math.isfinite(value):
            raise MotorValueError(f"the {what} position is not a number")
        if not -POSITION_TOLERANCE_MM <= value <= travel_mm + POSITION_TOLERANCE_MM:
            raise MotorLimitError(
                f"the {what} position {value:.2f} mm is outside the rail's travel "
                f"(0 to {travel_mm:g} mm from home)"
            )
    if abs(end_mm - start_mm) < 0.005:
        raise MotorRangeError(
            f"the end position equals the start position ({start_mm:.2f} mm): nothing to scan"
        )
