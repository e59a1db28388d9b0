"""The clearance benchmarks (issue 27) run at their smallest setting and their figures say what they should.

benchmarks/clearance_peers.py and benchmarks/random_obstacles.py run with ``--smoke`` in a subprocess (as a
user runs them); the bars are the tracker's (tests/test_tracking_clearance.py): clearance >= -1e-9 m,
closure and tracking <= 1e-10. Each starts a Python with Pinocchio and matplotlib (~2 s of CPU, more on a
loaded machine): marked slow (CI runs them).
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from conftest import BENCHMARKS

from kinredund.errors import TrackingError

PNG = b"\x89PNG\r\n\x1a\n"
pytestmark = pytest.mark.slow


def smoke(script: str, tmp_path) -> tuple[dict, str]:
    out, fig = tmp_path / "out.json", tmp_path / "fig.png"
    run = subprocess.run([sys.executable, str(BENCHMARKS / script), "--smoke", "--json", str(out), "--plot", str(fig)],
                         capture_output=True, text=True, timeout=300, cwd=BENCHMARKS.parent)
    assert run.returncode == 0, run.stderr
    assert fig.read_bytes()[:8] == PNG
    return json.loads(out.read_text()), run.stdout


def test_clearance_peers_smoke(tmp_path):
    res, stdout = smoke("clearance_peers.py", tmp_path)
    m = res["methods"]
    assert res["settings"]["loops"] == 1 and len(m["kinredund"]["drift"]) == 1
    ours, free = m["kinredund"], m["kinredund_free"]
    assert "failed" not in ours and "failed" not in free
    assert free["clearance_min"] < -0.009  # the within-limits optimum runs into the sphere
    assert ours["clearance_min"] >= -1e-9  # ours holds it, on the path, and closes
    assert ours["drift"][0] <= 1e-10 and ours["position_error_max"] <= 1e-10
    assert ours["median_us"] > 0 and len(ours["clearance"]) == len(ours["t"]) == 51
    for peer in ("pink", "pink_barrier", "pink_barrier_sd0"):  # pink is optional: run, or skipped with a reason printed
        assert (peer in m) != (peer in res["skipped"])
        if peer in res["skipped"]:
            assert f"skipped {peer}: not installed" in stdout or "is not installed" in stdout
        else:
            assert len(m[peer]["clearance"]) == 51 or "failed" in m[peer]
    if "pink" in m and "failed" not in m["pink"]:  # without its barrier pink runs in as deep as the optimum does
        assert m["pink"]["clearance_min"] < -0.005


def test_random_obstacles_smoke(tmp_path):
    res, _ = smoke("random_obstacles.py", tmp_path)
    assert set(res["robots"]) == {"panda", "xarm7"}
    for name, r in res["robots"].items():
        s = r["summary"]["kinredund"]
        assert s["tasks"] == 1 and s["completed"] + sum(s["causes"].values()) == 1, name
        assert s["wrong"] == 0  # every completion holds and closes; every stop is named, clear and on the path
        assert s["stops_clear_on_path_inside"] == sum(s["causes"].values())
        for task in r["tasks"]:
            assert task["penetration"] >= 0.01 - 1e-12  # the free optimum runs at least 1 cm in
            ours = task["kinredund"]
            if ours["completed"]:
                assert ours["clearance_min"] >= -1e-9 and max(ours["drift"]) <= 1e-10
                assert ours["position_error_max"] <= 1e-10
            else:
                assert ours["cause"] in TrackingError.CAUSES
        for peer in ("pink_barrier", "pink_barrier_sd0"):
            assert (peer in r["summary"]) != (peer in res["skipped"])


@pytest.mark.parametrize("script", ["clearance_peers.py", "random_obstacles.py"])
def test_bad_arguments_exit_2(script):
    run = subprocess.run([sys.executable, str(BENCHMARKS / script), "--loops", "0"], capture_output=True, text=True,
                         timeout=300, cwd=BENCHMARKS.parent)
    assert run.returncode == 2 and "--loops" in run.stderr
