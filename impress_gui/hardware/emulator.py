"""A software Cool Muscle CM1 for training, tests and the "Simulated motor" port: its ports.

The motor itself, :class:`CM1Emulator` (command parser, timed moves, banks, injected faults), is
in :mod:`impress_gui.hardware.emulator_model` and re-exported here with its
:class:`EmulatorConfig`. Two ways to reach it:

* a pyserial URL, ``cm1emu://?echo=1&id=1&time_scale=1&events=0`` (after
  :func:`register_url_handler`; :func:`impress_gui.hardware.cool_muscle.open_port` does that),
  or an :class:`EmulatedSerial` wrapping a motor you hold, to inject faults;
* :class:`PtyServer`, which puts the motor behind a pseudo-terminal so anything that opens a
  device path (the GUI, a terminal program) talks to it like a real port. POSIX only.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import types
from typing import Any

import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from impress_gui.hardware.emulator_model import GARBAGE_BYTES, CM1Emulator, EmulatorConfig

__all__ = [
    "GARBAGE_BYTES",
    "CM1Emulator",
    "EmulatedSerial",
    "EmulatorConfig",
    "PtyServer",
    "emulated_port",
    "register_url_handler",
]


class EmulatedSerial(SerialBase):
    """A pyserial port whose other end is a :class:`CM1Emulator` (``cm1emu://`` URLs)."""

    is_open: bool  # set by SerialBase

    def __init__(self, *args: Any, motor: CM1Emulator | None = None, **kwargs: Any) -> None:
        self.motor = motor
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        if self.is_open:
            raise SerialException("Port is already open.")
        if self.motor is None:
            try:
                self.motor = CM1Emulator(EmulatorConfig.from_url(self._port))
            except ValueError as exc:
                raise SerialException(f"bad emulator URL {self._port!r}: {exc}") from exc
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def _reconfigure_port(self, *args: object) -> None:
        pass

    def _motor(self) -> CM1Emulator:
        if not self.is_open or self.motor is None:
            raise PortNotOpenError()
        if not self.motor.link_up:
            raise SerialException("device reports readiness to read but returned no data")
        return self.motor

    @property
    def in_waiting(self) -> int:
        return self._motor().pending_output()

    def read(self, size: int = 1) -> bytes:
        motor = self._motor()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        data = bytearray()
        while len(data) < size:
            data += motor.take_output(size - len(data))
            if len(data) >= size:
                break
            remaining = 1.0 if deadline is None else deadline - time.monotonic()
            if remaining <= 0:
                break
            motor.wait_output(min(remaining, 0.05))
            motor = self._motor()
        return bytes(data)

    def write(self, data: bytes) -> int:
        self._motor().feed(bytes(data))
        return len(data)

    def reset_input_buffer(self) -> None:
        self._motor().clear_output()

    def reset_output_buffer(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    def _update_break_state(self) -> None:
        pass


def emulated_port(motor: CM1Emulator, *, timeout_s: float = 0.02) -> EmulatedSerial:
    """An open port wired to ``motor`` (keep the motor to inject faults)."""
    port = EmulatedSerial(motor=motor, timeout=timeout_s)
    port.port = "cm1emu://"
    port.open()
    return port


_HANDLER_PACKAGE = "impress_gui.hardware._cm1emu_urls"


def register_url_handler() -> None:
    """Teach ``serial.serial_for_url`` the ``cm1emu://`` scheme. Idempotent."""
    module_name = f"{_HANDLER_PACKAGE}.protocol_cm1emu"
    if module_name not in sys.modules:
        package = types.ModuleType(_HANDLER_PACKAGE)
        package.__path__ = []  # a namespace holding only the in-memory handler below
        handler = types.ModuleType(module_name)
        handler.Serial = EmulatedSerial  # type: ignore[attr-defined]
        sys.modules[_HANDLER_PACKAGE] = package
        sys.modules[module_name] = handler
    if _HANDLER_PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(_HANDLER_PACKAGE)


class PtyServer:
    """Serve a :class:`CM1Emulator` behind a pseudo-terminal; :attr:`path` is the device path.

    One background thread shuttles bytes; :meth:`close` (or leaving the ``with`` block) stops
    and joins it. When the motor's link is cut (:meth:`CM1Emulator.disconnect`) the server hangs
    up the terminal, as an unplugged adapter would.
    """

    def __init__(self, motor: CM1Emulator) -> None:
        self.motor = motor
        self.path = ""
        self._master = self._slave = -1
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> str:
        import pty
        import tty

        self._master, self._slave = pty.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self._thread = threading.Thread(target=self._run, name="cm1-emulator-pty", daemon=True)
        self._thread.start()
        return self.path

    def _run(self) -> None:
        import select

        while not self._stop.is_set():
            if not self.motor.link_up:
                self._close_master()
                return
            try:
                ready, _, _ = select.select([self._master], [], [], 0.005)
                if ready:
                    self.motor.feed(os.read(self._master, 4096))
                out = self.motor.take_output()
                if out:
                    os.write(self._master, out)
            except OSError:
                return

    def _close_master(self) -> None:
        if self._master >= 0:
            os.close(self._master)
            self._master = -1

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self._close_master()
        if self._slave >= 0:
            os.close(self._slave)
            self._slave = -1

    def __enter__(self) -> PtyServer:
        if not self.path:
            self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
