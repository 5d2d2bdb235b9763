"""Driver for the Cool Muscle CM1 servo that moves the scanner's camera along its rail.

Qt-free. A :class:`CoolMuscle` wraps any serial-like object (``read``, ``write``, ``in_waiting``,
``close``): a real port, a ``socket://`` URL, or the software motor of
:mod:`impress_gui.hardware.emulator`. Commands carry the motor-id suffix (``P.1=5000``), replies
are CR/LF-terminated lines, echoed commands and unsolicited status lines (``Ux.1=8``) are
recognised and skipped. The protocol knowledge and its uncertainties are in ``docs/motor.md``.

Every failure raises a :class:`MotorError` subclass with a stable code, and before it propagates
the driver sends a stop where the link still allows it, so an error never leaves the carriage
moving under software control. Public methods are serialised by a lock, so one driver may be
used from a worker thread while another thread asks it to :meth:`CoolMuscle.stop`.
"""

from __future__ import annotations

import re
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Protocol

import serial

from impress_gui.core.errors import Cancelled, ImpressError
from impress_gui.core.progress import CancelToken
from impress_gui.hardware.units import MotorUnits, move_duration_s

SIMULATED_PORT_NAMES = ("sim", "simulated", "simulated motor")
EMULATOR_SCHEME = "cm1emu://"


class MotorError(ImpressError):
    """A problem talking to, or reported by, the rail motor."""

    code = "E-MOTOR"


class MotorTimeout(MotorError):
    """The motor did not answer in time, or a move did not finish in the time its speed implies."""

    code = "E-MOTOR-TIMEOUT"


class MotorAlarm(MotorError):
    """The motor reports an alarm (over-current, position error, over-temperature, e-stop ...)."""

    code = "E-MOTOR-ALARM"

    def __init__(self, status: MotorStatus, message: str | None = None) -> None:
        super().__init__(message or f"motor alarm: {', '.join(status.alarms)} (Ux={status.bits})")
        self.status = status


class MotorDisconnected(MotorError):
    """The serial port vanished (cable pulled, adapter unplugged, emulator hung up)."""

    code = "E-MOTOR-DISCONNECTED"


class MotorNotConnected(MotorError):
    """An operation was asked for before connecting (or after closing)."""

    code = "E-MOTOR-NOT-CONNECTED"


class MotorGarbage(MotorError):
    """The motor sent bytes that are not its protocol (wrong baud rate, noise, another device)."""

    code = "E-MOTOR-GARBAGE"


class MotorPortError(MotorError):
    """The port cannot be opened (wrong name, in use, no permission)."""

    code = "E-MOTOR-PORT"


class MotorRangeError(MotorError):
    """A requested position, speed or bank is out of range."""

    code = "E-MOTOR-RANGE"


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


@dataclass(frozen=True)
class MotorConfig:
    """Link and behaviour settings of the driver. Times in seconds of wall clock."""

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


class SerialLike(Protocol):
    def write(self, data: bytes, /) -> int | None: ...
    def read(self, size: int = 1, /) -> bytes: ...
    @property
    def in_waiting(self) -> int: ...
    def close(self) -> None: ...


_REPLY_RE = re.compile(r"^(?P<key>[A-Za-z]+)\.(?P<id>\d+)=(?P<value>.*)$")
_MAX_UNKNOWN_LINES = 8
_ECHO = "<echo>"
_MAX_LINE_BYTES = 256

TrafficCallback = Callable[[str, str], None]


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
        raise MotorPortError(f"cannot open motor port {url!r}: {exc}") from exc


def list_serial_ports() -> list[tuple[str, str]]:
    """``(device, description)`` of the serial ports the system knows (not pseudo-terminals)."""
    from serial.tools import list_ports

    return [(p.device, p.description or p.device) for p in sorted(list_ports.comports())]


class CoolMuscle:
    """One CM1 on one serial link. Positions in pulses or mm, speeds in mm/s."""

    def __init__(
        self,
        port: SerialLike,
        config: MotorConfig | None = None,
        *,
        on_traffic: TrafficCallback | None = None,
    ) -> None:
        self.config = config or MotorConfig()
        self.units = self.config.units
        self.on_traffic = on_traffic
        self.version = ""
        self.last_status: MotorStatus | None = None
        self._port: SerialLike | None = port
        self._connected = False
        self._buf = bytearray()
        self._sent: deque[str] = deque(maxlen=32)
        self._lock = threading.RLock()
        if hasattr(port, "timeout"):
            port.timeout = min(0.02, self.config.reply_timeout_s)  # type: ignore[attr-defined]

    @classmethod
    def open(cls, port: str, config: MotorConfig | None = None, **kwargs: Any) -> CoolMuscle:
        """Open ``port`` (device path, pyserial URL, or ``sim``) without talking to the motor."""
        return cls(open_port(port, config), config, **kwargs)

    @property
    def port(self) -> SerialLike | None:
        return self._port

    @property
    def connected(self) -> bool:
        return self._connected

    # ----------------------------------------------------------------- link level

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
            raise MotorDisconnected(f"the motor port vanished while writing: {exc}") from exc

    def _fill(self, block: bool) -> None:
        assert self._port is not None
        try:
            waiting = self._port.in_waiting
            if waiting or block:
                self._buf += self._port.read(max(1, min(waiting, 4096)))
        except (serial.SerialException, OSError) as exc:
            raise MotorDisconnected(f"the motor port vanished while reading: {exc}") from exc

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

    def _stop_quietly(self) -> None:
        """Send stop, ignoring any further failure (used while an error propagates)."""
        if self._port is None:
            return
        self._buf.clear()
        try:
            self._write(self._cmd("]"))
            reset = getattr(self._port, "reset_input_buffer", None)
            if reset is not None:
                reset()
        except Exception:  # noqa: BLE001 - best effort on an already failing link
            pass

    def _drop(self) -> None:
        self._connected = False
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001 - the port is already gone
                pass

    @contextmanager
    def _guard(self, *, need_connection: bool = True) -> Iterator[None]:
        """Serialise access and leave the motor stopped if anything goes wrong."""
        with self._lock:
            if self._port is None or (need_connection and not self._connected):
                raise MotorNotConnected("the motor is not connected: connect first")
            try:
                yield
            except MotorDisconnected:
                self._drop()
                raise
            except (MotorError, Cancelled, KeyboardInterrupt):
                self._stop_quietly()
                raise

    # ----------------------------------------------------------------- operations

    def connect(self) -> str:
        """Check the motor answers, read its version, and (by default) stop it. Returns version."""
        with self._guard(need_connection=False):
            self._drain()
            command = self._cmd("?85")
            self._write(command)
            deadline = time.monotonic() + self.config.reply_timeout_s
            while (line := self._read_line(deadline)) is not None:
                if self._classify(line) is None:
                    self.version = line
                    break
            else:
                raise MotorTimeout(
                    f"no answer from motor {self.config.motor_id} within "
                    f"{self.config.reply_timeout_s:g} s: check cable, port, baud rate and id"
                )
            if self.config.stop_on_connect:
                self._write(self._cmd("]"))
            self._connected = True
            self.last_status = MotorStatus(self._query_int("?99", "Ux"))
            return self.version

    def close(self, *, stop: bool = True) -> None:
        """Stop the motor (unless ``stop=False``) and close the port. Safe to call twice."""
        with self._lock:
            if stop and self._connected and self._port is not None:
                self._stop_quietly()
            self._drop()

    def send(self, command: str) -> None:
        """Send a raw command line (the caller adds the id suffix). For scripting and tests."""
        with self._guard():
            self._write(command)

    def stop(self) -> None:
        """Stop (pause) motion and abort a running bank."""
        with self._guard():
            self._write(self._cmd("]"))

    def enable(self) -> None:
        with self._guard():
            self._write(self._cmd("("))

    def disable(self) -> None:
        with self._guard():
            self._write(self._cmd(")"))

    def emergency_stop(self) -> None:
        with self._guard():
            self._write("*")

    def release_emergency_stop(self) -> None:
        with self._guard():
            self._write("*1")

    def reset_alarm(self) -> None:
        """Disable then enable the motor, which clears a latched alarm."""
        with self._guard():
            self._write(self._cmd(")"))
            self._write(self._cmd("("))

    def set_zero(self) -> None:
        """Make the current position zero without moving."""
        with self._guard():
            self._write(self._cmd("|2"))

    def status(self) -> MotorStatus:
        with self._guard():
            self.last_status = MotorStatus(self._query_int("?99", "Ux"))
            return self.last_status

    def position_pulses(self) -> int:
        with self._guard():
            return self._query_int("?96", "Px")

    def position_mm(self) -> float:
        return self.units.pulses_to_mm(self.position_pulses())

    def speed_mm_s(self) -> float:
        """Current speed (zero when standing), in mm/s."""
        with self._guard():
            return abs(self.units.units_to_speed_mm_s(self._query_int("?97", "Sx")))

    def poll(self) -> MotorSnapshot:
        """Status, then position (so a finished move reports its final position)."""
        with self._guard():
            status = MotorStatus(self._query_int("?99", "Ux"))
            pulses = self._query_int("?96", "Px")
            self.last_status = status
            return MotorSnapshot(pulses, self.units.pulses_to_mm(pulses), status)

    def _refuse_if_alarm(self) -> None:
        status = MotorStatus(self._query_int("?99", "Ux"))
        if status.has_alarm:
            raise MotorAlarm(status, f"cannot move: {', '.join(status.alarms)} (reset it first)")

    def start_move_pulses(self, target_pulses: int, speed_units: int) -> MoveWatch:
        """Send P/S/A and start; returns the watch to pass to :meth:`check` or :meth:`wait`."""
        if speed_units < 1:
            raise MotorRangeError(f"speed must be at least 1 speed unit, got {speed_units}")
        with self._guard():
            self._refuse_if_alarm()
            here = self._query_int("?96", "Px")
            self._write(self._cmd("S", speed_units))
            self._write(self._cmd("A", self.config.accel_units))
            self._write(self._cmd("P", target_pulses))
            self._write(self._cmd("^"))
            expected = move_duration_s(
                target_pulses - here,
                self.units.speed_pulses_s(speed_units),
                self.units.accel_pulses_s2(self.config.accel_units),
            )
            timeout = expected * self.config.move_timeout_factor + self.config.move_timeout_margin_s
            what = f"move to {self.units.pulses_to_mm(target_pulses):.1f} mm"
            return MoveWatch(what, target_pulses, time.monotonic(), timeout)

    def start_move_mm(self, position_mm: float, speed_mm_s: float) -> MoveWatch:
        """Start an absolute move to ``position_mm`` at ``speed_mm_s`` (rounded to speed units)."""
        try:
            speed_units = self.units.speed_to_units(speed_mm_s)
        except ImpressError as exc:
            raise MotorRangeError(str(exc)) from exc
        return self.start_move_pulses(self.units.mm_to_pulses(position_mm), speed_units)

    def start_home(self) -> MoveWatch:
        """Start the motor's origin search (speed, direction and method are its K42..K48)."""
        with self._guard():
            self._refuse_if_alarm()
            self._write(self._cmd("|"))
            return MoveWatch("homing", None, time.monotonic(), self.config.home_timeout_s)

    def start_bank(self, bank: int) -> MoveWatch:
        """Run stored program bank ``bank`` (1..30)."""
        if not 1 <= bank <= 30:
            raise MotorRangeError(f"bank must be 1..30, got {bank}")
        with self._guard():
            self._write(self._cmd(f"[{bank}"))
            return MoveWatch(f"bank {bank}", None, time.monotonic(), self.config.bank_timeout_s)

    def check(self, watch: MoveWatch) -> tuple[bool, MotorSnapshot]:
        """One poll of a running move: ``(finished, snapshot)``; raises (and stops) on trouble."""
        with self._guard():
            snap = self.poll()
            done = watch.update(snap, time.monotonic(), self.config.in_position_tolerance_pulses)
            return done, snap

    def wait(
        self,
        watch: MoveWatch,
        *,
        on_update: Callable[[MotorSnapshot], None] | None = None,
        cancel: CancelToken | None = None,
    ) -> MotorSnapshot:
        """Poll until ``watch`` is finished. Cancelling (or Ctrl-C) stops the motor."""
        try:
            while True:
                with self._guard():
                    if cancel is not None:
                        cancel.check()
                    done, snap = self.check(watch)
                if on_update is not None:
                    on_update(snap)
                if done:
                    return snap
                time.sleep(self.config.poll_interval_s)
        except KeyboardInterrupt:
            with self._lock:
                self._stop_quietly()
            raise

    def move_to_mm(self, position_mm: float, speed_mm_s: float, **kwargs: Any) -> MotorSnapshot:
        """Move to an absolute position and wait; see :meth:`wait` for the keyword arguments."""
        return self.wait(self.start_move_mm(position_mm, speed_mm_s), **kwargs)

    def move_by_mm(self, distance_mm: float, speed_mm_s: float, **kwargs: Any) -> MotorSnapshot:
        """Move by a distance from the current position and wait."""
        return self.move_to_mm(self.position_mm() + distance_mm, speed_mm_s, **kwargs)

    def home(self, **kwargs: Any) -> MotorSnapshot:
        return self.wait(self.start_home(), **kwargs)

    def run_bank(self, bank: int, **kwargs: Any) -> MotorSnapshot:
        return self.wait(self.start_bank(bank), **kwargs)

    def write_program(self, lines: list[str], *, save: bool = True) -> None:
        """Send program lines (see :func:`scanner_program`) and optionally save to EEPROM."""
        with self._guard():
            for line in lines:
                self._write(line)
                self._drain()
            if save:
                self._write(self._cmd("$"))
                deadline = time.monotonic() + 10.0
                while True:  # the motor resets after saving; wait until it answers again
                    try:
                        self.last_status = MotorStatus(self._query_int("?99", "Ux"))
                        return
                    except MotorTimeout:
                        if time.monotonic() > deadline:
                            raise


def scanner_program(
    motor_id: int = 1,
    *,
    home_pulses: int = -1000,
    short_end_pulses: int = -40000,
    long_end_pulses: int = -130000,
    speed_units: int = 4,
    accel_units: int = 100,
) -> list[str]:
    """The thesis' four-button program (appendix B) as command lines; defaults are its values.

    Bank 1 home (zero here, then go to P1), bank 2 stop, bank 3 short run (to P2), bank 4 long
    run (to P3). Assigning the hardware inputs to the banks is done with the motor's own tool.
    """
    s = f".{motor_id}"

    def move(point: int) -> list[str]:
        return [f"P{point}{s}", f"S1{s}", f"A1{s}", f"^{s}"]

    return [
        f"P1{s}={home_pulses}",
        f"P2{s}={short_end_pulses}",
        f"P3{s}={long_end_pulses}",
        f"S1{s}={speed_units}",
        f"A1{s}={accel_units}",
        *[f"B1{s}", f"|2{s}", *move(1), f"END{s}"],
        *[f"B2{s}", f"]{s}", f"END{s}"],
        *[f"B3{s}", *move(2), f"END{s}"],
        *[f"B4{s}", *move(3), f"END{s}"],
    ]
