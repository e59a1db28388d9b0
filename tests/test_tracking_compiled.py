"""The compiled backend (issue 28): the same runs as the Python stepper, step by step and field by field.

The compiled core (``src/core/step.cpp``, driven by :mod:`kinredund.tracking.compiled`) does the default
mode's ordinary step; every other step (switches, rejected steps, the watch's measured steps, failures) is
the Python stepper's own, from the same state. Both backends compute the same quantities in a different
order, so they agree to rounding at each evaluation (checked directly below), and the corrector puts both
on the same optimum at every step: the joints agree to :data:`Q_BAR` (the issue's 1e-12 rad) over ten loops,
switches and stops happen at the same times with the same causes.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import warnings

import numpy as np
import pytest
from conftest import robot
from test_resolved_rate import time_varying_case as rr_time_varying_case
from test_tracking_limits import case as limits_case

import kinredund
from kinredund.errors import ChoiceError, OptionError, TrackingError
from kinredund.indices import CustomIndex, JointDeviation, mid_range, minimum_norm
from kinredund.paths import Circle, FunctionPath
from kinredund.problems import panda_circle
from kinredund.tasks import make_target
from kinredund.tasks.axis import frame_with_axis
from kinredund.thesis.chapter4 import load_example
from kinredund.tracking import Tracker, compiled, track, track_many
from kinredund.tracking.constraints.scene import SKIP_MARGIN
from kinredund.tracking.point import Evaluator

pytestmark = pytest.mark.skipif(compiled.load_core() is None and not os.environ.get("CI"),
                                reason="the compiled core is not built (CI requires it: test_core_build.py)")

#: joints [rad or m] of the two backends at every recorded step: the issue's bar. Both corrected points lie
#: within the corrector's tolerance (1e-12 max(1, |grad z|) on ||F||) of the same optimum, and agree far closer
Q_BAR = 1e-12
#: any other recorded number, relative to max(1, its size): the same optimum, evaluated by either backend
FIELD_BAR = 1e-9
#: the rates and what depends on them, relative: the rates carry cond(R) times the rounding of either backend's
#: LU, and M is the step's, at its predicted point, extrapolated with the rates; near a kinematic singularity
#: (1/rcond ~ 1e3 to 1e4 on the planar 3R's stretched arm) they agree to ~1e-8 relative while q agrees to 1e-14
RATE_BAR = 1e-6
#: the record's fields (and meta entries) of :data:`RATE_BAR`
RATE_FIELDS = ("m_eigs", "m_null_eigs", "qdot", "qddot", "joint_speed_max", "speed_over_velocity_limit_max")


def _close(a, b, path: str, bar: float = FIELD_BAR) -> None:
    """a and b agree: arrays and numbers to ``bar`` (relative), everything else exactly; ``path`` names it."""
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            _close(a[k], b[k], f"{path}.{k}", bar)
    elif isinstance(a, (list, tuple)) and not (a and isinstance(a[0], (int, float)) and not isinstance(a[0], bool)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _close(x, y, f"{path}[{i}]", bar)
    elif isinstance(a, (np.ndarray, list, tuple, float)) and not isinstance(a, bool):
        x, y = np.asarray(a, float), np.asarray(b, float)
        assert x.shape == y.shape, path
        scale = np.maximum(1.0, np.abs(x))
        with np.errstate(invalid="ignore"):  # inf - inf
            same = (x == y) | (np.abs(x - y) <= bar * scale) | (np.isnan(x) & np.isnan(y))
        assert np.all(same), \
            f"{path}: differs by {np.nanmax(np.abs(x - y)):.3g}"
    else:
        assert a == b, f"{path}: {a!r} != {b!r}"


def assert_same_smallest(a: dict, b: dict) -> None:
    """The general rows' smallest value per point (``meta["constraints"]["min_value"]``) of two records of one run.

    A scene's rows (SceneClearance: names "... kept ... m apart") give values that are exact at or below SKIP_MARGIN
    and lower bounds above it (its module docstring): the Python stepper's lowered from its own last exact query, the
    compiled check's (RowGuard.smallest) row by row from its kept values. There the two agree to FIELD_BAR where
    either is at or below SKIP_MARGIN (then both are exact), and elsewhere both are above it (each a lower bound:
    tests/test_tracking_row_guard.py checks them against exact distances). Other constraints' values are exact: they
    agree to FIELD_BAR at every point."""
    x, y = np.asarray(a["min_value"], float), np.asarray(b["min_value"], float)
    assert x.shape == y.shape
    lowered = bool(a["names"]) and all(" kept " in nm and nm.endswith(" m apart") for nm in a["names"])
    near = np.minimum(x, y) <= SKIP_MARGIN if lowered else np.ones(len(x), bool)
    np.testing.assert_allclose(y[near], x[near], rtol=FIELD_BAR, atol=FIELD_BAR)
    assert np.all(x[~near] > SKIP_MARGIN) and np.all(y[~near] > SKIP_MARGIN)


def assert_same_record(a, b) -> None:
    """Two records of the same run by the two backends: q to Q_BAR, every other field to FIELD_BAR (the general rows'
    smallest values as :func:`assert_same_smallest` says)."""
    assert a.meta["backend"] == "python" and b.meta["backend"] == "compiled"
    np.testing.assert_allclose(b.q, a.q, rtol=0, atol=Q_BAR)
    for f in dataclasses.fields(a):
        if f.name == "meta":
            assert set(a.meta) == set(b.meta)
            for k in set(a.meta) - {"backend"}:
                x, y = a.meta[k], b.meta[k]
                if k == "constraints":
                    assert_same_smallest(x, y)
                    x, y = ({f: v for f, v in r.items() if f != "min_value"} for r in (x, y))
                _close(x, y, f"meta.{k}", RATE_BAR if k in RATE_FIELDS else FIELD_BAR)
        else:
            _close(getattr(a, f.name), getattr(b, f.name), f.name, RATE_BAR if f.name in RATE_FIELDS else FIELD_BAR)


def assert_same_watched(a: dict, b: dict) -> None:
    """A stop's watched quantities agree, every one (``reach_checked_at`` too: where the path's reach was checked
    at several times and every residual is rounding, it is the first time, not the time of the largest rounding;
    ``reason`` too: it names no diverged corrector iterate's numbers)."""
    _close(a, b, "watched")


def both(r, path, index, q0, **kw):
    """The run by each backend (python, compiled)."""
    return (track(r, path, index, q0, backend="python", **kw), track(r, path, index, q0, backend="compiled", **kw))


@functools.cache
def axis_case():
    r = robot("ur5")
    seed = np.array([0.3, -1.2, 1.5, -1.9, -1.57, 0.3])
    T = r.fk(seed)
    path = Circle(T[:3, 3] - np.array([0.06, 0.0, 0.0]), 0.06, 0.12, normal=(0.0, 0.0, 1.0),
                  orientation=frame_with_axis((0.0, 0.0, -1.0)))
    index = JointDeviation(seed + 0.2)
    s0 = path(0.0)
    start = kinredund.solve_ik(r, make_target("axis", (s0.Q, s0.p)), index, q0=seed)
    assert start.converged
    return r, path, index, start.q


def time_varying_case():
    r, path, index, q_star, _, _ = rr_time_varying_case()
    return r, path, index, q_star(0.0)


@functools.cache
def problem(name):
    """(robot, path, index, q0) of the named problem (each task kind, index kind and a switch)."""
    if name.startswith("example_"):
        ex = load_example(name.split("_")[1])
        return ex.robot, ex.path, ex.index, ex.q0
    if name == "panda_wrist15":
        return panda_circle(wrist_amplitude=float(np.radians(15.0)))
    if name == "ur5_axis":
        return axis_case()
    if name == "planar_time_varying":
        return time_varying_case()
    return limits_case(name)


# -- the evaluation: the core's terms against the Python evaluator's, at random points --------------------------

@pytest.mark.parametrize("name", ["example_4.1", "panda_wrist15", "ur5_axis", "panda_elbow_circle",
                                  "planar_time_varying"])
@pytest.mark.parametrize("form", ["augmented", "velocity"])
def test_the_core_evaluates_the_python_terms(name, form):
    r, path, index, q0 = problem(name)
    tracker = Tracker(r, path, index, q0, path.period / 100, scheme=form, backend="compiled", limits=False)
    core, ev = tracker.compiled.core, Evaluator(r, path, index, form)
    rng = np.random.default_rng(0)
    empty = np.zeros(0)
    for _ in range(3):
        t = float(rng.uniform(0, path.period))
        q = q0 + rng.normal(0.0, 0.05, r.nq)
        lam = rng.normal(0.0, 1.0, core.m)
        s = path.sample(t)
        ref, rate = ((np.asarray(index.reference(t)), np.asarray(index.rate(t))) if index.time_varying
                     else (empty, empty))
        got = core.evaluate(q, lam, s.p, s.v, np.zeros((0, 0)) if s.Q is None else s.Q,
                            np.zeros(3) if s.omega is None else s.omega, ref, rate)
        pt = ev.point(q, t)
        M, top = pt.system(lam)
        for x, y in zip(got, (pt.r, pt.J, pt.xdot, pt.grad, M, top), strict=True):
            # one chain of ~100 operations on numbers of size |y| (kind 1 of the tolerance policy)
            np.testing.assert_allclose(x, y, rtol=0, atol=64 * np.finfo(float).eps * max(1.0, np.abs(y).max()))


# -- whole runs: step by step and the records ------------------------------------------------------------------

@pytest.mark.parametrize(("name", "scheme", "limits"), [
    ("example_4.1", "augmented", False), ("example_4.3", "velocity", False), ("panda_wrist15", "augmented", None),
    ("panda_wrist15", "velocity", None), ("panda_wrist15", "augmented", False), ("ur5_axis", "augmented", None),
    ("ur5_axis", "velocity", False), ("planar_time_varying", "augmented", False),
    ("panda_elbow_circle", "augmented", None), ("xarm7_circle", "velocity", None)])
def test_both_backends_give_the_same_record_over_ten_loops(name, scheme, limits):
    r, path, index, q0 = problem(name)
    a, b = both(r, path, index, q0, loops=10, steps_per_loop=100, scheme=scheme, limits=limits)
    assert_same_record(a, b)
    if limits is None and name.endswith("circle"):  # the named limit cases meet a bound and leave it again
        assert len(a.meta["switches"]) >= 2


def test_steps_agree_one_by_one_and_the_core_takes_the_ordinary_ones():
    r, path, index, q0 = problem("panda_elbow_circle")
    dt = path.period / 200
    a = Tracker(r, path, index, q0, dt, backend="python")
    b = Tracker(r, path, index, q0, dt, backend="compiled")
    assert (a.backend, b.backend) == ("python", "compiled")
    for _ in range(400):
        a.step()
        b.step()
        assert b.t == a.t and b.solver == a.solver
        np.testing.assert_allclose(b.q, a.q, rtol=0, atol=Q_BAR)
        np.testing.assert_allclose(b.qdot, a.qdot, rtol=0, atol=FIELD_BAR)
    c = b.compiled
    assert c.steps > 200 and c.held_steps > 20 and c.handed_back.get("limit", 0) > 0  # every route ran
    assert c.steps + sum(c.handed_back.values()) == 400


# -- joints held on their bounds: the reduced system in the core -------------------------------------------------

@pytest.mark.parametrize(("name", "scheme", "rule"), [
    ("panda_pose_circle", "augmented", "auto"), ("panda_pose_circle", "velocity", "auto"),
    ("panda_wrist_circle", "augmented", "auto"), ("panda_wrist_circle", "augmented", "thesis"),
    ("panda_wrist_circle", "velocity", "auto"), ("xarm7_circle", "augmented", "auto"),
    ("xarm7_circle", "velocity", "auto")])
def test_steps_on_a_bound_are_the_core_s_and_the_same_as_python_s(name, scheme, rule):
    """Circles on which a joint meets its limit, stays on it for a stretch and leaves it (switches in both
    directions): the core takes the steps with the joint held (the reduced system, the bound multipliers, the
    solver label: the wrist circle's held steps are ``qp`` and ``qp_aug``, or ``lu`` under the rule ``thesis``),
    the Python stepper the steps with a switch in them; both runs give the same record and the same switches."""
    r, path, index, q0 = problem(name)
    options = {"loops": 3, "steps_per_loop": 200, "scheme": scheme, "linear_solver": rule}
    a = track(r, path, index, q0, backend="python", **options)
    tracker = Tracker(r, path, index, q0, path.period / 200, scheme=scheme, backend="compiled", linear_solver=rule)
    b = track(r, path, index, q0, backend="compiled", **options)
    assert_same_record(a, b)
    switches = a.meta["switches"]
    assert len(switches) >= 2 and {w["kind"] for w in switches} == {"reach", "release"}
    assert [(w["joint"], w["kind"]) for w in b.meta["switches"]] == [(w["joint"], w["kind"]) for w in switches]
    # the switching times: Brent's method in both runs from states that agree to rounding (its xtol 1e-14 s)
    np.testing.assert_allclose(b.switch_times, a.switch_times, rtol=0, atol=1e-12)
    held = np.any(a.active_bounds != 0, axis=1)
    assert held.sum() >= 20  # long stretches on a bound
    for _ in range(len(a.t) - 1):  # the same run stepped: which route took the steps
        tracker.step()
    c = tracker.compiled
    assert c.held_steps >= held.sum() - 4 * len(switches)  # all but the steps with (or right after) a switch
    assert c.handed_back.get("limit", 0) + c.handed_back.get("release", 0) >= len(switches) // 2


@pytest.mark.parametrize(("name", "pushed", "scheme"), [
    ("panda_elbow_circle", (2, 6), "augmented"), ("panda_elbow_circle", (2, 6), "velocity"),
    ("xarm7_circle", (6,), "augmented")])
def test_several_joints_held_at_once(name, pushed, scheme):
    """z pulls the ``pushed`` joints beyond their upper limits: two or three joints sit on bounds at once (the
    reduced system without several columns), joining and leaving the active set one by one."""
    r, path, _, q0 = problem(name)
    reference = np.array(r.home, float)
    reference[list(pushed)] = np.asarray(r.upper)[list(pushed)] + 0.5
    index = JointDeviation(reference)
    a, b = both(r, path, index, q0, loops=2, steps_per_loop=200, scheme=scheme)
    assert_same_record(a, b)
    held = np.sum(a.active_bounds != 0, axis=1)
    assert held.max() >= 2 and (held >= 2).sum() >= 20
    np.testing.assert_allclose(b.switch_times, a.switch_times, rtol=0, atol=1e-12)
    tracker = Tracker(r, path, index, q0, path.period / 200, scheme=scheme, backend="compiled")
    several = 0
    for _ in range(len(a.t) - 1):  # the core took the steps with several joints held (but those with a switch)
        before = tracker.compiled.steps
        tracker.step()
        several += tracker.compiled.steps > before and int(tracker.stepper.fixed.sum()) >= 2
    assert several >= (held >= 2).sum() - 4 * len(a.switch_times)


@pytest.mark.parametrize(("name", "cause"), [("panda_pose_infeasible", "limits_infeasible"),
                                           ("panda_pose_fold", "not_strongly_stable")])
def test_a_stop_has_the_same_cause_time_and_last_good_state(name, cause):
    r, path, index, q0 = problem(name)
    assert_same_stop(cause, r, path, index, q0, loops=2)


def assert_same_stop(cause, r, path, index, q0, **options):
    """Both backends stop with ``cause`` at the same time, last good point, watch and partial record.

    The stop's time is compared exactly: a stop is reported at a requested time t0 + k dt or at a sub-step or
    switching time that the Python stepper computes in both runs (the core hands troubled steps back), so the
    same step gives the same float on any CPU."""
    errors = []
    for backend in ("python", "compiled"):
        with pytest.raises(TrackingError) as info:
            track(r, path, index, q0, backend=backend, **options)
        errors.append(info.value)
    a, b = errors
    assert a.cause == b.cause == cause and b.t == a.t
    for e in errors:  # the documented float array (a stop raised inside a step was given a list)
        assert isinstance(e.q, np.ndarray) and e.q.dtype == float and e.q.shape == np.shape(q0)
    np.testing.assert_allclose(b.q, a.q, rtol=0, atol=Q_BAR)
    assert_same_watched(a.watched, b.watched)
    assert_same_record(a.partial, b.partial)
    return a.watched.get("reason"), b.watched.get("reason")


def _planar_failure(kind):
    """(robot, path, index, q0, track options) of the planar 3R's failures (tests/test_tracking_failures.py)."""
    arm, index = robot("planar3r"), minimum_norm(3)
    q0 = np.array([0.2, 0.6, 0.6])
    p0 = arm.fk(q0)[:2, 3]
    d = p0 / np.linalg.norm(p0)
    if kind == "kinematic_singularity":  # a circle touching the 6 m reach at T/2
        path = Circle(np.array([5.0, 0.0, 0.0]), 1.0, 1.0, start_angle=np.pi)
        return arm, path, index, kinredund.solve_ik(arm, path(0.0).p[:2], index, starts=12, seed=0).q, {}
    if kind == "out_of_reach":
        path = Circle(np.append(p0 + 1.5 * d, 0.0), 1.5, 1.0, axis_x=(-d[0], -d[1], 0.0))
        return arm, path, index, kinredund.solve_ik(arm, p0, index, q0=q0).q, {}
    if kind == "path_discontinuity":
        def fn(t):
            return p0 + np.array([0.1 * t, 0.0]) + (np.array([0.0, 0.3]) if t >= 0.5 else 0.0), np.array([0.1, 0.0])

        return arm, FunctionPath(fn), index, kinredund.solve_ik(arm, p0, index, q0=q0).q, {"duration": 1.0,
                                                                                            "steps": 40}
    raise AssertionError(kind)


@pytest.mark.parametrize("scheme", ["augmented", "velocity"])
@pytest.mark.parametrize("cause", ["kinematic_singularity", "out_of_reach", "path_discontinuity"])
def test_a_failure_is_the_same_failure(cause, scheme):
    """The core hands the troubled steps back: the stop is the Python stepper's, at the same time and point."""
    r, path, index, q0, span = _planar_failure(cause)
    assert_same_stop(cause, r, path, index, q0, scheme=scheme, **span)


def test_a_stop_after_a_diverged_corrector_says_the_same_on_both_backends():
    """A random Frenet circle of benchmarks/random_tasks.py (Panda, seed 0, task 61) whose sub-steps end in a
    corrector that leaves the path (R singular at the iterate): the stop's reason quoted R's and J's smallest
    singular values at that diverged iterate, which follow the rounding of the run (3.7e-17 and 6.8e-19 for R,
    0.037 and 0.0026 for J, even two Python runs differed); the reason names the kind and the time alone. The
    path's reach, checked at two times, is rounding at both (2e-15 m): ``reach_checked_at`` was the time of the
    larger rounding (2.2528 and 2.2723 s), now the first time checked, as at every stop within reach. The stop is a
    fold: R singular with J of full rank at the iterate, and at the last good point (t = 2.24451 s) the reduced
    Hessian's eigenvalue 1.04 -> 0.80 in 0.43 ms is predicted to reach zero at 2.24512 s, sigma_min(J) (0.0022 ->
    0.0019) at 2.24599 s; at 3200 steps per loop the fold is predicted outright (eigenvalue 0.27 at 2.24481 s,
    sigma_min 0.0015). It was named ``kinematic_singularity`` while the watch named the quantity checked first, not
    the first to cross (:meth:`~kinredund.tracking.watch.Watch.ahead`)."""
    r = robot("panda")
    path = Circle(np.array([-0.33903649101701, 0.34581688074079814, 0.9497127978493409]), 0.06253317604837266,
                  0.07063657766295746, normal=(-0.6396533827388732, 0.5962898719226892, 0.48505869602877905),
                  axis_x=(-0.3064205736976936, 0.38092316437214957, -0.8723554177395156), frenet=True)
    q0 = np.array([0.9558297502240778, 0.35911663111437214, 1.6815512339550884, -1.096070832997186,
                   -2.4551767145700514, 3.084526350768149, -0.4031411704149526])
    index = mid_range(r.lower, r.upper)
    reasons = assert_same_stop("fold", r, path, index, q0, steps_per_loop=200, loops=1, diagnostics=False)
    assert all("singularity at t = " in w and "smallest singular value" not in w for w in reasons), reasons
    assert all("eigenvalue predicted to reach zero at t = 2.2451" in w for w in reasons), reasons


def test_sub_steps_of_a_coarse_run_are_the_same():
    """4 steps per loop: the corrector fails whole steps, the step control's sub-steps finish (tests/
    test_tracking_failures.py): the core hands those steps back."""
    arm, path, index, q0, _ = _planar_failure("out_of_reach")
    path = Circle(np.append(arm.fk(q0)[:2, 3] - np.array([1.0, 0.0]), 0.0), 1.0, 1.0)
    assert_same_record(*both(arm, path, index, q0, steps_per_loop=4, loops=10))


# -- the choice of backend ---------------------------------------------------------------------------------------

def test_the_default_is_compiled_where_the_core_runs_and_python_elsewhere(monkeypatch):
    monkeypatch.delenv("KINREDUND_BACKEND", raising=False)
    r, path, index, q0 = problem("panda_wrist15")
    dt = path.period / 100
    assert Tracker(r, path, index, q0, dt).backend == "compiled"
    assert Tracker(r, path, index, q0, dt, mode="thesis").backend == "python"
    custom = CustomIndex(lambda q: 0.5 * q @ q, lambda q: q, lambda q: np.eye(len(q)))
    assert Tracker(r, path, custom, q0, dt).backend == "python"
    monkeypatch.setenv("KINREDUND_BACKEND", "python")
    assert Tracker(r, path, index, q0, dt).backend == "python"
    assert Tracker(r, path, index, q0, dt, backend="compiled").backend == "compiled"  # the argument wins
    monkeypatch.setenv("KINREDUND_BACKEND", "compiled")  # a whole program's: the core wherever it can run
    assert Tracker(r, path, index, q0, dt).backend == "compiled"
    assert Tracker(r, path, custom, q0, dt).backend == "python"  # not an error: only the argument's is


def test_compiled_where_it_cannot_run_says_why():
    r, path, index, q0 = problem("panda_wrist15")
    dt = path.period / 100
    custom = CustomIndex(lambda q: 0.5 * q @ q, lambda q: q, lambda q: np.eye(len(q)))
    with pytest.raises(OptionError, match="CustomIndex"):
        Tracker(r, path, custom, q0, dt, backend="compiled")
    with pytest.raises(OptionError, match="mode='thesis'"):
        Tracker(r, path, index, q0, dt, mode="thesis", limits=False, backend="compiled")
    with pytest.raises(ChoiceError, match="backend"):
        Tracker(r, path, index, q0, dt, backend="fast")


def test_a_core_that_cannot_load_warns_once_and_runs_python(monkeypatch):
    monkeypatch.delenv("KINREDUND_BACKEND", raising=False)
    monkeypatch.setattr(compiled, "_CORE", [None, "ImportError: no module named kinredund._core"])
    monkeypatch.setattr(compiled, "_WARNED", [])
    r, path, index, q0 = problem("panda_wrist15")
    dt = path.period / 100
    with pytest.warns(compiled.BackendWarning, match="cannot be loaded"):
        assert Tracker(r, path, index, q0, dt).backend == "python"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once: not again
        assert Tracker(r, path, index, q0, dt).backend == "python"
    with pytest.raises(OptionError, match="cannot be loaded"):
        Tracker(r, path, index, q0, dt, backend="compiled")


def test_in_ci_the_compiled_backend_never_falls_back_silently():
    if os.environ.get("CI"):
        assert compiled.load_core() is not None, compiled.core_error()
    r, path, index, q0 = problem("panda_wrist15")
    tr = track(r, path, index, q0, loops=1, steps_per_loop=50)
    assert tr.meta["backend"] == (os.environ.get("KINREDUND_BACKEND") or "compiled").replace("auto", "compiled")


# -- the start: corrected onto the optimum, its rates and the watch's first measurement in the core ----------------

def random_start(name: str, k: int):
    """(robot, path, index, q0) of the k-th seeded random start of ``name``: q0 uniform inside the limits (away from
    them), the path a circle through its pose (the pose task, the orientation held), the index a JointDeviation from
    q0 plus noise, so that the start is off the optimum and the corrector moves it (k = 3: the second joint on its
    upper limit and the reference beyond it, so that it stays held)."""
    r = robot(name)
    rng = np.random.default_rng([k, 28])
    lo, hi = np.maximum(r.lower, -np.pi), np.minimum(r.upper, np.pi)
    q0 = rng.uniform(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo))
    reference = q0 + rng.normal(0.0, 0.2, r.nq)
    if k == 3:
        q0[1], reference[1] = r.upper[1], r.upper[1] + 2.0
    T = r.fk(q0)
    path = Circle(T[:3, 3] - np.array([0.0, 0.05, 0.0]), 0.05, 0.1, normal=(1.0, 0.0, 0.0), axis_x=(0.0, 1.0, 0.0),
                  orientation=T[:3, :3])
    return r, path, JointDeviation(reference), q0


def counted_starts(monkeypatch) -> list:
    """The results of the core's starts (``start_run``: a row, or the status that leaves the start to Python)."""
    core, got = compiled.load_core(), []
    inner = core.start_run

    def spy(*args):
        got.append(inner(*args))
        return got[-1]

    monkeypatch.setattr(core, "start_run", spy)
    return got


@pytest.mark.parametrize("name", ["panda", "xarm7"])
@pytest.mark.parametrize("k", range(4))
@pytest.mark.parametrize("limits", [None, False])
def test_the_compiled_start_is_the_python_start(name, k, limits, monkeypatch):
    """The core's start (``start_run``: the corrector's rounds from q0, the rates, the bound multipliers, the watch's
    exact measurement) against the Python stepper's: both correct onto the same optimum (q to Q_BAR), the rest is the
    same evaluation there to FIELD_BAR (measured: 1e-12 relative at most, lambda, on these starts)."""
    r, path, index, q0 = random_start(name, k)
    starts = counted_starts(monkeypatch)
    a, b = (Tracker(r, path, index, q0, path.period / 200, limits=limits, backend=backend)
            for backend in ("python", "compiled"))
    assert len(starts) == 1 and type(starts[0]) is tuple  # the compiled backend's start was the core's
    sa, sb = a.stepper, b.stepper
    if k != 3:  # (with a joint held the 7-joint arms have no redundancy left on the pose task: q0 is the point)
        assert np.abs(sa.q - q0).max() > 1e-3  # the start was corrected
    np.testing.assert_allclose(sb.q, sa.q, rtol=0, atol=Q_BAR)
    for key in ("lam", "qdot", "lamdot", "M", "rcond", "t"):
        _close(getattr(sa, key), getattr(sb, key), key)
    if limits is None:
        np.testing.assert_array_equal(sb.fixed, sa.fixed)
        assert sa.fixed.sum() == (k == 3)
        _close(sa.mu, sb.mu, "mu")
    assert sb.solver == sa.solver
    wa, wb = a.stepper.control.watch, b.stepper.control.watch
    _close([wa.sigma, wa.eig, wa.scale, wa.sigma_max], [wb.sigma, wb.eig, wb.scale, wb.sigma_max], "watch")


@pytest.mark.parametrize("case", ["off_the_path", "singular", "non_optimal"])
def test_a_start_that_fails_fails_alike_on_both_backends(case, monkeypatch):
    """A start off the path and a singular one are refused before the correction (the same code on both backends); a
    start the core cannot correct (R ill-conditioned at an iterate: status 2) is the Python stepper's, which names the
    failure as on the Python backend, to the same message (the same operations from the same state)."""
    if case == "singular":  # the planar 3R stretched out along the path's start
        r, index, q0 = robot("planar3r"), minimum_norm(3), np.zeros(3)
        path = Circle(np.array([5.0, 0.0, 0.0]), 1.0, 1.0)
    else:
        r, path, index, q0 = random_start("xarm7", 1)
        if case == "off_the_path":
            q0 = q0 + 0.01
        else:  # a reference that makes the corrector diverge from q0 (seeded: the core's start gives up with 2)
            index = JointDeviation(np.array([-1.07193156, 0.25140565, -1.53748977, 0.40307366, -2.05730051,
                                             -0.24740914, 1.13181298]))
            q0 = np.array([-0.98925069, -0.13681349, -1.83950706, 1.21642241, -1.49059654, -0.19497751, 1.25847011])
            T = r.fk(q0)
            path = Circle(T[:3, 3] - np.array([0.0, 0.05, 0.0]), 0.05, 0.1, normal=(1.0, 0.0, 0.0),
                          axis_x=(0.0, 1.0, 0.0), orientation=T[:3, :3])
    starts = counted_starts(monkeypatch)
    errors = []
    for backend in ("python", "compiled"):
        with pytest.raises(kinredund.KinredundError) as info:
            Tracker(r, path, index, q0, path.period / 200, backend=backend)
        errors.append(info.value)
    a, b = errors
    assert type(a) is type(b) and str(a) == str(b)
    assert getattr(a, "cause", None) == getattr(b, "cause", None)
    expected = {"off_the_path": ("PathError", None), "singular": ("TrackingError", "kinematic_singularity"),
                "non_optimal": ("TrackingError", "non_optimal_start")}[case]
    assert (type(a).__name__, getattr(a, "cause", None)) == expected
    assert starts == ([2] if case == "non_optimal" else [])


# -- many runs in one call ---------------------------------------------------------------------------------------

def test_track_many_equals_the_runs_one_by_one():
    problems = [problem("panda_wrist15"), problem("ur5_axis"), problem("panda_elbow_circle"),
                problem("panda_pose_infeasible")]
    options = {"loops": 2, "steps_per_loop": 100}
    many = track_many(problems, threads=2, **options)
    for got, p in zip(many, problems, strict=True):
        try:
            alone = track(*p, **options)
        except TrackingError as err:
            assert isinstance(got, TrackingError) and got.cause == err.cause and got.t == err.t
            np.testing.assert_array_equal(got.q, err.q)
            np.testing.assert_array_equal(got.partial.q, err.partial.q)
            continue
        # the same computation in another thread, bit for bit (threads sharing a workspace would be off by far more)
        for key in ("q", "lam", "qdot"):
            np.testing.assert_array_equal(getattr(got, key), getattr(alone, key), err_msg=key)
    with pytest.raises(OptionError, match="threads"):
        track_many(problems, threads=0)
    with pytest.raises(OptionError, match="problem 0"):
        track_many([problems[0][:3]])


def test_track_many_in_processes_equals_the_runs_one_by_one(monkeypatch):
    """processes=2: the problems and options inherited by two forked workers, the records and stops pickled back; the
    same computation, so the records are the runs' one by one bit for bit, the stops the same (cause, time, joints,
    partial record), with a sphere held (the runs whose switches hold the GIL, for which threads gain nothing). The
    workers are forked, so a path of a lambda is tracked too; where they must be spawned it is refused, as are
    processes=0 and threads and processes both."""
    from test_tracking_clearance import CASES, STOP_CASES

    from kinredund.paths import FunctionPath
    from kinredund.tracking import SphereClearance, many_processes

    circle, frame, center, radius = CASES["panda_elbow_sphere"]
    held = problem(circle)
    _, _, stop_center, stop_radius, _ = STOP_CASES["fold"]
    for problems, sphere in (([held, held], (center, radius)), ([held, held], (stop_center, stop_radius))):
        options = {"loops": 1, "steps_per_loop": 200, "constraints": [SphereClearance(held[0], frame, *sphere)]}
        many = track_many(problems, processes=2, **options)
        alone = track_many(problems, threads=1, **options)
        for got, want in zip(many, alone, strict=True):
            if isinstance(want, TrackingError):
                assert isinstance(got, TrackingError) and got.cause == want.cause == "collision" and got.t == want.t
                np.testing.assert_array_equal(got.q, want.q)
                got, want = got.partial, want.partial
            else:
                assert len(got.meta["switches"]) >= 2  # the sphere met and left
            for key in ("q", "lam", "qdot", "t"):
                np.testing.assert_array_equal(getattr(got, key), getattr(want, key), err_msg=key)
            assert got.meta == want.meta
    with pytest.raises(OptionError, match="processes must be an integer >= 1"):
        track_many(problems, processes=0)
    with pytest.raises(OptionError, match="threads= or processes=, not both"):
        track_many(problems, threads=2, processes=2)
    r, path, index, q0 = held
    lam = FunctionPath(lambda t: (path(t).p, path(t).v), period=path.period)  # (a lambda: forked, not pickled)
    got = track_many([(r, lam, index, q0)] * 2, processes=2, loops=1, steps_per_loop=50)
    np.testing.assert_array_equal(got[1].q, track(r, lam, index, q0, loops=1, steps_per_loop=50).q)
    monkeypatch.setattr(many_processes, "start_method", lambda: "spawn")  # where the platform has no fork
    with pytest.raises(OptionError, match="picklable"):
        track_many([(r, lam, index, q0)] * 2, processes=2)


def test_track_many_in_processes_raises_a_run_s_choice_error_as_such():
    """A worker's ChoiceError (an unknown scheme) came back as SolverError 'a worker process ... ended abruptly ...
    killed, or out of memory?': it pickled, but did not unpickle (ChoiceError's __init__ takes what, value, allowed).
    It is the ChoiceError that threads raise."""
    from kinredund.errors import ChoiceError

    good = problem("panda_wrist15")
    for how in ({"threads": 2}, {"processes": 2}):
        with pytest.raises(ChoiceError, match="unknown scheme 'bogus'; allowed: augmented") as info:
            track_many([good, good], loops=1, steps_per_loop=20, scheme="bogus", **how)
        assert info.value.allowed == ["augmented", "velocity", "pseudoinverse", "liegeois"]


def test_track_many_in_processes_raises_the_first_problem_s_error_as_threads_do():
    """An error of another family in a later problem (a user path's own exception) was raised, from the workers' map,
    before an earlier problem's JointVectorError (held back to the end), where threads raise the first problem's:
    both routes raise the error of the first problem that raised one."""
    from kinredund.errors import JointVectorError

    good = problem("panda_wrist15")
    r, path, index, q0 = good

    def sample(t):
        if t > 0.3:
            raise ZeroDivisionError("the user's own")
        s = path(t)
        return s.Q, s.p, s.omega, s.v

    failing = (r, FunctionPath(sample, period=path.period, has_orientation=True), index, q0)
    for how in ({"threads": 2}, {"processes": 2}):
        with pytest.raises(JointVectorError, match=r"got \(3,\)"):
            track_many([(r, path, index, q0[:3]), failing], loops=1, steps_per_loop=20, **how)
        with pytest.raises(ZeroDivisionError, match="the user's own"):
            track_many([good, failing], loops=1, steps_per_loop=20, **how)


def test_track_many_threads_stop_taking_problems_at_a_keyboard_interrupt():
    """Ctrl-C reaches the calling thread, one of track_many's workers: its run's KeyboardInterrupt used to be kept as
    that job's error while every other problem was still run to its end; now no job is taken after it, the runs under
    way end, and it is raised."""
    import time

    from kinredund.tracking.many import _in_threads

    ran = []

    def one(job):
        if job == 0:
            raise KeyboardInterrupt
        time.sleep(0.01)
        ran.append(job)
        return job

    with pytest.raises(KeyboardInterrupt):
        _in_threads(one, list(range(20)), 2)
    assert len(ran) <= 2  # the helper's job under way (and at most one it took before the interrupt)
    assert _in_threads(lambda job: job * 2, list(range(5)), 2) == [0, 2, 4, 6, 8]
