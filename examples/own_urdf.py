"""Your own arm from a URDF file: here a 4-joint arm written on the spot, tracking a point task
(m = 3, one degree of redundancy) around an ellipse-shaped loop given as a function of time.

Run: python examples/own_urdf.py
"""

import tempfile
from pathlib import Path

import numpy as np

import kinredund as kr

URDF = """<?xml version="1.0"?>
<robot name="my_arm">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="l3"/><link name="l4"/><link name="tool"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.3"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 0.1"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="10" velocity="2"/></joint>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5" effort="10" velocity="2"/></joint>
  <joint name="j4" type="revolute"><parent link="l3"/><child link="l4"/><origin xyz="0 0 0.35"/>
    <axis xyz="0 1 0"/><limit lower="-2.5" upper="2.5" effort="10" velocity="2"/></joint>
  <joint name="tool_joint" type="fixed"><parent link="l4"/><child link="tool"/><origin xyz="0 0 0.15"/></joint>
</robot>
"""

with tempfile.TemporaryDirectory() as folder:
    urdf = Path(folder) / "my_arm.urdf"
    urdf.write_text(URDF)
    robot = kr.load_robot(urdf, ee_frame="tool", task="position")

q_seed = np.array([0.2, 0.4, 0.6, 0.5])
c = robot.fk(q_seed)[:3, 3]
w = 2 * np.pi / 4.0  # one loop in 4 s


def ellipse(t):
    """The loop's point [m] and velocity [m/s] at time t [s] (a position path: no orientation)."""
    p = c + np.array([0.08 * (np.cos(w * t) - 1.0), 0.04 * np.sin(w * t), 0.0])
    v = np.array([-0.08 * w * np.sin(w * t), 0.04 * w * np.cos(w * t), 0.0])
    return p, v


path = kr.FunctionPath(ellipse, period=4.0)
index = kr.mid_range(robot.lower, robot.upper)  # stay near the middle of the joint ranges
start = kr.solve_ik(robot, path(0.0), index, q0=q_seed)
traj = kr.track(robot, path, index, start.q, loops=5)
print(f"drift {traj.loop_drift.max():.1e} rad, position error {traj.position_error.max():.1e} m")
assert traj.loop_drift.max() < 1e-10 and traj.position_error.max() < 1e-10
print("ok")
