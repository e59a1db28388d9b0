"""The stop diagnosis's smallest task residual in the compiled core (issue 28): ``StepCore.residual_min`` against
:func:`kinredund.tracking.failure.task_residual_min`'s Python iteration.

Both run Levenberg-Marquardt on 1/2 |r|^2 with the same operations (the core's r and J are the compiled step's, equal
to the Python evaluation's to rounding: tests/test_tracking_compiled.py), so from the same start they follow the same
iterates to rounding. Where the path point is reachable both residuals fall to rounding (<= 1e-12 m); where it is out
of reach both stop at the workspace boundary's Gauss-Newton minimum, where the residual is stationary: iterates that
differ by rounding end on residuals equal to far below the 1e-9 m asserted (the minimum's own value is metres).
"""

from __future__ import annotations

import numpy as np
import pytest

from kinredund import load_robot, minimum_norm, solve_ik
from kinredund.paths import Circle
from kinredund.problems import panda_circle
from kinredund.tracking import compiled, failure
from kinredund.tracking.point import Evaluator

pytestmark = pytest.mark.skipif(compiled.load_core() is None, reason="the compiled core is not built")


def planar_case():
    arm = load_robot("planar3r")
    path = Circle(np.array([5.0, 0.0, 0.0]), 1.0, 1.0, start_angle=np.pi)  # reaches 6 m: the arm's full reach
    index = minimum_norm(3)
    return arm, path, index, solve_ik(arm, path(0.0).p[:2], index, starts=12, seed=0).q


def python_route(ev, q, t):
    """task_residual_min with the core left out (the Python iteration on the evaluator's points)."""
    kept = failure._residual_core
    failure._residual_core = lambda ev: None
    try:
        return failure.task_residual_min(ev, q, t)
    finally:
        failure._residual_core = kept


@pytest.mark.parametrize("case", ["panda_pose", "planar"])
def test_the_core_iteration_is_the_python_one(case):
    robot, path, index, q0 = panda_circle() if case == "panda_pose" else planar_case()
    ev = Evaluator(robot, path, index, "augmented")
    assert failure._residual_core(ev) is not None
    rng = np.random.default_rng(7)
    reached = 0
    for _ in range(12):
        q = q0 + 0.8 * rng.standard_normal(len(q0))
        t = float(rng.uniform(0.0, path.period))
        res, q_min = failure.task_residual_min(ev, q, t)
        ref, _ = python_route(ev, q, t)
        assert np.all(np.isfinite(q_min)) and q_min.shape == q0.shape
        assert abs(res - ref) <= 1e-9
        # the configuration returned reaches the residual returned (evaluated afresh in Python)
        r = ev.point(q_min, t, need_dJ=False).r
        assert abs(float(np.linalg.norm(r)) - res) <= 1e-12 + 1e-9 * res
        reached += res <= 1e-12
    assert reached >= 6  # (the circles are within reach: most starts converge; the far case is the next test's)


def test_an_unreachable_point_stays_at_the_reach():
    """A planar 3R (links 1 + 2 + 3 m: reach 6 m) asked for a point 7 m out: the smallest residual is the 1 m the arm
    cannot close, from either route."""
    arm, path, index, q0 = planar_case()
    far_path = Circle(np.array([6.0, 0.0, 0.0]), 1.0, 1.0, start_angle=0.0)  # starts at (7, 0)
    ev = Evaluator(arm, far_path, index, "augmented")
    res, q_min = failure.task_residual_min(ev, q0, 0.0)
    ref, _ = python_route(ev, q0, 0.0)
    assert abs(res - 1.0) <= 1e-9 and abs(ref - 1.0) <= 1e-9
    assert np.abs(np.sin(q_min[1:])).max() <= 1e-4  # stretched out


def test_the_velocity_form_keeps_the_python_iteration():
    robot, path, index, _ = panda_circle()
    assert failure._residual_core(Evaluator(robot, path, index, "velocity")) is None


def test_bad_input_is_refused():
    robot, path, index, q0 = panda_circle()
    core = failure._residual_core(Evaluator(robot, path, index, "augmented"))
    s = path(0.0)
    with pytest.raises(ValueError, match="n entries"):
        core.residual_min(q0[:3], s.p, s.v, s.Q, s.omega, 10)
