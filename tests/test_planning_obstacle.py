"""The Chapter 6 obstacle planner as a configuration of the one planning pipeline: its motion is verified as
every plan's is (limits, path, closure, jumps; kinredund.planning.pipeline) before its clearance."""

from __future__ import annotations

import copy

import numpy as np
import pytest

import kinredund as kr
from kinredund.paths import Ellipse
from kinredund.planning.obstacles import EllipseObstacle
from kinredund.planning.options import ObstacleOptions
from kinredund.planning.pipeline import CLOSURE_TOL, TASK_TOL, verdict
from kinredund.planning.planner import plan
from kinredund.planning.result import PlanResult
from kinredund.planning.verify import limit_excursion, verify_motion_on_path

#: a small ellipse inside the planar 3R's reach, the obstacle far from the arm: a plan exists
CENTER, A, B, ANGLE = (0.6, 0.1), 0.12, 0.06, 0.35
QUICK = {"samples": 6, "steps_per_loop": 120, "substeps": 2}


@pytest.fixture(scope="module")
def setup():
    robot = kr.load_robot("planar3r_ch6")
    path = Ellipse(CENTER, A, B, angle=ANGLE)
    obstacle = EllipseObstacle((-0.8, -0.8), 0.1, 0.05)
    return robot, path, obstacle, plan(robot, path, obstacle, **QUICK)


def test_an_obstacle_plan_is_the_pipelines_result_and_says_what_it_checked(setup):
    robot, path, _, res = setup
    assert isinstance(res, PlanResult) and res.ok, res.reason
    tr = res.trajectory
    # the check is in the result and agrees with an independent one on the recorded motion
    again = verify_motion_on_path(robot, path, tr.t, tr.q, QUICK["steps_per_loop"])
    assert res.check == again and verdict(again) == ""
    assert again.limit_violation == 0.0 and np.all(limit_excursion(robot, tr.q) == 0.0)
    assert again.position_error_max <= TASK_TOL and len(again.closure) == 1 and again.closure[0] <= CLOSURE_TOL
    assert res.clearance.collision_free and np.all(res.clearance_min > 0)
    assert tr.meta["planner"] == "chapter6" and tr.meta["samples"]["kind"][0] == "optimum"
    assert res.summary()["check"]["closure"] == list(again.closure)


def test_the_verification_fails_a_motion_that_does_not_close_or_leaves_the_limits(setup):
    """What the old track_and_verify let through as ok (a drift was a note, the limits were not looked at):
    the pipeline's verdict names each."""
    robot, path, _, res = setup
    tr, per = res.trajectory, QUICK["steps_per_loop"]
    q = tr.q.copy()
    q[per:] += 1e-6  # the loop ends 1e-6 rad off its start, still on the path to first order
    assert "does not close" in verdict(verify_motion_on_path(robot, path, tr.t, q, per))
    narrow = copy.copy(robot)
    narrow.lower, narrow.upper = robot.lower.copy(), robot.upper.copy()
    narrow.upper[2] = tr.q[:, 2].max() - 1e-3
    assert "leaves the joint limits" in verdict(verify_motion_on_path(narrow, path, tr.t, tr.q, per))


def test_an_obstacle_plan_holds_limits_its_unlimited_motion_would_leave(setup):
    """Reproducer: with joint 3's upper limit below the unlimited motion's maximum but above every sample's
    optimum, the old planner tracked without limits and reported ok outside them. Now the plan is inside the
    limits at every recorded point, or fails with a cause."""
    robot, path, obstacle, free = setup
    knots = free.samples.q[:, 2]
    top = free.trajectory.q[:, 2].max()
    assert top > knots.max() + 1e-3  # the unlimited motion overshoots its knots there
    narrow = copy.copy(robot)
    narrow.lower, narrow.upper = robot.lower.copy(), robot.upper.copy()
    narrow.upper[2] = 0.5 * (top + knots.max())
    res = plan(narrow, path, obstacle, **QUICK)
    assert free.trajectory.q[:, 2].max() > narrow.upper[2]  # what the old planner would have reported
    if res.ok:
        assert np.all(limit_excursion(narrow, res.trajectory.q) == 0.0) and res.check.limit_violation == 0.0
    else:
        assert res.cause in PlanResult.CAUSES and res.reason


def test_obstacle_options_are_validated_once():
    with pytest.raises(kr.OptionError, match="weights"):
        ObstacleOptions(weights=(0.0, 0.0))
    with pytest.raises(kr.OptionError, match="sample times"):
        ObstacleOptions(samples=[0.0, 0.5, 0.4, 1.0])
    assert ObstacleOptions(samples=[0.0, 1.0, 2.0, 3.0]).samples == 4
    with pytest.raises(kr.OptionError, match="scene"):
        ObstacleOptions(scene=object())


def test_the_obstacle_planner_adds_samples_where_the_closed_walk_breaks(setup):
    """Where no closed walk exists at the sampling (4 samples, transitions not bisected, joint jumps <= 0.1 rad),
    the obstacle planner inserts samples in the intervals the walk cannot cross, within refine_samples, as kr.plan
    does; before, it told the user to try more samples."""
    robot, path, obstacle, _ = setup
    kw = {"samples": 4, "budget": 0, "max_jump": 0.1, "steps_per_loop": 60, "substeps": 1, "starts": 4,
          "check_doubling": False}
    failed = plan(robot, path, obstacle, refine_samples=0, **kw)
    assert not failed.ok and failed.cause == "no_closed_walk" and "refine_samples=0" in failed.reason
    res = plan(robot, path, obstacle, refine_samples=4, **kw)
    assert res.ok, res.reason
    smp = res.samples
    assert 4 < smp.sample_t.size <= 8 and any("sample(s) added" in note for note in res.notes)
    assert len(smp.weights) == smp.sample_t.size == len(smp.candidates)
    chain = np.vstack([smp.q, smp.q[:1] + smp.turns])  # the knots, closed by the first one a period later
    assert np.abs(np.diff(chain, axis=0)).max() <= kw["max_jump"]
