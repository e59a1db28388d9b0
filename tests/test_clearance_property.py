"""Property (issue 27): random tasks with random objects; every run either holds the clearance and closes, or
stops with a named cause whose configuration is on the path, inside the limits and clear. Never a silent contact.

Tasks: random reachable circles of ``benchmarks/random_obstacles.py`` (:func:`reachable_circle`: a circle
through a random within-limits configuration's end point, 3-10 cm at 0.1 m/s, z = 1/2 ||q - q_home||^2, the
start the within-limits optimum, screened by that optimum completing a loop) on the Panda and the xArm7.
Objects, through the Scene API: one or two spheres and boxes (sides, radii 3-8 cm), each where the free
optimum passes: at a point of the trajectory of a robot object's origin (one of the arm's links, drawn), off it
normal to its velocity (the benchmark's :func:`beside`) so that its surface comes ``CLEARANCE - depth`` from
that point (depth 1-3 cm); an object under the clearance at q0 is drawn again. The robot's own pairs are
checked too (``self_clearance``). Run through the public API: ``track(..., scene=, clearance=,
self_clearance=)``.

Checked independently of the tracker's record: distances afresh from the Scene's own query
(``scene.distances``, every checked pair, no broadphase) at every recorded point and every switching time,
each pair against its own clearance; joints against the limits; the end point against the path afresh
(``robot.fk``); the closure from the recorded joints at the ends of the loops; every third recorded point with a
row active a strict minimum of the held problem (the joint-level IK with the rows, :data:`MINIMUM_TOL`). A stop is a
:class:`~kinredund.errors.TrackingError` whose cause is one an obstacle run can have (:data:`CAUSES`) and
whose last good point passes the same checks. A good share of the runs must have had a row active (else the
property says nothing about the rows): counted and bounded below.

Bars (the issue's): clearance - 1e-9 m (the corrector holds an active row to ~1e-12), 1e-10 rad closure and
1e-10 m on the path (the corrector's 1e-12 times |grad z|), the limits to 1e-10 rad (a joint on a bound is put
there exactly).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from conftest import load_benchmark, robot

import kinredund as kr
from kinredund.errors import TrackingError
from kinredund.ik.rows import solve_ik_rows

bench = load_benchmark("random_obstacles")

#: the obstacles' and the robot's own clearance [m] (the defaults of track(..., scene=))
CLEARANCE, SELF_CLEARANCE = 0.02, 0.01
#: the issue's bars: clearance [m], closure [rad], on the path [m], inside the limits [rad]
HOLD_TOL, CLOSURE_TOL, PATH_TOL, LIMIT_TOL = 1e-9, 1e-10, 1e-10, 1e-10
#: a recorded point with a row active is a strict minimum of the held problem: the joint-level IK with the rows
#: (its own check: first-order conditions, multipliers' signs, the reduced Hessian positive definite), started there,
#: converges within MINIMUM_TOL [rad] of it (both hold the conditions to ~1e-12; two such points lie that residual
#: over the reduced Hessian's least eigenvalue apart, so 1e-8 allows an eigenvalue down to ~1e-4, and a saddle or
#: another branch fails it by far: 0.15 rad for the saddle tests/test_tracking_stop_causes.py pins). Every
#: MINIMUM_EVERY-th such point is solved (a few ms each)
MINIMUM_TOL, MINIMUM_EVERY = 1e-8, 3
#: the causes a run among obstacles may stop with (not the input's: a step too long, a path that jumps or
#: contradicts itself, a start off the optimum)
CAUSES = ("collision", "limits_infeasible", "not_strongly_stable", "switch_not_resolved", "kinematic_singularity",
          "fold", "out_of_reach", "step_control_exhausted")
#: per robot: the links whose objects' origins the obstacles are put beside (the upper arm, the elbow and the
#: forearm: an object at the wrist or the hand is mostly one the path itself runs into)
LINKS = {"panda": ("panda_link3", "panda_link4", "panda_link5"), "xarm7": ("link3", "link4", "link5")}
OBJECT_RANGE = (0.03, 0.08)  # [m] a sphere's radius, a box's half side
OBJECT_DRAWS, TASK_DRAWS = 20, 10
STEPS, LOOPS = 100, 2  # steps per loop, loops


def _pose(u: np.ndarray, rng) -> np.ndarray:
    """A rotation whose first axis is u and the others drawn about it."""
    a = np.cross(u, rng.normal(size=3))
    a /= np.linalg.norm(a)
    return np.column_stack([u, a, np.cross(u, a)])


def _place(sc, name: str, origins: dict, q0, rng) -> bool:
    """Put object ``name`` (a sphere or a box) beside a drawn link's trajectory (module docstring); False if none
    of :data:`OBJECT_DRAWS` draws keeps q0 clear."""
    for _ in range(OBJECT_DRAWS):
        P = origins[list(origins)[int(rng.integers(len(origins)))]]
        k, u = bench.beside(P, rng)
        half, depth = float(rng.uniform(*OBJECT_RANGE)), float(rng.uniform(*bench.DEPTH_RANGE))
        at = P[k] + (half + CLEARANCE - depth) * u  # the surface CLEARANCE - depth from P[k], facing it
        if rng.random() < 0.5:
            sc.add_sphere(name, half, at)
        else:
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = _pose(u, rng), at
            sc.add_box(name, 2 * half * np.array([1.0, *rng.uniform(0.5, 1.5, 2)]), T)
        if margin(sc, q0) > 0.0:
            return True
        sc.remove(name)
    return False


@functools.cache
def task(name: str, seed: int):
    """(robot, path, index, q0, scene) of one draw: a reachable circle, one or two objects where its optimum passes."""
    r = robot(name, "position")
    rng = np.random.default_rng(seed)
    for _ in range(TASK_DRAWS):
        path, index, q0, free, _ = bench.reachable_circle(r, rng, STEPS)
        sc = kr.Scene(r)
        if margin(sc, q0) <= 0.0:  # the start under the self clearance: not a task
            continue
        objs = [o for o in sc.robot_objects if o.rsplit("_", 1)[0] in LINKS[name]]
        origins = {o: np.array([sc.object_pose(o, q)[:3, 3] for q in free.q]) for o in objs}
        placed = [_place(sc, f"obstacle{i}", origins, q0, rng) for i in range(int(rng.integers(1, 3)))]
        if any(placed):
            return r, path, index, q0, sc
    raise RuntimeError(f"no task with an object in {TASK_DRAWS} draws ({name}, seed {seed})")


def margin(sc, q) -> float:
    """min over every checked pair of (distance - its clearance) [m] at q, afresh from the Scene's own query."""
    rec = sc.distances(np.asarray(q, float))
    world = set(sc.objects)
    clear = np.array([CLEARANCE if world & set(p) else SELF_CLEARANCE for p in rec.pairs])
    return float(np.min(rec.distance - clear))


def _off_path(r, path, t, q) -> float:
    return float(np.linalg.norm(r.fk(np.asarray(q, float))[:3, 3] - path(float(t)).p))


def _outside(r, q) -> float:
    q = np.atleast_2d(q)
    return float(np.max(np.maximum(q - r.upper, r.lower - q)))


def _minima(r, path, index, sc, tr) -> None:
    """Every :data:`MINIMUM_EVERY`-th recorded point with a row active is a strict minimum of the held problem, by
    the joint-level IK with the rows, independent of the tracker (:data:`MINIMUM_TOL`)."""
    rows = [kr.SceneClearance(sc, CLEARANCE, SELF_CLEARANCE)]
    active = [k for k, a in enumerate(tr.meta["constraints"]["active"]) if a][::MINIMUM_EVERY]
    for k in active:
        res = solve_ik_rows(r, path(float(tr.t[k])).p, index, rows, tr.q[k], tol=1e-12)
        assert res.converged and np.linalg.norm(res.q - tr.q[k]) <= MINIMUM_TOL, (float(tr.t[k]), res.reason)


@functools.cache
def outcome(name: str, seed: int) -> tuple[str, bool]:
    """Run one draw and check it (module docstring): (``held`` or the stop's cause, had a row active)."""
    r, path, index, q0, sc = task(name, seed)
    try:
        tr = kr.track(r, path, index, q0, loops=LOOPS, steps_per_loop=STEPS, scene=sc, clearance=CLEARANCE,
                      self_clearance=SELF_CLEARANCE, diagnostics=False)
    except TrackingError as err:
        assert err.cause in CAUSES, (err.cause, str(err))
        if err.watched.get("constraints"):  # a stop with a pair involved is the clearance's, the pair named
            assert err.cause == "collision", str(err)
        assert err.q is not None and err.t is not None, str(err)
        assert margin(sc, err.q) >= -HOLD_TOL, str(err)  # clear
        assert _outside(r, err.q) <= LIMIT_TOL, str(err)  # inside the limits
        assert _off_path(r, path, err.t, err.q) <= PATH_TOL, str(err)  # on the path
        seen = err.partial is not None and any(err.partial.meta["constraints"]["active"])
        if seen:
            _minima(r, path, index, sc, err.partial)
        return err.cause, bool(seen or err.watched.get("constraints") or err.watched.get("active_rows"))
    assert min(margin(sc, q) for q in tr.q) >= -HOLD_TOL  # every recorded point
    assert all(margin(sc, w["q"]) >= -HOLD_TOL for w in tr.meta["switches"])  # every switching time (rows, bounds)
    assert _outside(r, tr.q) <= LIMIT_TOL
    assert max(_off_path(r, path, t, q) for t, q in zip(tr.t, tr.q, strict=True)) <= PATH_TOL
    ends = tr.q[::STEPS]  # t = 0, T, 2T: the joints close after each loop
    assert len(ends) == LOOPS + 1 and np.abs(ends[1:] - ends[0]).max() <= CLOSURE_TOL
    _minima(r, path, index, sc, tr)
    return "held", any(tr.meta["constraints"]["active"])


def check_property(runs: list[tuple[str, int]], min_active: float, min_held: float) -> dict:
    """Every run checked (:func:`outcome`); shares ``min_active`` of them with a row active and ``min_held``
    held and closed (a property met by stops alone would say nothing of holding). The tally of outcomes."""
    results = [outcome(name, seed) for name, seed in runs]
    tally: dict = {}
    for cause, _ in results:
        tally[cause] = tally.get(cause, 0) + 1
    assert sum(a for _, a in results) >= min_active * len(runs), results
    assert tally.get("held", 0) >= min_held * len(runs), tally
    return tally


FAST = [("panda", 0), ("panda", 1), ("xarm7", 0), ("xarm7", 1)]


@pytest.mark.parametrize(("name", "seed"), FAST)
def test_clearance_held_and_closed_or_a_named_clear_stop(name, seed):
    cause, _ = outcome(name, seed)
    assert cause == "held" or cause in CAUSES


def test_most_fast_draws_meet_a_clearance():
    check_property(FAST, 0.5, 0.25)


@pytest.mark.slow
def test_clearance_property_on_many_draws():
    runs = [(name, seed) for name in ("panda", "xarm7") for seed in range(2, 14)]
    check_property(runs, 0.5, 0.25)
