"""A frame clearance's row in the compiled core (issue 28): ``kinredund._core.FrameRows`` (src/core/frame_rows.cpp).

A :class:`~kinredund.tracking.SphereClearance` or :class:`~kinredund.tracking.PlaneClearance` gives the compiled step
its row (``row_guard``): the core checks each step for a switch of it and holds it as the Python stepper's extended
system does (:mod:`kinredund.tracking.compiled_rows`). Its value, gradient and curvature are the constraint's own,
computed with the same Pinocchio calls, so they agree to rounding; its check is the stepper's search's first test
(``segment_lower_bounds``); stepped in turn, the two backends agree to the issue's 1e-12 rad at every step.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_tracking_clearance import CASES
from test_tracking_compiled import assert_same_record, both
from test_tracking_compiled_rows import agree_in_turn, assert_same_rows
from test_tracking_limits import case
from test_tracking_scene import CLEARANCE as SCENE_CLEARANCE
from test_tracking_scene import setup as scene_setup

from kinredund.model.loader import load_robot
from kinredund.tracking import PlaneClearance, SphereClearance, Tracker, compiled
from kinredund.tracking.rows import ROW_TOL
from kinredund.tracking.switches import segment_move

pytestmark = pytest.mark.skipif(compiled.load_core() is None, reason="the compiled core is not built")

EPS = np.finfo(float).eps


def constraints(robot):
    """A sphere and a plane on the origin of a frame four from the end (an elbow or wrist link)."""
    frame = robot.model.frames[len(robot.model.frames) - 6].name
    return [SphereClearance(robot, frame, [0.2, 0.1, 0.4], 0.1, 0.02),
            PlaneClearance(robot, frame, [0.0, 0.0, 0.1], [0.3, 0.2, 1.0], 0.01)]


@pytest.mark.parametrize("name", ["panda", "xarm7", "ur5"])
def test_the_cores_row_is_the_constraints(name):
    """FrameRows.rows and .curvature against the constraint's rows_at and curvature at random joints: the same
    Pinocchio calls and a few dozen operations on numbers of size max(1, |x|) (kind 1 of the tolerance policy)."""
    robot = load_robot(name, task="position")
    rng = np.random.default_rng(3)
    for c in constraints(robot):
        check = c.row_guard(ROW_TOL)
        assert check is not None and check.holds and check.valid()
        sizes = []
        for _ in range(20):
            q = rng.uniform(robot.lower, robot.upper)
            w = rng.normal()
            (value, G), (pv, pG) = check.compiled.rows(q), c.rows_at(q)
            H, pH = check.compiled.curvature(q, w), c.curvature(q, np.array([w]), np.array([0]))
            for x, y in ((value, pv), (G, pG), (H, pH)):
                assert x.shape == y.shape
                np.testing.assert_allclose(x, y, rtol=0, atol=64 * EPS * max(1.0, np.abs(y).max()))
            sizes.append((np.abs(pG).max(), np.abs(pH).max()))
        assert np.min(np.max(sizes, axis=0)) > 1e-2  # (the comparison is of numbers, not zeros)


def test_the_curvature_is_the_gradients_derivative():
    """w Hess c from the core against central differences of the constraint's gradient (step h = 1e-6: truncation
    O(h^2) ~ 1e-12 and the gradient's rounding eps |G| / h ~ 1e-10 of max(1, |H|); bar 1e-8, a hundredfold), so the
    core's curvature is right, not only Python's twin."""
    robot = load_robot("panda", task="position")
    rng = np.random.default_rng(4)
    h = 1e-6
    for c in constraints(robot):
        check = c.row_guard(ROW_TOL)
        for _ in range(5):
            q = rng.uniform(robot.lower, robot.upper)
            H = check.compiled.curvature(q, 1.0)
            D = np.array([(c.gradients(q + h * e) - c.gradients(q - h * e))[0] / (2 * h) for e in np.eye(len(q))])
            np.testing.assert_allclose(H, 0.5 * (D + D.T), rtol=0, atol=1e-8 * max(1.0, np.abs(H).max()))


def test_the_check_is_the_searchs_test():
    """FrameRows.clear on random steps is True exactly where the stepper's search has nothing to look at: the row at
    the end >= -ROW_TOL and its segment_lower_bounds >= -ROW_TOL (both cases drawn: steps near and far from the
    sphere); a second check from the first's end, with the value kept there, gives a fresh check's verdict."""
    robot = load_robot("panda", task="position")
    rng = np.random.default_rng(5)
    probe = SphereClearance(robot, "panda_link4", np.zeros(3), 1.0)
    points = np.array([probe.point(q) for q in rng.uniform(robot.lower, robot.upper, (50, 7))])
    centre = points.mean(axis=0)  # a sphere that holds about half the frame's points inside
    c = SphereClearance(robot, "panda_link4", centre, float(np.median(np.linalg.norm(points - centre, axis=1))))
    check = c.row_guard(ROW_TOL)
    verdicts = []
    for _ in range(300):
        q0 = rng.uniform(robot.lower, robot.upper)
        q1 = q0 + rng.normal(0.0, 0.02, len(q0))
        v0, v1 = rng.normal(0.0, 0.5, (2, len(q0)))
        h = 0.02
        c0, c1 = c.values(q0), c.values(q1)
        bound = c.segment_lower_bounds(q0, q1, c0, c1, segment_move(q0, q1, v0, v1, h))
        expected = bool(c1[0] >= -ROW_TOL and bound[0] >= -ROW_TOL)
        got = check.clear(q0, q1, v0, v1, h)
        assert got == expected and check.compiled.smallest == pytest.approx(c1[0], abs=64 * EPS)
        q2 = q1 + (q1 - q0)
        assert check.clear(q1, q2, v1, v0, h) == c.row_guard(ROW_TOL).clear(q1, q2, v1, v0, h)
        verdicts.append(got)
    assert 30 < sum(verdicts) < 270
    assert not check.clear(q0, q1, v0, v1, -1.0) and np.isnan(check.compiled.smallest)  # a bad step length


def test_a_joint_beyond_its_extent_is_never_cleared():
    """A prismatic joint's reach holds within its limits' extent only: beyond it the check clears no step, as
    segment_lower_bounds gives the search no bound."""
    robot = load_robot("panda", task="position")
    rows = SphereClearance(robot, "panda_link4", [2.0, 0.0, 0.0], 0.1).row_guard(ROW_TOL).compiled
    import kinredund._core as core

    model = robot.model
    fid = model.getFrameId("panda_link4")
    boxed = core.FrameRows(model, fid, 0, np.array([2.0, 0.0, 0.0]), np.zeros(3), 0.1, 0.0, np.ones(7),
                           np.full(7, 4.0), 1e-9)
    q = np.zeros(7)
    assert rows.clear(q, q, q, q, 0.01) and boxed.clear(q, q, q, q, 0.01)
    q[3] = -5.0
    assert not boxed.clear(q, q, np.zeros(7), np.zeros(7), 0.01)


class Padded(SphereClearance):
    """A user's sphere held 1 cm further out by its own value (a subclass: FrameRows would compute the base's)."""

    def _value(self, p):
        return super()._value(p) - 0.01


def test_a_subclass_gets_no_compiled_row():
    """A subclass of SphereClearance has no compiled check (its values may not be FrameRows'), as a SceneClearance
    subclass has none, so the compiled backend searches and holds its row in Python: the record is the Python run's
    (with the base's row in the core the compiled run stopped at t = 3.14 s, more than 8 switches in one step)."""
    circle, frame, center, radius = CASES["panda_elbow_sphere"]
    r, path, index, q0 = case(circle)
    c = Padded(r, frame, center, radius)
    assert c.row_guard(ROW_TOL) is None
    a, b = both(r, path, index, q0, loops=1, constraints=[c])
    assert len(a.meta["switches"]) >= 4
    assert_same_record(a, b)


@pytest.mark.parametrize(("kind", "bad", "says"), [
    (2, {}, "kind must be"), (0, {"radius": 0.0}, "radius"), (0, {"reach": -np.ones(7)}, "reach"),
    (0, {"point": np.array([np.nan, 0.0, 0.0])}, "point and normal"), (1, {"clearance": -1.0}, "clearance"),
    (0, {"tol": np.inf}, "tol"), (1, {"normal": np.array([0.0, 0.0, 2.0])}, "unit vector")])
def test_bad_arguments_are_refused(kind, bad, says):
    """The core's own checks (the constraints validate their input first: OptionError; these guard the core)."""
    robot = load_robot("panda", task="position")
    import kinredund._core as core

    args = {"point": np.zeros(3), "normal": np.array([0.0, 0.0, 1.0]), "radius": 0.1, "clearance": 0.0,
            "reach": np.ones(7), "extent": np.full(7, np.inf), "tol": 1e-9} | bad
    with pytest.raises(ValueError, match=says):
        core.FrameRows(robot.model, robot.model.getFrameId("panda_link4"), kind, **args)


def sphere_tracker(name, backend, **kw):
    circle, frame, center, radius = CASES[name]
    r, path, index, q0 = case(circle)
    return Tracker(r, path, index, q0, path.period / 200, backend=backend,
                   constraints=[SphereClearance(r, frame, center, radius)], **kw)


@pytest.mark.parametrize(("name", "options"), [("panda_elbow_sphere", {}),
                                               ("panda_elbow_sphere", {"scheme": "velocity"}),
                                               ("panda_elbow_sphere", {"strict": False}), ("xarm7_elbow_sphere", {})])
def test_steps_with_a_sphere_held_are_the_cores_and_agree_one_by_one(name, options):
    """Five loops stepped in turn (agree_in_turn: the joints to Q_BAR and the multipliers, the row's too, to rounding
    at every step, the row held and the switches the same); the core took most steps with the row held (none handed
    back for it as row_active), the switching-time search's corrector solves with it and the Newton solve after each
    switch (CoreCorrector.settle: a frame's rows settle, RowCheck.settles); each switching time located in the core
    (CoreCorrector.locate), and the compiled check of the stepper's own searches ruled the row out where it could
    (GeneralRows.step_check). The check leaves the held row out (the
    only row: it clears every step with it held), so no core step with the row held is searched in Python."""
    a, b = sphere_tracker(name, "python", **options), sphere_tracker(name, "compiled", **options)
    c = b.compiled
    assert c.held is not None
    searched = []  # the core's steps the Python search looked at: did they start with the row held?
    search = c._switch_within
    c._switch_within = lambda start: searched.append(bool(start.rows)) or search(start)
    cleared, check = [], b.stepper._rows_cleared  # the stepper's own searches: did the compiled check rule rows out?
    b.stepper._rows_cleared = lambda snap: cleared.append(check(snap)) or cleared[-1]
    agree_in_turn(a, b, 1000)
    assert b.stepper.step_check is c.guard and sum(cleared) >= len(b.stepper.switches)  # (and agreeing, above)
    sa, sb = a.stepper, b.stepper
    assert len(sa.switches) >= 8 and "row_active" not in c.handed_back and not any(searched)
    assert c.row_steps > 100 and c.steps + sum(c.handed_back.values()) == 1000
    assert sb.corrector.row_solves >= 8 and sb.corrector.settled >= len(sb.switches)  # (the Newton after each switch)
    # the switching times located in the core (CoreCorrector.locate: Brent's method in C++), none left to Python
    assert sb.corrector.located >= len(sb.switches) and sb.corrector.locates_declined == 0


def elbow_plane(frac: float):
    """(robot, path, index, q0, plane): the Panda's elbow circle and a plane tilted 0.1 from level that the elbow's
    origin, free, passes below for part of the loop (``frac``: the plane's height between the lowest and highest
    elbow of the free loop)."""
    circle, frame, _, _ = CASES["panda_elbow_sphere"]
    r, path, index, q0 = case(circle)
    probe = PlaneClearance(r, frame, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    free = Tracker(r, path, index, q0, path.period / 200, backend="python")
    heights = []
    for _ in range(200):
        free.step()
        heights.append(probe.values(free.q)[0])
    z = min(heights) + frac * (max(heights) - min(heights))
    return r, path, index, q0, PlaneClearance(r, frame, [0.0, 0.0, z], [0.1, 0.0, 1.0])


def test_a_plane_held_is_the_python_run():
    """The elbow kept above the plane at mid height: held and left on both backends, the same record."""
    r, path, index, q0, plane = elbow_plane(0.5)
    a, b = both(r, path, index, q0, loops=2, constraints=[plane])
    assert len(a.meta["switches"]) >= 4 and any(a.meta["constraints"]["active"])
    assert_same_record(a, b)
    assert_same_rows(a, b)


def test_two_constraints_held_together_are_the_cores():
    """The elbow sphere and a plane lower down (both on panda_link4): their checks are one (RowStack, the rows
    numbered as the stepper numbers them), and both rows are held at once for part of each loop, the plane's row
    reached first (rows (1, 0): the stack maps them back to their parts). Stepped in turn the backends agree at every
    step (agree_in_turn), the core taking the steps with both rows held; tracked, the records are the same."""
    r, path, index, q0, plane = elbow_plane(0.3)
    circle, frame, center, radius = CASES["panda_elbow_sphere"]
    both_rows = [SphereClearance(r, frame, center, radius), plane]
    a, b = (Tracker(r, path, index, q0, path.period / 200, backend=x, constraints=both_rows)
            for x in ("python", "compiled"))
    assert type(b.compiled.guard.compiled).__name__ == "RowStack" and b.compiled.held is not None
    agree_in_turn(a, b, 400)
    c = b.compiled
    assert "row_active" not in c.handed_back and c.row_steps > 150
    ta, tb = both(r, path, index, q0, loops=2, constraints=both_rows)
    assert sum(len(x) == 2 for x in ta.meta["constraints"]["active"]) > 100
    assert_same_record(ta, tb)
    assert_same_rows(ta, tb)


def test_a_scene_and_a_sphere_are_one_check_held_in_the_core():
    """test_tracking_scene's elbow ball (a scene's distance rows) and the elbow sphere (a frame's row) on one tracker:
    one check of both (RowStack of a RowGuard and a FrameRows), each one's rows held in the core in turn, the two
    backends agreeing at every step."""
    r, path, index, q0, sc = scene_setup("panda_elbow_ball")
    circle, frame, center, radius = CASES["panda_elbow_sphere"]
    options = {"scene": sc, "clearance": SCENE_CLEARANCE, "self_clearance": False,
               "constraints": [SphereClearance(r, frame, center, radius)]}
    a, b = (Tracker(r, path, index, q0, path.period / 200, backend=x, **options) for x in ("python", "compiled"))
    assert type(b.compiled.guard.compiled).__name__ == "RowStack"
    agree_in_turn(a, b, 400)
    assert len(a.stepper.switches) >= 8 and "row_active" not in b.compiled.handed_back and b.compiled.row_steps > 100


def test_a_held_step_with_odd_inertia_is_measured(monkeypatch):
    """A core's step with a row held skips the step control's watch_point only where the watch's gate passes it and
    R's inertia is even (odd_inertia on the core's factors: what watch_point's StepControl._indefinite would find).
    Where the inertia test says odd (forced here), every held step goes to watch_point, which measures it exactly;
    the run still agrees with the Python stepper's. Unforced, the test on the core's factors is the Python
    stepper's own at every held step."""
    from kinredund.tracking.step_control import odd_inertia

    a, b = sphere_tracker("panda_elbow_sphere", "python"), sphere_tracker("panda_elbow_sphere", "compiled")
    sa, sb = a.stepper, b.stepper
    checked = 0
    for _ in range(200):
        a.step()
        before = b.compiled.row_steps
        b.step()
        if b.compiled.row_steps > before:  # the core's step with the row held: its factors are the step's
            free = sb.n - int(np.count_nonzero(sb.fixed))
            assert odd_inertia(*b.compiled.held.factors(), free) == sa.control._indefinite()
            checked += 1
    assert checked > 50
    calls = []
    monkeypatch.setattr(compiled, "odd_inertia", lambda *args: True)
    forced = sphere_tracker("panda_elbow_sphere", "compiled")
    watch_point = forced.stepper.control.watch_point
    monkeypatch.setattr(forced.stepper.control, "watch_point", lambda *x: calls.append(1) or watch_point(*x))
    held = 0
    for _ in range(200):
        before = forced.compiled.row_steps
        forced.step()
        held += forced.compiled.row_steps - before
    assert held > 50 and len(calls) >= held
    np.testing.assert_allclose(forced.q, b.q, rtol=0, atol=1e-12)


def test_a_sphere_moved_after_the_tracker_was_made_is_read_afresh():
    """The core's row is a copy of the constraint's numbers: where the sphere is moved during a run (its centre
    array changed in place, or replaced), the check is no longer valid, so every step is searched and every held
    step taken by the Python stepper, which reads the constraint afresh: the two backends still agree step by step,
    the sphere's new place counted from the step after the move."""
    trackers = []
    for backend in ("python", "compiled"):
        circle, frame, center, radius = CASES["panda_elbow_sphere"]
        r, path, index, q0 = case(circle)
        sphere = SphereClearance(r, frame, center, radius)
        trackers.append((Tracker(r, path, index, q0, path.period / 200, backend=backend, constraints=[sphere]),
                         sphere))
    (a, ca), (b, cb) = trackers
    assert b.compiled.guard.valid()
    for k in range(300):
        if k == 60:  # in place on one, replaced on the other: both the same move of 1 cm
            ca.center[2] += 0.01
            cb.center = cb.center + np.array([0.0, 0.0, 0.01])
            assert not b.compiled.guard.valid() and not b.compiled.held.valid()
        a.step()
        b.step()
        assert b.stepper.rows == a.stepper.rows
        np.testing.assert_allclose(b.q, a.q, rtol=0, atol=1e-12)
    assert b.compiled.handed_back.get("row_active", 0) > 10  # (the held steps after the move: Python's)


#: a 6 cm sphere where the wrist (the origin of panda_link6) passes 1.5 cm inside it on test_tracking_limits's
#: panda_pose_circle (a pose task): held and left twice a loop
POSE_SPHERE = ("panda_link6", [0.10200570290581948, 0.13126014523781432, 0.4633816348018318], 0.06)


@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
def test_a_sphere_held_on_a_pose_task_is_the_python_run(scheme):
    """The row under a pose task's six equations (m = 6 + 1 with the row held): the same record on both backends,
    and stepped in turn the same at every step, the core holding the row."""
    r, path, index, q0 = case("panda_pose_circle")
    c = SphereClearance(r, *POSE_SPHERE)
    a, b = both(r, path, index, q0, loops=2, constraints=[c], scheme=scheme)
    assert len(a.meta["switches"]) >= 4 and sum(map(len, a.meta["constraints"]["active"])) > 50
    assert_same_record(a, b)
    assert_same_rows(a, b)
    ta, tb = (Tracker(r, path, index, q0, path.period / 200, backend=x, constraints=[c], scheme=scheme)
              for x in ("python", "compiled"))
    agree_in_turn(ta, tb, 200)
    assert tb.compiled.row_steps > 20 and "row_active" not in tb.compiled.handed_back


def test_a_stack_leaves_each_held_row_out_of_its_own_part():
    """RowStack.clear with rows held (the stack's numbers) gives each part its own held rows: with the second of two
    spheres reached at the step's end (its row below -tol) and the first clear, the stack clears the step only
    where the second sphere's row is held, and a first sphere held leaves the second's reach in the test."""
    import kinredund._core as core

    robot = load_robot("panda", task="position")
    q = 0.5 * (robot.lower + robot.upper)
    p = SphereClearance(robot, "panda_link4", np.zeros(3), 1.0).point(q)
    far = SphereClearance(robot, "panda_link4", p + np.array([0.0, 0.0, 0.5]), 0.1)  # 0.4 m clear
    inside = SphereClearance(robot, "panda_link4", p + np.array([0.0, 0.0, 0.05]), 0.1)  # 5 cm inside
    stack = core.RowStack([far.row_guard(ROW_TOL).compiled, inside.row_guard(ROW_TOL).compiled])
    v = np.zeros(7)
    assert stack.size == 2
    assert not stack.clear(q, q, v, v, 0.01)
    assert stack.clear(q, q, v, v, 0.01, np.array([1]))
    assert not stack.clear(q, q, v, v, 0.01, np.array([0]))
    assert stack.smallest == pytest.approx(inside.values(q)[0], abs=64 * EPS)  # the least of both, held or not
    with pytest.raises(ValueError, match="rows of the source"):
        stack.clear(q, q, v, v, 0.01, np.array([2]))


@pytest.mark.parametrize("rows", ["sphere", "plane", "sphere+plane"])
def test_ten_loops_held_are_the_python_record_and_close(rows):
    """The issue's bar over ten loops: the elbow circle tracked ten times round with the sphere, the plane or both on
    panda_link4, held and left each loop, gives on the compiled backend the Python backend's record (every field,
    assert_same_record; the rows, switches and multipliers, assert_same_rows), and the run closes on both: the loop
    drift stays at rounding, ten loops of it (a periodic branch of minima followed, its switches in the same places
    each loop). The switches come in the same number each loop."""
    r, path, index, q0, plane = elbow_plane(0.3)
    circle, frame, center, radius = CASES["panda_elbow_sphere"]
    sphere = SphereClearance(r, frame, center, radius)
    held = {"sphere": [sphere], "plane": [plane], "sphere+plane": [sphere, plane]}[rows]
    a, b = both(r, path, index, q0, loops=10, constraints=held)
    switches = [w["t"] for w in a.meta["switches"]]
    per_loop = np.bincount((np.asarray(switches) // path.period).astype(int), minlength=10)
    assert per_loop.min() >= 2 and per_loop.min() == per_loop.max(), per_loop
    assert_same_record(a, b)
    assert_same_rows(a, b)
    for x in (a, b):
        assert len(x.loop_drift) == 10 and x.loop_drift.max() < 1e3 * EPS  # (rounding: at most 3.1e-15 rad seen)


def test_the_cores_system_at_a_switch_is_the_python_evaluations():
    """PredictorCorrector.system_at (the strict-minimum measurement after a switch, a bound multiplier's rate) on the
    compiled backend is the core's evaluation (CoreCorrector.system_at): J with the held row's gradient, M with its
    curvature and top equal the Python point's to rounding, at every step of a loop with the row held or free, with
    joints held or not; and where the core does not hold an active row it is Python's own (None)."""
    b = sphere_tracker("panda_elbow_sphere", "compiled")
    s, seen = b.stepper, set()
    for _ in range(200):
        b.step()
        made = s.corrector.system_at(s.q, s.t, s.lam)
        pt = s.evaluate(s.q, s.t)
        M, top = pt.system(s.lam)
        for got, want in zip(made, (pt.J, M, top), strict=True):
            assert got.shape == want.shape
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * max(1.0, np.abs(want).max()))
        seen.add((bool(s.rows), bool(s.fixed.any())))
    assert {r for r, _ in seen} == {True, False} and any(j for _, j in seen)  # (a row held, a joint held: each met)
    s.corrector._guard = None  # a core that does not hold the rows: it declines where one is active
    s.rows = (0,)
    assert s.corrector.system_at(s.q, s.t, np.append(s.task_lam, 0.0)) is None


@pytest.mark.parametrize("which", ["sphere", "scene"])
def test_what_the_rows_check_clears_the_search_finds_nothing_in(which):
    """GeneralRows._rows_cleared is sound: wherever the compiled check rules a row's switch out of a step the stepper
    searches itself, its own full search (the rows' reaches at the end, _row_dips inside) finds none there; over two
    loops with the row met and left (a sphere's rows, a scene's)."""
    if which == "sphere":
        b = sphere_tracker("panda_elbow_sphere", "compiled")
    else:
        r, path, index, q0, sc = scene_setup("panda_elbow_ball")
        b = Tracker(r, path, index, q0, path.period / 200, backend="compiled", scene=sc, clearance=SCENE_CLEARANCE,
                    self_clearance=False)
    s, found, check = b.stepper, [], b.stepper._rows_cleared

    def audited(snap):
        cleared = check(snap)
        if cleared:
            end = s.state
            found.append([e for e in s._events() if e[1] == "row_reach"] + s._row_dips(snap))
            s.state = end
        return cleared

    s._rows_cleared = audited
    for _ in range(400):
        b.step()
    assert len(found) >= len(s.switches) >= 4 and not any(found)


@pytest.mark.parametrize("name", ["panda_elbow_sphere", "xarm7_elbow_sphere"])
def test_the_cores_switching_times_checked_by_pinocchio_alone(name):
    """The switches located in the core (CoreCorrector.locate), checked without kinredund's constraint or record code:
    Pinocchio's own forward kinematics at each switch's joints puts the frame origin on the sphere where its row is
    reached (to 1e-12 m: the switching time is solved to 1e-14 s, the row moves at well under 1 m/s, and the
    corrected point carries the corrector's residual, ~1e-13 m), a reached bound's joint on its bound exactly (set
    there), and the tool point on the path at the switch's time (to 1e-11 m, the corrector's tolerance over the task's
    smallest singular value)."""
    import pinocchio as pin

    circle, frame, center, radius = CASES[name]
    b = sphere_tracker(name, "compiled")
    r, path = b.robot, b.path
    for _ in range(400):
        b.step()
    assert b.stepper.corrector.located >= len(b.stepper.switches) >= 4
    model = r.model
    data, fid, eid = model.createData(), model.getFrameId(frame), model.getFrameId(r.ee_frame)
    kinds = set()
    for s in b.stepper.switches:
        q = np.array(s["q"])
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        assert np.linalg.norm(data.oMf[eid].translation - path(s["t"]).p) <= 1e-11
        if s.get("constraint") and s["kind"] == "reach":
            assert abs(np.linalg.norm(data.oMf[fid].translation - np.asarray(center)) - radius) <= 1e-12
        elif not s.get("constraint") and s["kind"] == "reach":
            j = s["joint"]
            assert q[j] in (model.lowerPositionLimit[j], model.upperPositionLimit[j])
        kinds.add((bool(s.get("constraint")), s["kind"]))
    assert (True, "reach") in kinds
