"""The emulated CM1 on its own (with a hand-driven clock), end to end through a pseudo-terminal,
and the ``impress motor`` command."""

from __future__ import annotations

import os

import pytest
import serial

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

    def start(**config):
        emu = CM1Emulator(EmulatorConfig(**{"time_scale": 50.0, **config}))
        server = PtyServer(emu)
        servers.append(server)
        return emu, server.start()

    yield start
    for server in servers:
        server.close()


@posix_only
@pytest.mark.parametrize("echo", [True, False])
def test_driver_through_a_pseudo_terminal(pty_motor, echo):
    emu, path = pty_motor(echo=echo)
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
