"""The scanner's rail (Qt-free): its travel, the thesis' scan speeds and scan lengths, and the
check of a scan's start and end positions.

Positions are millimetres from home along the scan direction, as everywhere in the motor code.
The window takes the speeds from here. The simulator (``impress_gui.sim``) keeps its own copy:
it models the physical rail independently of the software that drives it (and its source is
the key of the benchmarks' cached renders); the values must stay equal, which
``tests/test_motor_panel.py`` checks.
"""

from __future__ import annotations

import math

from impress_gui.hardware.motor_status import MotorRangeError

#: the rail's usable travel, mm from home (the 1.77 m rail of the thesis)
RAIL_TRAVEL_MM = 1770.0

#: the rail's three scan speeds (the thesis' slow, medium and fast), mm/s
SPEED_PRESETS_MM_S: dict[str, float] = {"slow": 1.3138, "medium": 5.2552, "fast": 13.138}
CUSTOM = "custom"

#: the scan lengths of the hardware buttons: short run (shoe) and long run (tire), mm
SCAN_LENGTHS_MM: dict[str, float] = {"short": 500.0, "long": 1700.0}


def speed_preset_for(speed_mm_s: float) -> str:
    """The name of the preset with this speed, or ``"custom"``."""
    for name, value in SPEED_PRESETS_MM_S.items():
        if math.isclose(speed_mm_s, value, rel_tol=0.0, abs_tol=5e-5):
            return name
    return CUSTOM


def scan_problem(start_mm: float, end_mm: float, travel_mm: float = RAIL_TRAVEL_MM) -> str:
    """Why a scan from ``start_mm`` to ``end_mm`` cannot run, or ``""`` when it can."""
    for what, value in (("start", start_mm), ("end", end_mm)):
        if not math.isfinite(value):
            return f"the {what} position is not a number"
        if not -0.005 <= value <= travel_mm + 0.005:
            return (
                f"the {what} position {value:.2f} mm is outside the rail's travel "
                f"(0 to {travel_mm:g} mm from home)"
            )
    if abs(end_mm - start_mm) < 0.005:
        return f"the end position equals the start position ({start_mm:.2f} mm): nothing to scan"
    return ""


def check_scan(start_mm: float, end_mm: float, travel_mm: float = RAIL_TRAVEL_MM) -> None:
    """Raise :class:`MotorRangeError` (``E-MOTOR-RANGE``) if the scan cannot run."""
    problem = scan_problem(start_mm, end_mm, travel_mm)
    if problem:
        raise MotorRangeError(problem)
