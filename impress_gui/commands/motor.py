"""``impress motor``: drive the Cool Muscle rail motor (or its emulator) from the command line.

Examples::

    impress motor ports
    impress motor --port /dev/ttyUSB0 status
    impress motor --port sim move --to 500 --speed 5
    impress motor --port COM3 run-bank 3
    impress motor emulate-pty            # a simulated motor behind a terminal device path
    impress motor calibrate --commanded-pulses 39000 --measured-mm 498.5

Moves obey the rail's limits (``--travel-mm``, default 1770 mm or ``$IMPRESS_RAIL_TRAVEL_MM``;
``--max-speed``): a refused move is reported with its code before the port is even opened.
A move, homing or bank run that is ended by Ctrl-C, a terminate signal (SIGTERM), a closed
terminal (SIGHUP) or any error sends the motor a stop first.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
from collections.abc import Iterator
from typing import Any

from impress_gui.core.base import codes

PORT_ENV = "IMPRESS_MOTOR_PORT"
TRAVEL_ENV = "IMPRESS_RAIL_TRAVEL_MM"
_NO_PORT_ACTIONS = {"ports", "emulate-pty", "calibrate", "speed-check"}
#: actions that move the carriage: any way they end other than finishing sends a stop
_MOVING_ACTIONS = {"home", "move", "run-bank"}
#: the signals that end a command (besides Ctrl-C), with how the message names them
_ENDING_SIGNALS = {
    "SIGTERM": "a terminate signal (SIGTERM)",
    "SIGHUP": "the terminal being closed (SIGHUP)",
}


def finite_float(text: str) -> float:
    """An argparse type: a finite number; anything else is refused with ``E-MOTOR-VALUE``."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"[E-MOTOR-VALUE] {text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"[E-MOTOR-VALUE] {text!r} is not a finite number")
    return value


def ranged_float(lo: float, hi: float):
    """An argparse type: a finite number from ``lo`` to ``hi``; else ``E-MOTOR-VALUE``."""

    def parse(text: str) -> float:
        value = finite_float(text)
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"[E-MOTOR-VALUE] {text!r} is outside {lo:g}..{hi:g}")
        return value

    return parse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    link = parser.add_argument_group("link and units")
    link.add_argument(
        "--port",
        default=os.environ.get(PORT_ENV),
        help=f"device path, pyserial URL, or 'sim' for the simulated motor (default: ${PORT_ENV})",
    )
    link.add_argument("--id", type=int, default=1, dest="motor_id", help="motor id (default 1)")
    link.add_argument("--baud", type=int, default=38400, help="baud rate (default 38400)")
    link.add_argument("--pulses-per-mm", type=finite_float, default=78.0, help="default 78")
    link.add_argument(
        "--speed-unit",
        type=finite_float,
        default=100.0,
        help="pulses/s of one S unit (default 100)",
    )
    link.add_argument("--accel", type=int, default=100, help="acceleration A value (default 100)")
    link.add_argument(
        "--timeout", type=ranged_float(0.01, 60.0), default=1.0,
        help="reply timeout, s (default 1; 0.01 to 60)"
    )
    link.add_argument(
        "--sim-time-scale", type=ranged_float(0.01, 1000.0), default=1.0,
        help="speed-up of the simulated motor (0.01 to 1000)"
    )
    link.add_argument(
        "--travel-mm",
        type=finite_float,
        default=os.environ.get(TRAVEL_ENV, "1770"),
        help=f"the rail's usable travel, mm from home: moves outside 0..TRAVEL are refused "
        f"(default 1770, or ${TRAVEL_ENV})",
    )
    link.add_argument(
        "--max-speed",
        type=finite_float,
        default=100.0,
        dest="max_speed_mm_s",
        help="the fastest move allowed, mm/s (default 100)",
    )
    link.add_argument("-v", "--verbose", action="store_true", help="print serial traffic")

    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    sub.add_parser("ports", help="list serial ports")
    sub.add_parser("status", help="version, position, state and alarms")
    sub.add_parser("home", help="origin search (homing)")
    move = sub.add_parser("move", help="move to a position or by a distance")
    where = move.add_mutually_exclusive_group(required=True)
    where.add_argument("--to", type=finite_float, dest="to_mm", help="absolute position, mm")
    where.add_argument("--by", "--mm", type=finite_float, dest="by_mm", help="distance, mm")
    move.add_argument("--speed", type=finite_float, default=5.0, dest="speed_mm_s", help="mm/s")
    for name, text in [
        ("stop", "stop motion and any running bank"),
        ("estop", "emergency stop"),
        ("release", "release the emergency stop"),
        ("enable", "servo on"),
        ("disable", "servo off (motor free)"),
        ("reset-alarm", "clear a latched alarm (disable, then enable)"),
        ("zero", "make the current position zero"),
    ]:
        sub.add_parser(name, help=text)
    bank = sub.add_parser("run-bank", help="run a stored program bank (1 home .. 4 long scan)")
    bank.add_argument("bank", type=int)
    prog = sub.add_parser("write-program", help="store the thesis' four-button program")
    prog.add_argument("--no-save", action="store_true", help="do not save to EEPROM")
    emu = sub.add_parser("emulate-pty", help="serve a simulated motor on a pseudo-terminal")
    emu.add_argument("--no-echo", action="store_true")
    emu.add_argument("--events", action="store_true", help="send Ux status at the end of moves")
    emu.add_argument("--seconds", type=finite_float, default=None, help="stop after this long")
    cal = sub.add_parser("calibrate", help="pulses per mm from a commanded and a measured move")
    cal.add_argument("--commanded-pulses", type=finite_float, required=True)
    cal.add_argument("--measured-mm", type=finite_float, required=True)
    chk = sub.add_parser("speed-check", help="speed from frames counted between two marks")
    chk.add_argument("--distance-mm", type=finite_float, required=True)
    chk.add_argument("--frames", type=finite_float, required=True)
    chk.add_argument("--fps", type=finite_float, required=True)
    chk.add_argument(
        "--commanded-s",
        type=finite_float,
        help="the S value the move ran at: also derive the speed unit",
    )


def _config(args: argparse.Namespace) -> Any:
    from impress_gui.hardware.motor_link import MotorConfig
    from impress_gui.hardware.rail import RailLimits
    from impress_gui.hardware.units import MotorUnits

    units = MotorUnits(pulses_per_mm=args.pulses_per_mm, speed_unit_pulses_s=args.speed_unit)
    return MotorConfig(
        motor_id=args.motor_id,
        baudrate=args.baud,
        units=units,
        accel_units=args.accel,
        reply_timeout_s=args.timeout,
        stop_on_connect=args.action != "status",  # looking must not stop a running scan
        limits=RailLimits(travel_mm=args.travel_mm, max_speed_mm_s=args.max_speed_mm_s),
    )


def _check_request(args: argparse.Namespace, config: Any) -> None:
    """Refuse a move, bank or program outside the limits before the port is opened."""
    from impress_gui.hardware import motor_limits as lim
    from impress_gui.hardware.motor_program import scanner_program

    units, limits = config.units, config.limits
    if args.action == "move":
        lim.check_speed_mm_s(args.speed_mm_s, units, limits)
        if args.to_mm is not None:
            lim.check_position_mm(args.to_mm, limits)
        else:
            lim.check_distance_mm(args.by_mm, limits)  # where it ends: once the position is read
    elif args.action == "run-bank":
        lim.check_bank(args.bank)
    elif args.action == "write-program":
        lim.check_program(scanner_program(args.motor_id), units, limits)


@contextlib.contextmanager
def _ending_signals_cancel(token: Any, received: list[str]) -> Iterator[None]:
    """While the block runs, SIGTERM and SIGHUP set ``token`` (a running wait then stops the
    motor and raises ``Cancelled``) and are noted in ``received``; handlers restored after.
    A signal the process ignores (``nohup`` ignores SIGHUP) stays ignored."""

    def handler(signum: int, _frame: object) -> None:
        received.append(signal.Signals(signum).name)
        token.cancel()

    previous = {}
    for name in _ENDING_SIGNALS:
        number = getattr(signal, name, None)
        if number is not None and signal.getsignal(number) is not signal.SIG_IGN:  # nohup
            previous[number] = signal.signal(number, handler)
    try:
        yield
    finally:
        for number, old in previous.items():
            signal.signal(number, old)


def _interrupted(received: list[str]) -> Any:
    from impress_gui.hardware.motor_status import MotorInterrupted

    what = _ENDING_SIGNALS.get(received[0], received[0]) if received else "a cancel request"
    return MotorInterrupted(f"ended by {what}; the motor was sent a stop")


def _port_url(args: argparse.Namespace) -> str:
    from impress_gui.core.base.errors import InputError
    from impress_gui.hardware.motor_link import EMULATOR_SCHEME, emulator_url, resolve_port_url

    if not args.port:
        raise InputError(f"no motor port: give --port (or set {PORT_ENV}); 'sim' simulates one")
    url = resolve_port_url(args.port)
    if url == EMULATOR_SCHEME:
        url = emulator_url(_config(args), args.sim_time_scale)
    return url


class _MoveReport:
    """While the motor moves: its position and state on stderr, at most once a second (a
    scan of the whole rail takes minutes and must not look hung)."""

    def __init__(self, what: str, every_s: float = 1.0) -> None:
        import time

        self._clock = time.monotonic
        self.what, self.every_s, self._last = what, every_s, None

    def __call__(self, snap: Any) -> None:
        now = self._clock()
        if self._last is not None and now - self._last < self.every_s:
            return
        self._last = now
        print(f"  {self.what}: {snap.position_mm:8.2f} mm, {snap.status.state}", file=sys.stderr,
              flush=True)


def _print_snapshot(snap: Any) -> None:
    print(f"position: {snap.position_mm:.2f} mm ({snap.position_pulses} pulses)")
    print(f"state: {snap.status.state} (Ux={snap.status.bits})")
    if snap.status.alarms:
        print(f"alarms: {', '.join(snap.status.alarms)}")


def _emulate(args: argparse.Namespace) -> int:
    import time

    from impress_gui.hardware.emulator import PtyServer
    from impress_gui.hardware.emulator_model import CM1Emulator, EmulatorConfig

    config = EmulatorConfig(
        motor_id=args.motor_id,
        echo=not args.no_echo,
        report_events=args.events,
        time_scale=args.sim_time_scale,
        speed_unit_pulses_s=args.speed_unit,
    )
    with PtyServer(CM1Emulator(config)) as server:
        print(f"simulated Cool Muscle on {server.path} (Ctrl-C to stop)", flush=True)
        deadline = None if args.seconds is None else time.monotonic() + args.seconds
        try:
            while deadline is None or time.monotonic() < deadline:
                time.sleep(0.1)
        except KeyboardInterrupt:
            pass
    return 0


def run(args: argparse.Namespace) -> int:
    action = args.action
    if action == "ports":
        from impress_gui.hardware.motor_link import list_serial_ports

        ports = list_serial_ports()
        for device, description in ports:
            print(f"{device}\t{description}")
        print("sim\tSimulated motor")
        return 0
    if action == "calibrate":
        from impress_gui.hardware.units import pulses_per_mm_from_measurement

        ppm = pulses_per_mm_from_measurement(args.commanded_pulses, args.measured_mm)
        print(f"pulses per mm: {ppm:.4f}")
        return 0
    if action == "speed-check":
        from impress_gui.hardware.units import speed_from_video_mm_s, speed_unit_from_measurement

        speed = speed_from_video_mm_s(args.distance_mm, args.frames, args.fps)
        print(f"speed: {speed:.3f} mm/s")
        if args.commanded_s:
            unit = speed_unit_from_measurement(args.commanded_s, speed, args.pulses_per_mm)
            print(f"one speed unit: {unit:.3f} pulses/s (at {args.pulses_per_mm:g} pulses/mm)")
        return 0
    if action == "emulate-pty":
        return _emulate(args)

    from impress_gui.core.base.errors import Cancelled, ImpressError
    from impress_gui.core.base.progress import CancelToken
    from impress_gui.hardware.cool_muscle import CoolMuscle
    from impress_gui.hardware.motor_status import MotorRangeError

    def traffic(direction: str, text: str) -> None:
        print(f"{direction} {text}", file=sys.stderr)

    config = _config(args)
    _check_request(args, config)
    token = CancelToken()
    received: list[str] = []  # the names of the signals that ended the command
    with _ending_signals_cancel(token, received):
        driver = CoolMuscle.open(
            _port_url(args), config, on_traffic=traffic if args.verbose else None
        )
        try:
            _act(args, driver, token)
            if received:
                raise _interrupted(received)
        except Cancelled:
            if action in _MOVING_ACTIONS:
                driver.close(stop=True)  # the driver stopped a running wait; this covers the rest
            raise _interrupted(received) from None
        except MotorRangeError:
            raise  # a refused move: nothing was sent, nothing moves
        except BaseException as exc:
            # the driver stops the motor on its own errors; this covers the rest (an error
            # between two driver calls, a bug) and is harmless twice
            if action in _MOVING_ACTIONS:
                driver.close(stop=True)
            if isinstance(exc, (ImpressError, KeyboardInterrupt)) or not isinstance(exc, Exception):
                raise
            if args.verbose:
                import traceback

                traceback.print_exc()
            stopped = "; the motor was sent a stop" if action in _MOVING_ACTIONS else ""
            raise ImpressError(
                f"internal error during 'motor {action}': {exc}{stopped} (-v shows the details)",
                code=codes.E_INTERNAL,
            ) from exc
        finally:
            # Leave the motor as the command left it: a finished move needs no stop, and
            # "release"/"enable" must not be undone. Errors already stopped it.
            driver.close(stop=False)
    return 0


def _act(args: argparse.Namespace, driver: Any, token: Any) -> None:
    """Connect and carry out ``args.action``; waits end early (with a stop) when ``token`` is set."""
    from impress_gui.hardware.motor_program import scanner_program

    action, units = args.action, driver.units
    version = driver.connect()
    if action == "status":
        print(f"motor: {version}")
        _print_snapshot(driver.poll())
        print(f"speed: {driver.speed_mm_s():.2f} mm/s")
        limits = driver.limits
        print(
            f"limits: travel 0 to {limits.travel_mm:g} mm, speed up to {limits.max_speed_mm_s:g} mm/s"
        )
    elif action == "home":
        token.check()
        _print_snapshot(driver.home(cancel=token, on_update=_MoveReport("homing")))
    elif action == "move":
        speed = args.speed_mm_s
        actual = units.units_to_speed_mm_s(units.speed_to_units(speed))
        if abs(actual - speed) > 1e-9:
            print(f"speed {speed:g} mm/s rounds to {actual:.3f} mm/s (S units)")
        token.check()
        if args.to_mm is not None:
            snap = driver.move_to_mm(args.to_mm, speed, cancel=token,
                                     on_update=_MoveReport("moving"))
        else:
            snap = driver.move_by_mm(args.by_mm, speed, cancel=token,
                                     on_update=_MoveReport("moving"))
        _print_snapshot(snap)
    elif action == "run-bank":
        token.check()
        _print_snapshot(driver.run_bank(args.bank, cancel=token,
                                        on_update=_MoveReport(f"bank {args.bank}")))
    elif action == "write-program":
        driver.write_program(scanner_program(args.motor_id), save=not args.no_save)
        print("program written" + ("" if args.no_save else " and saved"))
    else:
        simple = {
            "stop": driver.stop,
            "estop": driver.emergency_stop,
            "release": driver.release_emergency_stop,
            "enable": driver.enable,
            "disable": driver.disable,
            "reset-alarm": driver.reset_alarm,
            "zero": driver.set_zero,
        }
        simple[action]()
        _print_snapshot(driver.poll())
