"""The motor panel: port, connection, live position and state, Home / scans / jog, a big Stop.

The Cool Muscle driver lives in a :class:`MotorWorker` (:mod:`impress_gui.ui.motor.worker`) on
its own ``QThread``; the panel talks to it only through queued signals, so no serial I/O ever
runs on the GUI thread. Moves are polled by a timer on the worker thread (never a blocking wait),
which keeps the worker's event loop free: a Stop request is handled between two polls, i.e.
within one query round trip.

The window that hosts the panel must call :meth:`MotorPanel.shutdown` before it goes away
(closing the panel itself does it too); it stops the motor and joins the worker thread.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

from PySide6.QtCore import QCoreApplication, QThread, Signal
from PySide6.QtGui import QCloseEvent, QFont, QFontDatabase
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QFormLayout,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPlainTextEdit,
    QPushButton,
    QScrollArea,
    QSizePolicy,
    QVBoxLayout,
    QWidget,
)

from impress_gui.hardware.motor_limits import check_speed_mm_s
from impress_gui.hardware.motor_link import MotorConfig, list_serial_ports
from impress_gui.hardware.motor_status import MotorRangeError, MotorSnapshot
from impress_gui.hardware.rail import SCAN_LENGTHS_MM
from impress_gui.ui.common_widgets import SidePanelScroll
from impress_gui.ui.motor.scan_box import ScanSettingsBox
from impress_gui.ui.motor.worker import DriverFactory, MotorWorker, Step, default_driver_factory

__all__ = [
    "SIMULATED_LABEL",
    "DriverFactory",
    "MotorPanel",
    "MotorPanelSettings",
    "MotorWorker",
    "PortLister",
    "ScanSettingsBox",
    "Step",
    "default_driver_factory",
]

SIMULATED_LABEL = "Simulated motor"
PortLister = Callable[[], list[tuple[str, str]]]


@dataclass(frozen=True)
class MotorPanelSettings:
    """What the panel starts with. Distances in mm (from home), speeds in mm/s, times in s.

    ``speed_preset``: ``slow``, ``medium``, ``fast`` (the rail's speeds,
    :data:`~impress_gui.hardware.rail.SPEED_PRESETS_MM_S`) or ``custom`` (then ``speed_mm_s``);
    ``None`` picks the preset whose speed is ``speed_mm_s``, else custom.
    :meth:`MotorPanel.current_settings` gives the user's current choices, to save and restore.
    The rail's travel and maximum speed are ``motor.limits``
    (:class:`~impress_gui.hardware.rail.RailLimits`), enforced by the driver on every move;
    moves to a scan's start run at ``travel_speed_mm_s`` or the rail's maximum if lower.
    """

    motor: MotorConfig = field(default_factory=MotorConfig)
    speed_preset: str | None = None
    speed_mm_s: float = 5.2552  # the custom speed (the medium preset's speed by default)
    travel_speed_mm_s: float = 20.0
    start_mm: float = 0.0
    end_mm: float = 500.0
    short_scan_mm: float = SCAN_LENGTHS_MM["short"]
    long_scan_mm: float = SCAN_LENGTHS_MM["long"]
    jog_step_mm: float = 10.0
    idle_poll_s: float = 0.5
    sim_time_scale: float = 1.0
    log_lines: int = 500

    @property
    def rail_travel_mm(self) -> float:
        """The rail's usable travel, mm from home (``motor.limits.travel_mm``)."""
        return self.motor.limits.travel_mm


class MotorPanel(QWidget):
    """Self-contained motor control widget; see the module docstring."""

    position_changed = Signal(float)  # mm
    state_changed = Signal(str)
    connection_changed = Signal(bool)
    error = Signal(str, str)  # code, message
    program_stored = Signal(bool)  # the button program is in the motor (saved)

    _open_requested = Signal(str)
    _close_requested = Signal()
    _stop_requested = Signal()
    _plan_requested = Signal(object)
    _reset_requested = Signal()
    _program_requested = Signal(bool)
    _shutdown_requested = Signal()

    def __init__(
        self,
        parent: QWidget | None = None,
        *,
        settings: MotorPanelSettings | None = None,
        driver_factory: DriverFactory | None = None,
        port_lister: PortLister | None = None,
    ) -> None:
        super().__init__(parent)
        self.settings = s = settings or MotorPanelSettings()
        self._units = s.motor.units
        self._port_lister = port_lister or list_serial_ports
        self.is_connected = False
        self.is_busy = False
        self.last_snapshot: MotorSnapshot | None = None
        self._build_ui()
        self.refresh_ports()

        self._thread = QThread(self)
        self._thread.setObjectName("motor-worker")
        factory = driver_factory or default_driver_factory(s.sim_time_scale)
        self._worker = MotorWorker(factory, s.motor, s.idle_poll_s)
        self._worker.moveToThread(self._thread)
        self._thread.finished.connect(self._worker.deleteLater)
        self._open_requested.connect(self._worker.open_port)
        self._close_requested.connect(self._worker.close_port)
        self._stop_requested.connect(self._worker.stop)
        self._plan_requested.connect(self._worker.run_plan)
        self._reset_requested.connect(self._worker.reset_alarm)
        self._program_requested.connect(self._worker.write_program)
        self._worker.program_written.connect(self._on_program_written)
        self._shutdown_requested.connect(self._worker.shutdown)
        self._worker.connected.connect(self._on_connected)
        self._worker.disconnected.connect(self._on_disconnected)
        self._worker.snapshot.connect(self._on_snapshot)
        self._worker.busy_changed.connect(self._on_busy)
        self._worker.failed.connect(self._on_failed)
        self._worker.traffic.connect(self._on_traffic)
        self._thread.start()
        app = QCoreApplication.instance()
        if app is not None:
            app.aboutToQuit.connect(self.shutdown)
        self._update_enabled()

    # ----------------------------------------------------------------- layout

    def _build_ui(self) -> None:
        s = self.settings
        root = QVBoxLayout(self)

        link = QHBoxLayout()
        self.port_combo = QComboBox(editable=True)
        self.port_combo.setToolTip("A listed port, a typed device path or pyserial URL")
        self.port_combo.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Fixed)
        self.refresh_button = QPushButton("Refresh")
        self.connect_button = QPushButton("Connect")
        for w in (self.port_combo, self.refresh_button, self.connect_button):
            link.addWidget(w)
        root.addLayout(link)

        self.stop_button = QPushButton("STOP")
        font = QFont(self.stop_button.font())
        font.setPointSize(max(font.pointSize(), 9) * 2)
        font.setBold(True)
        self.stop_button.setFont(font)
        self.stop_button.setMinimumHeight(64)
        self.stop_button.setStyleSheet("QPushButton { background: #c62828; color: white; }")
        self.stop_button.setToolTip("Stop the carriage now (always available)")
        root.addWidget(self.stop_button)
        # the rest scrolls where the window is short (a laptop's 768 rows): the connection
        # and STOP stay in view whatever the window's height
        rest = QWidget()
        body = QVBoxLayout(rest)
        body.setContentsMargins(0, 0, 0, 0)
        self.scroll_area = SidePanelScroll(rest, min_width=0)
        self.scroll_area.setFrameShape(QScrollArea.Shape.NoFrame)
        root.addWidget(self.scroll_area, 1)

        status = QGroupBox("Motor")
        form = QFormLayout(status)
        self.position_label = QLabel("-")
        big = QFont(self.position_label.font())
        big.setPointSize(max(big.pointSize(), 9) + 6)
        self.position_label.setFont(big)
        self.state_label = QLabel("not connected")
        self.alarm_label = QLabel("")
        self.alarm_label.setStyleSheet("QLabel { color: #c62828; font-weight: bold; }")
        self.alarm_label.setWordWrap(True)
        self.error_label = QLabel("")
        self.error_label.setStyleSheet("QLabel { color: #c62828; }")
        self.error_label.setWordWrap(True)
        self.version_label = QLabel("")
        form.addRow("Position", self.position_label)
        form.addRow("State", self.state_label)
        form.addRow("Alarm", self.alarm_label)
        form.addRow("Last error", self.error_label)
        form.addRow("Motor", self.version_label)
        body.addWidget(status)

        self.scan_box = box = ScanSettingsBox(
            self._units,
            speed_preset=s.speed_preset,
            speed_mm_s=s.speed_mm_s,
            start_mm=s.start_mm,
            end_mm=s.end_mm,
            jog_step_mm=s.jog_step_mm,
            short_scan_mm=s.short_scan_mm,
            long_scan_mm=s.long_scan_mm,
            limits=s.motor.limits,
        )
        self.speed_preset_combo, self.speed_spin = box.speed_preset_combo, box.speed_spin
        self.speed_note, self.range_label = box.speed_note, box.range_label
        self.start_spin, self.end_spin, self.jog_spin = box.start_spin, box.end_spin, box.jog_spin
        self.short_button, self.long_button = box.short_button, box.long_button
        body.addWidget(box)

        grid = QGridLayout()
        self.home_button = QPushButton("Home")
        self.reset_button = QPushButton("Reset alarm")
        self.scan_button = QPushButton("Run scan")
        self.scan_button.setToolTip(
            "Go to the start position at travel speed, then run to the end position at the scan speed"
        )
        self.jog_minus_button = QPushButton("\u25c0 Jog \u2212")
        self.jog_plus_button = QPushButton("Jog + \u25b6")
        self.program_button = QPushButton("Store the button program")
        self.program_button.setToolTip(
            "Write the scanner's four-button program into the motor (banks 1-4: home, short "
            "scan, long scan, return), checked against the rail's limits, and save it"
        )
        grid.addWidget(self.home_button, 0, 0)
        grid.addWidget(self.reset_button, 0, 1)
        grid.addWidget(self.scan_button, 1, 0, 1, 2)
        grid.addWidget(self.jog_minus_button, 2, 0)
        grid.addWidget(self.jog_plus_button, 2, 1)
        grid.addWidget(self.program_button, 3, 0, 1, 2)
        body.addLayout(grid)

        self.log_polls_check = QCheckBox("Log status polls")
        self.log_view = QPlainTextEdit(readOnly=True)
        self.log_view.setMaximumBlockCount(s.log_lines)
        self.log_view.setFont(QFontDatabase.systemFont(QFontDatabase.SystemFont.FixedFont))
        self.log_view.setMinimumHeight(90)
        body.addWidget(self.log_polls_check)
        body.addWidget(self.log_view, 1)

        self.refresh_button.clicked.connect(self.refresh_ports)
        self.connect_button.clicked.connect(self._toggle_connection)
        self.stop_button.clicked.connect(self.stop)
        self.home_button.clicked.connect(self.home)
        self.scan_button.clicked.connect(self.run_scan)
        self.jog_minus_button.clicked.connect(lambda: self.jog(-self.jog_spin.value()))
        self.jog_plus_button.clicked.connect(lambda: self.jog(self.jog_spin.value()))
        self.reset_button.clicked.connect(lambda: self._reset_requested.emit())
        self.program_button.clicked.connect(lambda: self.write_program())

    # ----------------------------------------------------------------- actions

    def refresh_ports(self) -> None:
        typed = self.port_combo.currentText()
        self.port_combo.clear()
        self.port_combo.addItem(SIMULATED_LABEL, "sim")
        try:
            ports = self._port_lister()
        except Exception as exc:  # noqa: BLE001 - a broken enumeration must not break the panel
            ports = []
            self._log(f"! cannot list ports: {exc}")
        for device, description in ports:
            label = device if description in ("", "n/a", device) else f"{device} ({description})"
            self.port_combo.addItem(label, device)
        if typed:
            self.port_combo.setCurrentText(typed)

    def selected_port(self) -> str:
        """The chosen port: a listed entry's device, or the typed path / URL."""
        text = self.port_combo.currentText().strip()
        index = self.port_combo.findText(text)
        return str(self.port_combo.itemData(index)) if index >= 0 else text

    def connect_motor(self, port: str | None = None) -> None:
        if port is not None:
            self.port_combo.setCurrentText(port)
        self._log(f"# connecting to {self.selected_port()}")
        self.error_label.setText("")
        self.connect_button.setEnabled(False)
        self._open_requested.emit(self.selected_port())

    def disconnect_motor(self) -> None:
        self._close_requested.emit()

    def stop(self) -> None:
        self._log("# STOP")
        self._stop_requested.emit()

    def run_plan(self, steps: list[Step]) -> None:
        """Hand a list of steps (see :data:`Step`) to the worker; clears the last error."""
        self.error_label.setText("")
        self._plan_requested.emit(steps)

    def home(self) -> None:
        self.run_plan([("home",)])

    def run_scan(self) -> bool:
        """Go to the start position at travel speed, then to the end position at the scan speed.

        A start or end outside the rail's travel (``E-MOTOR-LIMIT``), an end equal to the start
        (``E-MOTOR-RANGE``) or a speed outside the rail's range (``E-MOTOR-SPEED``) is refused:
        the reason is shown, nothing is sent to the motor, and ``False`` is returned.
        """
        start, end = self.start_spin.value(), self.end_spin.value()
        travel_speed = self.travel_speed_mm_s()
        try:
            self.scan_box.check()
            check_speed_mm_s(travel_speed, self._units, self.settings.motor.limits)
        except MotorRangeError as exc:
            self._on_failed(exc.code, f"scan refused: {exc}")
            return False
        self.run_plan([("move", start, travel_speed), ("move", end, self.scan_box.speed_mm_s())])
        return True

    def travel_speed_mm_s(self) -> float:
        """The speed of moves to a scan's start: the setting, or the rail's maximum if lower."""
        return min(self.settings.travel_speed_mm_s, self.settings.motor.limits.max_speed_mm_s)

    def scan(self, length_mm: float) -> bool:
        """Set the end position to start + ``length_mm`` (the short / long presets) and scan."""
        self.scan_box.fill_length(length_mm)
        return self.run_scan()

    def current_settings(self) -> MotorPanelSettings:
        """The panel's settings with the user's current choices (speed, positions, jog step)."""
        box = self.scan_box
        return replace(
            self.settings,
            speed_preset=box.speed_preset(),
            speed_mm_s=box.custom_speed_mm_s,
            start_mm=self.start_spin.value(),
            end_mm=self.end_spin.value(),
            jog_step_mm=self.jog_spin.value(),
        )

    def jog(self, distance_mm: float) -> None:
        self.run_plan([("by", distance_mm, self.speed_spin.value())])

    def move_to(self, position_mm: float, speed_mm_s: float | None = None) -> None:
        speed = self.speed_spin.value() if speed_mm_s is None else speed_mm_s
        self.run_plan([("move", position_mm, speed)])

    def write_program(self, save: bool = True) -> None:
        """Store the four-button program in the motor (in the worker thread)."""
        self._log("# storing the button program" + (" (saved)" if save else ""))
        self._program_requested.emit(save)

    def _on_program_written(self, saved: bool) -> None:
        self._log("# button program stored" + (" and saved in the motor" if saved else ""))
        self.error_label.setText("")
        self.program_stored.emit(saved)

    def run_bank(self, bank: int) -> None:
        self.run_plan([("bank", bank)])

    def shutdown(self) -> None:
        """Stop the motor, close the port and join the worker thread. Safe to call twice."""
        if self._thread.isRunning():
            self._shutdown_requested.emit()
            if not self._thread.wait(10_000):
                self._thread.quit()
                self._thread.wait()

    def closeEvent(self, event: QCloseEvent) -> None:  # noqa: N802 - Qt override
        self.shutdown()
        super().closeEvent(event)

    # ----------------------------------------------------------------- worker -> panel

    def _toggle_connection(self) -> None:
        if self.is_connected:
            self.disconnect_motor()
        else:
            self.connect_motor()

    def _on_connected(self, version: str) -> None:
        self.is_connected = True
        self.version_label.setText(version)
        self.alarm_label.setText("")
        self._log(f"# connected: {version}")
        self.connection_changed.emit(True)
        self._update_enabled()

    def _on_disconnected(self, reason: str) -> None:
        self.is_connected = False
        self.is_busy = False
        self.state_label.setText("not connected")
        self._log("# disconnected" + (f": {reason}" if reason else ""))
        self.connection_changed.emit(False)
        self._update_enabled()

    def _on_snapshot(self, snap: MotorSnapshot) -> None:
        self.last_snapshot = snap
        self.position_label.setText(f"{snap.position_mm:.2f} mm")
        self.state_label.setText(snap.status.state)
        self.alarm_label.setText(", ".join(snap.status.alarms))
        self.position_changed.emit(snap.position_mm)
        self.state_changed.emit(snap.status.state)

    def _on_busy(self, busy: bool, what: str) -> None:
        self.is_busy = busy
        if busy:
            self._log(f"# {what}")
        self._update_enabled()

    def _on_failed(self, code: str, message: str) -> None:
        self.error_label.setText(f"[{code}] {message}")
        self._log(f"! [{code}] {message}")
        self.error.emit(code, message)
        self._update_enabled()

    def _on_traffic(self, direction: str, text: str) -> None:
        if not self.log_polls_check.isChecked() and text.startswith(("?96", "?99", "Px.", "Ux.")):
            return
        self._log(f"{direction} {text}")

    def _log(self, line: str) -> None:
        self.log_view.appendPlainText(line)

    def _update_enabled(self) -> None:
        self.connect_button.setEnabled(True)
        self.connect_button.setText("Disconnect" if self.is_connected else "Connect")
        self.port_combo.setEnabled(not self.is_connected)
        self.refresh_button.setEnabled(not self.is_connected)
        can_move = self.is_connected and not self.is_busy
        for b in (
            self.home_button,
            self.scan_button,
            self.jog_minus_button,
            self.jog_plus_button,
            self.program_button,
        ):
            b.setEnabled(can_move)
        self.reset_button.setEnabled(self.is_connected)
        self.stop_button.setEnabled(True)  # always
