"""The Panda draws a 10 cm circle with its hand, holding the orientation, 20 loops: the joints come back
to where they started, loop after loop, on the optimum of z = 1/2 ||q - q_home||^2 all along.

Run: python examples/panda_circle.py
"""

import numpy as np

import kinredund as kr

robot = kr.load_robot("panda")
T = robot.fk(robot.home)
path = kr.Circle(T[:3, 3] - np.array([0.05, 0.0, 0.0]), 0.05, 0.1, orientation=T[:3, :3])
index = kr.JointDeviation(robot.home)
start = kr.solve_ik(robot, path(0.0), index)
traj = kr.track(robot, path, index, start.q, loops=20)

print(f"joint drift after each of 20 loops <= {traj.loop_drift.max():.1e} rad")
print(f"position error <= {traj.position_error.max():.1e} m, orientation (vect) <= {traj.vect_error.max():.1e}")
print(f"normality residual (first-order optimality) <= {traj.normality_residual.max():.1e}")
assert traj.loop_drift.max() < 1e-10 and traj.position_error.max() < 1e-10
traj.save_json("panda_circle.json")
print("wrote panda_circle.json (kinredund play panda_circle.json --html replay.html); ok")
