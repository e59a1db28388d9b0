"""The benchmark path of the Panda (issue 8): a 0.1 m circle through the home pose.

The circle lies in the vertical plane facing the robot (normal +x), starts at the home pose's point P
and runs counter-clockwise at ``speed``; the orientation is held at the home orientation, or turns
about the tool's z axis by ``wrist_amplitude`` sin(2 pi t / T) (the +-15 deg variant). The index is
z = 1/2 ||q - q_home||^2, whose constrained minimum at the start is the home configuration itself.
"""

from __future__ import annotations

import numpy as np

from kinredund.indices import JointDeviation
from kinredund.model.loader import load_robot
from kinredund.model.robot import Robot
from kinredund.paths import Circle


def panda_circle(robot: Robot | None = None, radius: float = 0.1, speed: float = 0.1,
                 wrist_amplitude: float = 0.0):
    """(robot, path, index, q0) for the Panda benchmark; ``wrist_amplitude`` [rad] (0 or 15 deg)."""
    robot = robot or load_robot("panda")
    q0 = robot.home.copy()
    T0 = robot.fk(q0)
    Q0, p0 = T0[:3, :3], T0[:3, 3]
    path = Circle(p0 - radius * np.array([0.0, 1.0, 0.0]), radius, speed, normal=(1.0, 0.0, 0.0),
                  axis_x=(0.0, 1.0, 0.0), orientation=Q0, roll_amplitude=wrist_amplitude)
    return robot, path, JointDeviation(q0), q0
