"""What a playback shows, in plain numpy: frames, obstacle shape and camera (no meshcat here).

The meshcat side (:mod:`kinredund.viz._meshcat`) turns these numbers into scene commands. Keeping
them apart lets the tests check the geometry without a viewer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import JointVectorError, PathError, TaskError, check_choice
from ..trajectory import Trajectory

#: Obstacle kinds that ``traj.meta["obstacle"]`` may name.
OBSTACLE_KINDS = ("ellipse", "elliptic_cylinder")
OBSTACLE_KEYS = "kind, center, a, b, angle (default 0), axis (default [0, 0, 1]), height"
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


@dataclass(frozen=True)
class Obstacle:
    """An elliptic obstacle: a flat ellipse (planar tasks) or an elliptic cylinder.

    Attributes:
        kind: ``ellipse`` or ``elliptic_cylinder``.
        center: centre [m], shape (3,).
        a, b: semi-axes [m] (a along the major axis).
        angle: angle of the major axis about ``axis`` from the x axis [rad].
        axis: unit vector of the cylinder's axis (the ellipse's normal).
        height: the cylinder's height [m] (for an ellipse, the drawn thickness).
    """

    kind: str
    center: np.ndarray
    a: float
    b: float
    angle: float
    axis: np.ndarray
    height: float

    def frame(self) -> np.ndarray:
        """Rotation whose columns are the major axis, the minor axis and the cylinder axis."""
        e3 = self.axis
        major = np.array([math.cos(self.angle), math.sin(self.angle), 0.0])
        major = major - e3 * float(major @ e3)
        if np.linalg.norm(major) < 1e-9:  # axis along x/y: measure the angle from the z axis instead
            major = np.array([0.0, 0.0, 1.0]) - e3 * e3[2]
        e1 = major / np.linalg.norm(major)
        return np.column_stack([e1, np.cross(e3, e1), e3])

    def unit_cylinder_transform(self) -> np.ndarray:
        """The 4x4 transform that maps meshcat's unit cylinder (radius 1, height 1, axis y) onto the obstacle.

        The matrix is ``R Q diag(a, height, b)``: the scale acts in the cylinder's own axes and Q (a
        proper rotation) sends its y axis to the obstacle's axis, so the matrix decomposes cleanly.
        """
        Q = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # x->major, y->axis, z->-minor
        T = np.eye(4)
        T[:3, :3] = self.frame() @ Q @ np.diag([self.a, self.height, self.b])
        T[:3, 3] = self.center
        return T

    def outline(self, count: int = 64) -> np.ndarray:
        """Points on the ellipse through the centre, shape (count, 3) [m]."""
        s = np.linspace(0.0, 2.0 * np.pi, count)
        R = self.frame()
        return self.center + np.outer(self.a * np.cos(s), R[:, 0]) + np.outer(self.b * np.sin(s), R[:, 1])

    def corner_points(self) -> np.ndarray:
        """Points that bound the drawn obstacle (outline at both ends of the cylinder) [m]."""
        ring = self.outline(32)
        half = 0.5 * self.height * self.axis
        return np.vstack([ring + half, ring - half])


def _number(obstacle: dict, key: str, default=None, positive: bool = False) -> float:
    if key not in obstacle:
        if default is None:
            raise TaskError(f"obstacle needs the key {key!r}; its keys are {OBSTACLE_KEYS}")
        return float(default)
    try:
        value = float(obstacle[key])
    except (TypeError, ValueError) as err:
        raise TaskError(f"obstacle {key!r} must be a number, got {obstacle[key]!r}") from err
    if not math.isfinite(value) or (positive and value <= 0.0):
        need = "a finite number > 0" if positive else "a finite number"
        raise TaskError(f"obstacle {key!r} must be {need}, got {value!r}")
    return value


def _vector(obstacle: dict, key: str, default) -> np.ndarray:
    raw = obstacle.get(key, default)
    try:
        v = np.asarray(raw, dtype=float)
    except (TypeError, ValueError) as err:
        raise TaskError(f"obstacle {key!r} must be 3 numbers [x, y, z], got {raw!r}") from err
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise TaskError(f"obstacle {key!r} must be 3 finite numbers [x, y, z], got {raw!r}")
    return v


def parse_obstacle(obstacle: dict, scale: float = 1.0) -> Obstacle:
    """Validate ``traj.meta["obstacle"]`` and return an :class:`Obstacle`.

    Args:
        obstacle: ``{"kind": "ellipse"|"elliptic_cylinder", "center": [x, y, z], "a": .., "b": ..,
            "angle": rad, "axis": [0, 0, 1], "height": m}``; ``angle`` defaults to 0, ``axis`` to
            z, ``height`` to ``scale`` for a cylinder and to 2 % of ``scale`` for an ellipse.
        scale: a length of the scene [m], for the defaults.

    Raises:
        TaskError: a key is missing or holds a bad value (the message names it).
        ChoiceError: an unknown ``kind`` (lists the known ones).
    """
    if not isinstance(obstacle, dict):
        raise TaskError(f"the obstacle must be a dict with kind, center, a, b, got {type(obstacle).__name__}")
    kind = check_choice("obstacle kind", obstacle.get("kind"), OBSTACLE_KINDS)
    if "center" not in obstacle:
        raise TaskError(f"obstacle needs the key 'center'; its keys are {OBSTACLE_KEYS}")
    center = _vector(obstacle, "center", None)
    a = _number(obstacle, "a", positive=True)
    b = _number(obstacle, "b", positive=True)
    angle = _number(obstacle, "angle", 0.0)
    axis = _vector(obstacle, "axis", [0.0, 0.0, 1.0])
    norm = float(np.linalg.norm(axis))
    if norm < 1e-12:
        raise TaskError("obstacle 'axis' must be a non-zero vector")
    default_height = scale if kind == "elliptic_cylinder" else 0.02 * scale
    height = _number(obstacle, "height", default_height, positive=True)
    return Obstacle(kind, center, a, b, angle, axis / norm, height)


def check_trajectory(traj: Trajectory, nq: int) -> None:
    """Check the arrays a playback reads: t increasing and finite, q of shape (N, nq), p of shape (N, 3).

    Raises:
        PathError: bad times or positions.
        JointVectorError: q of the wrong shape or with non-finite entries.
    """
    t = np.asarray(traj.t, dtype=float)
    if t.ndim != 1 or len(t) == 0 or not np.all(np.isfinite(t)):
        raise PathError(f"trajectory times must be a non-empty finite 1-D array, got shape {t.shape}")
    if len(t) > 1 and np.any(np.diff(t) <= 0.0):
        k = int(np.argmax(np.diff(t) <= 0.0))
        raise PathError(
            f"trajectory times must increase strictly; t[{k + 1}] = {t[k + 1]} <= t[{k}] = {t[k]}",
            t=float(t[k + 1]),
        )
    q = np.asarray(traj.q, dtype=float)
    if q.shape != (len(t), nq):
        raise JointVectorError(
            f"trajectory q must have shape ({len(t)}, {nq}) for robot {traj.robot!r} (one row per time), "
            f"got {q.shape}"
        )
    if not np.all(np.isfinite(q)):
        raise JointVectorError("trajectory q has non-finite entries")
    for name in ("p", "p_desired"):
        arr = np.asarray(getattr(traj, name), dtype=float)
        if arr.shape != (len(t), 3) or not np.all(np.isfinite(arr)):
            raise PathError(f"trajectory {name} must be finite with shape ({len(t)}, 3), got {arr.shape}")


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
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise TaskError(f"fps must be a number > 0, got {fps!r}")
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
