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
    env = {**os.environ, "MPLBACKEND": "Agg"}  # the installed kinredund, as `make bench` runs them (_bench.py)
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


def _kinredund_file(*setup: str) -> str:
    """Where a fresh Python (no PYTHONPATH, in a scratch folder) imports kinredund from, after ``setup``."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    code = "; ".join(["import sys", *setup, "import kinredund", "print(kinredund.__file__)"])
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=BENCHMARKS,
                         timeout=HANG)
    assert run.returncode == 0, run.stderr
    return run.stdout.strip().splitlines()[-1]


def test_the_benchmarks_import_the_installed_package_not_the_checkout():
    """_bench.py put the checkout first on sys.path, so the scripts timed the checkout's kinredund, which has no
    compiled core unless `make install` copied it there (the copy this replaces)."""
    installed = _kinredund_file()
    assert not installed.startswith(str(BENCHMARKS.parent / "kinredund"))
    assert _kinredund_file(f"sys.path.insert(0, {str(BENCHMARKS)!r})", "import _bench") == installed


def test_a_full_run_refuses_a_checkout_without_the_core_and_a_smoke_run_says_so(monkeypatch, capsys):
    bench = load_benchmark("ik").parser.__globals__  # _bench's namespace, as the scripts import it
    from kinredund.tracking import compiled

    monkeypatch.setattr(compiled, "_CORE", [None, "ImportError: no module named kinredund._core"])
    monkeypatch.setattr(bench["kinredund"], "__file__", str(BENCHMARKS.parent / "kinredund" / "__init__.py"))
    assert bench["installed"]() == {"path": str(BENCHMARKS.parent / "kinredund"), "checkout": True,
                                    "compiled_core": False, "core_error": compiled.core_error()}
    with pytest.raises(SystemExit, match="source checkout.*make install"):
        bench["parser"]("x").parse_args([])
    assert bench["parser"]("x").parse_args(["--smoke"]).smoke
    assert "the figures time the Python paths" in capsys.readouterr().err


def test_the_held_rows_benchmark_runs_the_sphere_and_its_pseudo_backends(tmp_path):
    """scene_rows.py's sphere case with both pseudo-backends (the rows held left to Python; no compiled check): it
    exits 0, and its compiled and Python backends, stepped in turn, agree to the tracker's 1e-12 rad per step (no
    speed asserted)."""
    out = tmp_path / "figures.json"
    run = subprocess.run([sys.executable, str(BENCHMARKS / "scene_rows.py"), "--smoke", "--case", "sphere",
                          "--backends", "compiled,compiled-no-check,compiled-rows-in-python", "--json", str(out)],
                         capture_output=True, text=True, cwd=tmp_path, env={**os.environ, "MPLBACKEND": "Agg"},
                         timeout=HANG)
    assert run.returncode == 0, f"{run.stdout[-2000:]}\n{run.stderr[-4000:]}"
    figures = json.loads(out.read_text())
    assert figures["case"] == "sphere" and figures["agreement_q_max"] < 1e-12
    assert figures["backend_compiled-no-check"] == "compiled-no-check" and figures["scene_active_steps"] > 0
    assert figures["switches"] >= 1 and 0.0 < figures["switch_share"] < 1.0  # (a share of one run's time)


def test_the_many_runs_benchmark_runs_the_sphere_case(tmp_path):
    """many.py's ``--sphere`` case (clearance_peers' elbow sphere in every run) with ``--processes``: it exits 0, its
    runs complete, and the records of one and two threads and of track_many(processes=2) are those of the runs one by
    one, bit for bit (no speed asserted)."""
    out = tmp_path / "figures.json"
    run = subprocess.run([sys.executable, str(BENCHMARKS / "many.py"), "--smoke", "--sphere", "--processes", "--json",
                          str(out)],
                         capture_output=True, text=True, cwd=tmp_path, env={**os.environ, "MPLBACKEND": "Agg"},
                         timeout=HANG)
    assert run.returncode == 0, f"{run.stdout[-2000:]}\n{run.stderr[-4000:]}"
    figures = json.loads(out.read_text())
    assert figures["case"] == "sphere" and figures["same_as_one_by_one"] and figures["stopped"] == 0
    assert 0.0 < figures["core_runs_share"] < 1.0 and figures["runs"] == 2
    assert figures["runs_per_s_track_many_processes"] > 0.0
