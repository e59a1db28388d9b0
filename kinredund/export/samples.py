"""The content every export format holds: joint names, times, and joint positions, velocities, accelerations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.errors import KinredundError, check_array
from kinredund.trajectory import Trajectory


class ExportError(KinredundError, ValueError):
    """A record that cannot be exported, an output that exists already, or a file that is not an export."""



#: the largest time [s] whose whole nanoseconds fit an int64 (2^63 - 1 ns, about 292 years)
MAX_NANOSECOND_TIME = (2**63 - 1024) / 1e9


def to_nanoseconds(t) -> np.ndarray:
    """Times [s] as whole nanoseconds (int64): what a ROS 2 Duration holds (sec, nanosec).

    Raises:
        ExportError: a time that is not finite, or beyond +-:data:`MAX_NANOSECOND_TIME` (its nanoseconds
            do not fit an int64: numpy would wrap them silently to another number).
    """
    t = np.asarray(t, float)
    bad = ~np.isfinite(t) | (np.abs(t) > MAX_NANOSECOND_TIME)
    if np.any(bad):
        k, count = int(np.flatnonzero(bad)[0]), np.count_nonzero(bad)
        raise ExportError(f"time t[{k}] = {float(t.flat[k])!r} s cannot be held in whole nanoseconds (int64): "
                          f"times must be finite and within +-{MAX_NANOSECOND_TIME:.4g} s ({count} are not)")
    return np.round(t * 1e9).astype(np.int64)


def distinct_nanoseconds(t) -> np.ndarray:
    """:func:`to_nanoseconds` of increasing times, refused if two samples round to the same nanosecond.

    Raises:
        ExportError: as :func:`to_nanoseconds`, or samples k and k+1 closer than half a nanosecond (a
            file of such stamps would hold two points at one time, which its reader refuses).
    """
    ns = to_nanoseconds(t)
    same = np.flatnonzero(np.diff(ns) <= 0)
    if same.size:
        k, t = int(same[0]), np.ravel(t)
        raise ExportError(f"samples {k} and {k + 1} (t = {float(t[k])!r} s and {float(t[k + 1])!r} s) "
                          f"fall in the same nanosecond ({same.size} such pairs): a ROS 2 Duration and a retimed "
                          "record hold whole nanoseconds, so two samples would share one time; track with "
                          "fewer steps or a lower speed")
    return ns


def from_nanoseconds(ns) -> np.ndarray:
    """Whole nanoseconds back to seconds, as the readers compute them (ns / 1e9): with
    :func:`to_nanoseconds`, the times a bag or a retimed record hold, read back exactly."""
    return np.asarray(ns, np.int64) / 1e9


@dataclass(frozen=True)
class JointSamples:
    """Joint samples of a trajectory, as the exported files hold them.

    Attributes:
        joint_names: the robot's joint names, in the order of q's columns.
        t: times [s], shape (N,), strictly increasing.
        q: joint positions, shape (N, n) [rad or m].
        qdot: joint velocities, shape (N, n) [rad/s or m/s], or None.
        qddot: joint accelerations, shape (N, n) [rad/s^2 or m/s^2], or None.
    """

    joint_names: tuple[str, ...]
    t: np.ndarray
    q: np.ndarray
    qdot: np.ndarray | None = None
    qddot: np.ndarray | None = None

    def checked(self) -> JointSamples:
        """The samples validated (finite arrays of matching shapes, increasing times, one name per joint).

        Raises:
            ExportError: what is wrong.
        """
        names = tuple(self.joint_names)
        if not names or not all(isinstance(n, str) and n for n in names) or len(set(names)) != len(names):
            raise ExportError(f"joint names must be distinct non-empty strings, got {list(names)!r}")
        t = check_array(self.t, (None,), "sample times t [s]", ExportError)
        if len(t) == 0 or np.any(np.diff(t) <= 0.0):
            raise ExportError("sample times must be at least one, strictly increasing")
        shape = (len(t), len(names))
        q = check_array(self.q, shape, "joint positions q", ExportError, f"{len(names)} joints")
        more = {k: None if getattr(self, k) is None else
                check_array(getattr(self, k), shape, f"joint {k}", ExportError, f"{len(names)} joints")
                for k in ("qdot", "qddot")}
        return JointSamples(names, t, q, **more)

    @classmethod
    def from_trajectory(cls, traj: Trajectory, joint_names=None) -> JointSamples:
        """The samples of a record; ``joint_names`` default to those of the record's robot.

        Raises:
            ExportError: a record that is not a joint trajectory of that robot.
        """
        if not isinstance(traj, Trajectory):
            raise ExportError(f"export takes a kinredund Trajectory, got {type(traj).__name__}")
        if joint_names is None:
            from kinredund.model.loader import load_robot

            joint_names = load_robot(traj.robot, task=traj.task).joint_names
        elif isinstance(joint_names, (str, bytes)) or not hasattr(joint_names, "__len__"):
            raise ExportError(f"joint_names must be a list of names, one per joint, got {joint_names!r}")
        columns = np.shape(traj.q)[-1] if np.ndim(traj.q) == 2 else None
        if columns is not None and len(joint_names) != columns:  # (the record's own shape is checked() below)
            raise ExportError(f"joint_names: {len(joint_names)} names for a record of {columns} joints (q's columns); "
                              "give one name per joint, or None for the robot's")
        traj = traj.checked(len(joint_names))
        return cls(tuple(joint_names), traj.t, traj.q, traj.qdot, traj.qddot).checked()

    def equal_to(self, other: JointSamples) -> float:
        """The largest absolute difference between two sample sets' t, q, qdot, qddot (inf if they do not match
        in names, shapes or which arrays they have)."""
        if self.joint_names != other.joint_names or self.q.shape != other.q.shape:
            return float("inf")
        worst = max(float(np.abs(self.t - other.t).max()), float(np.abs(self.q - other.q).max()))
        for k in ("qdot", "qddot"):
            a, b = getattr(self, k), getattr(other, k)
            if (a is None) != (b is None):
                return float("inf")
            if a is not None:
                worst = max(worst, float(np.abs(a - b).max()))
        return worst
