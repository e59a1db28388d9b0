"""A 6-axis UR5 with an axially symmetric tool: the tool-axis task (m = 5) leaves the spin about the
axis free, so the arm is redundant by one and the cyclic scheme applies. The tool is held normal to
the plane of a 12 cm circle for 10 loops.

Run: python examples/tool_axis_ur5.py
"""

import numpy as np

import kinredund as kr
from kinredund.tasks.axis import frame_with_axis

robot = kr.load_robot("ur5")  # its default task is the tool axis (m = 5): redundant by one
q_seed = robot.home  # a regular pose (the URDF's zero pose is singular)
p0 = robot.fk(q_seed)[:3, 3]
path = kr.Circle(p0 - np.array([0.06, 0.0, 0.0]), 0.06, 0.12, orientation=frame_with_axis([0.0, 0.0, -1.0]))
index = kr.JointDeviation(q_seed + 0.2)
start = kr.solve_ik(robot, path(0.0), index, q0=q_seed)
traj = kr.track(robot, path, index, start.q, loops=10)
spin = np.unwrap([np.arctan2(*robot.fk(q)[1::-1, 0]) for q in traj.q[:201:10]])
print(f"drift {traj.loop_drift.max():.1e} rad, position error {traj.position_error.max():.1e} m, "
      f"axis error {traj.axis_error.max():.1e} rad, spin range over a loop {np.ptp(spin):.3f} rad")
assert traj.loop_drift.max() < 1e-10 and traj.axis_error.max() < 1e-10
print("ok")
