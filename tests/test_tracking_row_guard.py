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
    for _ in range(60):
        q0, v0, t0 = tr.stepper.q, tr.stepper.qdot, tr.t
        tr.step()
        if v0 is None:
            continue
        step = (q0, tr.stepper.q, v0, tr.stepper.qdot, tr.t - t0)
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
