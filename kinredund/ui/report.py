"""What the commands print: progress, summaries as aligned ``name value unit`` rows, the files written."""

from __future__ import annotations

import math
import sys

import numpy as np

from kinredund.ui.options import EXIT_FAILED, EXIT_OK


def progress_for(label: str, args):
    """The progress display of a command (:class:`kinredund.ui.progress.Progress`), shown at once."""
    from kinredund.ui.progress import Progress

    bar = Progress(label, quiet=getattr(args, "quiet", False))
    bar(0, 1, "starting")
    return bar


#: Units of the summary figures the commands print.
_UNITS = {"position_error_max": "m", "max_position_residual": "m", "clearance_min": "m",
          "clearance_lower_bound": "m", "clearance_doubling_change": "m", "penetration_max": "m",
          "spline_gap_max": "rad", "loop_drift": "rad", "theta3_ref_deg": "deg", "theta4_ref_deg": "deg",
          "max_joint_step_deg": "deg", "timings_s": "s", "wrist_reach_needed": "m", "wrist_reach_available": "m"}


def _number(v) -> str:
    return str(v) if isinstance(v, (bool, int, np.integer)) else f"{float(v):.3g}"


def _shown(value) -> bool:
    """Whether a summary value says something (not None, NaN, or an empty list or dict)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return False
    return not (isinstance(value, (list, tuple, dict, str)) and len(value) == 0)


def _format(key: str, value) -> str:
    unit = _UNITS.get(key, "")
    suffix = f" {unit}" if unit else ""
    if key == "loop_drift":  # a list per loop from tracking, one float from a plan: one format
        drift = [float(v) for v in (value if isinstance(value, (list, tuple, np.ndarray)) else [value])]
        return f"{drift[-1]:.3g} rad after loop {len(drift)}" + (
            f" (largest {max(drift):.3g} rad)" if len(drift) > 1 else "")
    if isinstance(value, dict):
        return ", ".join(f"{k.removesuffix('_s')} {_number(v)}{suffix}" for k, v in value.items() if _shown(v))
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, str) for v in value):
            return ", ".join(value)
        items = [_number(v) for v in value]
        text = f"[{', '.join(items)}]" if len(items) <= 7 else f"[{items[0]}, {items[1]}, ..., {items[-1]}] " \
            f"({len(items)} values)"
        return text + suffix
    if isinstance(value, (float, int, np.floating, np.integer)) and not isinstance(value, bool):
        return _number(value) + suffix
    return str(value)


def print_summary(summary: dict) -> None:
    """Print ``summary`` as aligned ``name value unit`` rows, leaving out empty values (None, NaN, {})."""
    for key, value in summary.items():
        if _shown(value):
            print(f"  {key:26s} {_format(key, value)}")


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
