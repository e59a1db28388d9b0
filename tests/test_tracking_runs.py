"""Runs of compiled steps in one C++ call (issue 28: :mod:`kinredund.tracking.runs`, ``src/core/loop.cpp``).

``track()`` on the compiled backend advances in runs of ordinary steps, each one C++ call with the GIL released,
the record written from the core's output rows. Each step of a run is the step
:meth:`~kinredund.tracking.compiled.CompiledStep.step` takes alone: the same core function on the same inputs
(the same path samples, the same predictor history, the same watch gate), so the record and the stepper's state
are the same numbers, not merely close ones, and so are stops. The backends' agreement is
``test_tracking_compiled.py``'s, which runs through these runs too.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest
from test_tracking_compiled import problem

from kinredund import load_robot
from kinredund.errors import TrackingError
from kinredund.ik.solve import solve_ik
from kinredund.indices import minimum_norm
from kinredund.paths import Circle, FunctionPath
from kinredund.tracking import SphereClearance, Tracker, compiled, run, runs, watch
from kinredund.tracking.recorder import Recorder
from kinredund.trajectory import Deferred

pytestmark = pytest.mark.skipif(compiled.load_core() is None and not os.environ.get("CI"),
                                reason="the compiled core is not built (CI requires it: test_core_build.py)")


def _value(x):
    return x() if isinstance(x, Deferred) else x


def assert_identical(a, b, where: str = "") -> None:
    """Every field of two records is the same (arrays bit for bit, NaN where NaN): the same operations on the same
    inputs in the same order give the same floating-point results."""
    for f in dataclasses.fields(a):
        x, y = _value(getattr(a, f.name)), _value(getattr(b, f.name))
        if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=f"{where}{f.name}")
        else:
            assert x == y, f"{where}{f.name}: {x!r} != {y!r}"


def user_path_case():
    """The Panda wrist circle as a user's function (the path's samples one by one: Path.sample_many's default)."""
    r, path, index, q0 = problem("panda_wrist15")

    def fn(t):
        s = path.sample(t)
        return s.Q, s.p, s.omega, s.v

    return r, FunctionPath(fn, period=path.period, has_orientation=True), index, q0


def tracked(monkeypatch, name: str, batched: bool, **options):
    """track() of the named problem with the runs (``batched``) or one step at a time (the runs' reference)."""
    monkeypatch.setattr(run, "stepping", runs.stepping if batched else runs.one_by_one)
    try:
        return run.track(*(user_path_case() if name == "user_path" else problem(name)), backend="compiled",
                         **options)
    except TrackingError as err:
        return err


@pytest.mark.parametrize(("name", "options"), [
    ("panda_elbow_circle", {"loops": 2}),  # a joint reaches its bound and leaves it (runs go on while it is held)
    ("panda_elbow_circle", {"loops": 1, "scheme": "velocity"}),  # held steps of the velocity form (label lu)
    ("ur5_axis", {"loops": 2, "scheme": "velocity"}),  # the path's orientation, the velocity form
    ("planar_time_varying", {"loops": 1, "limits": False}),  # the reference sampled per step with the path
    ("example_4.1", {"loops": 2, "limits": False, "strict": False}),  # no step control, no watch
    ("panda_wrist15", {"loops": 1, "steps_per_loop": 37}),  # runs through the watch's measured steps
    ("panda_pose_circle", {"loops": 1}),  # held steps each measured (rcond low): inverse iteration in the runs
    ("user_path", {"loops": 1}),  # a path sampled one time at a time
])
def test_runs_record_the_same_numbers_as_single_steps(monkeypatch, name, options):
    a = tracked(monkeypatch, name, False, **options)
    b = tracked(monkeypatch, name, True, **options)
    assert_identical(a, b)
    assert a.meta == b.meta


def test_a_stop_in_a_run_is_the_same_stop(monkeypatch):
    a = tracked(monkeypatch, "panda_pose_infeasible", False, loops=2)
    b = tracked(monkeypatch, "panda_pose_infeasible", True, loops=2)
    assert isinstance(a, TrackingError) and isinstance(b, TrackingError)
    assert (b.cause, b.t) == (a.cause, a.t)
    np.testing.assert_array_equal(b.q, a.q)
    assert_identical(a.partial, b.partial, "partial.")


def planar_reach_case():
    """A planar arm stretched towards its reach (sigma_min(J) -> 0 at T/2, where the run stops)."""
    arm = load_robot("planar3r")
    path = Circle(np.array([5.0, 0.0, 0.0]), 1.0, 1.0, start_angle=np.pi)
    index = minimum_norm(3)
    return arm, path, index, solve_ik(arm, path(0.0).p[:2], index, starts=12, seed=0).q


def watched_runs(monkeypatch) -> list:
    """What happens to the compiled steps from now on, in order: ("run", steps done, status, measurements kept) per
    call of the core's run_steps, ("back", status) per step handed to the Python stepper."""
    core, events = compiled.load_core(), []
    inner, hand_back = core.run_steps, compiled.CompiledStep.hand_back

    def counting(*args):
        done, status, kept = inner(*args)
        events.append(("run", done, status, 0 if kept is None else kept[-1]))
        return done, status, kept

    def back(self, status):
        events.append(("back", status))
        return hand_back(self, status)

    monkeypatch.setattr(core, "run_steps", counting)
    monkeypatch.setattr(compiled.CompiledStep, "hand_back", back)
    return events


def stops_both_ways(monkeypatch, case) -> tuple:
    """(the stop one step at a time, the stop in runs) of track() on ``case``, each a TrackingError."""
    stops = []
    for stepping in (runs.one_by_one, runs.stepping):
        monkeypatch.setattr(run, "stepping", stepping)
        with pytest.raises(TrackingError) as info:
            run.track(*case, backend="compiled", steps_per_loop=200)
        stops.append(info.value)
    return tuple(stops)


def test_a_run_through_the_watch_stops_where_single_steps_stop(monkeypatch):
    """The planar arm stretched towards its reach: the watch's verdicts inside a run (the core's WatchHistory) predict
    the crossing (the run is cut before the step it predicts into: AHEAD, then handed back as ``watch_ahead``) and,
    with the fold floor raised to just under the reduced Hessian's value at an exactly measured step inside a run
    (EIG_FLOOR 0.129257, its scale ~3.84: the eigenvalue falls slower there than the prediction from the last two
    measurements, which lets the run reach that step), reject it there (WATCH_DUE; CompiledStep.accept measures it
    again and hands it back): the same stop, partial record and counters as single steps, each branch reached."""
    case, core = planar_reach_case(), compiled.load_core()
    for floor, branch in ((watch.EIG_FLOOR, "cut"), (0.129257, "rejected")):
        monkeypatch.setattr(watch, "EIG_FLOOR", floor)
        events = watched_runs(monkeypatch)
        a, b = stops_both_ways(monkeypatch, case)
        assert (b.cause, b.t) == (a.cause, a.t)
        assert a.cause == {"cut": "kinematic_singularity", "rejected": "fold"}[branch]
        assert_identical(a.partial, b.partial, "partial.")
        assert a.partial.meta == b.partial.meta
        seen = {"cut" if x[0] == "run" and x[2] == core.AHEAD and y == ("back", 8) else
                "rejected" if x[0] == "run" and x[2] == core.WATCH_DUE and y == ("back", compiled.WATCH_REJECTS)
                else None for x, y in zip(events, events[1:], strict=False)}
        assert branch in seen, events


def single_and_runs(r, path, index, q0, dt: float, steps: int, **options) -> tuple:
    """Two compiled Trackers of one problem after ``steps`` steps: one stepped alone, one advanced in runs (recorded);
    (single, batched, the batched one's Recorder, the steps each call of the runs took)."""
    single = Tracker(r, path, index, q0, dt, backend="compiled", **options)
    batched = Tracker(r, path, index, q0, dt, backend="compiled", **options)
    rec = Recorder(batched.stepper)
    advance = runs.stepping(batched, rec)
    taken = []
    while sum(taken) < steps:
        taken.append(advance(steps - sum(taken)))
    for _ in range(steps):
        single.step()
    return single, batched, rec, taken


def test_runs_take_many_steps_per_call_and_leave_the_state_of_single_steps():
    r, path, index, q0 = problem("panda_elbow_circle")
    single, batched, rec, taken = single_and_runs(r, path, index, q0, path.period / 200, 300)
    assert sum(taken) == 300 and len(rec) == 300
    assert max(taken) > watch.EXACT_EVERY  # runs go on through the watch's exact measurements (every 32nd step)
    a, b = single.stepper, batched.stepper
    assert (b.t, b.k) == (a.t, a.k)
    for key in ("q", "lam", "qdot", "lamdot", "y", "yd", "M"):
        np.testing.assert_array_equal(getattr(b, key), getattr(a, key), err_msg=key)
    assert len(b.prev) == len(a.prev)
    for u, v in zip(b.prev, a.prev, strict=True):
        np.testing.assert_array_equal(u, v)
    assert b.control.watch.gate == a.control.watch.gate and b.control.speed2 == a.control.speed2
    assert batched.compiled.steps == single.compiled.steps
    assert batched.compiled.handed_back == single.compiled.handed_back


def side_by_side(name: str, held_per_call) -> tuple:
    """(path, single, batched, their recorders): one loop of 200 steps of the named problem's compiled tracker one
    step at a time and in runs (``held_per_call(k)``: the held steps the core took in each call)."""
    r, path, index, q0 = problem(name)
    dt = path.period / 200
    single = Tracker(r, path, index, q0, dt, backend="compiled")
    batched = Tracker(r, path, index, q0, dt, backend="compiled")
    rec_a, rec_b = Recorder(single.stepper), Recorder(batched.stepper)
    rec_a.add()
    rec_b.add()
    advance, done = runs.stepping(batched, rec_b), 0
    while done < 200:
        before = batched.compiled.held_steps
        done += advance(200 - done)
        held_per_call(batched.compiled.held_steps - before)
    for _ in range(200):
        single.step()
        rec_a.add()
    return path, single, batched, rec_a, rec_b


def test_runs_go_on_through_steps_with_a_joint_held_on_its_bound():
    """Runs do not stop at a held joint: the core steps on the reduced system (the active set it was given) until
    the active set changes, and the record, the switches and the state are those of single steps."""
    held_runs = []  # the held steps the core took in each call
    path, single, batched, rec_a, rec_b = side_by_side("panda_elbow_circle", held_runs.append)
    assert max(held_runs) >= 10  # many held steps per call (through the watch's measurements of each: rcond is low)
    assert batched.compiled.held_steps == single.compiled.held_steps >= max(held_runs)
    assert batched.compiled.handed_back == single.compiled.handed_back
    info = {"robot_name": "panda", "scheme": "augmented", "mode": "default", "loops": 1, "steps_per_loop": 200,
            "period": path.period}
    a, b = (rec.trajectory(meta={}, **info) for rec in (rec_a, rec_b))
    assert_identical(a, b)
    assert len(a.meta["switches"]) >= 2 and a.meta == b.meta
    np.testing.assert_array_equal(a.active_bounds, b.active_bounds)
    assert np.count_nonzero(np.abs(b.active_bounds).sum(axis=1)) >= max(held_runs)  # points recorded with a held joint


def test_runs_go_on_through_the_watch_s_inverse_iteration_and_leave_its_state_of_single_steps():
    """On the Panda pose circle R's rcond is ~2.5e-5 while joint 4 is held: the watch measures every held step by its
    inverse iteration with R's factors. The runs measure them in the core (run_steps, the routine of the single
    steps' StepCore.watch_measure) and go on through them: far fewer calls than measured steps, and the watch's
    history, vector, counters and the record those of single steps, bit for bit."""
    held_runs = []
    path, single, batched, rec_a, rec_b = side_by_side("panda_pose_circle", held_runs.append)
    calls = len(held_runs)
    wa, wb = single.stepper.control.watch, batched.stepper.control.watch
    assert wb.core_measured == wa.core_measured >= 20 and wb.gate == wa.gate
    assert calls < wa.core_measured // 2  # (a run was cut at each before: one call per measured step)
    assert (wb.times, wb.eig, wb.sigma_times, wb.sigma) == (wa.times, wa.eig, wa.sigma_times, wa.sigma)
    for u, v in zip(wb.iteration, wa.iteration, strict=True):
        np.testing.assert_array_equal(u, v)
    assert batched.compiled.handed_back == single.compiled.handed_back
    info = {"robot_name": "panda", "scheme": "augmented", "mode": "default", "loops": 1, "steps_per_loop": 200,
            "period": path.period}
    assert_identical(*(rec.trajectory(meta={}, **info) for rec in (rec_a, rec_b)))


def test_the_core_refuses_arrays_of_the_wrong_shape():
    r, path, index, q0 = problem("example_4.1")
    tr = Tracker(r, path, index, q0, path.period / 100, backend="compiled", limits=False)
    s, core = tr.stepper, compiled.load_core()
    t = np.array([s.dt, 2 * s.dt])
    p = np.zeros((2, 3))
    none = np.zeros((0, 9)), np.zeros((0, 3)), np.zeros((0, s.n)), np.zeros((0, s.n))
    watch = (True, 1e-4, 0.8, 1.0, 0, 32)
    with pytest.raises(ValueError, match=r"out must have at least 2 rows"):
        core.run_steps(tr.compiled.core, t, p, p, *none, s.y, s.yd, s.prev, s.qdot, 0.0, True, watch, np.zeros((1, 5)))
    with pytest.raises(ValueError, match=r"v must have shape \(2, 3\)"):
        core.run_steps(tr.compiled.core, t, p, p[:1], *none, s.y, s.yd, s.prev, s.qdot, 0.0, True, watch,
                       np.zeros((2, 5)))


@pytest.mark.parametrize("kw", [{}, {"frenet": True}, {"orientation": np.eye(3)},
                                {"orientation": np.diag([1.0, -1.0, -1.0]), "roll_amplitude": 0.3}])
def test_a_circle_samples_many_times_as_it_samples_each(kw):
    path = Circle(np.array([0.4, -0.1, 0.5]), 0.12, 0.3, start_angle=0.7, normal=(0.2, 0.3, 0.9), **kw)
    times = (0.013 * np.arange(40) - 0.1).tolist()
    many = path.sample_many(times)
    for k, want in enumerate(path.sample(t) for t in times):
        got = many.sample(k)
        for name in ("p", "v", "Q", "omega"):  # the same operations: the same numbers
            a, b = getattr(got, name), getattr(want, name)
            assert (a is None) == (b is None), name
            if a is not None:
                np.testing.assert_array_equal(a, b, err_msg=name)
                np.testing.assert_array_equal(getattr(many, name)[k], b, err_msg=f"stacked {name}")


def test_progress_is_told_of_every_step_in_order():
    r, path, index, q0 = problem("panda_wrist15")
    seen = []
    tr = run.track(r, path, index, q0, loops=1, steps_per_loop=60, backend="compiled",
                   progress=lambda done, total: seen.append((done, total)))
    assert seen == [(k, 60) for k in range(1, 61)] and len(tr.t) == 61


def test_one_sampling_of_the_path_ahead_takes_the_blocks_that_stack_and_no_other():
    """ahead.sample_block (SamplesAhead's and the runs' sampling): a circle's samples as Path.sample_many gives
    them at step_times (t0 + k dt, the stepper's clock to the bit); None where the samples do not stack (PathError)
    or a field has another shape, so that the steps sample one by one."""
    from kinredund.errors import PathError
    from kinredund.paths.base import Samples
    from kinredund.tracking.ahead import sample_block, step_times

    t0, dt = 0.25, 0.01
    times = step_times(t0, dt, 3, 5)
    assert times == [t0 + k * dt for k in range(3, 8)]
    path = problem("panda_wrist15")[1]
    at = sample_block(path, times)
    for j, t in enumerate(times):
        one = path.sample(t)
        np.testing.assert_array_equal(at.p[j], one.p)
        np.testing.assert_array_equal(at.Q[j], one.Q)

    class Stub:
        def __init__(self, samples):
            self.samples = samples

        def sample_many(self, times):
            if self.samples is None:
                raise PathError("no stack")
            return self.samples

    k = len(times)
    good = Samples(np.zeros((k, 3)), np.zeros((k, 3)), np.zeros((k, 3, 3)), np.zeros((k, 3)))
    assert sample_block(Stub(good), times) is good
    assert sample_block(Stub(Samples(np.zeros((k, 3)), np.zeros((k, 3)))), times) is not None  # no orientation
    for bad in (None, Samples(np.zeros((k, 2)), np.zeros((k, 3))), Samples(np.zeros((k, 3)), np.zeros((k - 1, 3))),
                Samples(np.zeros((k, 3)), np.zeros((k, 3)), np.zeros((k, 9)), np.zeros((k, 3))),
                Samples(np.zeros((k, 3)), np.zeros((k, 3)), np.zeros((k, 3, 3)), np.zeros((k, 4)))):
        assert sample_block(Stub(bad), times) is None


def scene_case(name: str):
    """(robot, path, index, q0, track's scene options) of test_tracking_scene's ball met and left by the elbow,
    test_tracking_self_clearance's hand held off the upper arm (a self pair met and left twice a loop) and
    test_tracking_clearance's elbow sphere."""
    from test_tracking_scene import CLEARANCE
    from test_tracking_scene import setup as ball_setup
    from test_tracking_self_clearance import SELF_CLEARANCE
    from test_tracking_self_clearance import setup as self_setup

    if name == "ball":
        *problem_, sc = ball_setup("panda_elbow_ball")
        return (*problem_, {"scene": sc, "clearance": CLEARANCE, "self_clearance": False, "steps_per_loop": 400})
    if name == "sphere":  # test_tracking_clearance's elbow sphere (a frame's row: FrameRows)
        from test_tracking_clearance import CASES
        from test_tracking_limits import case

        circle, frame, center, radius = CASES["panda_elbow_sphere"]
        r, path, index, q0 = case(circle)
        return r, path, index, q0, {"constraints": [SphereClearance(r, frame, center, radius)]}
    *problem_, sc = self_setup()
    return (*problem_, {"scene": sc, "self_clearance": SELF_CLEARANCE})


def counted_runs(monkeypatch, held: list | None = None) -> list:
    """Per call of the core's run_steps from now on: (steps done, status, measurements kept, guarded); ``held``
    receives the steps done by each call with general rows held in the core."""
    core = compiled.load_core()
    calls, inner = [], core.run_steps

    def counting(*args):
        rows = args[0].held_rows
        done, status, kept = inner(*args)
        calls.append((done, status, 0 if kept is None else kept[-1], args[-1] is not None))
        if held is not None and rows:
            held.append(done)
        return done, status, kept

    monkeypatch.setattr(core, "run_steps", counting)
    return calls


@pytest.mark.parametrize("name", ["ball", "self_pair", "sphere"])
def test_a_scene_run_records_the_same_numbers_as_single_guarded_steps(monkeypatch, name):
    """With a scene (or a sphere) the runs check each step with the rows' compiled check in the core's run (as
    StepCore.step_guarded checks a single step) and hand the first step it does not clear to the stepper's search
    (GUARD_DUE); they go on with a row held (the core's held rows, the check leaving them out, a step whose R has
    odd inertia handed over for the watch's exact measurement): the record - the row fields (smallest value per
    point, active rows, multipliers, switches) included - is that of single guarded steps, bit for bit, and each
    kind of hand-back is reached."""
    r, path, index, q0, options = scene_case(name)
    records, held = [], []
    for stepping in (runs.one_by_one, runs.stepping):
        monkeypatch.setattr(run, "stepping", stepping)
        calls = counted_runs(monkeypatch, held)
        records.append(run.track(r, path, index, q0, loops=2, backend="compiled", **options))
    a, b = records
    assert_identical(a, b)
    assert a.meta == b.meta
    assert len(a.meta["switches"]) >= 4 and any(a.meta["constraints"]["active"])  # rows met and left
    statuses = {status for _, status, _, _ in calls}
    core = compiled.load_core()
    assert core.GUARD_DUE in statuses  # a step the check does not clear: the stepper's search took it
    assert all(guarded for *_, guarded in calls)
    assert sum(done for done, *_ in calls) > len(a.t) // 2  # most steps in runs
    assert sum(held) > sum(map(bool, a.meta["constraints"]["active"])) // 3  # steps with a row held too
    # a guarded run goes on through the steps the watch measures (its verdicts the run's, step by step)
    assert max(kept for _, _, kept, _ in calls) >= 2 and max(done for done, *_ in calls) > watch.EXACT_EVERY


#: test_tracking_limits's circle case in the Panda's plane of symmetry (x-z): its home (the joints about axes across
#: that plane at zero, joint 7 moving no point of the task), a 0.1 m circle in the plane at 0.1 m/s, z = 1/2 ||q -
#: home||^2; and a sphere centred in the plane where the free optimum's elbow (panda_link4's origin) passes at 7/40 of
#: the loop, 5 mm larger than its distance from the free start's elbow, so that the start is held on it (HEAD_ON_Q0:
#: solve_ik_rows's minimum at t = 0, its out-of-plane joints' 1e-16 rad set to zero, push |w| = 0.43)
HEAD_ON_SPHERE = ("panda_link4", [-0.19381380788762115, 0.0, 0.5958658552800273], 0.039506645060579854)
HEAD_ON_Q0 = [0.0, -0.769665703885916, 0.0, -2.338583082196584, 0.0, 1.5305534882181615, 0.785]


def test_a_run_hands_over_a_held_step_whose_r_has_odd_inertia(monkeypatch):
    """The elbow pressed head-on into a sphere in the arm's plane of symmetry: the held optimum stays in the plane,
    and as the push grows the row's curvature (its multiplier over the radius) takes the reduced Hessian's
    out-of-plane eigenvalue through zero without a fold (a pitchfork: the held branch goes on, as a saddle). R's
    condition, the watch's gate, does not fall (rcond rises, 0.0026 -> 0.0033) and the watch's history holds the
    start's measurement alone, so nothing predicts the crossing: a run with the row held steps onto the saddle and
    only its inertia test (loop.cpp: odd_inertia on the step's R factors) ends it there, with WATCH_DUE, for
    CompiledStep.accept to measure exactly and hand back. Checked: a run ended after held steps with WATCH_DUE at a
    step whose factors have odd inertia (Python's odd_inertia) and which the gate would have passed (due_next False:
    no other exit of the run gives WATCH_DUE there), where Z^T M Z (Z an SVD null basis of [J; G]) has an
    eigenvalue of -0.050 (the 13 held steps before it in the run: minima, their inertia even); one step at a time
    the Python test finds the same step, with the same numbers. Both ways the run stops at the step before it
    (``collision``, a fold under it), with the same joints and partial record."""
    from test_tracking_limits import circle_case

    from kinredund.tracking.step_control import odd_inertia

    r, path, index, _ = circle_case("panda", [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785], [0, 1, 0], [1, 0, 0], 0.1)
    sphere = SphereClearance(r, *HEAD_ON_SPHERE)
    core = compiled.load_core()
    inner, accept = core.run_steps, compiled.CompiledStep.accept
    events = []

    def counting(*args):
        held = bool(args[0].held_rows)
        done, status, kept = inner(*args)
        events.append(("run", held, done, status))
        return done, status, kept

    def measured(self, out, sample, t_to, *args, **kwargs):
        s = self.stepper
        if self.rows and s.rows:  # a held step: R's inertia, the gate's verdict, Z^T M Z's least eigenvalue
            free = ~s.fixed
            y = out[self.output_layout()[0][0]]
            pt = s.evaluate(y[:s.n], t_to)
            M, A = pt.system(y[s.n:])[0][np.ix_(free, free)], pt.J[:, free]
            Z = np.linalg.svd(A)[2][len(A):].T
            events.append(("held", t_to, odd_inertia(*self.held.factors(), int(free.sum())),
                           s.control.watch.due_next(float(out[-2])), float(np.linalg.eigvalsh(Z.T @ M @ Z)[0])))
        return accept(self, out, sample, t_to, *args, **kwargs)

    monkeypatch.setattr(core, "run_steps", counting)
    monkeypatch.setattr(compiled.CompiledStep, "accept", measured)
    stops, held = [], []
    for stepping in (runs.one_by_one, runs.stepping):
        events.clear()
        monkeypatch.setattr(run, "stepping", stepping)
        with pytest.raises(TrackingError) as info:
            run.track(r, path, index, np.array(HEAD_ON_Q0), backend="compiled", loops=1, steps_per_loop=100,
                      constraints=[sphere])
        stops.append(info.value)
        held.append([e for e in events if e[0] == "held"])
    j = next(j for j, e in enumerate(events) if e[0] == "held" and e[2])  # the runs' step with odd inertia
    saddle, (_, rows, done, status) = events[j], events[j - 1]
    assert rows and done >= 2 and status == core.WATCH_DUE  # the end of a run of held steps
    assert saddle[3] is False and saddle[4] < -0.01  # the gate passes it; a saddle of the held problem
    assert held[0][-1] == saddle and len(held[0]) == done + 1  # one step at a time: the same step, the same numbers
    assert all(not odd and eig > 0.0 for _, _, odd, _, eig in held[0][:-1])  # minima before it
    a, b = stops
    assert (b.cause, b.t) == (a.cause, a.t) and a.cause == "collision"
    assert a.watched["underlying_cause"] == b.watched["underlying_cause"] == "fold"
    assert saddle[1] == pytest.approx(a.t + path.period / 100, abs=1e-12)  # the step after the last good one
    np.testing.assert_array_equal(b.q, a.q)
    assert_identical(a.partial, b.partial, "partial.")
    assert a.partial.meta == b.partial.meta


def test_scene_runs_leave_the_state_and_the_checks_counters_of_single_steps():
    """Tracker-level: after 400 steps in runs the stepper's state, the step counters and the scene check's own
    counters (placements of the objects, exact distances, per-row recomputations) are those of single guarded
    steps - the check ran on the same steps with the same arrays - and its clock counted the runs' checks."""
    r, path, index, q0, options = scene_case("ball")
    options = {k: v for k, v in options.items() if k != "steps_per_loop"}
    single, batched, rec, taken = single_and_runs(r, path, index, q0, path.period / 400, 400, **options)
    assert sum(taken) == 400 and len(rec) == 400 and max(taken) >= watch.EXACT_EVERY // 2
    a, b = single.stepper, batched.stepper
    assert (b.t, b.k, b.rows) == (a.t, a.k, a.rows)
    for key in ("q", "lam", "qdot", "y", "yd"):
        np.testing.assert_array_equal(getattr(b, key), getattr(a, key), err_msg=key)
    assert batched.compiled.steps == single.compiled.steps
    assert batched.compiled.handed_back == single.compiled.handed_back
    ga, gb = single.compiled.guard.compiled, batched.compiled.guard.compiled
    assert (gb.placements, gb.distances, gb.computed) == (ga.placements, ga.distances, ga.computed)
    assert gb.placements > 0 and gb.distances > 0 and gb.seconds > 0.0


def test_a_stop_in_a_scene_run_is_the_same_stop(monkeypatch):
    """test_tracking_scene's fingers pressed on the upper arm until a self pair's distance is not differentiable
    (``collision``): the same stop, time, joints and partial record (row fields included) in runs as in single steps."""
    from test_tracking_scene import setup as scene_setup

    from kinredund.geometry import Scene

    r, path, index, q0, _ = scene_setup()
    stops = []
    for stepping in (runs.one_by_one, runs.stepping):
        monkeypatch.setattr(run, "stepping", stepping)
        with pytest.raises(TrackingError) as info:
            run.track(r, path, index, q0, backend="compiled", scene=Scene(r))
        stops.append(info.value)
    a, b = stops
    assert (b.cause, b.t) == (a.cause, a.t) and a.cause == "collision"
    np.testing.assert_array_equal(b.q, a.q)
    assert_identical(a.partial, b.partial, "partial.")
    assert a.partial.meta == b.partial.meta


def assert_same_watch(a, b) -> None:
    """Two watches in the same state, bit for bit: histories, floors' scales, the prediction, the inverse iteration's
    vector and reference, the gate and the count of the core's measurements."""
    for key in ("times", "eig", "sigma_times", "sigma", "sigma_max", "scale", "safe_before", "gate", "core_measured",
                "_fresh", "_sigma_ref", "_key", "_exact_at"):
        assert getattr(b, key) == getattr(a, key), key
    for key in ("_v", "_J_ref"):
        np.testing.assert_array_equal(getattr(b, key), getattr(a, key), err_msg=key)


def test_runs_leave_the_watch_as_single_steps_leave_it(monkeypatch):
    """The watch's verdicts taken in the core's runs (WatchHistory: the crossing tests, the measurements kept, the
    history and its prediction; Watch.take_run) leave the watch in the state single steps leave it, bit for bit: on
    the Panda pose circle, whose held steps are measured by the inverse iteration inside the runs (core_measured
    grows in runs), and on the planar arm stretched towards its reach, a run cut by a predicted crossing (AHEAD)."""
    events = watched_runs(monkeypatch)
    path, single, batched, *_ = side_by_side("panda_pose_circle", lambda held: None)
    assert_same_watch(single.stepper.control.watch, batched.stepper.control.watch)
    assert any(x[0] == "run" and x[3] >= 2 for x in events)  # measurements kept inside runs
    assert batched.stepper.control.watch.core_measured > 20
    arm, path, index, q0 = planar_reach_case()
    dt = path.period / 200
    single = Tracker(arm, path, index, q0, dt, backend="compiled")
    batched = Tracker(arm, path, index, q0, dt, backend="compiled")
    advance, done = runs.stepping(batched, Recorder(batched.stepper)), 0
    events.clear()
    while done < 95:  # before the stop (t = T/2: step 100), past the first cut (AHEAD)
        done += advance(95 - done)
    for _ in range(done):
        single.step()
    assert any(x[0] == "run" and x[2] == compiled.load_core().AHEAD for x in events), events
    assert_same_watch(single.stepper.control.watch, batched.stepper.control.watch)


def test_track_many_in_threads_records_what_single_steps_record(monkeypatch):
    """track_many on two threads, whose runs take the watch's verdicts in the core with the GIL released (the Panda
    pose circle's inverse-iteration measurements kept in runs, the planar arm's run cut by a predicted crossing and
    its stop, a bound reached and left on the Panda elbow circle), gives each problem's record or stop of single
    steps in one thread, bit for bit."""
    from kinredund.tracking import track_many

    problems = [problem("panda_pose_circle"), planar_reach_case(), problem("panda_elbow_circle")] * 2
    many = track_many(problems, threads=2, backend="compiled")
    monkeypatch.setattr(run, "stepping", runs.one_by_one)
    for got, p in zip(many, problems, strict=True):
        try:
            alone = run.track(*p, backend="compiled")
        except TrackingError as err:
            assert isinstance(got, TrackingError) and (got.cause, got.t) == (err.cause, err.t)
            assert_identical(err.partial, got.partial, "partial.")
            continue
        assert_identical(alone, got)
        assert alone.meta == got.meta


#: the run of test_a_run_leaves_no_cyclic_garbage, in an interpreter of its own: the suite's other tests leave
#: threads behind (Dask's event loop, the meshcat server) whose own cyclic garbage a collection here would count
_CYCLIC_GARBAGE_RUN = """
import collections, gc, sys
sys.path.insert(0, sys.argv[1])
from test_tracking_compiled import problem
from test_tracking_runs import planar_reach_case
from kinredund.errors import TrackingError
from kinredund.problems import panda_circle
from kinredund.tracking import run
case, switching = panda_circle(wrist_amplitude=0.1), problem("panda_elbow_circle")
run.track(*case, backend="compiled")
run.track(*switching, backend="compiled")
gc.collect()
gc.disable()
gc.set_debug(gc.DEBUG_SAVEALL)
traj = run.track(*case, backend="compiled")
switched = len(run.track(*switching, backend="compiled").meta["switches"])
stopped = None
try:
    run.track(*planar_reach_case(), backend="compiled", steps_per_loop=200)
except TrackingError as err:
    stopped = err.partial
found = gc.collect()
kinds = collections.Counter(type(o).__qualname__ for o in gc.garbage).most_common(8)
print(found, len(traj.q), -1 if stopped is None else len(stopped.q), switched, kinds)
gc.set_debug(0)
gc.garbage.clear()
gc.enable()
"""


def test_a_run_leaves_no_cyclic_garbage():
    """track() unlinks its stepper from its step control once the run is recorded (a run's one reference cycle), and
    the switch search's Brent method is kinredund.tracking.roots' (scipy's brentq left its function for the collector):
    a finished run's objects (the benchmark circle of benchmarks/many.py), a run's with two bound switches, and a
    stopped one's, are freed by reference counting, none left for the cyclic garbage collector, whose collections
    held the GIL ~25 us per run (track_many's threads). Measured in a fresh interpreter, where no other thread makes
    garbage of its own meanwhile."""
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-P", "-c", _CYCLIC_GARBAGE_RUN, os.path.dirname(__file__)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    found, steps, stopped_steps, switched, kinds = done.stdout.strip().split(" ", 4)
    assert int(found) == 0, f"{found} objects left for the cyclic collector: {kinds}"
    assert int(steps) == 201 and int(stopped_steps) > 1 and int(switched) >= 2


def test_record_columns_and_step_times_are_numpy_s():
    """Column.array stacks a record's rows as np.concatenate (np.array for one list of rows) does, bit for bit, dtype
    and shape (rows of vectors and of matrices, blocks of rows and lists of rows, one block, ints), in copies below
    numpy's 500-entry threshold for releasing the GIL; step_time_array's clock is t0 + np.arange(first, first + count)
    dt, the same floats, within and beyond its table of step numbers."""
    from kinredund.tracking.ahead import step_time_array
    from kinredund.tracking.recorder import COPY_ELEMENTS, Column

    rng = np.random.default_rng(28)
    for shape, dtype in (((7,), float), ((7, 7), float), ((3,), int)):
        column, blocks = Column(), []
        for size in (1, 200, 3, 120):
            rows = rng.normal(size=(size, *shape)).astype(dtype)
            if size < 10:  # rows appended one by one (a list), else a run's block (a strided view, as the core's)
                for row in rows:
                    column.append(row)
                blocks.append(list(rows))
            else:
                wide = np.zeros((size, 2 * int(np.prod(shape))), dtype)
                block = wide[:, ::2].reshape(size, *shape)
                block[...] = rows
                column.extend(block)
                blocks.append(block)
        got, want = column.array(), np.concatenate(blocks)
        assert got.dtype == want.dtype and got.shape == want.shape and got.tobytes() == want.tobytes()
        single = Column()
        single.extend(blocks[1])
        assert single.array().tobytes() == np.array(blocks[1]).tobytes() and COPY_ELEMENTS <= 500
    for t0, dt, first, count in ((0.0, 0.1, 1, 200), (2.5, 1e-3, 12345, 256), (0.0, np.pi / 100, 7, 300)):
        want = t0 + np.arange(first, first + count) * dt
        assert step_time_array(t0, dt, first, count).tobytes() == want.tobytes()


def test_track_many_raises_the_first_bad_problem_s_error_after_every_run(monkeypatch):
    """track_many's threads (the caller one of them, each taking the next problem) give the records in the problems'
    order and, where a run raises an error of bad input, raise the first such problem's error (as
    ThreadPoolExecutor.map did) once every run has ended: the runs after it were made too."""
    from kinredund.errors import JointVectorError
    from kinredund.tracking import many, track_many

    good = problem("panda_wrist15")
    worse, bad = (*good[:3], np.zeros(2)), (*good[:3], np.zeros(3))
    ran, inner = [], run.track

    def counted(*args, **kwargs):
        ran.append(len(args[3]))
        return inner(*args, **kwargs)

    monkeypatch.setattr(many, "track", counted)
    with pytest.raises(JointVectorError, match=r"got \(3,\)"):
        track_many([good, bad, good, worse, good], threads=2, loops=1, steps_per_loop=20)
    assert sorted(ran) == [2, 3, 7, 7, 7]
    alone = inner(*good, loops=1, steps_per_loop=20)
    for traj in track_many([good, good, good], threads=3, loops=1, steps_per_loop=20):
        assert_identical(alone, traj)


@pytest.mark.parametrize("problems", [None, 3, "abcd", np.array(0.0)])
def test_track_many_refuses_problems_that_are_not_a_list_of_tuples(problems):
    """None or a number raised Python's TypeError ('NoneType' object is not iterable); a string was taken as its
    characters. Each is an OptionError saying what problems must be."""
    from kinredund.errors import OptionError
    from kinredund.tracking import track_many

    with pytest.raises(OptionError, match=r"problems must be a list of \(robot, path, index, q0\) tuples, got "
                                          f"{type(problems).__name__}"):
        track_many(problems)


def test_track_many_starts_no_more_threads_than_problems(monkeypatch):
    """threads beyond the problems' count would find no problem to take: track_many starts at most one thread per
    problem (the caller one of them), so threads=10**6 for two problems runs them on two threads (it started a
    million threads, which the machine could not make)."""
    import threading

    from kinredund.tracking import many, track_many

    good = problem("panda_wrist15")
    started, inner = [], threading.Thread

    def counted(*args, **kwargs):
        started.append(1)
        return inner(*args, **kwargs)

    monkeypatch.setattr(many.threading, "Thread", counted)
    records = track_many([good, good], threads=10**6, loops=1, steps_per_loop=20)
    assert len(started) == 1  # the second problem's; the first runs on the calling thread
    alone = run.track(*good, loops=1, steps_per_loop=20)
    for traj in records:
        assert_identical(alone, traj)


@pytest.mark.parametrize("backend", ["compiled", "python"])
def test_a_start_within_the_tolerance_is_polished_so_the_loop_closes(backend):
    """The start takes one Newton update even where F is within the corrector's tolerance (an IK answer): a start
    1e-13 rad off the corrected one (F within tol, so that without the update the run starts there and every loop
    ends 1e-13 away from it) is moved onto the manifold, and two loops close to rounding (~5e-16 here; bar 1e-14)."""
    from kinredund.problems import panda_circle

    r, path, index, q0 = panda_circle(wrist_amplitude=0.1)
    exact = np.asarray(run.track(r, path, index, q0, backend=backend, loops=1).q[0])
    off = np.random.default_rng(3).normal(size=7)
    start = exact + 1e-13 * off / np.abs(off).max()
    q = np.asarray(run.track(r, path, index, start, backend=backend, loops=2).q)
    assert np.abs(q[0] - start).max() > 5e-14  # moved
    assert np.abs(q[-1] - q[0]).max() <= 1e-14 and np.abs(q[len(q) // 2] - q[0]).max() <= 1e-14
