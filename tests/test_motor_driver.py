"""The Cool Muscle driver against the emulator: every operation, echo on/off, timing, faults."""

from __future__ import annotations

import threading

import numpy as np
import pytest
import serial

from impress_gui.core.base.errors import Cancelled, ImpressError, InputError
from impress_gui.core.base.progress import CancelToken
from impress_gui.hardware.cool_muscle import (
    CoolMuscle,
    MotorAlarm,
    MotorConfig,
    MotorDisconnected,
    MotorGarbage,
    MotorNotConnected,
    MotorPortError,
    MotorRangeError,
    MotorSettingsError,
    MotorStatus,
    MotorTimeout,
    RailLimits,
    scanner_program,
)
from impress_gui.hardware.emulator import (
    CM1Emulator,
    EmulatedSerial,
    EmulatorConfig,
    emulated_port,
    register_url_handler,
)
from impress_gui.hardware.units import (
    MotorUnits,
    move_duration_s,
    pulses_per_mm_from_measurement,
    speed_from_video_mm_s,
    speed_unit_from_measurement,
)

pytestmark = pytest.mark.usefixtures("no_stray_threads")


TIME_SCALE = 50.0  # emulated seconds per wall second


class CommandClock:
    """Emulated time that advances by ``step_s`` for every command line the motor receives
    (and by what :meth:`advance` adds), never with the wall clock: a move lasts as many of the
    driver's queries as its length says, however long a busy machine keeps the test waiting
    between two of them."""

    def __init__(self, step_s: float) -> None:
        self.step_s, self.extra_s = step_s, 0.0
        self.motor: CM1Emulator | None = None

    def __call__(self) -> float:
        return self.extra_s + self.step_s * (0 if self.motor is None else len(self.motor.received))

    def advance(self, seconds: float) -> None:
        self.extra_s += seconds


@pytest.fixture
def rig():
    made: list[CoolMuscle] = []

    def make(*, echo=True, events=False, time_scale=TIME_SCALE, emulator=None, step_s=None,
             **config):
        """The emulated motor and a connected driver; with ``step_s`` the motor's clock is a
        :class:`CommandClock` (else the wall clock, ``time_scale`` times faster)."""
        clock = None if step_s is None else CommandClock(step_s)
        emu = CM1Emulator(
            EmulatorConfig(
                echo=echo, report_events=events, time_scale=time_scale, **(emulator or {})
            ),
            clock=clock,
        )
        if clock is not None:
            clock.motor = emu
        config = {"poll_interval_s": 0.005, "reply_timeout_s": 0.3, **config}
        driver = CoolMuscle(emulated_port(emu), MotorConfig(**config))
        made.append(driver)
        driver.connect()
        return emu, driver

    yield make
    for driver in made:
        driver.close()


def assert_stopped(emu: CM1Emulator, short_of_mm: float | None = None) -> None:
    """The emulated motor stands still (and, if given, short of a target it was sent to)."""
    assert not emu.moving
    if short_of_mm is not None:
        assert abs(emu.position_pulses / 78.0) < short_of_mm - 1.0
    here = emu.position_pulses
    emu.wait_output(0.02)  # let emulated time pass
    if isinstance(emu.clock, CommandClock):
        emu.clock.advance(1.0)  # (a clock the wall clock does not move)
    assert emu.position_pulses == here


# ----------------------------------------------------------------- units and status


def test_units_round_trip_and_speed_units():
    u = MotorUnits(pulses_per_mm=80.0, speed_unit_pulses_s=10.0, direction=-1)
    assert u.mm_to_pulses(500.0) == -40000
    assert u.pulses_to_mm(-40000) == pytest.approx(500.0)
    assert u.speed_to_units(5.0) == 40
    assert u.units_to_speed_mm_s(40) == pytest.approx(5.0)
    assert MotorUnits(pulses_per_mm=78.0).speed_to_units(0.01) == 1  # never zero
    with pytest.raises(InputError):
        u.speed_to_units(0.0)
    with pytest.raises(InputError):
        MotorUnits(pulses_per_mm=0.0)
    with pytest.raises(InputError):
        MotorUnits(direction=0)


def test_calibration_helpers():
    # the thesis' short run: 39 000 pulses measured as 500 mm on a ruler
    assert pulses_per_mm_from_measurement(-39000, 500.0) == pytest.approx(78.0)
    # marks 100 mm apart, line passes them in 150 frames at 30 fps -> 5 s -> 20 mm/s
    assert speed_from_video_mm_s(100.0, 150, 30.0) == pytest.approx(20.0)
    # S = 4 measured at 5.2 mm/s with 78 pulses/mm -> one speed unit is 101.4 pulses/s
    assert speed_unit_from_measurement(4, 5.2, 78.0) == pytest.approx(101.4)
    for bad in [(0, 1.0), (100, 0.0), (100, float("nan"))]:
        with pytest.raises(InputError):
            pulses_per_mm_from_measurement(*bad)
    with pytest.raises(InputError):
        speed_from_video_mm_s(100.0, 0, 30.0)


def test_move_duration_trapezoid_and_triangle():
    # 1000 pulses at 100 p/s with 100 p/s^2: 1 s up, 1 s down, 900 pulses at full speed
    assert move_duration_s(1000, 100, 100) == pytest.approx(11.0)
    # 100 pulses cannot reach full speed: two halves of sqrt(50/100*2)... = 2*sqrt(1)
    assert move_duration_s(-100, 100, 100) == pytest.approx(2.0)
    assert move_duration_s(0, 100, 100) == 0.0


@pytest.mark.parametrize(
    ("bits", "state", "alarms", "flags"),
    [
        (0, "moving", (), ()),
        (8, "in position", (), ("in position",)),
        (40, "in position", (), ("in position", "push-mode torque limit")),
        (16, "free", (), ("motor free",)),
        (4, "alarm", ("overload / over-current",), ()),
        (1 + 128, "alarm", ("position error overflow", "over temperature"), ()),
        (512, "emergency stop", ("emergency stop",), ()),
    ],
)
def test_status_bits_decode(bits, state, alarms, flags):
    status = MotorStatus(bits)
    assert status.state == state
    assert status.alarms == alarms
    assert status.flags == flags
    assert status.moving == (state == "moving")


# ----------------------------------------------------------------- operations


@pytest.mark.parametrize("echo", [True, False])
def test_connect_reads_version_with_and_without_echo(rig, echo):
    emu, driver = rig(echo=echo)
    assert driver.connected
    assert "CM1" in driver.version
    assert driver.status().in_position
    assert driver.position_pulses() == 0
    assert emu.received[0] == "?85.1"


@pytest.mark.parametrize("echo", [True, False])
def test_move_to_and_by_mm(rig, echo):
    emu, driver = rig(echo=echo)
    snap = driver.move_to_mm(10.0, 5.0)
    assert snap.status.in_position
    assert snap.position_mm == pytest.approx(10.0, abs=0.02)
    assert emu.position_pulses == driver.units.mm_to_pulses(10.0)
    snap = driver.move_by_mm(-4.0, 5.0)
    assert snap.position_mm == pytest.approx(6.0, abs=0.02)
    assert "P.1=-780" in emu.received  # 10 mm at 78 pulses/mm, negative direction
    assert_stopped(emu)


def test_move_duration_matches_speed(rig):
    units = MotorUnits(pulses_per_mm=80.0, speed_unit_pulses_s=10.0)
    # the emulated motor's true speed unit is the calibrated one; 10 000 pulses/s^2 ramps
    emu, driver = rig(
        units=units, accel_units=10, time_scale=20.0, emulator={"speed_unit_pulses_s": 10.0}
    )
    # 60 mm at 8 mm/s (640 pulses/s) takes 7.5 s, plus one ramp time for the two ramps
    expected_s = 7.5 + 640 / 10_000
    t0_before = emu.clock()
    watch = driver.start_move_mm(60.0, 8.0)
    t0_after = emu.clock()
    # the move the motor was given (its own record: speed and ramps as commanded)
    commanded = emu._move
    assert commanded is not None
    assert commanded.duration_s == pytest.approx(expected_s, rel=1e-3)
    brackets: list[tuple[float, float, float]] = []
    last_moving_s = t0_before
    while True:
        before = emu.clock()
        done, snap = driver.check(watch)
        after = emu.clock()
        brackets.append((before, after, snap.position_mm))
        if done:
            break
        last_moving_s = before
    # the move ended after the last poll that saw it moving and before the first that did not,
    # whatever the load on the machine running the test
    shortest_s, longest_s = last_moving_s - t0_after, after - t0_before
    assert shortest_s <= expected_s <= longest_s
    # every position read lies on the commanded trapezoid (8 mm/s cruise, 125 mm/s^2 ramps,
    # worked out here, not by the emulator) somewhere between the emulated times just before
    # and just after its poll: a wrong speed or a stale position falls outside the bracket,
    # a busy machine only widens it
    def travelled_mm(t: float) -> float:
        v, a = 8.0, 10_000 / 80.0
        t_ramp, total = v / a, 60.0 / v + v / a
        t = min(max(t, 0.0), total)
        if t < t_ramp:
            return 0.5 * a * t * t
        if t <= total - t_ramp:
            return 0.5 * v * t_ramp + v * (t - t_ramp)
        return 60.0 - 0.5 * a * (total - t) ** 2

    start_s = commanded.t0_s
    assert t0_before <= start_s <= t0_after
    quantum_mm = 1 / 80.0  # one pulse
    for before, after, x_mm in brackets:
        low, high = travelled_mm(before - start_s), travelled_mm(after - start_s)
        assert low - quantum_mm <= x_mm <= high + quantum_mm
    x = np.array([x_mm for _, _, x_mm in brackets])
    assert ((x > 5.0) & (x < 55.0)).sum() >= 3  # read during the cruise, not only at the ends
    assert np.all(np.diff(x) >= 0)  # position updates during the move, never backwards
    assert snap.position_mm == pytest.approx(60.0, abs=0.02)


def test_positions_are_reported_during_a_move(rig):
    # 0.05 emulated s per command: the 20 mm move (1.95 s at 10.26 mm/s) lasts about twenty
    # polls of two queries each, however busy the machine is
    emu, driver = rig(step_s=0.05)
    seen: list[float] = []
    driver.move_to_mm(20.0, 10.0, on_update=lambda s: seen.append(s.position_mm))
    inside = [p for p in seen if 0.5 < p < 19.5]
    assert len(inside) >= 3


def test_stop_mid_move_from_another_thread(rig):
    emu, driver = rig()
    watch = driver.start_move_mm(1000.0, 5.0)
    done, snap = driver.check(watch)
    assert not done and snap.status.moving
    stopper = threading.Thread(target=driver.stop)
    stopper.start()
    stopper.join()
    final = driver.wait(watch)  # the move ends at once, short of its target
    assert final.position_mm < 999.0
    assert_stopped(emu, short_of_mm=1000.0)


def test_enable_disable_zero_and_speed(rig):
    emu, driver = rig(step_s=0.05)  # emulated time moves with the commands, not the wall clock
    driver.disable()
    assert driver.status().free
    driver.enable()
    assert driver.status().in_position
    driver.move_to_mm(5.0, 5.0)
    driver.set_zero()
    assert driver.position_pulses() == 0
    watch = driver.start_move_mm(50.0, 5.0)
    driver.check(watch)
    # The emulator ramps up at the configured acceleration; poll until cruising (the
    # 50-mm move at 5 mm/s lasts ten emulated seconds, two hundred queries; the ramp 4 ms).
    cruise = driver.units.units_to_speed_mm_s(4)
    speed = driver.speed_mm_s()
    for _ in range(20):
        if speed == pytest.approx(cruise, rel=0.05):
            break
        speed = driver.speed_mm_s()
    assert speed == pytest.approx(cruise, rel=0.05)
    driver.stop()
    assert driver.speed_mm_s() == 0.0


def test_home_returns_to_the_switch_and_zeroes(rig):
    emu, driver = rig()
    driver.move_to_mm(30.0, 10.0)
    driver.set_zero()  # the position counter no longer matches the switch
    snap = driver.home()
    assert snap.position_pulses == 0
    assert "|.1" in emu.received
    assert_stopped(emu)


def test_emergency_stop_and_release(rig):
    # emulated time moves with the commands: the 100 mm move (20 s) cannot end, however long
    # the machine keeps the test from sending the emergency stop
    emu, driver = rig(step_s=0.05)
    driver.start_move_mm(100.0, 5.0)
    driver.emergency_stop()
    status = driver.status()
    assert status.emergency_stop and status.state == "emergency stop"
    assert_stopped(emu, short_of_mm=100.0)
    with pytest.raises(MotorAlarm):
        driver.move_to_mm(0.0, 5.0)  # refused while the emergency stop is active
    driver.release_emergency_stop()
    assert driver.move_to_mm(0.0, 10.0).position_pulses == 0


def test_write_program_and_run_banks(rig):
    # emulated time moves 0.05 s per command, not with the wall clock: the long run (1000
    # pulses at 1000 pulses/s) lasts twenty queries, and bank 2 is sent three after it starts
    emu, driver = rig(events=True, step_s=0.05)
    driver.write_program(scanner_program(home_pulses=-100, short_end_pulses=-1000,
                                         long_end_pulses=-2000, speed_units=10))  # fmt: skip
    assert emu.saved == 1
    assert sorted(emu.banks) == [1, 2, 3, 4]
    assert driver.run_bank(1).position_pulses == -100  # home: zero here, go to P1
    assert driver.run_bank(3).position_pulses == -1000  # short run
    watch = driver.start_bank(4)  # long run, stopped by bank 2
    done, snap = driver.check(watch)
    assert not done and snap.status.moving
    driver.start_bank(2)
    snap = driver.wait(watch)
    # stopped well before the long run's target, after it had set off
    assert -2000 < snap.position_pulses < -1000
    assert_stopped(emu)
    with pytest.raises(MotorRangeError):
        driver.start_bank(0)


def test_thesis_program_has_the_thesis_values():
    lines = scanner_program()
    for expected in ["P1.1=-1000", "P2.1=-40000", "P3.1=-130000", "S1.1=4", "A1.1=100"]:
        assert expected in lines
    assert lines.count("END.1") == 4


def test_unsolicited_status_lines_do_not_confuse_queries(rig):
    emu, driver = rig(events=True, echo=False)
    for target in (3.0, 6.0, 9.0):
        driver.move_to_mm(target, 10.0)  # each end of move emits an unsolicited Ux.1=8
        assert driver.position_mm() == pytest.approx(target, abs=0.02)


def test_url_handler_and_motor_id():
    register_url_handler()
    port = serial.serial_for_url("cm1emu://?echo=0&id=2&time_scale=100", timeout=0.02)
    assert isinstance(port, EmulatedSerial)
    driver = CoolMuscle(port, MotorConfig(motor_id=2, reply_timeout_s=0.3, poll_interval_s=0.005))
    try:
        driver.connect()
        assert driver.move_to_mm(2.0, 5.0).position_mm == pytest.approx(2.0, abs=0.02)
        assert all(line.endswith(".2") or "=" in line for line in port.motor.received)
    finally:
        driver.close()
    with pytest.raises(serial.SerialException, match="colour"):
        serial.serial_for_url("cm1emu://?colour=red")


def test_open_by_name_sim_and_bad_port():
    driver = CoolMuscle.open("sim", MotorConfig(reply_timeout_s=0.3))
    try:
        assert driver.connect()
    finally:
        driver.close()
    with pytest.raises(MotorPortError) as info:
        CoolMuscle.open("/dev/does-not-exist-impress")
    assert info.value.code == "E-MOTOR-PORT"
    assert str(info.value) == (
        "cannot open motor port '/dev/does-not-exist-impress': there is no such port "
        "(impress motor ports lists them)"
    )


def test_port_failures_are_told_in_plain_words():
    import errno

    from impress_gui.hardware.motor_link import plain_reason

    assert plain_reason(OSError(errno.EACCES, "Permission denied")) == (
        "permission denied (on Linux, join the dialout group)"
    )
    assert plain_reason(serial.SerialException("[Errno 16] could not open port: busy")) == (
        "the port is in use by another program"
    )
    text = "Could not configure port: (25, 'Inappropriate ioctl for device')"
    assert plain_reason(serial.SerialException(text)) == "this is not a serial port"
    assert plain_reason(OSError(errno.EROFS, "x")) == "read-only file system"
    assert plain_reason(serial.SerialException("device disconnected")) == "device disconnected"


def test_wrong_motor_id_times_out():
    emu = CM1Emulator(EmulatorConfig(motor_id=3))
    driver = CoolMuscle(emulated_port(emu), MotorConfig(motor_id=1, reply_timeout_s=0.1))
    with pytest.raises(MotorTimeout):
        driver.connect()
    driver.close()


def test_traffic_is_reported(rig):
    emu = CM1Emulator(EmulatorConfig(time_scale=TIME_SCALE))
    log: list[str] = []
    driver = CoolMuscle(emulated_port(emu), on_traffic=lambda d, t: log.append(d + t))
    driver.connect()
    driver.close()
    assert log[:2] == [">?85.1", "<?85.1"]
    assert any(line.startswith("<ID1") for line in log)


# ----------------------------------------------------------------- faults


def test_alarm_mid_move_raises_and_leaves_motor_stopped(rig):
    emu, driver = rig()
    emu.inject_alarm(bits=4, at_fraction=0.4)
    with pytest.raises(MotorAlarm) as info:
        driver.move_to_mm(20.0, 10.0)
    assert info.value.code == "E-MOTOR-ALARM"
    assert info.value.status.alarms == ("overload / over-current",)
    assert 6.0 < driver.position_mm() < 10.0
    assert_stopped(emu, short_of_mm=20.0)
    last_start = max(i for i, line in enumerate(emu.received) if line == "^.1")
    assert "].1" in emu.received[last_start:]  # the driver sent stop after the alarm
    with pytest.raises(MotorAlarm):
        driver.move_to_mm(0.0, 10.0)  # refused until the alarm is reset
    driver.reset_alarm()
    assert driver.move_to_mm(0.0, 10.0).position_pulses == 0


def test_no_reply_raises_timeout_and_motor_is_stopped(rig):
    emu, driver = rig(reply_timeout_s=0.1)
    driver.start_move_mm(1000.0, 5.0)
    emu.set_no_reply()
    with pytest.raises(MotorTimeout) as info:
        driver.position_mm()
    assert info.value.code == "E-MOTOR-TIMEOUT"
    assert_stopped(emu, short_of_mm=1000.0)  # the stop sent after the error got through


def test_garbage_raises_and_motor_is_stopped(rig):
    emu, driver = rig()
    watch = driver.start_move_mm(1000.0, 5.0)
    emu.inject_garbage()
    with pytest.raises(MotorGarbage) as info:
        driver.wait(watch)
    assert info.value.code == "E-MOTOR-GARBAGE"
    assert_stopped(emu, short_of_mm=1000.0)
    assert driver.status().in_position  # the link works again afterwards


def test_disconnect_raises_and_reconnecting_stops_the_motor(rig):
    emu, driver = rig()
    watch = driver.start_move_mm(1000.0, 5.0)
    emu.disconnect()
    with pytest.raises(MotorDisconnected) as info:
        driver.wait(watch)
    assert info.value.code == "E-MOTOR-DISCONNECTED"
    assert not driver.connected
    with pytest.raises(MotorNotConnected) as info2:
        driver.stop()
    assert info2.value.code == "E-MOTOR-NOT-CONNECTED"
    # nothing can reach a motor whose cable is out; connecting again stops it first
    emu.reconnect()
    again = CoolMuscle(emulated_port(emu), MotorConfig(reply_timeout_s=0.3))
    again.connect()
    assert_stopped(emu, short_of_mm=1000.0)
    again.close()


def test_move_that_does_not_finish_in_time(rig):
    emu, driver = rig(move_timeout_factor=0.1, move_timeout_margin_s=0.0, time_scale=1.0)
    with pytest.raises(MotorTimeout):
        driver.move_to_mm(10.0, 5.0)
    assert_stopped(emu, short_of_mm=10.0)


def test_cancel_stops_the_motor(rig):
    emu, driver = rig()
    token = CancelToken()
    calls = []

    def on_update(snap):
        calls.append(snap)
        if len(calls) == 3:
            token.cancel()

    with pytest.raises(Cancelled):
        driver.move_to_mm(1000.0, 5.0, on_update=on_update, cancel=token)
    assert_stopped(emu, short_of_mm=1000.0)


def test_operations_need_a_connection():
    emu = CM1Emulator()
    driver = CoolMuscle(emulated_port(emu))
    with pytest.raises(MotorNotConnected):
        driver.position_mm()
    driver.close()
    with pytest.raises(MotorNotConnected):
        driver.connect()


def test_bad_speed_is_a_range_error(rig):
    emu, driver = rig()
    with pytest.raises(MotorRangeError) as info:
        driver.start_move_mm(10.0, 0.0)
    assert isinstance(info.value, ImpressError)
    assert_stopped(emu)


class ScriptedPort:
    """A serial-like object that answers each write with canned bytes."""

    def __init__(self, answers: dict[bytes, bytes]) -> None:
        self.answers, self.out, self.written = answers, bytearray(), []
        self.timeout = 0.0

    def write(self, data: bytes) -> int:
        self.written.append(data)
        self.out += self.answers.get(data, b"")
        return len(data)

    def read(self, size: int = 1) -> bytes:
        data, self.out = bytes(self.out[:size]), self.out[size:]
        return data

    @property
    def in_waiting(self) -> int:
        return len(self.out)

    def close(self) -> None:
        pass


def test_line_endings_stray_lines_and_bad_values():
    port = ScriptedPort(
        {
            b"?85.1\r": b"?85.1\rID1 :CM1v2\n",
            b"?99.1\r": b"Ux.2=4\r\nhello\rUx.1=8\r\n",  # other motor, noise, then ours
            b"?96.1\r": b"Px.1=12x\r\n",
        }
    )
    driver = CoolMuscle(port, MotorConfig(reply_timeout_s=0.05))
    assert driver.connect() == "ID1 :CM1v2"
    assert driver.status().bits == 8
    with pytest.raises(MotorGarbage):
        driver.position_pulses()
    assert port.written[-1] == b"].1\r"  # stop sent after the error


# ----------------------------------------------------------------- limits

NAN, INF = float("nan"), float("inf")
#: words a message for the user must not contain (Python type names, errno text)
NOT_PLAIN = ("float", "int(", "str", "NoneType", "Error", "Errno", "Traceback")


def assert_refused(emu: CM1Emulator, driver: CoolMuscle, call, code: str) -> ImpressError:
    """``call()`` raises ``code``, and the emulated motor received nothing at all."""
    before = list(emu.received)
    with pytest.raises(MotorRangeError) as info:
        call()
    assert info.value.code == code, str(info.value)
    assert emu.received == before  # not a query, not a stop: nothing reached the motor
    assert not emu.moving and driver.connected
    assert not any(word in str(info.value) for word in NOT_PLAIN), str(info.value)
    return info.value


@pytest.mark.parametrize(
    ("position", "speed", "code"),
    [
        (5000.0, 5.0, "E-MOTOR-LIMIT"),  # past the far end of the 1770 mm rail
        (-300.0, 5.0, "E-MOTOR-LIMIT"),  # behind home
        (1770.01, 5.0, "E-MOTOR-LIMIT"),
        (1e9, 5.0, "E-MOTOR-LIMIT"),  # would overflow the controller's 32-bit position
        (1e300, 5.0, "E-MOTOR-LIMIT"),
        (NAN, 5.0, "E-MOTOR-VALUE"),
        (INF, 5.0, "E-MOTOR-VALUE"),
        (-INF, 5.0, "E-MOTOR-VALUE"),
        ("100", 5.0, "E-MOTOR-VALUE"),
        (None, 5.0, "E-MOTOR-VALUE"),
        (10.0, 1e9, "E-MOTOR-SPEED"),
        (10.0, 100.5, "E-MOTOR-SPEED"),  # the rail's maximum is 100 mm/s
        (10.0, 0.0, "E-MOTOR-SPEED"),
        (10.0, -5.0, "E-MOTOR-SPEED"),
        (10.0, 0.3, "E-MOTOR-SPEED"),  # less than half of one speed unit (1.28 mm/s)
        (10.0, NAN, "E-MOTOR-VALUE"),
        (10.0, INF, "E-MOTOR-VALUE"),
        (10.0, True, "E-MOTOR-VALUE"),
    ],
)
def test_moves_outside_the_limits_are_refused_and_send_nothing(rig, position, speed, code):
    emu, driver = rig()
    error = assert_refused(emu, driver, lambda: driver.start_move_mm(position, speed), code)
    assert isinstance(error, ImpressError)
    assert_refused(emu, driver, lambda: driver.move_to_mm(position, speed), code)
    assert driver.move_to_mm(3.0, 5.0).position_mm == pytest.approx(3.0, abs=0.02)  # still works


def test_refused_move_messages_say_why(rig):
    emu, driver = rig()
    texts = {}
    for name, call in {
        "far": lambda: driver.start_move_mm(5000.0, 5.0),
        "nan": lambda: driver.start_move_mm(NAN, 5.0),
        "fast": lambda: driver.start_move_mm(10.0, 1e9),
        "slow": lambda: driver.start_move_mm(10.0, 0.3),
    }.items():
        with pytest.raises(MotorRangeError) as info:
            call()
        texts[name] = str(info.value)
    assert texts["far"] == (
        "the target position 5000.00 mm is outside the rail's travel (0 to 1770 mm from home)"
    )
    assert texts["nan"] == "the target position must be a finite number of mm, got nan"
    assert texts["fast"] == (
        "the speed 1e+09 mm/s is faster than the rail's maximum of 100 mm/s"
    )
    assert "slowest speed is one speed unit, 1.28 mm/s" in texts["slow"]


@pytest.mark.parametrize(
    ("pulses", "speed_units", "code"),
    [
        (2**31, 4, "E-MOTOR-LIMIT"),  # one past the controller's 32-bit position register
        (-(2**31) - 1, 4, "E-MOTOR-LIMIT"),
        (-(2**40), 4, "E-MOTOR-LIMIT"),
        (-138_061, 4, "E-MOTOR-LIMIT"),  # one pulse past 1770 mm (78 pulses/mm, direction -1)
        (1000, 4, "E-MOTOR-LIMIT"),  # positive pulses lie behind home
        (-780.5, 4, "E-MOTOR-VALUE"),
        (NAN, 4, "E-MOTOR-VALUE"),
        (-780, 0, "E-MOTOR-SPEED"),
        (-780, -4, "E-MOTOR-SPEED"),
        (-780, 79, "E-MOTOR-SPEED"),  # 101.3 mm/s
        (-780, 2**40, "E-MOTOR-SPEED"),
        (-780, 4.0, "E-MOTOR-VALUE"),
    ],
)
def test_moves_in_pulses_obey_the_same_limits(rig, pulses, speed_units, code):
    emu, driver = rig()
    assert_refused(emu, driver, lambda: driver.start_move_pulses(pulses, speed_units), code)


def test_the_ends_of_the_travel_are_reachable(rig):
    emu, driver = rig(time_scale=1000.0)
    assert driver.move_to_mm(1770.0, 100.0).position_pulses == -138_060
    assert driver.move_to_mm(0.0, 100.0).position_pulses == 0


@pytest.mark.parametrize(
    ("distance", "code"),
    [(5000.0, "E-MOTOR-LIMIT"), (-1771.0, "E-MOTOR-LIMIT"), (NAN, "E-MOTOR-VALUE"),
     (INF, "E-MOTOR-VALUE")],
)  # fmt: skip
def test_relative_moves_longer_than_the_rail_send_nothing(rig, distance, code):
    emu, driver = rig()
    assert_refused(emu, driver, lambda: driver.move_by_mm(distance, 5.0), code)
    assert_refused(emu, driver, lambda: driver.start_move_by_mm(distance, 5.0), code)


def test_relative_move_past_an_end_is_refused_by_where_it_ends(rig):
    emu, driver = rig(time_scale=1000.0)
    driver.move_to_mm(1765.0, 50.0)
    before = len(emu.received)
    with pytest.raises(MotorRangeError) as info:
        driver.move_by_mm(10.0, 5.0)
    assert info.value.code == "E-MOTOR-LIMIT"
    assert str(info.value) == (
        "a move by +10.00 mm from 1765.00 mm would end at 1775.00 mm, outside the rail's "
        "travel (0 to 1770 mm from home)"
    )
    assert emu.received[before:] == ["?96.1"]  # the position was read; no move was sent
    with pytest.raises(MotorRangeError):
        driver.move_by_mm(-1766.0, 5.0)  # behind home
    assert [line for line in emu.received[before:] if line != "?96.1"] == []
    assert driver.move_by_mm(5.0, 5.0).position_pulses == -138_060  # to the end exactly
    assert_stopped(emu)


def test_banks_programs_and_raw_commands_are_checked(rig):
    emu, driver = rig()
    assert_refused(emu, driver, lambda: driver.start_bank(0), "E-MOTOR-RANGE")
    assert_refused(emu, driver, lambda: driver.start_bank(31), "E-MOTOR-RANGE")
    assert_refused(emu, driver, lambda: driver.start_bank(2.5), "E-MOTOR-VALUE")
    far = scanner_program(long_end_pulses=-200_000)  # 2564 mm: past the rail's end
    error = assert_refused(emu, driver, lambda: driver.write_program(far), "E-MOTOR-LIMIT")
    assert "P3.1=-200000" in str(error)
    fast = scanner_program(speed_units=1000)  # 1282 mm/s
    assert_refused(emu, driver, lambda: driver.write_program(fast), "E-MOTOR-SPEED")
    behind = scanner_program(home_pulses=1000)  # 12.8 mm behind home
    assert_refused(emu, driver, lambda: driver.write_program(behind), "E-MOTOR-LIMIT")
    assert emu.saved == 0
    for line, code in [
        ("P.1=99999999999", "E-MOTOR-LIMIT"),
        ("P.1=-200000", "E-MOTOR-LIMIT"),
        ("P.1=12.5", "E-MOTOR-VALUE"),
        ("S.1=0", "E-MOTOR-SPEED"),
        ("A.1=4294967296", "E-MOTOR-VALUE"),
        ("P=-200000", "E-MOTOR-LIMIT"),  # without the id suffix
        ("p2.1=5000", "E-MOTOR-LIMIT"),
    ]:
        assert_refused(emu, driver, lambda line=line: driver.send(line), code)
    driver.send("P.1=-780")  # within the limits: sent
    assert emu.received[-1] == "P.1=-780"


def test_a_smaller_configured_travel_and_speed_are_honoured(rig):
    limits = RailLimits(travel_mm=100.0, max_speed_mm_s=12.2)
    emu, driver = rig(limits=limits, time_scale=200.0)
    assert driver.limits == limits
    assert driver.move_to_mm(100.0, 10.0).position_mm == pytest.approx(100.0, abs=0.02)
    error = assert_refused(emu, driver, lambda: driver.start_move_mm(100.5, 10.0), "E-MOTOR-LIMIT")
    assert "(0 to 100 mm from home)" in str(error)
    assert_refused(emu, driver, lambda: driver.start_move_pulses(-7801, 4), "E-MOTOR-LIMIT")
    assert_refused(emu, driver, lambda: driver.move_by_mm(150.0, 10.0), "E-MOTOR-LIMIT")
    assert_refused(emu, driver, lambda: driver.start_move_mm(50.0, 13.138), "E-MOTOR-SPEED")
    # 12.2 mm/s rounds to S = 10, 12.82 mm/s: faster than the maximum, so refused too
    error = assert_refused(emu, driver, lambda: driver.start_move_mm(50.0, 12.2), "E-MOTOR-SPEED")
    assert "runs at 12.82 mm/s" in str(error)
    assert_refused(emu, driver, lambda: driver.write_program(scanner_program()), "E-MOTOR-LIMIT")
    assert driver.move_by_mm(-50.0, 11.0).position_mm == pytest.approx(50.0, abs=0.02)


def test_rail_limits_are_validated_and_round_trip():
    assert RailLimits() == RailLimits(travel_mm=1770.0, max_speed_mm_s=100.0)
    limits = RailLimits(travel_mm=1200.0, max_speed_mm_s=20.0)
    assert RailLimits.from_dict(limits.to_dict()) == limits
    assert RailLimits.from_dict({"travel_mm": "1200", "max_speed_mm_s": "20"}) == limits
    assert RailLimits.from_dict({"travel_mm": 500}) == RailLimits(travel_mm=500.0)
    bad = [
        {"travel_mm": 0.0},
        {"travel_mm": -5.0},
        {"travel_mm": NAN},
        {"travel_mm": INF},
        {"travel_mm": 20_000.0},
        {"travel_mm": "long"},
        {"max_speed_mm_s": 0.0},
        {"max_speed_mm_s": 5000.0},
        {"colour": 1.0},
    ]
    for values in bad:
        with pytest.raises(MotorSettingsError) as info:
            RailLimits.from_dict(values)
        assert info.value.code == "E-MOTOR-SETTINGS"
        assert not any(word in str(info.value) for word in NOT_PLAIN), str(info.value)
    with pytest.raises(MotorSettingsError):
        RailLimits(travel_mm=True)
    # a travel whose far end in pulses the controller's 32-bit counter cannot hold
    with pytest.raises(MotorSettingsError) as info:
        MotorConfig(units=MotorUnits(pulses_per_mm=2e6), limits=RailLimits(travel_mm=1770.0))
    assert "position counter" in str(info.value)
    assert MotorConfig().limits == RailLimits()


def test_any_exception_during_a_move_stops_the_motor(rig):
    emu, driver = rig()

    def on_update(snap):
        if snap.position_mm > 1.0:
            raise RuntimeError("a bug in the caller")

    with pytest.raises(RuntimeError):
        driver.move_to_mm(1000.0, 5.0, on_update=on_update)
    assert_stopped(emu, short_of_mm=1000.0)
    last_start = max(i for i, line in enumerate(emu.received) if line == "^.1")
    assert "].1" in emu.received[last_start:]
    # an exception inside a driver call (here: while the position is parsed) stops it as well
    watch = driver.start_move_mm(1000.0, 5.0)
    driver.check(watch)
    original = driver._classify

    def broken(line):
        raise ValueError("broken parser")

    driver._classify = broken  # type: ignore[method-assign]
    with pytest.raises(ValueError):
        driver.wait(watch)
    driver._classify = original  # type: ignore[method-assign]
    assert_stopped(emu, short_of_mm=1000.0)
    assert emu.received[-1] == "].1" and emu.received.count("].1") >= 2
