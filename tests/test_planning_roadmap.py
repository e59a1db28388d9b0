"""Chapter 6: the cut cylinder, the policy indices, the thesis's closed forms, the roadmap plan of Section 6.3."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import rounding
from scipy.spatial import cKDTree

from kinredund.indices import check_index
from kinredund.kinematics.hd import HDTable
from kinredund.model.catalog import cybotech_p15
from kinredund.model.robot import robot_from_hd
from kinredund.planning.clearance import link_clearance, link_segments
from kinredund.planning.obstacles import EllipseObstacle, EllipticCylinder, obstacle_from_dict
from kinredund.planning.policy import PlanarPolicy, SpatialPolicy
from kinredund.planning.roadmap import check_architecture, origins, plan_roadmap, self_motion
from kinredund.planning.spatial import (
    arm_plane_semi_axis_discriminant,
    link2_semi_axis_discriminant,
    link4_direction_thesis,
    scaled_p15,
    section_cylinder,
    section_path,
)
from kinredund.planning.spline import JointSpline
from kinredund.trajectory import Trajectory


def _boundary_cloud(cyl: EllipticCylinder, around=1500, up=400, radial=200) -> np.ndarray:
    ring, _ = cyl.boundary(np.linspace(0, 2 * np.pi, around, endpoint=False))
    z0 = cyl.z_range[0]
    top = cyl.top_height(ring)
    pts = [np.column_stack([ring, z0 + f * (top - z0)]) for f in np.linspace(0, 1, up)]
    for f in np.linspace(0, 1, radial):
        xy = cyl.center[:2] + f * (ring - cyl.center[:2])
        pts += [np.column_stack([xy, cyl.top_height(xy)]), np.column_stack([xy, np.full(len(xy), z0)])]
    return np.vstack(pts)


def test_cut_cylinder_distance_is_exact_against_its_sampled_surface():
    cyl = section_cylinder()
    cloud = _boundary_cloud(cyl)
    spacing = 2 * np.pi * 0.5 / 1500 + 1.4 / 400  # a bound of the cloud's spacing [m]
    rng = np.random.default_rng(0)
    X = rng.uniform([0.9, -0.8, -0.4], [2.9, 0.8, 2.0], size=(800, 3))
    d = cyl.signed_distance(X)
    near = cKDTree(cloud).query(X)[0]
    assert np.all(np.abs(d) <= near + 1e-12)  # the exact distance never exceeds a sampled one
    assert np.all(near - np.abs(d) <= spacing)  # and the samples come within their spacing of it
    # the roadmap's screening bound: never above the distance, and exact inside
    bound = cyl.surface_bound(X)
    assert np.all(bound <= d + 1e-12)
    np.testing.assert_allclose(bound[d < 0], d[d < 0], atol=1e-12)
    # the path of Eqs. (6.46)-(6.50) is the rim of the cut
    path = section_path()
    ps = np.array([path(t).p for t in np.linspace(0, path.period, 97)])
    assert np.abs(cyl.signed_distance(ps)).max() < 1e-12


def test_cut_cylinder_segment_distance_against_dense_sampling_and_round_trip():
    cyl = section_cylinder()
    rng = np.random.default_rng(1)
    p0 = rng.uniform([0.5, -1, 0], [3.0, 1, 2.5], size=(60, 3))
    p1 = rng.uniform([0.5, -1, 0], [3.0, 1, 2.5], size=(60, 3))
    got = cyl.segment_distance(p0, p1)
    s = np.linspace(0, 1, 4001)
    for k in range(60):
        dense = cyl.signed_distance(p0[k] + np.outer(s, p1[k] - p0[k]))
        step = np.linalg.norm(p1[k] - p0[k]) / 4000
        assert got[k] <= dense.min() + 1e-9
        assert dense.min() - got[k] <= step  # 1-Lipschitz: the samples are within a step of the minimum
    again = obstacle_from_dict(cyl.to_dict())
    np.testing.assert_allclose(again.signed_distance(p0), cyl.signed_distance(p0), atol=1e-14)


@pytest.mark.parametrize("seed", [0, 1])
def test_policy_gradients_and_hessians(seed):
    rng = np.random.default_rng(seed)
    ob = EllipseObstacle((0.9, 0.0), 0.15, 0.075, np.radians(20))
    _, n = ob.boundary(rng.uniform(0, 2 * np.pi))
    planar = PlanarPolicy(ob, 0.5, n, (1e-3, 1.0))
    robot = scaled_p15()
    spatial = SpatialPolicy(robot, section_cylinder(), np.array([1.0, 0.3, 0.0]), link=(4, 5))
    for _ in range(3):
        check_index(planar, rng.uniform(-3, 3, 3), tol=1e-5)
        check_index(spatial, rng.uniform(-2, 2, 7), tol=1e-5)


def test_policy_semi_axis_term_equals_the_thesis_discriminant_route():
    """With w2 = 0 the index is w1 / (2 b^2) (Eqs. 6.21, 6.44): the b it implies is the root of the
    thesis's vanishing discriminant (Eqs. 6.15-6.16 for link 2, 6.36-6.37 for the projected link k2)."""
    rng = np.random.default_rng(2)
    w1 = 1e-3
    ob = EllipseObstacle((0.9, 0.0), 0.15, 0.075, 0.35)
    planar = PlanarPolicy(ob, 0.5, np.array([1.0, 0.0]), (w1, 0.0))
    for t1, t2, t3 in rng.uniform(-3, 3, (15, 3)):
        b = np.sqrt(0.5 * w1 / planar.evaluate(np.array([t1, t2, t3]))[0])
        assert b == pytest.approx(link2_semi_axis_discriminant(ob, 0.5, t1, t2), rel=1e-13)
    robot, cyl = scaled_p15(), section_cylinder()
    spatial = SpatialPolicy(robot, cyl, np.array([1.0, 0.3, 0.0]), link=(4, 5), weights=(w1, 0.0))
    assert spatial.wrist_joints.tolist() == [4, 5, 6]  # the joints that do not move the wrist centre
    for theta in rng.uniform(-3, 3, (15, 7)):
        theta[spatial.wrist_joints] = spatial.wrist_ref  # no wrist term
        b = np.sqrt(0.5 * w1 / spatial.evaluate(theta)[0])
        assert b == pytest.approx(arm_plane_semi_axis_discriminant(cyl, theta[0]), rel=1e-13)


def test_jacobian_and_origins_is_one_pass_of_jacobian_and_joint_origins():
    rng = np.random.default_rng(6)
    for robot in (scaled_p15(), robot_from_hd(HDTable(np.zeros(3), [0.5, 0.6, 0.3], np.zeros(3)), task="planar")):
        for q in rng.uniform(-3, 3, (4, robot.nq)):
            K, origins = robot.kinematics.jacobian_and_origins(q)
            np.testing.assert_allclose(K, robot.kinematics.jacobian(q)[2], rtol=0, atol=1e-14)
            # two Pinocchio passes (kind 1 of the tolerance policy): equal up to rounding, not bit for bit
            np.testing.assert_allclose(origins, robot.kinematics.joint_origins(q), rtol=0, atol=rounding())


def _link4_error(alpha_deg, sign=1.0):
    t = cybotech_p15()
    robot = robot_from_hd(HDTable(np.radians(alpha_deg), t.a, t.b, name="variant"), task="position")
    err = 0.0
    for q in np.random.default_rng(3).uniform(-3, 3, (20, 7)):
        o = robot.kinematics.joint_origins(q)
        L = (o[5] - o[4]) / np.linalg.norm(o[5] - o[4])
        err = max(err, float(np.abs(L - sign * link4_direction_thesis(q)).max()))
    return err


def test_printed_direction_cosines_need_alpha2_zero():
    assert _link4_error([90, 180, -90, 90, 90, 90, -90]) > 0.5  # Table 4.1 as printed: no
    assert _link4_error([90, 180, -90, 90, 90, 90, -90], -1.0) > 0.5
    assert _link4_error([90, 0, -90, 90, 90, 90, -90], -1.0) < 1e-12  # alpha2 = 0: up to the sign
    assert _link4_error([90, 0, -90, -90, 90, 90, -90]) < 1e-12  # and exactly with alpha4 = -90 deg


def test_closed_form_self_motion_reaches_the_target():
    robot = scaled_p15()
    arch = check_architecture(robot)
    p = section_path()(1.0).p
    q, ok = self_motion(arch, p, np.linspace(-np.pi, np.pi, 90, endpoint=False))
    assert ok.sum() > 20
    ends = origins(arch, q[ok])[:, 4]
    assert np.abs(ends - p).max() < 1e-12
    fk = np.array([robot.fk(np.concatenate([qq, np.zeros(3)]))[:3, 3] for qq in q[ok][:10]])
    assert np.abs(fk - p).max() < 1e-12
    with pytest.raises(Exception, match="architecture of Table 4.1"):
        check_architecture(robot_from_hd(HDTable(np.zeros(3), [1, 1, 1], np.zeros(3)), task="planar"))


def test_periodic_spline_joins_up_across_the_loop():
    t = np.linspace(0, 4.0, 7, endpoint=False)
    q = np.column_stack([np.sin(t), np.cos(2 * t) + t * np.pi / 2])
    spl = JointSpline(t, q, 4.0, np.array([0.0, 2 * np.pi]))
    np.testing.assert_allclose(spl(4.0), spl(0.0) + [0.0, 2 * np.pi], atol=1e-12)
    np.testing.assert_allclose(spl.rate(4.0 - 1e-9), spl.rate(1e-9), atol=1e-6)
    np.testing.assert_allclose(spl.values(t), q, atol=1e-12)


def test_penetration_of_the_tool_link_is_found():
    robot = scaled_p15()
    cyl = section_cylinder()
    seg = link_segments(robot, np.zeros(7))
    inward = seg.copy()
    p = section_path()(0.0).p  # the far point of the rim: the last link ends there, coming out of the solid
    inward[0, -1, 1] = p
    inward[0, -1, 0] = p + np.array([-0.5, 0.0, -0.3])
    _, pen, tip = link_clearance(cyl, inward, tool_tip=0.1)
    assert tip[0] < 1e-12 and pen[0] > 0.05
    outward = inward.copy()
    outward[0, -1, 0] = p + np.array([0.5, 0.0, 0.0])  # along the outward normal: touches at P only
    _, pen, _ = link_clearance(cyl, outward, tool_tip=0.1)
    assert pen[0] < 1e-12


def test_screening_clearance_is_a_lower_bound_of_the_exact_one():
    """The roadmap's screening (link_clearance with the cylinder's surface_bound) never reports more
    clearance than the exact distance, and the same where a link is inside."""
    robot, cyl = scaled_p15(), section_cylinder()
    seg = link_segments(robot, np.random.default_rng(8).uniform(-np.pi, np.pi, (200, 7)))
    exact = link_clearance(cyl, seg, tool_tip=0.1)
    screen = link_clearance(cyl, seg, tool_tip=0.1, distance=cyl.surface_bound)
    assert np.all(screen[0] <= exact[0] + 1e-12) and np.any(screen[0] < exact[0] - 1e-3)
    inside = exact[0] < 0
    assert inside.any()
    np.testing.assert_allclose(screen[0][inside], exact[0][inside], atol=1e-9)
    assert np.all(screen[1] + screen[2] >= exact[1] + exact[2] - 1e-12)  # no penetration is missed


@pytest.fixture(scope="module")
def section_6_3(tmp_path_factory):
    from kinredund.ui.reproduce import plan_case

    out = tmp_path_factory.mktemp("ch6")
    result = plan_case("6.3", json_path=out / "6.3.json", plot_path=out / "6.3.png")
    return result, out


def test_section_6_3_plan_is_collision_free_cyclic_and_on_the_path(section_6_3):
    result, out = section_6_3
    assert result.ok, result.reason
    tr = result.trajectory
    assert tr.position_error.max() < 1e-8
    assert tr.loop_drift[0] < 1e-8  # the joint path closes after a loop
    c = result.clearance
    assert np.all(result.clearance_min > 0) and np.all(c.lower_bound > 0)
    # the last link's deepest point is its end point here, so the penetration (whole-link depth minus end-point
    # depth) is 0 in exact arithmetic; the two evaluations of the distance differ by rounding of ~1 m
    # coordinates (a few eps: 2.8e-17 seen on AMD EPYC), far below the planner's own PENETRATION_TOL of 1e-9
    assert c.penetration.max() <= rounding()
    # the check's resolution is fine enough: doubling it moves no minimum by more than the stated bound
    assert np.all(c.doubling_change <= 0.5 * c.motion_bound + 1e-12)
    assert result.spline_gap_max < 1e-2
    assert tr.meta["obstacle"]["kind"] == "elliptic_cylinder" and "top_plane" in tr.meta["obstacle"]
    data = json.loads((out / "6.3.json").read_text())
    for key in ("t", "q", "q_spline", "samples", "clearance_min", "obstacle", "ok", "reason"):
        assert key in data
    assert len(data["clearance_min"]) == 4 and data["ok"] is True
    assert (out / "6.3.png").stat().st_size > 0 and (out / "6.3_snapshots.png").stat().st_size > 0


def test_section_6_3_clearance_against_dense_sampling_of_the_links(section_6_3):
    """The reported per-link minima against the obstacle's signed distance sampled along the segments
    between consecutive joint origins, at the checked times (joints interpolated here by np.interp)."""
    result, _ = section_6_3
    tr, rep = result.trajectory, result.clearance
    robot, cyl = scaled_p15(), section_cylinder()
    q = np.column_stack([np.interp(rep.t, tr.t, tr.q[:, j]) for j in range(robot.nq)])
    pts = np.array([robot.kinematics.joint_origins(qk) for qk in q])  # (N, njoints + 1, 3)
    home = robot.kinematics.joint_origins(robot.home)
    links = [k for k in range(len(home) - 1) if np.linalg.norm(home[k + 1] - home[k]) > 1e-9]
    assert len(links) == len(result.clearance_min)
    s = np.linspace(0.0, 1.0, 161)
    for n, k in enumerate(links):
        a, b = pts[:, k], pts[:, k + 1]
        length = np.linalg.norm(b[0] - a[0])
        if n == len(links) - 1:
            b = b - rep.tool_tip * (b - a) / length  # the tool tip at P is left out
        dense = cyl.signed_distance(a[:, None] + s[None, :, None] * (b - a)[:, None])  # (N, samples)
        half_step = 0.5 * np.linalg.norm(b[0] - a[0]) / (len(s) - 1)  # 1-Lipschitz between samples
        assert dense.min() > 0
        assert result.clearance_min[n] <= dense.min() + 1e-9  # the exact minimum is below every sample
        assert result.clearance_min[n] >= dense.min() - half_step - 1e-9
        assert rep.lower_bound[n] <= dense.min() + 1e-9
    # the whole last link at the tracked steps: nothing of it inside the cylinder (P itself is on the rim)
    i, j = links[-1], links[-1] + 1
    steps = np.array([robot.kinematics.joint_origins(qk) for qk in tr.q])
    whole = cyl.signed_distance(steps[:, i, None] + s[None, :, None] * (steps[:, j] - steps[:, i])[:, None])
    assert whole.min() >= -1e-9


def test_section_6_3_trajectory_saves_and_reloads(section_6_3, tmp_path):
    result, _ = section_6_3
    tr = result.trajectory
    json.dumps(tr.meta, allow_nan=False)  # the meta is strict JSON (the roadmap's samples carry no clearance)
    assert tr.meta["samples"]["clearance"][0] == [None] * len(result.clearance_min)
    f = tmp_path / "6.3_trajectory.json"
    tr.save_json(f)
    back = Trajectory.load_json(f)
    np.testing.assert_array_equal(back.t, tr.t)
    np.testing.assert_array_equal(back.q, tr.q)
    assert back.meta["samples"] == tr.meta["samples"]
    np.testing.assert_array_equal(back.meta["samples"]["q"], result.samples.q)


def test_an_obstacle_too_large_for_the_arm_is_reported_as_failed():
    robot = scaled_p15()
    big = EllipticCylinder((1.9, 0.0, 0.7), 1.6, 1.2, 0.0, height=1.4, top_normal=[-0.17, 0.0, 0.98], top_z=1.278)
    result = plan_roadmap(robot, section_path(), big, slices=24, grid=120)
    assert not result.ok
    assert "no cyclic collision-free motion" in result.reason
    assert result.trajectory is None


@pytest.mark.parametrize("tool_tip", [-0.1, 1.2, "long"])
def test_roadmap_plan_checks_the_tool_tip_like_plan(tool_tip):
    from kinredund.errors import OptionError
    from kinredund.planning.planner import plan

    robot, path, cyl = scaled_p15(), section_path(), section_cylinder()  # the last link is 1.12 m long
    for planner in (plan, plan_roadmap):
        with pytest.raises(OptionError, match="tool_tip"):
            planner(robot, path, cyl, tool_tip=tool_tip)
