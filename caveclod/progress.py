"""A dependency-free progress bar on stderr.

On a terminal the bar redraws in place (at most ten times a second); in a
log (stderr not a terminal) it prints one plain line per tenth of the work,
so CI logs and pipes stay readable.
"""

from __future__ import annotations

import sys
import time


class Progress:
    """``Progress(label, total)``; ``update(done)``; ``close()``."""

    def __init__(self, label: str, total: int, enabled: bool = True, stream=None):
        self.label, self.total, self.enabled = label, max(int(total), 1), enabled
        self.stream = stream or sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.start = self.last = time.perf_counter()
        self.done = 0
        self.logged_tenths = -1

    def update(self, done: int) -> None:
        self.done = done
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.tty:
            if now - self.last >= 0.1:
                self.last = now
                self._draw(now)
        else:
            tenths = int(10 * min(done / self.total, 1.0))
            if tenths > self.logged_tenths:
                self.logged_tenths = tenths
                self.stream.write(f"{self.label}: {10 * tenths:3d}%  {now - self.start:6.1f}s\n")
                self.stream.flush()

    def _draw(self, now: float) -> None:
        frac = min(self.done / self.total, 1.0)
        bar = "#" * int(30 * frac)
        self.stream.write(f"\r{self.label:<12} [{bar:<30}] {100 * frac:5.1f}%  {now - self.start:6.1f}s")
        self.stream.flush()

    def close(self) -> None:
        if not self.enabled:
            return
        if self.tty:
            self.done = self.total
            self._draw(time.perf_counter())
            self.stream.write("\n")
            self.stream.flush()
        else:
            self.update(self.total)


def stage(message: str, enabled: bool = True) -> None:
    """One line naming a build stage, when progress is shown."""
    if enabled:
        sys.stderr.write(f"{message}\n")
        sys.stderr.flush()
