"""Every benchmark script runs to the end at its smallest setting (``--smoke``), so that none rots unseen.

Each runs in its own process as ``make bench`` runs it (``python benchmarks/NAME.py``), from a scratch
folder, and must exit 0 and write its JSON; a peer package that is not installed (pink, daqp,
roboticstoolbox-python) is skipped with a printed line, never a crash. A hang fails at the timeout.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import load_benchmark

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"
#: scripts whose smoke runs are in a test of their own that checks their figures too (test_clearance_benchmarks.py)
OWN_TEST = {"clearance_peers", "random_obstacles"}
SCRIPTS = sorted(p.stem for p in BENCHMARKS.glob("[!_]*.py") if p.stem not in OWN_TEST)
#: [s] a smoke run takes a few seconds; this only turns a hang into a failure (no speed is asserted)
HANG = 300
#: the scripts whose smallest run still takes over ~10 s (sweep starts a local Dask cluster)
SLOW = {"sweep"}


def test_every_script_is_smoke_run():
    assert len(SCRIPTS) >= 10 and {"ik", "peers", "random_tasks"} <= set(SCRIPTS)


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in SCRIPTS])
def test_benchmark_runs_at_its_smallest_setting(name, tmp_path):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(BENCHMARKS.parent),
                                                                     os.environ.get("PYTHONPATH")])),
           "MPLBACKEND": "Agg"}
    out = tmp_path / "figures.json"
    run = subprocess.run([sys.executable, str(BENCHMARKS / f"{name}.py"), "--smoke", "--json", str(out)],
                         capture_output=True, text=True, cwd=tmp_path, env=env, timeout=HANG)
    assert run.returncode == 0, f"{name} --smoke failed:\n{run.stdout[-2000:]}\n{run.stderr[-4000:]}"
    assert "Traceback" not in run.stderr
    figures = json.loads(out.read_text())
    assert "machine" in figures and len(figures) > 1
    for peer in ("pink", "daqp", "roboticstoolbox"):
        if peer in (BENCHMARKS / f"{name}.py").read_text() and not _installed(peer):
            assert "skipped" in run.stdout, f"{name}: {peer} is missing and no line says what was skipped"


def _installed(module: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(module) is not None


def test_peers_verdict_takes_no_ratio_against_a_drift_at_rounding():
    """A drift of exactly 0 gave 'smallest_peer_drift_ratio 3.85e+297' (a ratio against 1e-300)."""
    peers = load_benchmark("peers")
    ok = {"drift": [0.0], "position_error_max": 1e-12, "orientation_error_max": 1e-12,
          "normality_residual_max": 1e-12, "step_us_median": 50.0}
    res = {"variants": {"constant": {"augmented": ok, "pseudoinverse": {**ok, "drift": [3.85e-3]}}}}
    v = peers.verdict(res)["constant"]
    assert "smallest_peer_drift_ratio" not in v
    assert v["drift_at_rounding"] and v["smallest_peer_drift"] == 3.85e-3
    res["variants"]["constant"]["augmented"] = {**ok, "drift": [1e-12]}
    assert peers.verdict(res)["constant"]["smallest_peer_drift_ratio"] == pytest.approx(3.85e9, rel=1e-12)
