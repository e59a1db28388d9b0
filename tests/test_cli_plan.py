"""``kinredund plan ROBOT``, run as a user runs it (a subprocess of the installed script): a cyclic plan of
a 6-axis arm on its tool-axis task whose JSON ``retime`` and ``export --bag`` take as they take ``track``'s."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from conftest import robot

from kinredund.export import JointSamples, read_bag
from kinredund.planning.cyclic import CLOSURE_TOL, TASK_TOL
from kinredund.trajectory import Trajectory

SCRIPT = Path(sys.executable).parent / "kinredund"
RADIUS, SPEED, STEPS = 0.04, 0.08, 100


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(SCRIPT), *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def test_plan_ur5_then_retime_then_export_a_bag(tmp_path):
    out = run("plan", "ur5", "--radius", str(RADIUS), "--speed", str(SPEED), "--samples", "12", "--starts", "2",
              "--loops", "1", "--steps", str(STEPS), "--json", "plan.json", "--quiet", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "task axis" in out.stdout
    data = json.loads((tmp_path / "plan.json").read_text())
    assert data["plan"]["ok"] is True and data["plan"]["cause"] == ""
    planned = Trajectory.load_json(tmp_path / "plan.json")
    r = robot("ur5")
    assert planned.robot == "ur5" and planned.task == "axis" and len(planned.t) == STEPS + 1
    # independently of the planner: inside the limits, on the circle (the robot's FK), the axis held, closed
    assert np.all(planned.q >= r.lower) and np.all(planned.q <= r.upper)
    T = np.array([r.fk(q) for q in planned.q])
    p_home = r.fk(r.home)[:3, 3]
    centre = p_home - np.array([RADIUS, 0.0, 0.0])  # path_for: the circle starts at the home point
    assert np.abs(np.linalg.norm(T[:, :3, 3] - centre, axis=1) - RADIUS).max() <= TASK_TOL
    assert np.abs(T[:, 2, 3] - centre[2]).max() <= TASK_TOL  # a horizontal circle
    axis_home = r.fk(r.home)[:3, 2]
    assert np.arccos(np.clip(T[:, :3, 2] @ axis_home, -1.0, 1.0)).max() <= 1e-6  # the start axis held
    assert np.abs(planned.q[-1] - planned.q[0]).max() <= CLOSURE_TOL
    # z = 1/2 ||q - home||^2 and the circle starts at the home point: the plan starts at home itself, not at a
    # copy shifted by a whole turn on the UR5's +-2 pi joints (z = 19.7 there; it did before the home seeded
    # the first sample and z broke ties between equally long walks)
    assert np.abs(planned.q[0] - r.home).max() <= 1e-6

    out = run("retime", "plan.json", "--amax", "5", "--json", "timed.json", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    timed = Trajectory.load_json(tmp_path / "timed.json")
    assert np.abs(timed.q - planned.q).max() <= CLOSURE_TOL  # the same joint path at new times (closed on q_0)
    vmax = np.asarray(r.model.velocityLimit)
    assert np.max(np.abs(timed.qdot) / vmax) <= 1 + 1e-6 and np.max(np.abs(timed.qddot)) <= 5 * (1 + 1e-6)

    out = run("export", "timed.json", "--bag", "bag", cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert read_bag(tmp_path / "bag").equal_to(JointSamples.from_trajectory(timed, r.joint_names)) <= 1e-12


def test_plan_refuses_an_open_path_and_an_unknown_robot(tmp_path):
    line = {"t": [0.0, 1.0, 2.0, 3.0], "p": [[0.4 + 0.01 * k, 0.0, 0.4] for k in range(4)], "closed": False}
    (tmp_path / "open.json").write_text(json.dumps(line))
    out = run("plan", "panda", "--task", "position", "--path", "file", "--path-file", "open.json", "--json", "p.json",
              cwd=tmp_path)
    assert out.returncode == 2 and "closed path" in out.stderr
    out = run("plan", "no_such_robot", cwd=tmp_path)
    assert out.returncode == 2 and "kinredund: error:" in out.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["open.json"]


def test_plan_of_a_thesis_case_refuses_the_robot_plan_outputs(tmp_path, capsys):
    """``plan 6.2|6.3`` writes no HTML replay nor partial record: --html and --partial are refused before
    any work (exit 2), not left silently unwritten (plan 6.2 ran and exited 1 with no word about them)."""
    from kinredund.ui.cli import EXIT_USAGE, main

    for option in ("--html", "--partial"):
        code = main(["plan", "6.2", "--quiet", option, str(tmp_path / "out.file")])
        err = capsys.readouterr().err
        assert code == EXIT_USAGE and f"{option} apply to a robot's plan" in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_plan_summary_prints_its_intervals_and_its_check(capsys):
    """`plan 6.3` crashed printing its summary (TypeError in format_value: off_optimum's [start, end] pairs and the
    check's dict were not printable), and so did `plan ROBOT` on a plan with an interval off z's optimum."""
    from kinredund.planning.result import PlanResult
    from kinredund.planning.verify import MotionCheck
    from kinredund.ui.cli_plan import print_plan_summary

    check = MotionCheck(0.0, 1e-12, 2e-12, (3e-16, 4e-16), 0.01, 1.02, (), -1)
    result = PlanResult(True, "", off_optimum=((0.5, 0.75), (1.0, 1.25)), check=check, link_names=("link 1",),
                        notes=("a note",), timings={"total_s": 1.5})
    print_plan_summary(result.summary())
    out = capsys.readouterr().out
    assert "off_optimum                [0.5, 0.75]; [1, 1.25] s" in out
    assert "check.closure              [3e-16, 4e-16]" in out and "check.limit_violation      0" in out
    assert "a note" in out and "total 1.5 s" in out
