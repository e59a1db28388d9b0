"""Progress of long commands on standard error: a tqdm bar on a terminal, a line every few seconds elsewhere.

The library reports progress through a callable ``progress(done, total, stage=None)``: the tracker
calls it after each step (without a stage), the planners name their stages (``roadmap``, ``tracking``,
``clearance``, ...). :class:`Progress` is that callable for the command line: on a terminal one tqdm
bar whose description follows the stage (it restarts when the stage changes, so the whole run shows,
not only the tracking); off a terminal (a log, CI, a pipe) a plain line at the first call, at each new
stage and then every ``interval`` seconds; with ``quiet`` nothing.
"""

from __future__ import annotations

import shutil
import sys
import time

#: Seconds between two lines off a terminal.
LOG_INTERVAL = 5.0


class Progress:
    """Callable as ``progress(done, total, stage=None)``; ``close()`` ends the bar.

    Args:
        label: what runs (``plan 6.3``), first on every line.
        quiet: print nothing.
        stream: where to write; default standard error.
        interval: seconds between lines off a terminal [s].
    """

    def __init__(self, label: str, *, quiet: bool = False, stream=None, interval: float = LOG_INTERVAL):
        self.label = label
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.interval = interval
        self.terminal = bool(getattr(self.stream, "isatty", lambda: False)())
        self.stage: str | None = None
        self._bar = None
        self._last_line = -float("inf")
        self._start = time.perf_counter()

    def __call__(self, done: int, total: int, stage: str | None = None) -> None:
        if self.quiet:
            return
        stage = stage if stage is not None else (self.stage or "working")
        new_stage = stage != self.stage
        self.stage = stage
        total = max(int(total), 1)
        done = min(max(int(done), 0), total)
        if self.terminal:
            self._draw(done, total, new_stage)
            return
        now = time.perf_counter()
        if new_stage or now - self._last_line >= self.interval or (done == total and stage == "done"):
            self._last_line = now
            print(f"{self.label}: {stage} {done}/{total} ({100.0 * done / total:.0f}%), "
                  f"{now - self._start:.1f} s", file=self.stream, flush=True)

    def _draw(self, done: int, total: int, new_stage: bool) -> None:
        from tqdm import tqdm

        if self._bar is None:
            # a terminal that reports no width (a bare pty) gets 80 columns
            wide = shutil.get_terminal_size((0, 0)).columns > 0
            self._bar = tqdm(total=total, file=self.stream, leave=False, dynamic_ncols=wide, ncols=None if wide else 80,
                             mininterval=0.1, desc=f"{self.label}: {self.stage}",
                             bar_format="{desc} {bar} {n_fmt}/{total_fmt} [{elapsed}]")
        if new_stage or self._bar.total != total:
            self._bar.reset(total=total)
        self._bar.set_description_str(f"{self.label}: {self.stage}", refresh=False)
        self._bar.n = done
        if new_stage:
            self._bar.refresh()
        else:
            self._bar.update(0)  # redraws at most every mininterval

    def prefixed(self, prefix: str):
        """A callable ``(done, total, stage=None)`` whose stages read ``prefix: stage`` (one part of a longer run)."""
        def report(done: int, total: int, stage: str | None = None) -> None:
            self(done, total, prefix if stage is None else f"{prefix}: {stage}")

        return report

    def clear(self) -> None:
        """Wipe the bar off the terminal line (before printing something else there); it redraws at its next call."""
        if self._bar is not None:
            self._bar.clear()

    def close(self) -> None:
        """End the bar (a terminal) or print the last line with the total time (elsewhere)."""
        if self.quiet:
            return
        elapsed = time.perf_counter() - self._start
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        if self.stage is not None and not self.terminal:
            print(f"{self.label}: done, {elapsed:.1f} s", file=self.stream, flush=True)

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

