"""Switching times located on the corrected path where the optimum moves fast within a step (issue 27).

Named case ``panda_fast_bound``: the second task of ``python benchmarks/random_obstacles.py --robot panda``
(seed 0): a 9.1 cm circle at 0.1 m/s, a sphere of 9.0 cm where the within-limits optimum's elbow (the origin
of panda_link4) passes, held by a SphereClearance. With the sphere's row active, the constrained optimum races
towards joint 1's lower bound (rates of 24 rad/s at t = 0.459 s: the joints cover 0.4 rad within the next step
of 0.029 s) and reaches it 0.0024 s into that step. The switch locator evaluated the path at a trial time by
one Euler prediction from the step's start plus the corrector; across that step the prediction is 0.4 rad off
and the corrector diverged (R singular at |q| ~ 1e5), so the run stopped as ``switch_not_resolved`` although
the switch is there to be located. Now the locator follows the path in pieces where one prediction does not
reach it (``SwitchLocation._corrected_to``), locates joint 1's switch and finds the honest end: with the
row and the bound active, R is singular (smallest singular value 3e-9: the constrained optimum is not strongly
stable there). The race is its sign: there the task's rows and the sphere's row are nearly dependent (the
smallest singular value of [J; G] is 2.1e-3 over all joints, 8.4e-4 with joint 1 fixed, against 0.96 for the
largest), the issue's "two active constraints and the task become dependent".
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import robot

from kinredund.errors import TrackingError
from kinredund.paths import Circle
from kinredund.tracking import SphereClearance, track
from kinredund.tracking.switches import SwitchLocation

#: the circle: center [m], radius [m], plane normal, start direction; the sphere: center [m], radius [m]; the
#: within-limits optimum at t = 0 [rad] (solve_ik(..., bounds=True)), as random_obstacles.py drew them
CIRCLE = ([-0.01861674442175671, -0.6498221127086985, 0.7399548410023404], 0.09135389615674927,
          (0.480321379031315, 0.6457754601469505, 0.5935195261467395),
          (-0.5466260801338063, 0.7496008233472453, -0.3732271883915765))
SPHERE = ([-0.06621909592104155, -0.1473994008331781, 0.6408812667851804], 0.08981621351436472)
Q0 = [-0.7668329855859277, -0.06835766330787763, -0.8846735249684328, -1.5950518519315748, -0.06273376096059928,
      2.1738870289305576, 0.7849999999999999]


def stop():
    from kinredund.indices import JointDeviation

    r = robot("panda", "position")
    center, radius, normal, axis_x = CIRCLE
    path = Circle(np.array(center), radius, 0.1, normal=normal, axis_x=axis_x)
    sphere = SphereClearance(r, "panda_link4", *SPHERE)
    with pytest.raises(TrackingError) as info:
        track(r, path, JointDeviation(r.home.copy()), np.array(Q0), loops=1, steps_per_loop=200,
              constraints=[sphere], diagnostics=False)
    return r, path, sphere, info.value


def test_a_fast_switch_is_located_and_the_stop_named(monkeypatch):
    located = []
    switch = SwitchLocation._switch

    def spy(self, joint, kind):
        located.append((float(self.t), joint, kind, float(self.q[joint])))
        switch(self, joint, kind)

    monkeypatch.setattr(SwitchLocation, "_switch", spy)
    r, path, sphere, err = stop()
    assert err.cause == "collision"
    assert err.watched["underlying_cause"] == "not_strongly_stable", str(err)  # was switch_not_resolved
    t, joint, kind, value = located[-1]  # joint 1 met its lower bound inside the last step, and was fixed there
    assert (joint, kind) == (0, "lower") and abs(value - r.lower[0]) <= 1e-10  # Brent's time, 1e-14 s x 24 rad/s
    assert err.t < t < err.t + float(path.period) / 200
    q = np.asarray(err.q)  # the last good point: on the path, inside the limits, clear
    assert np.linalg.norm(r.fk(q)[:3, 3] - path(err.t).p) <= 1e-10
    assert np.all(q >= r.lower) and np.all(q <= r.upper)
    assert sphere.values(q)[0] >= -1e-9
