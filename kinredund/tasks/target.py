"""Tasks: what the end effector must do, and the validated targets (Chapters 2 and 4).

A task kind (``planar``, ``position``, ``pose``) sets the task dimension m and how a target is given:

- ``planar``: target (x, y) [m] of point P; residual p[:2] - x_d; Jacobian rows pdot_x, pdot_y of K.
- ``position``: target p_d (3,) [m]; residual p - p_d; Jacobian the pdot rows of K.
- ``pose``: target a 4x4 homogeneous matrix (Q_d, p_d); residual the closure 7-vector of Eq. (2.13)
  (:func:`kinredund.closure.closure_vector`); Jacobian J = H K of Eq. (2.14), 7 x n with one dependent
  row (Eq. 2.10) (:func:`kinredund.kinematics.closure.displacement_jacobian`). The twist-level Jacobian is K
  itself (Eq. 4.31).

The residuals and Jacobians the joint-level IK drives to zero are :class:`kinredund.tasks.residual.TaskResidual`;
the resolved-rate scheme takes the rows :data:`TASK_ROWS` of K.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.errors import TaskError, check_array
from kinredund.kinematics import closure

#: rows of K = [omega; pdot] used by the position-only tasks
TASK_ROWS = {"planar": np.array([3, 4]), "position": np.array([3, 4, 5])}


@dataclass(frozen=True)
class Target:
    """A validated target: ``Q`` (3x3 or None for position tasks) and ``p`` (3,) [m]."""

    task: str
    p: np.ndarray
    Q: np.ndarray | None = None

    @property
    def vector(self) -> np.ndarray:
        """The target as given: (x, y), p, or the 4x4 pose."""
        if self.task == "pose":
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = self.Q, self.p
            return T
        return self.p[: 2 if self.task == "planar" else 3].copy()


def make_target(task: str, target, *, z: float = 0.0) -> Target:
    """Validate a target for a task kind.

    Args:
        task: ``planar``, ``position`` or ``pose``.
        target: (x, y), (x, y, z), or a 4x4 homogeneous pose (a (Q, p) pair is accepted too).
        z: the plane height used for planar targets [m].

    Raises:
        TaskError: not numeric, wrong size, non-finite entries, a 4x4 whose last row is not
            (0, 0, 0, 1), or a rotation that is not orthonormal.
    """
    if task == "pose":
        if isinstance(target, tuple) and len(target) == 2:
            Q = check_array(target[0], (3, 3), "a pose target's rotation Q")
            p = check_array(target[1], (3,), "a pose target's position p [m]")
        else:
            T = check_array(target, (4, 4), "a pose target (a 4x4 homogeneous matrix, or (Q, p))")
            if np.abs(T[3] - (0.0, 0.0, 0.0, 1.0)).max() > 1e-9:
                raise TaskError(f"a pose target's last row must be (0, 0, 0, 1), got {T[3].tolist()}")
            Q, p = T[:3, :3], T[:3, 3]
        if np.abs(Q @ Q.T - np.eye(3)).max() > 1e-8 or np.linalg.det(Q) < 0:
            raise TaskError("the pose target's rotation is not a proper orthonormal matrix (Q Q^T = 1, det Q = +1)")
        return Target("pose", p.copy(), Q.copy())
    size = {"planar": 2, "position": 3}.get(task)
    if size is None:
        raise TaskError(f"unknown task kind {task!r}; allowed: planar, position, pose")
    x = check_array(target, (size,), f"a {task} target")
    p = np.array([x[0], x[1], z]) if size == 2 else x.copy()
    return Target(task, p)


def pose_errors(Q: np.ndarray, p: np.ndarray, target: Target) -> tuple[float, float, float]:
    """(position error [m], trace error |tr Q - tr Q_d|, vect error ||vect Q - vect Q_d||).

    The orientation errors are in the thesis's invariants (Example 4.3); zero for position tasks.
    """
    rows = TASK_ROWS.get(target.task, np.array([3, 4, 5])) - 3
    pos = float(np.linalg.norm(p[rows] - target.p[rows]))
    if target.task != "pose":
        return pos, 0.0, 0.0
    tr = float(abs(np.trace(Q) - np.trace(target.Q)))
    ve = float(np.linalg.norm(closure.vect(Q) - closure.vect(target.Q)))
    return pos, tr, ve


def orientation_error(Q: np.ndarray, Q_d: np.ndarray) -> float:
    """The angle [rad] of Q_d^T Q: a frame-independent orientation error."""
    return closure.rotation_log(Q_d.T @ Q)[1]
