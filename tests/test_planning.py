"""Chapter 6: obstacles and clearance against brute force, the planar case's impossibility, the JSON."""

from __future__ import annotations

import itertools
import json

import numpy as np
import pytest
from conftest import robot, rounding
from hypothesis import given, settings
from hypothesis import strategies as st

from kinredund import ChoiceError, TaskError
from kinredund.kinematics.angles import wrap_joints
from kinredund.paths import Ellipse
from kinredund.planning.branches import PENETRATION_PENALTY, candidates, clearance_of, entries, transition
from kinredund.planning.clearance import link_model, verify_motion
from kinredund.planning.obstacles import EllipseObstacle, EllipticCylinder
from kinredund.planning.planner import default_policy
from kinredund.planning.selfmotion import routes, trace
from kinredund.planning.walk import choose
from kinredund.thesis.chapter4 import load_example, run_example
from kinredund.thesis.chapter6 import case_robot, planar_feasibility, planar_setup
from kinredund.ui.cli import EXIT_FAILED, main
from kinredund.ui.reproduce import plan_case


def _ellipse_points(ob, m=20000):
    s = np.linspace(0, 2 * np.pi, m, endpoint=False)
    p, _ = ob.boundary(s)
    return p


@settings(max_examples=30, deadline=None)
@given(a=st.floats(0.1, 2.0), ratio=st.floats(1.0, 5.0), angle=st.floats(-3.0, 3.0), seed=st.integers(0, 1000))
def test_ellipse_signed_distance_against_brute_force(a, ratio, angle, seed):
    ob = EllipseObstacle(center=(0.3, -0.2), a=a, b=a / ratio, angle=angle)
    rng = np.random.default_rng(seed)
    pts = ob.center[:2] + rng.uniform(-2.5 * a, 2.5 * a, size=(50, 2))
    m = 20000
    brute = np.min(np.linalg.norm(pts[:, None, :] - _ellipse_points(ob, m)[None], axis=2), axis=1)
    d = ob.ellipse_distance(pts)
    # the samples are points of the ellipse, so none is nearer than the exact distance; and the closest
    # point lies on an arc of length <= a 2 pi / m between two samples, within half of it of one of them
    assert np.all(np.abs(d) <= brute + 1e-12)
    assert np.all(brute - np.abs(d) <= np.pi * a / m)
    u, v = ob.local(pts)
    inside = (u / ob.a) ** 2 + (v / ob.b) ** 2 < 1
    assert np.all((d < 0) == inside)


def test_segment_and_cylinder_distances_against_dense_sampling():
    rng = np.random.default_rng(3)
    cyl = EllipticCylinder(center=(1.9, 0.0, 0.7), a=0.5, b=0.25, angle=0.3, height=1.4)
    flat = EllipseObstacle(center=(1.9, 0.0), a=0.5, b=0.25, angle=0.3)
    for ob in (cyl, flat):
        for _ in range(40):
            p0 = np.array([1.9, 0.0, 0.7]) + rng.uniform(-1.5, 1.5, 3)
            p1 = np.array([1.9, 0.0, 0.7]) + rng.uniform(-1.5, 1.5, 3)
            if ob is flat:
                p0[2] = p1[2] = 0.0
            s = np.linspace(0.0, 1.0, 4001)[:, None]
            dense = ob.signed_distance(p0 + s * (p1 - p0)).min()
            exact = ob.segment_distance(p0, p1)
            assert exact <= dense + 1e-9  # the minimum over the segment is below every sample
            assert exact >= dense - np.linalg.norm(p1 - p0) / 4000  # 1-Lipschitz: within a sample step
    # the cylinder's top and side: exact values at hand-made points
    assert cyl.signed_distance(np.array([1.9, 0.0, 1.9])) == pytest.approx(0.5)
    assert cyl.signed_distance(np.array([1.9 + 0.5 * np.cos(0.3) + 0.2 * np.cos(0.3), 0.5 * np.sin(0.3)
                                         + 0.2 * np.sin(0.3), 0.7])) == pytest.approx(0.2, abs=1e-9)


def test_bad_obstacles():
    with pytest.raises(TaskError, match="semi-axis a"):
        EllipseObstacle(center=(0, 0), a=-1.0, b=0.5)
    with pytest.raises(TaskError, match="center"):
        EllipseObstacle(center=(0, np.nan), a=1.0, b=0.5)


@settings(max_examples=25, deadline=None)
@given(a=st.floats(0.05, 0.6), ratio=st.floats(1.0, 4.0))
def test_section_6_2_policy_is_out_of_reach_for_any_semi_axes(a, ratio):
    """Joint 3 at P + l3 n lies beyond l1 + l2 on the far side of an obstacle centred 0.9 m away."""
    r, _, _ = planar_setup()
    ob = EllipseObstacle(center=(0.9, 0.0), a=a, b=a / ratio, angle=np.radians(20))
    path = Ellipse((0.9, 0.0), a, a / ratio, angle=np.radians(20))
    check = planar_feasibility(r, path, ob)
    assert not check["reachable"]
    assert check["wrist_reach_needed"] >= 0.9 + 0.3 - 1e-6 > check["wrist_reach_available"] == pytest.approx(1.1)


def test_a_closed_planar_loop_around_a_convex_obstacle_sweeps_over_it():
    """The topological fact behind Section 6.2: Example 4.1's cyclic joint path around its circle crosses
    the disc (any closed planar motion whose end point circles an obstacle does)."""
    ex = load_example("4.1")
    tr = run_example(ex, loops=1)
    disc = EllipseObstacle(center=(3.0, 3.0), a=0.8, b=0.8)
    report = verify_motion(robot("planar3r"), disc, tr.t, tr.q, substeps=4)
    assert tr.loop_drift[0] < 1e-8
    assert report.minimum.min() < -0.1  # some link passes deep inside
    # and the same check finds clearance when the obstacle is moved away from the arm's sweep
    far = EllipseObstacle(center=(-3.0, -3.0), a=0.5, b=0.5)
    assert verify_motion(robot("planar3r"), far, tr.t, tr.q, substeps=4).minimum.min() > 1.0


def test_reproduce_6_2_reports_the_failure_with_its_reason(tmp_path):
    js, png = tmp_path / "p.json", tmp_path / "p.png"
    result = plan_case("6.2", json_path=js, plot_path=png)
    assert not result.ok and "beyond" in result.reason and "sweep" in result.reason
    data = json.loads(js.read_text())
    for key in ("t", "q", "q_spline", "samples", "clearance_min", "links", "obstacle", "ok", "reason"):
        assert key in data
    assert data["links"] == [0.5, 0.6, 0.3] and data["ok"] is False
    ob = data["obstacle"]
    assert ob["center"][:2] == [0.9, 0.0] and ob["a"] == 2 * ob["b"] and ob["angle"] == pytest.approx(np.radians(20))
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_plan_command_exit_code_for_a_failed_plan(tmp_path, capsys):
    js = tmp_path / "p.json"
    assert main(["plan", "6.2", "--json", str(js)]) == EXIT_FAILED
    assert "plan failed" in capsys.readouterr().err
    assert json.loads(js.read_text())["ok"] is False


def test_doubling_check_shares_the_base_grid():
    """The report with the doubling check equals the one without, and its change is measured against an
    independent run at twice the resolution."""
    r = robot("planar3r_ch6")
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 2.0, 9)
    q = np.cumsum(rng.uniform(-0.4, 0.4, (9, 3)), axis=0)
    ob = EllipseObstacle(center=(0.9, 0.1), a=0.3, b=0.15, angle=0.35)
    both = verify_motion(r, ob, t, q, substeps=3, tool_tip=0.05)
    base = verify_motion(r, ob, t, q, substeps=3, tool_tip=0.05, check_doubling=False)
    fine = verify_motion(r, ob, t, q, substeps=6, tool_tip=0.05, check_doubling=False)
    assert base.doubling_change is None and both.t.size == base.t.size == 8 * 3 + 1
    # the same grid computed within another batch: equal up to rounding (BLAS may block a larger batch
    # differently), kind 1 of the tolerance policy in conftest.py
    for name in ("t", "clearance", "penetration", "minimum", "lower_bound", "motion_bound"):
        np.testing.assert_allclose(getattr(both, name), getattr(base, name), rtol=0, atol=rounding())
    np.testing.assert_allclose(both.doubling_change, np.abs(fine.minimum - base.minimum), rtol=0, atol=rounding())
    assert np.any(both.doubling_change > 0)
    with pytest.raises(TaskError, match="substeps"):
        verify_motion(r, ob, t, q, substeps=0)


def test_case_robot():
    r = case_robot("6.3")
    assert r.name == "cybotech_p15_x8" and r.hd.b[0] == pytest.approx(8 * 0.16)
    assert case_robot("6.2").hd.a.tolist() == [0.5, 0.6, 0.3]
    with pytest.raises(ChoiceError, match="6.2, 6.3"):
        case_robot("6.4")


def test_choose_takes_the_cheapest_cyclic_sequence():
    """Three samples with 2, 3 and 2 candidates: the cheapest loop (1, 2, 0) costs 0.5 + 0.5 + 0.2, though
    its first step is not the cheapest one from candidate 1 (that one leads to 2.2)."""
    costs = [np.array([[1.0, 5.0, 9.0], [0.0, 4.0, 0.5]]),
             np.array([[2.0, 7.0], [1.0, 1.0], [0.5, 8.0]]),
             np.array([[9.0, 0.2], [3.0, 6.0]])]  # the last one closes the loop back to the first sample
    assert choose(costs) == ([1, 2, 0], pytest.approx(1.2))
    # against enumeration, with forbidden (infinite) transitions
    rng = np.random.default_rng(11)
    for _ in range(20):
        sizes = rng.integers(1, 4, size=4)
        costs = [np.where(rng.random((sizes[k], sizes[(k + 1) % 4])) < 0.3, np.inf,
                          rng.random((sizes[k], sizes[(k + 1) % 4]))) for k in range(4)]
        totals = {seq: sum(costs[k][seq[k], seq[(k + 1) % 4]] for k in range(4))
                  for seq in itertools.product(*(range(s) for s in sizes))}
        best = min(totals.values())
        seq, total = choose(costs)
        if np.isfinite(best):
            assert total == pytest.approx(best) and totals[tuple(seq)] == pytest.approx(best)
        else:
            assert seq is None and total == np.inf
    assert choose([np.full((2, 2), np.inf)] * 3) == (None, np.inf)


def test_self_motion_of_the_planar_3r_keeps_the_end_point_and_follows_the_null_space():
    r = robot("planar3r_ch6")
    qa = np.array([0.3, 1.1, -0.8])
    target = r.kinematics.pose(qa)[1][:2]
    step = 0.05
    loop = trace(r, target, qa, 1, step=step)  # no goal: once round the closed self-motion curve
    assert not loop.reached and len(loop.points) > 50
    assert np.abs(wrap_joints(loop.points[-1] - qa, r.revolute)).max() < 0.5 * step
    qb = loop.points[len(loop.points) // 3]
    found = routes(r, target, qa, qb, step=step)
    assert len(found) == 2 and found[0].length < found[1].length  # both ways round, shortest first
    assert found[0].length + found[1].length == pytest.approx(loop.length, abs=4 * step)
    for route in found:
        pts = route.points
        np.testing.assert_array_equal(pts[0], qa)
        assert np.abs(wrap_joints(pts[-1] - qb, r.revolute)).max() < 1e-12  # the goal itself
        ends = np.array([r.kinematics.pose(q)[1][:2] for q in pts])
        assert np.abs(ends - target).max() < 1e-9  # the task holds all along
        dq = np.diff(pts, axis=0)
        size = np.linalg.norm(dq, axis=1)
        assert size.max() <= step * np.sqrt(3) + 1e-12 and route.length == pytest.approx(size.sum())
        # each step is along the null space of J (to first order: it leaves it by the curve's bending)
        Jdq = np.array([r.kinematics.jacobian(q)[2][3:5] @ d for q, d in zip(pts[:-1], dq, strict=True)])
        assert np.all(np.linalg.norm(Jdq, axis=1) <= 0.25 * step * size)
    first = [route.points[1] - qa for route in found]
    assert first[0] @ first[1] < 0  # they leave qa in opposite directions


def test_transition_between_candidates_is_refined_on_the_path():
    """Two samples of a small ellipse within the planar arm's reach: the candidates (policy minima) and
    the refined transition between them - on the path at its times, joints within max_jump, and the
    clearances it reports are those of its points."""
    r = robot("planar3r_ch6")
    center, a, b, angle = (0.6, 0.1), 0.12, 0.06, 0.35
    ob = EllipseObstacle(center, a, b, angle)
    path = Ellipse(center, a, b, angle=angle)
    model = link_model(r)
    tip = model.lengths[-1] / 6
    rng = np.random.default_rng(0)
    cands = []
    for t in (0.0, 0.5):
        p = path(t).p
        index = default_policy(r, ob, ob.normal_at(p), (1e-3, 1.0))
        found = entries(candidates(r, index, p[:2], [rng.uniform(-np.pi, np.pi, 3) for _ in range(8)], model, ob,
                                   0.0, tip, 200))
        assert found and all(c.clearance.min() > 0 for c in found)
        cands.append(found)
    max_jump = 0.15
    done = [(transition(r, path, 0.0, ca, 0.5, cb, model=model, obstacle=ob, radius=0.0, tool_tip=tip,
                        max_jump=max_jump, budget=32), ca, cb) for ca in cands[0] for cb in cands[1]]
    done = [(tr, ca, cb) for tr, ca, cb in done if np.isfinite(tr.cost)]
    assert done and any(tr.points for tr, _, _ in done)
    for tr, ca, cb in done:
        times = [0.0] + [t for t, _ in tr.points] + [0.5]
        chain = np.array([ca.q] + [q for _, q in tr.points] + [cb.q + tr.shift])
        assert np.all(np.diff(times) > 0) and np.abs(np.diff(chain, axis=0)).max() <= max_jump
        for t, q in tr.points:
            assert np.abs(r.kinematics.pose(q)[1][:2] - path(t).p[:2]).max() < 1e-9
        assert len(tr.clearance) == len(tr.points)
        for (_, q), c in zip(tr.points, tr.clearance, strict=True):
            np.testing.assert_allclose(c, clearance_of(r, q, model, ob, 0.0, tip), rtol=0, atol=rounding())  # kind 1
        worst = min([ca.clearance.min(), cb.clearance.min()] + [c.min() for c in tr.clearance])
        assert tr.min_clearance == worst
        energy = float(np.sum(np.diff(chain, axis=0) ** 2))
        assert tr.cost == pytest.approx(energy + PENETRATION_PENALTY * max(0.0, -worst), rel=1e-12)


def test_the_motion_bound_holds_on_an_arm_with_a_prismatic_joint():
    """The clearance check's rigorous bound (no point of link k moves by more than sum_i |dq_i| R_ik) on an RPR arm
    whose prismatic joint stretches link 1 far beyond its home length. Before, the reach was the chain length at
    home and a prismatic joint moved only the links after its origin: the bound was exceeded 251-fold (the
    stretched link's far end moves with the prismatic joint itself)."""
    from kinredund.kinematics.hd import HDTable
    from kinredund.model.robot import robot_from_hd
    from kinredund.planning.clearance import link_segments, longest_segments, motion_bound

    table = HDTable(alpha=[np.pi / 2, 0.0, 0.0], a=[0.0, 0.0, 0.5], b=[0.3, 0.1, 0.0], kinds="RPR",
                    lower=[-np.pi, 0.0, -np.pi], upper=[np.pi, 1.5, np.pi], name="rpr")
    r = robot_from_hd(table, task="position")
    model = link_model(r)
    rng = np.random.default_rng(3)
    ratios = []
    for _ in range(300):
        qa = rng.uniform(r.lower, r.upper)
        qb = np.clip(qa + rng.normal(0.0, 0.02, 3), r.lower, r.upper)
        sa, sb = link_segments(r, [qa, qb], model)
        moved = np.linalg.norm(sb - sa, axis=2).max(axis=1)  # a link's points move affinely: the most at an end
        ratios.append((moved / motion_bound(model, np.array([qa, qb]))).max())
        # the segment lengths stay within their bound over the joint box
        seg = np.linalg.norm(np.diff(r.kinematics.joint_origins(qa), axis=0), axis=1)
        assert np.all(seg <= longest_segments(r)[1] + 1e-12)
    assert max(ratios) <= 1.0 + 1e-9
    assert max(ratios) > 0.5  # the bound is not vacuous
