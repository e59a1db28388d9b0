"""A minimal progress bar on standard error (no dependency), for runs longer than a second."""

from __future__ import annotations

import sys
import time


class ProgressBar:
    """Callable as ``bar(done, total)``; draws on a terminal, stays quiet otherwise (logs, CI)."""

    def __init__(self, label: str, stream=None, min_interval: float = 0.1):
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.min_interval = min_interval
        self._last = 0.0
        self._start = time.perf_counter()

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        if done < total and now - self._last < self.min_interval:
            return
        self._last = now
        frac = done / max(total, 1)
        bar = "#" * int(30 * frac)
        self.stream.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}% {now - self._start:6.1f}s")
        if done >= total:
            self.stream.write("\n")
        self.stream.flush()
