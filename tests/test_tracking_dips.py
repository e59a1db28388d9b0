"""A clearance met and left inside one step (issue 27): the rows are checked inside the step, not only at its ends.

Named case ``panda_wrist_graze``: on ``panda_elbow_circle`` (test_tracking_limits), a sphere of radius 1 cm
placed so that the within-limits optimum's wrist (the origin of panda_link7) passes 0.1 mm inside it at the
middle of step 60 (t = 2.533 s) while both recorded ends of that step are 0.17 mm clear: the point moves 4.6 mm
in the step and the graze lasts 0.025 s of its 0.042 s. Before the rows were sampled inside the step the run
took it for the run without the sphere (no switch, every recorded point clear, the wrist through the sphere in
between). Bars: the issue's (1e-9 m, 1e-9 s, 1e-10 closure and tracking); the sphere's placement and the
bisection use the bounded joint-level IK to 1e-12.
"""

from __future__ import annotations

import functools

import numpy as np
from test_tracking_limits import bisected, case

import kinredund as kr

#: the step the wrist grazes the sphere in, the sphere's radius [m] and how deep the optimum goes into it [m]
STEP, RADIUS, DEPTH = 60, 0.01, 1e-4


def optimum_at(t, seed):
    """The within-limits optimum at t (bounded joint-level IK from ``seed``, to 1e-12)."""
    r, path, index, _ = case("panda_elbow_circle")
    res = kr.solve_ik(r, path(t).p, index, q0=seed, bounds=True, tol=1e-12)
    assert res.converged
    return res.q


@functools.cache
def setup():
    """(robot, path, index, q0, the free run, the sphere, the middle of the step)."""
    r, path, index, q0 = case("panda_elbow_circle")
    free = kr.track(r, path, index, q0, loops=1)
    t_mid = free.t[STEP] + 0.5 * free.meta["dt"]
    probe = kr.SphereClearance(r, "panda_link7", [0.0, 0.0, 0.0], 1.0)
    p = probe.point(optimum_at(t_mid, free.q[STEP]))
    move = probe.point(free.q[STEP + 1]) - probe.point(free.q[STEP])
    side = np.cross(move, [0.0, 0.0, 1.0])
    centre = p + (RADIUS - DEPTH) * side / np.linalg.norm(side)  # the wrist DEPTH inside at t_mid
    return r, path, index, q0, free, kr.SphereClearance(r, "panda_link7", centre, RADIUS), t_mid


def test_the_graze_is_inside_one_step():
    r, path, index, q0, free, sphere, t_mid = setup()
    ends = [sphere.values(free.q[k])[0] for k in (STEP, STEP + 1)]
    assert min(ends) > 1e-4  # both recorded ends of the step clear
    assert abs(sphere.values(optimum_at(t_mid, free.q[STEP]))[0] + DEPTH) <= 1e-12  # inside in between
    assert min(sphere.values(q)[0] for q in free.q) > 1e-4  # and every recorded point of the loop clear


def test_the_graze_is_met_and_left_inside_the_step():
    r, path, index, q0, free, sphere, t_mid = setup()
    tr = kr.track(r, path, index, q0, constraints=[sphere])
    sw = [w for w in tr.meta["switches"] if w.get("constraint")]
    assert [w["kind"] for w in sw] == ["reach", "release"]
    assert free.t[STEP] < sw[0]["t"] < t_mid < sw[1]["t"] < free.t[STEP + 1]
    assert min(sphere.values(np.array(w["q"]))[0] for w in sw) >= -1e-9
    assert min(sphere.values(q)[0] for q in tr.q) >= -1e-9
    assert tr.loop_drift.max() <= 1e-10 and tr.position_error.max() <= 1e-10
    for w, lo, hi in ((sw[0], free.t[STEP], t_mid), (sw[1], t_mid, free.t[STEP + 1])):
        seed = np.array(w["q"])

        def margin(t, seed=seed):
            return float(sphere.values(optimum_at(t, seed))[0])

        assert abs(bisected(margin, lo, hi) - w["t"]) <= 1e-9  # one crossing on each side of the middle


def test_segment_lower_bounds_hold_along_the_segment():
    """The bounds that spare the sampling (Constraint.segment_lower_bounds) are lower bounds: on random short
    straight joint moves, every one of 11 points along the segment keeps each row above its bound."""
    from test_tracking_scene import setup as scene_setup

    r, sc = scene_setup()[0], scene_setup()[4]
    cs = [kr.SphereClearance(r, "panda_link7", [0.3, 0.1, 0.5], 0.05),
          kr.PlaneClearance(r, "panda_link4", [0, 0, 0.2], [0, 0, 1]),
          kr.SceneClearance(sc, self_clearance=0.01)]
    rng = np.random.default_rng(5)
    for _ in range(10):
        q0 = rng.uniform(r.lower + 0.2, r.upper - 0.2)
        q1 = q0 + rng.uniform(-0.05, 0.05, 7)
        for c in cs:
            c0, c1 = (sc.distances(x).distance - c.clearances if c is cs[2] else c.values(x) for x in (q0, q1))
            bound = c.segment_lower_bounds(q0, q1, c0, c1, np.abs(q1 - q0))
            along = np.array([sc.distances(q0 + s * (q1 - q0)).distance - c.clearances if c is cs[2] else
                              c.values(q0 + s * (q1 - q0)) for s in np.linspace(0.0, 1.0, 11)])
            assert np.all(along >= bound - 1e-12)
