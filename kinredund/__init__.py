"""kinredund: kinematic control of redundant manipulators on Pinocchio.

After S. Mathur, *Algorithms for the Kinematic Control of Redundant Manipulators*, M.Eng. thesis,
McGill University, 1989. See the README for the map from thesis chapters to modules.
"""

from kinredund.errors import (
    ChoiceError,
    FrameNotFoundError,
    HDTableError,
    JointVectorError,
    KinredundError,
    PathError,
    SingularityError,
    SolverError,
    TaskError,
    UnknownRobotError,
    URDFError,
)
from kinredund.ik.solve import IKResult, check_optimality, solve_ik
from kinredund.kinematics.hd import HDTable
from kinredund.model.robot import Robot, known_robots, load_robot, robot_from_hd

__version__ = "0.1.0"

__all__ = [
    "ChoiceError",
    "FrameNotFoundError",
    "HDTable",
    "IKResult",
    "HDTableError",
    "JointVectorError",
    "KinredundError",
    "PathError",
    "Robot",
    "SingularityError",
    "SolverError",
    "TaskError",
    "URDFError",
    "UnknownRobotError",
    "check_optimality",
    "known_robots",
    "load_robot",
    "robot_from_hd",
    "solve_ik",
]
