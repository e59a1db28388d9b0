"""Chapter 4: the resolved-rate scheme reproduces Examples 4.1-4.3 and closes the joint path."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from conftest import configurations, robot

import kinredund
from kinredund.indices import CustomIndex, JointDeviation, TimeVaryingReference, minimum_norm
from kinredund.kinematics.finite_diff import central_difference
from kinredund.paths import Circle, FunctionPath
from kinredund.tasks import task_terms
from kinredund.thesis.chapter4 import indefinite_interval, load_example, run_example
from kinredund.tracking import Tracker, track
from kinredund.tracking.compiled_correct import CoreCorrector
from kinredund.tracking.linalg import RateQP, classify, hermite_weights, solve_rates
from kinredund.tracking.predictor_corrector import PredictorCorrector


@functools.cache
def example(name):
    return load_example(name)


@functools.cache
def run(name, mode="default", scheme="augmented", loops=10):
    return run_example(example(name), loops=loops, mode=mode, scheme=scheme)


@pytest.mark.parametrize("name", ["4.1", "4.2", "4.3"])
def test_default_mode_closes_the_joint_path_loop_after_loop(name):
    tr = run(name)
    assert tr.loop_drift.shape == (10,)
    assert tr.loop_drift.max() < 1e-8
    assert tr.position_error.max() < 1e-8
    assert tr.normality_residual.max() < 1e-9  # on the constrained optimum all along
    if name == "4.3":
        assert tr.trace_error.max() < 1e-8 and tr.vect_error.max() < 1e-8


@pytest.mark.parametrize("name", ["4.1", "4.2", "4.3"])
def test_pseudoinverse_drifts_orders_of_magnitude_more(name):
    ours = run(name)
    pinv = run(name, scheme="pseudoinverse")
    assert pinv.position_error.max() < 1e-8  # it tracks the path just as well ...
    assert pinv.loop_drift[-1] > 1e-4  # ... but its joints do not come back
    assert pinv.loop_drift[-1] > 1e4 * max(ours.loop_drift[-1], 1e-15)


def test_example_4_3_velocity_jacobian_scheme_is_cyclic_with_lu():
    tr = run("4.3", scheme="velocity", loops=3)
    assert set(tr.solver) == {"lu"}  # M* is not symmetric: no QP
    assert tr.loop_drift.max() < 1e-8
    assert tr.position_error.max() < 1e-8 and tr.vect_error.max() < 1e-8
    aug = run("4.3")
    assert np.abs(tr.q - aug.q[: len(tr.q)]).max() < 1e-8  # both forms follow the same optimal path


def test_example_4_2_M_indefinite_on_one_interval_and_lu_there():
    tr_auto = run_example(example("4.2"), loops=1, mode="default")
    interval = indefinite_interval(tr_auto)
    assert interval is not None
    lo, hi = interval
    assert 1.8 < lo < 2.6 and 3.7 < hi < 4.4, interval  # the thesis reports roughly 2.3 s to 4 s
    neg = tr_auto.m_eigs.min(axis=1) < 0
    idx = np.flatnonzero(neg)
    assert np.all(np.diff(idx) == 1)  # one contiguous interval
    assert tr_auto.m_null_eigs.min() > 0  # the projection stays positive definite
    labels = np.array(tr_auto.solver)
    assert set(labels[neg]) == {"qp_aug"} and set(labels[~neg]) == {"qp"}
    # the thesis's rule (QP only where M itself is positive definite): LU on exactly that interval
    tr = run_example(example("4.2"), loops=1, mode="thesis")
    lab = np.array(tr.solver)
    neg_t = tr.m_eigs.min(axis=1) < 0
    assert set(lab[neg_t]) == {"lu"} and set(lab[~neg_t]) == {"qp"}
    assert run("4.2").loop_drift.max() < 1e-8  # and the path stays cyclic


def test_example_4_1_M_indefinite_but_projection_positive_definite():
    """In 4.1 M itself has a negative eigenvalue all along while Z^T M Z > 0: still a convex QP."""
    tr = run_example(example("4.1"), loops=1)
    assert tr.m_eigs.min(axis=1).max() < 0 and tr.m_null_eigs.min() > 0
    assert set(tr.solver) == {"qp_aug"}


@pytest.mark.parametrize("name", ["4.1", "4.2", "4.3"])
def test_thesis_mode_errors_are_of_the_thesis_order(name):
    tr = run(name, mode="thesis", loops=1)
    assert 1e-7 < tr.position_error.max() < 2e-3
    assert tr.loop_drift[0] > 1e-5  # the explicit scheme drifts a little every loop
    if name == "4.3":
        assert tr.trace_error.max() < 1e-2 and tr.vect_error.max() < 1e-2


def test_qp_and_lu_give_the_same_rates():
    ex = example("4.2")
    rr = Tracker(ex.robot, ex.path, ex.index, ex.q0, ex.path.period / 200, limits=False)
    prox = RateQP(3, 2)
    checked = {"qp": 0, "qp_aug": 0}
    for _ in range(200):
        rr.step()
        pt = rr.stepper.ev.point(rr.q, rr.t)
        M, top = pt.system(rr.lam)
        label = classify(M, pt.J, "auto")
        if label == "lu":
            continue
        a = solve_rates(M, pt.J, top, pt.xdot, label=label, backend="proxsuite", prox=prox)
        b = solve_rates(M, pt.J, top, pt.xdot, label="lu", backend="kkt", prox=None)
        assert np.abs(a.thetadot - b.thetadot).max() < 1e-8
        assert np.abs(a.lamdot - b.lamdot).max() < 1e-6
        checked[label] += 1
    assert checked["qp"] > 10 and checked["qp_aug"] > 10


@pytest.mark.parametrize("name", ["planar3r", "cybotech_p15", "panda"])
@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
def test_task_jacobians_and_their_derivatives_match_finite_differences(name, scheme):
    """The scheme's J and Lambda = d(J^T lam)/dtheta (built on the kinematics layer) against central differences."""
    r = robot(name)
    rng = np.random.default_rng(11)
    for q_star in configurations(r, seed=11, count=2):
        Q0, p0 = r.kinematics.pose(q_star)
        sample = kinredund.paths.PathSample(p0 + 0.01, np.zeros(3), Q0 @ _rot(0.3), np.zeros(3))

        def terms(q, sample=sample):
            return task_terms(r.task, scheme, *r.kinematics.jacobian_hessian(q), sample)

        q = q_star + 0.05
        tt = terms(q)
        if not (scheme == "velocity" and r.task == "pose"):  # the log map's Jacobian is K only at r = 0
            assert np.abs(tt.J - central_difference(lambda x: terms(x).r, q)).max() < 1e-7
        lam = rng.normal(size=len(tt.r))
        fd = central_difference(lambda x, lam=lam: terms(x).J.T @ lam, q)
        assert np.abs(tt.Lambda(lam) - fd).max() < 1e-7


def test_lambda_of_the_pose_task_is_the_contraction_of_the_checked_tensor():
    """No second derivative code: the fused Lambda equals lam . dJ with dJ from closure (foundation-tested)."""
    from kinredund.kinematics import closure
    from kinredund.tasks.pose import U_REL

    r = robot("panda")
    rng = np.random.default_rng(5)
    for q in configurations(r, seed=5, count=3):
        Q, p, K, dk = r.kinematics.jacobian_hessian(q)
        Q_d = Q @ _rot(0.7)
        sample = kinredund.paths.PathSample(p, np.zeros(3), Q_d, np.zeros(3))
        lam = rng.normal(size=6)
        # the target-frame rows: Q_rel = Q_d^T Q and K_rel = [Q_d^T K_omega; K_v]
        K_rel = np.concatenate([Q_d.T @ K[:3], K[3:]])
        dK = dk.tensor()
        dK_rel = np.concatenate([np.einsum("ab,bik->aik", Q_d.T, dK[:3]), dK[3:]])
        dJ = closure.displacement_jacobian_derivative(Q_d.T @ Q, K_rel, dK_rel)
        want = closure.contract(U_REL @ lam, dJ)
        assert np.abs(task_terms("pose", "augmented", Q, p, K, dk, sample).Lambda(lam) - want).max() < 1e-12


def test_explicit_time_derivative_of_the_target_frame_jacobian():
    """The augmented pose task's rows live in the moving target frame: dJ/dt at fixed q enters Eq. (4.24)."""
    from kinredund.problems import panda_circle

    r, path, _, q0 = panda_circle(wrist_amplitude=np.radians(15))
    q = q0 + 0.05
    Q, p, K, dk = r.kinematics.jacobian_hessian(q)
    lam = np.random.default_rng(4).normal(size=6)
    for t in (0.3, 2.0):
        dJdt_T = task_terms("pose", "augmented", Q, p, K, dk, path(t)).dJdt_T(lam)
        fd = central_difference(
            lambda x: task_terms("pose", "augmented", Q, p, K, None, path(x[0])).J.T @ lam, np.array([t]))[..., 0]
        assert np.abs(dJdt_T - fd).max() < 1e-7 and np.abs(fd).max() > 1e-2


def _rot(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_algorithmic_singularity_is_reported():
    """R singular while J has full rank: z = 1/2 (q - q0)^T J0^T J0 (q - q0) has M = J0^T J0 at q0."""
    r = robot("planar3r")
    q0 = np.array([0.3, 0.8, 0.9])
    J0 = r.position_jacobian(q0)[:2]
    A = J0.T @ J0
    index = CustomIndex(lambda q: 0.5 * (q - q0) @ A @ (q - q0), lambda q: A @ (q - q0), lambda q: A)
    p0 = r.fk(q0)[:2, 3]
    path = Circle(p0 - np.array([0.5, 0.0]), 0.5, 1.0)
    with pytest.raises(kinredund.SingularityError) as err:
        track(r, path, index, q0)
    assert "algorithmic" in str(err.value) and err.value.t == 0.0 and err.value.sigma_min < 1e-9
    assert err.value.q == pytest.approx(q0.tolist())


def test_path_leaving_the_workspace_says_when():
    r = robot("planar3r")
    q0 = np.array([0.2, 0.6, 0.6])
    p0 = r.fk(q0)[:2, 3]
    direction = p0 / np.linalg.norm(p0)
    # starts at p0 and reaches 3 m further out: beyond the 6 m reach
    path = Circle(p0 + 1.5 * direction, 1.5, 1.0, axis_x=(-direction[0], -direction[1], 0.0))
    with pytest.raises((kinredund.PathError, kinredund.SingularityError)) as err:
        track(r, path, minimum_norm(3), q0)
    assert err.value.t is not None and 0 < err.value.t < path.period
    assert "t = " in str(err.value)


def test_singular_start_is_reported():
    r = robot("planar3r")
    q0 = np.zeros(3)  # stretched arm: J has rank 1
    path = Circle((5.0, 0.0), 1.0, 1.0)
    with pytest.raises(kinredund.SingularityError, match="t = 0"):
        track(r, path, minimum_norm(3), q0)


@pytest.mark.parametrize("jump", [0.02, 0.3])
def test_corrector_recovers_from_a_jump_in_the_path(jump, monkeypatch):
    """A step the predictor misses badly: chord iterations, then fresh factorisations, end on F = 0 itself."""
    r = robot("planar3r")
    q0 = np.array([0.2, 0.6, 0.6])
    p0 = r.fk(q0)[:2, 3]

    def fn(t):
        p = p0 + np.array([0.1 * t, 0.0]) + (np.array([0.0, jump]) if t >= 0.5 else 0.0)
        return p, np.array([0.1, 0.0])

    fresh = []
    newton = PredictorCorrector._newton
    monkeypatch.setattr(PredictorCorrector, "_newton",
                        lambda self, *a, **k: (fresh.append(self.t), newton(self, *a, **k))[1])
    solve = CoreCorrector._solve  # the compiled backend's corrector solves: the fallback is the core's (restarts)

    def core_solve(self, y, newton):
        before = self.restarts
        made = solve(self, y, newton)
        if self.restarts > before:
            fresh.append(self.stepper.t)
        return made

    monkeypatch.setattr(CoreCorrector, "_solve", core_solve)
    # the strict tracker (the default) reports the path's jump instead of following it (issue 15)
    with pytest.raises(kinredund.TrackingError) as err:
        track(r, FunctionPath(fn), minimum_norm(3), q0, duration=1.0, steps=40)
    assert err.value.cause == "path_discontinuity" and err.value.t < 0.5
    tr = track(r, FunctionPath(fn), minimum_norm(3), q0, duration=1.0, steps=40, strict=False)
    assert tr.position_error.max() < 1e-11 and tr.normality_residual.max() < 1e-11
    # the start (the Python stepper's on the Python backend: the compiled one corrects it in the core, start_run),
    # then the jump for the larger one
    assert (0.0 in fresh) == (tr.meta["backend"] == "python") and (jump < 0.1 or 0.5 in fresh)
    # after the jump the joints sit at the constrained minimum of the shifted path
    k = int(np.argmax(tr.t >= 0.5))
    best = kinredund.solve_ik(r, tr.p_desired[k][:2], minimum_norm(3), q0=tr.q[k])
    assert np.abs(best.q - tr.q[k]).max() < 1e-8


@pytest.mark.parametrize("bad", ["p", "v"])
@pytest.mark.parametrize(("mode", "scheme"), [("default", "augmented"), ("default", "velocity"),
                                              ("thesis", "augmented"), ("default", "pseudoinverse"),
                                              ("thesis", "liegeois")])
def test_non_finite_path_sample_says_when(bad, mode, scheme):
    """The stepper reads samples unchecked and checks its results: the path's own message, with t, either way."""
    r = robot("planar3r")
    q0 = np.array([0.2, 0.6, 0.6])
    p0 = r.fk(q0)[:2, 3]

    def fn(t):
        p, v = p0 + np.array([0.1 * t, 0.0]), np.array([0.1, 0.0])
        if t > 0.5:
            return (np.array([np.nan, 0.0]), v) if bad == "p" else (p, np.array([np.inf, -np.inf]))
        return p, v

    with pytest.raises(kinredund.PathError, match=rf"non-finite {bad} at t = 0\.525 s") as err:
        track(r, FunctionPath(fn), minimum_norm(3), q0, duration=1.0, steps=40, mode=mode, scheme=scheme,
              limits=mode == "default" and scheme in ("augmented", "velocity"))
    assert err.value.t == pytest.approx(0.525)


def test_start_off_the_path_and_bad_options():
    r = robot("planar3r")
    path = Circle((3.0, 3.0), 0.8, 1.0)
    with pytest.raises(kinredund.PathError, match="away from the path"):
        track(r, path, minimum_norm(3), np.array([0.1, 0.2, 0.3]))
    q0 = example("4.1").q0
    with pytest.raises(kinredund.ChoiceError, match="augmented, velocity, pseudoinverse, liegeois"):
        track(r, path, minimum_norm(3), q0, scheme="jacobian_transpose")
    with pytest.raises(kinredund.ChoiceError, match="default, thesis"):
        track(r, path, minimum_norm(3), q0, mode="fast")
    with pytest.raises(kinredund.PathError, match="needs a performance index"):
        track(r, path, None, q0)
    with pytest.raises(kinredund.PathError, match="orientation"):
        track(robot("cybotech_p15"), Circle((0.16, 0, 0.36), 0.14, 1.0), minimum_norm(7), np.zeros(7))


def test_liegeois_baseline_tracks_but_is_not_cyclic_with_optimum():
    ex = example("4.2")
    tr = run_example(ex, loops=3, scheme="liegeois")
    assert tr.position_error.max() < 1e-8
    assert tr.normality_residual.max() > 1e-3  # off the constrained optimum
    ours = run("4.2")
    assert tr.loop_drift.max() > 1e4 * max(ours.loop_drift.max(), 1e-15)


@functools.cache
def time_varying_case():
    """The planar 3R following a feasible joint path q*(t) (Eq. 6.27): (robot, path, index, q*, fn, qa)."""
    r = robot("planar3r")
    qa = np.array([0.4, 0.7, 0.5])
    w = 2 * np.pi / 5.0

    def q_star(t):
        return qa + 0.1 * np.array([np.sin(w * t), np.cos(w * t) - 1, 0.5 * np.sin(2 * w * t)])

    def q_star_rate(t):
        return 0.1 * w * np.array([np.cos(w * t), -np.sin(w * t), np.cos(2 * w * t)])

    def fn(t):
        q, qd = q_star(t), q_star_rate(t)
        return r.fk(q)[:2, 3], r.position_jacobian(q)[:2] @ qd

    return r, FunctionPath(fn, period=5.0), TimeVaryingReference(q_star, q_star_rate), q_star, fn, qa


def test_time_varying_index_feed_forward():
    """Eq. (6.27): with h = 1/2||q - q*(t)||^2 and q*(t) on a feasible joint path, the scheme follows q*(t)."""
    r, path, index, q_star, fn, qa = time_varying_case()
    tr = track(r, path, index, q_star(0.0), loops=2)
    err = max(np.abs(tr.q[i] - q_star(t)).max() for i, t in enumerate(tr.t))
    assert err < 1e-9
    assert tr.loop_drift.max() < 1e-9
    static = track(r, FunctionPath(fn, period=5.0), JointDeviation(qa), _start(r, qa, fn), loops=1)
    assert max(np.abs(static.q[i] - q_star(t)).max() for i, t in enumerate(static.t)) > 1e-3


def _start(r, qa, fn):
    from kinredund.ik.solve import solve_ik

    res = solve_ik(r, fn(0.0)[0], JointDeviation(qa), q0=qa, starts=8)
    assert res.converged
    return res.q


@pytest.mark.parametrize("points", [2, 3])
def test_hermite_predictor_is_exact_to_its_degree(points):
    """The predictor's weights extrapolate polynomials of degree 2k - 1 exactly, and no higher."""
    h, t0 = 0.03, 0.7
    rng = np.random.default_rng(points)
    w = hermite_weights(h, points)
    nodes = t0 + h * np.arange(1 - points, 1)
    for degree, exact in [(2 * points - 1, True), (2 * points, False)]:
        c = rng.normal(size=degree + 1)
        y, dy = np.polynomial.Polynomial(c), np.polynomial.Polynomial(c).deriv()
        data = np.ravel(np.column_stack([y(nodes), dy(nodes)]))
        err = abs(w @ data - y(t0 + h))
        assert (err < 1e-12) if exact else (err > 1e-9 * abs(c[-1]))
    if points == 2:
        assert np.allclose(w, [5.0, 2.0 * h, -4.0, 4.0 * h])  # the cubic of the literature


@pytest.mark.parametrize("name", ["4.2", "4.3", "panda"])
def test_default_mode_rates_are_the_time_derivative_of_the_path(name):
    """The rates the corrector solves for (Eq. 4.24 at the predicted point) match central differences of
    the tracked joints and multipliers; they drive the predictor, which the corrector would otherwise hide.

    The Panda's rolling tool has non-zero orientation multipliers, so its rates need (dJ/dt)^T lambda.
    """
    if name == "panda":
        from kinredund.problems import panda_circle

        r, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    else:
        ex = example(name)
        r, path, index, q0 = ex.robot, ex.path, ex.index, ex.q0
    dt = path.period / 2000
    rr = Tracker(r, path, index, q0, dt, limits=False)  # Example 4.3's start violates the limits as read
    ys, yds = [], []
    for _ in range(300):
        rr.step()
        ys.append(np.concatenate([rr.q, rr.lam]))
        yds.append(np.concatenate([rr.qdot, rr.lamdot]))
    ys, yds = np.array(ys), np.array(yds)
    fd = (ys[2:] - ys[:-2]) / (2 * dt)
    scale = np.abs(yds).max()
    assert np.abs(yds[1:-1] - fd).max() < 1e-4 * scale
