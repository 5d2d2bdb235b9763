"""The Cool Muscle CM1's serial link (Qt-free): the driver's settings, port names (``sim`` for
the simulated motor), the emulator's ``cm1emu://`` URL, opening and listing ports, and
:class:`MotorLink`, the line level the driver builds on (commands out, reply lines in, echoes
and unsolicited lines skipped). Re-exported by :mod:`impress_gui.hardware.cool_muscle`.
"""

from __future__ import annotations

import errno
import os
import re
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import serial

from impress_gui.hardware.motor_limits import check_rail_fits
from impress_gui.hardware.motor_status import (
    MotorDisconnected,
    MotorGarbage,
    MotorNotConnected,
    MotorPortError,
    MotorSettingsError,
    MotorStatus,
    MotorTimeout,
)
from impress_gui.hardware.rail import RailLimits
from impress_gui.hardware.units import MotorUnits

SIMULATED_PORT_NAMES = ("sim", "simulated", "simulated motor")
EMULATOR_SCHEME = "cm1emu://"


@dataclass(frozen=True)
class MotorConfig:
    """Link and behaviour settings of the driver. Times in seconds of wall clock.

    ``limits`` are the rail's travel and maximum speed, which the driver enforces on every move
    (:mod:`impress_gui.hardware.motor_limits`); a travel whose far end in pulses the motor
    controller cannot hold raises ``E-MOTOR-SETTINGS``.
    """

    motor_id: int = 1
    baudrate: int = 38400
    bytesize: int = 8
    parity: str = "N"
    stopbits: float = 1
    units: MotorUnits = field(default_factory=MotorUnits)
    accel_units: int = 100
    reply_timeout_s: float = 1.0
    poll_interval_s: float = 0.05
    move_timeout_factor: float = 1.5
    move_timeout_margin_s: float = 5.0
    home_timeout_s: float = 300.0
    bank_timeout_s: float = 600.0
    in_position_tolerance_pulses: int = 20
    stop_on_connect: bool = True
    limits: RailLimits = field(default_factory=RailLimits)

    def __post_init__(self) -> None:
        if not isinstance(self.limits, RailLimits):
            raise MotorSettingsError("the motor settings hold no usable rail limits")
        check_rail_fits(self.units, self.limits)


class SerialLike(Protocol):
    """What the driver needs of a port (a pyserial port has it all)."""

    def write(self, data: bytes, /) -> int | None: ...
    def read(self, size: int = 1, /) -> bytes: ...
    @property
    def in_waiting(self) -> int: ...
    def close(self) -> None: ...


#: what a failing port's error number means, in the user's words
_ERRNO_WORDS = {
    errno.ENOENT: "there is no such port (impress motor ports lists them)",
    errno.EACCES: "permission denied (on Linux, join the dialout group)",
    errno.EPERM: "permission denied (on Linux, join the dialout group)",
    errno.EBUSY: "the port is in use by another program",
    errno.ENOTTY: "this is not a serial port",
    errno.ENXIO: "no device answers at this port (is the adapter plugged in?)",
    errno.ENODEV: "no device answers at this port (is the adapter plugged in?)",
    errno.EIO: "input/output error (was the adapter unplugged?)",
    errno.ECONNREFUSED: "nothing accepts connections at that address",
    errno.ETIMEDOUT: "the connection timed out",
}
_ERRNO_RE = re.compile(r"\[Errno (\d+)\]|\((\d+), '")


def plain_reason(exc: BaseException) -> str:
    """Why a port failed, in plain words: no error numbers, no names of exception classes."""
    number = getattr(exc, "errno", None)
    if not isinstance(number, int):
        m = _ERRNO_RE.search(str(exc))
        number = int(m[1] or m[2]) if m else None
    if number in _ERRNO_WORDS:
        return _ERRNO_WORDS[number]
    if number:
        return os.strerror(number).lower()
    return re.sub(r"\[Errno \d+\]\s*", "", str(exc)).strip() or "no reason given"


def resolve_port_url(port: str) -> str:
    """``sim`` (or ``Simulated motor``) -> the emulator URL; anything else unchanged."""
    return EMULATOR_SCHEME if port.strip().lower() in SIMULATED_PORT_NAMES else port.strip()


def emulator_url(config: MotorConfig | None = None, time_scale: float = 1.0) -> str:
    """The ``cm1emu://`` URL of a simulated motor matching ``config`` (id and speed unit)."""
    cfg = config or MotorConfig()
    unit = cfg.units.speed_unit_pulses_s
    return f"{EMULATOR_SCHEME}?id={cfg.motor_id}&time_scale={time_scale:g}&speed_unit={unit:g}"


def open_port(port: str, config: MotorConfig | None = None) -> Any:
    """Open a device path or pyserial URL with the link settings of ``config``."""
    cfg = config or MotorConfig()
    url = resolve_port_url(port)
    if url.lower().startswith(EMULATOR_SCHEME):
        from impress_gui.hardware.emulator import register_url_handler

        register_url_handler()
    try:
        return serial.serial_for_url(
            url,
            baudrate=cfg.baudrate,
            bytesize=cfg.bytesize,
            parity=cfg.parity,
            stopbits=cfg.stopbits,
            timeout=0.02,
            write_timeout=2.0,
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise MotorPortError(f"cannot open motor port {url!r}: {plain_reason(exc)}") from exc


def list_serial_ports() -> list[tuple[str, str]]:
    """``(device, description)`` of the serial ports the system knows (not pseudo-terminals)."""
    from serial.tools import list_ports

    return [(p.device, p.description or p.device) for p in sorted(list_ports.comports())]


_REPLY_RE = re.compile(r"^(?P<key>[A-Za-z]+)\.(?P<id>\d+)=(?P<value>.*)$")
_MAX_UNKNOWN_LINES = 8
_ECHO = "<echo>"
_MAX_LINE_BYTES = 256

TrafficCallback = Callable[[str, str], None]


class MotorLink:
    """The line level of one CM1 link: sends commands, reads CR/LF lines, skips echoes and
    unsolicited lines, and matches query replies.
    :class:`~impress_gui.hardware.cool_muscle.CoolMuscle` builds on it."""

    def __init__(
        self, port: SerialLike, config: MotorConfig, on_traffic: TrafficCallback | None
    ) -> None:
        self.config = config
        self.on_traffic = on_traffic
        self.last_status: MotorStatus | None = None
        self._port: SerialLike | None = port
        self._buf = bytearray()
        self._sent: deque[str] = deque(maxlen=32)

    def _log(self, direction: str, text: str) -> None:
        if self.on_traffic is not None:
            self.on_traffic(direction, text)

    def _write(self, text: str) -> None:
        if self._port is None:
            raise MotorNotConnected("the motor port is closed")
        self._log(">", text)
        self._sent.append(text)
        try:
            self._port.write(text.encode("ascii") + b"\r")
        except serial.SerialTimeoutException as exc:
            raise MotorTimeout(f"writing {text!r} to the motor timed out") from exc
        except (serial.SerialException, OSError) as exc:
            raise MotorDisconnected(
                f"the motor port vanished while writing: {plain_reason(exc)}"
            ) from exc

    def _fill(self, block: bool) -> None:
        assert self._port is not None
        try:
            waiting = self._port.in_waiting
            if waiting or block:
                self._buf += self._port.read(max(1, min(waiting, 4096)))
        except (serial.SerialException, OSError) as exc:
            raise MotorDisconnected(
                f"the motor port vanished while reading: {plain_reason(exc)}"
            ) from exc

    def _pop_line(self) -> str | None:
        while True:
            ends = [i for i in (self._buf.find(b"\r"), self._buf.find(b"\n")) if i >= 0]
            if not ends:
                if len(self._buf) > _MAX_LINE_BYTES:
                    raw = bytes(self._buf[:40])
                    self._buf.clear()
                    raise MotorGarbage(f"the motor sent {raw!r}... without a line end")
                return None
            end = min(ends)
            raw = bytes(self._buf[:end])
            del self._buf[: end + 1]
            if not raw:
                continue
            if any(b < 0x20 or b > 0x7E for b in raw):
                self._log("<", repr(raw))
                raise MotorGarbage(f"the motor sent unreadable bytes {raw[:40]!r}")
            line = raw.decode("ascii").strip()
            if line:
                self._log("<", line)
                return line

    def _read_line(self, deadline_s: float) -> str | None:
        while True:
            line = self._pop_line()
            if line is not None:
                return line
            if time.monotonic() >= deadline_s:
                return None
            self._fill(block=True)

    def _classify(self, line: str) -> tuple[str, str] | None:
        """``(key, value)`` of a reply for this motor, ``(ECHO, "")`` for an echoed command,
        ``None`` for any other line."""
        if line in self._sent:
            self._sent.remove(line)
            return _ECHO, ""
        m = _REPLY_RE.match(line)
        if m is None:
            return None
        if int(m["id"]) != self.config.motor_id:
            return _ECHO, ""  # another motor on a daisy chain: not ours, not garbage
        key, value = m["key"], m["value"].strip()
        if key == "Ux" and re.fullmatch(r"-?\d+", value):
            self.last_status = MotorStatus(int(value))
        return key, value

    def _drain(self) -> None:
        """Handle everything already received (late echoes, unsolicited status lines)."""
        self._fill(block=False)
        while (line := self._pop_line()) is not None:
            self._classify(line)

    def _cmd(self, name: str, value: int | None = None) -> str:
        text = f"{name}.{self.config.motor_id}"
        return text if value is None else f"{text}={int(value)}"

    def _query_int(self, name: str, key: str) -> int:
        self._drain()
        command = self._cmd(name)
        self._write(command)
        deadline = time.monotonic() + self.config.reply_timeout_s
        unknown = 0
        while (line := self._read_line(deadline)) is not None:
            reply = self._classify(line)
            if reply is None or reply[0] != key:
                unknown += reply is None
                if unknown > _MAX_UNKNOWN_LINES:
                    raise MotorGarbage(f"no {key} reply to {command}, only unexpected text")
                continue
            try:
                return int(reply[1])
            except ValueError:
                raise MotorGarbage(f"unreadable reply to {command}: {line!r}") from None
        raise MotorTimeout(f"no reply to {command} within {self.config.reply_timeout_s:g} s")
