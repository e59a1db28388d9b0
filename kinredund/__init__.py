"""kinredund: kinematic control of redundant manipulators on Pinocchio.

After S. Mathur, *Algorithms for the Kinematic Control of Redundant Manipulators*, M.Eng. thesis,
McGill University, 1989. See the README for the map from thesis chapters to modules and
docs/architecture.md for the layers.

What a user needs is exported here::

    import kinredund as kr

    robot = kr.load_robot("panda")
    index = kr.JointDeviation(robot.home)
    path = kr.Circle(robot.fk(robot.home)[:3, 3] - (0.05, 0, 0), 0.05, 0.1,
                     orientation=robot.fk(robot.home)[:3, :3])
    start = kr.solve_ik(robot, robot.fk(robot.home), index)
    traj = kr.track(robot, path, index, start.q, loops=2)
"""

from importlib.metadata import version as _version

from kinredund import indices, paths, tasks
from kinredund.errors import (
    ChoiceError,
    FrameNotFoundError,
    GeometryError,
    HDTableError,
    JointVectorError,
    KinredundError,
    OptionError,
    PathError,
    SingularityError,
    SolverError,
    TaskError,
    TrackingError,
    UnknownRobotError,
    URDFError,
)
from kinredund.geometry import (
    Clearance,
    DistanceRows,
    Distances,
    PairMatrix,
    Scene,
    check_motion,
    load_scene,
    save_scene,
)
from kinredund.ik import IKResult, check_optimality, solve_ik
from kinredund.indices import CustomIndex, Index, JointDeviation, TimeVaryingReference, mid_range, minimum_norm
from kinredund.kinematics.hd import HDTable
from kinredund.model.loader import known_robots, load_robot
from kinredund.model.robot import Robot, robot_from_hd
from kinredund.paths import (
    AxisPath,
    Circle,
    Ellipse,
    FunctionPath,
    Helix,
    Path,
    PathSample,
    SampledPath,
    read_path_file,
)
from kinredund.planning.cyclic import CyclicPlan, plan
from kinredund.planning.options import PlanOptions
from kinredund.planning.result import PlanResult
from kinredund.tasks import Task, get_task, task_names
from kinredund.tracking import (
    CornerClearance,
    JointLimits,
    PlaneClearance,
    SceneClearance,
    SphereClearance,
    Tracker,
    track,
)
from kinredund.trajectory import Trajectory

__version__ = _version("kinredund")

__all__ = [
    "AxisPath",
    "ChoiceError",
    "Clearance",
    "Circle",
    "CornerClearance",
    "CyclicPlan",
    "CustomIndex",
    "DistanceRows",
    "Distances",
    "Ellipse",
    "FrameNotFoundError",
    "FunctionPath",
    "GeometryError",
    "HDTable",
    "HDTableError",
    "Helix",
    "IKResult",
    "Index",
    "JointDeviation",
    "JointLimits",
    "JointVectorError",
    "KinredundError",
    "OptionError",
    "PairMatrix",
    "Path",
    "PathError",
    "PathSample",
    "PlaneClearance",
    "PlanOptions",
    "PlanResult",
    "SceneClearance",
    "Robot",
    "SampledPath",
    "Scene",
    "SingularityError",
    "SolverError",
    "SphereClearance",
    "Task",
    "TaskError",
    "TrackingError",
    "TimeVaryingReference",
    "Tracker",
    "TrackingError",
    "Trajectory",
    "URDFError",
    "UnknownRobotError",
    "check_motion",
    "check_optimality",
    "get_task",
    "indices",
    "known_robots",
    "load_robot",
    "load_scene",
    "mid_range",
    "minimum_norm",
    "paths",
    "plan",
    "read_path_file",
    "robot_from_hd",
    "save_scene",
    "solve_ik",
    "task_names",
    "tasks",
    "track",
]
