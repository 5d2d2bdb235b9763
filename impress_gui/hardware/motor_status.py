"""What the Cool Muscle CM1 reports, and how talking to it fails (Qt-free): the errors of the
driver, the decoded ``Ux`` status word, a position-and-status snapshot, and the watch that
decides when a running move is over. Re-exported by :mod:`impress_gui.hardware.cool_muscle`.
"""

from __future__ import annotations

from dataclasses import dataclass

from impress_gui.core.base import codes
from impress_gui.core.base.errors import ImpressError


class MotorError(ImpressError):
    """A problem talking to, or reported by, the rail motor."""

    code = codes.E_MOTOR


class MotorTimeout(MotorError):
    """The motor did not answer in time, or a move did not finish in the time its speed implies."""

    code = codes.E_MOTOR_TIMEOUT


class MotorAlarm(MotorError):
    """The motor reports an alarm (over-current, position error, over-temperature, e-stop ...)."""

    code = codes.E_MOTOR_ALARM

    def __init__(self, status: MotorStatus, message: str | None = None) -> None:
        super().__init__(message or f"motor alarm: {', '.join(status.alarms)} (Ux={status.bits})")
        self.status = status


class MotorDisconnected(MotorError):
    """The serial port vanished (cable pulled, adapter unplugged, emulator hung up)."""

    code = codes.E_MOTOR_DISCONNECTED


class MotorNotConnected(MotorError):
    """An operation was asked for before connecting (or after closing)."""

    code = codes.E_MOTOR_NOT_CONNECTED


class MotorGarbage(MotorError):
    """The motor sent bytes that are not its protocol (wrong baud rate, noise, another device)."""

    code = codes.E_MOTOR_GARBAGE


class MotorPortError(MotorError):
    """The port cannot be opened (wrong name, in use, no permission)."""

    code = codes.E_MOTOR_PORT


class MotorRangeError(MotorError):
    """A requested position, speed or bank is out of range. The base of the refusals below:
    a refused command sends nothing to the motor."""

    code = codes.E_MOTOR_RANGE


class MotorLimitError(MotorRangeError):
    """A move would take the carriage outside the rail's travel, or past what the motor
    controller's 32-bit position counter can hold."""

    code = codes.E_MOTOR_LIMIT


class MotorSpeedError(MotorRangeError):
    """A speed outside the rail's speed range: zero or negative, slower than one speed unit,
    or faster than the rail's maximum."""

    code = codes.E_MOTOR_SPEED


class MotorValueError(MotorRangeError):
    """A position, distance, speed or bank that is not a usable number (not a number,
    infinite, or not a whole number where the motor needs one)."""

    code = codes.E_MOTOR_VALUE


class MotorSettingsError(MotorError):
    """A rail or motor setting is unusable (a travel that is not a positive length, a speed
    range that is empty, a travel the controller's position counter cannot hold)."""

    code = codes.E_MOTOR_SETTINGS


class MotorInterrupted(MotorError):
    """A command was ended from outside (terminate signal, closed terminal) during its run;
    the motor was sent a stop first."""

    code = codes.E_MOTOR_INTERRUPTED


#: ``Ux`` bits that are alarms the user must see, with their names.
ALARM_BITS: dict[int, str] = {
    1: "position error overflow",
    2: "over-speed / regeneration over-voltage",
    4: "overload / over-current",
    128: "over temperature",
    512: "emergency stop",
}
#: Other ``Ux`` bits.
FLAG_BITS: dict[int, str] = {
    8: "in position",
    16: "motor free",
    32: "push-mode torque limit",
    256: "push-mode time-out",
}
_ALARM_MASK = sum(ALARM_BITS)


@dataclass(frozen=True)
class MotorStatus:
    """The motor's ``Ux`` status word, decoded. ``Ux = 0`` means running."""

    bits: int

    @property
    def alarm_bits(self) -> int:
        return self.bits & _ALARM_MASK

    @property
    def has_alarm(self) -> bool:
        return self.alarm_bits != 0

    @property
    def alarms(self) -> tuple[str, ...]:
        return tuple(name for bit, name in ALARM_BITS.items() if self.bits & bit)

    @property
    def flags(self) -> tuple[str, ...]:
        return tuple(name for bit, name in FLAG_BITS.items() if self.bits & bit)

    @property
    def emergency_stop(self) -> bool:
        return bool(self.bits & 512)

    @property
    def in_position(self) -> bool:
        return bool(self.bits & 8)

    @property
    def free(self) -> bool:
        return bool(self.bits & 16)

    @property
    def moving(self) -> bool:
        return not (self.has_alarm or self.in_position or self.free)

    @property
    def state(self) -> str:
        """One word for the user: emergency stop, alarm, free, in position or moving."""
        if self.emergency_stop:
            return "emergency stop"
        if self.has_alarm:
            return "alarm"
        if self.free:
            return "free"
        return "in position" if self.in_position else "moving"


@dataclass(frozen=True)
class MotorSnapshot:
    """Position and status read together."""

    position_pulses: int
    position_mm: float
    status: MotorStatus


@dataclass
class MoveWatch:
    """Book-keeping of one running move; :meth:`update` says when it is over."""

    description: str
    target_pulses: int | None
    started_s: float
    timeout_s: float
    seen_moving: bool = False

    def update(self, snap: MotorSnapshot, now_s: float, tolerance_pulses: int) -> bool:
        status = snap.status
        if status.has_alarm:
            raise MotorAlarm(status, f"{self.description}: alarm {', '.join(status.alarms)}")
        if status.moving:
            self.seen_moving = True
        elif status.free:
            raise MotorError(f"{self.description}: the motor was disabled during the move")
        elif status.in_position and (
            self.seen_moving
            or self.target_pulses is None
            or abs(snap.position_pulses - self.target_pulses) <= tolerance_pulses
        ):
            return True
        if now_s - self.started_s > self.timeout_s:
            raise MotorTimeout(f"{self.description}: not finished after {self.timeout_s:.1f} s")
        return False
