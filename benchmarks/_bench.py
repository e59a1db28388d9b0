"""Shared helpers of the benchmark scripts: timing medians, a table printer and the JSON output."""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from datetime import date
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def time_calls(fn, repeat: int = 2000, warmup: int = 50) -> dict:
    """Median and p95 [us] of ``fn()`` over ``repeat`` calls, each timed on its own."""
    for _ in range(warmup):
        fn()
    ts = np.empty(repeat)
    for i in range(repeat):
        t0 = time.perf_counter()
        fn()
        ts[i] = time.perf_counter() - t0
    return {"median_us": float(np.median(ts) * 1e6), "p95_us": float(np.percentile(ts, 95) * 1e6)}


def machine() -> dict:
    """Where and when the figures were taken."""
    import os

    return {"date": date.today().isoformat(), "python": platform.python_version(),
            "machine": platform.machine(), "cpus": os.cpu_count(), "processor": platform.processor()}


def print_table(rows: list[list], header: list[str]) -> None:
    """A plain aligned table on stdout."""
    cells = [header] + [[f"{c:.3g}" if isinstance(c, float) else str(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    for k, row in enumerate(cells):
        print("  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)))
        if k == 0:
            print("  ".join("-" * w for w in widths))


def parser(description: str) -> argparse.ArgumentParser:
    """The common command line: ``--json FILE``."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--json", type=Path, default=None, help="write the figures to this JSON file")
    return p


def write_json(path: Path | None, data: dict) -> None:
    """Write the figures atomically (temporary file + rename)."""
    if path is None:
        return
    from kinredund.generate import atomic_write_text

    atomic_write_text(Path(path), json.dumps({"machine": machine(), **data}, indent=2))
    print(f"wrote {path}")
