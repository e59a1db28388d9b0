"""A control loop with kinredund's Tracker: the Panda follows a 10 cm circle, one step per tick.

Run it: ``python examples/control_loop.py``. Each ``tracker.step()`` advances the tracker by ``dt``:
the joints ``tracker.q`` stay on the circle and at the optimum of the index (the distance from the home
pose), and after a whole loop they come back where they started.
"""

import numpy as np

from kinredund import load_robot
from kinredund.indices import JointDeviation
from kinredund.paths import Circle
from kinredund.tracking import Tracker

robot = load_robot("panda")
q0 = robot.home.copy()
T0 = robot.fk(q0)
# a 0.1 m circle through the hand's home position, in the y-z plane, the hand keeping its orientation
circle = Circle(T0[:3, 3] - [0.0, 0.1, 0.0], 0.1, 0.1, normal=(1.0, 0.0, 0.0), axis_x=(0.0, 1.0, 0.0),
                orientation=T0[:3, :3])
steps = 200
tracker = Tracker(robot, circle, JointDeviation(q0), q0, dt=circle.period / steps)

worst = 0.0
for _ in range(steps):
    tracker.step()  # in a real loop: send tracker.q (or tracker.qdot) to the robot here
    worst = max(worst, float(np.linalg.norm(robot.fk(tracker.q)[:3, 3] - circle(tracker.t).p)))

print(f"t = {tracker.t:.3f} s after {steps} steps: largest position error {worst:.2e} m, "
      f"joints {np.abs(tracker.q - q0).max():.2e} rad from where they started")
print("ok")
