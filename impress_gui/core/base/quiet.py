"""No library's own warning lines on a user's console.

The console command turns them off for its process (:func:`quiet_libraries`); a process it
starts (a batch scan's worker, the digital cast's triangulation, the simulator's renderers) is
a fresh interpreter that does not inherit the filter, so it is given
:func:`quiet_libraries` to run first (:func:`child_initializer`). What a user needs to know
comes as the command's coded errors and warnings. ``IMPRESS_DEBUG=1`` keeps the libraries'
lines, in every process."""

from __future__ import annotations

import logging
import os
import warnings
from collections.abc import Callable

_active = False


def quiet_libraries() -> None:
    """Hide warnings (numpy's RuntimeWarnings with source lines) and log records nobody
    handles (Python's last-resort handler would print tifffile's WARNING lines to stderr)
    in this process, unless ``IMPRESS_DEBUG`` is set."""
    global _active
    if os.environ.get("IMPRESS_DEBUG"):
        return
    _active = True
    warnings.simplefilter("ignore")
    root = logging.getLogger()
    if not root.handlers:
        root.addHandler(logging.NullHandler())


def child_initializer() -> Callable[[], None] | None:
    """What a child process should run first: :func:`quiet_libraries` where this process is
    quiet (the console command), else nothing (the window, the tests, the API: a caller who
    has not asked for quiet keeps the libraries' lines)."""
    return quiet_libraries if _active else None


def run_quietly(quiet: bool, target: Callable, *args):
    """``target(*args)`` in a child process, quiet first if ``quiet`` (a picklable entry point
    for ``multiprocessing.Process``)."""
    if quiet:
        quiet_libraries()
    return target(*args)
