"""Joint-level IK (Chapter 4.2, Appendix D): starting configurations of Examples 4.1-4.3 as global
constrained minima, pose recovery on every robot, optimality reports checked by finite differences,
joint limits, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ALL_ROBOTS, IK_TOL, assert_ik_converged, configurations, robot, rounding

from kinredund import JointVectorError, TaskError
from kinredund.ik.solve import IKResult, check_optimality, solve_ik
from kinredund.indices import CustomIndex, IndexCheckError, JointDeviation, check_index, minimum_norm
from kinredund.kinematics import closure
from kinredund.kinematics.closure import rotation_log
from kinredund.kinematics.finite_diff import central_difference
from kinredund.tasks import make_target, orientation_error, task_residual
from kinredund.thesis.starts import example_4_1_start, example_4_2_start, example_4_3_start

EXAMPLES = {"4.1": example_4_1_start, "4.2": example_4_2_start, "4.3": example_4_3_start}
STARTS = {"4.1": 16, "4.2": 16, "4.3": 24}


def _self_motion_curvature(r, target, index, q, L, h=1e-3):
    """d^2 z / ds^2 along the self-motion through q with tangent L (unit), by central differences of
    z on the constraint manifold (points q + s L projected back onto g = x by pose-only solves)."""

    def z_on_manifold(s):
        res = solve_ik(r, target, q0=q + s * L, tol=1e-14)
        assert res.converged
        return index.value(res.q)

    return (z_on_manifold(h) - 2.0 * z_on_manifold(0.0) + z_on_manifold(-h)) / h**2


def _planar_self_motion(x, y, a=(2.0, 2.0, 2.0), n=400001):
    """Every configuration of the planar 3R reaching (x, y), on a grid of the last link's angle psi
    (both elbow branches): an independent, closed-form map of the constraint manifold."""
    psi = np.linspace(-np.pi, np.pi, n)
    wx, wy = x - a[2] * np.cos(psi), y - a[2] * np.sin(psi)
    c2 = (wx**2 + wy**2 - a[0] ** 2 - a[1] ** 2) / (2 * a[0] * a[1])
    ok = np.abs(c2) <= 1
    out = []
    for sign in (1.0, -1.0):
        q2 = sign * np.arccos(np.clip(c2, -1, 1))
        q1 = np.arctan2(wy, wx) - np.arctan2(a[1] * np.sin(q2), a[0] + a[1] * np.cos(q2))
        out.append(np.stack([q1, q2, psi - q1 - q2], axis=1)[ok])
    return np.vstack(out)


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_example_start_is_global_constrained_minimum(name):
    r, target, index = EXAMPLES[name]()
    best = solve_ik(r, target, index, starts=STARTS[name], seed=1)
    assert_ik_converged(r, target, best)  # converged, and the task held as a fresh FK pass measures it
    # the normality residual (Eq. D.30) afresh at the answer (check_optimality evaluates anew): within the
    # solver's bar max(tol, 1e-13 (1 + |grad z|)) plus the rounding of a fresh evaluation
    g = float(np.abs(index.evaluate(best.q)[1]).max())
    bar = max(IK_TOL, 1e-13 * (1.0 + g)) + rounding(g)
    assert check_optimality(r, target, best.q, index).normality_residual <= bar
    assert best.starts == STARTS[name]
    assert best.reduced_hessian_pd and best.reduced_hessian_min_eig > 0  # Eq. (D.33)
    assert np.isclose(best.objective, index.value(best.q), rtol=0, atol=1e-14)
    # no single start, from other seeds, finds a lower constrained minimum
    rng = np.random.default_rng(123)
    lo, hi = np.maximum(r.lower, -2 * np.pi), np.minimum(r.upper, 2 * np.pi)
    lower_found = []
    for _ in range(STARTS[name]):
        one = solve_ik(r, target, index, q0=rng.uniform(lo, hi))
        if one.converged and one.objective < best.objective - 1e-9:
            lower_found.append(one.objective)
    assert not lower_found, f"other starts found lower z: {lower_found} < {best.objective}"


@pytest.mark.parametrize("name", ["4.1", "4.2"])
def test_planar_example_minimum_matches_closed_form_map_of_the_manifold(name):
    """The planar manifold, sampled in closed form with each joint shifted by 2 pi k to its best
    value, has no point with z below the solver's minimum, and its minimum is the solver's."""
    r, target, index = EXAMPLES[name]()
    best = solve_ik(r, target, index, starts=STARTS[name])
    Q = _planar_self_motion(*target)
    ref, w = index.reference, index.weights
    Q = ref + (Q - ref + np.pi) % (2 * np.pi) - np.pi  # each joint's 2 pi shift closest to the reference
    z = 0.5 * ((Q - ref) ** 2 * w).sum(axis=1)
    assert best.objective <= z.min() + 1e-12
    assert z.min() - best.objective < 1e-8  # grid spacing 1.6e-5 rad: O(h^2)


@pytest.mark.parametrize("name", list(EXAMPLES))
def test_reduced_hessian_equals_curvature_along_the_self_motion(name):
    """Eq. (D.33) checked by finite differences: with n - m = 1 the reduced Hessian is the second
    derivative of z along the unit-speed self-motion curve."""
    r, target, index = EXAMPLES[name]()
    best = solve_ik(r, target, index, starts=STARTS[name])
    opt = check_optimality(r, target, best.q, index)
    assert opt.null_space.shape == (r.nq, 1) and opt.reduced_hessian.shape == (1, 1)
    fd = _self_motion_curvature(r, target, index, best.q, opt.null_space[:, 0])
    assert abs(fd - opt.reduced_hessian[0, 0]) < 1e-5 * max(1.0, abs(fd))
    # solve_ik's own report (from the terms of its converged iteration, not from check_optimality)
    assert abs(fd - best.reduced_hessian_min_eig) < 1e-5 * max(1.0, abs(fd))


def test_lambda_from_k_and_from_closure_jacobian_give_the_same_reduced_hessian():
    """Example 4.3: Lambda* = d(K^T lambda*)/dtheta (Eq. 4.37) and Lambda = d(J^T lambda)/dtheta of the
    closure 7-vector (Eq. 4.26, J = H K rank 6, minimum-norm lambda) agree on the null space."""
    r, target, index = example_4_3_start()
    best = solve_ik(r, target, index, starts=STARTS["4.3"])
    opt = check_optimality(r, target, best.q, index)
    Q, _, K, dK = r.kinematics.jacobian_derivative(best.q)
    _, grad, H = index.evaluate(best.q)
    J = closure.displacement_jacobian(Q, K)
    dJ = closure.displacement_jacobian_derivative(Q, K, dK)
    lam = np.linalg.lstsq(J.T, -grad, rcond=None)[0]
    assert np.linalg.norm(J.T @ lam + grad) < 1e-10  # normality (4.5) with the closure Jacobian
    L = opt.null_space
    assert np.abs(J @ L).max() < 1e-10
    reduced = L.T @ (H + closure.contract(lam, dJ)) @ L
    assert np.allclose(reduced, opt.reduced_hessian, atol=1e-9)


def test_example_4_3_with_bounds_keeps_the_limits_and_meets_kkt():
    """The unbounded minimum of Example 4.3 breaks the limit of axis 2; with bounds the minimum sits
    on it, the KKT residual vanishes and z grows along the self-motion into the feasible side."""
    r, target, index = example_4_3_start()
    free = solve_ik(r, target, index, starts=STARTS["4.3"])
    assert np.any((free.q < r.lower) | (free.q > r.upper))  # the documented reason to offer bounds
    best = solve_ik(r, target, index, starts=STARTS["4.3"], bounds=True)
    assert_ik_converged(r, target, best)  # converged; the KKT residual with the held limit: opt below
    assert np.all((best.q >= r.lower) & (best.q <= r.upper))
    assert best.objective >= free.objective - 1e-12
    opt = check_optimality(r, target, best.q, index, bounds=True)
    assert opt.active.any()
    L = check_optimality(r, target, best.q, index).null_space[:, 0]
    j = int(np.flatnonzero(opt.active)[0])
    inward = L if (best.q[j] >= r.upper[j]) == (L[j] < 0) else -L
    moved = solve_ik(r, target, q0=best.q + 1e-3 * inward, tol=1e-14)
    assert r.lower[j] <= moved.q[j] <= r.upper[j]
    assert index.value(moved.q) > best.objective


def _stationary_maximum_of_example_4_1():
    """A local maximum of z = 1/2 |theta|^2 along Example 4.1's self-motion: the minimum of -z there."""
    r, target, _ = example_4_1_start()
    neg = CustomIndex(lambda q: -0.5 * q @ q, lambda q: -q, lambda q: -np.eye(3))
    top = solve_ik(r, target, neg, q0=[0.34, 1.26, -1.43])  # near the maximum of the elbow-up branch
    assert top.converged and top.reduced_hessian_pd  # a minimum of -z ...
    return r, target, top


def test_second_order_report_flags_a_maximum():
    r, target, top = _stationary_maximum_of_example_4_1()
    at_max = solve_ik(r, target, minimum_norm(3), q0=top.q)  # ... is a stationary maximum of z
    assert at_max.converged and at_max.iterations == 0
    assert at_max.normality_residual < 1e-10
    assert not at_max.reduced_hessian_pd
    assert at_max.reduced_hessian_min_eig == pytest.approx(-top.reduced_hessian_min_eig, rel=1e-9)
    opt = check_optimality(r, target, top.q, minimum_norm(3))
    fd = _self_motion_curvature(r, target, minimum_norm(3), top.q, opt.null_space[:, 0])
    assert fd < 0 and abs(fd - opt.reduced_hessian_min_eig) < 1e-5 * abs(fd)


def test_constrained_solve_leaves_a_maximum_when_started_near_it():
    r, target, top = _stationary_maximum_of_example_4_1()
    res = solve_ik(r, target, minimum_norm(3), q0=top.q + np.array([1e-3, 0.0, 0.0]))
    assert res.converged and res.reduced_hessian_pd
    assert res.objective < minimum_norm(3).value(top.q)


@pytest.mark.parametrize("name", ALL_ROBOTS)
def test_pose_recovered_for_random_configurations(name):
    """Forward pose of a random configuration -> solve from home -> the same pose to 1e-10 m/rad."""
    r = robot(name)
    for q in configurations(r, seed=11, count=8):
        T = r.fk(q)
        target = T[:2, 3] if r.task == "planar" else T
        res = solve_ik(r, target, starts=8, seed=5)
        assert res.converged, res.reason
        got = r.fk(res.q)
        assert np.abs(got[:2, 3] - T[:2, 3]).max() < 1e-10
        if r.task == "pose":
            assert np.abs(got[:3, 3] - T[:3, 3]).max() < 1e-10
            assert orientation_error(got[:3, :3], T[:3, :3]) < 1e-10


@pytest.mark.parametrize("name", ["panda", "xarm7", "cybotech_p15"])
def test_bounded_pose_solve_stays_within_limits(name):
    r = robot(name)
    for q in configurations(r, seed=12, count=4, margin=0.02):
        res = solve_ik(r, r.fk(q), bounds=True, starts=30, seed=2)
        assert_ik_converged(r, r.fk(q), res)
        assert np.all((res.q >= r.lower) & (res.q <= r.upper))


def test_seed_outside_limits_is_projected_and_noted():
    r = robot("panda")
    q0 = r.home.copy()
    q0[3] = 0.5  # above the upper limit of axis 4 (-0.0698 rad)
    res = solve_ik(r, r.fk(r.home), q0=q0, bounds=True)
    assert "projected" in res.notes and "[3]" in res.notes
    assert res.converged and np.all((res.q >= r.lower) & (res.q <= r.upper))
    assert solve_ik(r, r.fk(r.home), q0=q0).notes == ""


def test_pose_error_jacobian_matches_finite_differences():
    r = robot("panda")
    rng = np.random.default_rng(3)
    for _ in range(3):
        qd, q = r.random_configuration(rng, 0.1), r.random_configuration(rng, 0.1)
        res = task_residual(make_target("pose", r.fk(qd)))
        Q, p, K = r.kinematics.jacobian(q)
        e, jl = res.error(Q, p)
        fd = central_difference(lambda x, res=res: res.error(*r.kinematics.pose(x))[0], q)
        assert np.abs(res.jacobian(K, jl) - fd).max() < 1e-7


@pytest.mark.parametrize("phi", [1e-7, 0.3, 2.0, np.pi - 1e-5, np.pi - 1e-7, np.pi - 1e-8, np.pi])
def test_rotation_log_inverts_rotation_from_invariants(phi):
    """The axis to ~1e-10 at every angle, near pi too (where vect Q = u sin(phi) has lost its digits)."""
    u = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    Q = closure.rotation_from_invariants(u, phi)
    w, angle = rotation_log(Q)
    assert angle == pytest.approx(phi, abs=1e-12)
    axis = w / angle
    assert np.abs(axis - u).max() < 1e-10 or (phi == np.pi and np.abs(axis + u).max() < 1e-10)
    u_ni, phi_ni = closure.natural_invariants(Q)
    assert phi_ni == pytest.approx(phi, abs=1e-12)
    assert np.abs(u_ni - u).max() < 1e-10 or (phi == np.pi and np.abs(u_ni + u).max() < 1e-10)


def test_unreachable_target_returns_the_closest_configuration():
    r = robot("planar3r")  # reach 6 m
    res = solve_ik(r, (10.0, 0.0), starts=3)
    assert not res.converged and res.reason
    assert 4.0 - 1e-12 <= res.residual < 4.0 + 1e-6  # the arm stretched towards the target
    res = solve_ik(r, (10.0, 0.0), minimum_norm(3), starts=2)
    assert not res.converged and res.reason and res.residual < 4.0 + 1e-3
    far = np.eye(4)
    far[:3, 3] = [5.0, 0.0, 0.5]
    res = solve_ik(robot("panda"), far, starts=3, bounds=True)
    assert not res.converged and res.reason and res.residual > 3.0


def test_timeout_is_reported():
    r, target, index = example_4_3_start()
    res = solve_ik(r, target, index, starts=1000, timeout=1e-4)
    assert res.reason == "timeout" or (res.converged and res.starts < 1000)
    res = solve_ik(r, target, index, q0=r.home, timeout=1e-9)
    assert not res.converged and res.reason == "timeout"


def test_pose_only_multistart_stops_at_first_success():
    r = robot("panda")
    res = solve_ik(r, r.fk(r.home), starts=50)
    assert res.converged and res.starts == 1 and res.iterations == 0


def test_custom_index_equals_builtin_and_is_checked():
    r, target, index = example_4_1_start()
    right = CustomIndex(lambda q: 0.5 * q @ q, lambda q: q.copy(), lambda q: np.eye(3))
    wrong = CustomIndex(lambda q: 0.5 * q @ q, lambda q: 2.0 * q, lambda q: np.eye(3))
    q = np.array([0.3, -0.4, 1.1])
    g_err, h_err = check_index(right, q)
    assert g_err < 1e-8 and h_err < 1e-8
    with pytest.raises(IndexCheckError, match="gradient"):
        check_index(wrong, q)
    a = solve_ik(r, target, right, q0=[0.1, 0.5, 0.5])
    b = solve_ik(r, target, index, q0=[0.1, 0.5, 0.5])
    assert a.converged and np.allclose(a.q, b.q, atol=1e-10)


def test_bad_input_raises_with_a_clear_message():
    r = robot("planar3r")
    with pytest.raises(TaskError, match=r"shape \(2,\)"):
        solve_ik(r, (1.0, 2.0, 3.0))
    with pytest.raises(TaskError, match="non-finite"):
        solve_ik(r, (np.nan, 1.0))
    with pytest.raises(TaskError, match="4x4"):
        solve_ik(robot("panda"), np.eye(3))
    with pytest.raises(JointVectorError, match=r"q0 must have shape \(3,\)"):
        solve_ik(r, (3.0, 3.0), q0=[0.0, 0.0])
    with pytest.raises(JointVectorError, match="non-finite"):
        solve_ik(r, (3.0, 3.0), q0=[0.0, np.inf, 0.0])
    with pytest.raises(TaskError, match="starts must be an integer >= 1"):
        solve_ik(r, (3.0, 3.0), starts=0)
    with pytest.raises(TaskError, match="tol must be"):
        solve_ik(r, (3.0, 3.0), tol=-1.0)
    with pytest.raises(TaskError, match="timeout must be"):
        solve_ik(r, (3.0, 3.0), timeout=0.0)
    with pytest.raises(TaskError, match=r"shapes \(3,\)/\(3, 3\)"):
        solve_ik(r, (3.0, 3.0), JointDeviation(np.zeros(4)))
    with pytest.raises(TaskError, match="for a 'pose' task"):
        solve_ik(r, make_target("pose", np.eye(4)))
    with pytest.raises(TaskError, match="fewer than the 6"):
        solve_ik(r.with_task("pose"), np.eye(4))


def test_non_numeric_and_malformed_input_raises_errors_of_the_family():
    """Input numpy cannot read as numbers, and 4x4 poses whose last row is not (0, 0, 0, 1), raise
    kinredund errors (never a bare ValueError) naming what is wrong."""
    with pytest.raises(TaskError, match="position target must be numeric"):
        make_target("position", "abc")
    with pytest.raises(TaskError, match="planar target must be numeric"):
        make_target("planar", ["x", 1.0])
    with pytest.raises(TaskError, match="pose target .* must be numeric"):
        make_target("pose", "abc")
    with pytest.raises(TaskError, match="rotation Q must be numeric"):
        make_target("pose", ("abc", np.zeros(3)))
    with pytest.raises(TaskError, match=r"position p \[m\] must have shape \(3,\)"):
        make_target("pose", (np.eye(3), np.zeros(4)))
    bad = np.eye(4)
    bad[3] = [0.0, 0.0, 0.5, 1.0]
    for call in (lambda: make_target("pose", bad), lambda: solve_ik(robot("panda"), bad)):
        with pytest.raises(TaskError, match=r"last row must be \(0, 0, 0, 1\)"):
            call()
    bad[3] = [0.0, 0.0, 0.0, 2.0]
    with pytest.raises(TaskError, match="last row"):
        make_target("pose", bad)
    got = make_target("pose", np.eye(4))
    assert np.array_equal(got.Q, np.eye(3)) and np.array_equal(got.p, np.zeros(3))
    with pytest.raises(TaskError, match="index reference must be numeric"):
        JointDeviation("abc")
    with pytest.raises(TaskError, match=r"index reference must have shape \(n,\)"):
        JointDeviation(np.zeros((2, 2)))
    with pytest.raises(TaskError, match="index weights must be numeric"):
        JointDeviation(np.zeros(3), "abc")
    with pytest.raises(TaskError, match=r"index weights must have shape \(3,\)"):
        JointDeviation(np.zeros(3), np.ones(2))
    with pytest.raises(TaskError, match=">= 0"):
        JointDeviation(np.zeros(3), [1.0, -1.0, 1.0])
    with pytest.raises(TaskError, match="non-finite"):
        JointDeviation([0.0, np.inf])


def test_pose_only_result_reports_the_residual_reached_and_no_index_terms():
    """Without an index the record's residual is the distance actually reached (by forward kinematics)
    and the index fields say that nothing was checked: 0, 0, False, nan."""
    r = robot("planar3r")
    res = solve_ik(r, (3.0, 3.0), q0=[0.3, 0.2, 0.1])
    assert isinstance(res, IKResult) and res.converged and res.reason == "" and res.iterations > 0
    assert res.residual == pytest.approx(np.linalg.norm(r.fk(res.q)[:2, 3] - (3.0, 3.0)), rel=0, abs=1e-15)
    assert (res.normality_residual, res.objective, res.reduced_hessian_pd) == (0.0, 0.0, False)
    assert np.isnan(res.reduced_hessian_min_eig) and res.starts == 1 and res.time_s > 0.0


def _at_a_limit(r, rng):
    """A random q with one joint at a limit, and the box lb <= d <= ub of a step from it."""
    q = r.random_configuration(rng)
    j = rng.integers(r.nq)
    q[j] = r.upper[j] if rng.random() < 0.5 else r.lower[j]
    return q, r.lower - q, r.upper - q


def test_box_step_guess_is_the_proxsuite_solution(monkeypatch):
    """The active-set guess of the bounded least-squares step is taken only when it is the QP's
    solution: compare with proxsuite on random problems with joints at and past their limits."""
    from kinredund.ik import qp as ik_qp

    rng = np.random.default_rng(4)
    r = robot("panda")
    guessed = 0
    for _ in range(100):
        q, lb, ub = _at_a_limit(r, rng)
        G, e, mu = r.velocity_jacobian(q), 0.1 * rng.normal(size=6), 1e-3
        H, g = G.T @ G + mu * np.eye(7), G.T @ e
        guess = ik_qp._active_set_guess(H, g, lb, ub)
        monkeypatch.setattr(ik_qp, "GUESS_ROUNDS", 0)
        exact = ik_qp.BoxStep(7, 6).least_squares(G, e, mu, lb, ub)
        monkeypatch.undo()
        if guess is not None:
            guessed += 1
            assert np.abs(guess - exact).max() < 1e-7  # proxsuite: eps_abs 1e-11 over mu 1e-3
    assert guessed >= 20


def _equality_problem(r, rng):
    """A random feasible equality-form box QP (B, c, G, e, lb, ub) of a step from a q with a joint at a limit."""
    q, lb, ub = _at_a_limit(r, rng)
    G = r.velocity_jacobian(q)[:3]  # three constraint rows: four dimensions to meet the box in
    e = -G @ rng.uniform(lb, ub)  # feasible: some d in the box meets G d = -e
    A = rng.normal(size=(r.nq, r.nq))
    return A @ A.T + 0.1 * np.eye(r.nq), 5.0 * rng.normal(size=r.nq), G, e, lb, ub


def test_box_step_equality_guess_is_the_proxsuite_solution(monkeypatch):
    """The active-set guesses of the bounded Newton step (min 1/2 d^T B d + c^T d, G d = -e, within the box) are
    taken only when they are the QP's solution: compare with proxsuite on random feasible problems (about half of
    the solved ones hold two joints or more at a bound), and check the constraints on their own."""
    from kinredund.ik import qp as ik_qp

    rng = np.random.default_rng(5)
    r = robot("panda")
    guessed = 0
    for _ in range(100):
        B, c, G, e, lb, ub = _equality_problem(r, rng)
        guess = ik_qp._equality_guess(B, c, G, e, lb, ub)
        monkeypatch.setattr(ik_qp, "GUESS_ROUNDS", 0)
        exact = ik_qp.BoxStep(7, 3).equality(B, c, G, e, lb, ub)
        monkeypatch.undo()
        if guess is not None:
            guessed += 1
            assert np.all(guess >= lb) and np.all(guess <= ub)
            assert np.abs(G @ guess + e).max() <= 1e-12 * (1.0 + np.abs(e).max())  # an exact solve, rounding only
            assert exact is not None and np.abs(guess - exact).max() < 1e-7  # proxsuite: eps_abs 1e-11
    assert guessed >= 50


def test_proxsuite_answer_is_polished_to_the_exact_solution_of_its_active_set():
    """Where the guesses fail and proxsuite solves the bounded Newton step's QP, the step returned is proxsuite's
    answer polished: the exact solution of the equality-constrained QP on proxsuite's active set (its joints within
    1e-6 of a bound; the KKT system solved here with numpy), which meets the QP's KKT conditions, while proxsuite's
    own answer is off by up to ~1e-9 (its eps_abs 1e-11 is on the residuals)."""
    from kinredund.ik import qp as ik_qp

    rng = np.random.default_rng(5)
    r = robot("panda")
    n, m = r.nq, 3
    cases, raw_off = 0, 0.0
    for _ in range(200):
        B, c, G, e, lb, ub = _equality_problem(r, rng)
        if ik_qp._equality_guess(B, c, G, e, lb, ub) is not None:
            continue  # proxsuite is used only where the guesses fail
        box = ik_qp.BoxStep(n, m)
        d = box.equality(B, c, G, e, lb, ub)
        x = box._eq[0].results.x
        if d is None:  # infeasible for proxsuite (rare: e is drawn feasible)
            continue
        cases += 1
        at_lb, at_ub = x - lb <= 1e-6, ub - x <= 1e-6
        free = ~(at_lb | at_ub)
        dh = np.where(at_lb, lb, np.where(at_ub, ub, 0.0))
        K = np.block([[B[np.ix_(free, free)], G[:, free].T], [G[:, free], np.zeros((m, m))]])
        sol = np.linalg.solve(K, np.concatenate([-(c + B @ dh)[free], -e - G @ dh]))
        exact = dh.copy()
        exact[free] = sol[: free.sum()]
        # two LU solves of one KKT system (cond(K) < 1e4 here): rounding only (1e-15 seen)
        assert np.abs(d - exact).max() <= 1e-13 * max(1.0, np.abs(exact).max())
        # KKT: within the box, G d = -e, and the Lagrangian's gradient pushes every held joint outwards
        assert np.all(d >= lb) and np.all(d <= ub)
        assert np.abs(G @ d + e).max() <= rounding(np.abs(G).max() * np.abs(d).max() + np.abs(e).max())
        grad = B @ exact + c + G.T @ sol[free.sum():]
        bar = rounding(np.abs(B).max() * np.abs(exact).max() + np.abs(c).max())
        assert np.all(grad[at_lb] >= -bar) and np.all(grad[at_ub] <= bar) and np.abs(grad[free]).max() <= bar
        raw_off = max(raw_off, float(np.abs(x - exact).max()))
    assert cases >= 20 and raw_off > 1e-11  # proxsuite was used, and its own answer was not the exact one


def test_unbounded_result_turns_free_wrist_joints_into_their_limits():
    r, target, index = example_4_3_start()
    res = solve_ik(r, target, index, starts=STARTS["4.3"])
    wrist = slice(4, 7)  # z does not depend on them: any 2 pi turn is free
    assert np.all((res.q[wrist] >= r.lower[wrist]) & (res.q[wrist] <= r.upper[wrist]))
    assert_ik_converged(r, target, res)


@pytest.mark.parametrize("bounds", [False, True])
def test_constrained_minimum_on_the_panda_improves_on_the_pose_solution(bounds):
    from kinredund.indices import mid_range

    r = robot("panda")
    index = mid_range(r.lower, r.upper)
    for q in configurations(r, seed=13, count=5, margin=0.02):
        T = r.fk(q)
        pose = solve_ik(r, T, bounds=True, starts=20)
        best = solve_ik(r, T, index, q0=pose.q, bounds=bounds)
        assert_ik_converged(r, T, best)
        assert best.objective <= index.value(pose.q) + 1e-12
        if bounds:
            assert np.all((best.q >= r.lower) & (best.q <= r.upper))
        else:
            assert best.reduced_hessian_pd


def test_unrolled_closure_residual_equals_the_closure_vector():
    """TaskResidual.residual (the closure 7-vector's norm, hand-unrolled for speed) equals the norm of
    closure.closure_vector (Eq. 2.13) on random Panda pose pairs; for position and planar targets it
    is the distance of point P from the target."""
    r = robot("panda")
    rng = np.random.default_rng(77)
    for _ in range(20):
        qd, q = r.random_configuration(rng), r.random_configuration(rng)
        target = make_target("pose", r.fk(qd))
        Q, p = r.kinematics.pose(q)
        ref = np.linalg.norm(closure.closure_vector(Q, p, target.Q, target.p))
        assert abs(task_residual(target).residual(Q, p) - ref) < 1e-15 * max(1.0, ref)
    p_d = r.fk(qd)[:3, 3]
    assert task_residual(make_target("position", p_d)).residual(Q, p) == pytest.approx(
        np.linalg.norm(p - p_d), rel=1e-15, abs=0.0)
    assert task_residual(make_target("planar", p_d[:2], z=5.0)).residual(Q, p) == pytest.approx(
        np.linalg.norm(p[:2] - p_d[:2]), rel=1e-15, abs=0.0)


# -- the lean pose-only solver (index=None) -----------------------------------------------------------
@pytest.mark.parametrize("name", ["panda", "planar3r", "puma7"])
def test_error_terms_are_the_newton_error(name):
    """The cheap tuple form of the error (pose-only iterations) equals TaskResidual.error."""
    r = robot(name)
    rng = np.random.default_rng(31)
    for _ in range(3):
        qd, q = r.random_configuration(rng, 0.1), r.random_configuration(rng, 0.1)
        T = r.fk(qd)
        res = task_residual(make_target(r.task, T[:2, 3] if r.task == "planar" else T))
        Q, p = r.kinematics.pose(q)
        e, phi = res.error_terms(Q, p)
        ref = res.error(Q, p)[0]
        assert np.allclose(e, ref, rtol=0, atol=1e-15)
        assert phi == pytest.approx(float(ref @ ref), rel=1e-14)


@pytest.mark.parametrize("name", ["panda", "puma7"])
def test_pose_only_steps_converge_like_newton_near_a_solution(name):
    """G = K for pose targets is the Jacobian of e up to Jl^-1 = 1 + O(|e|): near a solution each
    iteration squares the residual (until the damping floor and round-off), as Newton's method does."""
    r = robot(name)
    rng = np.random.default_rng(21)
    for _ in range(4):
        qs = r.random_configuration(rng, 0.1)
        T = r.fk(qs)
        d = rng.normal(size=r.nq)
        q0 = qs + 0.05 * d / np.linalg.norm(d)
        rs = [check_optimality(r, T, q0).residual]
        rs += [solve_ik(r, T, q0=q0, max_iter=k, tol=1e-14).residual for k in range(1, 5)]
        for a, b in zip(rs, rs[1:], strict=False):
            assert b <= max(100.0 * a * a, 1e-3 * a, 1e-14), rs


def test_freeze_and_clip_holds_joints_pushed_out_of_their_limits():
    """A joint at its upper limit that the damped step would push further is held there; the other
    joints take the damped least-squares step of theirs, argmin ||G_f d + e||^2 + mu ||d||^2 (lstsq of
    [G_f; sqrt(mu) 1] d = [-e; 0]), which leaves a far smaller linearised error than the clipped
    unheld step; a joint pushed past a limit it was not at is clipped, not held."""
    from kinredund.ik.common import Setup
    from kinredund.ik.pose_only import freeze_and_clip as _freeze_and_clip

    r = robot("panda")
    rng = np.random.default_rng(5)
    q = r.random_configuration(rng, 0.1)
    q[3] = r.upper[3]
    G = r.velocity_jacobian(q)
    e = -0.2 * G[:, 3]  # the error of a pose that joint 3 raised by 0.2 rad would reach
    mu = 1e-3
    x = np.linalg.solve(G @ G.T + mu * np.eye(6), e)
    qn = q - G.T @ x
    assert qn[3] > r.upper[3]
    s = Setup(kin=r.kinematics, res=task_residual(make_target("pose", r.fk(q))), index=None, lower=r.lower,
              upper=r.upper, bounds=True, rtol=1e-10, tol=1e-10, max_iter=10, deadline=None, box=None)
    got, held = _freeze_and_clip(s, q, qn, G, e, mu)
    assert held == [3] and got[3] == r.upper[3]
    free = [0, 1, 2, 4, 5, 6]
    A = np.vstack([G[:, free], np.sqrt(mu) * np.eye(6)])
    d = np.linalg.lstsq(A, np.concatenate([-e, np.zeros(6)]), rcond=None)[0]
    assert np.all((q[free] + d > r.lower[free]) & (q[free] + d < r.upper[free]))  # nothing to clip here
    assert np.abs(got[free] - (q[free] + d)).max() < 1e-12
    linearised = lambda x: np.linalg.norm(e + G @ (x - q))  # noqa: E731
    assert linearised(got) < 0.1 * linearised(np.clip(qn, r.lower, r.upper))
    # joint 6 (index 5) just above its lower limit, which the step pushes it past: clipped there
    assert d[4] < -0.02
    q2 = q.copy()
    q2[5] = r.lower[5] + 0.01
    got2, held2 = _freeze_and_clip(s, q2, q2 - G.T @ x, G, e, mu)
    assert held2 == [3] and got2[5] == r.lower[5] and got2[3] == r.upper[3]
    assert np.abs(np.delete(got2 - q2, [3, 5]) - np.delete(d, 4)).max() < 1e-12


def test_turn_past_limits_continues_a_joint_the_other_way_round():
    """Panda joint 7 (range 2 pi - 0.49 rad) held at its upper limit goes to its lower limit, the angle
    0.49 rad further on; an xArm7 joint (range 4 pi) turns by exactly 2 pi: the same pose; a joint
    whose range misses a turn by more than TURN_GAP (Panda joint 2) is not turned."""
    from kinredund.ik.common import Setup
    from kinredund.ik.pose_only import turn_past_limits as _turn_past_limits

    def setup(r):
        return Setup(kin=r.kinematics, res=task_residual(make_target("pose", np.eye(4))), index=None,
                     lower=r.lower, upper=r.upper, bounds=True, rtol=1e-10, tol=1e-10, max_iter=10,
                     deadline=None, box=None, revolute=r.revolute)

    panda, xarm = robot("panda"), robot("xarm7")
    q = panda.home.copy()
    q[6] = panda.upper[6]
    out = _turn_past_limits(setup(panda), q, [6])
    assert out[6] == panda.lower[6] and np.array_equal(np.delete(out, 6), np.delete(q, 6))
    assert (out[6] - q[6]) % (2 * np.pi) == pytest.approx(2 * np.pi - (panda.upper[6] - panda.lower[6]))
    q = panda.home.copy()
    q[1] = panda.lower[1]
    assert _turn_past_limits(setup(panda), q, [1]) is None
    q = xarm.home.copy()
    q[2] = xarm.lower[2] + 0.1
    q[4] = xarm.upper[4]
    out = _turn_past_limits(setup(xarm), q, [4])
    assert out[4] == pytest.approx(xarm.upper[4] - 2 * np.pi)
    assert np.allclose(xarm.fk(out), xarm.fk(q), atol=1e-12)


@pytest.mark.parametrize("name", ["panda", "xarm7"])
def test_bounded_multistart_solves_the_trac_ik_protocol(name):
    """TRAC-IK's protocol without its time budget: random configurations within the limits -> forward
    pose -> solve seeded at mid-limits (tol 1e-5): every target solved within the limits."""
    r = robot(name)
    mid = 0.5 * (r.lower + r.upper)
    for q in configurations(r, seed=2015, count=60):
        res = solve_ik(r, r.fk(q), q0=mid, bounds=True, tol=1e-5, starts=64)
        assert res.converged, res.reason
        assert np.all((res.q >= r.lower) & (res.q <= r.upper))
        assert res.residual < 1e-5


def test_multistart_samples_do_not_depend_on_the_batch_size(monkeypatch):
    """The start samples are drawn SAMPLE_BATCH at a time: the same draws as one at a time, so the
    result of a solve that needs several starts is the same for any batch size."""
    from kinredund.ik import solve as ik

    r = robot("panda")
    mid = 0.5 * (r.lower + r.upper)
    rng = np.random.default_rng(8)
    for _ in range(200):
        T = r.fk(r.random_configuration(rng))
        res = solve_ik(r, T, q0=mid, bounds=True, tol=1e-5, starts=64)
        if res.starts >= 4:
            break
    assert res.converged and res.starts >= 4
    monkeypatch.setattr(ik, "SAMPLE_BATCH", 1)
    one = solve_ik(r, T, q0=mid, bounds=True, tol=1e-5, starts=64)
    monkeypatch.setattr(ik, "SAMPLE_BATCH", 3)
    three = solve_ik(r, T, q0=mid, bounds=True, tol=1e-5, starts=64)
    assert one.starts == three.starts == res.starts
    assert np.array_equal(one.q, res.q) and np.array_equal(three.q, res.q)


def test_constrained_minimum_seeded_at_the_index_reference_off_the_path():
    """grad z = 0 at the seed: the merit function's penalty weight must still be positive."""
    import kinredund
    from kinredund.indices import JointDeviation

    r = kinredund.load_robot("panda")
    target = r.fk(r.home)
    target[:3, 3] += 0.01
    res = kinredund.solve_ik(r, target, JointDeviation(r.home), q0=r.home)
    assert_ik_converged(r, target, res)
    assert res.reduced_hessian_pd


def test_a_stop_s_cause_is_its_reason_without_numbers():
    """IKResult.cause: two stops alike at points a rounding apart compare equal; different kinds do not."""
    from kinredund.ik.solve import IKResult

    def stop(reason):
        return IKResult(np.zeros(7), False, 200, 1e-3, 0.0, 0.0, False, np.nan, reason)

    a, b = stop("max_iter (200) reached: residual 1.25e-07, normality 3.1e-05"), stop(
        "max_iter (200) reached: residual 9.7e-08, normality -2e-05")
    assert a.cause == b.cause == "max_iter (#) reached: residual #, normality #"
    assert stop("line search failed at residual 0.5").cause != a.cause
    assert stop("").cause == ""
