"""The command line: each command runs, writes what it says, and fails clearly with the right exit code."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from kinredund.cli import EXIT_FAILED, EXIT_USAGE, main


def test_robots_lists_every_name(capsys):
    assert main(["robots"]) == 0
    out = capsys.readouterr().out
    for name in ("planar3r", "planar3r_ch6", "puma7", "cybotech_p15", "panda", "xarm7"):
        assert name in out


@pytest.mark.parametrize("example", ["4.1", "4.2"])
def test_reproduce_chapter4_writes_json_and_plot(tmp_path, example):
    js, png = tmp_path / "r.json", tmp_path / "r.png"
    assert main(["reproduce", example, "--loops", "2", "--json", str(js), "--plot", str(png)]) == 0
    data = json.loads(js.read_text())
    for key in ("t", "q", "q0", "solver", "m_min_eig", "position_error_max", "trace_error_max", "vect_error_max",
                "loop_drift"):
        assert key in data
    assert len(data["q"]) == len(data["t"]) == 401 and len(data["loop_drift"]) == 2
    assert max(data["loop_drift"]) < 1e-8 and data["position_error_max"] < 1e-8
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"


def test_reproduce_4_3_thesis_mode(tmp_path):
    js = tmp_path / "r.json"
    assert main(["reproduce", "4.3", "--mode", "thesis", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert data["mode"] == "thesis" and data["position_error_max"] < 2e-3 and data["vect_error_max"] < 1e-2


def test_reproduce_3_2(tmp_path):
    js = tmp_path / "h.json"
    assert main(["reproduce", "3.2", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert len(data["beta"]) == len(data["q"]) > 10


def test_bad_arguments_exit_2_with_a_message(capsys, tmp_path):
    with pytest.raises(SystemExit) as err:
        main(["reproduce", "4.9"])
    assert err.value.code == EXIT_USAGE
    assert "invalid choice" in capsys.readouterr().err
    assert main(["reproduce", "4.1", "--loops", "0"]) == EXIT_USAGE
    assert "--loops must be >= 1" in capsys.readouterr().err
    with pytest.raises(SystemExit) as err:
        main(["ik", "planar3r", "--target", "1,nan"])
    assert err.value.code == EXIT_USAGE
    assert main(["ik", "kuka", "--target", "1,2"]) == EXIT_USAGE
    assert "unknown robot 'kuka'" in capsys.readouterr().err
    assert main(["ik", "planar3r", "--target", "1,2,3"]) == EXIT_USAGE
    assert "shape (2,)" in capsys.readouterr().err
    missing = tmp_path / "nothing.json"
    assert main(["play", str(missing), "--html", str(tmp_path / "x.html")]) == EXIT_USAGE
    assert "cannot read" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["play", str(bad), "--html", str(tmp_path / "x.html")]) == EXIT_USAGE
    assert "not valid JSON" in capsys.readouterr().err
    assert not (tmp_path / "x.html").exists()


def test_ik_command(capsys, tmp_path):
    js = tmp_path / "ik.json"
    assert main(["ik", "planar3r", "--target", "3.8,3", "--index", "min-norm", "--starts", "8", "--json", str(js)]) == 0
    out = json.loads(js.read_text())
    assert out["converged"] and out["normality_residual"] < 1e-9
    assert main(["ik", "planar3r", "--target", "9,0"]) == EXIT_FAILED  # out of reach: not converged
    assert '"converged": false' in capsys.readouterr().out


def test_track_and_play(tmp_path):
    js, html = tmp_path / "t.json", tmp_path / "t.html"
    assert main(["track", "planar3r", "--radius", "0.5", "--speed", "0.5", "--loops", "2", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert max(data["loop_drift"]) < 1e-8
    assert main(["play", str(js), "--html", str(html)]) == 0
    assert html.stat().st_size > 100_000 and b"<html" in html.read_bytes()[:2000].lower()


def test_track_pose_task_holds_the_start_orientation(tmp_path):
    """For a pose task the circle keeps the start pose's orientation: vect and trace errors stay ~0."""
    from kinredund import load_robot
    from kinredund.trajectory import Trajectory

    js = tmp_path / "pose.json"
    assert main(["track", "puma7", "--radius", "0.1", "--steps", "60", "--json", str(js)]) == 0
    tr = Trajectory.load_json(js)
    robot = load_robot("puma7")
    Q_start = robot.fk(tr.q[0])[:3, :3]
    assert max(np.abs(robot.fk(q)[:3, :3] - Q_start).max() for q in tr.q) < 1e-9
    assert tr.position_error.max() < 1e-9 and tr.loop_drift.max() < 1e-8


def test_track_path_from_file(tmp_path):
    ts = np.linspace(0.0, 4.0, 41)
    p = np.column_stack([3.0 + 0.5 * np.cos(2 * np.pi * ts / 4), 3.0 + 0.5 * np.sin(2 * np.pi * ts / 4)])
    f = tmp_path / "path.json"
    f.write_text(json.dumps({"t": ts.tolist(), "p": p.tolist()}))
    js = tmp_path / "t.json"
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f), "--index", "min-norm",
                 "--json", str(js)]) == 0
    assert json.loads(js.read_text())["position_error_max"] < 1e-8
    f.write_text(json.dumps({"t": [0, 1], "p": [[0, 0], [1, 1]]}))
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f)]) == EXIT_USAGE


def test_console_script_is_installed():
    from pathlib import Path

    script = Path(sys.executable).parent / "kinredund"  # installed by pip next to the interpreter
    assert script.exists()
    out = subprocess.run([str(script), "robots"], capture_output=True, text=True)
    assert out.returncode == 0 and "panda" in out.stdout
    out = subprocess.run([str(script), "reproduce", "9.9"], capture_output=True, text=True)
    assert out.returncode == 2 and "invalid choice" in out.stderr


def test_failed_run_leaves_no_output_file(tmp_path, capsys):
    js = tmp_path / "t.json"
    # a 3 m circle around the home point: the path leaves the 6 m workspace
    assert main(["track", "planar3r", "--radius", "3", "--speed", "1", "--index", "min-norm", "--json", str(js)]) \
        == EXIT_USAGE
    err = capsys.readouterr().err
    assert "kinredund: error:" in err and "t = " in err
    assert not js.exists() and not list(tmp_path.iterdir())
