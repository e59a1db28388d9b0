"""The stepper's state as one value (kinredund.tracking.state): what a rejected step is put back to.

The step control and the limits' switch resolution undo a step by assigning a saved ``stepper.state``; these
tests check that the record holds everything a step changes (so nothing drifts out of it, as two name lists
once did), that it is frozen, and that stepping from a restored state repeats the run bit for bit.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_tracking_limits import case

from kinredund.tracking import Tracker
from kinredund.tracking.state import ConstrainedState, StepState

#: attributes a step sets that are not state: derived from the state (the free rows of R, rebuilt when a
#: state is assigned) or scratch of the step in progress (the predictor's point, set before it is read)
DERIVED = {"_free_idx", "_sel", "q_pred"}


@pytest.mark.parametrize("limits", [True, False])
def test_every_attribute_a_step_changes_is_in_the_state(limits):
    r, path, index, q0 = case("panda_elbow_circle")  # meets a bound and leaves it within a loop
    s = Tracker(r, path, index, q0, path.period / 100, limits=limits).stepper
    fields = {f.name for f in dataclasses.fields(s.state_class)}
    assert s.state_class is (ConstrainedState if limits else StepState)
    changed = set()
    for _ in range(100):
        before = dict(vars(s))
        s.step()
        changed |= {k for k, v in vars(s).items() if k not in before or before[k] is not v}
    assert changed - fields <= DERIVED
    if limits:
        assert s.switches  # the loop did switch: the active set's part of the state was exercised


def test_state_is_frozen_and_a_restored_state_repeats_the_run_exactly():
    r, path, index, q0 = case("panda_elbow_circle")
    s = Tracker(r, path, index, q0, path.period / 100).stepper
    for _ in range(20):
        s.step()
    saved = s.state
    with pytest.raises(dataclasses.FrozenInstanceError):
        saved.q = None
    first = []
    for _ in range(40):  # through a switch of the active set
        s.step()
        first.append((s.t, s.q, s.lam, s.fixed))
    assert len(s.switches) > len(saved.switches)
    s.state = saved
    assert s.t == saved.t and s.k == saved.k and len(s.switches) == len(saved.switches)
    for t, q, lam, fixed in first:
        s.step()
        assert s.t == t and np.array_equal(s.q, q) and np.array_equal(s.lam, lam) and np.array_equal(s.fixed, fixed)
