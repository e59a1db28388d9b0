"""The benchmark path of the Panda (issue 8): a 0.1 m circle through the home pose.

The circle lies in the vertical plane facing the robot (normal +x), starts at the home pose's point P
and runs counter-clockwise at ``speed``; the orientation is held at the home orientation, or turns
about the tool's z axis by ``wrist_amplitude`` sin(2 pi t / T) (the +-15 deg variant). The index is
z = 1/2 ||q - q_home||^2, whose constrained minimum at the start is the home configuration itself.

Also random bounded problems of the joint-level IK with an index (issue 28, :func:`near_seed_ik_problems`), on which
the IK's two backends are compared (tests/test_ik_compiled.py, benchmarks/ik.py).
"""

from __future__ import annotations

import numpy as np

from kinredund.indices import JointDeviation, mid_range
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


def near_seed_ik_problems(robot: Robot, n: int, seed: int, spread: float = 0.3):
    """n random IK problems (target 4x4 pose, seed q0, index), drawn from ``np.random.default_rng(seed)``: the pose
    of a configuration uniform within the limits, q0 that configuration plus normal noise of sd ``spread`` [rad or m]
    clipped into the limits, and the index in turn mid-range, a JointDeviation with a random reference (up to 1
    beyond the limits) and random weights, one with its reference 1 beyond the upper limits (the last two hold
    joints on their limits in a bounded solve)."""
    rng = np.random.default_rng(seed)
    mid = mid_range(robot.lower, robot.upper)
    for k in range(n):
        qt = rng.uniform(robot.lower, robot.upper)
        q0 = np.clip(qt + rng.normal(0.0, spread, robot.nq), robot.lower, robot.upper)
        index = [mid,
                 JointDeviation(rng.uniform(robot.lower - 1.0, robot.upper + 1.0), rng.uniform(0.2, 2.0, robot.nq)),
                 JointDeviation(robot.upper + 1.0, np.ones(robot.nq))][k % 3]
        yield robot.fk(qt), q0, index
