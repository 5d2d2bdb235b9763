"""How long the GUI thread was kept from running by *this process* (not by a busy machine).

A QTimer ticks every ``period_s`` on the GUI thread. Between two ticks the thread either ran,
waited in the scheduler's run queue (the machine was busy: other processes had the cores), or
slept. Sleeping beyond the timer's period means something in this process held it back: a
worker thread holding the interpreter (the GIL) or a lock the GUI thread needed. Linux keeps the
first two per thread in ``/proc/thread-self/schedstat`` (time on a core, time runnable but
waiting, in ns), so ``blocked = wall gap - on core - waiting - period`` is what the code did,
whatever the load. Without schedstat (another kernel) the plain wall-clock gap is used.
"""

from __future__ import annotations

import time
from pathlib import Path

from PySide6.QtCore import QTimer

SCHEDSTAT = Path("/proc/thread-self/schedstat")


def _sched() -> tuple[float, float] | None:
    try:
        on_core, waiting, _ = SCHEDSTAT.read_text().split()
    except (OSError, ValueError):
        return None
    return int(on_core) * 1e-9, int(waiting) * 1e-9


class EventLoopMonitor:
    def __init__(self, period_s: float = 0.010) -> None:
        self.period_s = period_s
        self.blocked: list[float] = []  # per interval, seconds held back by this process
        self.gaps: list[float] = []  # per interval, wall clock
        self.timer = QTimer()
        self.timer.timeout.connect(self._tick)
        self._last: tuple[float, tuple[float, float] | None] | None = None

    def start(self) -> None:
        self._last = (time.perf_counter(), _sched())
        self.timer.start(int(round(self.period_s * 1000)))

    def stop(self) -> None:
        self.timer.stop()

    def _tick(self) -> None:
        now, sched = time.perf_counter(), _sched()
        t0, s0 = self._last
        gap = now - t0
        self.gaps.append(gap)
        if sched is not None and s0 is not None:
            ran, waited = sched[0] - s0[0], sched[1] - s0[1]
            self.blocked.append(max(0.0, gap - ran - waited - self.period_s))
        else:
            self.blocked.append(gap)
        self._last = (now, sched)

    @property
    def worst_blocked_s(self) -> float:
        return max(self.blocked, default=0.0)
