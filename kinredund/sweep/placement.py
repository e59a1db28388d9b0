"""Part placements: poses of the part frame in the robot's base frame, and a path carried by the part.

A placement is a 4x4 homogeneous transform T = [[R, o], [0, 1]] of the part frame in the base frame
(the world of the robot model) [m]. :func:`grid` lays placements out over position and yaw (rotation
about the base z axis); any list of 4x4 poses works too (:func:`check_placements`).

:class:`PartPath` is a path given in the part frame, seen from the base: positions p -> R p + o,
velocities v -> R v, orientations Q -> R Q and angular velocities omega -> R omega (the part does not
move while the path runs, so the twist only turns with it).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from kinredund.errors import KinredundError, PathError, check_array, check_size
from kinredund.paths import Path, PathSample
from kinredund.paths.base import Samples


class PlacementError(KinredundError, ValueError):
    """A placement that is not a 4x4 rigid transform, or a grid axis that is not a list of finite numbers."""


def placement_pose(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    """The 4x4 pose of a part at (x, y, z) [m], turned by ``yaw`` [rad] about the base z axis."""
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = (x, y, z)
    return T


def _axis(values, name: str) -> np.ndarray:
    """A grid axis: one finite number, or a non-empty 1-D sequence of them."""
    arr = np.atleast_1d(np.asarray(values, dtype=float)) if not isinstance(values, (str, bytes)) else None
    if arr is None or arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
        raise PlacementError(f"grid axis {name} must be a finite number or a non-empty list of them, got {values!r}")
    return arr


def grid(x=0.0, y=0.0, z=0.0, yaw=0.0) -> np.ndarray:
    """Placements on the grid x by y by z by yaw (each a number or a list of values), shape (N, 4, 4).

    Args:
        x, y, z: the part frame's origin in the base frame [m].
        yaw: the part's rotation about the base z axis [rad].

    Returns:
        The poses in ``itertools.product`` order: x outermost, yaw innermost (placement k of a grid of
        sizes (nx, ny, nz, nyaw) is at ``np.unravel_index(k, (nx, ny, nz, nyaw))``).

    Raises:
        PlacementError: an axis that is not finite numbers, or more placements than
            :data:`~kinredund.errors.MAX_PLACEMENTS` (refused before any is built).
    """
    axes = [_axis(v, n) for v, n in ((x, "x"), (y, "y"), (z, "z"), (yaw, "yaw"))]
    sizes = [len(a) for a in axes]
    check_size(math.prod(sizes), f"the grid's placements ({' x '.join(map(str, sizes))})", "placements",
               PlacementError)
    return np.array([placement_pose(*map(float, v)) for v in itertools.product(*axes)])


def check_placements(placements) -> np.ndarray:
    """The placements as a float array (N, 4, 4) of rigid transforms, or PlacementError saying which is not.

    A rotation block must be orthonormal with determinant +1 (to 1e-9) and the last row [0, 0, 0, 1].
    """
    try:
        T = np.asarray(placements, dtype=float)
    except (TypeError, ValueError) as err:
        raise PlacementError(f"placements must be a list of 4x4 poses, got {type(placements).__name__}") from err
    if T.ndim == 2:
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4) or T.shape[0] == 0:
        raise PlacementError(f"placements must be a non-empty list of 4x4 poses, got an array of shape {T.shape}")
    check_size(T.shape[0], "placements", "placements", PlacementError)
    bad = ~np.all(np.isfinite(T), axis=(1, 2))
    R = T[:, :3, :3]
    err = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2), initial=0.0)
    bad |= ~(err <= 1e-9) | ~(np.linalg.det(R) > 0) | ~np.all(T[:, 3] == [0.0, 0.0, 0.0, 1.0], axis=1)
    if np.any(bad):
        k = int(np.flatnonzero(bad)[0])
        raise PlacementError(f"placement {k} is not a rigid transform (rotation orthonormal with det +1, last row "
                             f"0 0 0 1): {T[k].tolist()}")
    return T


def pose_coordinates(T: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, yaw) of a placement: its origin [m] and the angle of its x axis about base z [rad]."""
    return float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), math.atan2(float(T[1, 0]), float(T[0, 0]))


class PartPath(Path):
    """A path given in a part frame, seen from the base with the part at ``pose`` (4x4).

    Args:
        path: any :class:`kinredund.paths.Path`, in part coordinates.
        pose: the part frame in the base frame (a rigid 4x4 transform) [m].
    """

    def __init__(self, path: Path, pose):
        if not isinstance(path, Path):
            raise PathError(f"a part path wraps a kinredund.paths.Path, got {type(path).__name__}")
        T = check_placements(check_array(pose, (4, 4), "part pose", PlacementError))[0]
        self.path = path
        self.pose = T
        self.period = path.period
        self.has_orientation = path.has_orientation
        self._R, self._o = T[:3, :3].copy(), T[:3, 3].copy()

    def sample(self, t: float) -> PathSample:
        s = self.path.sample(t)
        R = self._R
        p = R @ s.p + self._o
        if s.Q is None:
            return PathSample(p, R @ s.v)
        return PathSample(p, R @ s.v, R @ s.Q, R @ s.omega)

    def computes_together(self) -> bool:
        """As :meth:`Path.computes_together`, and so does the wrapped path (a caller's path is not called ahead)."""
        return super().computes_together() and self.path.computes_together()

    def sample_many(self, times: list[float]) -> Samples:
        """:meth:`sample` at each of ``times`` [s]: the wrapped path's samples together (its own
        ``sample_many``), turned and moved by the pose as arrays (row-wise R x, the same dot products)."""
        s = self.path.sample_many(times)
        R, Rt = self._R, self._R.T
        P, V = s.p @ Rt + self._o, s.v @ Rt
        if s.Q is None:
            return Samples(P, V)
        return Samples(P, V, R @ s.Q, s.omega @ Rt)

    def __repr__(self) -> str:
        return f"PartPath({self.path!r}, pose={self.pose.tolist()})"


def part_circle(robot, radius: float = 0.1, speed: float = 0.1, normal=(0.0, 0.0, 1.0), axis_x=None) -> Path:
    """A circle of ``radius`` [m] about the part frame's origin, at ``speed`` [m/s], about ``normal``.

    Tasks that hold an orientation (pose, axis) hold the tool orientation the robot has at its home
    configuration (as if the part sat unturned at the base), so the tool turns with the part's yaw.
    """
    from kinredund.paths import Circle
    from kinredund.tasks import get_task

    Q = robot.fk(robot.home)[:3, :3] if get_task(robot.task).has_orientation else None
    return Circle(np.zeros(3), radius, speed, normal=tuple(normal), axis_x=axis_x, orientation=Q)


def panda_part_circle(robot=None):
    """The Panda benchmark circle (:func:`kinredund.problems.panda_circle`) as a part path.

    Returns:
        (robot, path, index, pose): the path in the part frame (the vertical 0.1 m circle through the
        home pose's point P, about the part origin), the index z = 1/2 ||q - q_home||^2 and the part pose
        that puts the circle where the benchmark has it.
    """
    from kinredund.problems import panda_circle

    robot, world, index, _ = panda_circle(robot)
    part = part_circle(robot, world.radius, world.speed, normal=(1.0, 0.0, 0.0), axis_x=(0.0, 1.0, 0.0))
    return robot, part, index, placement_pose(*world.center)
