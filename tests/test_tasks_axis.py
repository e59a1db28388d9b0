"""The tool-axis task (m = 5): residual, Jacobians and tracking terms against central differences on the
UR5, the Panda and random HD arms; its IK residual; and the task objects' shared contract."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import configurations, robot

import kinredund
from kinredund.kinematics.finite_diff import central_difference
from kinredund.kinematics.hd import HDTable
from kinredund.paths import Circle
from kinredund.tasks import TASKS, get_task, make_target, task_residual
from kinredund.tasks.axis import axis_angle_error, frame_with_axis

#: central differences with step 1e-6 on smooth maps of unit scale: truncation ~1e-12, rounding
#: ~1e-16 / 1e-6 = 1e-10, so 1e-7 leaves three orders of margin and still catches any wrong term (O(1))
FD_BAR = 1e-7


def _ur5():
    return kinredund.load_robot("ur5", task="axis")


def _random_hd(seed: int):
    rng = np.random.default_rng(seed)
    n = 6
    table = HDTable(alpha=rng.uniform(-np.pi, np.pi, n), a=rng.uniform(0.1, 0.5, n), b=rng.uniform(-0.3, 0.3, n),
                    name=f"random{seed}")
    return kinredund.robot_from_hd(table, task="axis")


ROBOTS = {"ur5": _ur5, "panda": lambda: robot("panda", "axis"), "hd7": lambda: _random_hd(7),
          "hd8": lambda: _random_hd(8)}


def _path_through(r, q):
    """A Frenet circle near the arm's point at q: Q_d and omega_d both vary in time."""
    T = r.fk(q)
    return Circle(T[:3, 3] + 0.02, 0.05, 0.3, normal=(0.3, 0.5, 0.8), frenet=True)


@pytest.mark.parametrize("name", list(ROBOTS))
@pytest.mark.parametrize("formulation", ["augmented", "velocity"])
def test_axis_tracking_terms_against_central_differences(name, formulation):
    r = ROBOTS[name]()
    task = get_task("axis")
    rng = np.random.default_rng(3)
    for q in configurations(r, seed=5, count=2):
        path = _path_through(r, q)
        t = 0.37

        def terms(x, t=t, path=path):
            return task.tracking_terms(formulation, *r.kinematics.jacobian_hessian(x), path(t))

        tt = terms(q)
        assert tt.r.shape == (5,) and tt.J.shape == (5, r.nq)
        if formulation == "augmented":  # the exact Jacobian of r
            assert np.abs(tt.J - central_difference(lambda x: terms(x).r, q)).max() < FD_BAR
        lam = rng.normal(size=5)
        Lam, dJdt = tt.system(lam)
        fd = central_difference(lambda x, lam=lam: terms(x).J.T @ lam, q)
        assert np.abs(Lam - fd).max() < FD_BAR
        if formulation == "augmented":  # a true Hessian of lam . r(theta)
            assert np.abs(Lam - Lam.T).max() < FD_BAR
        # time derivatives at fixed theta: xdot = -dr/dt, (dJ/dt)^T lam
        Qp, pp, K, dk = r.kinematics.jacobian_hessian(q)

        def at_time(s, Qp=Qp, pp=pp, K=K, dk=dk, path=path):
            return task.tracking_terms(formulation, Qp, pp, K, dk, path(float(s[0])))

        assert np.abs(tt.xdot + central_difference(lambda s: at_time(s).r, np.array([t]))[:, 0]).max() < FD_BAR
        fd_t = central_difference(lambda s, lam=lam: at_time(s).J.T @ lam, np.array([t]))[:, 0]
        assert np.abs(dJdt - fd_t).max() < FD_BAR


@pytest.mark.parametrize("name", list(ROBOTS))
def test_on_the_path_both_forms_have_the_same_jacobian(name):
    """Where a = a_d (r = 0), the velocity form's rows of the twist equal the exact Jacobian."""
    r = ROBOTS[name]()
    task = get_task("axis")
    q = configurations(r, seed=2, count=1)[0]
    Qp, pp, K, dk = r.kinematics.jacobian_hessian(q)
    sample = kinredund.paths.PathSample(pp, np.zeros(3), Qp @ frame_with_axis([0, 0, 1]), np.zeros(3))
    aug, vel = (task.tracking_terms(f, Qp, pp, K, dk, sample) for f in ("augmented", "velocity"))
    assert np.abs(aug.r).max() < 1e-15 and np.abs(aug.J - vel.J).max() < 1e-14
    assert np.linalg.matrix_rank(aug.J) == 5


@pytest.mark.parametrize("name", list(ROBOTS))
def test_axis_ik_residual_against_central_differences(name):
    r = ROBOTS[name]()
    rng = np.random.default_rng(9)
    for q in configurations(r, seed=4, count=2):
        T = r.fk(q + 0.1)
        res = task_residual(make_target("axis", T))
        Q, p, K, dk = r.kinematics.jacobian_hessian(q)
        e, aux = res.error(Q, p)
        G = res.jacobian(K, aux)
        assert np.abs(G - central_difference(lambda x, res=res: res.error(*r.kinematics.pose(x))[0], q)).max() < FD_BAR
        lam = rng.normal(size=5)
        lam_k = res.k_multipliers(lam, aux)
        assert np.abs(G.T @ lam - K.T @ lam_k).max() < 1e-12
        exact = dk.contract(lam_k) + res.extra_hessian(K, lam, aux)

        def gt_lam(x, lam=lam, res=res):
            Qx, px, Kx = r.kinematics.jacobian(x)
            return res.jacobian(Kx, res.error(Qx, px)[1]).T @ lam

        assert np.abs(exact - central_difference(gt_lam, q)).max() < FD_BAR
        # the reported residual is the distance [a - a_d; p - p_d] (no zero at a = -a_d): the axis part
        # ||a - a_d||^2 = ||S a^||^2 + (1 - a . a_d)^2, computed here from the frames directly
        a, a_d = Q[:, 2], T[:3, 2]
        assert res.residual(Q, p) == pytest.approx(np.sqrt(np.sum((a - a_d) ** 2) + np.sum(e[2:] ** 2)), rel=1e-12)


def test_axis_targets_and_errors():
    T = np.eye(4)
    T[:3, :3] = frame_with_axis([1.0, 2.0, 2.0])
    T[:3, 3] = (0.1, 0.2, 0.3)
    a = make_target("axis", T)
    b = make_target("axis", (np.array([1.0, 2.0, 2.0]) * 5.0, T[:3, 3]))
    assert np.allclose(a.Q[:, 2], b.Q[:, 2], atol=1e-15) and np.allclose(b.Q[:, 2], np.array([1, 2, 2]) / 3)
    assert np.abs(b.Q.T @ b.Q - np.eye(3)).max() < 1e-15 and np.linalg.det(b.Q) == pytest.approx(1.0)
    with pytest.raises(kinredund.TaskError, match="nonzero"):
        make_target("axis", (np.zeros(3), np.zeros(3)))
    with pytest.raises(kinredund.TaskError):
        make_target("axis", (np.array([np.nan, 0.0, 1.0]), np.zeros(3)))
    # the axis error is the angle between the z axes; a spin about the axis is no error
    spin = frame_with_axis([0, 0, 1]) @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert axis_angle_error(spin, np.eye(3)) == pytest.approx(0.0, abs=1e-15)
    tilt = np.array([[1.0, 0, 0], [0, np.cos(0.3), -np.sin(0.3)], [0, np.sin(0.3), np.cos(0.3)]])
    assert axis_angle_error(tilt, np.eye(3)) == pytest.approx(0.3, abs=1e-15)
    errs = get_task("axis").error_values(tilt, np.array([0.0, 0.0, 0.1]), make_target("axis", np.eye(4)))
    assert errs == pytest.approx({"position_error": 0.1, "axis_error": 0.3}, abs=1e-15)


def test_every_task_kind_keeps_the_contract():
    """Each registered kind: its dimension, a target from its own FK, a zero residual there, its error names."""
    r = robot("panda")
    q = r.home
    T = r.fk(q)
    for name, task in TASKS.items():
        rr = r.with_task(name)
        assert rr.task_dim == task.dim and get_task(name) is task
        tgt = task.make_target(T if task.has_orientation else task.point_target(T[:3, 3]), z=T[2, 3])
        res = task.ik_residual(tgt)
        Q, p = r.kinematics.pose(q)
        assert res.residual(Q, p) < 1e-12 and res.error(Q, p)[0].shape == (task.dim,)
        assert set(task.error_values(Q, p, tgt)) == set(task.error_names)
    with pytest.raises(kinredund.ChoiceError, match="axis"):
        get_task("tool")


@pytest.mark.parametrize("name", ["ur5", "panda"])
def test_axis_ik_optimum_is_checked_on_the_right_manifold(name):
    """solve_ik on the axis task: the optimality check's null space has n - 5 directions (that of G, not
    of K's 6 rows), and the reduced Hessian reported is that of the true Lagrangian
    Hess z + d(G^T lambda)/dtheta (central differences). (The d a / d theta term of the Lagrangian,
    K_omega^T a m^T K_omega at a solution, vanishes on that null space, where K_omega v is parallel to a.)"""
    r = ROBOTS[name]()
    q_seed = configurations(r, seed=6, count=1)[0]
    index = kinredund.JointDeviation(q_seed + 0.3)
    target = make_target("axis", r.fk(q_seed))
    res = kinredund.solve_ik(r, target, index, q0=q_seed)
    assert res.converged, res.reason
    opt = kinredund.check_optimality(r, target, res.q, index)
    assert opt.null_space.shape == (r.nq, r.nq - 5)
    assert opt.normality_residual < 1e-9  # the IK's stopping tolerance is 1e-12 scaled; this is a check
    resid = task_residual(target)
    Q, p, K, dk = r.kinematics.jacobian_hessian(res.q)
    G = resid.jacobian(K, resid.error(Q, p)[1])
    _, grad, H = index.evaluate(res.q)
    lam = np.linalg.lstsq(G.T, -grad, rcond=None)[0]

    def gt_lam(x):
        Qx, px, Kx = r.kinematics.jacobian(x)
        return resid.jacobian(Kx, resid.error(Qx, px)[1]).T @ lam

    L = opt.null_space
    want = L.T @ (H + central_difference(gt_lam, res.q)) @ L
    assert np.abs(opt.reduced_hessian - 0.5 * (want + want.T)).max() < 1e-6
