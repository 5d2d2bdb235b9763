"""The software Cool Muscle CM1 itself (Qt-free), without any transport.

:class:`CM1Emulator` is the motor: it parses command lines, echoes them (or not), answers the
queries, runs timed trapezoidal moves whose position can be read while they run, homes, stores
and runs program banks, and can be told to misbehave (alarm mid-move, no reply, garbage bytes,
a vanished port). Its clock runs ``time_scale`` times faster than the wall clock so tests of
long moves take milliseconds. It has no thread of its own: time is evaluated whenever the
motor is spoken to or read. It is reached through the ports of
:mod:`impress_gui.hardware.emulator`, which re-exports it.
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from urllib.parse import parse_qs, urlsplit

from impress_gui.hardware.motor_program import scanner_program
from impress_gui.hardware.units import move_duration_s

_LINE_RE = re.compile(
    r"^(?P<op>END|[A-Z]|[?()^\]\[|*$])(?P<num>\d*)(?:\.(?P<id>\d+))?(?:=(?P<value>-?\d+))?$"
)
GARBAGE_BYTES = b"\xff\x81#\x00\xfe~\x07"


@dataclass(frozen=True)
class EmulatorConfig:
    """Behaviour of the emulated motor. Speeds in the motor's units (see ``MotorUnits``)."""

    motor_id: int = 1
    echo: bool = True
    report_events: bool = False
    time_scale: float = 1.0
    speed_unit_pulses_s: float = 100.0
    accel_unit_pulses_s2: float = 1000.0
    home_speed_units: int = 50
    home_switch_pulses: int = 0
    start_position_pulses: int = 0
    preload_program: bool = True
    version: str = "CM1v2.39.5 emulator"

    @classmethod
    def from_url(cls, url: str) -> EmulatorConfig:
        """Read ``cm1emu://?echo=0&id=2&time_scale=20&events=1`` options."""
        query = {k: v[-1] for k, v in parse_qs(urlsplit(url).query).items()}
        unknown = set(query) - {"echo", "id", "time_scale", "events", "speed_unit"}
        if unknown:
            raise ValueError(f"unknown cm1emu:// option(s): {', '.join(sorted(unknown))}")
        return cls(
            motor_id=int(query.get("id", 1)),
            echo=query.get("echo", "1") not in ("0", "false", "off"),
            report_events=query.get("events", "0") not in ("0", "false", "off"),
            time_scale=float(query.get("time_scale", 1.0)),
            speed_unit_pulses_s=float(query.get("speed_unit", 100.0)),
        )


@dataclass
class _Move:
    start_pulses: float
    end_pulses: float
    t0_s: float
    speed_pulses_s: float
    accel_pulses_s2: float
    homing: bool = False
    alarm_at_s: float | None = None
    alarm_bits: int = 0

    @property
    def duration_s(self) -> float:
        d = self.end_pulses - self.start_pulses
        return move_duration_s(d, self.speed_pulses_s, self.accel_pulses_s2)

    @property
    def t_end_s(self) -> float:
        return self.t0_s + self.duration_s

    def _travelled(self, t: float) -> tuple[float, float]:
        """(distance, speed) after ``t`` seconds of the move, both non-negative."""
        d, a = abs(self.end_pulses - self.start_pulses), self.accel_pulses_s2
        v = min(self.speed_pulses_s, math.sqrt(d * a))  # peak speed (triangular if short)
        t_ramp, total = v / a, self.duration_s
        t = min(max(t, 0.0), total)
        if t < t_ramp:
            return 0.5 * a * t * t, a * t
        if t <= total - t_ramp:
            return 0.5 * v * t_ramp + v * (t - t_ramp), v
        left = total - t
        return d - 0.5 * a * left * left, a * left

    def position(self, now_s: float) -> float:
        s, _ = self._travelled(now_s - self.t0_s)
        return self.start_pulses + math.copysign(s, self.end_pulses - self.start_pulses)

    def speed(self, now_s: float) -> float:
        return self._travelled(now_s - self.t0_s)[1]


class CM1Emulator:
    """The emulated motor. Thread-safe; all times are the emulator's (scaled) seconds."""

    def __init__(
        self, config: EmulatorConfig | None = None, *, clock: Callable[[], float] | None = None
    ) -> None:
        self.config = config or EmulatorConfig()
        if clock is None:
            t0, scale = time.monotonic(), self.config.time_scale
            clock = lambda: (time.monotonic() - t0) * scale  # noqa: E731
        self.clock = clock
        self.echo = self.config.echo
        self.received: list[str] = []  #: every command line, for tests and the traffic view
        self.saved = 0  #: how many times ``$`` was received
        self._cond = threading.Condition()
        self._out = bytearray()
        self._in = bytearray()
        self._phys = float(self.config.start_position_pulses)
        self._offset = 0.0
        self._move: _Move | None = None
        self._alarm = 0
        self._free = False
        self._estop = False
        self._regs: dict[str, int] = {"P": 0, "S": 10, "A": 100}
        self._params: dict[int, int] = {}
        self.banks: dict[int, list[str]] = {}
        self._defining: list[str] | None = None
        self._bank: list[str] = []
        self._t_cursor = 0.0
        self._no_reply = False
        self._garbage = 0
        self._link_up = True
        self._alarm_plan: tuple[int, float] | None = None
        if self.config.preload_program:  # the thesis' four banks, as on the rig's motor
            for line in scanner_program(self.config.motor_id):
                self._line(line, 0.0)
            self._out.clear()
            self.received.clear()

    # ----------------------------------------------------------------- faults

    def inject_alarm(self, bits: int = 4, at_fraction: float = 0.5) -> None:
        """Raise alarm ``bits`` (default over-current) ``at_fraction`` of the way through the
        running move, or of the next one if none runs."""
        with self._cond:
            now = self.clock()
            self._advance(now)
            if self._move is not None:
                m = self._move
                m.alarm_at_s, m.alarm_bits = m.t0_s + at_fraction * m.duration_s, bits
                m.alarm_at_s = max(m.alarm_at_s, now)
            else:
                self._alarm_plan = (bits, at_fraction)

    def set_no_reply(self, on: bool = True) -> None:
        """The motor still obeys but sends nothing back (a broken receive line)."""
        with self._cond:
            self._no_reply = on

    def inject_garbage(self, count: int = 1) -> None:
        """Replace the next ``count`` query replies with non-protocol bytes."""
        with self._cond:
            self._garbage += count

    def disconnect(self) -> None:
        """The port vanishes (adapter unplugged). The motor itself keeps doing what it does."""
        with self._cond:
            self._link_up = False

    def reconnect(self) -> None:
        with self._cond:
            self._link_up = True
            self._out.clear()
            self._in.clear()

    @property
    def link_up(self) -> bool:
        return self._link_up

    # ----------------------------------------------------------------- inspection

    @property
    def position_pulses(self) -> int:
        with self._cond:
            return int(round(self._logical(self.clock())))

    @property
    def moving(self) -> bool:
        with self._cond:
            self._advance(self.clock())
            return self._move is not None

    # ----------------------------------------------------------------- byte interface

    def feed(self, data: bytes) -> None:
        """Bytes from the host. Complete lines (CR or LF) are executed at once."""
        with self._cond:
            now = self.clock()
            self._advance(now)
            self._in += data
            while True:
                ends = [i for i in (self._in.find(b"\r"), self._in.find(b"\n")) if i >= 0]
                if not ends:
                    break
                raw, self._in = bytes(self._in[: min(ends)]), self._in[min(ends) + 1 :]
                line = raw.decode("ascii", "replace").strip()
                if line:
                    self._line(line, now)
            self._cond.notify_all()

    def take_output(self, max_bytes: int = 1 << 16) -> bytes:
        with self._cond:
            self._advance(self.clock())
            data = bytes(self._out[:max_bytes])
            del self._out[:max_bytes]
            return data

    def pending_output(self) -> int:
        with self._cond:
            self._advance(self.clock())
            return len(self._out)

    def wait_output(self, timeout_s: float) -> None:
        """Block up to ``timeout_s`` wall seconds for output (re-checking time every 2 ms)."""
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while True:
                self._advance(self.clock())
                remaining = deadline - time.monotonic()
                if self._out or remaining <= 0:
                    return
                self._cond.wait(min(remaining, 0.002))

    def clear_output(self) -> None:
        with self._cond:
            self._out.clear()

    # ----------------------------------------------------------------- model

    def _emit(self, text: str, *, reply: bool = False) -> None:
        if self._no_reply:
            return
        if reply and self._garbage:
            self._garbage -= 1
            self._out += GARBAGE_BYTES + b"\r\n"
            return
        self._out += text.encode("ascii") + b"\r\n"

    def _logical(self, now: float) -> float:
        self._advance(now)
        phys = self._move.position(now) if self._move is not None else self._phys
        return phys - self._offset

    def _status_bits(self) -> int:
        bits = self._alarm | (512 if self._estop else 0) | (16 if self._free else 0)
        if self._move is None and not bits:
            bits |= 8
        return bits

    def _event(self) -> None:
        if self.config.report_events:
            self._emit(f"Ux.{self.config.motor_id}={self._status_bits()}")

    def _advance(self, now: float) -> None:
        """Bring the model to time ``now``: finish moves, raise planned alarms, run banks."""
        while True:
            m = self._move
            if m is not None:
                if m.alarm_at_s is not None and m.alarm_at_s <= min(now, m.t_end_s):
                    self._phys, self._move = m.position(m.alarm_at_s), None
                    self._alarm |= m.alarm_bits
                    self._bank = []
                    self._event()
                    return
                if m.t_end_s > now:
                    return
                self._phys, self._move, self._t_cursor = m.end_pulses, None, m.t_end_s
                if m.homing:
                    self._offset = self._phys
                self._event()
            elif self._bank:
                self._execute(self._bank.pop(0), self._t_cursor)
            else:
                return

    def _halt(self, now: float, *, abort_bank: bool = True) -> None:
        if self._move is not None:
            self._phys, self._move = self._move.position(now), None
        if abort_bank:
            self._bank = []

    def _start(
        self, target: float, speed_units: int, accel_units: int, now: float, homing: bool = False
    ) -> None:
        if self._alarm or self._estop or self._free:
            return
        start = self._move.position(now) if self._move is not None else self._phys
        speed = max(1, speed_units) * self.config.speed_unit_pulses_s
        accel = max(1, accel_units) * self.config.accel_unit_pulses_s2
        self._move = _Move(start, target, now, speed, accel, homing)
        if self._alarm_plan is not None:
            bits, fraction = self._alarm_plan
            self._alarm_plan = None
            self._move.alarm_at_s, self._move.alarm_bits = (
                now + fraction * self._move.duration_s,
                bits,
            )

    def _line(self, line: str, now: float) -> None:
        m = _LINE_RE.match(line)
        if m is not None and m["id"] is not None and int(m["id"]) != self.config.motor_id:
            return  # for another motor on the chain
        self.received.append(line)
        if self.echo:
            self._emit(line)
        if self._defining is not None:
            if m is not None and m["op"] == "END":
                self._defining = None
            else:
                self._defining.append(line)
            return
        if m is None:
            return  # unknown command: ignored
        self._execute(line, now)

    def _execute(self, line: str, now: float) -> None:
        m = _LINE_RE.match(line)
        if m is None:
            return
        op, num, value = m["op"], m["num"], m["value"]
        n = int(num) if num else None
        mid = self.config.motor_id
        if op in "PSA" and len(op) == 1:
            if value is not None:
                self._regs[f"{op}{n or ''}"] = int(value)
            elif n is not None:
                self._regs[op] = self._regs.get(f"{op}{n}", self._regs[op])
        elif op == "K" and n is not None and value is not None:
            self._params[n] = int(value)
            if n == 23:
                self.echo = not int(value) & 8
        elif op == "^":
            target = self._regs["P"] + self._offset
            self._start(target, self._regs["S"], self._regs["A"], now)
        elif op == "]":
            self._halt(now)
        elif op == "*":
            if n == 1:
                self._estop = False
            else:
                self._halt(now)
                self._estop = True
        elif op == "(":
            self._free, self._alarm = False, 0
        elif op == ")":
            self._halt(now)
            self._free = True
        elif op == "|":
            if n == 2:
                self._halt(now, abort_bank=False)
                self._offset = self._phys
            else:
                speed = self._params.get(42, self.config.home_speed_units)
                self._start(self.config.home_switch_pulses, speed, self._regs["A"], now, True)
        elif op == "[" and n in self.banks:
            self._halt(now)
            self._bank, self._t_cursor = list(self.banks[n]), now
            self._advance(now)
        elif op in ("B", "L") and n is not None:
            self._defining = []  # logic banks (L) are accepted and ignored
            if op == "B":
                self.banks[n] = self._defining
        elif op == "$":
            self.saved += 1
        elif op == "?":
            self._advance(now)
            replies = {
                96: lambda: f"Px.{mid}={int(round(self._logical(now)))}",
                97: lambda: f"Sx.{mid}={self._speed_units(now)}",
                98: lambda: f"Ix.{mid}={100 if self._move is not None else 0}",
                99: lambda: f"Ux.{mid}={self._status_bits()}",
                85: lambda: f"ID{mid} :{self.config.version}",
            }
            if n in replies:
                self._emit(replies[n](), reply=True)

    def _speed_units(self, now: float) -> int:
        if self._move is None:
            return 0
        return int(round(self._move.speed(now) / self.config.speed_unit_pulses_s))
