"""The compiled check of a step for a scene's row switch (``kinredund._core.RowGuard``, issue 27).

The compiled driver (:mod:`kinredund.tracking.compiled`) asks it before taking a core's step with no row active:
where it says the step is clear, the stepper's own search (``pending_switches``) is not run. So it must never
call a step clear that the stepper's test would look into: a row below -ROW_TOL at the step's end, or a row whose
lower bound along the step (``SceneClearance.segment_lower_bounds`` of the values at both ends) is below -ROW_TOL.
Checked here against that test computed in Python from exact distances (a fresh SceneClearance: no kept values), on
random steps near and far from the objects, in collision and across long moves (where it must hand back), and on a
run (its kept and lowered values are lower bounds of the exact ones, so it may hand back more, never less).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_tracking_compiled import Q_BAR

import kinredund as kr
from kinredund.errors import OptionError
from kinredund.problems import panda_circle
from kinredund.tracking import SceneClearance, Tracker, compiled
from kinredund.tracking.rows import ROW_TOL
from kinredund.tracking.switches import segment_move

pytestmark = pytest.mark.skipif(compiled.load_core() is None, reason="the compiled core is not built")

#: a step of the test's random draws is left out of the exact comparison where the exact test's least margin is
#: within this of its threshold [m]: the two computations (numpy, Eigen) round differently (kind 1, the bounds'
#: products summing ~10 terms of ~1 m)
EDGE = 1e-12


def panda_scene():
    r = panda_circle()[0]
    sc = kr.Scene(r)
    sc.add_box("table", [0.8, 0.8, 0.04], [0.45, 0.0, -0.05])
    sc.add_sphere("ball", 0.08, [0.45, 0.1, 0.45])
    sc.add_box("post", [0.06, 0.06, 0.8], [0.6, -0.3, 0.4])
    return r, sc


def exact_test(sc, q0, q1, v0, v1, h) -> tuple[bool, float]:
    """(the step is clear by the stepper's test on exact values, its least margin above -ROW_TOL [m])."""
    c = SceneClearance(sc)
    c0, c1 = SceneClearance(sc).values(q0), SceneClearance(sc).values(q1)
    move = segment_move(q0, q1, v0, v1, h)  # the stepper's own (_row_dips)
    margin = min(c1.min(), c.segment_lower_bounds(q0, q1, c0, c1, move).min()) + ROW_TOL
    return margin >= 0.0, margin


def run_steps(tr, count: int):
    """The steps (q0, q1, v0, v1, h) of ``count`` steps of ``tr`` (the first left out: no rate at its start)."""
    for _ in range(count):
        q0, v0, t0 = tr.stepper.q, tr.stepper.qdot, tr.t
        tr.step()
        if v0 is not None:
            yield q0, tr.stepper.q, v0, tr.stepper.qdot, tr.t - t0


def random_step(r, rng):
    q0 = r.lower + (r.upper - r.lower) * rng.uniform(0.1, 0.9, r.nq)
    scale = 10.0 ** rng.uniform(-4, -0.5)
    q1 = q0 + scale * rng.standard_normal(r.nq)
    v0, v1 = rng.standard_normal(r.nq), rng.standard_normal(r.nq)
    return q0, q1, v0, v1, 10.0 ** rng.uniform(-4, -1.5)


def test_the_guard_is_the_stepper_test_on_random_steps():
    """A fresh guard (exact values at both ends) says clear exactly where the stepper's test on exact values does."""
    r, sc = panda_scene()
    rng = np.random.default_rng(7)
    counts = {True: 0, False: 0}
    for _ in range(300):
        step = random_step(r, rng)
        want, margin = exact_test(sc, *step)
        got = SceneClearance(sc).row_guard(ROW_TOL).clear(*step)
        if abs(margin) > EDGE:
            assert got == want, (margin, step)
            counts[want] += 1
    assert counts[True] > 30 and counts[False] > 30  # both answers drawn: clear steps, and ones it must hand back


def test_a_step_into_an_object_or_past_it_is_handed_back():
    """The end inside the ball: reached. Both ends clear of it but the step's bound through it: a possible dip."""
    r, sc = panda_scene()
    c = SceneClearance(sc)
    guard = c.row_guard(ROW_TOL)
    rng = np.random.default_rng(2)
    inside = None
    while inside is None:
        q = r.lower + (r.upper - r.lower) * rng.uniform(0.1, 0.9, r.nq)
        inside = q if SceneClearance(sc).values(q).min() < -0.01 else None
    zero = np.zeros(r.nq)
    assert not guard.clear(inside, inside, zero, zero, 0.01)
    far = r.home
    assert SceneClearance(sc).values(far).min() > 0.01
    assert guard.clear(far, far, zero, zero, 0.01)  # still: nothing moves
    fast = np.full(r.nq, 100.0)  # 1 rad per joint within the step: every row's bound drops far below zero
    assert not guard.clear(far, far, fast, fast, 0.01)
    assert not exact_test(sc, far, far, fast, fast, 0.01)[0]


def test_the_guard_along_a_run_never_calls_clear_what_the_exact_test_does_not():
    """One guard over the steps of a run (its kept, lowered values): clear only where the exact test is clear."""
    r, sc = panda_scene()
    _, path, index, q0 = panda_circle(r)
    tr = Tracker(r, path, index, q0, path.period / 200, scene=sc, backend="python")
    guard = tr.stepper.general[0].row_guard(ROW_TOL)
    cleared = 0
    for step in run_steps(tr, 60):
        if guard.clear(*step):
            cleared += 1
            assert exact_test(sc, *step)[0]
    assert cleared > 30


def test_the_compiled_run_takes_the_cleared_steps_without_the_search():
    """A far object: every step is cleared by the guard (the search not run), and the run is the
    Python run's."""
    robot, path, index, q0 = panda_circle()
    far = kr.Scene(robot)
    far.add_sphere("lamp", 0.05, [0.0, 0.0, 1.6])
    dt = path.period / 200
    a = Tracker(robot, path, index, q0, dt, scene=far, backend="python")
    b = Tracker(robot, path, index, q0, dt, scene=far, backend="compiled")
    calls = []
    search = b.stepper.pending_switches
    b.stepper.pending_switches = lambda snap: calls.append(snap) or search(snap)
    for _ in range(40):
        a.step()
        b.step()
        np.testing.assert_allclose(b.q, a.q, rtol=0, atol=Q_BAR)
    assert b.compiled.steps == 40 and not calls  # the start has its rates: every step cleared


def test_bad_guard_arguments_name_what_is_expected():
    r, sc = panda_scene()
    ws = sc.workspace(own=True)
    c = SceneClearance(sc)
    with pytest.raises(ValueError, match="row_of_pair"):
        ws.row_guard(np.zeros(3, int), c.clearances, c.influence, np.zeros((c.size, r.nq)), np.full(r.nq, np.inf),
                     ROW_TOL, 0.005)
    rows = np.where(np.arange(len(sc.pairs)) < c.size, np.arange(len(sc.pairs)), -1)
    twice = rows.copy()
    twice[1] = 0
    with pytest.raises(OptionError, match="row_of_pair names a row twice"):  # a row's value is one pair's
        ws.row_guard(twice, c.clearances, c.influence, np.zeros((c.size, r.nq)), np.full(r.nq, np.inf), ROW_TOL,
                     0.005)
    for what, bound, extent in (("bound", -np.ones((c.size, r.nq)), np.full(r.nq, np.inf)),
                                ("bound", np.full((c.size, r.nq), np.nan), np.full(r.nq, np.inf)),
                                ("extent", np.zeros((c.size, r.nq)), np.full(r.nq, np.nan))):
        with pytest.raises(OptionError, match=f"row guard's {what} must be >= 0"):  # never a looser test
            ws.row_guard(rows, c.clearances, c.influence, bound, extent, ROW_TOL, 0.005)
    with pytest.raises(ValueError, match="bound"):
        ws.row_guard(rows, c.clearances, c.influence, np.zeros((c.size, 3)), np.full(r.nq, np.inf), ROW_TOL, 0.005)
    with pytest.raises(ValueError, match="influence"):
        ws.row_guard(rows, c.clearances, 0.0, np.zeros((c.size, r.nq)), np.full(r.nq, np.inf), ROW_TOL, 0.005)
    class Mine(SceneClearance):  # a subclass's rows are its own: the scene's check is not for them
        pass

    assert Mine(sc).row_guard(ROW_TOL) is None
    guard = c.row_guard(ROW_TOL)
    with pytest.raises(ValueError, match="entries"):
        guard.clear(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), 0.01)
    nan = np.full(r.nq, np.nan)
    assert not guard.clear(nan, nan, nan, nan, 0.01)  # not finite: handed back, never a silent clear


@pytest.mark.parametrize("backend", ["python", "compiled"])
def test_a_scene_changed_during_a_run_is_refused_as_on_the_python_stepper(backend):
    """The guard checks the scene as it was made: after a change it clears no step, so the compiled run meets the
    stepper's error (SceneClearance: make a new one) at the next step, as the Python run does."""
    robot, path, index, q0 = panda_circle()
    far = kr.Scene(robot)
    far.add_sphere("lamp", 0.05, [0.0, 0.0, 1.6])
    tr = Tracker(robot, path, index, q0, path.period / 200, scene=far, backend=backend)
    for _ in range(3):
        tr.step()
    far.add_sphere("ball", 0.05, [0.0, 0.5, 1.6])
    with pytest.raises(OptionError, match="make a new one"):
        tr.step()


def _core_args(tr):
    """The arguments of the core's next step from ``tr``'s state, as the compiled driver passes them."""
    s, ctl = tr.stepper, tr.stepper.control
    t_to = s.t0 + (s.k + 1) * s.dt
    sample = s.ev.sample(t_to)
    empty = np.zeros(0)
    return t_to, (t_to, sample.p, sample.v, sample.Q, sample.omega, empty, empty, s.y, s.yd, s.prev, s.qdot,
                  ctl.speed2, True)


def test_the_core_step_with_its_guard_is_the_step_then_the_guard():
    """StepCore.step_guarded: the row of StepCore.step, bit for bit, and the verdict of RowGuard.clear on that step
    (from y[:n] with the rates qdot to the row's q and qdot) and its smallest value at the step's end
    (RowGuard.smallest), bit for bit: one piece of code called two ways. A fast start (a possible dip) and h < 0 (no
    check: no smallest value, NaN) are not cleared."""
    r, sc = panda_scene()
    _, path, index, q0 = panda_circle(r)
    tr = Tracker(r, path, index, q0, path.period / 200, scene=sc, backend="compiled")
    core, n = tr.compiled.core, r.nq
    N = len(tr.stepper.task_lam) + n
    verdicts = []
    for k in range(40):
        tr.step()
        if k % 4:
            continue
        s = tr.stepper
        t_to, args = _core_args(tr)
        h = t_to - s.t
        for qdot in (s.qdot, 30 * s.qdot):  # the second: the rows' bounds along the step lower
            args = (*args[:10], qdot, *args[11:])
            plain = core.step(*args)
            core.set_guard(SceneClearance(sc).row_guard(ROW_TOL).compiled)  # fresh guards: the same kept values
            if type(plain) is int:  # handed back (a jump): no row, no check
                assert core.step_guarded(h, *args) == plain
                continue
            out, cleared, smallest = core.step_guarded(h, *args)
            assert np.array_equal(out, plain)
            alone = SceneClearance(sc).row_guard(ROW_TOL).compiled
            assert cleared == alone.clear(s.y[:n], out[:n], qdot, out[N:N + n], h)
            assert smallest == alone.smallest  # the same values at the step's end, bit for bit
            verdicts.append(cleared)
            unchecked = core.step_guarded(-1.0, *args)
            assert unchecked[1] is False and np.isnan(unchecked[2])
    assert any(verdicts) and not all(verdicts)
    core.set_guard(None)  # none: nothing is cleared
    t_to, args = _core_args(tr)
    assert core.step_guarded(t_to - tr.stepper.t, *args)[1] is False
    with pytest.raises(TypeError, match="RowGuard"):
        core.set_guard(np.zeros(3))


def test_the_kept_rows_stand_in_for_queries_until_their_bounds_lapse():
    """After one check, a step of 1e-6 rad places nothing (every row kept: exact beyond the influence, or lowered far
    above skip) and gives the exact test's verdict; a long step places the objects again. Over a run near the ball
    the kept rows never clear a step the exact test does not, and they place the objects on few steps."""
    r, sc = panda_scene()
    c = SceneClearance(sc)
    q = r.home.copy()
    v = np.zeros(r.nq)
    guard = c.row_guard(ROW_TOL).compiled
    assert guard.clear(q, q, v, v, 0.01) == exact_test(sc, q, q, v, v, 0.01)[0]
    placed = guard.placements
    assert placed == 1  # the start: every row exact at q
    q1 = q + 1e-6
    assert guard.clear(q, q1, v, v, 0.01) == exact_test(sc, q, q1, v, v, 0.01)[0]
    assert guard.placements == placed
    q2 = q1 + 0.5
    assert guard.clear(q1, q2, v, v, 0.01) == exact_test(sc, q1, q2, v, v, 0.01)[0]
    assert guard.placements == placed + 1
    _, path, index, q0 = panda_circle(r)
    tr = Tracker(r, path, index, q0, path.period / 200, scene=sc, backend="python")
    guard = tr.stepper.general[0].row_guard(ROW_TOL).compiled
    steps = cleared = 0
    for step in run_steps(tr, 200):
        steps += 1
        if guard.clear(*step):
            cleared += 1
            assert exact_test(sc, *step)[0]
    assert cleared > steps // 2
    assert guard.placements < steps // 2  # most steps: the kept rows alone


def test_the_record_takes_the_checks_smallest_value_exact_near_the_clearance(monkeypatch):
    """track() on the compiled backend records a guarded step's smallest row value from the core's check of it
    (RowGuard.smallest, handed over with the step), with no query of its own. Against coal afresh at every recorded
    point (test_tracking_scene's ball, met and left by the elbow: the ball's least distance less the clearance), the
    record equals it (to 1e-12 m) wherever that is at or below SKIP_MARGIN, and is a lower bound above SKIP_MARGIN
    elsewhere (SceneClearance's docstring: "exact near the clearances and lower bounds elsewhere"). Single steps, to see
    each point's value come from the check (test_tracking_runs: the runs' record is the same bits)."""
    from test_tracking_scene import CLEARANCE, ball_distance
    from test_tracking_scene import setup as ball_setup

    from kinredund.tracking import run, runs
    from kinredund.tracking.constraints.scene import SKIP_MARGIN
    from kinredund.tracking.limited import LimitedPredictorCorrector

    monkeypatch.setattr(run, "stepping", runs.one_by_one)

    r, path, index, q0, sc = ball_setup("panda_elbow_ball")
    kept = []  # per recorded point: did its smallest value come from the check (no query)?
    record = LimitedPredictorCorrector.row_record

    def row_record(self):
        kept.append(self._smallest[0] is self.q)
        return record(self)

    monkeypatch.setattr(LimitedPredictorCorrector, "row_record", row_record)
    tr = kr.track(r, path, index, q0, loops=1, steps_per_loop=400, scene=sc, clearance=CLEARANCE,
                  self_clearance=False, backend="compiled")  # (400 steps: a few checked steps end near the ball)
    smallest = np.array(tr.meta["constraints"]["min_value"])
    exact = ball_distance(sc, tr.q) - CLEARANCE
    kept = np.array(kept)
    assert len(kept) == len(exact) and kept.sum() > len(kept) // 2  # most points: the check's value
    near = exact <= SKIP_MARGIN
    assert (near & kept).sum() >= 3 and (~near & kept).sum() >= 10  # both kinds from the check
    np.testing.assert_allclose(smallest[near], exact[near], rtol=0, atol=1e-12)
    assert np.all(smallest[~near] <= exact[~near] + 1e-12) and np.all(smallest[~near] > SKIP_MARGIN)
    assert np.any(smallest[~near] < exact[~near] - 1e-3)  # (lower bounds there, not exact values)
