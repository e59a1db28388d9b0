"""The robot's own pairs held apart in the tracker (issue 27): a self pair active, held, released, closed.

Named case ``panda_hand_to_upper_arm``: a 7 cm circle at 0.1 m/s on the Panda (position task, z = 1/2 ||q -
q_home||^2), from a seeded search of random reachable circles (seed 1, draw 29 of
``benchmarks/random_obstacles.py``'s kind of circle). The within-limits optimum brings the left finger's hull to
4.9 mm of panda_link2's (the upper arm), 1 cm under the self clearance of 1.5 cm held here, over two stretches of
the loop. Held, the pair (panda_link2_0, panda_leftfinger_3) is met and left twice a loop (a vertex of one hull
against a face of the other: a smooth distance), and the run closes.

Bars: the issue's (1e-9 m clearance, 1e-10 closure and tracking, 1e-9 first-order conditions, checked afresh:
distances from coal over every checked pair, gradients from the scene), 1e-12 against the run without a scene
where no row is active (it takes the same steps). Where a self pair's hulls press flat faces together the
distance is not differentiable and one row per pair cannot hold it: test_tracking_scene's
``test_the_hand_into_the_upper_arm_is_held_then_stops_named`` checks that stop's message.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from test_tracking_clearance import kkt_check
from test_tracking_limits import bisected, circle_case
from test_tracking_scene import _Row, lone_switches

import kinredund as kr

#: the circle's configuration at t = 0 (before the bounded IK), plane normal, x axis and radius [m]
HAND = ([-0.5155, -0.4727, 2.4727, -2.4618, 0.5934, 0.3018, -2.1293], [-0.3847, -0.8749, 0.2942],
        [-0.6266, 0.0135, -0.7792], 0.07)
SELF_CLEARANCE = 0.015
PAIR = ("panda_link2_0", "panda_leftfinger_3")


@functools.cache
def setup():
    r, path, index, q0 = circle_case("panda", *HAND)
    return r, path, index, q0, kr.Scene(r)


@functools.cache
def run(loops=1, with_scene=True):
    r, path, index, q0, sc = setup()
    if not with_scene:
        return kr.track(r, path, index, q0, loops=loops)
    return kr.track(r, path, index, q0, loops=loops, scene=sc, self_clearance=SELF_CLEARANCE)


def least_distance(sc, qs) -> np.ndarray:
    """The least distance [m] over every pair the scene checks (here: the robot's own), afresh from coal."""
    return np.array([sc.min_distance(q) for q in np.atleast_2d(qs)])


def test_the_free_optimum_brings_the_hand_under_the_self_clearance():
    sc = setup()[4]
    free = run(with_scene=False)
    d = least_distance(sc, free.q)
    assert d[0] > SELF_CLEARANCE and d.min() < SELF_CLEARANCE - 0.009  # 1 cm under it
    assert sc.closest(free.q[int(np.argmin(d))])[0] == PAIR  # the hand at the upper arm


def check_held(tr, sc) -> None:
    assert least_distance(sc, tr.q).min() >= SELF_CLEARANCE - 1e-9  # every recorded point
    sw = [w for w in tr.meta["switches"] if w.get("constraint")]
    assert [w["kind"] for w in sw[:2]] == ["reach", "release"] and all(" and ".join(PAIR) in w["name"] for w in sw)
    assert least_distance(sc, np.array([w["q"] for w in sw])).min() >= SELF_CLEARANCE - 1e-9  # switching times
    assert tr.loop_drift.max() <= 1e-10 and tr.position_error.max() <= 1e-10


def test_the_hand_is_held_off_the_upper_arm():
    sc = setup()[4]
    tr, free = run(), run(with_scene=False)
    check_held(tr, sc)
    active = np.array([bool(a) for a in tr.meta["constraints"]["active"]])
    assert 10 < active.sum() < len(active) - 10
    assert np.abs(tr.q[~active] - free.q[~active]).max() <= 1e-12  # no row active: the run without a scene
    assert np.abs(tr.q[active] - free.q[active]).max() > 1e-3  # and where one is, the hand is held off


def test_first_order_conditions_with_the_self_row_hold_independently():
    r, path, index, q0, sc = setup()
    c = kr.SceneClearance(sc, self_clearance=SELF_CLEARANCE)
    worst, seen = kkt_check(r, index, run(), [_Row(c, i) for i in range(c.size)])
    assert seen > 10 and worst <= 1e-9


def test_switching_times_agree_with_bisection():
    """The pair is met where the within-limits optimum's distance crosses the self clearance and left where
    the held one's multiplier reaches zero, which is the same crossing: bisection on the bounded joint-level
    IK's optimum (to 1e-12) and coal's distance of the pair, independent of the tracker's Brent search, to
    1e-9 s."""
    r, path, index, _, sc = setup()
    tr = run()
    dt = tr.meta["dt"]
    lone = lone_switches(tr.meta["switches"])
    assert [w["kind"] for w in lone] == ["reach", "release"]
    for w in lone:
        seed = np.array(w["q"])

        def margin(t, seed=seed):
            res = kr.solve_ik(r, path(t).p, index, q0=seed, bounds=True, tol=1e-12)
            assert res.converged
            return float(sc.distances(res.q).as_dict()[PAIR]) - SELF_CLEARANCE

        assert abs(bisected(margin, w["t"] - 0.5 * dt, w["t"] + 0.5 * dt) - w["t"]) <= 1e-9


@pytest.mark.slow
def test_the_hand_is_held_off_the_upper_arm_for_ten_loops():
    tr = run(loops=10)
    check_held(tr, setup()[4])
    assert len(tr.meta["switches"]) >= 20  # met and left twice a loop, every loop


#: a configuration on panda_elbow_circle (test_tracking_limits) held 1 cm off itself, t = 7.0005 s: the right
#: finger's pad nearly parallel to a face of panda_link2's hull, 5e-5 rad of panda_joint5 away
FLAT = [-0.01994029663574623, -1.2783499392666005, -0.008817396621063784, -2.7509588622806014,
        -0.008070431052483989, 0.7506452478897205, 0.7807029903059824]


def test_a_jump_of_the_witness_points_is_found():
    """Two hulls' faces come parallel: the pair's witness points jump (1.5 cm across joint 5's next 1e-4 rad),
    the distance is not differentiable there, and ``discontinuities`` says so, naming the corner: the two ends of
    the finger box's edge (vertices 5 and 7) whose distances to the link's hull are the distance's two pieces there
    (tests/test_geometry_polytopes.py checks them); along joint 7 (smooth there) and for the other finger's pair
    (a vertex on a face) it says nothing."""
    r = kr.load_robot("panda", task="position")
    c = kr.SceneClearance(kr.Scene(r), self_clearance=0.01)
    q, e = np.array(FLAT), np.eye(7)
    flat = c.pairs.index(("panda_link2_0", "panda_rightfinger_3"))
    notes = c.discontinuities(q, 1e-4 * e[4], [flat])
    assert len(notes) == 1 and "panda_link2_0 and panda_rightfinger_3 is not differentiable" in notes[0]
    jump = float(notes[0].split("jump by ")[1].split(" m")[0])
    assert 0.01 < jump < 0.02
    assert "the least there of the distances of panda_rightfinger_3's vertices 5 and 7 to panda_link2_0" in notes[0]
    assert c.discontinuities(q, 1e-4 * e[6], [flat]) == []
    assert c.discontinuities(q, 1e-4 * e[4], [c.pairs.index(("panda_link1_0", "panda_leftfinger_3"))]) == []
    assert kr.SphereClearance(r, "panda_link7", [0, 0, 0], 0.1).discontinuities(q, e[4], [0]) == []  # the default


@pytest.mark.slow
def test_a_plan_holds_the_hand_off_the_upper_arm_on_the_optimum():
    """``plan(..., scene=, self_clearance=)`` on the named case: the candidates where the free minimum is under
    the self clearance are the minima that keep it (the bounded IK with the distance rows), the motion holds the
    pair at the clearance over part of each loop, and that stretch is not off the optimum (off_optimum is
    empty; measured without the rows it was ((1.21, 2.00),))."""
    r, path, index, q0, sc = setup()
    res = kr.plan(r, path, index, scene=sc, self_clearance=SELF_CLEARANCE, samples=12, starts=4, loops=2)
    assert res.ok, res.reason
    tr = res.trajectory
    active = np.array([bool(a) for a in tr.meta["constraints"]["active"]])
    assert active.sum() > 20 and least_distance(sc, tr.q).min() >= SELF_CLEARANCE - 1e-9
    assert min(least_distance(sc, c).min() for c in res.samples.candidates) >= SELF_CLEARANCE - 1e-9
    assert res.off_optimum == ()
