"""Access to the compiled kernels (:mod:`impress_gui.core.reconstruction.kernels`) without stalling a window.

Importing the kernels compiles them for their signatures - several seconds the first time,
during which numba holds the GIL - or loads them from numba's on-disk cache (a fraction of a
second). A window therefore starts :func:`prepare_in_background` when it opens: a child
process compiles and fills the cache while the user works, and :func:`kernels` (called by the
core wherever it needs them, typically in a worker thread) waits for that child before
importing. Command-line runs simply compile on first use.
"""

from __future__ import annotations

import subprocess
import sys
import threading

_lock = threading.Lock()
_child: subprocess.Popen | None = None
_MODULE = "impress_gui.core.reconstruction.kernels"


def prepare_in_background() -> None:
    """Compile or check the kernels' cache in a child process (once per process; nothing to
    do when they are loaded already, or in a frozen bundle, which compiles in memory)."""
    global _child
    with _lock:
        if _child is not None or _MODULE in sys.modules or getattr(sys, "frozen", False):
            return
        _child = subprocess.Popen([sys.executable, "-c", f"import {_MODULE}"],
                                  stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)


def kernels():
    """The kernels module, after any background preparation has finished."""
    with _lock:
        child = _child
    if child is not None:
        child.wait()
    from impress_gui.core.reconstruction import kernels as module

    return module
