"""Starting-configuration problems of Examples 4.1-4.3 (Chapter 4.3): min z s.t. g(theta) = x at the
first point of each path.

The thesis finds each starting configuration as the constrained minimum of the example's index at the
path's first point (with QUADMIN; here :func:`kinredund.ik.solve_ik`, multi-start for the global
minimum). Each function returns ``(robot, target, index)`` ready for ``solve_ik(robot, target, index)``,
the target taken from :func:`example_path` at t = 0; the parameters are those adopted in
``docs/thesis_readings.md``.

Example::

    robot, target, index = example_4_1_start()
    start = solve_ik(robot, target, index, starts=20)
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import ChoiceError
from kinredund.indices import Index, JointDeviation, mid_range, minimum_norm
from kinredund.model.loader import load_robot
from kinredund.model.robot import Robot
from kinredund.paths import Circle, Path

EXAMPLES = ("4.1", "4.2", "4.3")


def example_path(name: str) -> Path:
    """The path of Example 4.1, 4.2 or 4.3.

    Raises:
        ChoiceError: another name.
    """
    if name == "4.1":
        return Circle((3.0, 3.0), 0.8, 1.0)
    if name == "4.2":
        return Circle((1.5, 1.5), 0.8, 1.0)
    if name == "4.3":
        return Circle((0.16, 0.0, 0.36), 0.14, 1.0, normal=(1.0, 0.0, 0.0), axis_x=(0.0, 1.0, 0.0), frenet=True)
    raise ChoiceError("example", name, EXAMPLES)


def _first_point(name: str) -> np.ndarray:
    """The target at the path's start: (x, y) [m] for the planar examples, else the 4x4 pose."""
    s = example_path(name).sample(0.0)
    if s.Q is None:
        return s.p[:2].copy()
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = s.Q, s.p
    return T


def example_4_1_start() -> tuple[Robot, np.ndarray, Index]:
    """Example 4.1: planar 3R (links 2 m), circle of radius 0.8 m about (3, 3) m starting at
    (3.8, 3) m; z = 1/2 sum theta_i^2, Eq. (4.45)."""
    return load_robot("planar3r"), _first_point("4.1"), minimum_norm(3)


def example_4_2_start() -> tuple[Robot, np.ndarray, Index]:
    """Example 4.2: the same arm, circle of radius 0.8 m about (1.5, 1.5) m starting at (2.3, 1.5) m;
    z = 1/2 [(theta2 - pi/2)^2 + (theta3 - pi)^2], Eq. (4.46) ((pi/2, pi) is isotropic)."""
    index = JointDeviation(np.array([0.0, np.pi / 2, np.pi]), weights=np.array([0.0, 1.0, 1.0]))
    return load_robot("planar3r"), _first_point("4.2"), index


def example_4_3_start() -> tuple[Robot, np.ndarray, Index]:
    """Example 4.3: CYBOTECH P-15 (Table 4.1), pose at beta = 0 of the circle in the plane x = 0.16 m:
    p = (0.16, 0.14, 0.36) m, Q_d = [e_n, e_t, e_n x e_t] = [[0, 0, 1], [1, 0, 0], [0, 1, 0]] (Eq. 4.47);
    z = 1/2 sum_{i<=4} (theta_i - mid_i)^2 over the limits of axes 1-4, Eq. (4.49).

    Returns the target as a 4x4 homogeneous pose [m].
    """
    robot = load_robot("cybotech_p15")
    return robot, _first_point("4.3"), mid_range(robot.lower, robot.upper, joints=[0, 1, 2, 3])
