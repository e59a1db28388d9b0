"""What the ``kinredund`` commands print: summary figures with their units, aligned tables, advice in the
command line's words. :mod:`kinredund.ui.cli` prints through these."""

from __future__ import annotations

import math
import re

import numpy as np

#: Units of the summary figures the commands print (a figure without one is a count or a ratio).
UNITS = {"position_error_max": "m", "axis_error_max": "rad", "max_position_residual": "m", "clearance_min": "m",
         "clearance_lower_bound": "m", "clearance_doubling_change": "m", "penetration_max": "m",
         "spline_gap_max": "rad", "loop_drift": "rad", "theta3_ref_deg": "deg", "theta4_ref_deg": "deg",
         "max_joint_step_deg": "deg", "timings_s": "s", "wrist_reach_needed": "m", "wrist_reach_available": "m",
         "off_optimum": "s"}


def _number(v) -> str:
    return str(v) if isinstance(v, (bool, int, np.integer)) else f"{float(v):.3g}"


def _shown(value) -> bool:
    """Whether a summary value says something (not None, NaN, or an empty list or dict)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return False
    return not (isinstance(value, (list, tuple, dict, str)) and len(value) == 0)


def format_value(key: str, value) -> str:
    """``value`` as the summary prints it: a number with its unit, a drift per loop, a list summed up."""
    unit = UNITS.get(key, "")
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
        if all(isinstance(v, (list, tuple)) for v in value):  # intervals: [a, b] pairs
            return "; ".join(f"[{', '.join(_number(x) for x in v)}]" for v in value) + suffix
        items = [_number(v) for v in value]
        if len(items) <= 7:
            return f"[{', '.join(items)}]{suffix}"
        if len(set(items)) == 1:  # not [0, 0, ..., 0]
            return f"{len(items)} values, all {items[0]}{suffix}"
        low, high = min(value), max(value)
        return f"{len(items)} values from {_number(low)} to {_number(high)}{suffix}"
    if isinstance(value, (float, int, np.floating, np.integer)) and not isinstance(value, bool):
        return _number(value) + suffix
    return str(value)


def print_summary(summary: dict) -> None:
    """Print ``summary`` as aligned ``name value unit`` rows, leaving out empty values (None, NaN, {})."""
    for key, value in summary.items():
        if _shown(value):
            print(f"  {key:26s} {format_value(key, value)}")


def print_table(header, rows, right=()) -> None:
    """Print ``rows`` under ``header``, each column as wide as its longest entry (the last one free);
    the columns numbered in ``right`` are right-aligned."""
    cells = [tuple(header), *(tuple(r) for r in rows)]
    widths = [max(len(c[k]) for c in cells) for k in range(len(header) - 1)]
    for c in cells:
        pairs = enumerate(zip(c[:-1], widths, strict=True))
        columns = (v.rjust(w) if k in right else v.ljust(w) for k, (v, w) in pairs)
        print("  ".join(columns) + "  " + c[-1])


def in_cli_words(message: str) -> str:
    """A library message with its Python advice in command-line words: ``robot.with_task('position')``
    becomes ``--task position``."""
    return re.sub(r"robot\.with_task\('(\w+)'\)", r"--task \1", message)
