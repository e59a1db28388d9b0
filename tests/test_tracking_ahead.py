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
from kinredund.tracking import Tracker, compiled
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
