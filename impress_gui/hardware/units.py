"""Units of the rail motor: millimetres and mm/s for people, pulses and speed units for the motor.

Published sources disagree on the Cool Muscle's pulses per revolution and on the size of one
speed unit (both depend on the resolution parameter K37), so nothing here is a constant: a
:class:`MotorUnits` record carries the values, and two helpers derive them from measurements:

* :func:`pulses_per_mm_from_measurement` - command a move of N pulses, measure how far the
  carriage went with a ruler, and get pulses per millimetre;
* :func:`speed_from_video_mm_s` - the thesis' speed check: count the video frames the laser
  line takes to pass between two marks a known distance apart, and get the real speed in mm/s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from impress_gui.core.base.errors import InputError


@dataclass(frozen=True)
class MotorUnits:
    """Conversion between the user's millimetres and the motor's pulses.

    ``pulses_per_mm``: encoder pulses per millimetre of carriage travel (calibrate it).
    ``speed_unit_pulses_s``: pulses per second of one unit of the motor's ``S`` value.
    ``accel_unit_pulses_s2``: pulses per second squared of one unit of the ``A`` value.
    ``direction``: +1 if a positive distance along the scan is a positive pulse count, -1 if it
    is negative (the thesis' program moves towards negative pulses).

    The defaults come from the thesis' stored program (a 50 cm run ends 39 000 pulses past the
    home position, so about 78 pulses/mm) and the most common reading of the manual (one speed
    unit = 100 pulses/s). Both must be checked on the rig: see ``docs/motor.md``.
    """

    pulses_per_mm: float = 78.0
    speed_unit_pulses_s: float = 100.0
    accel_unit_pulses_s2: float = 1000.0
    direction: int = -1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.pulses_per_mm) and self.pulses_per_mm > 0):
            raise InputError(f"pulses per mm must be positive, got {self.pulses_per_mm}")
        if not (math.isfinite(self.speed_unit_pulses_s) and self.speed_unit_pulses_s > 0):
            raise InputError(f"speed unit must be positive, got {self.speed_unit_pulses_s}")
        if not (math.isfinite(self.accel_unit_pulses_s2) and self.accel_unit_pulses_s2 > 0):
            raise InputError(f"acceleration unit must be positive, got {self.accel_unit_pulses_s2}")
        if self.direction not in (1, -1):
            raise InputError(f"direction must be +1 or -1, got {self.direction}")

    def mm_to_pulses(self, position_mm: float) -> int:
        """Position (or distance) in mm -> the nearest whole number of pulses."""
        return int(round(position_mm * self.pulses_per_mm * self.direction))

    def pulses_to_mm(self, pulses: float) -> float:
        return float(pulses) / self.pulses_per_mm * self.direction + 0.0  # no -0.0

    def speed_to_units(self, speed_mm_s: float) -> int:
        """Speed in mm/s -> the motor's integer ``S`` value (at least 1)."""
        if not (math.isfinite(speed_mm_s) and speed_mm_s > 0):
            raise InputError(f"speed must be a positive number of mm/s, got {speed_mm_s}")
        return max(1, int(round(speed_mm_s * self.pulses_per_mm / self.speed_unit_pulses_s)))

    def units_to_speed_mm_s(self, speed_units: float) -> float:
        return float(speed_units) * self.speed_unit_pulses_s / self.pulses_per_mm

    def speed_pulses_s(self, speed_units: float) -> float:
        return float(speed_units) * self.speed_unit_pulses_s

    def accel_pulses_s2(self, accel_units: float) -> float:
        return float(accel_units) * self.accel_unit_pulses_s2


def move_duration_s(distance_pulses: float, speed_pulses_s: float, accel_pulses_s2: float) -> float:
    """Time of a trapezoidal (or, if short, triangular) move from rest to rest, in seconds."""
    d = abs(float(distance_pulses))
    if d == 0:
        return 0.0
    if speed_pulses_s <= 0 or accel_pulses_s2 <= 0:
        raise InputError("speed and acceleration must be positive")
    d_ramps = speed_pulses_s**2 / accel_pulses_s2  # both ramps together
    if d <= d_ramps:
        return 2.0 * math.sqrt(d / accel_pulses_s2)
    return 2.0 * speed_pulses_s / accel_pulses_s2 + (d - d_ramps) / speed_pulses_s


def pulses_per_mm_from_measurement(commanded_pulses: float, measured_mm: float) -> float:
    """Pulses per mm from a commanded move of ``commanded_pulses`` that measured ``measured_mm``.

    The sign is ignored (use :attr:`MotorUnits.direction` for the sense of travel).
    """
    if not (math.isfinite(measured_mm) and abs(measured_mm) > 0):
        raise InputError("the measured distance must be a non-zero number of mm")
    if not (math.isfinite(commanded_pulses) and abs(commanded_pulses) > 0):
        raise InputError("the commanded move must be a non-zero number of pulses")
    ppm = abs(float(commanded_pulses)) / abs(float(measured_mm))
    if not (math.isfinite(ppm) and PULSES_PER_MM_RANGE[0] <= ppm <= PULSES_PER_MM_RANGE[1]):
        # 1e300 pulses over 1e-300 mm gave "pulses per mm: inf"
        raise InputError(f"{abs(commanded_pulses):g} pulses over {abs(measured_mm):g} mm is "
                         f"{ppm:g} pulses per mm: no rail drive has that (give a measurement "
                         f"of {PULSES_PER_MM_RANGE[0]:g} to {PULSES_PER_MM_RANGE[1]:g} per mm)")
    return ppm


#: pulses per mm a measured calibration may give (the Cool Muscle on its rail: about 78)
PULSES_PER_MM_RANGE = (0.01, 1.0e6)


def speed_unit_from_measurement(
    speed_units: float, measured_speed_mm_s: float, pulses_per_mm: float
) -> float:
    """Pulses/s of one speed unit, from a move at ``S = speed_units`` measured at mm/s."""
    if speed_units <= 0 or measured_speed_mm_s <= 0 or pulses_per_mm <= 0:
        raise InputError("speed units, measured speed and pulses per mm must be positive")
    return measured_speed_mm_s * pulses_per_mm / speed_units


def speed_from_video_mm_s(distance_mm: float, frames: float, fps: float) -> float:
    """The thesis' speed check: marks ``distance_mm`` apart passed in ``frames`` frames at ``fps``.

    Frames are counted from the frame where the line touches the first mark to the frame where it
    touches the second, so the elapsed time is ``frames / fps`` seconds.
    """
    if not (math.isfinite(distance_mm) and distance_mm > 0):
        raise InputError("the distance between the marks must be positive")
    if not (math.isfinite(frames) and frames > 0):
        raise InputError("the number of frames must be positive")
    if not (math.isfinite(fps) and fps > 0):
        raise InputError("the frame rate must be positive")
    return distance_mm * fps / frames
