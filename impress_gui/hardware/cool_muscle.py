"""Driver for the Cool Muscle CM1 servo that moves the scanner's camera along its rail.

Qt-free. A :class:`CoolMuscle` wraps any serial-like object (``read``, ``write``, ``in_waiting``,
``close``): a real port, a ``socket://`` URL, or the software motor of
:mod:`impress_gui.hardware.emulator`. Commands carry the motor-id suffix (``P.1=5000``), replies
are CR/LF-terminated lines, echoed commands and unsolicited status lines (``Ux.1=8``) are
recognised and skipped. The protocol knowledge and its uncertainties are in ``docs/motor.md``.

Every failure raises a :class:`MotorError` subclass with a stable code, and before it propagates
the driver sends a stop where the link still allows it, so an error (or any other exception,
Ctrl-C included) never leaves the carriage moving under software control. Public methods are
serialised by a lock, so one driver may be used from a worker thread while another thread asks
it to :meth:`CoolMuscle.stop`.

Every move is checked against the rail's limits (``MotorConfig.limits``: the travel, 0 to
1770 mm from home by default, and the maximum speed) and the controller's 32-bit registers
before anything is sent: a refused move raises ``E-MOTOR-LIMIT``, ``E-MOTOR-SPEED``,
``E-MOTOR-VALUE`` or ``E-MOTOR-RANGE`` and sends nothing (:mod:`impress_gui.hardware.motor_limits`).

The errors, the status word and the move watch are in :mod:`impress_gui.hardware.motor_status`;
the settings, opening a port and the line level (``MotorLink``, the base of :class:`CoolMuscle`)
in :mod:`impress_gui.hardware.motor_link`; the stored program in
:mod:`impress_gui.hardware.motor_program`; the rail's limits in
:mod:`impress_gui.hardware.rail`. All are re-exported here.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from impress_gui.core.base.progress import CancelToken
from impress_gui.hardware.motor_limits import (
    check_bank,
    check_distance_mm,
    check_move_by_mm,
    check_position_mm,
    check_program,
    check_program_line,
    check_speed_mm_s,
    check_speed_units,
    check_target_pulses,
)
from impress_gui.hardware.motor_link import (
    EMULATOR_SCHEME,
    SIMULATED_PORT_NAMES,
    MotorConfig,
    MotorLink,
    SerialLike,
    TrafficCallback,
    emulator_url,
    list_serial_ports,
    open_port,
    resolve_port_url,
)
from impress_gui.hardware.motor_program import scanner_program
from impress_gui.hardware.motor_status import (
    ALARM_BITS,
    FLAG_BITS,
    MotorAlarm,
    MotorDisconnected,
    MotorError,
    MotorGarbage,
    MotorInterrupted,
    MotorLimitError,
    MotorNotConnected,
    MotorPortError,
    MotorRangeError,
    MotorSettingsError,
    MotorSnapshot,
    MotorSpeedError,
    MotorStatus,
    MotorTimeout,
    MotorValueError,
    MoveWatch,
)
from impress_gui.hardware.rail import RailLimits
from impress_gui.hardware.units import move_duration_s

__all__ = [
    "ALARM_BITS",
    "EMULATOR_SCHEME",
    "FLAG_BITS",
    "SIMULATED_PORT_NAMES",
    "CoolMuscle",
    "MotorAlarm",
    "MotorConfig",
    "MotorDisconnected",
    "MotorError",
    "MotorGarbage",
    "MotorInterrupted",
    "MotorLimitError",
    "MotorNotConnected",
    "MotorPortError",
    "MotorRangeError",
    "MotorSettingsError",
    "MotorSnapshot",
    "MotorSpeedError",
    "MotorStatus",
    "MotorTimeout",
    "MotorValueError",
    "MoveWatch",
    "RailLimits",
    "SerialLike",
    "TrafficCallback",
    "emulator_url",
    "list_serial_ports",
    "open_port",
    "resolve_port_url",
    "scanner_program",
]


class CoolMuscle(MotorLink):
    """One CM1 on one serial link. Positions in pulses or mm, speeds in mm/s."""

    def __init__(
        self,
        port: SerialLike,
        config: MotorConfig | None = None,
        *,
        on_traffic: TrafficCallback | None = None,
    ) -> None:
        super().__init__(port, config or MotorConfig(), on_traffic)
        self.units = self.config.units
        self.version = ""
        self._connected = False
        self._lock = threading.RLock()
        if hasattr(port, "timeout"):
            port.timeout = min(0.02, self.config.reply_timeout_s)

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

    @property
    def limits(self) -> RailLimits:
        """The rail's travel and maximum speed, enforced on every move."""
        return self.config.limits

    # ----------------------------------------------------------------- safety

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

    def _stop_for(self, exc: BaseException) -> None:
        """Send stop once for an exception on its way out (nested guards see it again)."""
        if getattr(exc, "_motor_stop_sent", False):
            return
        self._stop_quietly()
        try:
            exc._motor_stop_sent = True  # type: ignore[attr-defined]
        except AttributeError:  # an exception without attributes: a second stop is harmless
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
        """Serialise access and leave the motor stopped if anything goes wrong: a motor error,
        a cancel, Ctrl-C, or any other exception."""
        with self._lock:
            if self._port is None or (need_connection and not self._connected):
                raise MotorNotConnected("the motor is not connected: connect first")
            try:
                yield
            except MotorDisconnected:
                self._drop()
                raise
            except BaseException as exc:
                self._stop_for(exc)
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
        """Send a raw command line (the caller adds the id suffix). For scripting and tests.
        A position or speed in it (``P.1=...``, ``S.1=...``) must obey the limits."""
        check_program_line(command, self.units, self.limits)
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
        """Send P/S/A and start; returns the watch to pass to :meth:`check` or :meth:`wait`.

        The target must lie within the rail's travel and the controller's 32-bit range
        (``E-MOTOR-LIMIT``), the speed value from 1 to the rail's maximum (``E-MOTOR-SPEED``),
        both whole numbers (``E-MOTOR-VALUE``); a refused move sends nothing.
        """
        target_pulses = check_target_pulses(target_pulses, self.units, self.limits)
        speed_units = check_speed_units(speed_units, self.units, self.limits)
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
        """Start an absolute move to ``position_mm`` at ``speed_mm_s`` (rounded to speed units).
        Refused, with nothing sent, outside the rail's limits (see :meth:`start_move_pulses`)."""
        position = check_position_mm(position_mm, self.limits)
        speed_units = check_speed_mm_s(speed_mm_s, self.units, self.limits)
        return self.start_move_pulses(self.units.mm_to_pulses(position), speed_units)

    def start_move_by_mm(self, distance_mm: float, speed_mm_s: float) -> MoveWatch:
        """Start a move by ``distance_mm`` from the current position. The distance and speed
        are checked first; then the position is read and the move refused (no move command
        sent) if it would end outside the rail's travel."""
        distance = check_distance_mm(distance_mm, self.limits)
        speed_units = check_speed_mm_s(speed_mm_s, self.units, self.limits)
        with self._lock:
            target = check_move_by_mm(self.position_mm(), distance, self.limits)
            return self.start_move_pulses(self.units.mm_to_pulses(target), speed_units)

    def start_home(self) -> MoveWatch:
        """Start the motor's origin search (speed, direction and method are its K42..K48)."""
        with self._guard():
            self._refuse_if_alarm()
            self._write(self._cmd("|"))
            return MoveWatch("homing", None, time.monotonic(), self.config.home_timeout_s)

    def start_bank(self, bank: int) -> MoveWatch:
        """Run stored program bank ``bank`` (1..30). What the bank does is stored in the motor:
        a program written by :meth:`write_program` was checked against the limits then."""
        bank = check_bank(bank)
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
        """Poll until ``watch`` is finished. Cancelling, Ctrl-C, or any exception (in
        ``on_update`` too) stops the motor."""
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
        except BaseException as exc:
            with self._lock:
                self._stop_for(exc)
            raise

    def move_to_mm(self, position_mm: float, speed_mm_s: float, **kwargs: Any) -> MotorSnapshot:
        """Move to an absolute position and wait; see :meth:`wait` for the keyword arguments."""
        return self.wait(self.start_move_mm(position_mm, speed_mm_s), **kwargs)

    def move_by_mm(self, distance_mm: float, speed_mm_s: float, **kwargs: Any) -> MotorSnapshot:
        """Move by a distance from the current position and wait (see :meth:`start_move_by_mm`)."""
        return self.wait(self.start_move_by_mm(distance_mm, speed_mm_s), **kwargs)

    def home(self, **kwargs: Any) -> MotorSnapshot:
        return self.wait(self.start_home(), **kwargs)

    def run_bank(self, bank: int, **kwargs: Any) -> MotorSnapshot:
        return self.wait(self.start_bank(bank), **kwargs)

    def write_program(self, lines: list[str], *, save: bool = True) -> None:
        """Send program lines (see :func:`scanner_program`) and optionally save to EEPROM.
        Stored positions and speeds must obey the rail's limits: a program with one that does
        not is refused whole, with nothing sent."""
        lines = check_program(lines, self.units, self.limits)
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
