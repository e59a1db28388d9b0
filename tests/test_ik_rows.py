"""The bounded joint-level IK with distance rows (issue 27): min z s.t. the task, the limits and the clearances.

Named case: test_tracking_scene's ``panda_elbow_ball`` (the within-limits optimum runs 5 mm into a 5 cm ball,
held 2 cm off it). Checked independently of the solver: distances afresh from coal, the first-order conditions
on an SVD null basis of [J; G_ball] with G afresh from the scene, and the tracker's held optimum at the same
time (both hold the same first-order conditions: the tracker to ~1e-12, the IK to its tol 1e-10, so they agree
to 1e-9). The planner's use: its candidates and its off_optimum measure (test_planning_scene for the plan).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_tracking_scene import CLEARANCE, ball_distance, run, setup

import kinredund as kr
from kinredund.errors import OptionError
from kinredund.ik.rows import solve_ik_rows
from kinredund.planning.follow import FOLLOW_TOL, measure
from kinredund.tracking.constraints.joint_limits import JointLimits


def _ball_rows():
    r, path, index, q0, sc = setup()
    return kr.SceneClearance(sc, clearance=CLEARANCE, self_clearance=None)


def test_the_minimum_that_keeps_the_clearance_is_the_tracker_s_held_optimum():
    r, path, index, _, sc = setup()
    c = _ball_rows()
    free, held = run(with_scene=False), run()
    k = int(np.argmin(ball_distance(sc, free.q)))  # where the free optimum is deepest in the ball
    res = solve_ik_rows(r, path(free.t[k]).p, index, [c], free.q[k])
    assert res.converged, res.reason
    assert abs(ball_distance(sc, res.q)[0] - CLEARANCE) <= 1e-10  # on the clearance, afresh from coal
    assert np.abs(res.q - held.q[k]).max() <= 1e-9  # the tracker's constrained optimum at that time
    assert np.abs(r.fk(res.q)[:3, 3] - path(free.t[k]).p).max() <= 1e-10
    i = c.pairs.index(("panda_link3_0", "ball"))
    assert res.active == (i,) and res.multipliers[0] > 0.1  # the ball pushes the arm out
    fixed = np.flatnonzero((res.q <= r.lower + 1e-9) | (res.q >= r.upper - 1e-9))  # joints on a limit
    A = np.vstack([r.kinematics.jacobian(res.q)[2][3:], c.gradients(res.q)[i], np.eye(7)[fixed]])
    _, s, Vt = np.linalg.svd(A)
    grad = index.evaluate(res.q)[1]
    assert np.linalg.norm(Vt[len(A):] @ grad) <= 1e-9  # first-order conditions with the row, independently
    y = np.linalg.lstsq(A.T, -grad, rcond=None)[0]
    assert -y[3] > 0.1  # nu = -y of the row: the right sign
    side = np.where(res.q[fixed] <= r.lower[fixed] + 1e-9, 1.0, -1.0)
    assert np.all(-side * y[4:] >= -1e-9)  # and the limits' multipliers hold the joints in


def test_where_no_row_is_reached_it_is_the_bounded_minimum():
    r, path, index, q0, sc = setup()
    res = solve_ik_rows(r, path(0.0).p, index, [_ball_rows()], q0)
    ref = kr.solve_ik(r, path(0.0).p, index, q0=q0, bounds=True)
    assert res.converged and res.active == () and ball_distance(sc, res.q)[0] > CLEARANCE + 0.05
    assert np.abs(res.q - ref.q).max() <= 1e-9


def test_bad_input_is_named():
    r, path, index, q0, _ = setup()
    with pytest.raises(OptionError, match="performance index"):
        solve_ik_rows(r, path(0.0).p, None, [_ball_rows()], q0)
    with pytest.raises(OptionError, match="general-row"):
        solve_ik_rows(r, path(0.0).p, index, [JointLimits(r)], q0)
    with pytest.raises(OptionError, match="general-row"):
        solve_ik_rows(r, path(0.0).p, index, [], q0)


def test_a_point_held_at_the_clearance_is_on_the_constrained_optimum():
    """The planner's off_optimum measure (planning.follow.measure) on the held run: with the scene's rows the
    held points are z's constrained optimum (moved <= FOLLOW_TOL); without them the bounded solve moves them
    into the ball (the held stretch was reported off the optimum)."""
    r, path, index, _, sc = setup()
    held = run()
    active = np.array([bool(a) for a in held.meta["constraints"]["active"]])
    t, q = held.t[active][::4], held.q[active][::4]
    moved, ok, _ = measure(r, path, index, t, q, 0.5, [_ball_rows()])
    assert ok.all() and moved.max() <= FOLLOW_TOL
    moved, ok, _ = measure(r, path, index, t, q, 0.5)
    assert moved.min() > 1e-3
