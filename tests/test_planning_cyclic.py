"""The cyclic planner for any arm (issue 15): samples of z's within-limits minima, a closed walk, a spline,
time-varying reference tracking, and its independent verification."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import load_benchmark, robot, rounding

from kinredund.errors import KinredundError, OptionError, PathError, TaskError
from kinredund.ik.solve import solve_ik
from kinredund.indices import JointDeviation
from kinredund.paths import Circle, Helix
from kinredund.planning.cyclic import CLOSURE_TOL, TASK_TOL, plan
from kinredund.planning.options import PlanOptions
from kinredund.planning.topology import RepeatedPath, orientation_loop_flips
from kinredund.planning.verify import (
    JUMP_FACTOR,
    JUMP_FLOOR,
    joint_jumps,
    limit_excursion,
    task_errors,
    verify_motion_on_path,
)
from kinredund.planning.walk import shrunk_limits
from kinredund.tasks import get_task
from kinredund.tasks.axis import frame_with_axis
from kinredund.tracking import track

#: the task generator of the random-tasks benchmark (benchmarks/_circles.py: not part of the library)
_circles = load_benchmark("_circles")
NAMED_CASES, RADIUS_RANGE, SPEED_RANGE = _circles.NAMED_CASES, _circles.RADIUS_RANGE, _circles.SPEED_RANGE
random_circle, start_of = _circles.random_circle, _circles.start_of
STEPS = 200  # per loop, the benchmark's
#: the strict tracker without joint limits (the thesis's scheme)
UNBOUNDED = {"limits": False}


def _case(name):
    task, seed = NAMED_CASES[name]
    r = robot(task.robot)
    return r, task.path(), task.performance_index(r), start_of(r, task, seed)


def _assert_completed(r, path, result, loops=2):
    """The plan's own verdict (planning.verify), and its figures against the tracker's own record: two
    computations of one figure that must agree (the record's task errors come from the recorder)."""
    assert result.ok and result.cause == "", result.reason
    tr = result.trajectory
    assert len(tr.t) == loops * STEPS + 1
    # inside the limits at every recorded point, exactly (a direct comparison, not verify's excursion)
    assert np.all(tr.q >= r.lower) and np.all(tr.q <= r.upper)
    pos, _ = task_errors(r, path, tr.t, tr.q)
    assert np.abs(pos - tr.position_error).max() <= 1e-12  # verify's FK and the recorder's agree
    assert tr.position_error.max() <= TASK_TOL  # the corrector holds ~1e-12: 1e-9 leaves headroom
    assert result.check.orientation_error_max <= TASK_TOL and result.check.jumps == ()
    for k in range(1, loops + 1):  # the same joints after every loop
        assert np.abs(tr.q[k * STEPS] - tr.q[0]).max() <= CLOSURE_TOL


# -- the independent checks -------------------------------------------------------------------------
def test_joint_jumps_finds_one_step_that_moves_much_more_than_its_neighbours():
    t = np.linspace(0.0, 2 * np.pi, 201)
    q = np.column_stack([np.sin(t), np.cos(2 * t), 0.3 * t])
    step, ratio, jumps = joint_jumps(q)
    assert jumps == () and ratio < 1.1  # smooth: consecutive steps differ by O(dt)
    bad = q.copy()
    bad[120:] += np.array([0.0, 0.5, 0.0])  # a branch switch inside step 119
    step, ratio, jumps = joint_jumps(bad)
    assert jumps == (119,) and step > 0.4 and ratio > JUMP_FACTOR
    still = np.zeros((50, 3))
    still[25:] += 0.5 * JUMP_FLOOR  # below the floor: round-off of a still arm, never a jump
    assert joint_jumps(still)[2] == ()


def test_limit_excursion_is_the_distance_beyond_the_nearest_limit():
    r = robot("panda")
    q = np.array([r.home, r.home, r.home])
    q[1, 3] = r.upper[3] + 0.25
    q[2, 0] = r.lower[0] - 0.125
    assert np.allclose(limit_excursion(r, q), [0.0, 0.25, 0.125], rtol=0, atol=1e-15)


def test_verification_uses_the_robots_fk_and_the_loops():
    r = robot("panda")
    path = Circle(r.fk(r.home)[:3, 3], 0.05, 0.1, orientation=r.fk(r.home)[:3, :3])
    t = np.arange(2 * STEPS + 1) * path.period / STEPS
    q = np.tile(r.home, (len(t), 1))  # the arm held still at the circle's centre: one radius off the path
    c = verify_motion_on_path(r, path, t, q, STEPS)
    assert c.closure == (0.0, 0.0) and c.limit_violation == 0.0 and c.orientation_error_max < 1e-12
    assert c.position_error_max == pytest.approx(0.05, rel=1e-9)


# -- the generator -------------------------------------------------------------------------------------
def test_generator_is_reproducible_and_draws_what_it_documents():
    r = robot("xarm7")
    a = [random_circle(r, np.random.default_rng(3)) for _ in range(2)]
    assert a[0] == a[1]
    rng = np.random.default_rng(4)
    for _ in range(20):
        task = random_circle(r, rng)
        assert RADIUS_RANGE[0] <= task.radius <= RADIUS_RANGE[1] and SPEED_RANGE[0] <= task.speed <= SPEED_RANGE[1]
        n, e1 = np.array(task.normal), np.array(task.axis_x)
        assert abs(np.linalg.norm(n) - 1) < 1e-12 and abs(n @ e1) < 1e-12
        s = task.path()(0.0)
        assert np.linalg.norm(s.p - np.array(task.center)) == pytest.approx(task.radius, rel=1e-12)
        if task.index == "posture":
            ref = np.array(task.reference)
            assert np.all((ref >= r.lower) & (ref <= r.upper))


# -- the planner on circles where the strict tracker fails ------------------------------------------------
@pytest.mark.parametrize("name", ["panda_fold", "xarm7_fold"])
def test_strict_tracker_fails_and_planner_completes(name):
    r, path, index, start = _case(name)
    assert start.converged
    with pytest.raises(KinredundError):  # today's tracker without limits, from the within-limits optimum
        track(r, path, index, start.q, steps_per_loop=STEPS, loops=2, diagnostics=False, **UNBOUNDED)
    result = plan(r, path, index, seed=1)
    _assert_completed(r, path, result)
    s = result.samples
    assert s.sample_t.size == 24 and all(len(c) >= 1 for c in s.candidates)
    optima = [q for q, kind in zip(s.q, s.kind, strict=True) if kind == "optimum"]
    assert len(optima) == 24
    inner = shrunk_limits(r, 1e-3)  # plan()'s default margin: the knots are solved inside these limits
    for q, t in zip(optima, s.sample_t, strict=True):  # the knots are on the path, a margin inside the limits
        assert task_errors(r, path, [t], [q])[0][0] <= 1e-9
        assert np.all(q >= inner.lower) and np.all(q <= inner.upper) and np.all(inner.lower > r.lower)


def test_planner_from_the_strict_trackers_start_rides_the_limit():
    """panda_fold from the start the strict tracker used: the plan keeps its branch (the walk starts
    there), completes within the limits and reaches the limit the unconstrained optimum crosses."""
    r, path, index, start = _case("panda_fold")
    result = plan(r, path, index, q0=start.q, seed=1)
    _assert_completed(r, path, result)
    assert np.abs(result.trajectory.q[0] - start.q).max() < 1e-6  # the start's branch (z's minimum from q0)
    gap = np.minimum(result.trajectory.q - r.lower, r.upper - result.trajectory.q).min()
    assert gap < 2e-3  # on the margin of a limit (1e-3 rad) for part of the loop


def test_planner_through_a_fold_says_it_follows_its_reference_there():
    """panda_fold_followed from the strict tracker's start: the minimum of z followed ceases to exist;
    the plan still closes inside the limits, following its reference (through refined knots that are not
    optima of z) across the fold only, and says where."""
    r, path, index, start = _case("panda_fold_followed")
    with pytest.raises(KinredundError):
        track(r, path, index, start.q, steps_per_loop=STEPS, loops=2, diagnostics=False, **UNBOUNDED)
    result = plan(r, path, index, q0=start.q, seed=1)
    _assert_completed(r, path, result)
    assert result.off_optimum and "refined" in result.samples.kind
    for a, b in result.off_optimum:
        assert 0 <= a < b <= path.period
        assert any(f"{a:.4g} s" in note and "follows its reference" in note for note in result.notes)
    # the reference crosses the fold (refined knots there); elsewhere the motion is z's optimum itself, so the
    # flagged intervals are a small part of the loop and every point outside them passes the independent solve
    assert sum(b - a for a, b in result.off_optimum) < 0.25 * path.period
    assert _assert_on_optimum_outside(r, path, index, result) >= STEPS // 2


def _assert_on_optimum_outside(r, path, index, result):
    """At every recorded point of the first loop outside ``off_optimum``, an independent bounded solve of z
    (solve_ik with the limits as bounds, from the planned configuration) moves it by at most 1e-6 rad: the
    plan follows z's own optimum there, as it says. Returns the number of points checked."""
    tr, checked = result.trajectory, 0
    for tk, qk in zip(tr.t[:STEPS], tr.q[:STEPS], strict=True):
        if any(a <= tk <= b for a, b in result.off_optimum):
            continue
        res = solve_ik(r, get_task(r.task).target_at(path, tk), index, q0=qk, bounds=True)
        assert res.converged and np.abs(res.q - qk).max() <= 1e-6, (tk, res.reason)
        checked += 1
    return checked


@pytest.mark.slow
@pytest.mark.parametrize("name", ["xarm7_fold", "panda_limit"])
def test_plan_follows_z_itself_where_it_says_and_the_reference_plan_says_where_it_does_not(name):
    """The issue's measurement: a motion that tracks the spline reference everywhere lies up to ~1e-3 rad
    from z's bounded optimum. With follow (the default) the plan follows z's own optimum wherever it is
    strongly stable (every point outside off_optimum passes the independent solve); with follow=False the
    reference motion is kept and off_optimum covers the points it measured off z's optimum."""
    r, path, index, _ = _case(name)
    followed = plan(r, path, index, seed=1, loops=1)
    _assert_completed(r, path, followed, loops=1)
    assert _assert_on_optimum_outside(r, path, index, followed) >= STEPS // 2
    reference = plan(r, path, index, seed=1, loops=1, follow=False)
    _assert_completed(r, path, reference, loops=1)
    assert reference.off_optimum  # the spline between its knots is not z's optimum, and the plan says so
    _assert_on_optimum_outside(r, path, index, reference)


def test_planner_where_the_unconstrained_optimum_meets_a_limit():
    r, path, index, start = _case("panda_limit")
    tr = track(r, path, index, start.q, steps_per_loop=STEPS, loops=2, diagnostics=False, **UNBOUNDED)
    assert limit_excursion(r, tr.q).max() > 1e-3  # the strict tracker without limits leaves them
    _assert_completed(r, path, plan(r, path, index, seed=1))  # the shortest closed walk: another branch
    result = plan(r, path, index, q0=start.q, seed=1)  # the strict tracker's branch
    _assert_completed(r, path, result)
    q = result.trajectory.q
    assert np.minimum(q - r.lower, r.upper - q).min() < 2e-3  # it stays on (the margin of) the limit instead


def test_planner_on_a_planar_arm():
    """Any arm: the thesis's planar 3R (task ``planar``, m = 2) on a circle through its home point. Its progress
    comes as progress(done, total, stage), the one signature of every planner."""
    r = robot("planar3r")
    path = Circle(r.fk(r.home)[:3, 3] - np.array([0.1, 0.0, 0.0]), 0.1, 0.2)
    calls = []
    result = plan(r, path, JointDeviation(r.home), loops=1, progress=lambda d, n, stage: calls.append((d, n, stage)))
    _assert_completed(r, path, result, loops=1)
    stages = list(dict.fromkeys(c[2] for c in calls))
    assert stages == ["samples", "closed walk", "tracking", "following z"]  # no clearance stage without a scene
    assert all(0 <= d <= n for d, n, _ in calls)


@pytest.mark.parametrize("name", ["ur5", "ur10", "kinova", "z1", "talos_arm"])
def test_planner_on_a_six_axis_arm_with_the_tool_axis_task(name):
    """Every task kind plans: a 6-axis arm with the tool-axis task (m = 5), the README's UR5 circle. It
    raised TaskError ("a pose target must have shape (4, 4)") before the targets came from the task object."""
    r = robot(name)
    assert r.task == "axis" and r.nq == 6
    T = r.fk(r.home)  # the tool axis held at its home direction along a small circle through the home point
    path = Circle(T[:3, 3] - np.array([0.04, 0.0, 0.0]), 0.04, 0.08, orientation=frame_with_axis(T[:3, 2]))
    result = plan(r, path, JointDeviation(r.home), samples=12, starts=2, loops=1, steps_per_loop=STEPS)
    _assert_completed(r, path, result, loops=1)
    tr = result.trajectory
    assert tr.task == "axis" and tr.axis_error.max() <= TASK_TOL  # the tool axis held, from the record


def test_planner_on_the_position_task():
    """The position task (m = 3) on the 7-axis Panda: the fourth task kind."""
    r = robot("panda", "position")
    path = Circle(r.fk(r.home)[:3, 3] - np.array([0.05, 0.0, 0.0]), 0.05, 0.1)
    result = plan(r, path, JointDeviation(r.home), samples=12, starts=2, loops=1, steps_per_loop=STEPS)
    _assert_completed(r, path, result, loops=1)


def test_planner_adds_samples_where_the_closed_walk_breaks_within_its_budget():
    """At 4 samples and no bisection the Panda's fold has no closed walk; the planner inserts sample times
    where the walk breaks (up to refine_samples) and completes; with refine_samples=0 it says why."""
    r, path, z, _ = _case("panda_fold")
    coarse = {"samples": 4, "budget": 0, "starts": 2, "loops": 1, "steps_per_loop": STEPS}
    failed = plan(r, path, z, refine_samples=0, **coarse)
    assert not failed.ok and failed.cause == "no_closed_walk" and "refine_samples=0" in failed.reason
    assert failed.trajectory is None and failed.samples.sample_t.size == 4
    result = plan(r, path, z, **coarse)
    _assert_completed(r, path, result, loops=1)
    st = result.samples.sample_t
    assert 4 < st.size <= 4 + 24 and np.all(np.diff(st) > 0) and st[-1] < path.period
    assert any("sample(s) added" in note for note in result.notes)


# -- which closed paths admit a closed joint path --------------------------------------------------------
def test_orientation_loop_class():
    Q0 = robot("panda").fk(robot("panda").home)[:3, :3]
    assert orientation_loop_flips(Circle((0.4, 0.0, 0.5), 0.05, 0.1, frenet=True)) is True  # one turn about n
    assert orientation_loop_flips(Circle((0.4, 0.0, 0.5), 0.05, 0.1, orientation=Q0)) is False
    assert orientation_loop_flips(Circle((0.4, 0.0, 0.5), 0.05, 0.1, orientation=Q0, roll_amplitude=2.0)) is False
    assert orientation_loop_flips(Circle((0.4, 0.0, 0.5), 0.05, 0.1)) is None  # no orientation
    twice = RepeatedPath(Circle((0.4, 0.0, 0.5), 0.05, 0.1, frenet=True), 2)
    assert orientation_loop_flips(twice) is False  # traversed twice the loop is contractible (Z_2)
    assert twice.period == pytest.approx(2 * twice.base.period, rel=1e-15)
    assert np.array_equal(twice(0.3).Q, twice.base(0.3).Q)


def test_plan_refuses_a_frenet_circle_with_one_cycle_and_says_why():
    r = robot("panda")
    T = r.fk(r.home)
    path = Circle(T[:3, 3], 0.05, 0.1, normal=T[:3, 2], axis_x=T[:3, 0], frenet=True)
    result = plan(r, path, JointDeviation(r.home))
    assert not result.ok and result.cause == "orientation_loop" and "not contractible" in result.reason
    assert result.samples is None
    with pytest.raises(OptionError, match="cycles"):
        plan(r, path, JointDeviation(r.home), cycles=0)


# -- bad input -------------------------------------------------------------------------------------------
def test_plan_rejects_bad_input():
    r = robot("panda")
    index = JointDeviation(r.home)
    with pytest.raises(PathError, match="closed path"):
        plan(r, Helix(), index)
    path = Circle(r.fk(r.home)[:3, 3], 0.05, 0.1, orientation=r.fk(r.home)[:3, :3])
    with pytest.raises(TaskError, match="Index"):
        plan(r, path, "z")
    with pytest.raises(OptionError, match="samples"):
        plan(r, path, index, samples=3)
    with pytest.raises(TaskError, match="redundant"):
        plan(robot("planar3r", "position"), Circle((1.0, 1.0, 0.0), 0.1), JointDeviation(np.zeros(3)))
    with pytest.raises(TaskError, match="inside the joint limits"):
        plan(r, path, index, q0=r.upper + 0.1)


@pytest.mark.parametrize(("option", "value", "match"), [
    ("rounds", -1, "rounds must be an integer >= 0"), ("max_candidates", 0, "max_candidates must be an integer >= 1"),
    ("seed", -1, "seed must be an integer >= 0"), ("margin", "0.1", "margin"), ("margin", float("nan"), "margin"),
    ("margin", 10.0, "quarter of panda's narrowest joint range"), ("budget", -1, "budget must be an integer >= 0"),
    ("loops", 10**9, "at most"), ("max_jump", 0.0, "max_jump"), ("samples", 24.0, "samples must be an integer"),
    ("steps", 100, "unknown plan option"), ("starts", 2501, "starts must be at most 2500"),
])
def test_plan_refuses_each_bad_option_once_before_any_work(option, value, match):
    """One options object (PlanOptions) checks every option before any solve: no silent cap (a margin of 10 rad
    was capped at a quarter of each range), no run that cannot end (10**9 loops), no negative count accepted."""
    r = robot("panda")
    path = Circle(r.fk(r.home)[:3, 3], 0.05, 0.1, orientation=r.fk(r.home)[:3, :3])
    with pytest.raises(OptionError, match=match):
        plan(r, path, JointDeviation(r.home), **{option: value})
    with pytest.raises(OptionError, match=match):  # the same refusal from the options object itself
        PlanOptions.of(**{option: value}).check_for(r)


def test_plan_says_why_when_the_path_leaves_the_reachable_set():
    r = robot("panda")
    far = Circle((3.0, 0.0, 0.5), 0.05, 0.1, orientation=np.eye(3))
    result = plan(r, far, JointDeviation(r.home), samples=6, starts=2)
    assert not result.ok and result.cause == "no_minimum" and "no within-limits local minimum" in result.reason
    assert result.trajectory is None


# -- the benchmark runs ------------------------------------------------------------------------------------
def test_random_tasks_benchmark_runs_one_task():
    pytest.importorskip("pink")
    pytest.importorskip("daqp")
    bench = load_benchmark("random_tasks")
    res = bench.run_robot("panda", 1, seed=5, progress=False)
    summary = bench.summarise(res)
    row = res["tasks"][0]
    for m in bench.METHODS:
        assert summary[m]["tasks"] == 1 and "completed" in row[m] and row[m]["time_s"] > 0
        if not row[m]["completed"]:
            assert row[m]["cause"]
    assert row["planner"]["completed"], row["planner"]  # it completes this task (seed 5)
    assert row["planner"]["inside"] and row["planner"]["closed"] and row["planner"]["jumps"] == 0


def test_task_errors_are_the_robots_task_errors():
    """A planar arm on a circle drawn 0.5 m above its plane is on the path (the planar task holds x and y):
    the independent check measures the task's own error, not the distance in space."""
    r = robot("planar3r")
    path = Circle(np.array([3.0, 1.0, 0.5]), 0.5, 0.5)
    tr = track(r, path, JointDeviation(np.zeros(3)), _planar_start(r, path), steps_per_loop=50, **UNBOUNDED)
    pos, ang = task_errors(r, path, tr.t, tr.q)
    assert pos.max() <= 1e-10 and np.abs(pos - tr.position_error).max() <= 1e-12 and ang.max() == 0.0
    check = verify_motion_on_path(r, path, tr.t, tr.q)
    assert check.position_error_max <= 1e-10 and check.closure_max <= 1e-10


def _planar_start(r, path):
    from kinredund.ik.solve import solve_ik

    res = solve_ik(r, path(0.0).p[:2], JointDeviation(np.zeros(3)), starts=8, seed=0)
    assert res.converged
    return res.q


def test_blended_index_derivatives_and_weight_against_central_differences():
    """b = w z + (1 - w) h of planning.follow: its gradient and Hessian (check_index), d(grad b)/dt and
    dw/dt against central differences in t, w = 1 outside the intervals and 0 inside past the ramps."""
    from kinredund.indices import TimeVaryingReference, check_index
    from kinredund.planning.follow import BlendedIndex, Weight

    period, ramp = 2.0, 0.1
    weight = Weight([(-0.2, 0.5), (1.2, 1.6)], period, ramp)  # the first wraps around t = 0
    assert weight(1.0) == (1.0, 0.0) and weight(0.3)[0] == 0.0 and weight(1.4)[0] == 0.0
    assert weight(1.95)[0] == 0.0 and 0.0 < weight(1.85)[0] < 1.0  # the wrapped interval: plateau, ramp
    ref = TimeVaryingReference(lambda t: np.array([np.sin(t), np.cos(2 * t), 0.3 * t]),
                               lambda t: np.array([np.cos(t), -2 * np.sin(2 * t), 0.3]))
    b = BlendedIndex(JointDeviation(np.array([0.2, -0.1, 0.4]), np.array([1.0, 2.0, 0.5])), ref, weight)
    theta, eps = np.array([0.3, -0.2, 0.7]), 1e-6
    for t in (0.42, 0.46, 1.25, 1.27, 1.53, 1.85, 1.0, 0.3):  # on the ramps, outside and inside
        w, dw = weight(t)
        assert 0.0 <= w <= 1.0
        assert abs(dw - (weight(t + eps)[0] - weight(t - eps)[0]) / (2 * eps)) <= 1e-6
        fd = (b.gradient(theta, t + eps) - b.gradient(theta, t - eps)) / (2 * eps)
        assert np.abs(b.time_derivative_of_gradient(theta, t) - fd).max() <= 1e-6
    check_index(b, theta)  # t = 0.0: on the wrapped interval's plateau (w = 0)


def test_every_planner_returns_the_one_result_with_one_validated_cause_vocabulary():
    """kr.plan, the Chapter 6 planner and the roadmap return the pipeline's one PlanResult, whose cause comes from
    planning.result.PLAN_CAUSES: an unknown cause, a failure without a cause or an ok plan with one are refused."""
    import inspect

    from kinredund.errors import ChoiceError
    from kinredund.planning import cyclic, planner, roadmap
    from kinredund.planning.cyclic import CyclicPlan
    from kinredund.planning.result import PLAN_CAUSES, PlanResult

    assert CyclicPlan is PlanResult and CyclicPlan.CAUSES is PLAN_CAUSES
    for fn in (cyclic.plan, planner.plan, roadmap.plan_roadmap):
        assert inspect.signature(fn).return_annotation in (PlanResult, "PlanResult")
    assert PlanResult(False, "no way", cause="no_closed_walk").cause == "no_closed_walk"
    with pytest.raises(ChoiceError, match="plan cause"):
        PlanResult(False, "no way", cause="bad_luck")
    with pytest.raises(KinredundError, match="exactly when"):
        CyclicPlan(False, "failed", None, None, None)
    with pytest.raises(KinredundError, match="exactly when"):
        CyclicPlan(True, "", None, None, None, cause="verification")


def test_a_bad_run_across_t0_is_one_interval_and_the_weight_is_zero_on_all_of_it():
    """Bad points at both ends of the period are one run through t = 0 (the loop closes): the weight must
    follow the reference (w = 0) at every one of them. Before, the run was split into an interval ending
    past the period and one starting before 0, and Weight took the first that matched: w = 1 (z's own
    optimum, at a fold) at t = 0.85 here, and 0.5 at 0.9."""
    from kinredund.planning.follow import Weight, bad_intervals

    period, per, ramp = 1.0, 20, 0.1
    t = np.arange(per) * period / per
    bad = np.zeros(per, bool)
    bad[:3] = bad[-3:] = True  # t = 0, 0.05, 0.1 and 0.85, 0.9, 0.95
    intervals = bad_intervals(t, bad, period, ramp)
    assert len(intervals) == 1
    weight = Weight(intervals, period, ramp)
    fine = np.linspace(0.85, 1.1, 251)  # from the first bad point to the last one through t = 0
    assert max(abs(weight(tk)[0]) for tk in fine) <= rounding()  # 1 - s(1): zero but for rounding
    assert all(weight(tk)[0] == 1.0 for tk in t[6:14])  # past the ramps: z itself (the literal 1.0 returned)
    assert len(bad_intervals(t, bad, period, 0.0)) == 1
