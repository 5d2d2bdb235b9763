"""Work around a reference-count bug of PySide6 6.12.0 that aborts the interpreter.

``SignalInstance.emit`` returns ``True`` without a new reference, so every ``emit`` made from
Python takes one reference away from ``True``. On CPython < 3.12 (where ``True`` is not yet
immortal) the count reaches zero after a few thousand emits and the process aborts with
"Fatal Python error: bool_dealloc" - in a long session, or at exit. :func:`guard` detects the
bug with a private signal and, only when it is present, gives ``True`` a reference count so
large that no session can use it up. Call it once before the GUI starts (``create_app`` does;
test suites that emit signals without it should call it in their conftest).
"""

from __future__ import annotations

import ctypes
import sys

_RESERVE = 1 << 40
_state = {"checked": False, "applied": False}


def emit_loses_references() -> bool:
    """True when a Python-side ``emit`` takes a reference away from ``True``."""
    from PySide6.QtCore import QObject, Signal

    class _Probe(QObject):
        ping = Signal()

    probe = _Probe()
    before = sys.getrefcount(True)
    for _ in range(8):
        probe.ping.emit()
    lost = before - sys.getrefcount(True)
    probe.deleteLater()
    return lost >= 8


def guard() -> bool:
    """Apply the workaround if needed (idempotent); return whether it is in effect."""
    if _state["checked"]:
        return _state["applied"]
    _state["checked"] = True
    if sys.version_info >= (3, 12) or sys.implementation.name != "cpython":
        return False
    if emit_loses_references():
        ctypes.c_ssize_t.from_address(id(True)).value += _RESERVE
        _state["applied"] = True
    return _state["applied"]
