"""A Scene's distances held in the tracker (issue 27): SceneClearance rows, track(..., scene=, clearance=).

Named cases, each a circle whose within-limits optimum runs into a sphere put through the Scene:

- ``panda_elbow_ball``: the circle ``panda_elbow_circle`` of test_tracking_limits with a 5 cm sphere where the
  optimum's upper arm (panda_link3's hull, at the elbow) passes: the free optimum runs 5 mm into it (2.5 cm
  under the 2 cm clearance) over part of the loop; held, one row is met and left;
- ``xarm7_elbow_ball``: a 9.85 cm circle on the xArm7 (a draw of benchmarks/random_obstacles.py, seed 5, the
  sphere of radius 5.78 cm where the optimum's elbow passes): the free optimum runs 10 cm into it; held,
  link3's row is met, then link4's, then link3's is left and link4's (two rows active together for 0.004 s).

Distances are checked afresh with coal (``scene.distances``) on the recorded configurations. Tolerances: the
corrector holds the active row to ~1e-12 (its tol); the bars are the issue's (1e-9 m clearance, 1e-10 closure
and tracking, 1e-12 for the run without an active distance before the first switch, which takes the same
steps as the run without a scene; after a release the two runs converge onto one optimum each by its own
corrector, to 1e-10).
"""

from __future__ import annotations

import functools
import json
import re

import numpy as np
import pinocchio as pin
import pytest
from test_tracking_limits import bisected, case, circle_case

import kinredund as kr
from kinredund.errors import OptionError, TrackingError
from kinredund.kinematics.state import point_curvature

#: the sphere's center [m] and radius [m], and the clearance [m] of the named case
BALL = ([-0.3178, 0.2255, 0.3518], 0.05)
CLEARANCE = 0.02
#: per named case: the circle (test_tracking_limits.circle_case's arguments) and the ball (center [m], radius [m])
CASES = {"panda_elbow_ball": (None, BALL),
         "xarm7_elbow_ball": (("xarm7", [0.965, -0.5709, 1.1913, 0.8711, 0.0753, 0.886, 0.0],
                               [-0.2809, -0.9058, 0.3172], [0.9065, -0.359, -0.2224], 0.0985),
                              ([-0.253, -0.0502, 0.3989], 0.0578))}


@functools.cache
def setup(name="panda_elbow_ball"):
    circle, (center, radius) = CASES[name]
    r, path, index, q0 = case("panda_elbow_circle") if circle is None else circle_case(*circle)
    sc = kr.Scene(r)
    sc.add_sphere("ball", radius, center)
    return r, path, index, q0, sc


@functools.cache
def run(loops=1, with_scene=True, name="panda_elbow_ball"):
    r, path, index, q0, sc = setup(name)
    if not with_scene:
        return kr.track(r, path, index, q0, loops=loops)
    return kr.track(r, path, index, q0, loops=loops, scene=sc, clearance=CLEARANCE, self_clearance=False)


def ball_distance(sc, qs) -> np.ndarray:
    """The least distance [m] of the ball from the robot at each q, afresh from coal."""
    return np.array([min(v for p, v in sc.distances(q).as_dict().items() if "ball" in p) for q in np.atleast_2d(qs)])


def test_point_curvature_against_differences():
    """sum c^T Hess p of a point fixed to a link (the kinematics layer's point Hessian) vs central differences."""
    r = setup()[0]
    m, rng = r.model, np.random.default_rng(3)
    q = 0.5 * (r.lower + r.upper) + 0.3 * rng.standard_normal(7)
    for j in (2, 4, 7):
        loc, c = rng.standard_normal(3) * 0.1, rng.standard_normal(3)

        def f(x, j=j, loc=loc, c=c):
            d = m.createData()
            pin.forwardKinematics(m, d, x)
            return c @ d.oMi[j].act(loc)

        e, n = 1e-4, len(q)
        E = np.eye(n) * e
        H = np.array([[(f(q + E[a] + E[b]) - f(q + E[a] - E[b]) - f(q - E[a] + E[b]) + f(q - E[a] - E[b]))
                       / (4 * e * e) for b in range(n)] for a in range(n)])
        d = m.createData()
        pin.forwardKinematics(m, d, q)
        p = d.oMi[j].act(loc)
        pin.computeJointJacobians(m, d, q)
        assert np.abs(point_curvature(m, d, np.array([j]), p[None], c[None]) - H).max() <= 1e-7  # O(e^2)


def test_rows_are_the_scene_pairs_and_far_pairs_a_lower_bound():
    r, path, index, q0, sc = setup()
    c = kr.SceneClearance(sc, clearance=CLEARANCE, self_clearance=0.01)
    assert c.size == len(sc.pairs) and c.pairs == sc.pairs  # one row per checked pair, in the scene's order
    rows = sc.distance_rows(q0, c.influence)
    vals, G = c.rows_at(q0)
    for k, pair in enumerate(rows.pairs):
        i = sc.pairs.index(pair)
        own = "ball" not in pair
        assert vals[i] == pytest.approx(rows.d[k] - (0.01 if own else CLEARANCE), abs=1e-15)
        assert np.allclose(G[i], rows.G[k], rtol=0, atol=1e-15)
    far = [i for i, p in enumerate(sc.pairs) if p not in rows.pairs]
    assert far and np.all(sc.distances(q0).distance[far] > c.influence)  # the bound holds
    assert np.all(vals[far] == c.influence - c.clearances[far]) and not G[far].any()
    assert "ball" in c.names()[sc.pairs.index(("panda_link3_0", "ball"))]


def test_witness_curvature_is_the_scene_s():
    r, path, index, q0, sc = setup()
    c = kr.SceneClearance(sc, self_clearance=None, curvature="witness")
    rows = sc.distance_rows(q0, c.influence)
    k = rows.pairs.index(("panda_link3_0", "ball"))
    w = np.zeros(len(rows.pairs))
    w[k] = 2.0
    i = c.pairs.index(("panda_link3_0", "ball"))
    assert np.allclose(c.curvature(q0, np.array([2.0]), np.array([i])), sc.distance_curvature(q0, rows, w),
                       rtol=0, atol=1e-14)


@pytest.mark.parametrize("name", CASES)
def test_the_free_optimum_runs_under_the_clearance(name):
    d = ball_distance(setup(name)[4], run(with_scene=False, name=name).q)
    assert d[0] > CLEARANCE + 0.03 and d.min() < -0.004  # the named case is what it claims: into the ball


@pytest.mark.parametrize("name", CASES)
def test_clearance_held_and_equal_to_the_free_run_where_inactive(name):
    sc = setup(name)[4]
    tr, free = run(name=name), run(with_scene=False, name=name)
    d = ball_distance(sc, tr.q)
    assert d.min() >= CLEARANCE - 1e-9  # every recorded point, afresh with coal
    sw = [w for w in tr.meta["switches"] if w.get("constraint")]
    assert {w["kind"] for w in sw} == {"reach", "release"} and all("ball" in w["name"] for w in sw)
    assert ball_distance(sc, np.array([w["q"] for w in sw])).min() >= CLEARANCE - 1e-9  # at the switching times
    active = np.array([bool(a) for a in tr.meta["constraints"]["active"]])
    assert 10 < active.sum() < len(active) - 10
    before = tr.t < sw[0]["t"]
    assert before.sum() > 10 and np.abs(tr.q[before] - free.q[before]).max() <= 1e-12  # the same steps
    assert np.abs(tr.q[~active] - free.q[~active]).max() <= 1e-10  # no distance active: the run without a scene
    assert np.abs(tr.q[active] - free.q[active]).max() > 0.01  # and where one is, the arm is pushed out
    assert tr.position_error.max() <= 1e-10 and tr.loop_drift.max() <= 1e-10


@pytest.mark.slow
@pytest.mark.parametrize("name", CASES)
def test_clearance_held_and_closed_after_ten_loops(name):
    sc = setup(name)[4]
    tr = run(loops=10, name=name)
    assert ball_distance(sc, tr.q).min() >= CLEARANCE - 1e-9
    assert tr.loop_drift.max() <= 1e-10 and tr.position_error.max() <= 1e-10


def test_a_start_under_the_clearance_is_refused():
    r, path, index, q0, _ = setup()
    sc = kr.Scene(r)
    sc.add_sphere("ball", 0.05, sc.object_pose("panda_link4_0", q0)[:3, 3])  # in contact at the start
    with pytest.raises(TrackingError, match=r"panda_link4_0 and ball kept 0.02 m apart by") as err:
        kr.track(r, path, index, q0, scene=sc, self_clearance=False)
    assert err.value.cause == "collision"
    sc.move("ball", [0.0, 0.0, 2.0])  # clear, but under a clearance larger than its distance
    d = ball_distance(sc, q0)[0]
    with pytest.raises(TrackingError, match=r"ball kept .* apart by") as err:
        kr.Tracker(r, path, index, q0, 0.01, scene=sc, clearance=d + 0.01, self_clearance=False)
    assert err.value.cause == "collision" and "0.01" in str(err.value)


def test_a_start_under_the_self_clearance_says_what_lets_it_start():
    """A self pair under self_clearance at the start: the refusal names it and by how much, and, as it may be that
    close wherever the arm goes (baxter's coaxial covers stay 5 mm apart; the default pair matrix leaves out only
    pairs in contact), says what lets the run start: a smaller self_clearance, or the pair left out (scene.ignore),
    which then starts. An obstacle's pair gets no such words."""
    r, path, index, q0, _ = setup()
    sc = kr.Scene(r)
    ks, d = sc.pair_distances(q0, influence=1.0)  # (the robot's own pairs alone: no object added)
    own = {sc.pairs[k]: x for k, x in zip(ks.tolist(), d.tolist(), strict=True)}
    (a, b), closest = min(own.items(), key=lambda x: x[1])
    with pytest.raises(TrackingError, match=re.escape(f"{a} and {b} kept {closest + 0.01:.4g} m apart by")) as err:
        kr.Tracker(r, path, index, q0, 0.01, scene=sc, self_clearance=closest + 0.01)
    said = str(err.value)
    assert f"give a smaller self_clearance (now {closest + 0.01:g} m)" in said and "scene.ignore(" in said
    others = [p for p, x in own.items() if x < closest + 0.01]
    for p in others:
        sc.ignore(*p)
    kr.Tracker(r, path, index, q0, 0.01, scene=sc, self_clearance=closest + 0.01)  # left out: it starts
    sc.add_sphere("ball", 0.05, sc.object_pose("panda_link4_0", q0)[:3, 3])
    with pytest.raises(TrackingError, match="panda_link4_0 and ball kept 0.02 m apart by") as err:
        kr.Tracker(r, path, index, q0, 0.01, scene=sc, self_clearance=False)
    assert "self_clearance" not in str(err.value)


def test_options_are_checked():
    r, path, index, q0, sc = setup()
    with pytest.raises(OptionError, match="need scene="):
        kr.track(r, path, index, q0, clearance=0.02)
    with pytest.raises(OptionError, match="clearance"):
        kr.SceneClearance(sc, clearance=-0.01)
    with pytest.raises(OptionError, match="influence"):
        kr.SceneClearance(sc, clearance=0.05, influence=0.03)
    c = kr.SceneClearance(sc, self_clearance=None)
    sc2 = kr.Scene(r)
    c2 = kr.SceneClearance(sc2)
    sc2.add_sphere("late", 0.05, [2.0, 0.0, 0.0])
    with pytest.raises(OptionError, match="changed"):
        c2.values(q0)
    assert c.size == sum("ball" in p for p in sc.pairs)


@pytest.mark.slow
def test_the_hand_into_the_upper_arm_is_held_then_stops_named():
    """Self-collision: on ``panda_elbow_circle`` the free optimum brings the fingers into the upper arm
    (panda_link1/2's hulls, to -5 mm). Held 1 cm apart, the two fingers press on link1 and link2 at once from
    t = 6.12 s; at t = 7.0005 s the right finger's pad comes parallel to a face of link2's hull, where the pair's
    witness points jump 1.2-1.5 cm (within 5e-5 rad of joint 5): the distance is not differentiable, the optimum
    presses on that corner, which one row per pair cannot hold (the corrector does not converge there; past it
    the rates run to 10 rad/s, sigma_min([J; G_A]) 0.04 -> 0.018). The run stops, cause ``collision`` naming
    the pairs and the jump, at a last good configuration that is clear, with a partial record that kept 1 cm
    at every point. (test_tracking_self_clearance holds a self pair that stays smooth.)"""
    r, path, index, q0, _ = setup()
    sc = kr.Scene(r)
    free = ball_distance_self(sc, run(with_scene=False).q)
    assert free.min() < 0.0  # the free optimum collides with itself
    with pytest.raises(TrackingError) as err:
        kr.track(r, path, index, q0, scene=sc)
    e = err.value
    assert e.cause == "collision" and 0 < e.t < path.period
    assert any("finger" in n and "panda_link" in n for n in e.watched["constraints"])
    assert "panda_link2_0 and panda_rightfinger_3 is not differentiable" in str(e) and e.watched["nonsmooth"]
    assert "panda_rightfinger_3's vertices" in str(e)  # the corner named: the ends of the finger box's edge
    assert ball_distance_self(sc, e.q)[0] >= 0.01 - 1e-9
    part = e.partial
    assert len(part.t) > 100 and ball_distance_self(sc, part.q).min() >= 0.01 - 1e-9
    assert any(part.meta["constraints"]["active"])  # held over part of the way before the stop


def ball_distance_self(sc, qs) -> np.ndarray:
    """The least distance [m] between two of the robot's objects at each q, afresh from coal."""
    return np.array([sc.distances(q).min_distance for q in np.atleast_2d(qs)])


def test_cli_track_with_a_scene(tmp_path, capsys):
    from kinredund.ui.cli import EXIT_USAGE, main

    r = kr.load_robot("panda")
    sc = kr.Scene(r)
    sc.add_sphere("ball", 0.05, r.fk(r.home)[:3, 3])  # where the circle starts: the hand in it
    f = kr.geometry.save_scene(sc, tmp_path / "scene.json")
    assert main(["track", "panda", "--steps", "20", "--scene", str(f), "--quiet"]) != 0
    assert "and ball kept 0.02 m apart by" in capsys.readouterr().err
    sc.move("ball", [0.0, 0.6, 1.2])  # out of the way: held with the self pairs, recorded
    f = kr.geometry.save_scene(sc, tmp_path / "scene.json")
    js = tmp_path / "t.json"
    assert main(["track", "panda", "--steps", "20", "--scene", str(f), "--clearance", "0.03",
                 "--self-clearance", "off", "--json", str(js), "--quiet"]) == 0
    names = json.loads(js.read_text())["meta"]["constraints"]["names"]
    assert names and all("ball kept 0.03 m apart" in n for n in names)  # no self pairs
    assert main(["track", "panda", "--clearance", "0.03", "--quiet"]) == EXIT_USAGE


def test_skipped_queries_give_lower_bounds():
    """Between exact queries the values are the last exact ones lowered by B.|dq| (Scene.motion_bound):
    never above the exact c, and every distance change of random joint moves stays within that bound."""
    r, path, index, q0, sc = setup()
    B = sc.motion_bound()
    assert B.shape == (len(sc.pairs), 7) and np.all(B < 3.0) and np.all(B.sum(axis=1) > 0)  # the Panda's reach
    rng = np.random.default_rng(7)
    for _ in range(20):
        q1 = q0 + rng.uniform(-0.3, 0.3, 7)
        q2 = q1 + rng.uniform(-0.05, 0.05, 7)
        d1, d2 = sc.distances(q1).distance, sc.distances(q2).distance
        assert np.all(np.abs(d2 - d1) <= B @ np.abs(q2 - q1) + 1e-12)
    c = kr.SceneClearance(sc, self_clearance=0.01)
    c.values(q0)  # exact here
    skipped = 0
    for k in range(1, 30):
        q = q0 + 1e-3 * k * np.sin(np.arange(7) + k)
        lower, true = c.values(q), sc.distances(q).distance - c.clearances  # every pair exactly
        assert np.all(lower <= true + 1e-12)
        skipped += not np.array_equal(lower, true)
    assert skipped > 5


def test_gradient_against_differences():
    """G of the ball's row against central differences of its value (step 1e-6: O(1e-12) error), where the
    free optimum is closest to the ball."""
    sc = setup()[4]
    free = run(with_scene=False)
    q = free.q[int(np.argmin(ball_distance(sc, free.q)))]
    c = kr.SceneClearance(sc, self_clearance=None)
    i = c.pairs.index(("panda_link3_0", "ball"))
    E = np.eye(7) * 1e-6
    fd = np.array([(c.rows_at(q + e)[0][i] - c.rows_at(q - e)[0][i]) / 2e-6 for e in E])
    assert np.abs(c.gradients(q)[i] - fd).max() <= 1e-8


class _Row:
    """Row i of a constraint as a one-row constraint (for test_tracking_clearance's kkt_check)."""

    def __init__(self, c, i):
        self.c, self.i = c, i

    def gradients(self, q):
        return self.c.gradients(q)[self.i: self.i + 1]


@pytest.mark.parametrize("name", CASES)
def test_first_order_conditions_with_the_ball_row_hold_independently(name):
    """At every point grad z vanishes on the null space of [J; G_active; e_fixed] (an SVD basis, G afresh from
    the scene), and the least-squares multipliers of the active rows and bounds have the right sign."""
    from test_tracking_clearance import kkt_check

    r, path, index, q0, sc = setup(name)
    c = kr.SceneClearance(sc, self_clearance=None)
    worst, seen = kkt_check(r, index, run(name=name), [_Row(c, i) for i in range(c.size)])
    assert seen > 10 and worst <= 1e-9


def lone_switches(switches) -> list[dict]:
    """The row switches between no active row and one (the free within-limits optimum on one side)."""
    active, out = set(), []
    for w in (w for w in switches if w.get("constraint")):
        after = active | {w["row"]} if w["kind"] == "reach" else active - {w["row"]}
        if (active | after) == {w["row"]}:
            out.append(w)
        active = after
    return out


@pytest.mark.parametrize("name", CASES)
def test_switching_times_agree_with_bisection(name):
    """A row met from, or left to, no active row is switched where the within-limits optimum's distance of its
    pair crosses the clearance (nu = 0 there): bisection on it, the optimum from the bounded joint-level IK (to
    1e-12: ~1e-10 s at the ~0.01 m/s the distance changes) and the distance from coal, independent of the
    tracker's Brent search, to 1e-9 s."""
    r, path, index, _, sc = setup(name)
    tr = run(name=name)
    dt = tr.meta["dt"]
    lone = lone_switches(tr.meta["switches"])
    assert [w["kind"] for w in lone] == ["reach", "release"]
    for w in lone:
        pair, seed = tuple(w["name"].split(" kept")[0].split(" and ")), np.array(w["q"])

        def margin(t, seed=seed, pair=pair):
            res = kr.solve_ik(r, path(t).p, index, q0=seed, bounds=True, tol=1e-12)
            assert res.converged
            return float(sc.distances(res.q).as_dict()[pair]) - CLEARANCE

        assert abs(bisected(margin, w["t"] - 0.5 * dt, w["t"] + 0.5 * dt) - w["t"]) <= 1e-9


def test_a_scene_of_another_robot_with_the_same_joint_names_is_refused():
    """Two HD-table arms share the joint names joint_1 ... joint_3: a scene of the one held the other's
    clearances with the wrong links' distances (only the names were compared)."""
    from kinredund.kinematics.hd import HDTable
    from kinredund.model.robot import robot_from_hd
    from kinredund.tracking.tracker import scene_constraints

    planar = kr.load_robot("planar3r")
    other = robot_from_hd(HDTable(np.zeros(3), [0.5, 0.6, 0.3], np.zeros(3)), task="planar")
    assert other.joint_names == planar.joint_names
    with pytest.raises(OptionError, match="placements"):
        scene_constraints(planar, kr.Scene(other), None, False)
    assert len(scene_constraints(planar, kr.Scene(kr.load_robot("planar3r")), 0.02, None)) == 1


@pytest.mark.parametrize("other", ["xarm7", "ur5"])
def test_a_scene_clearance_of_another_robot_is_refused_as_a_constraint_too(other):
    """scene= of another robot was refused, but the same scene's SceneClearance given in constraints= was not: the
    Panda run evaluated the xarm7's collision model at the Panda's joints and returned a record with no error. Both
    are refused by the one check (tracker.check_robot_of), naming the scene's joints; the tracked robot's own
    scene, made of the robot loaded again, is taken."""
    r, path, index, q0 = case("panda_elbow_circle")
    o = kr.load_robot(other)
    sc = kr.Scene(o)
    sc.add_sphere("far", 0.1, [2.0, 2.0, 2.0])  # [m]: far from both arms
    words = f"is of a robot with joints .*{o.joint_names[0]}.* not the tracked .*panda_joint1"
    with pytest.raises(OptionError, match=f"the scene {words}"):
        kr.track(r, path, index, q0, loops=1, steps_per_loop=20, scene=sc, self_clearance=False)
    for c in (kr.SceneClearance(sc, self_clearance=None), kr.CornerClearance(sc, self_clearance=None)):
        with pytest.raises(OptionError, match=f"the constraint .* {words}"):
            kr.track(r, path, index, q0, loops=1, steps_per_loop=20, constraints=[c])
    own = kr.Scene(kr.load_robot(r.name))
    own.add_sphere("far", 0.1, [2.0, 2.0, 2.0])
    traj = kr.track(r, path, index, q0, loops=1, steps_per_loop=20,
                    constraints=[kr.SceneClearance(own, self_clearance=None)])
    assert traj.q.shape == (21, r.nq)
