"""The compiled backend with general inequality rows (issues 27, 28): the hybrid run equals the Python run.

With ``constraints=`` or ``scene=`` a step with no row active, and one with a scene's row active (the core holds it:
:mod:`kinredund.tracking.compiled_rows`), is taken by the compiled core and then checked by the Python stepper's own
search for a switch within it (``pending_switches``: a row reached at its end, a row dipping below zero inside it)
unless the scene's compiled check rules one out; a step with another constraint's row active, or one the search finds
a switch in, is the Python stepper's (:mod:`kinredund.tracking.compiled`). So the record, the row fields (smallest
distance, active rows, their multipliers, the switches and their times) and the stops are those of
``backend="python"``: the joints to the issue's 1e-12 rad at every point, the rest to test_tracking_compiled's bars
(the same optimum, evaluated by either backend). A scene's smallest distance is exact near the clearances and a lower
bound elsewhere, each backend's its own there (the compiled one the core's check's: ``RowGuard.smallest``), so there
both are only far
from the clearances (``assert_same_smallest``). The cases are the named ones of test_tracking_clearance and
test_tracking_scene.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_clearance_property import CLEARANCE as SCENE_CLEARANCE
from test_clearance_property import LOOPS, STEPS, task
from test_clearance_property import SELF_CLEARANCE as OWN
from test_tracking_clearance import CASES, STOP_CASES
from test_tracking_compiled import FIELD_BAR, Q_BAR, assert_same_record, assert_same_smallest, assert_same_stop, both
from test_tracking_limits import case
from test_tracking_scene import CLEARANCE
from test_tracking_scene import setup as scene_setup
from test_tracking_self_clearance import SELF_CLEARANCE
from test_tracking_self_clearance import setup as self_setup

from kinredund.errors import TrackingError
from kinredund.geometry import Scene
from kinredund.tracking import SphereClearance, Tracker, compiled, track

pytestmark = pytest.mark.skipif(compiled.load_core() is None, reason="the compiled core is not built")

#: switching times [s] of the two backends: each located by the Python stepper's Brent search (to 1e-14 s) from
#: states that agree to rounding
SWITCH_BAR = 1e-10


def sphere(name, shift=(0.0, 0.0, 0.0)):
    circle, frame, center, radius = CASES[name]
    r, path, index, q0 = case(circle)
    return r, path, index, q0, SphereClearance(r, frame, np.add(center, shift), radius)


def assert_same_rows(a, b) -> None:
    """The row fields of two records: the active rows and the switches (kinds, rows) exactly, the switching times
    to SWITCH_BAR, the multipliers to 1e-9 (assert_same_record has them relatively), the smallest values as
    assert_same_smallest says (to 1e-9 where exact)."""
    ra, rb = a.meta["constraints"], b.meta["constraints"]
    assert ra["active"] == rb["active"] and ra["names"] == rb["names"]
    assert_same_smallest(ra, rb)
    for x, y in zip(ra["multipliers"], rb["multipliers"], strict=True):
        np.testing.assert_allclose(y, x, rtol=0, atol=1e-9)
    sa, sb = a.meta["switches"], b.meta["switches"]
    assert [(w["kind"], w["name"]) for w in sa] == [(w["kind"], w["name"]) for w in sb]
    np.testing.assert_allclose([w["t"] for w in sb], [w["t"] for w in sa], rtol=0, atol=SWITCH_BAR)
    for x, y in zip(sa, sb, strict=True):
        np.testing.assert_allclose(y["q"], x["q"], rtol=0, atol=Q_BAR)


def stepped(r, path, index, q0, steps, **kw):
    """Two Trackers (python, compiled) stepped in turn ``steps`` times; the joints and rates compared at each step.
    Returns the compiled one."""
    dt = path.period / 200
    a = Tracker(r, path, index, q0, dt, backend="python", **kw)
    b = Tracker(r, path, index, q0, dt, backend="compiled", **kw)
    assert (a.backend, b.backend) == ("python", "compiled")
    for _ in range(steps):
        a.step()
        b.step()
        assert b.t == a.t and b.stepper.rows == a.stepper.rows
        np.testing.assert_allclose(b.q, a.q, rtol=0, atol=Q_BAR)
    assert len(b.stepper.switches) == len(a.stepper.switches)
    return b.compiled


@pytest.mark.parametrize("name", CASES)
def test_a_held_sphere_with_switches_is_the_python_run(name):
    r, path, index, q0, c = sphere(name)
    a, b = both(r, path, index, q0, loops=2, constraints=[c])
    assert len(a.meta["switches"]) >= 4 and any(a.meta["constraints"]["active"])  # met and left, each loop
    assert_same_record(a, b)
    assert_same_rows(a, b)


@pytest.mark.parametrize("options", [{"scheme": "velocity"}, {"strict": False}])
def test_the_velocity_form_and_the_plain_step_too(options):
    r, path, index, q0, c = sphere("panda_elbow_sphere")
    a, b = both(r, path, index, q0, loops=1, constraints=[c], **options)
    assert a.meta["switches"]
    assert_same_record(a, b)
    assert_same_rows(a, b)


def test_a_row_active_at_the_start():
    """test_tracking_clearance's elbow starting on a sphere it moves into (the row active from the start, so the
    stepper's lam holds its multiplier then): released and met again, the same on both backends."""
    r, path, index, q0, _ = sphere("panda_elbow_sphere")
    probe = SphereClearance(r, "panda_link4", [0.0, 0.0, 0.0], 1.0)
    free = track(r, path, index, q0, loops=1, steps_per_loop=100)
    p0, ahead = probe.point(q0), probe.point(free.q[1]) - probe.point(q0)
    c = SphereClearance(r, "panda_link4", p0 + 0.05 * ahead / np.linalg.norm(ahead), 0.05)
    a, b = both(r, path, index, q0, loops=2, steps_per_loop=100, constraints=[c])
    assert a.meta["constraints"]["active"][0] == [0] and len(a.meta["switches"]) >= 2
    assert_same_record(a, b)
    assert_same_rows(a, b)


def test_a_scene_ball_held_is_the_python_run():
    r, path, index, q0, sc = scene_setup("panda_elbow_ball")
    a, b = both(r, path, index, q0, loops=1, scene=sc, clearance=CLEARANCE, self_clearance=False)
    assert a.meta["switches"] and any(a.meta["constraints"]["active"])
    assert_same_record(a, b)
    assert_same_rows(a, b)


class Unchecked(SphereClearance):
    """A sphere's clearance without the compiled check (as a user's own constraint has none)."""

    def row_guard(self, tol):
        return None


def test_the_core_takes_the_steps_with_no_row_active():
    """Stepped one by one: every step agrees, and the core took all but the steps with the row active and those
    the search handed back (a row reached within them). A constraint with no compiled check (a user's, here the sphere
    without its row_guard) runs the hybrid routes: the steps with its row active are the Python stepper's."""
    r, path, index, q0, c = sphere("panda_elbow_sphere")
    cs = stepped(r, path, index, q0, 200, constraints=[Unchecked(r, c.frame, c.center, c.radius)])
    back = cs.handed_back
    assert back.get("row_active", 0) > 10 and back.get("rows", 0) >= 1  # both hybrid routes ran
    assert cs.steps > 100 and cs.steps > back["row_active"]  # most steps are the core's
    assert cs.steps + sum(back.values()) == 200


def test_a_far_sphere_leaves_every_step_to_the_core():
    """A sphere 2 m above the elbow's: no row is ever active or near, so no step is handed back for the rows, and
    the record is the Python run's (and that of the run without the sphere)."""
    r, path, index, q0, c = sphere("panda_elbow_sphere", shift=(0.0, 0.0, 2.0))
    cs = stepped(r, path, index, q0, 100, constraints=[c])
    assert "row_active" not in cs.handed_back and "rows" not in cs.handed_back and cs.steps >= 90
    a, b = both(r, path, index, q0, loops=1, constraints=[c])
    assert not any(b.meta["constraints"]["active"]) and not any(w.get("constraint") for w in b.meta["switches"])
    assert_same_record(a, b)
    assert_same_rows(a, b)
    free = track(r, path, index, q0, loops=1, backend="compiled")
    np.testing.assert_allclose(b.q, free.q, rtol=0, atol=Q_BAR)


def test_a_self_pair_held_is_the_python_run():
    """test_tracking_self_clearance's hand held off the upper arm (a self pair met and left twice a loop)."""
    r, path, index, q0, sc = self_setup()
    a, b = both(r, path, index, q0, loops=2, scene=sc, self_clearance=SELF_CLEARANCE)
    assert len(a.meta["switches"]) >= 4
    assert_same_record(a, b)
    assert_same_rows(a, b)


def test_a_self_pair_that_cannot_be_held_stops_the_same_way():
    """test_tracking_scene's fingers pressed on the upper arm until a pair's distance is not differentiable."""
    r, path, index, q0, _ = scene_setup()
    assert_same_stop("collision", r, path, index, q0, scene=Scene(r))


def test_the_corner_of_a_self_pair_is_named_whatever_the_rounding(monkeypatch):
    """The stop's corner note (constraints.scene._corner_note -> polytopes.vertex_corner) names the same two vertices
    from configurations a few ulps from the stop's (coal's witness points, anywhere along the parallel edge there,
    named none in 3 of these 10 draws before the vertices' own distances decided)."""
    import kinredund.tracking.constraints.scene as constraint_scene
    from kinredund.geometry.polytopes import vertex_corner

    seen, note = [], constraint_scene._corner_note
    monkeypatch.setattr(constraint_scene, "_corner_note",
                        lambda one, pair, a, b: seen.append((one, a.copy(), b.copy())) or note(one, pair, a, b))
    r, path, index, q0, _ = scene_setup()
    with pytest.raises(TrackingError, match="vertices 5 and 7"):
        track(r, path, index, q0, scene=Scene(r), backend="python")
    one, a, b = seen[-1]
    step = 1e-6 * (b - a) / np.abs(b - a).max()
    rng = np.random.default_rng(1)
    for _ in range(10):
        ulps = rng.integers(-4, 5, size=(2, len(a))) * np.spacing(np.abs(a) + 1.0)
        assert vertex_corner(one, 0, a - step + ulps[0], b + step + ulps[1]) == (1, 5, 7)


@pytest.mark.parametrize("name", STOP_CASES)
def test_a_sphere_that_cannot_be_held_stops_the_same_way(name):
    circle, frame, center, radius, steps = STOP_CASES[name]
    r, path, index, q0 = case(circle)
    c = SphereClearance(r, frame, center, radius)
    assert_same_stop("collision", r, path, index, q0, loops=1, steps_per_loop=steps, constraints=[c])


def test_the_python_backend_runs_every_step_in_python(monkeypatch):
    monkeypatch.setenv("KINREDUND_BACKEND", "python")
    r, path, index, q0, c = sphere("panda_elbow_sphere")
    tr = Tracker(r, path, index, q0, path.period / 200, constraints=[c])
    assert tr.backend == "python" and getattr(tr, "compiled", None) is None
    assert tr.step == tr.stepper.step  # the Python stepper's own step
    monkeypatch.delenv("KINREDUND_BACKEND")
    assert Tracker(r, path, index, q0, path.period / 200, constraints=[c]).backend == "compiled"


@pytest.mark.parametrize(("name", "seed"), [("panda", 1), ("xarm7", 0), ("panda", 0), ("xarm7", 2)])
def test_random_circles_among_random_objects_are_the_python_runs(name, seed):
    """Draws of test_clearance_property (random reachable circles, one or two objects where the optimum passes,
    the self pairs too): held with switches (panda 1, xarm7 0) or stopped (panda 0, xarm7 2), the same either way."""
    r, path, index, q0, sc = task(name, seed)
    options = {"loops": LOOPS, "steps_per_loop": STEPS, "scene": sc, "clearance": SCENE_CLEARANCE,
               "self_clearance": OWN}
    try:
        a = track(r, path, index, q0, backend="python", **options)
    except TrackingError as err:
        assert_same_stop(err.cause, r, path, index, q0, **options)  # the partial records with their row fields
        return
    b = track(r, path, index, q0, backend="compiled", **options)
    assert a.meta["switches"]
    assert_same_record(a, b)
    assert_same_rows(a, b)



# -- a scene's rows held in the core (kinredund.tracking.compiled_rows) -----------------------------------------------

def scene_tracker(backend, scheme="augmented", **kw):
    """A Tracker on test_tracking_scene's elbow ball (its row met and left twice a loop), 200 steps a loop."""
    r, path, index, q0, sc = scene_setup("panda_elbow_ball")
    return Tracker(r, path, index, q0, path.period / 200, backend=backend, scheme=scheme, scene=sc,
                   clearance=CLEARANCE, self_clearance=False, **kw)


#: a ball beside the Panda's elbow on test_tracking_limits's pose circle (centre [m], radius [m]): its pair with the
#: elbow's links is within the influence along part of the loop
POSE_BALL = ([-0.3948, -0.2149, 0.4086], 0.05)


@pytest.mark.parametrize("task_kind", ["position", "pose"])
@pytest.mark.parametrize("form", ["augmented", "velocity"])
def test_the_core_evaluates_the_extended_system_of_a_held_row(task_kind, form):
    """StepCore.set_rows: r, J, xdot, grad, M (with the row's curvature sum w Hess c by central differences) and top
    against RowPoint's at points near the ball (the row nearest there held), for random multipliers. Both sides
    compute the same distance rows at the same q (the scene's query, in C++ either way), so the bar is the task's
    terms' (test_the_core_evaluates_the_python_terms)."""
    from kinredund.tracking.constraints.base import DIFFERENCE_STEP
    from kinredund.tracking.rows import row_point

    if task_kind == "position":
        tr = scene_tracker("compiled", scheme=form)
    else:
        r, path, index, q0 = case("panda_pose_circle")
        sc = Scene(r)
        sc.add_sphere("ball", POSE_BALL[1], POSE_BALL[0])
        tr = Tracker(r, path, index, q0, path.period / 200, backend="compiled", scheme=form, scene=sc,
                     clearance=CLEARANCE, self_clearance=False)
    s = tr.stepper
    c = s.general[0]
    for _ in range(100):  # to where the ball is within 2 cm of its clearance (or a row active)
        if s.rows or c.rows_at(s.q)[0].min() < 0.02:
            break
        tr.step()
    values, G = c.rows_at(s.q)  # (exact: values() may be lower bounds away from the clearances)
    row = int(np.argmin(values))
    assert values[row] < 0.02 and np.abs(G[row]).max() > 0.01  # its pair within the influence
    core = tr.compiled.core
    assert tr.compiled.held is not None
    core.set_rows(np.array([row], dtype=np.int64), DIFFERENCE_STEP)
    assert core.held_rows == 1 and core.m == len(s.task_lam) + 1
    rng = np.random.default_rng(2)
    eps = np.finfo(float).eps
    for _ in range(3):
        q = s.q + rng.normal(0.0, 1e-3, s.n)
        lam = rng.normal(0.0, 1.0, core.m)
        sample = s.ev.sample(s.t)
        Q, omega = (np.zeros((0, 0)), np.zeros(3)) if sample.Q is None else (sample.Q, sample.omega)
        got = core.evaluate(q, lam, sample.p, sample.v, Q, omega, np.zeros(0), np.zeros(0))
        pt = row_point(s.ev.point(q, s.t), s.general, [(0, row)])
        M, top = pt.system(lam)
        assert pt.J.shape == (core.m, s.n) and got[1].shape == pt.J.shape and np.abs(pt.J[-1]).max() > 0.01
        for x, y in zip(got, (pt.r, pt.J, pt.xdot, pt.grad, M, top), strict=True):
            # one chain of ~100 operations on numbers of size |y| (kind 1 of the tolerance policy)
            np.testing.assert_allclose(x, y, rtol=0, atol=64 * eps * max(1.0, np.abs(y).max()))


def agree_in_turn(a, b, steps: int) -> None:
    """Trackers a (python) and b (compiled) stepped in turn ``steps`` times: the joints to Q_BAR and the multipliers
    (the rows' too) to rounding at every step, the rows held the same, and at a step with a row held the record's
    fields; the switching times to SWITCH_BAR at the end."""
    sa, sb = a.stepper, b.stepper
    for _ in range(steps):
        a.step()
        b.step()
        assert b.t == a.t and sb.rows == sa.rows
        np.testing.assert_allclose(b.q, a.q, rtol=0, atol=Q_BAR)
        # lambda and w: the task's and the row's multipliers [N-ish], solved from the same system (1e-12 relative)
        np.testing.assert_allclose(sb.lam, sa.lam, rtol=0, atol=1e-12 * max(1.0, np.abs(sa.lam).max()))
        if sa.rows:  # the record's fields of a step with the row held: the label (discrete), the bound multipliers,
            assert sb.label == sa.label  # R's condition (FIELD_BAR: the same optimum), the smallest row value (exact
            np.testing.assert_allclose(sb.mu, sa.mu, rtol=0, atol=FIELD_BAR)  # near the clearance either way)
            assert sb.rcond == pytest.approx(sa.rcond, rel=FIELD_BAR)
            assert sb.row_record()[0] == pytest.approx(sa.row_record()[0], abs=Q_BAR)
    assert [w["t"] for w in sb.switches] == pytest.approx([w["t"] for w in sa.switches], abs=SWITCH_BAR)


@pytest.mark.parametrize("options", [{}, {"scheme": "velocity"}, {"strict": False}])
def test_steps_with_a_scene_row_held_are_the_cores_and_agree_one_by_one(options):
    """Ten loops stepped in turn: the joints to Q_BAR and the multipliers (the row's too) to rounding at every step,
    the rows held and the switches the same; the core took every step with the row held but those its own tests
    hand back (a held row's multiplier turning negative: row_release) and those around the switches, and the
    corrector solves of those with the row held too, and the switching-time searches themselves
    (CoreCorrector.locate)."""
    a, b = scene_tracker("python", **options), scene_tracker("compiled", **options)
    agree_in_turn(a, b, 2000)
    c = b.compiled
    back = c.handed_back
    assert len(a.stepper.switches) >= 20 and "row_active" not in back and back.get("row_release", 0) >= 5
    assert c.row_steps > 300 and c.steps + sum(back.values()) == 2000
    cc = b.stepper.corrector
    assert cc.row_solves >= 20 and cc.settled == 0  # (the Newton after a switch with a scene's rows: Python's)
    assert cc.located >= len(b.stepper.switches) and cc.locates_declined == 0  # (the switching times: the core's)


def test_a_held_row_stays_pythons_where_the_core_cannot_make_its_step():
    """The witness curvature is not the core's: its steps with a row held are handed back (reason row_active), and
    stepped in turn they are the Python backend's."""
    from kinredund.tracking import SceneClearance

    r, path, index, q0, sc = scene_setup("panda_elbow_ball")
    witness = {"constraints": [SceneClearance(sc, clearance=CLEARANCE, self_clearance=None, curvature="witness")]}
    a, b = (Tracker(r, path, index, q0, path.period / 200, backend=x, **witness) for x in ("python", "compiled"))
    assert b.compiled.held is None
    held = 0
    for _ in range(120):
        held += bool(b.stepper.rows)
        a.step()
        b.step()
        np.testing.assert_allclose(b.q, a.q, rtol=0, atol=Q_BAR)
    assert held >= 5 and b.compiled.handed_back["row_active"] == held and b.compiled.row_steps == 0


def test_a_run_of_steps_refuses_rows_held_without_their_check():
    """A run of steps (src/core/loop.cpp) with rows held checks each step for the other rows' switches with the rows'
    check (the held ones left out): without the check (guard None) the core refuses to run, before it reads any other
    argument."""
    import kinredund._core as core_module

    from kinredund.tracking.constraints.base import DIFFERENCE_STEP

    tr = scene_tracker("compiled")
    core = tr.compiled.core
    core.set_rows(np.array([0], dtype=np.int64), DIFFERENCE_STEP)
    empty, mat = np.zeros(0), np.zeros((0, 3))
    with pytest.raises(ValueError, match="a run with rows needs guard"):
        core_module.run_steps(core, empty, mat, mat, np.zeros((0, 9)), mat, np.zeros((0, 7)), np.zeros((0, 7)),
                              empty, empty, [], empty, 0.0, False, (False,), np.zeros((0, 1)), None)
    core.set_rows(np.zeros(0, dtype=np.int64), DIFFERENCE_STEP)
    assert core.held_rows == 0
