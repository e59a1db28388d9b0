"""What a playback shows, in plain numpy: frames, obstacle shape and camera (no meshcat here).

The meshcat side (:mod:`kinredund.ui.viz._meshcat`) turns these numbers into scene commands. Keeping
them apart lets the tests check the geometry without a viewer. Obstacles are the planner's own
(:mod:`kinredund.planning.obstacles`, read from ``traj.meta["obstacle"]`` by ``obstacle_from_dict``);
only their drawing geometry lives here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import TaskError, check_positive
from kinredund.planning.obstacles import EllipseObstacle, EllipticCylinder, Obstacle, obstacle_from_dict
from kinredund.trajectory import Trajectory

#: Vertical field of view of meshcat's default camera [deg].
CAMERA_FOV_DEG = 75.0
#: The default cap on the number of animation frames of one playback.
MAX_FRAMES = 900


@dataclass(frozen=True)
class Frames:
    """Joint values resampled for playback.

    Attributes:
        times: playback clock of each frame [s], starting at 0, shape (F,).
        q: joint values of each frame, shape (F, n) [rad or m].
        p: end-effector positions of each frame (interpolated from ``traj.p``), shape (F, 3) [m].
    """

    times: np.ndarray
    q: np.ndarray
    p: np.ndarray


def read_obstacle(traj: Trajectory) -> Obstacle | None:
    """The obstacle of ``traj.meta["obstacle"]`` (as ``Obstacle.to_dict`` writes it), or None.

    Raises:
        ChoiceError: an unknown kind; TaskError: a missing or bad value (``obstacle_from_dict``).
    """
    raw = traj.meta.get("obstacle") if isinstance(traj.meta, dict) else None
    return None if raw is None else obstacle_from_dict(raw)


def obstacle_height(obstacle: Obstacle) -> float:
    """The drawn height [m]: :attr:`EllipticCylinder.height`, or :attr:`EllipseObstacle.thickness`.

    Raises:
        TaskError: an obstacle of another type (the message lists the drawable ones).
    """
    if isinstance(obstacle, EllipticCylinder):
        return float(obstacle.height)
    if isinstance(obstacle, EllipseObstacle):
        return float(obstacle.thickness)
    raise TaskError(f"playback draws EllipseObstacle and EllipticCylinder, got {type(obstacle).__name__}")


def obstacle_frame(obstacle: Obstacle) -> np.ndarray:
    """Rotation whose columns are the major axis, the minor axis (Eqs. 6.4-6.5) and the cylinder axis +Z."""
    e1, e2 = obstacle.axes()
    return np.array([[e1[0], e2[0], 0.0], [e1[1], e2[1], 0.0], [0.0, 0.0, 1.0]])


def unit_cylinder_transform(obstacle: Obstacle) -> np.ndarray:
    """The 4x4 transform that maps meshcat's unit cylinder (radius 1, height 1, axis y) onto ``obstacle``.

    The matrix is ``R Q diag(a, height, b)``: the scale acts in the cylinder's own axes and Q (a
    proper rotation) sends its y axis to the obstacle's axis, so the matrix decomposes cleanly.
    """
    Q = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # x->major, y->axis, z->-minor
    T = np.eye(4)
    T[:3, :3] = obstacle_frame(obstacle) @ Q @ np.diag([obstacle.a, obstacle_height(obstacle), obstacle.b])
    T[:3, 3] = obstacle.center
    return T


def obstacle_outline(obstacle: Obstacle, count: int = 64) -> np.ndarray:
    """Points on the ellipse (Eq. 6.19's boundary) at the height of the centre, shape (count, 3) [m]."""
    xy, _ = obstacle.boundary(np.linspace(0.0, 2.0 * np.pi, count))
    return np.column_stack([xy, np.full(count, obstacle.center[2])])


def obstacle_corner_points(obstacle: Obstacle) -> np.ndarray:
    """Points that bound the drawn obstacle (its outline at both ends of the cylinder) [m]."""
    ring = obstacle_outline(obstacle, 32)
    half = np.array([0.0, 0.0, 0.5 * obstacle_height(obstacle)])
    return np.vstack([ring + half, ring - half])


def _interp_rows(t_src: np.ndarray, values: np.ndarray, t_out: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of ``values`` (rows at ``t_src``) at ``t_out``."""
    if len(t_src) == 1:
        return np.repeat(values[:1], len(t_out), axis=0)
    k = np.clip(np.searchsorted(t_src, t_out, side="right") - 1, 0, len(t_src) - 2)
    w = ((t_out - t_src[k]) / (t_src[k + 1] - t_src[k]))[:, None]
    return (1.0 - w) * values[k] + w * values[k + 1]


def resample(
    traj: Trajectory, fps: float = 30.0, max_frames: int = MAX_FRAMES, realtime: bool = True
) -> Frames:
    """Frames for playback at ``fps``, at most ``max_frames`` of them.

    With ``realtime`` the playback clock is the trajectory's time (a 5 s loop plays in 5 s); the
    frames are spread evenly over it, fewer than ``fps`` per second if the cap requires. Without it,
    every stored step (or an even selection of at most ``max_frames``) is one frame at ``fps``.

    Raises:
        KinredundError: ``fps`` not positive or ``max_frames`` < 2 (as :class:`TaskError`).
    """
    check_positive(fps, "fps", TaskError)
    if int(max_frames) < 2:
        raise TaskError(f"max_frames must be at least 2, got {max_frames!r}")
    t = np.asarray(traj.t, dtype=float)
    q = np.asarray(traj.q, dtype=float)
    p = np.asarray(traj.p, dtype=float)
    if len(t) == 1:
        return Frames(np.zeros(1), q[:1].copy(), p[:1].copy())
    if realtime:
        duration = float(t[-1] - t[0])
        count = int(min(max_frames, math.ceil(duration * fps) + 1))
        count = max(count, 2)
        clock = np.linspace(0.0, duration, count)
        src = t[0] + clock
    else:
        count = int(min(max_frames, len(t)))
        idx = np.linspace(0.0, len(t) - 1, count)
        src = np.interp(idx, np.arange(len(t)), t)
        clock = np.arange(count) / float(fps)
    return Frames(clock, _interp_rows(t, q, src), _interp_rows(t, p, src))


def camera_view(points: np.ndarray, planar: bool) -> tuple[np.ndarray, np.ndarray]:
    """Where to look from: the centre of ``points`` and the camera's offset from it [m], world axes.

    The offset's length fits a sphere around all points into the vertical field of view; planar
    tasks are seen from above, at a slant, spatial ones from the front right and above.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    center = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.05)
    direction = np.array([0.25, -0.6, 1.0]) if planar else np.array([1.0, -1.3, 0.8])
    direction /= np.linalg.norm(direction)
    distance = 1.1 * radius / math.sin(math.radians(0.5 * CAMERA_FOV_DEG))
    return center, distance * direction


def to_camera_axes(offset: np.ndarray) -> list[float]:
    """World z-up offset -> the y-up axes of meshcat's ``/Cameras/default/rotated`` frame."""
    dx, dy, dz = (float(v) for v in offset)
    return [dx, dz, -dy]


@dataclass(frozen=True)
class FloorGrid:
    """A square grid on z = 0: centre (x, y) [m], half side [m] and line spacing [m]."""

    center: np.ndarray
    half: float
    spacing: float


def nice_step(value: float) -> float:
    """The number of the form 1, 2 or 5 times a power of ten nearest above ``value`` (> 0)."""
    exponent = math.floor(math.log10(value))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10.0**exponent >= value * (1 - 1e-12):
            return m * 10.0**exponent
    return 10.0 ** (exponent + 1)


def floor_grid(points: np.ndarray, lines_per_half: int = 6) -> FloorGrid:
    """A floor grid under ``points`` [m]: their footprint on z = 0 with a margin of 40 %, in round steps.

    The spacing is a 1-2-5 step giving about ``lines_per_half`` lines on each side of the centre; the
    centre sits on a grid line.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    reach = max(0.5 * float((hi - lo).max()) * 1.4, 0.05)
    spacing = nice_step(reach / lines_per_half)
    center = np.round(0.5 * (lo + hi) / spacing) * spacing
    half = math.ceil((reach + float(np.abs(0.5 * (lo + hi) - center).max())) / spacing) * spacing
    return FloorGrid(center, half, spacing)
