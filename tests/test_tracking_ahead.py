"""The compiled step's path samples taken ahead in blocks, and its point read from the core's row on demand (issue 28).

:class:`~kinredund.tracking.ahead.SamplesAhead` gives the core the path's samples of a block of steps computed
together (:meth:`~kinredund.paths.Path.sample_many`); :class:`~kinredund.tracking.compiled.CompiledPoint` makes
its fields only where they are read. Both must give what the step-by-step sampling and the eager point gave.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from conftest import rounding

from kinredund.paths import Circle, FunctionPath
from kinredund.problems import panda_circle
from kinredund.tracking import Tracker, compiled, track
from kinredund.tracking.ahead import BLOCK, MIN_BLOCK, NO_OMEGA, NO_Q, SamplesAhead

Q0 = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
CIRCLES = {"position": Circle(np.array([0.4, 0.1, 0.5]), 0.1, speed=0.3),
           "frenet": Circle(np.array([0.4, 0.1, 0.5]), 0.1, speed=0.3, start_angle=0.7, frenet=True),
           "rolling": Circle(np.array([0.4, 0.1, 0.5]), 0.1, speed=0.3, orientation=Q0, roll_amplitude=0.3)}


@pytest.mark.parametrize("kind", list(CIRCLES))
def test_a_block_holds_the_path_s_samples_at_the_steps_times(kind):
    """Each row of two successive blocks is the path's own sample at t0 + k dt (the stepper's clock), to rounding
    (the same operations on arrays: the circle's sample_many); a path without orientation gets the core's
    placeholders for Q and omega."""
    path, t0, dt = CIRCLES[kind], 0.25, 0.013
    ahead = SamplesAhead(path, t0, dt, block=MIN_BLOCK + 3)
    ahead.first, ahead.count = 3 - ahead.block, ahead.block  # as after a whole block: the next ones follow it
    for k in (3, 3 + ahead.block):
        ahead.fill(k)
        assert (ahead.first, ahead.count, len(ahead.rows)) == (k, ahead.block, ahead.block)
        for j, (p, v, Q, omega) in enumerate(ahead.rows):
            s = path.sample(t0 + (k + j) * dt)
            np.testing.assert_allclose(p, s.p, rtol=0, atol=rounding(1.0))
            np.testing.assert_allclose(v, s.v, rtol=0, atol=rounding(1.0))
            if s.Q is None:
                assert Q is NO_Q and omega is NO_OMEGA
            else:
                np.testing.assert_allclose(Q, s.Q, rtol=0, atol=rounding(1.0))
                np.testing.assert_allclose(omega, s.omega, rtol=0, atol=rounding(1.0))
            np.testing.assert_allclose(ahead.samples.sample(j).p, s.p, rtol=0, atol=rounding(1.0))


def test_a_path_without_its_own_sample_many_is_not_called_ahead():
    """A user's path (the base class's sample_many, a loop over its own code) is sampled by each step itself."""
    calls = []

    def fn(t):
        calls.append(t)
        return np.array([t, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])

    ahead = SamplesAhead(FunctionPath(fn), 0.0, 0.01)
    for k in range(1, 200):
        ahead.fill(k)
    assert ahead.samples is None and ahead.rows == [] and calls == []


class Raised(Circle):
    """A user's circle 2 cm higher: it overrides ``sample`` only, so Circle's ``sample_many`` does not follow it."""

    def sample(self, t):
        s = super().sample(t)
        return type(s)(s.p + np.array([0.0, 0.0, 0.02]), s.v, s.Q, s.omega)


def test_a_path_that_overrides_sample_alone_is_sampled_by_its_own_sample():
    """computes_together is False for a subclass overriding ``sample`` alone and for a part path around a user's
    path (whose ``sample_many`` would call the user's code ahead); True for the library's circle and a part path
    around it. A compiled track() and Tracker.step() on the raised circle then follow its own sample: the record's
    targets are its samples, the same as the Python backend's run."""
    from kinredund.sweep.placement import PartPath

    base = CIRCLES["position"]
    raised = Raised(base.center, base.radius, speed=base.speed)
    user = FunctionPath(lambda t: (np.array([t, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])))
    assert base.computes_together() and PartPath(base, np.eye(4)).computes_together()
    assert not raised.computes_together() and not user.computes_together()
    assert not PartPath(user, np.eye(4)).computes_together()
    assert SamplesAhead(PartPath(user, np.eye(4)), 0.0, 0.01).own is False
    robot, _, index, q0 = panda_circle()
    robot = robot.with_task("position")
    from kinredund.ik import solve_ik

    start = solve_ik(robot, raised.sample(0.0).p, index, q0=q0)
    assert start.converged, start.reason
    dt = raised.period / 100
    if compiled.load_core() is not None:
        tracker = Tracker(robot, raised, index, start.q, dt, backend="compiled")
        for _ in range(40):  # beyond the first block sampled ahead
            tracker.step()
        assert tracker.compiled.steps == 40  # all the core's (a parent's samples: steps handed back as jumps)
        np.testing.assert_allclose(robot.kinematics.pose(tracker.q)[1], raised.sample(tracker.t).p, rtol=0,
                                   atol=1e-10)
    runs = {b: track(robot, raised, index, start.q, steps_per_loop=100, backend=b)
            for b in (("compiled", "python") if compiled.load_core() is not None else ("python",))}
    for rec in runs.values():
        heights = rec.p_desired[:, 2]
        np.testing.assert_allclose(heights, [raised.sample(t).p[2] for t in rec.t], rtol=0, atol=rounding(1.0))
    if len(runs) == 2:
        np.testing.assert_allclose(runs["compiled"].q, runs["python"].q, rtol=0, atol=1e-12)


def test_blocks_grow_while_steps_follow_and_start_over_after_a_gap():
    """Steps one after another: blocks of 1, 2, 4, ... steps (sampled ahead from MIN_BLOCK on), up to the block
    size; a step after a gap (a run taken elsewhere) starts over with one step, sampled by the step itself."""
    ahead = SamplesAhead(CIRCLES["frenet"], 0.0, 0.01)
    sizes, k = [], 1
    while len(sizes) < 9:
        ahead.fill(k)
        sizes.append(ahead.count)
        sampled = ahead.count >= MIN_BLOCK
        assert (ahead.samples is not None) == sampled and len(ahead.rows) == sampled * ahead.count
        k += ahead.count
    assert sizes == [1, 2, 4, 8, 16, 32, 64, 64, 64] and BLOCK == 64
    ahead.fill(k + 5)
    assert (ahead.first, ahead.count, ahead.samples) == (k + 5, 1, None)


@pytest.mark.skipif(compiled.load_core() is None and not os.environ.get("CI"), reason="the compiled core is not built")
def test_the_compiled_step_s_point_is_the_evaluation_at_its_point():
    """The point a compiled step leaves (read from the core's row on first use) is the Python evaluation at its
    (q, t): the path sample, J and the task residual; its recorded pose is the forward kinematics at the corrected
    joints. 70 steps cross the first block of samples taken ahead."""
    robot, path, index, q0 = panda_circle()
    tr = Tracker(robot, path, index, q0, path.period / 200, backend="compiled")
    for _ in range(70):
        tr.step()
    pt = tr.stepper.pt
    assert isinstance(pt, compiled.CompiledPoint) and tr.compiled.steps > 60
    ref = tr.stepper.ev.point(np.array(pt.q), pt.t)
    s = path.sample(tr.t)
    assert pt.t == tr.t
    np.testing.assert_allclose(pt.sample.p, s.p, rtol=0, atol=rounding(1.0))
    np.testing.assert_allclose(pt.sample.Q, s.Q, rtol=0, atol=rounding(1.0))
    np.testing.assert_allclose(pt.J, ref.J, rtol=0, atol=rounding(10.0))  # the core's J, another order of sums
    np.testing.assert_allclose(pt.r, ref.r, rtol=0, atol=rounding(1.0))  # the full evaluation, in Python
    Q, p = robot.kinematics.pose(tr.q)
    np.testing.assert_allclose(pt.recorded.pose[0], Q, rtol=0, atol=rounding(1.0))
    np.testing.assert_allclose(pt.recorded.pose[1], p, rtol=0, atol=rounding(1.0))
    np.testing.assert_allclose(pt.recorded.sample.p, s.p, rtol=0, atol=rounding(1.0))
    with pytest.raises(AttributeError):
        pt.not_a_field  # noqa: B018 - the attribute access is the test
    import copy

    twin = copy.copy(pt)  # a copy's slots are copied (the fields read so far); it reads none it lacks by recursion
    np.testing.assert_array_equal(twin.q, pt.q)
