"""The command line: each command runs, writes what it says, and fails clearly with the right exit code."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import TRACK_HOLD
from test_viz import scene_commands
from test_viz import track as animation_track

from kinredund.ui.cli import EXIT_FAILED, EXIT_USAGE, main


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
    capsys.readouterr()
    # counts are checked by argparse with the library's own bounds, before any work
    for argv, message in ((["reproduce", "4.1", "--loops", "0"], "--loops: must be an integer >= 1, got 0"),
                          (["track", "planar3r", "--steps", "-3"], "--steps: must be an integer >= 1, got -3"),
                          (["ik", "planar3r", "--target", "1,2", "--starts", "0"], "--starts: must be an integer >= 1"),
                          (["plan", "6.2", "--samples", "3"], "--samples: must be an integer >= 4, got 3")):
        with pytest.raises(SystemExit) as err:
            main(argv)
        assert err.value.code == EXIT_USAGE
        assert message in capsys.readouterr().err
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
    out = json.loads(js.read_text(), parse_constant=lambda c: pytest.fail(f"non-strict JSON: {c}"))
    # converged: the solver's residuals passed its own test (what they mean is checked in test_ik.py)
    assert out["converged"] and 0.0 <= out["normality_residual"] < float("inf")
    assert out["robot"] == "planar3r" and out["starts"] == 8 and len(out["q"]) == 3  # the IKResult's fields
    assert main(["ik", "planar3r", "--target", "9,0"]) == EXIT_FAILED  # out of reach: not converged
    assert '"converged": false' in capsys.readouterr().out


def test_track_and_play(tmp_path):
    js, html = tmp_path / "t.json", tmp_path / "t.html"
    assert main(["track", "planar3r", "--radius", "0.5", "--speed", "0.5", "--loops", "2", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert max(data["loop_drift"]) < 1e-8
    assert main(["play", str(js), "--html", str(html)]) == 0
    # the replay's tracer keyframes follow the tracked p at the trajectory's own clock
    (anim,) = [c for c in scene_commands(html.read_text()) if c["type"] == "set_animation"]
    fps = anim["animations"][0]["clip"]["fps"]
    keys, tracer = animation_track(anim, "/meshcat/path/tracer", "position")
    t, p = np.array(data["t"]), np.array(data["p"])
    assert len(keys) > 300 and keys[-1] / fps == pytest.approx(t[-1] - t[0])  # two loops of 2 pi 0.5 / 0.5 s
    expected = np.column_stack([np.interp(t[0] + keys / fps, t, p[:, i]) for i in range(3)])
    np.testing.assert_allclose(tracer, expected, atol=1e-9)
    # and they lie on the tracked circle (radius 0.5 m about the start point - 0.5 m in x, plane z = 0)
    center = p[0] - [0.5, 0.0, 0.0]
    np.testing.assert_allclose(np.linalg.norm(tracer - center, axis=1), 0.5, atol=1e-4)
    np.testing.assert_allclose(tracer[:, 2], 0.0, atol=1e-12)


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
    assert tr.position_error.max() < TRACK_HOLD and tr.loop_drift.max() < 1e-8


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


def test_track_open_path_from_file(tmp_path, capsys):
    """An open path ("closed": false) is tracked once over its duration, with --steps steps in all."""
    from kinredund.paths import read_path_file

    ts = 5.0 + np.linspace(0.0, 2.0, 21)  # times need not start at 0: they count from the first sample
    angle = 0.25 * np.pi * (ts - 5.0)  # a quarter of the circle of test_track_path_from_file
    p = np.column_stack([3.0 + 0.5 * np.cos(angle), 3.0 + 0.5 * np.sin(angle)])
    f = tmp_path / "open.json"
    f.write_text(json.dumps({"t": ts.tolist(), "p": p.tolist(), "closed": False}))
    path, duration = read_path_file(f)
    assert path.period is None and duration == pytest.approx(2.0)
    js = tmp_path / "t.json"
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f), "--index", "min-norm",
                 "--steps", "50", "--json", str(js)]) == 0
    data = json.loads(js.read_text())
    assert data["steps"] == 50 and len(data["t"]) == 51 and data["t"][-1] == pytest.approx(2.0)
    assert data["loop_drift"] is None and data["loop_period"] is None
    assert data["position_error_max"] < 1e-8
    np.testing.assert_allclose(np.array(data["p"])[[0, -1], :2], p[[0, -1]], atol=1e-8)  # from end to end
    f.write_text(json.dumps({"t": ts.tolist(), "p": p.tolist(), "closed": "no"}))
    assert main(["track", "planar3r", "--path", "file", "--path-file", str(f)]) == EXIT_USAGE
    assert "'closed' in" in capsys.readouterr().err


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
