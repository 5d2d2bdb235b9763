"""The motor panel driven with pytest-qt against the emulated motor."""

from __future__ import annotations

import os
import signal
from dataclasses import replace

import pytest
from PySide6.QtCore import Qt
from test_motor_driver import CommandClock

from impress_gui.hardware.cool_muscle import CoolMuscle, MotorConfig
from impress_gui.hardware.emulator import CM1Emulator, EmulatorConfig, PtyServer, emulated_port
from impress_gui.hardware.rail import RAIL_TRAVEL_MM, SPEED_PRESETS_MM_S, RailLimits
from impress_gui.ui.motor.panel import SIMULATED_LABEL, MotorPanel, MotorPanelSettings

pytestmark = pytest.mark.usefixtures("no_stray_threads")


TIME_SCALE = 20.0
FAST = MotorConfig(poll_interval_s=0.01, reply_timeout_s=0.3)


class Rig:
    """Panels made for one test, with the emulated motors their connections created."""

    def __init__(self, qtbot) -> None:
        self.qtbot = qtbot
        self.panels: list[MotorPanel] = []
        self.motors: list[CM1Emulator] = []
        self.ports: list[str] = []
        #: when set, the motors' clocks are a CommandClock of this step (not the wall clock)
        self.step_s: float | None = None

    def factory(self, port, config, on_traffic):
        self.ports.append(port)
        clock = None if self.step_s is None else CommandClock(self.step_s)
        motor = CM1Emulator(EmulatorConfig(time_scale=TIME_SCALE), clock=clock)
        if clock is not None:
            clock.motor = motor
        self.motors.append(motor)
        return CoolMuscle(emulated_port(motor), config, on_traffic=on_traffic)

    def panel(self, *, default_factory: bool = False, **settings) -> MotorPanel:
        settings = {"motor": FAST, "idle_poll_s": 0.05, **settings}
        panel = MotorPanel(
            settings=MotorPanelSettings(**settings),
            driver_factory=None if default_factory else self.factory,
            port_lister=lambda: [("/dev/ttyFAKE0", "USB-Serial Controller")],
        )
        self.qtbot.addWidget(panel)
        self.panels.append(panel)
        return panel

    def connected_panel(self, port: str = SIMULATED_LABEL, **settings) -> MotorPanel:
        panel = self.panel(**settings)
        panel.port_combo.setCurrentText(port)
        with self.qtbot.waitSignal(panel.connection_changed, timeout=5000) as blocker:
            panel.connect_button.click()
        assert blocker.args == [True]
        self.qtbot.waitUntil(lambda: panel.state_label.text() == "in position", timeout=3000)
        return panel


@pytest.fixture
def rig(qtbot):
    r = Rig(qtbot)
    yield r
    for panel in r.panels:
        panel.shutdown()
        assert panel._thread.isFinished()
    for motor in r.motors:
        assert not motor.moving  # no test leaves a carriage moving


def test_ports_listed_typed_and_simulated(rig):
    panel = rig.panel()
    items = [panel.port_combo.itemText(i) for i in range(panel.port_combo.count())]
    assert items == [SIMULATED_LABEL, "/dev/ttyFAKE0 (USB-Serial Controller)"]
    panel.port_combo.setCurrentIndex(1)
    assert panel.selected_port() == "/dev/ttyFAKE0"
    panel.port_combo.setCurrentText("socket://rig-laptop:7000")
    assert panel.selected_port() == "socket://rig-laptop:7000"
    panel.port_combo.setCurrentIndex(0)
    assert panel.selected_port() == "sim"
    assert panel.stop_button.isEnabled()  # even when not connected
    assert not panel.home_button.isEnabled()


def test_connect_shows_version_state_and_position(rig):
    panel = rig.connected_panel()
    assert rig.ports == ["sim"]
    assert "CM1" in panel.version_label.text()
    assert panel.position_label.text() == "0.00 mm"
    assert panel.connect_button.text() == "Disconnect"
    assert not panel.port_combo.isEnabled()
    with rig.qtbot.waitSignal(panel.connection_changed, timeout=3000) as blocker:
        panel.connect_button.click()
    assert blocker.args == [False]
    assert panel.state_label.text() == "not connected"


def test_scan_shows_positions_during_the_move_and_stops_on_stop(rig, qtbot):
    # emulated time moves 0.01 s per command, not with the wall clock: each poll (two
    # queries, then 10 ms of sleep) finds the carriage 0.1 mm further on, and the 500 mm scan
    # (97.5 s) cannot end before some 4900 polls, over 48 s, however busy the machine is
    rig.step_s = 0.01
    panel = rig.connected_panel(short_scan_mm=500.0, speed_mm_s=5.0, end_mm=100.0)
    motor = rig.motors[0]
    positions: list[float] = []
    panel.position_changed.connect(positions.append)
    panel.short_button.click()  # a preset: fills the end position, does not move
    assert panel.end_spin.value() == 500.0 and not panel.is_busy
    panel.scan_button.click()
    qtbot.waitUntil(lambda: len({round(p, 1) for p in positions if 0.5 < p < 499.0}) >= 5,
                    timeout=30000)
    assert panel.is_busy and panel.state_label.text() == "moving"
    assert not panel.scan_button.isEnabled() and panel.stop_button.isEnabled()
    assert positions == sorted(positions)  # the carriage advances
    qtbot.mouseClick(panel.stop_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not panel.is_busy and panel.state_label.text() == "in position",
                    timeout=30000)
    assert not motor.moving
    assert 0.5 < motor.position_pulses / -78.0 < 499.0  # stopped part way
    assert panel.scan_button.isEnabled()
    assert "# STOP" in panel.log_view.toPlainText()


def test_home_and_jog(rig, qtbot):
    panel = rig.connected_panel(jog_step_mm=4.0, speed_mm_s=10.0)
    motor = rig.motors[0]
    panel.jog_plus_button.click()
    qtbot.waitUntil(lambda: not panel.is_busy and motor.position_pulses == -312)
    qtbot.waitUntil(lambda: panel.position_label.text() == "4.00 mm")
    panel.jog_minus_button.click()
    qtbot.waitUntil(lambda: not panel.is_busy and motor.position_pulses == 0)
    panel.move_to(8.0)
    qtbot.waitUntil(lambda: not panel.is_busy and motor.position_pulses == -624)
    panel.home_button.click()
    qtbot.waitUntil(lambda: not panel.is_busy and panel.position_label.text() == "0.00 mm")
    assert "|.1" in motor.received


def test_alarm_is_shown_and_motor_stopped(rig, qtbot):
    panel = rig.connected_panel(jog_step_mm=20.0, speed_mm_s=5.0)
    motor = rig.motors[0]
    motor.inject_alarm(bits=4, at_fraction=0.5)
    with qtbot.waitSignal(panel.error, timeout=5000) as blocker:
        panel.jog_plus_button.click()
    assert blocker.args[0] == "E-MOTOR-ALARM"
    assert "E-MOTOR-ALARM" in panel.error_label.text()
    qtbot.waitUntil(lambda: panel.alarm_label.text() == "overload / over-current")
    assert not motor.moving and not panel.is_busy
    qtbot.waitUntil(lambda: panel.state_label.text() == "alarm")
    panel.reset_button.click()
    qtbot.waitUntil(lambda: panel.state_label.text() == "in position")
    assert panel.alarm_label.text() == ""
    panel.jog_plus_button.click()  # moves again after the reset; the old error is cleared
    assert panel.error_label.text() == ""
    qtbot.waitUntil(lambda: not panel.is_busy and motor.position_pulses == -2340)  # 10 + 20 mm


def test_vanished_port_disconnects_the_panel(rig, qtbot):
    panel = rig.connected_panel()
    with qtbot.waitSignal(panel.connection_changed, timeout=3000) as blocker:
        rig.motors[0].disconnect()
    assert blocker.args == [False]
    assert "E-MOTOR-DISCONNECTED" in panel.error_label.text()
    assert panel.connect_button.text() == "Connect" and panel.connect_button.isEnabled()
    assert panel.stop_button.isEnabled()
    panel.stop_button.click()  # harmless without a motor


def test_bad_port_reports_an_error(rig, qtbot):
    panel = rig.panel(default_factory=True)
    panel.port_combo.setCurrentText("/dev/no-such-port-impress")
    with qtbot.waitSignal(panel.error, timeout=3000) as blocker:
        panel.connect_button.click()
    assert blocker.args[0] == "E-MOTOR-PORT"
    qtbot.waitUntil(panel.connect_button.isEnabled)
    assert not panel.is_connected


def test_default_factory_simulated_motor(rig, qtbot):
    panel = rig.panel(default_factory=True, sim_time_scale=50.0, jog_step_mm=5.0)
    with qtbot.waitSignal(panel.connection_changed, timeout=5000):
        panel.connect_button.click()  # "Simulated motor" is the first entry
    panel.jog_plus_button.click()
    qtbot.waitUntil(lambda: not panel.is_busy and panel.position_label.text() == "5.00 mm")


@pytest.mark.skipif(os.name != "posix", reason="pseudo-terminals are POSIX only")
def test_typed_pseudo_terminal_path(rig, qtbot):
    motor = CM1Emulator(EmulatorConfig(time_scale=50.0, echo=False))
    with PtyServer(motor) as server:
        panel = rig.panel(default_factory=True, jog_step_mm=3.0)
        panel.port_combo.setCurrentText(server.path)
        with qtbot.waitSignal(panel.connection_changed, timeout=5000):
            panel.connect_button.click()
        panel.jog_plus_button.click()
        qtbot.waitUntil(lambda: not panel.is_busy and motor.position_pulses == -234)
        panel.shutdown()


def sent_stop_after_last_move(motor: CM1Emulator) -> bool:
    start = max(i for i, line in enumerate(motor.received) if line == "^.1")
    return "].1" in motor.received[start:]


def test_closing_the_panel_mid_scan_stops_the_motor(rig, qtbot):
    panel = rig.connected_panel(long_scan_mm=1700.0)
    motor = rig.motors[0]
    panel.long_button.click()
    panel.scan_button.click()
    qtbot.waitUntil(lambda: panel.is_busy and motor.moving)
    panel.close()  # as when the window closes: stops the carriage, joins the worker thread
    assert panel._thread.isFinished()
    assert not motor.moving and sent_stop_after_last_move(motor)


class Host:
    """The part of the main window a terminate signal uses: its motor panel and shutdown."""

    def __init__(self, panel: MotorPanel) -> None:
        self.motor_panel = panel
        self.closed = False

    def shutdown(self) -> None:
        self.motor_panel.shutdown()

    def close(self) -> None:
        self.closed = True


@pytest.mark.skipif(not hasattr(signal, "SIGHUP"), reason="no SIGHUP on this system")
@pytest.mark.parametrize("signame", ["SIGTERM", "SIGHUP"])
def test_a_terminate_signal_stops_the_motor_and_shuts_down(rig, qtbot, signame):
    from impress_gui.ui.app import on_process_signals, stop_motor_and_shut_down

    panel = rig.connected_panel(long_scan_mm=1700.0)
    motor = rig.motors[0]
    panel.long_button.click()
    panel.scan_button.click()
    qtbot.waitUntil(lambda: panel.is_busy and motor.moving)
    host, received = Host(panel), []
    number = getattr(signal, signame)
    # as from a terminal: a run under nohup (or a background shell) inherits SIGHUP ignored,
    # which on_process_signals deliberately leaves ignored
    inherited = signal.signal(number, signal.SIG_DFL) if (
        signal.getsignal(number) is signal.SIG_IGN) else None
    before = signal.getsignal(number)

    def ended(number: int) -> None:
        received.append(number)
        stop_motor_and_shut_down(host)

    restore = on_process_signals(ended)
    try:
        os.kill(os.getpid(), number)  # handled on the GUI thread, not fatal
        qtbot.waitUntil(lambda: host.closed, timeout=5000)
    finally:
        restore()
        after = signal.getsignal(number)
        if inherited is not None:
            signal.signal(number, inherited)
    assert received == [number]
    assert panel._thread.isFinished()
    assert not motor.moving and sent_stop_after_last_move(motor)
    assert after is before  # the previous handler is back


class BrokenDriver(CoolMuscle):
    """A driver whose move watch fails with a bug (not a motor error) on the third poll."""

    checks = 0

    def check(self, watch):
        BrokenDriver.checks += 1
        if BrokenDriver.checks == 3:
            raise RuntimeError("a bug while polling")
        return super().check(watch)


def test_an_unexpected_exception_mid_move_stops_the_motor(rig, qtbot, capsys):
    BrokenDriver.checks = 0

    def factory(port, config, on_traffic):
        motor = CM1Emulator(EmulatorConfig(time_scale=TIME_SCALE))
        rig.motors.append(motor)
        return BrokenDriver(emulated_port(motor), config, on_traffic=on_traffic)

    panel = MotorPanel(settings=MotorPanelSettings(motor=FAST, idle_poll_s=0.05),
                       driver_factory=factory, port_lister=lambda: [])
    qtbot.addWidget(panel)
    rig.panels.append(panel)
    with qtbot.waitSignal(panel.connection_changed, timeout=5000):
        panel.connect_button.click()
    motor = rig.motors[0]
    with qtbot.waitSignal(panel.error, timeout=5000) as blocker:
        panel.move_to(1000.0, 5.0)
    assert blocker.args[0] == "E-INTERNAL"
    assert "a bug while polling" in blocker.args[1] and "the motor was sent a stop" in blocker.args[1]
    qtbot.waitUntil(lambda: not panel.is_busy)
    assert not motor.moving and sent_stop_after_last_move(motor)
    assert panel.is_connected  # the link itself is fine: the user can go on
    assert "RuntimeError" in capsys.readouterr().err  # the details, for a bug report


def test_moves_past_a_smaller_travel_are_refused(rig, qtbot):
    limits = RailLimits(travel_mm=100.0)
    panel = rig.connected_panel(
        motor=replace(FAST, limits=limits), jog_step_mm=10.0, speed_mm_s=13.138, end_mm=100.0
    )
    motor = rig.motors[0]
    assert panel.settings.rail_travel_mm == 100.0
    assert panel.range_label.text().startswith("runs 100 mm")
    panel.move_to(95.0)
    qtbot.waitUntil(lambda: not panel.is_busy and motor.position_pulses == -95 * 78)
    moves = len(motor.received)
    with qtbot.waitSignal(panel.error, timeout=3000) as blocker:
        panel.jog_plus_button.click()
    assert blocker.args[0] == "E-MOTOR-LIMIT"
    assert "would end at 105.00 mm, outside the rail's travel (0 to 100 mm" in blocker.args[1]
    with qtbot.waitSignal(panel.error, timeout=3000) as blocker:
        panel.move_to(150.0)
    assert blocker.args[0] == "E-MOTOR-LIMIT"
    qtbot.waitUntil(lambda: not panel.is_busy)
    assert not [line for line in motor.received[moves:] if line.startswith(("P", "S", "A", "^"))]
    panel.end_spin.setValue(120.0)
    assert "outside the rail's travel (0 to 100 mm from home)" in panel.range_label.text()
    assert not panel.run_scan()
    assert motor.position_pulses == -95 * 78


def test_rail_limits_are_saved_and_loaded_with_the_settings(tmp_path):
    from impress_gui.ui.app import make_settings
    from impress_gui.ui.motor.choices import load_motor_choices, save_motor_choices

    path = tmp_path / "settings.ini"
    first = load_motor_choices(make_settings(path))
    assert first.motor.limits == RailLimits()  # nothing saved yet: the thesis' rail
    limits = RailLimits(travel_mm=1200.0, max_speed_mm_s=20.0)
    settings = make_settings(path)
    save_motor_choices(settings, replace(first, motor=replace(first.motor, limits=limits),
                                         end_mm=1100.0))
    settings.sync()
    again = load_motor_choices(make_settings(path))
    assert again.motor.limits == limits and again.rail_travel_mm == 1200.0
    assert again.end_mm == 1100.0
    text = path.read_text()
    assert "[rail]" in text and "travel_mm=1200" in text
    # a hand-edited file: a bad value is ignored whole, a good one is taken
    for travel, expected in [("-5", RailLimits()), ("long", RailLimits()),
                             ("800", RailLimits(travel_mm=800.0))]:
        settings = make_settings(path)
        settings.setValue("rail/travel_mm", travel)
        settings.setValue("rail/max_speed_mm_s", 100.0)
        settings.sync()
        assert load_motor_choices(make_settings(path)).motor.limits == expected
    settings.setValue("motor/end_mm", 1500.0)  # beyond an 800 mm rail: not taken
    settings.sync()
    assert load_motor_choices(make_settings(path)).end_mm == 500.0


# ----------------------------------------------------------------------------- scan settings


def choose(panel: MotorPanel, preset: str) -> None:
    """Pick a speed preset the way a user does: through the combo box."""
    panel.speed_preset_combo.setCurrentIndex(panel.speed_preset_combo.findData(preset))


def test_speed_presets_set_the_speed_and_custom_enables_the_box(rig):
    panel = rig.panel()  # defaults: medium, the rail's speed; no motor needed
    assert panel.speed_preset_combo.currentData() == "medium"
    assert panel.speed_spin.value() == pytest.approx(5.2552) and not panel.speed_spin.isEnabled()
    assert [panel.speed_preset_combo.itemText(i) for i in range(4)] == [
        "slow (1.3138 mm/s)", "medium (5.2552 mm/s)", "fast (13.138 mm/s)", "custom"]
    for name, speed in SPEED_PRESETS_MM_S.items():
        choose(panel, name)
        assert panel.speed_spin.value() == pytest.approx(speed)
        assert not panel.speed_spin.isEnabled()
    assert panel.speed_note.text() == "motor runs at 12.82 mm/s (S = 10)"  # fast, default units
    choose(panel, "custom")
    assert panel.speed_spin.isEnabled()
    panel.speed_spin.setValue(7.5)
    choose(panel, "slow")
    assert panel.speed_spin.value() == pytest.approx(1.3138)
    choose(panel, "custom")  # the custom speed comes back
    assert panel.speed_spin.value() == pytest.approx(7.5)
    assert rig.panel(speed_mm_s=13.138).speed_preset_combo.currentData() == "fast"
    assert rig.panel(speed_mm_s=10.0).speed_preset_combo.currentData() == "custom"


def test_choices_round_trip_through_the_settings(rig):
    panel = rig.panel()
    choose(panel, "custom")
    panel.speed_spin.setValue(3.25)
    choose(panel, "slow")
    panel.start_spin.setValue(40.0)
    panel.long_button.click()
    panel.jog_spin.setValue(2.5)
    saved = panel.current_settings()
    assert (saved.speed_preset, saved.speed_mm_s) == ("slow", pytest.approx(3.25))
    assert (saved.start_mm, saved.end_mm, saved.jog_step_mm) == (40.0, 1740.0, 2.5)
    again = rig.panel(**{k: getattr(saved, k) for k in
                         ("speed_preset", "speed_mm_s", "start_mm", "end_mm", "jog_step_mm")})
    assert again.current_settings() == saved
    assert again.speed_spin.value() == pytest.approx(1.3138)


def test_scan_runs_from_start_to_end_at_the_preset_speed(rig, qtbot):
    panel = rig.connected_panel(start_mm=20.0, end_mm=120.0)
    motor = rig.motors[0]
    choose(panel, "fast")
    assert panel.range_label.text() == "runs 100 mm in about 0 min 08 s"  # at 12.82 mm/s
    with qtbot.waitSignal(panel.position_changed, timeout=3000):
        assert panel.run_scan()
    qtbot.waitUntil(lambda: not panel.is_busy and motor.position_pulses == -120 * 78, timeout=5000)
    moves = [line for line in motor.received if line[0] in "PS" and "=" in line]
    # to the start at travel speed (20 mm/s -> S = 16), then to the end at the fast preset (S = 10)
    assert moves == ["S.1=16", "P.1=-1560", "S.1=10", "P.1=-9360"]
    qtbot.waitUntil(lambda: panel.position_label.text() == "120.00 mm")
    assert panel.error_label.text() == ""


@pytest.mark.parametrize(("start", "end", "speed", "code", "reason"), [
    (0.0, RAIL_TRAVEL_MM + 30.0, 5.0, "E-MOTOR-LIMIT",
     "the end position 1800.00 mm is outside the rail's travel"),
    (300.0, 300.0, 5.0, "E-MOTOR-RANGE", "the end position equals the start position (300.00 mm)"),
    (-10.0, 400.0, 5.0, "E-MOTOR-LIMIT",
     "the start position -10.00 mm is outside the rail's travel"),
    (0.0, 400.0, 0.3, "E-MOTOR-SPEED",
     "the speed 0.3 mm/s is slower than the motor can run: its slowest speed is one speed unit"),
])  # fmt: skip
def test_invalid_scan_is_refused_with_a_message_and_no_motion(
    rig, qtbot, start, end, speed, code, reason
):
    panel = rig.connected_panel(start_mm=start, end_mm=end, speed_mm_s=speed)
    motor = rig.motors[0]
    assert reason in panel.range_label.text() and panel.range_label.isVisibleTo(panel)  # before trying
    with qtbot.waitSignal(panel.error, timeout=10000) as blocker:
        panel.scan_button.click()
    assert blocker.args[0] == code
    assert reason in panel.error_label.text() and panel.error_label.isVisibleTo(panel)
    assert code in panel.error_label.text()
    with qtbot.waitSignal(panel.state_changed, timeout=10000):
        pass  # the worker has handled everything queued before its next poll
    assert not panel.is_busy and not motor.moving
    assert not [line for line in motor.received if line.startswith(("P", "S", "^"))]
    assert motor.position_pulses == 0


def test_long_preset_past_the_rail_end_is_flagged(rig, qtbot):
    panel = rig.connected_panel(start_mm=100.0)
    panel.long_button.click()
    assert panel.end_spin.value() == 1800.0  # filled as asked, not clamped
    assert panel.range_label.text().startswith("Cannot scan: the end position 1800.00 mm")
    assert not panel.run_scan()
    panel.start_spin.setValue(0.0)
    panel.long_button.click()
    assert panel.range_label.text().startswith("runs 1700 mm")


def test_the_simulator_the_calibration_tab_and_the_rail_share_the_speeds():
    from impress_gui.sim.rig import SPEED_PRESETS_MM_S as SIM_RIG
    from impress_gui.sim.simulate import SPEED_NAMES
    from impress_gui.ui.calibration.setup import SPEED_PRESETS

    assert SPEED_NAMES == SPEED_PRESETS_MM_S == SPEED_PRESETS
    assert sorted(SIM_RIG) == sorted(SPEED_PRESETS_MM_S.values())


def test_store_the_button_program_from_the_panel(rig, qtbot):
    """The four-button program is written from the panel (it was CLI only): the motor holds
    the thesis' four banks afterwards and saved them (issue 21, item 13)."""
    panel = rig.connected_panel()
    motor = rig.motors[-1]
    motor.banks.clear()
    assert panel.program_button.isEnabled()
    with qtbot.waitSignal(panel.program_stored, timeout=15000) as blocker:
        panel.program_button.click()
    assert blocker.args == [True]
    assert sorted(motor.banks) == [1, 2, 3, 4] and motor.saved == 1
    assert "button program stored and saved" in panel.log_view.toPlainText()
