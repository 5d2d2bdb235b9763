"""The commands' progress lines on stderr: ``  42.0 %  what is being done``."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable


def progress_printer(every_s: float = 2.0, quiet: bool = False) -> Callable[[float, str], None]:
    """A progress callback printing one line at most every ``every_s`` seconds (0: every
    call), and always the last (fraction 1); nothing when ``quiet``."""
    last = 0.0

    def progress(frac: float, msg: str) -> None:
        nonlocal last
        now = time.monotonic()
        if not quiet and (every_s <= 0 or now - last > every_s or frac >= 1.0):
            last = now
            print(f"  {100 * frac:5.1f} %  {msg}", file=sys.stderr, flush=True)

    return progress
