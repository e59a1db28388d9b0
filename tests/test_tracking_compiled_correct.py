"""The Python stepper's corrector solve in the compiled core (issue 28: kinredund/tracking/compiled_correct.py).

On the compiled backend the limited stepper's ``_correct`` (a handed-back step's, a sub-step's, each evaluation of
the switching-time search) is the core's ``StepCore.correct``. From the same state and prediction both routes
make the same operations in a different order: q and lambda, their rates and the bound multipliers agree to
rounding (1e-12 relative to max(1, |x|)), the label and the predictor's history exactly; R's LU factors agree to
rounding with the same pivots. A solve the core declines is Python's own, with its own error.
"""

from __future__ import annotations

import os
import re

import numpy as np
import pytest
from test_tracking_compiled import assert_same_record, problem
from test_tracking_compiled_rows import SWITCH_BAR

from kinredund.errors import KinredundError, TrackingError
from kinredund.paths import FunctionPath
from kinredund.tracking import Tracker, compiled, track
from kinredund.tracking.compiled_correct import CoreCorrector

pytestmark = pytest.mark.skipif(compiled.load_core() is None and not os.environ.get("CI"),
                                reason="the compiled core is not built (CI requires it: test_core_build.py)")

#: the two routes' results, relative to max(1, |x|): the same operations on the same inputs in another order
BAR = 1e-12


def _result(s) -> dict:
    """What ``_correct`` leaves in the stepper ``s``."""
    lu, piv = s.lu
    return {"q": s.q, "lam": s.lam, "qdot": s.qdot, "lamdot": s.lamdot, "mu": s.mu, "M": s.M, "J": s.pt.J,
            "lu": lu, "piv": np.asarray(piv), "rcond": s.rcond, "label": s.solver, "history": len(s.prev),
            "fixed": s.fixed.copy()}


def _both_routes(s, act) -> tuple[dict, dict, int] | None:
    """``act()`` (a corrector solve of the stepper ``s``) by the core, then from the same state by Python:
    (the core's result, Python's, how many solves the core made), or None where the solve fails on both routes
    with the same error (the core declined it: Python's own failure)."""
    hook = s.corrector
    assert isinstance(hook, CoreCorrector)
    snap, used, declined = s.state, hook.used, hook.declined
    failed = None
    try:
        act()
        core = _result(s)
    except KinredundError as err:
        failed = err
        assert hook.declined == declined + 1 and hook.used == used
    made = hook.used - used
    s.state, s.corrector = snap, None
    try:
        if failed is not None:
            with pytest.raises(type(failed)) as again:
                act()
            assert str(again.value) == str(failed)
            return None
        act()
        python = _result(s)
    finally:
        s.corrector = hook
        s.state = snap
    return core, python, made


def _assert_same(core: dict, python: dict, what: str) -> None:
    for key in ("q", "lam", "qdot", "lamdot", "mu", "M", "J", "lu"):
        x, y = np.asarray(python[key], float), np.asarray(core[key], float)
        assert x.shape == y.shape, f"{what}: {key}"
        err = np.max(np.abs(x - y) / np.maximum(1.0, np.abs(x)), initial=0.0)
        assert err <= BAR, f"{what}: {key} differs by {err:.3g}"
    np.testing.assert_array_equal(core["piv"], python["piv"], err_msg=what)
    assert abs(core["rcond"] - python["rcond"]) <= 1e-6 * python["rcond"], what  # an estimate from the same factors
    for key in ("label", "history", "fixed"):
        assert np.all(core[key] == python[key]), f"{what}: {key} {core[key]} != {python[key]}"


@pytest.mark.parametrize(("name", "scheme", "holds"), [
    ("panda_pose_circle", "augmented", 4), ("panda_pose_circle", "velocity", 4), ("panda_wrist_circle", "augmented", 4),
    ("xarm7_circle", "augmented", 4), ("xarm7_circle", "velocity", 4), ("ur5_axis", "augmented", 0),
    ("ur5_axis", "velocity", 0), ("planar_time_varying", "augmented", 4)])
def test_the_core_s_correct_is_python_s(name, scheme, holds):
    """From states along the run (some with the free joint nearest a bound held on it, as a switch leaves them;
    random predictions: Euler steps of random length, perturbed), the core's solve and Python's ``_correct`` give
    the same point, rates, multipliers, label and factors; long Euler steps make the chord iterations fail, so the
    fallback (a fresh Newton from the prediction, the rates there, the predictor's history cleared) is compared
    too. ``holds``: the solves with a joint held at the least (the UR5's axis task has one degree of redundancy: a
    joint held leaves J_F square, and from these states both routes fail the same way)."""
    r, path, index, q0 = problem(name)
    dt = path.period / 100
    tracker = Tracker(r, path, index, q0, dt, scheme=scheme, backend="compiled", limits=True)
    s = tracker.stepper
    rng = np.random.default_rng(1)
    restarted = solves = held = failures = 0
    for k in range(24):
        for _ in range(1 + k % 5):  # (through a stretch on a bound: the pose circle's from t ~ 0.45 T to 0.75 T)
            tracker.step()
        snap = s.state
        hold, far = k % 4 in (1, 3), k % 4 >= 2
        free = np.flatnonzero(~s.fixed)
        if hold and len(free) > len(s.task_lam):  # the free joint nearest a bound held on it (a switch's set)
            margins = np.minimum(s.q - s.lo, s.hi - s.q)[free]
            i = int(free[np.argmin(margins)])
            s._apply_switch(i, "lower" if s.q[i] - s.lo[i] < s.hi[i] - s.q[i] else "upper")
        # a prediction: an Euler step of up to a step's length, perturbed; or a long one from further off (the
        # chord iterations fail from there: the fallback, a fresh Newton from the prediction and the rates there)
        h = dt * (rng.uniform(4.0, 12.0) if far else rng.uniform(0.05, 1.0))
        y = np.concatenate([s.q, s.lam]) + h * s.yd + rng.normal(0.0, 3e-2 if far else 1e-4, len(s.y))
        s.prev.extend((s.y, s.yd))  # a history for the fallback to clear

        def solve(y=y, t=s.t + h):
            s.t = t
            s._correct(y)

        got = _both_routes(s, solve)
        held += bool(s.any_active) and got is not None
        s.state = snap
        if got is None:  # the prediction is too far off: the same failure on both routes
            failures += 1
            continue
        core, python, made = got
        assert made == 1
        _assert_same(core, python, f"{name} {scheme} state {k}")
        solves += 1
        restarted += core["history"] == 0
    assert solves >= 12 and held >= holds and failures <= solves
    assert restarted >= 1  # the fallback ran


def test_a_solve_the_core_declines_is_python_s_with_its_error():
    """A non-finite prediction: the core returns a status (its R is not factorised), the hook declines and Python's
    ``_correct`` meets the failure and names it, as without the hook."""
    r, path, index, q0 = problem("panda_wrist_circle")
    tracker = Tracker(r, path, index, q0, path.period / 100, backend="compiled")
    s = tracker.stepper
    tracker.step()
    hook, snap = s.corrector, s.state
    y = s.y.copy()
    y[0] = np.nan
    with pytest.raises(KinredundError) as core_route:
        s._correct(y)
    assert hook.declined == 1 and hook.used == 0
    s.state, s.corrector = snap, None
    with pytest.raises(KinredundError) as python_route:
        s._correct(y)
    assert type(core_route.value) is type(python_route.value)
    assert str(core_route.value) == str(python_route.value)


def test_handed_back_steps_correct_in_the_core():
    """On a circle where a joint meets its limit and leaves it, the steps handed back to the Python stepper (the
    switches) make their corrector solves in the core, none declined, the switching times are located there
    (Brent's method in C++), and the run's record is the Python backend's."""
    r, path, index, q0 = problem("panda_pose_circle")
    tracker = Tracker(r, path, index, q0, path.period / 200, backend="compiled")
    for _ in range(200):
        tracker.step()
    c, hook = tracker.compiled, tracker.stepper.corrector
    handed = sum(c.handed_back.values())
    assert c.handed_back.get("limit", 0) >= 1 and c.handed_back.get("release", 0) >= 1
    switches = len(tracker.stepper.switches)
    # each handed-back step's own solve; per switch the correction to its time, the Newton solve there (settle) and the
    # correction on to the step's end
    assert switches >= 2 and hook.used >= handed + 3 * switches and hook.declined == 0
    # the switching-time searches: Brent's method in the core, its solves there too (CoreCorrector.locate)
    assert hook.located >= c.handed_back["limit"] + c.handed_back["release"] and hook.locates_declined == 0
    a = track(r, path, index, q0, backend="python", loops=1, steps_per_loop=200)
    b = track(r, path, index, q0, backend="compiled", loops=1, steps_per_loop=200)
    assert_same_record(a, b)


def test_a_search_that_meets_a_users_error_is_pythons_and_says_so():
    """A user's path function that raises ValueError at times only the switching-time search evaluates (a table of
    samples at dt / 64): the core's search hands the search to Python's (CoreCorrector.locate declines), which meets the
    error and names it, switch_not_resolved, the message and time the Python backend's (the raw ValueError escaped)."""
    r, circle, index, q0 = problem("panda_pose_circle")
    dt = circle.period / 200

    def fn(t):
        k = t / dt * 64
        if abs(k - round(k)) > 1e-6:
            raise ValueError(f"no table entry at t = {t!r}")
        s = circle.sample(t)
        return s.Q, s.p, s.omega, s.v

    path = FunctionPath(fn, period=circle.period, has_orientation=True)
    stops = {}
    for backend in ("python", "compiled"):
        tracker = Tracker(r, path, index, q0, dt, backend=backend)
        with pytest.raises(TrackingError) as err:
            for _ in range(200):
                tracker.step()
        stops[backend] = err.value
    a, b = stops["python"], stops["compiled"]
    assert a.cause == b.cause == "switch_not_resolved" and a.t == b.t  # (the last good point: the step's start)
    # the same words; the search's iterate where the table failed (a time in the message) the same to rounding: the
    # backends' corrector solves differ in the last bits, and so does Brent's next point from them (another BLAS
    # kernel gave 1.7373371056854676 against ...5465). The bar: a wrong bracket or step would miss it by a table
    # spacing or more (dt / 64 = 3.1e-4 s), rounding moves it by ~1e-15 s; 1e-10 s is far from both
    at = [float(re.search(r"no table entry at t = ([0-9.e+-]+)", str(x)).group(1)) for x in (a, b)]
    assert at[1] == pytest.approx(at[0], rel=0, abs=SWITCH_BAR)  # (the switching times' bar of the backends)
    masked = [re.sub(r"no table entry at t = [0-9.e+-]+", "", str(x)) for x in (a, b)]
    assert masked[0] == masked[1]
    assert tracker.stepper.corrector.locates_declined >= 1
