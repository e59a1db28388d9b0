"""Chapter 6: obstacles and clearance against brute force, the planar case's impossibility, the JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import robot
from hypothesis import given, settings
from hypothesis import strategies as st

from kinredund import ChoiceError, TaskError
from kinredund.cli import EXIT_FAILED, main
from kinredund.examples.chapter4 import load_example, run_example
from kinredund.examples.chapter6 import case_robot, planar_feasibility, planar_setup, reproduce
from kinredund.paths import Ellipse
from kinredund.planning.clearance import verify_motion
from kinredund.planning.obstacles import EllipseObstacle, EllipticCylinder


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
    brute = np.min(np.linalg.norm(pts[:, None, :] - _ellipse_points(ob)[None], axis=2), axis=1)
    d = ob.ellipse_distance(pts)
    assert np.allclose(np.abs(d), brute, atol=2e-3 * a)  # the boundary sampling's own error
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
    result = reproduce("6.2", json_path=js, plot_path=png)
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
    for name in ("t", "clearance", "penetration", "minimum", "lower_bound", "motion_bound"):
        np.testing.assert_array_equal(getattr(both, name), getattr(base, name))
    np.testing.assert_array_equal(both.doubling_change, np.abs(fine.minimum - base.minimum))
    assert np.any(both.doubling_change > 0)
    with pytest.raises(TaskError, match="substeps"):
        verify_motion(r, ob, t, q, substeps=0)


def test_case_robot():
    r = case_robot("6.3")
    assert r.name == "cybotech_p15_x8" and r.hd.b[0] == pytest.approx(8 * 0.16)
    assert case_robot("6.2").hd.a.tolist() == [0.5, 0.6, 0.3]
    with pytest.raises(ChoiceError, match="6.2, 6.3"):
        case_robot("6.4")
