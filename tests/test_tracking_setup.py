"""A run's set-up (issue 28: track_many's threads): what it shares between runs and threads; the core's start checks.

The set-up keeps what depends only on the robot, the limits, the time step or the options (the limits' bounds, the
predictor's weights, the checked options), made once and shared read-only; the compiled start makes the start's rank
check and lambda in the core, the GIL released (``start_checks``: lambda by scipy's LAPACK calls of the Python
stepper, the same numbers bit for bit; the rank verdict a bound from the same QR, the Python check deciding near
it), and its StepCore steps with the robot's own pin.Model, which it keeps alive. The records themselves are held
by test_tracking_runs.py, test_tracking_compiled.py and test_tracking_api.py.
"""

from __future__ import annotations

import os
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.linalg import lapack

from kinredund.errors import ChoiceError, JointVectorError, OptionError, PathError
from kinredund.paths import PathSample
from kinredund.paths.base import checked
from kinredund.problems import panda_circle
from kinredund.tracking import Tracker, compiled
from kinredund.tracking.compiled_start import CompiledStart, make_step_core
from kinredund.tracking.linalg import multipliers
from kinredund.tracking.watch import SIGMA_FLOOR

needs_core = pytest.mark.skipif(compiled.load_core() is None and not os.environ.get("CI"),
                                reason="the compiled core is not built (CI requires it: test_core_build.py)")


def bits(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, float).view(np.uint64)


@needs_core
def test_the_core_start_checks_give_multipliers_lambda_bit_for_bit_and_clear_only_full_rank():
    """start_checks makes multipliers' dgeqrf, dormqr and dtrtrs with the arguments scipy's wrappers pass: the same
    library on the same numbers gives the same bits (the claim is equality of two routes through one code), on wide J
    of every task size, near-singular ones and a zero gradient included. Its rank verdict, a bound from the same QR,
    clears J only where the stepper's own check (dgesvd: sigma_min > floor max(1, sigma_max)) passes by the floor it
    is given, and clears every J here whose sigma_min is 30x that floor (the bound loses at most m: ||.||_F of R^-1
    and of J)."""
    core = compiled.load_core()
    rng = np.random.default_rng(28)
    floor = 4.0 * SIGMA_FLOOR
    cleared = 0
    for trial in range(600):
        m = int(rng.integers(1, 7))
        n = int(rng.integers(m, 10))
        J = rng.normal(size=(m, n)) * 10.0 ** rng.uniform(-3, 3)
        if trial % 5 == 0:  # a row nearly dependent on another: sigma_min from ~1e-12 to ~1e-9 of sigma_max
            J[-1] = 10.0 ** rng.uniform(-12, -9) * rng.normal(size=n) + 1e-3 * J[0] * (m > 1)
        grad = np.zeros(n) if trial % 7 == 0 else rng.normal(size=n) * 10.0 ** rng.uniform(-5, 2)
        clear, lam = core.start_checks(J, grad, floor)
        assert lam is not None
        np.testing.assert_array_equal(bits(lam), bits(multipliers(J, grad)[0]))
        sv = lapack.dgesvd(J, compute_uv=0, full_matrices=0)[1]
        if clear:
            assert sv[-1] > floor * max(1.0, sv[0])
            cleared += 1
        elif sv[-1] > 30.0 * floor * max(1.0, sv[0]):
            raise AssertionError(f"a J of full rank not cleared: {sv}")
    assert 400 < cleared < 600
    J = np.eye(3, 5)
    J[1, 2] = np.nan
    assert core.start_checks(J, np.ones(5), floor) == (False, None)  # not finite: the Python checks decide
    with pytest.raises(ValueError):
        core.start_checks(np.eye(3, 5), np.ones(4), floor)


@needs_core
@pytest.mark.parametrize(("smallest", "clear"), [(1e-6, True), (3e-7, True), (3e-8, False), (5e-9, False)])
def test_a_start_near_the_rank_floor_is_left_to_the_python_check(smallest, clear):
    """The compiled start's check clears J only where sigma_min(J) is certainly above 4x the stepper's floor
    (SIGMA_FLOOR x sigma_max, here 1; its bound from the QR loses up to sqrt(6) on each side): near the floor and
    below it, the stepper's own check decides (and names a singularity in its words)."""
    rng = np.random.default_rng(3)
    U = np.linalg.qr(rng.normal(size=(6, 6)))[0]
    V = np.linalg.qr(rng.normal(size=(7, 7)))[0]
    s = np.array([1.0, 0.8, 0.5, 0.3, 0.1, smallest])
    J = U @ np.diag(s) @ V[:6]
    got, lam = CompiledStart(compiled.load_core()).checks(SimpleNamespace(J=J, grad=rng.normal(size=7)))
    assert got is clear and lam is not None


@needs_core
def test_the_step_core_keeps_the_robot_s_model_alive():
    """A StepCore steps with the robot's pin.Model itself (no copy per run): it holds one reference to it, given
    back when the core goes."""
    r, path, index, q0 = panda_circle()
    tracker = Tracker(r, path, index, q0, path.period / 200, backend="compiled")
    model = r.model
    before = sys.getrefcount(model)
    core = make_step_core(tracker.stepper, compiled.load_core())
    assert sys.getrefcount(model) == before + 1
    del core
    assert sys.getrefcount(model) == before


def test_runs_share_the_limits_bounds_and_the_predictor_weights_read_only():
    """Two runs on one robot and time step share the bounds derived from its limits and the predictor's weights, and
    neither can be changed in place; a start with every joint free shares the zero active set, which a switch
    replaces (it is never changed in place either)."""
    r, path, index, q0 = panda_circle()
    a, b = (Tracker(r, path, index, q0, path.period / 200).stepper for _ in range(2))
    for name in ("lo", "hi", "_lo_tol", "_hi_tol", "fixed", "side", "mu"):
        x, y = getattr(a, name), getattr(b, name)
        assert x is y and not x.flags.writeable, name
        with pytest.raises(ValueError):
            x[0] = 0.0
    np.testing.assert_array_equal(a.lo, r.lower)
    assert a.hermite is b.hermite and all(not w.flags.writeable for w in a.hermite[1:])
    other = Tracker(r, path, index, q0, path.period / 100).stepper
    assert other.hermite is not a.hermite and other.lo is a.lo


def test_the_kept_options_tell_types_apart_and_a_bad_option_fails_every_time():
    """The tracker's checked options are kept by value and type: True is a flag, 1 is not, however often True was
    given first; a refused option is refused on every call."""
    r, path, index, q0 = panda_circle()
    dt = path.period / 200
    for _ in range(2):
        Tracker(r, path, index, q0, dt, project_start=True)
        with pytest.raises(OptionError, match="project_start must be True or False"):
            Tracker(r, path, index, q0, dt, project_start=1)
        with pytest.raises(ChoiceError):
            Tracker(r, path, index, q0, dt, scheme="augmentd")
        with pytest.raises(OptionError, match="tol"):
            Tracker(r, path, index, q0, dt, tol=np.array([1e-12]))
    for gain in (0.0, -0.0):  # one key to a cache: checked afresh, the gain kept as given
        got = Tracker(r, path, index, q0, dt, scheme="liegeois", liegeois_gain=gain, limits=False).stepper.gain
        assert str(got) == str(gain)


def test_check_q_returns_a_checked_vector_itself_and_refuses_as_before():
    """Robot.check_q gives a finite float64 vector of the right length back as it is (what check_joint_vector gives
    for it), converts others, and refuses a wrong length or a non-finite entry with check_joint_vector's error; a
    vector whose squares overflow is still finite, and accepted."""
    r = panda_circle()[0]
    q = r.home.copy()
    assert r.check_q(q) is q
    np.testing.assert_array_equal(r.check_q(list(q)), q)
    big = np.full(7, 1e200)
    assert r.check_q(big) is big
    for bad, said in ((q[:6], "must have shape"), (np.where(np.arange(7) == 2, np.nan, q), "non-finite")):
        with pytest.raises(JointVectorError, match=said):
            r.check_q(bad)
    assert r.joint_names == r.joint_names and r.joint_names is not r.joint_names  # a new list each time


def test_checked_passes_small_samples_and_names_what_is_wrong_as_calling_a_path_does():
    """paths.checked (calling a path, and the tracker's start) passes a sample of small finite entries, and refuses
    a non-finite entry and entries whose squares overflow with their own messages."""
    Q, p, w, v = np.eye(3), np.array([0.5, 0.0, 1e140]), np.zeros(3), np.ones(3)
    s = PathSample(p, v, Q, w)
    assert checked(s, 0.0) is s
    with pytest.raises(PathError, match="non-finite omega"):
        checked(PathSample(p, v, Q, np.array([0.0, np.inf, 0.0])), 0.25)
    with pytest.raises(PathError, match="too large"):
        checked(PathSample(np.array([1e200, 0.0, 0.0]), v), 0.5)
    assert checked(PathSample(np.array([1e151, 0.0, 0.0]), v), 0.5).p[0] == 1e151  # squares below overflow: passes


def test_the_index_checked_at_the_start_serves_the_first_evaluation_there_only():
    """The tracker checks the index at q0 (check_index_at) and hands its terms to the evaluator: the first evaluation
    takes them where it is at that very array and t = 0; another array with the same numbers, or another time,
    evaluates the index; either way only the first evaluation is offered them."""
    from kinredund.tracking.point import Evaluator

    r, path, index, q0 = panda_circle()
    ev = Evaluator(r, path, index, "augmented")
    kept = (0.0, np.arange(7.0), np.eye(7))  # not the index's terms at q0 (its gradient is zero there)
    ev.keep_index_at(q0, kept)
    np.testing.assert_array_equal(ev.point(q0.copy(), 0.0).grad, 0.0)  # another array: evaluated
    ev.keep_index_at(q0, kept)
    np.testing.assert_array_equal(ev.point(q0, 0.5).grad, 0.0)  # another time: evaluated
    ev.keep_index_at(q0, kept)
    assert ev.point(q0, 0.0).grad is kept[1]  # the very array at t = 0: taken
    np.testing.assert_array_equal(ev.point(q0, 0.0).grad, 0.0)  # once
