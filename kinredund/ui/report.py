"""What the commands print around a run: its progress, the files written, the exit code of a result that checks
itself (the summaries and tables: :mod:`kinredund.ui.summary`)."""

from __future__ import annotations

import sys

from kinredund.ui.options import EXIT_FAILED, EXIT_OK


def progress_for(label: str, args):
    """The progress display of a command (:class:`kinredund.ui.progress.Progress`), shown at once."""
    from kinredund.ui.progress import Progress

    bar = Progress(label, quiet=getattr(args, "quiet", False))
    bar(0, 1, "starting")
    return bar


def wrote(*paths) -> None:
    """Print ``wrote PATH`` for every path that is not None."""
    for p in paths:
        if p is not None:
            print(f"wrote {p}")


def outcome(ok: bool, failure: str) -> int:
    """The exit code of a run whose result checked itself: EXIT_OK, or ``kinredund: FAILURE`` on stderr and
    EXIT_FAILED."""
    if ok:
        return EXIT_OK
    print(f"kinredund: {failure}", file=sys.stderr)
    return EXIT_FAILED
