"""Shared helpers of the benchmark scripts: timings, a table printer and the JSON output.

Three ways to time, for three kinds of call:

- :func:`time_calls`: each call timed on its own; median and p95 [us] (calls of ~10 us and more);
  :func:`time_in_turn` does it for several functions called in turn (for ratios between them);
- :func:`timeit_us`: ``timeit`` runs of many back-to-back calls; the median run's mean [us] (calls of
  ~1-3 us, where timing each call on its own adds the timer's overhead);
- :func:`best_of_us`: per argument, the best of a few calls [us], with the call's result (a time per
  input, e.g. per pose).

Every script takes ``--smoke``: its smallest setting (every stage once, on the least data), which the test
suite runs (tests/test_benchmarks_smoke.py) so that no script rots; its figures mean nothing. A peer
package that is not installed (pink, daqp, roboticstoolbox-python: ``pip install .[bench]``) is skipped
with a printed line (:func:`optional`), never a crash.

The scripts time the installed package (``make install`` builds its compiled core into site-packages), not the
checkout: nothing here puts the checkout on ``sys.path``. A kinredund imported from a source checkout (through
``PYTHONPATH``) has no compiled core, so it would time the Python paths only: a full run refuses it (a
``--smoke`` run says so on stderr and goes on); the JSON's ``machine`` says which kinredund ran and whether
its compiled core was loaded (:func:`installed`).
"""

from __future__ import annotations

import argparse
import gc
import importlib.util
import platform
import sys
import time
import timeit
from datetime import date
from pathlib import Path

import numpy as np

try:  # the installed package, never the checkout: its compiled core is built into site-packages only (make install)
    import kinredund
except ImportError as err:  # pragma: no cover - depends on the environment
    raise SystemExit(f"the benchmarks time the installed kinredund, which this Python ({sys.executable}) cannot "
                     f"import ({err}): run `make install` and then `make bench` (or .venv/bin/python "
                     "benchmarks/NAME.py)") from err


def time_calls(fn, repeat: int = 2000, warmup: int = 50) -> dict:
    """Median and p95 [us] of ``fn()`` over ``repeat`` calls, each timed on its own."""
    return time_in_turn({"fn": fn}, repeat, warmup)["fn"]


def time_in_turn(fns: dict, repeat: int = 2000, warmup: int = 50, clock=time.perf_counter) -> dict:
    """:func:`time_calls` for several functions called in turn (one call of each per round).

    Background load and the machine's drift then hit all of them alike, so their ratios hold even
    when the absolute times of one run move. Garbage collection is off while timing (as in
    ``peers.py``'s round robin). ``clock=time.thread_time`` counts this thread's CPU time only (not the
    time the scheduler gives other processes on a loaded machine). Returns {name: {"median_us", "p95_us"}}.
    """
    for _ in range(warmup):
        for fn in fns.values():
            fn()
    ts = {name: np.empty(repeat) for name in fns}
    gc.disable()
    try:
        for i in range(repeat):
            for name, fn in fns.items():
                t0 = clock()
                fn()
                ts[name][i] = clock() - t0
    finally:
        gc.enable()
    return {name: summary_us(t) for name, t in ts.items()}


def step_in_turn(runners: dict, total: int) -> tuple[dict, dict, dict]:
    """Step every runner ``total`` times, one step of each in turn (so load hits them alike), with the garbage
    collector off. A runner has ``step()`` and ``state()``. Returns (times [s] per step, states from the start,
    failure message) per runner name; a runner that raises stops there and its failure is a result, not a crash."""
    times = {m: [] for m in runners}
    rec = {m: [r.state()] for m, r in runners.items()}
    failed = {}
    gc.disable()
    try:
        for k in range(total):
            for m, r in runners.items():
                if m in failed:
                    continue
                t0 = time.perf_counter()
                try:
                    r.step()
                except Exception as err:  # noqa: BLE001 - a method failing is a result, not a crash
                    cause = getattr(err, "cause", None) or type(err).__name__
                    failed[m] = f"step {k + 1}: {cause}: {str(err)[:200]}"
                    continue
                times[m].append(time.perf_counter() - t0)
                rec[m].append(r.state())
    finally:
        gc.enable()
    return times, rec, failed


def summary_us(seconds) -> dict:
    """{"median_us", "p95_us"} of per-call times given in seconds."""
    return {"median_us": float(np.median(seconds) * 1e6), "p95_us": float(np.percentile(seconds, 95) * 1e6)}


def timeit_us(fn, number: int, repeat: int) -> float:
    """Median over ``repeat`` ``timeit`` runs of the mean time [us] of ``number`` back-to-back calls ``fn()``."""
    runs = timeit.repeat(fn, number=number, repeat=repeat)
    return float(np.median(runs) / number * 1e6)


def best_of_us(fn, args, repeat: int = 5) -> tuple[np.ndarray, list]:
    """Per argument ``a`` of ``args``: the best of ``repeat`` timed calls ``fn(a)`` [us], and the last call's result."""
    times, results = np.empty(len(args)), []
    for i, a in enumerate(args):
        best, out = np.inf, None
        for _ in range(repeat):
            t0 = time.perf_counter()
            out = fn(a)
            best = min(best, time.perf_counter() - t0)
        times[i] = best * 1e6
        results.append(out)
    return times, results


def machine() -> dict:
    """Where and when the figures were taken."""
    import os

    return {"date": date.today().isoformat(), "python": platform.python_version(),
            "machine": platform.machine(), "cpus": os.cpu_count(), "processor": platform.processor(),
            "kinredund": installed()}


def installed() -> dict:
    """Which kinredund runs: its folder, whether that is a source checkout (a folder with pyproject.toml above
    the package, as ``PYTHONPATH=$PWD`` gives) and whether its compiled core loaded (else the import error)."""
    from kinredund.tracking.compiled import core_error, load_core

    folder = Path(kinredund.__file__).resolve().parent
    return {"path": str(folder), "checkout": (folder.parent / "pyproject.toml").is_file(),
            "compiled_core": load_core() is not None, "core_error": core_error()}


def check_installed(smoke: bool) -> dict:
    """Refuse (SystemExit) to time a checkout's kinredund without the compiled core, which would time the Python
    paths only; on ``smoke`` (no figure means anything) print why on stderr and go on. An installed kinredund
    without the core (where it could not be built: the Python fallback) is timed, with a line on stderr."""
    where = installed()
    if where["compiled_core"]:
        return where
    why = f"kinredund ({where['path']}) runs without its compiled core ({where['core_error']})"
    if where["checkout"]:
        why = (f"{why}: it is imported from a source checkout (PYTHONPATH?), which has no compiled core; the "
               "benchmarks time the installed package: run `make install`, then `make bench` or .venv/bin/python "
               "benchmarks/NAME.py without the checkout on PYTHONPATH")
        if not smoke:
            raise SystemExit(why)
    print(f"note: {why}; the figures time the Python paths", file=sys.stderr)
    return where


def print_table(rows: list[list], header: list[str]) -> None:
    """A plain aligned table on stdout."""
    cells = [header] + [[f"{c:.3g}" if isinstance(c, float) else str(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    for k, row in enumerate(cells):
        print("  ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)))
        if k == 0:
            print("  ".join("-" * w for w in widths))


def parser(description: str) -> argparse.ArgumentParser:
    """The common command line: ``--json FILE`` and ``--smoke``."""
    p = _Parser(description=description)
    p.add_argument("--json", type=Path, default=None, help="write the figures to this JSON file")
    p.add_argument("--smoke", action="store_true",
                   help="the smallest setting: check that the script runs (its figures mean nothing)")
    return p


class _Parser(argparse.ArgumentParser):
    """Parses as argparse does, then :func:`check_installed` (every script parses its command line first)."""

    def parse_args(self, args=None, namespace=None):
        parsed = super().parse_args(args, namespace)
        check_installed(getattr(parsed, "smoke", False))
        return parsed


def optional(*modules: str, what: str) -> bool:
    """Whether every one of ``modules`` can be imported; if not, print that ``what`` is skipped and why."""
    missing = [m for m in modules if importlib.util.find_spec(m) is None]
    if missing:
        print(f"skipped {what}: {', '.join(missing)} not installed (pip install .[bench])")
    return not missing


def write_json(path: Path | None, data: dict) -> None:
    """Write the figures and the machine as strict JSON, atomically (``kinredund.io.write_json``)."""
    if path is None:
        return
    from kinredund.io import write_json as write_strict_json

    write_strict_json(path, {"machine": machine(), **data}, indent=2)
    print(f"wrote {path}")
