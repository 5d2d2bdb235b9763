"""The motor's limits (Qt-free): every value the driver would send is checked here first, and a
refused value raises a coded :class:`~impress_gui.hardware.motor_status.MotorRangeError`
subclass before anything reaches the serial line.

* positions: finite numbers within the rail's travel (:class:`~impress_gui.hardware.rail.RailLimits`,
  0 to 1770 mm from home by default), and pulse counts the controller's 32-bit position
  register can hold (``E-MOTOR-LIMIT``); a relative move is checked by where it ends;
* speeds: finite, more than zero, at least one speed unit once rounded, at most the rail's
  maximum (``E-MOTOR-SPEED``);
* anything that is not a finite number, or not a whole number where the motor needs one
  (``E-MOTOR-VALUE``);
* program lines (``P1.1=-40000``, ``S1.1=4``) as far as they can be read: stored positions and
  speeds obey the same limits; banks are numbered 1 to 30 (``E-MOTOR-RANGE``).

:class:`~impress_gui.hardware.cool_muscle.CoolMuscle` calls these on every move; the command
line and the window call them too, to refuse a request before opening the port.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Iterable

from impress_gui.hardware.motor_status import (
    MotorLimitError,
    MotorRangeError,
    MotorSettingsError,
    MotorSpeedError,
    MotorValueError,
)
from impress_gui.hardware.rail import POSITION_TOLERANCE_MM, RailLimits
from impress_gui.hardware.units import MotorUnits

#: the range of the controller's position (and any other) register: signed 32 bits
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
#: the motor's program banks
BANKS = range(1, 31)

_ASSIGN_RE = re.compile(r"^(?P<op>[A-Za-z]+)(?P<num>\d*)(?:\.(?P<id>\d+))?\s*=(?P<value>.*)$")


def _shown(value: object) -> str:
    """A value as the user wrote it: ``nan``, ``inf``, ``1e+09``, ``'abc'`` (never a type name)."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        try:
            return f"{float(value):g}"
        except OverflowError:
            return "a number too large to use"
    if isinstance(value, str):
        return repr(value)
    return "something that is not a number"


def _mm(value: float) -> str:
    return f"{value:.2f}" if abs(value) < 1e6 else f"{value:.3g}"


def finite_number(value: object, what: str, unit: str) -> float:
    """``value`` as a float, or :class:`MotorValueError` if it is not a finite number."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise MotorValueError(f"the {what} must be a number of {unit}, got {_shown(value)}")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise MotorValueError(f"the {what} must be a finite number of {unit}, got {_shown(value)}")
    return number


def whole_number(value: object, what: str) -> int:
    """``value`` as an int, or :class:`MotorValueError` if it is not a whole number."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise MotorValueError(f"the {what} must be a whole number, got {_shown(value)}")
    return int(value)


def check_position_mm(
    position_mm: object, limits: RailLimits, what: str = "target position"
) -> float:
    """A position in mm from home that lies within the rail's travel."""
    position = finite_number(position_mm, what, "mm")
    if not -POSITION_TOLERANCE_MM <= position <= limits.travel_mm + POSITION_TOLERANCE_MM:
        raise MotorLimitError(
            f"the {what} {_mm(position)} mm is outside the rail's travel "
            f"(0 to {limits.travel_mm:g} mm from home)"
        )
    return position


def check_distance_mm(distance_mm: object, limits: RailLimits) -> float:
    """A distance for a relative move: finite and no longer than the travel. Where the move
    ends is checked with :func:`check_move_by_mm` once the current position is known."""
    distance = finite_number(distance_mm, "distance", "mm")
    if abs(distance) > limits.travel_mm + POSITION_TOLERANCE_MM:
        raise MotorLimitError(
            f"a move by {_mm(distance)} mm is longer than the rail's travel "
            f"({limits.travel_mm:g} mm)"
        )
    return distance


def check_move_by_mm(here_mm: float, distance_mm: object, limits: RailLimits) -> float:
    """The absolute target of a move by ``distance_mm`` from ``here_mm``, within the travel."""
    distance = check_distance_mm(distance_mm, limits)
    target = here_mm + distance
    if not -POSITION_TOLERANCE_MM <= target <= limits.travel_mm + POSITION_TOLERANCE_MM:
        raise MotorLimitError(
            f"a move by {distance:+.2f} mm from {_mm(here_mm)} mm would end at {_mm(target)} mm, "
            f"outside the rail's travel (0 to {limits.travel_mm:g} mm from home)"
        )
    return target


def check_target_pulses(target_pulses: object, units: MotorUnits, limits: RailLimits) -> int:
    """A target in encoder pulses: a whole number the controller can hold, within the travel."""
    target = whole_number(target_pulses, "target position in pulses")
    if not INT32_MIN <= target <= INT32_MAX:
        raise MotorLimitError(
            f"the target {target} pulses is beyond the motor controller's position counter "
            f"({INT32_MIN} to {INT32_MAX} pulses)"
        )
    low, high = sorted((units.mm_to_pulses(0.0), units.mm_to_pulses(limits.travel_mm)))
    if not low <= target <= high:
        raise MotorLimitError(
            f"the target {target} pulses ({_mm(units.pulses_to_mm(target))} mm) is outside the "
            f"rail's travel (0 to {limits.travel_mm:g} mm from home: {low} to {high} pulses)"
        )
    return target


def check_speed_units(speed_units: object, units: MotorUnits, limits: RailLimits) -> int:
    """A speed as the motor's ``S`` value: a whole number from 1 to the rail's maximum."""
    value = whole_number(speed_units, "speed value S")
    if value < 1:
        raise MotorSpeedError(f"the speed value S must be at least 1, got {value}")
    speed = units.units_to_speed_mm_s(value)
    if speed > limits.max_speed_mm_s * (1 + 1e-9):
        raise MotorSpeedError(
            f"S = {value} is {speed:.2f} mm/s, faster than the rail's maximum of "
            f"{limits.max_speed_mm_s:g} mm/s"
        )
    return value


def check_speed_mm_s(speed_mm_s: object, units: MotorUnits, limits: RailLimits) -> int:
    """A speed in mm/s within the rail's range; returns the motor's ``S`` value (rounded to the
    nearest whole speed unit, which must not be faster than the maximum either)."""
    speed = finite_number(speed_mm_s, "speed", "mm/s")
    if speed <= 0:
        raise MotorSpeedError(f"the speed must be more than 0 mm/s, got {speed:g} mm/s")
    if speed > limits.max_speed_mm_s:
        raise MotorSpeedError(
            f"the speed {speed:g} mm/s is faster than the rail's maximum of "
            f"{limits.max_speed_mm_s:g} mm/s"
        )
    value = int(round(speed * units.pulses_per_mm / units.speed_unit_pulses_s))
    if value < 1:
        one = units.units_to_speed_mm_s(1)
        raise MotorSpeedError(
            f"the speed {speed:g} mm/s is slower than the motor can run: its slowest speed is "
            f"one speed unit, {one:.2f} mm/s"
        )
    try:
        return check_speed_units(value, units, limits)
    except MotorSpeedError:
        actual = units.units_to_speed_mm_s(value)
        raise MotorSpeedError(
            f"the speed {speed:g} mm/s runs at {actual:.2f} mm/s in whole speed units, faster "
            f"than the rail's maximum of {limits.max_speed_mm_s:g} mm/s"
        ) from None


def check_bank(bank: object) -> int:
    """A program bank number, 1 to 30."""
    number = whole_number(bank, "bank number")
    if number not in BANKS:
        raise MotorRangeError(f"the bank must be 1 to 30, got {number}")
    return number


def check_program_line(line: str, units: MotorUnits, limits: RailLimits) -> None:
    """A command or program line as far as it can be read: a stored or immediate position
    (``P.1=...``, ``P2.1=...``) and speed (``S.1=...``) obey the limits, and every value fits
    the controller's 32-bit registers. Other lines pass unchecked."""
    m = _ASSIGN_RE.match(line.strip())
    if m is None:
        return
    op, raw = m["op"].upper(), m["value"].strip()
    if not re.fullmatch(r"[+-]?\d+", raw):
        raise MotorValueError(f"in {line.strip()!r}: the value must be a whole number")
    value = int(raw) if len(raw) <= 20 else INT32_MAX + 1
    try:
        if op == "P":
            check_target_pulses(value, units, limits)
        elif op == "S":
            check_speed_units(value, units, limits)
        elif not INT32_MIN <= value <= INT32_MAX:
            raise MotorValueError(
                f"the value {value} is beyond the motor controller's registers "
                f"({INT32_MIN} to {INT32_MAX})"
            )
    except MotorRangeError as exc:
        raise type(exc)(f"in {line.strip()!r}: {exc}") from None


def check_program(lines: Iterable[str], units: MotorUnits, limits: RailLimits) -> list[str]:
    """Every line of a program (see :func:`check_program_line`); returns them as a list."""
    lines = list(lines)
    for line in lines:
        check_program_line(line, units, limits)
    return lines


def check_rail_fits(units: MotorUnits, limits: RailLimits) -> None:
    """The travel, in pulses, fits the controller's 32-bit position counter."""
    end = units.mm_to_pulses(limits.travel_mm)
    if not INT32_MIN <= end <= INT32_MAX:
        raise MotorSettingsError(
            f"a travel of {limits.travel_mm:g} mm at {units.pulses_per_mm:g} pulses per mm is "
            f"{abs(end)} pulses, more than the motor controller's position counter can hold "
            f"({INT32_MAX})"
        )
