"""Progress of long commands on standard error: a tqdm bar on a terminal, a line every few seconds elsewhere.

The library reports progress through a callable ``progress(done, total, stage=None)``: the tracker
calls it after each step (without a stage), the planners name their stages (``roadmap``, ``tracking``,
``clearance``, ...). :class:`Progress` is that callable for the command line: on a terminal one tqdm
bar whose description follows the stage (it restarts when the stage changes, so the whole run shows,
not only the tracking); off a terminal (a log, CI, a pipe) plain lines: one at the first call, one
when a stage ends (where it got to), and one every ``interval`` seconds from a timer thread, so the log
moves at a steady pace even through a stage that reports rarely; with ``quiet`` nothing.

The last line says how the run ended: ``done``, ``failed`` or ``interrupted`` (:meth:`Progress.close`
reads the exception in flight when it is called from a ``finally`` block or a ``with`` statement).
"""

from __future__ import annotations

import shutil
import sys
import threading
import time

from kinredund.errors import check_choice

#: Seconds between two lines off a terminal.
LOG_INTERVAL = 5.0
#: How a run can end, as the last progress line says it.
OUTCOMES = ("done", "failed", "interrupted")


def outcome_of(exc: BaseException | None) -> str:
    """``done`` without an exception, ``interrupted`` for Ctrl-C (KeyboardInterrupt) or a signal's
    SystemExit, ``failed`` for any other exception."""
    if exc is None:
        return "done"
    return "interrupted" if isinstance(exc, (KeyboardInterrupt, SystemExit)) else "failed"


class Progress:
    """Callable as ``progress(done, total, stage=None)``; ``close()`` ends the bar with the run's outcome.

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
        self._done, self._total = 0, 1
        self._bar = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._timer: threading.Thread | None = None
        self._last_line = -float("inf")
        self._start = time.perf_counter()

    def __call__(self, done: int, total: int, stage: str | None = None) -> None:
        if self.quiet:
            return
        stage = stage if stage is not None else (self.stage or "working")
        total = max(int(total), 1)
        done = min(max(int(done), 0), total)
        with self._lock:
            previous = self.stage
            new_stage = stage != previous
            if new_stage and previous is not None and not self.terminal:
                self._line(f"{previous} {self._done}/{self._total} ({self._percent()})")  # where it got to
            self.stage, self._done, self._total = stage, done, total
            if self.terminal:
                self._draw(done, total, new_stage)
            elif previous is None:
                self._line(self._state())
                self._start_timer()

    def _percent(self) -> str:
        return f"{100.0 * self._done / self._total:.0f}%"

    def _state(self) -> str:
        return f"{self.stage} {self._done}/{self._total} ({self._percent()})"

    def _line(self, text: str) -> None:
        """Print ``label: text, elapsed`` (off a terminal; the caller holds the lock)."""
        now = time.perf_counter()
        self._last_line = now
        print(f"{self.label}: {text}, {now - self._start:.1f} s", file=self.stream, flush=True)

    def _start_timer(self) -> None:
        """The thread that prints the current state every ``interval`` seconds without a line."""
        def beat() -> None:
            while not self._stop.wait(min(self.interval, 1.0)):
                with self._lock:
                    if not self._stop.is_set() and time.perf_counter() - self._last_line >= self.interval:
                        self._line(self._state())

        self._timer = threading.Thread(target=beat, name=f"progress {self.label}", daemon=True)
        self._timer.start()

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

    def close(self, outcome: str | None = None) -> None:
        """End the bar and say how the run ended: ``done``, ``failed`` or ``interrupted``.

        Args:
            outcome: one of :data:`OUTCOMES`; default from the exception in flight (:func:`outcome_of` of
                ``sys.exc_info()``, which a ``finally`` block sees), ``done`` without one.

        Off a terminal the last line is ``label: outcome, elapsed`` (with the stage and count where a failed
        or interrupted run stopped); on a terminal the bar is wiped and, unless ``done``, that line printed.
        """
        if outcome is None:
            outcome = outcome_of(sys.exc_info()[1])
        check_choice("progress outcome", outcome, OUTCOMES)
        self._stop.set()
        if self._timer is not None:
            self._timer.join()
            self._timer = None
        if self.quiet:
            return
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        if self.stage is None or (self.terminal and outcome == "done"):
            return
        with self._lock:
            if outcome == "done" and not self.terminal:
                self._line(self._state())  # where the last stage got to, as at every stage's end
            self._line(outcome if outcome == "done" else f"{outcome} at {self._state()}")
        self.stage = None  # closed: a second close prints nothing

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, kind, exc, tb) -> None:
        self.close(outcome_of(exc))
