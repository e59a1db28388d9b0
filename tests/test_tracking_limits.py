"""Hard joint limits in the cyclic tracker (issue 14): the constrained optimum followed exactly, inside.

Named cases: circles on the Panda and the xArm7 (position task, z = 1/2 ||theta - home||^2) on which the
unconstrained optimum leaves the URDF limits and the limited one meets a bound and leaves it again.
Tolerances: the corrector holds the task and the first-order conditions to ~1e-12 (its tol, scaled by
||grad z||); switching times are solved to 1e-14 s; the bars below leave two to three orders of margin.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from conftest import load_benchmark, robot, rounding

import kinredund
from kinredund.errors import OptionError, SingularityError, TrackingError
from kinredund.indices import JointDeviation
from kinredund.paths import Circle
from kinredund.problems import panda_circle
from kinredund.tracking import Tracker, track
from kinredund.tracking.constraints import JointLimits

#: (robot, a configuration on the circle, the circle's normal, its x axis, radius [m]); speed 0.1 m/s
CASES = {
    "panda_elbow_circle": ("panda", [0.5981, -1.2209, -0.1932, -2.5949, -0.0485, 1.3779, 1.2498],
                           [0.4405, -0.8901, 0.117], [0.8409, 0.3634, -0.401], 0.1333),
    "panda_wrist_circle": ("panda", [-0.3848, -0.9802, 0.2809, -2.7316, 0.1287, 1.6107, 0.8219],
                           [0.4974, -0.6838, -0.5339], [0.7791, 0.0814, 0.6215], 0.1237),
    "xarm7_circle": ("xarm7", [-0.4007, -0.187, 0.1197, 0.0733, 0.0738, 1.2542, -0.4195],
                     [0.1246, 0.7365, 0.6649], [0.9873, -0.0254, -0.157], 0.0636),
}
#: pose-task cases (the tool keeps the orientation it has at the given configuration)
POSE_CASES = {
    "panda_pose_circle": ("panda", [-0.0777, -1.1391, 0.2501, -2.9447, -0.306, 2.1239, 1.2622],
                          [-0.0675, 0.2596, 0.9633], [0.9464, -0.289, 0.1442], 0.0626),
    # one degree of redundancy: a second bound would fix the arm, so the path cannot be followed inside
    "panda_pose_infeasible": ("panda", [-0.2906, -0.4692, 0.2375, -2.8016, -0.1485, 1.4761, 0.983],
                              [-0.528, 0.34, 0.7782], [0.7265, -0.2938, 0.6212], 0.0868),
    # with a joint on its limit the six free joints turn singular for the pose (LICQ fails): a fold
    "panda_pose_fold": ("panda", [-0.5075, -0.7989, -0.3446, -2.7968, 0.0073, 1.9131, 0.539],
                        [-0.4087, 0.7602, 0.505], [-0.6608, -0.6281, 0.4109], 0.1347),
}


@functools.cache
def case(name):
    """(robot, path, index, q0): the circle and the bounded optimum at its start."""
    pose = name in POSE_CASES
    return circle_case(*(POSE_CASES if pose else CASES)[name], pose=pose)


def circle_case(rname, qs, n, ax, rad, pose=False):
    """(robot, path, index, q0) of a circle of radius ``rad`` [m] at 0.1 m/s through the end point at ``qs``
    (plane normal ``n``, start direction ``-ax``), z = 1/2 ||q - q_home||^2 and the bounded optimum at t = 0."""
    r = robot(rname, "pose" if pose else "position")
    qs, n, ax = np.array(qs), np.array(n, float), np.array(ax, float)
    n /= np.linalg.norm(n)
    ax -= (ax @ n) * n
    ax /= np.linalg.norm(ax)
    T = r.fk(qs)
    p = T[:3, 3]
    path = Circle(p - rad * ax, rad, 0.1, normal=tuple(n), axis_x=tuple(ax), orientation=T[:3, :3] if pose else None)
    index = JointDeviation(r.home.copy())
    target = (T[:3, :3], p) if pose else p
    free = kinredund.solve_ik(r, target, index, q0=qs)
    start = kinredund.solve_ik(r, target, index, q0=free.q, bounds=True)
    assert start.converged
    return r, path, index, start.q


@functools.cache
def run(name, loops=10, limits=True, scheme="augmented"):
    r, path, index, q0 = case(name)
    return track(r, path, index, q0, loops=loops, limits=limits, scheme=scheme)


def bisected(f, lo: float, hi: float) -> float:
    """The time [s] in (lo, hi) where f changes sign, by bisection to 1e-11 s (f must change sign there):
    an independent check of the tracker's switching times (Brent's method to 1e-14 s)."""
    f_lo = f(lo)
    assert f_lo * f(hi) < 0  # a crossing in the bracket
    while hi - lo > 1e-11:
        mid = 0.5 * (lo + hi)
        f_mid = f(mid)
        lo, hi, f_lo = (mid, hi, f_mid) if f_mid * f_lo > 0 else (lo, mid, f_lo)
    return 0.5 * (lo + hi)


def excess(r, q):
    """The largest excursion beyond the limits [rad] (<= 0 inside)."""
    q = np.atleast_2d(q)
    return float(np.max(np.maximum(q - r.upper, r.lower - q)))


ALL = [*CASES, "panda_pose_circle"]


@pytest.mark.parametrize("name", ALL)
def test_unconstrained_optimum_leaves_the_limits(name):
    r, path, index, q0 = case(name)
    free = run(name, loops=1, limits=False)
    assert excess(r, free.q) > 0.02  # the named case is what it claims: the thesis's scheme leaves the limits
    assert excess(r, q0) <= 0.0


@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
@pytest.mark.parametrize("name", ALL)
def test_limited_run_is_inside_closed_and_on_the_path(name, scheme):
    r, path, index, q0 = case(name)
    tr = run(name, scheme=scheme)
    assert excess(r, tr.q) <= 1e-10  # at every step
    assert tr.trace_error.max() <= 1e-10 and tr.vect_error.max() <= 1e-10  # zero for position tasks
    switches = tr.meta["switches"]
    assert len(switches) >= 20 and len(tr.switch_times) == len(switches)  # >= 2 per loop: reach and release
    assert {w["kind"] for w in switches} == {"reach", "release"}
    assert excess(r, np.array([w["q"] for w in switches])) <= 1e-10  # and at every switching time
    assert tr.loop_drift.max() <= 1e-10  # closed after 10 loops
    assert tr.position_error.max() <= 1e-10
    assert np.all(tr.bound_multipliers >= -1e-9)  # no multiplier of the wrong sign survives
    assert np.all((tr.bound_multipliers == 0.0) | (tr.active_bounds != 0))
    assert tr.limit_margins.min() >= -1e-10
    assert np.all(np.isfinite(tr.meta["joint_speed_max"])) and tr.meta["speed_over_velocity_limit_max"] > 0


@pytest.mark.parametrize("name", ALL)
def test_bounded_first_order_conditions_hold_independently(name):
    """kinredund.ik.check_optimality with the bounds (its own active-set and sign test) at every point."""
    r, path, index, _ = case(name)
    tr = run(name, loops=1)
    worst = 0.0
    for t, q, act in zip(tr.t, tr.q, tr.active_bounds, strict=True):
        s = path(t)
        opt = kinredund.check_optimality(r, (s.Q, s.p) if r.task == "pose" else s.p, q, index, bounds=True)
        worst = max(worst, opt.normality_residual)
        assert opt.residual <= 1e-10
        assert np.array_equal(opt.active, act != 0)  # the same active set, the multipliers' signs right
    assert worst <= 1e-9


def _free_optimum(r, index, path, t, seed):
    """The unconstrained optimum at time t near ``seed`` (joint-level IK, no bounds)."""
    res = kinredund.solve_ik(r, path(t).p, index, q0=seed)
    assert res.converged
    return res.q


def test_switching_times_agree_with_bisection_on_the_free_optimum():
    """A bound is met and left again where the free optimum's joint crosses it (mu = 0 there): bisection
    on that crossing with the joint-level IK, independent of the tracker's Brent search, to 1e-9 s."""
    name = "panda_elbow_circle"
    r, path, index, _ = case(name)
    tr = run(name, loops=1)
    switches = tr.meta["switches"]
    kinds = [w["kind"] for w in switches]
    assert "reach" in kinds and "release" in kinds
    dt = tr.meta["dt"]
    for w in switches[:2]:
        j, bound = w["joint"], (r.lower if w["bound"] == "lower" else r.upper)[w["joint"]]
        seed = np.array(w["q"])

        def margin(t, j=j, bound=bound, seed=seed):  # the free optimum crosses the bound within the bracket
            return _free_optimum(r, index, path, t, seed)[j] - bound

        assert abs(bisected(margin, w["t"] - 0.5 * dt, w["t"] + 0.5 * dt) - w["t"]) <= 1e-9


def test_rates_match_central_differences_between_switches():
    name = "panda_elbow_circle"
    r, path, index, q0 = case(name)
    dt = path.period / 2000
    tracker = Tracker(r, path, index, q0, dt)
    ts, qs, qds = [tracker.t], [tracker.q.copy()], [tracker.qdot.copy()]
    for _ in range(2000):  # one loop
        tracker.step()
        ts.append(tracker.t)
        qs.append(tracker.q.copy())
        qds.append(tracker.qdot.copy())
    ts, qs, qds = np.array(ts), np.array(qs), np.array(qds)
    switch_t = np.array([w["t"] for w in tracker.stepper.switches])
    assert len(switch_t) >= 1
    fd = (qs[2:] - qs[:-2]) / (2 * dt)
    clear = np.array([not np.any((switch_t > ts[k] - 1.5 * dt) & (switch_t < ts[k] + 1.5 * dt))
                      for k in range(1, len(ts) - 1)])
    scale = np.abs(qds).max()
    # central differences err by O(dt^2 |q'''|); the rates are solved at the predicted point, ~1e-10 away
    assert np.abs(qds[1:-1][clear] - fd[clear]).max() < 1e-4 * scale
    assert clear.sum() > 1900 and (~clear).sum() >= 2  # both sides of each switch excluded, the rest checked


def test_equals_the_bounded_joint_level_ik_solved_afresh():
    name = "panda_wrist_circle"
    r, path, index, _ = case(name)
    tr = run(name, loops=1)
    rng = np.random.default_rng(0)
    for k in np.linspace(0, len(tr.t) - 1, 20).astype(int):
        seed = np.clip(tr.q[k] + 1e-3 * rng.normal(size=r.nq), r.lower, r.upper)
        res = kinredund.solve_ik(r, tr.p_desired[k], index, q0=seed, bounds=True)
        assert res.converged
        assert np.abs(res.q - tr.q[k]).max() <= 1e-9


def test_velocity_form_follows_the_same_constrained_optimum():
    """The displacement and velocity-Jacobian forms (Eqs. 4.24 and 4.36) reach the same joints, with limits."""
    a, b = run("panda_pose_circle"), run("panda_pose_circle", scheme="velocity")
    assert np.abs(a.q - b.q).max() <= 1e-9
    assert np.abs(a.switch_times - b.switch_times).max() <= 1e-9


def test_limits_inactive_give_the_unconstrained_run():
    r, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
    a = track(r, path, index, q0, loops=2, limits=False)
    b = track(r, path, index, q0, loops=2)
    assert np.abs(a.q - b.q).max() <= 1e-12
    assert b.switch_times.size == 0 and not b.active_bounds.any() and a.active_bounds is None


def test_start_outside_the_limits_is_named_unless_projected():
    r, path, index, q0 = case("panda_elbow_circle")
    bad = q0.copy()
    bad[3] = r.upper[3] + 0.05
    with pytest.raises(TrackingError, match=r"panda_joint4 <= -0.0698 by 0.05") as err:
        track(r, path, index, bad)
    assert err.value.cause == "limits_infeasible"
    # projected: joint 4 put on its limit; the start is then off the path and says so
    with pytest.raises(kinredund.PathError, match="away from the path"):
        Tracker(r, path, index, bad, 0.01, project_start=True)


def test_thesis_mode_and_baselines_refuse_limits():
    r, path, index, q0 = case("panda_elbow_circle")
    for kw in ({"mode": "thesis"}, {"scheme": "pseudoinverse"}, {"scheme": "liegeois"}):
        with pytest.raises(OptionError, match="limits=False"):
            Tracker(r, path, index, q0, 0.01, limits=True, **kw)
        assert Tracker(r, path, index, q0, 0.01, **kw).limits is None  # the default: without them there
    with pytest.raises(OptionError, match="margin"):
        JointLimits(r, margin=-0.1)
    with pytest.raises(OptionError, match="no room"):
        JointLimits(r, margin=10.0)


def test_margin_keeps_the_joints_further_in():
    r, path, index, q0 = case("panda_elbow_circle")
    lim = JointLimits(r, margin=0.02)
    start = kinredund.solve_ik(r, path(0.0).p, index, q0=q0, bounds=True)
    q0m = lim.project(start.q)
    res = kinredund.solve_ik(r, path(0.0).p, index, q0=q0m, bounds=True)
    if excess(r, res.q + 0.02 * np.sign(res.q - 0.5 * (r.lower + r.upper))) > 0:
        pytest.skip("the start sits within the margin of a limit")
    tr = track(r, path, index, res.q, limits=lim)
    assert np.min(np.minimum(tr.q - r.lower, r.upper - tr.q)) >= 0.02 - 1e-10


@pytest.mark.parametrize("name", ALL)
def test_rate_qp_agrees_with_the_active_set_after_each_switch(name):
    """The rate QP (proxsuite, the decider where the LU route cannot tell) keeps a bound just reached and
    lets go of one just released, as the switch itself decided."""
    r, path, index, q0 = case(name)
    tracker = Tracker(r, path, index, q0, path.period / 200)
    s, seen = tracker.stepper, 0
    for _ in range(200):
        tracker.step()
        if len(s.switches) > seen:
            w = s.switches[-1]
            seen = len(s.switches)
            side = 1.0 if w["bound"] == "lower" else -1.0
            assert s._qp_keeps_bound(w["joint"], side) == (w["kind"] == "reach") == bool(s.fixed[w["joint"]])
    assert seen >= 2


@pytest.mark.parametrize(("name", "cause"), [("panda_pose_infeasible", "limits_infeasible"),
                                           ("panda_pose_fold", "not_strongly_stable")])
def test_a_path_that_cannot_be_followed_inside_stops_with_the_last_good_state(name, cause):
    r, path, index, q0 = case(name)
    with pytest.raises(TrackingError) as info:
        track(r, path, index, q0, loops=2)
    err = info.value
    assert err.cause == cause and 0 < err.t < path.period
    q = np.array(err.q)
    assert excess(r, q) <= 1e-10  # inside the limits
    T, s = r.fk(q), path(err.t)
    assert np.linalg.norm(T[:3, 3] - s.p) <= 1e-10 and np.abs(T[:3, :3] - s.Q).max() <= 1e-10  # on the path
    assert {"active", "bound_multipliers", "limit_margins"} <= set(err.watched)  # and the strict watch's
    assert min(err.watched["bound_multipliers"]) >= 0.0
    part = err.partial.checked(r.nq)  # a valid record: plots and playback accept it
    assert part.t[-1] == pytest.approx(err.t) and np.array_equal(part.q[-1], q)
    assert excess(r, part.q) <= 1e-10
    # a Tracker that stops stays at the last requested time: its clock and step count agree (t = t0 + k dt)
    tracker = Tracker(r, path, index, q0, path.period / 200)
    with pytest.raises(TrackingError):
        for _ in range(400):
            tracker.step()
    s = tracker.stepper
    assert s.t == s.t0 + s.k * s.dt and abs(s.t - err.t) <= 1e-12 and np.array_equal(tracker.q, q)


def test_a_stop_inside_a_bounded_step_is_diagnosed_on_the_free_joints_at_the_last_good_point(monkeypatch):
    """A reduced R found singular at a corrector iterate (which may have diverged: q ~ 300 rad in the z1 case
    below) stopped with that iterate's words, "algorithmic (R singular while J has full rank)", and no watched
    quantity of the free joints. The stop is said at the last good point on the Jacobian of the free joints:
    here a stand-in makes the reduced R singular a few steps after a joint reached its limit."""
    from kinredund.tracking.limited import LimitedPredictorCorrector
    from kinredund.tracking.point import Evaluator

    real = LimitedPredictorCorrector._factor_matrix

    def singular(self, pt, R, J):
        if pt.t < 5.8:  # panda_joint4 reaches its lower limit at 5.49 s (and stays there up to the stop at 6.14 s)
            return real(self, pt, R, J)
        raise SingularityError("algorithmic (R singular while J has full rank) singularity: stand-in", t=pt.t,
                               q=pt.q + 300.0, sigma_min=1e-17)

    monkeypatch.setattr(LimitedPredictorCorrector, "_factor_matrix", singular)
    r, path, index, q0 = case("panda_pose_fold")
    with pytest.raises(TrackingError) as info:
        track(r, path, index, q0, loops=1, backend="python")
    err, q = info.value, np.asarray(info.value.q)
    fixed = np.asarray(err.watched["active"]) != 0
    assert err.cause == "not_strongly_stable" and fixed.sum() == 1 and excess(r, q) <= 1e-10
    J = Evaluator(r, path, index, "augmented").point(q, err.t, need_dJ=False).J  # afresh, at the last good point
    s_free, s_all = np.linalg.svd(J[:, ~fixed], compute_uv=False), np.linalg.svd(J, compute_uv=False)
    assert abs(err.watched["sigma_min_J"] - s_free[-1]) <= rounding(s_free[0])
    assert abs(err.watched["sigma_min_J_all_joints"] - s_all[-1]) <= rounding(s_all[0])
    text = str(err)
    assert "while J has full rank" not in text and "turned singular at a corrector iterate" in text
    assert f"the Jacobian of the 6 free joints has smallest singular value {s_free[-1]:.3g} (J of all 7: " \
           f"{s_all[-1]:.3g}), as many as the rows they must meet" in text


@pytest.mark.slow
def test_the_z1_stop_with_joint4_on_its_limit_names_the_free_joints():
    """benchmarks/plan_peers.py --n 15 --seed 1, task 10 on z1: the plan's re-tracking stopped with joint4 on its
    lower limit, said as "algorithmic (R singular while J has full rank)" of a corrector iterate at q ~ 300 rad;
    at the last good point the 5 free joints' Jacobian (square: LICQ) has sigma_min 0.0058, J's own 0.0198."""
    from kinredund.planning.cyclic import plan

    z1 = robot("z1")
    circles = load_benchmark("_circles")
    task = next(task for i, task, _ in circles.drawn(z1, 15, 1, orientations=("held",)) if i == 10)
    res = plan(z1, task.path(), task.performance_index(z1), seed=11, loops=2, steps_per_loop=200)
    assert res.ok or ("while J has full rank" not in res.reason and "free joints has smallest" in res.reason), \
        res.reason


def test_the_limits_record_survives_json(tmp_path):
    tr = run("panda_elbow_circle", loops=1)
    path = tmp_path / "run.json"
    tr.save_json(path)
    back = kinredund.Trajectory.load_json(path)
    assert np.array_equal(back.active_bounds, tr.active_bounds)
    assert np.abs(back.bound_multipliers - tr.bound_multipliers).max() == 0.0
    assert np.abs(back.switch_times - tr.switch_times).max() == 0.0
    assert [w["t"] for w in back.meta["switches"]] == list(tr.switch_times)


def test_a_start_on_a_bound_stays_on_it():
    """solve_ik(bounds=True) puts a joint on its limit (within its tolerance, here 1e-11 outside): the tracker
    fixes it there instead of letting the first steps carry it outside."""
    r, path, index, _ = case("panda_elbow_circle")
    tr = run("panda_elbow_circle", loops=1)
    reach, release = tr.meta["switches"][:2]
    t_mid = 0.5 * (reach["t"] + release["t"])
    k = int(np.argmin(np.abs(tr.t - t_mid)))
    start = kinredund.solve_ik(r, path(tr.t[k]).p, index, q0=tr.q[k], bounds=True)
    j, side = reach["joint"], (1.0 if reach["bound"] == "lower" else -1.0)
    bound = r.lower[j] if side > 0 else r.upper[j]
    assert abs(start.q[j] - bound) <= 1e-9  # on the bound
    q0 = start.q.copy()
    q0[j] = bound - side * 1e-11  # just outside, as an iterative solver may leave it
    tracker = Tracker(r, path, index, q0, path.period / 200, t0=tr.t[k])
    assert tracker.stepper.fixed[j] and tracker.q[j] == bound
    for _ in range(5):
        tracker.step()
        assert excess(r, tracker.q) <= 1e-10
    assert np.abs(tracker.q - tr.q[k + 5]).max() <= 1e-9  # the same constrained optimum as the run


def test_a_bounded_stop_is_retried_in_sub_steps_like_any_failed_step():
    """A whole step the bounded stepper cannot take (its corrector fails with a joint held, a TrackingError of
    the limits) was a stop at once, without the sub-steps every other failed step gets: with 4 steps per loop
    the pose circle stopped one step (T/4) before the fold that finer steps all stop at, and the infeasible
    circle's stop was named for its corrector (not_strongly_stable) instead of the two joints on their limits."""
    r, path, index, q0 = case("panda_pose_circle")
    stops = []
    for steps in (4, 8):
        with pytest.raises(TrackingError) as info:
            track(r, path, index, q0, steps_per_loop=steps, loops=1, diagnostics=False)
        stops.append(info.value)
    coarse, fine = stops
    assert coarse.cause == fine.cause == "not_strongly_stable"
    assert coarse.t == pytest.approx(fine.t, abs=1e-12) and coarse.t == pytest.approx(0.75 * path.period, abs=1e-12)
    np.testing.assert_allclose(coarse.q, fine.q, rtol=0, atol=1e-8)  # the same point, corrected from other steps
    r, path, index, q0 = case("panda_pose_infeasible")
    with pytest.raises(TrackingError) as info:
        track(r, path, index, q0, steps_per_loop=8, loops=1, diagnostics=False)
    assert info.value.cause == "limits_infeasible" and "2 joints on their limits" in str(info.value)
    assert np.all(info.value.q >= r.lower - 1e-12) and np.all(info.value.q <= r.upper + 1e-12)


def test_a_bounded_stop_stays_the_limits_cause_where_the_sub_steps_fail_otherwise():
    """Where the whole step raises the limits' stop and every sub-step then fails in its corrector (emulated: the
    stepper's step raises limits_infeasible, its Euler sub-steps a SingularityError), the stop is the limits' stop
    (the cause the whole step named, at the step's start), not step_control_exhausted."""
    r, path, index, q0 = case("panda_pose_circle")
    tracker = Tracker(r, path, index, q0, path.period / 100, limits=True, backend="python")
    tracker.step()
    s = tracker.stepper
    t_start, q_start = tracker.t, tracker.q.copy()

    def whole_step():
        raise s._failure("limits_infeasible", "emulated: 2 joints on their limits")

    def sub_step(t_next):
        raise SingularityError("emulated: the corrector diverged")

    s.plain_step, s.euler_to = whole_step, sub_step
    with pytest.raises(TrackingError) as info:
        tracker.step()
    err = info.value
    assert err.cause == "limits_infeasible" and "emulated: 2 joints" in str(err)
    assert err.t == pytest.approx(t_start, abs=1e-15) and np.abs(np.asarray(err.q) - q_start).max() <= 1e-15
