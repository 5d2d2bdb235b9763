"""The motor panel's worker: owns the Cool Muscle driver on its own ``QThread``.

:class:`MotorWorker` runs plans of steps (moves, jogs, homing, banks) and polls them with a
timer on its thread (never a blocking wait), so its event loop stays free and a Stop request is
handled between two polls. It reports to :class:`~impress_gui.ui.motor.panel.MotorPanel` only
through signals. Re-exported by :mod:`impress_gui.ui.motor.panel`.

Whatever goes wrong while the carriage moves, the worker leaves it standing: the driver stops the
motor on its own errors, and any other exception in a step or a poll (a bug) sends a stop,
forgets the plan and is reported as ``E-INTERNAL``. Closing the port (the panel's shutdown, when
the window closes or the process is told to end) sends a stop too. Moves outside the rail's
limits are refused by the driver before anything is sent.
"""

from __future__ import annotations

import sys
import traceback
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QObject, QTimer, Signal, Slot

from impress_gui.core.base import codes
from impress_gui.core.base.errors import ImpressError
from impress_gui.hardware.cool_muscle import CoolMuscle
from impress_gui.hardware.motor_link import (
    EMULATOR_SCHEME,
    MotorConfig,
    TrafficCallback,
    emulator_url,
    resolve_port_url,
)
from impress_gui.hardware.motor_program import scanner_program
from impress_gui.hardware.motor_status import MotorDisconnected, MoveWatch

DriverFactory = Callable[[str, MotorConfig, TrafficCallback], CoolMuscle]
#: one step of a plan: ("move", position_mm, speed_mm_s), ("by", distance_mm, speed_mm_s),
#: ("home",) or ("bank", n)
Step = tuple[Any, ...]


def default_driver_factory(sim_time_scale: float = 1.0) -> DriverFactory:
    """Open a real port, a pyserial URL, or (for ``sim``) a fresh emulated motor."""

    def factory(port: str, config: MotorConfig, on_traffic: TrafficCallback) -> CoolMuscle:
        url = resolve_port_url(port)
        if url == EMULATOR_SCHEME:
            url = emulator_url(config, sim_time_scale)
        return CoolMuscle.open(url, config, on_traffic=on_traffic)

    return factory


def _coded(exc: Exception) -> ImpressError:
    """``exc`` itself when it is a coded error, else an ``E-INTERNAL`` one that says what it was."""
    if isinstance(exc, ImpressError):
        return exc
    traceback.print_exception(exc, file=sys.stderr)
    return ImpressError(f"internal error while opening the motor: {exc}", code=codes.E_INTERNAL)


class MotorWorker(QObject):
    """Owns the driver. Lives in the worker thread; every slot runs there."""

    connected = Signal(str)  # motor version
    disconnected = Signal(str)  # reason, empty when asked for
    snapshot = Signal(object)  # MotorSnapshot
    busy_changed = Signal(bool, str)  # busy, what
    failed = Signal(str, str)  # error code, message
    traffic = Signal(str, str)  # direction, line
    program_written = Signal(bool)  # saved to the motor's memory

    def __init__(self, factory: DriverFactory, config: MotorConfig, idle_poll_s: float) -> None:
        super().__init__()
        self._factory, self._config = factory, config
        self._busy_ms = max(1, int(config.poll_interval_s * 1000))
        self._idle_ms = max(1, int(idle_poll_s * 1000))
        self._driver: CoolMuscle | None = None
        self._plan: list[Step] = []
        self._watch: MoveWatch | None = None
        self._timer = QTimer(self)
        self._timer.timeout.connect(self._tick)

    def _on_traffic(self, direction: str, text: str) -> None:
        self.traffic.emit(direction, text)

    @Slot(str)
    def open_port(self, port: str) -> None:
        self.close_port()
        try:
            driver = self._factory(port, self._config, self._on_traffic)
        except Exception as exc:  # noqa: BLE001 - reported; see _coded
            self._refuse_connection(_coded(exc))
            return
        try:
            version = driver.connect()
        except Exception as exc:  # noqa: BLE001 - reported; see _coded
            driver.close()
            self._refuse_connection(_coded(exc))
            return
        self._driver = driver
        self.connected.emit(version)
        self._timer.start(self._idle_ms)
        self._tick()

    def _refuse_connection(self, exc: ImpressError) -> None:
        self.failed.emit(exc.code, str(exc))
        self.disconnected.emit(str(exc))

    @Slot()
    def close_port(self) -> None:
        self._timer.stop()
        self._set_idle()
        if self._driver is not None:
            driver, self._driver = self._driver, None
            driver.close()
            self.disconnected.emit("")

    @Slot()
    def stop(self) -> None:
        self._plan.clear()
        self._watch = None
        if self._driver is None:
            return
        try:
            self._driver.stop()
        except ImpressError as exc:
            self._fail(exc)
            return
        except Exception as exc:  # noqa: BLE001 - reported, never left to kill the thread
            self._fail_unexpected(exc)
            return
        self._set_idle()
        self._tick()

    @Slot(object)
    def run_plan(self, steps: list[Step]) -> None:
        if self._driver is None:
            self.failed.emit(codes.E_MOTOR_NOT_CONNECTED, "the motor is not connected: connect first")
            return
        self._plan = list(steps)
        self._watch = None
        self._next_step()

    @Slot(bool)
    def write_program(self, save: bool) -> None:
        """Store the scanner's four-button program (home, short scan, long scan, return) in the
        motor, checked against the rail's limits first; ``save``: into its memory."""
        if self._driver is None:
            self.failed.emit(codes.E_MOTOR_NOT_CONNECTED, "the motor is not connected: connect first")
            return
        try:
            self._driver.write_program(scanner_program(self._config.motor_id), save=save)
        except ImpressError as exc:
            self._fail(exc)
            return
        except Exception as exc:  # noqa: BLE001 - reported, never left to kill the thread
            self._fail_unexpected(exc)
            return
        self.program_written.emit(save)
        self._tick()

    @Slot()
    def reset_alarm(self) -> None:
        if self._driver is not None:
            try:
                self._driver.reset_alarm()
            except ImpressError as exc:
                self._fail(exc)
            except Exception as exc:  # noqa: BLE001 - reported, never left to kill the thread
                self._fail_unexpected(exc)
            self._tick()

    @Slot()
    def shutdown(self) -> None:
        """Stop the motor, close the port, and end the worker thread."""
        self.close_port()
        thread = self.thread()
        if thread is not None:
            thread.quit()

    def _set_idle(self) -> None:
        self._plan.clear()
        self._watch = None
        if self._timer.isActive():
            self._timer.setInterval(self._idle_ms)
        self.busy_changed.emit(False, "")

    def _next_step(self) -> None:
        assert self._driver is not None
        if not self._plan:
            self._set_idle()
            return
        step = self._plan.pop(0)
        try:
            kind = step[0]
            if kind == "move":
                self._watch = self._driver.start_move_mm(step[1], step[2])
            elif kind == "by":
                self._watch = self._driver.start_move_by_mm(step[1], step[2])
            elif kind == "home":
                self._watch = self._driver.start_home()
            elif kind == "bank":
                self._watch = self._driver.start_bank(int(step[1]))
            else:
                raise ValueError(f"unknown step {step!r}")
        except ImpressError as exc:
            self._fail(exc)
            return
        except Exception as exc:  # noqa: BLE001 - a bug must not leave the carriage moving
            self._fail_unexpected(exc)
            return
        self.busy_changed.emit(True, self._watch.description)
        self._timer.start(self._busy_ms)

    def _tick(self) -> None:
        if self._driver is None:
            return
        try:
            if self._watch is not None:
                done, snap = self._driver.check(self._watch)
                self.snapshot.emit(snap)
                if done:
                    self._watch = None
                    self._next_step()
            else:
                self.snapshot.emit(self._driver.poll())
        except ImpressError as exc:
            self._fail(exc)
        except Exception as exc:  # noqa: BLE001 - a bug must not leave the carriage moving
            self._fail_unexpected(exc)

    def _fail_unexpected(self, exc: Exception) -> None:
        """Any other exception: send a stop, forget the plan, report ``E-INTERNAL``."""
        traceback.print_exception(exc, file=sys.stderr)
        self._plan.clear()
        self._watch = None
        stopped = ""
        if self._driver is not None:
            try:
                self._driver.stop()
                stopped = "; the motor was sent a stop"
            except Exception:  # noqa: BLE001 - the report below matters more
                stopped = "; sending a stop failed too: use the hardware stop button"
        self._fail(
            ImpressError(f"internal error while driving the motor: {exc}{stopped}", code=codes.E_INTERNAL)
        )

    def _fail(self, exc: ImpressError) -> None:
        """The driver already stopped the motor; forget the plan and tell the panel."""
        self._set_idle()
        self.failed.emit(exc.code, str(exc))
        if isinstance(exc, MotorDisconnected) or (
            self._driver is not None and not self._driver.connected
        ):
            self._timer.stop()
            if self._driver is not None:
                self._driver.close(stop=False)
            self._driver = None
            self.disconnected.emit(str(exc))
        elif self._driver is not None:
            try:
                self.snapshot.emit(self._driver.poll())
            except Exception:  # noqa: BLE001 - the error is already reported
                pass
