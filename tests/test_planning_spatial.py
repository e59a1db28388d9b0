"""Section 6.3 (spatial case): the reach of the policy's wrist point and the planner's fast failure."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from kinredund.planning.clearance import link_model
from kinredund.planning.planner import plan, wrist_reach
from kinredund.planning.spatial import scaled_p15, section_cylinder, section_path


def _targets(count=73, **shape):
    path = section_path(**shape)
    ts = np.linspace(0.0, path.period, count)
    ps = np.array([path(t).p for t in ts])
    return ps


@pytest.mark.parametrize("scale", [8.0, 12.0])
def test_wrist_reach_bounds_every_configuration(scale):
    robot = scaled_p15(scale)
    cyl = section_cylinder()
    ps = _targets(9)
    wr = wrist_reach(robot, ps, cyl.normal_at(ps))
    i = int(link_model(robot).pairs[-1][0])
    rng = np.random.default_rng(3)
    dist = [np.linalg.norm(robot.kinematics.joint_origins(robot.random_configuration(rng, 0.0))[i] - wr.origin)
            for _ in range(400)]
    assert max(dist) <= wr.reach + 1e-9
    assert max(dist) > 0.97 * wr.reach  # the bound is nearly attained (links 2-3 stretched)
    stretched = np.zeros(robot.nq)
    stretched[2] = np.pi if np.linalg.norm(robot.kinematics.joint_origins(stretched)[i] - wr.origin) < wr.reach - 1e-9 \
        else 0.0
    assert np.linalg.norm(robot.kinematics.joint_origins(stretched)[i] - wr.origin) == pytest.approx(wr.reach)


def test_wrist_point_is_the_end_point_moved_along_the_normal():
    """W is one last-link length from P, at P's height and that far from the directrix too: so P is
    W's closest point of the obstacle's ellipse and W - P lies along the outward normal at P."""
    robot = scaled_p15(12.0)
    cyl = section_cylinder()
    ps = _targets(37)
    wr = wrist_reach(robot, ps, cyl.normal_at(ps))
    length = link_model(robot).lengths[-1]
    assert length == pytest.approx(0.14 * 12.0)  # b5 of Table 4.1 times the scale
    np.testing.assert_allclose(np.abs(cyl.ellipse_distance(ps)), 0.0, atol=1e-12)  # P on the lateral surface
    np.testing.assert_allclose(np.linalg.norm(wr.wrist - ps, axis=1), length, rtol=1e-12)
    np.testing.assert_allclose(wr.wrist[:, 2], ps[:, 2], atol=1e-12)
    np.testing.assert_allclose(cyl.ellipse_distance(wr.wrist), length, rtol=1e-9)


def test_a_negative_wrist_margin_is_how_far_the_links_miss_the_wrist_point():
    """Minimised over the joints numerically, the last link's joint comes no closer to W than -margin."""
    robot = scaled_p15(8.0)
    cyl = section_cylinder()
    ps = _targets(13)
    wr = wrist_reach(robot, ps, cyl.normal_at(ps))
    i = int(link_model(robot).pairs[-1][0])
    rng = np.random.default_rng(4)
    out = wr.margin < 0
    assert 0 < out.sum() < len(ps)
    for w, m in zip(wr.wrist[out], wr.margin[out], strict=True):
        gaps = [np.linalg.norm(least_squares(lambda q, w=w: robot.kinematics.joint_origins(q)[i] - w, q0).fun)
                for q0 in rng.uniform(-np.pi, np.pi, (4, robot.nq))]
        assert min(gaps) == pytest.approx(-m, abs=1e-6)


@pytest.mark.parametrize("scale", [8.0, 9.0, 10.0, 12.0, 14.0])
def test_wrist_margin_matches_the_p15_closed_form(scale):
    # O2 at height b1 = 0.16 s, links 2-3 reach (a2 + a3) = 0.36 s, last link b5 = 0.14 s (Table 4.1 x s)
    robot = scaled_p15(scale)
    cyl = section_cylinder()
    ps = _targets(181)
    n = cyl.normal_at(ps)
    wr = wrist_reach(robot, ps, n)
    expected = 0.36 * scale - np.linalg.norm(ps + 0.14 * scale * n - np.array([0.0, 0.0, 0.16 * scale]), axis=1)
    np.testing.assert_allclose(wr.margin, expected, atol=1e-9)
    assert (wr.margin.min() > 0) == (scale >= 12.0)  # scale 11 is the borderline (margin ~0)


def test_plan_fails_fast_when_the_wrist_is_out_of_reach():
    robot = scaled_p15(8.0)
    path, cyl = section_path(), section_cylinder()
    res = plan(robot, path, cyl, samples=9)
    assert not res.ok and res.samples is None and res.trajectory is None
    assert "S1 " in res.reason and "beyond the reach" in res.reason
    p = path(0.0).p
    w = p + 1.12 * cyl.normal_at(p)
    short = np.linalg.norm(w - np.array([0.0, 0.0, 1.28])) - 2.88
    assert f"{short:.4g} m beyond" in res.reason


def test_an_end_point_out_of_reach_fails_whatever_the_flag():
    robot = scaled_p15(8.0)
    far = {"center": (10.0, 0.0)}
    res = plan(robot, section_path(**far), section_cylinder(**far), samples=6, check_reach=False)
    assert not res.ok and res.samples is None
    assert "out of reach" in res.reason and "S1 " in res.reason


def test_top_normal_policy_aims_the_last_link_along_the_cut_normal():
    from kinredund.errors import TaskError
    from kinredund.planning.obstacles import EllipticCylinder
    from kinredund.planning.spatial import top_normal_policy

    robot = scaled_p15(8.0)
    cyl = section_cylinder()
    p = section_path()(0.7).p
    pol = top_normal_policy(robot, cyl, cyl.normal_at(p), (1e-3, 1.0))
    np.testing.assert_allclose(pol.normal, np.asarray(cyl.top_normal) / np.linalg.norm(cyl.top_normal))
    assert pol.weights == (0.0, 1.0)
    # the index is 0 when the last link points along -n_top (Eq. 6.44 with w1 = 0), the wrist at its
    # reference; aligned with the lateral surface's -n instead, it is not
    i, j = (int(v) for v in link_model(robot).pairs[-1])

    def aligned(direction):  # arm joints putting the last link (from the model's joint origins) along direction
        def miss(q4):
            o = robot.kinematics.joint_origins(np.concatenate([q4, np.zeros(3)]))
            return (o[j] - o[i]) / np.linalg.norm(o[j] - o[i]) - direction

        sol = least_squares(miss, np.full(4, 0.3), xtol=1e-15, ftol=1e-15, gtol=1e-15)
        assert np.abs(sol.fun).max() < 1e-12
        return np.concatenate([sol.x, np.zeros(3)])

    top_n = np.asarray(cyl.top_normal) / np.linalg.norm(cyl.top_normal)
    z, g, _ = pol.evaluate(aligned(-top_n))
    assert abs(z) < 1e-12 and np.abs(g).max() < 1e-9  # its minimum
    lateral = -cyl.normal_at(p)
    assert pol.evaluate(aligned(lateral))[0] == pytest.approx(1.0 - float(lateral @ -top_n))  # w2/2 |L - l|^2
    with pytest.raises(TaskError, match="top_normal"):
        top_normal_policy(robot, EllipticCylinder((1.9, 0.0, 0.5), 0.5, 0.25, 0.0, height=1.0), cyl.normal_at(p),
                          (1e-3, 1.0))


@pytest.mark.parametrize("weights", [(0.0, 0.0), (1e-3, -1.0), (np.nan, 1.0), "ab", [(1e-3, 1.0)] * 5])
def test_plan_rejects_bad_weights_before_solving(weights):
    from kinredund.errors import OptionError

    with pytest.raises(OptionError, match="weights"):
        plan(scaled_p15(8.0), section_path(), section_cylinder(), samples=6, weights=weights)
