"""The emulated CM1 on its own (with a hand-driven clock), end to end through a pseudo-terminal,
and the ``impress motor`` command."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest
import serial
from test_motor_driver import CommandClock

from impress_gui.cli import main
from impress_gui.hardware.cool_muscle import (
    CoolMuscle,
    MotorAlarm,
    MotorConfig,
    MotorDisconnected,
)
from impress_gui.hardware.emulator import (
    GARBAGE_BYTES,
    CM1Emulator,
    EmulatorConfig,
    PtyServer,
    emulated_port,
)

pytestmark = pytest.mark.usefixtures("no_stray_threads")


posix_only = pytest.mark.skipif(os.name != "posix", reason="pseudo-terminals are POSIX only")


class Clock:
    """A clock the test moves by hand (emulated seconds)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def talk(emu: CM1Emulator, *lines: str) -> list[str]:
    for line in lines:
        emu.feed(line.encode() + b"\r\n")
    return emu.take_output().decode("ascii", "replace").split("\r\n")[:-1]


def make(clock: Clock, **config) -> CM1Emulator:
    return CM1Emulator(EmulatorConfig(**{"echo": False, **config}), clock=clock)


# ----------------------------------------------------------------- the emulated motor


def test_move_follows_a_trapezoid_in_time():
    clock = Clock()
    emu = make(clock)
    # 10 000 pulses at S=10 (1000 pulses/s) with A=1 (1000 pulses/s^2): 1 s ramps, 11 s in all
    talk(emu, "P.1=10000", "S.1=10", "A.1=1", "^.1")
    for t, position, speed in [(0.5, 125, 5), (1.0, 500, 10), (6.0, 5500, 10), (10.5, 9875, 5)]:
        clock.t = t
        assert talk(emu, "?96.1", "?97.1", "?99.1") == [
            f"Px.1={position}",
            f"Sx.1={speed}",
            "Ux.1=0",
        ]
    clock.t = 11.0
    assert talk(emu, "?96.1", "?97.1", "?99.1") == ["Px.1=10000", "Sx.1=0", "Ux.1=8"]


def test_echo_id_suffix_and_parameters():
    clock = Clock()
    emu = make(clock, echo=True)
    assert talk(emu, "?99.1") == ["?99.1", "Ux.1=8"]
    assert talk(emu, "?99.2") == []  # another motor's command: silence
    assert talk(emu, "K23.1=8") == ["K23.1=8"]  # K23 bit 8: echo off from now on
    assert talk(emu, "?96.1") == ["Px.1=0"]
    assert talk(emu, "?85.1")[0].startswith("ID1 :CM1")
    emu2 = make(clock, motor_id=2)
    assert talk(emu2, "?99.2") == ["Ux.2=8"]


def test_end_of_move_events():
    clock = Clock()
    emu = make(clock, report_events=True)
    talk(emu, "P.1=100", "S.1=10", "^.1")
    assert talk(emu) == []
    clock.t = 1.0
    assert talk(emu) == ["Ux.1=8"]  # unsolicited


def test_stop_homing_zero_and_emergency_stop():
    clock = Clock()
    emu = make(clock, home_speed_units=10)
    talk(emu, "P.1=5000", "S.1=10", "^.1")
    clock.t = 2.0
    talk(emu, "].1")
    clock.t = 3.0
    assert talk(emu, "?96.1", "?99.1") == ["Px.1=1995", "Ux.1=8"]  # stopped where it was
    talk(emu, "|2.1")
    assert talk(emu, "?96.1") == ["Px.1=0"]
    talk(emu, "|.1")  # origin search back to the switch, 1995 pulses away
    clock.t = 6.0
    assert talk(emu, "?96.1", "?99.1") == ["Px.1=0", "Ux.1=8"]
    talk(emu, "P.1=1000", "^.1")
    clock.t = 6.2
    talk(emu, "*")
    clock.t = 7.0
    assert talk(emu, "?99.1") == ["Ux.1=512"]
    talk(emu, "^.1")  # refused during the emergency stop
    assert not emu.moving
    talk(emu, "*1")
    assert talk(emu, "?99.1") == ["Ux.1=8"]


def test_banks_define_run_and_preloaded_program():
    clock = Clock()
    emu = make(clock)
    assert sorted(emu.banks) == [1, 2, 3, 4]  # the thesis program, as on the rig
    talk(emu, "B7.1", "S.1=10", "P.1=100", "^.1", "P.1=300", "^.1", "END.1", "$.1")
    assert emu.banks[7] == ["S.1=10", "P.1=100", "^.1", "P.1=300", "^.1"]
    assert emu.saved == 1
    talk(emu, "[7.1")
    clock.t = 0.15  # the first move (100 pulses) ended at 0.11 s, the second (200) runs
    assert talk(emu, "?96.1", "?99.1") == ["Px.1=135", "Ux.1=0"]
    clock.t = 2.0
    assert talk(emu, "?96.1", "?99.1") == ["Px.1=300", "Ux.1=8"]
    talk(emu, "[3.1")  # short run of the thesis program: to P2 = -40000 at S1 = 4
    clock.t = 2.0 + 40000 / 400 + 1.0
    assert talk(emu, "?96.1") == ["Px.1=-40000"]


def test_faults_alarm_no_reply_garbage_disconnect():
    clock = Clock()
    emu = make(clock)
    emu.inject_alarm(bits=128, at_fraction=0.5)
    talk(emu, "P.1=1000", "S.1=10", "A.1=1000", "^.1")
    clock.t = 5.0
    assert talk(emu, "?96.1", "?99.1") == ["Px.1=500", "Ux.1=128"]
    talk(emu, "(.1")  # enable clears the latched alarm
    assert talk(emu, "?99.1") == ["Ux.1=8"]
    emu.set_no_reply()
    assert talk(emu, "?99.1") == []
    emu.set_no_reply(False)
    emu.inject_garbage()
    emu.feed(b"?99.1\r")
    assert emu.take_output() == GARBAGE_BYTES + b"\r\n"
    port = emulated_port(emu)
    emu.disconnect()
    with pytest.raises(serial.SerialException):
        port.read(1)
    emu.reconnect()
    port.write(b"?99.1\r")
    assert port.read(9) == b"Ux.1=8\r\n"


# ----------------------------------------------------------------- end to end through a pty


@pytest.fixture
def pty_motor():
    servers: list[PtyServer] = []

    def start(step_s: float | None = None, **config):
        """The motor behind a pseudo-terminal; with ``step_s``, its clock is a
        :class:`CommandClock` (else the wall clock, ``time_scale`` times faster)."""
        clock = None if step_s is None else CommandClock(step_s)
        emu = CM1Emulator(EmulatorConfig(**{"time_scale": 50.0, **config}), clock=clock)
        if clock is not None:
            clock.motor = emu
        server = PtyServer(emu)
        servers.append(server)
        return emu, server.start()

    yield start
    for server in servers:
        server.close()


@posix_only
@pytest.mark.parametrize("echo", [True, False])
def test_driver_through_a_pseudo_terminal(pty_motor, echo):
    # emulated time moves 0.05 s per command received, not with the wall clock: the 15 mm
    # move (1.46 s at 10.26 mm/s) lasts about fifteen polls of two queries each, each poll
    # finding the carriage about 0.8 mm further on, however busy the machine is
    emu, path = pty_motor(echo=echo, step_s=0.05)
    assert path.startswith("/dev/")
    config = MotorConfig(reply_timeout_s=0.5, poll_interval_s=0.005)
    driver = CoolMuscle.open(path, config)
    try:
        assert "CM1" in driver.connect()
        assert type(driver.port).__name__ == "Serial"  # a real pyserial port on a tty
        seen: list[float] = []
        snap = driver.move_to_mm(15.0, 10.0, on_update=lambda s: seen.append(s.position_mm))
        assert snap.position_mm == pytest.approx(15.0, abs=0.02)
        assert any(0.5 < p < 14.5 for p in seen)
        assert driver.home().position_pulses == 0
        assert driver.run_bank(1).position_pulses == -1000  # preloaded thesis bank
        driver.start_move_mm(1000.0, 5.0)
        driver.stop()
        assert driver.status().in_position  # answered after the emulator handled the stop
        assert not emu.moving
    finally:
        driver.close()


@posix_only
def test_alarm_and_hangup_through_a_pseudo_terminal(pty_motor):
    emu, path = pty_motor()
    driver = CoolMuscle.open(path, MotorConfig(reply_timeout_s=0.5, poll_interval_s=0.005))
    try:
        driver.connect()
        emu.inject_alarm(bits=1)
        with pytest.raises(MotorAlarm) as info:
            driver.move_to_mm(20.0, 10.0)
        assert info.value.status.alarms == ("position error overflow",)
        assert not emu.moving
        driver.reset_alarm()
        watch = driver.start_move_mm(1000.0, 5.0)
        emu.disconnect()  # the server hangs up the terminal, like an unplugged adapter
        with pytest.raises(MotorDisconnected):
            driver.wait(watch)
        assert not driver.connected
    finally:
        driver.close()


# ----------------------------------------------------------------- the command line


@posix_only
def test_cli_through_a_pseudo_terminal(pty_motor, capsys):
    emu, path = pty_motor()
    assert main(["motor", "--port", path, "status"]) == 0
    out = capsys.readouterr().out
    assert "CM1" in out and "state: in position" in out
    assert main(["motor", "--port", path, "move", "--to", "10", "--speed", "5"]) == 0
    assert "position: 10.00 mm" in capsys.readouterr().out
    assert emu.position_pulses == -780
    assert main(["motor", "--port", path, "run-bank", "1"]) == 0
    assert emu.position_pulses == -1000
    emu.inject_alarm(bits=4)
    assert main(["motor", "--port", path, "move", "--by", "-5"]) == 2
    assert "E-MOTOR-ALARM" in capsys.readouterr().err
    assert not emu.moving


def test_cli_simulated_motor_and_helpers(capsys):
    args = ["motor", "--port", "sim", "--sim-time-scale", "100", "move", "--to", "3"]
    assert main(args) == 0
    assert "position: 3.00 mm" in capsys.readouterr().out
    assert main(["motor", "calibrate", "--commanded-pulses", "39000", "--measured-mm", "500"]) == 0
    assert "78.0000" in capsys.readouterr().out
    assert (
        main(["motor", "speed-check", "--distance-mm", "100", "--frames", "150", "--fps", "30"])
        == 0
    )
    assert "20.000 mm/s" in capsys.readouterr().out
    check = ["--pulses-per-mm", "78", "speed-check", "--distance-mm", "100", "--frames", "150"]
    assert main(["motor", *check, "--fps", "30", "--commanded-s", "20"]) == 0
    assert "one speed unit: 78.000 pulses/s" in capsys.readouterr().out
    assert main(["motor", "ports"]) == 0
    assert "Simulated motor" in capsys.readouterr().out
    assert main(["motor", "--port", "/dev/no-such-port-impress", "status"]) == 2
    assert "E-MOTOR-PORT" in capsys.readouterr().err


@posix_only
def test_cli_emulate_pty_serves_and_stops(capsys):
    assert main(["motor", "emulate-pty", "--seconds", "0.1"]) == 0
    assert "simulated Cool Muscle on /dev/" in capsys.readouterr().out


# ----------------------------------------------------------------- the command line's limits


@posix_only
@pytest.mark.parametrize(
    ("args", "code"),
    [
        (["move", "--to", "5000"], "E-MOTOR-LIMIT"),
        (["move", "--to", "-300"], "E-MOTOR-LIMIT"),
        (["move", "--to", "1e9"], "E-MOTOR-LIMIT"),
        (["move", "--to", "10", "--speed", "1e9"], "E-MOTOR-SPEED"),
        (["move", "--to", "10", "--speed", "0"], "E-MOTOR-SPEED"),
        (["move", "--to", "10", "--speed", "-2"], "E-MOTOR-SPEED"),
        (["move", "--by", "5000"], "E-MOTOR-LIMIT"),
        (["run-bank", "31"], "E-MOTOR-RANGE"),
        (["--travel-mm", "100", "move", "--to", "150"], "E-MOTOR-LIMIT"),
        (["--travel-mm", "1000", "write-program"], "E-MOTOR-LIMIT"),  # its long run: 1667 mm
        (["--max-speed", "10", "move", "--to", "10", "--speed", "13.138"], "E-MOTOR-SPEED"),
        (["--travel-mm", "-5", "status"], "E-MOTOR-SETTINGS"),
        (["--travel-mm", "1770", "--pulses-per-mm", "2e6", "status"], "E-MOTOR-SETTINGS"),
    ],
)
def test_cli_refuses_moves_outside_the_limits_before_opening_the_port(
    pty_motor, capsys, args, code
):
    emu, path = pty_motor()
    assert main(["motor", "--port", path, *args]) == 2
    err = capsys.readouterr().err
    assert f"error [{code}]" in err and "Traceback" not in err
    assert emu.received == []  # the port was not even opened


@pytest.mark.parametrize(
    "args",
    [
        ["move", "--to", "nan"],
        ["move", "--to", "inf"],
        ["move", "--by=-inf"],
        ["move", "--to", "10", "--speed", "nan"],
        ["--travel-mm", "nan", "status"],
        ["move", "--to", "1e400"],
    ],
)
def test_cli_rejects_non_finite_numbers_with_a_code(capsys, args):
    with pytest.raises(SystemExit) as info:
        main(["motor", "--port", "sim", *args])
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert "E-MOTOR-VALUE" in err and "is not a finite number" in err
    assert "Traceback" not in err


@posix_only
def test_cli_relative_move_past_the_end_is_refused_without_moving(pty_motor, capsys):
    emu, path = pty_motor()
    assert main(["motor", "--port", path, "move", "--to", "1765", "--speed", "50"]) == 0
    moves = len([line for line in emu.received if line.startswith(("P", "S", "A", "^"))])
    assert main(["motor", "--port", path, "move", "--by", "10"]) == 2
    assert "error [E-MOTOR-LIMIT]: a move by +10.00 mm from 1765.00 mm" in capsys.readouterr().err
    assert len([line for line in emu.received if line.startswith(("P", "S", "A", "^"))]) == moves
    assert emu.position_pulses == -1765 * 78


def _wait_for(condition, timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


@posix_only
@pytest.mark.parametrize(
    ("signame", "status", "message"),
    [
        ("SIGTERM", 2, "error [E-MOTOR-INTERRUPTED]: ended by a terminate signal (SIGTERM)"),
        ("SIGHUP", 2, "error [E-MOTOR-INTERRUPTED]: ended by the terminal being closed (SIGHUP)"),
        ("SIGINT", 130, "impress motor: interrupted"),
    ],
)
def test_cli_move_ended_by_a_signal_stops_the_motor(pty_motor, signame, status, message):
    emu, path = pty_motor(time_scale=1.0)  # 1000 mm at 5 mm/s: over three minutes
    # as from a terminal: a test run under nohup or from a background shell would hand the
    # command SIGHUP / SIGINT ignored, which it deliberately leaves ignored; the prelude puts
    # the dispositions a terminal gives back, then runs `python -m impress_gui`
    prelude = ("import runpy, signal, sys; signal.signal(signal.SIGHUP, signal.SIG_DFL); "
               "signal.signal(signal.SIGINT, signal.default_int_handler); "
               "sys.argv = ['impress_gui'] + sys.argv[1:]; "
               "runpy.run_module('impress_gui', run_name='__main__', alter_sys=True)")
    command = [sys.executable, "-c", prelude, "motor", "--port", path, "move", "--to", "1000"]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, text=True
    )
    try:
        # (generous bounds: a busy machine may take long to start the command; the move
        # itself lasts over three minutes)
        _wait_for(lambda: emu.moving and emu.position_pulses < -40, timeout_s=60.0)  # on its way
        proc.send_signal(getattr(signal, signame))
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == status, err
    assert message in err and "Traceback" not in err
    start = max(i for i, line in enumerate(emu.received) if line == "^.1")
    # the stop reached the motor (the pseudo-terminal's server thread may still be passing on
    # the last bytes the command wrote before it exited)
    _wait_for(lambda: "].1" in emu.received[start:], timeout_s=10.0)
    assert not emu.moving
    here = emu.position_pulses
    assert 0 > here > -1000 * 78  # stopped part way
    emu.wait_output(0.05)  # let the emulated time pass: the position stays
    assert emu.position_pulses == here


def test_cli_reports_the_position_while_a_bank_runs(capsys):
    """`impress motor run-bank` is not silent for the minutes a scan takes (issue 21, item 13):
    the position and state go to stderr while it moves, at most once a second."""
    # (at 20x the bank runs about 5 s of wall time: two reports a second apart even when a
    # busy machine holds the command up for a second)
    assert main(["motor", "--port", "sim", "--sim-time-scale", "20", "run-bank", "3"]) == 0
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip().startswith("bank 3:")]
    assert len(lines) >= 2, err
    positions = [float(ln.split(":")[1].split("mm")[0]) for ln in lines]
    assert positions == sorted(positions) and positions[-1] > positions[0]
    assert "position:" in out


@pytest.mark.parametrize("argv", [
    ["motor", "--port", "sim", "--timeout", "-1", "status"],
    ["motor", "--port", "sim", "--timeout", "1e9", "status"],
    ["motor", "--port", "sim", "--sim-time-scale", "0", "status"],
    ["motor", "calibrate", "--commanded-pulses", "1e300", "--measured-mm", "1e-300"],
])
def test_link_values_out_of_range_are_refused_with_a_code(argv, capsys):
    # a hostile-input audit: --timeout -1 was an internal error (pyserial), --sim-time-scale 0
    # ran into E-MOTOR-TIMEOUT, a calibration printed "pulses per mm: inf"
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse's refusal of an option's value
        rc = exc.code
    err = capsys.readouterr().err
    assert rc == 2 and "[E-" in err and "Traceback" not in err and "E-INTERNAL" not in err
