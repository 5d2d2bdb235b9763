"""The half-written files and folders this process has open: the hidden work folder of an
output being made, the temporary file beside an output file. Each is noted while it exists so
that a forced exit (a terminate signal the command could not finish cleaning up after, see
:func:`impress_gui.cli._on_terminate`) can remove them: nothing half-written is ever left
where the user looks, even when the normal clean-up is stuck."""

from __future__ import annotations

import os
import shutil
import threading
from pathlib import Path

_lock = threading.Lock()
_open: set[Path] = set()


def note(path: str | os.PathLike) -> None:
    """``path`` (a work folder or a temporary file) exists until :func:`done` is called."""
    with _lock:
        _open.add(Path(path))


def done(path: str | os.PathLike) -> None:
    """``path`` was renamed into place or removed: no longer this process's to remove."""
    with _lock:
        _open.discard(Path(path))


def open_paths() -> list[Path]:
    with _lock:
        return sorted(_open)


def remove_all() -> None:
    """Remove every noted path (the last resort before a forced exit). Takes no lock: it may
    run while the thread that holds it is stuck; a path noted or dropped meanwhile is only
    missed or removed twice (both harmless: removal ignores what is gone)."""
    for path in _open.copy():  # set.copy is one step under the GIL
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            try:
                path.unlink()
            except OSError:
                pass
        _open.discard(path)
