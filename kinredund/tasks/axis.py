"""The tool-axis task: point P and the tool axis a follow the path, the spin about a is free (m = 5).

An axially symmetric tool (a torch, a nozzle, a drill, a spindle) fixes the tool point and the tool's
axis, five numbers, and leaves the spin about the axis to the arm: a 6-axis arm becomes redundant by
one, a 7-axis arm by two, and the scheme of Chapter 4 applies unchanged to the task map
g(theta) = x(t) (Eq. 4.1) with a full-rank Jacobian.

The tool axis is the z axis of the end-effector frame, a = Q e_z (give ``load_robot(..., tool_axis=...)``
for another one: it adds a frame whose z axis is that axis). The desired axis is the z axis of the
path's rotation Q_d (a path that gives only an axis gives any rotation with that z axis).

Task map, written in the target frame like the closure equations of the pose task: with the axis in
the target frame a^ = Q_d^T a and S the selection of its x and y components,

    r = [S a^; p - p_d]                                                        (5,)

Spurious zeros: S a^ = 0 holds at a^ = e_z (a = a_d) and at a^ = -e_z (a = -a_d, the tool pointing
backwards: for a torch or a spindle, at the robot). Both the IK's Newton error and the tracking
residual r vanish there, and Newton's method converges to either. What rejects the reversed zero:

- the joint-level IK reports the residual sqrt(||a - a_d||^2 + ||p - p_d||^2), which vanishes only at
  a = a_d (||a - a_d||^2 = ||S a^||^2 + (1 - a^_z)^2: equal to ||S a^||^2 to fourth order on the
  branch, 4 on the reversed one), so convergence (residual < tol) needs a . a_d > 0; a start that
  lands on a = -a_d stops at once with that reason (:meth:`AxisResidual.spurious`) and the next start
  is run (``starts > 1``);
- the tracker refuses a start with a . a_d <= 0 (:meth:`AxisTask.branch_error`); from a start on the
  branch the run keeps it (r is held at ~1e-12 at every step, and reaching a = -a_d turns the axis
  by pi through points where ||S a^|| = 1).
 With W = Q_d^T K_omega the angular columns in the target frame:

- augmented (displacement) form: J = [S (-[a^]x) W; K_pdot], the exact Jacobian dr/dtheta, and
  Lambda = d(J^T lambda)/dtheta = sum_c (a x m)_c dK_omega[c] + K_omega^T [m]x [a]x K_omega
  + sum_c lambda_p,c dK_pdot[c] with m = Q_d S^T lambda_a (world axes): a true Hessian of lambda^T r,
  symmetric (Eq. 4.20 for this task);
- velocity form (Eq. 4.31): J* = [S (-[e_z]x) W; K_pdot], the rows of the twist in the target frame
  that the axis task holds (equal to J on the path, where a^ = e_z), and
  Lambda* = sum_c (m*)_c dK_omega[c] + sum_c lambda_p,c dK_pdot[c], m* = Q_d (e_z x S^T lambda_a)
  (Eq. 4.42 for this task);
- the desired rate xdot = -dr/dt at fixed theta = [S (w_d x a^); v_d], w_d = Q_d^T omega_d, and
  (dJ/dt)^T lambda at fixed theta = K_omega^T (a x (omega_d x m)) (augmented) or
  K_omega^T (omega_d x m*) (velocity): Q_d turns at omega_d.

The record's errors: the position error [m] and the axis error, the angle between a and a_d [rad].
"""

from __future__ import annotations

import math

import numpy as np

from kinredund.errors import TaskError, check_array
from kinredund.tasks.base import Target, Task, TaskResidual, TaskTerms
from kinredund.tasks.pose import PoseTask

_XY = np.array([0, 1])
#: -[e_z]x restricted to its x and y rows: the velocity form's angular rows in the target frame
_PERP = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def frame_with_axis(axis) -> np.ndarray:
    """A rotation whose z axis is the unit vector ``axis``: its x axis the unit vector of e_x, e_y or e_z
    (the one least aligned with ``axis``) made orthogonal to it."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    seed = np.eye(3)[int(np.argmin(np.abs(a)))]
    x = seed - (seed @ a) * a
    x /= np.linalg.norm(x)
    return np.column_stack([x, _cross(a, x), a])


def axis_angle_error(Q: np.ndarray, Q_d: np.ndarray) -> np.ndarray:
    """The angle [rad] between the tool axes Q e_z and Q_d e_z, for rotations (3, 3) or stacks (N, 3, 3)."""
    a, b = Q[..., :, 2], Q_d[..., :, 2]
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def reversed_axis(cos_angle: float) -> str:
    """The message of a tool axis on the reversed branch (a . a_d = ``cos_angle`` <= 0)."""
    return (f"the tool axis points away from the target's (a . a_d = {cos_angle:.6g}, angle "
            f"{math.degrees(math.acos(max(-1.0, min(1.0, cos_angle)))):.4g} deg): the axis residual "
            "[S Q_d^T a; p - p_d] vanishes at a = -a_d too, a spurious zero that is not the task")


class AxisTerms(TaskTerms):
    """The tracking terms of the tool-axis task in either form (module docstring)."""

    __slots__ = ("_K", "_a", "_Qd", "_omega", "_velocity")

    def __init__(self, velocity: bool, Q, p, K, dk, s):
        Qd = s.Q
        a = Q[:, 2]
        W = Qd.T @ K[:3]  # angular columns in the target frame
        ah = Qd.T @ a  # a^
        w_d = Qd.T @ s.omega
        rows = _PERP if velocity else -_skew(ah)[_XY]  # S (-[e_z]x) or S (-[a^]x)
        self.r = np.concatenate((ah[_XY], p - s.p))
        self.J = np.concatenate((rows @ W, K[3:]))
        self.xdot = np.concatenate((_cross(w_d, ah)[_XY], s.v))
        self.basis, self._dk = None, dk
        self._K, self._a, self._Qd, self._omega, self._velocity = K, a, Qd, s.omega, velocity

    def _m(self, lam):
        mu = np.array([lam[0], lam[1], 0.0])  # S^T lambda_a
        if self._velocity:
            return self._Qd @ _cross(np.array([0.0, 0.0, 1.0]), mu)  # m* = Q_d (e_z x S^T lambda_a)
        return self._Qd @ mu  # m = Q_d S^T lambda_a

    def system(self, lam):
        m = self._m(lam)
        Ko = self._K[:3]
        if self._velocity:
            w = m  # Lambda*, Eq. (4.42): the twist's angular multipliers are m*
            dJdt = Ko.T @ _cross(self._omega, m)
        else:
            w = _cross(self._a, m)
            dJdt = Ko.T @ _cross(self._a, _cross(self._omega, m))
        mu = np.concatenate((lam[2:], w))  # Pinocchio's [v; omega] order
        Lam = self._hessian().contract_pinocchio(mu)
        if not self._velocity:  # d a / d theta_j = omega_j x a, Eq. (4.20) for this task
            Lam = Lam + Ko.T @ (np.outer(self._a, m) - float(self._a @ m) * np.eye(3)) @ Ko  # [m]x [a]x
        return Lam, dJdt

    def Lambda(self, lam):
        return self.system(lam)[0]

    def dJdt_T(self, lam):
        return self.system(lam)[1]


class AxisResidual(TaskResidual):
    """e = [S Q_d^T a; p - p_d] and its exact Jacobian G = [S (-[a^]x) Q_d^T K_omega; K_pdot] for the
    joint-level IK (Eq. D.23 for this task)."""

    def __init__(self, target: Target):
        self.target = target
        self.rows, self.row_selection, self.m = np.arange(6), None, 5
        self.QdT = np.ascontiguousarray(target.Q.T)
        self.p_d = target.p.copy()

    def error(self, Q, p):
        ah = self.QdT @ Q[:, 2]
        return np.concatenate((ah[_XY], p - self.p_d)), (Q[:, 2].copy(), ah)

    def error_terms(self, Q, p):
        e, _ = self.error(Q, p)
        ev = tuple(e.tolist())
        return ev, float(e @ e)

    def jacobian(self, K, aux):
        _, ah = aux
        return np.concatenate((-_skew(ah)[_XY] @ (self.QdT @ K[:3]), K[3:]))

    def k_multipliers(self, lam, aux):
        """lambda* = [a x m; lambda_p] with G^T lambda = K^T lambda*, m = Q_d S^T lambda_a."""
        a, _ = aux
        m = self.QdT.T @ np.array([lam[0], lam[1], 0.0])
        return np.concatenate((_cross(a, m), lam[2:]))

    def normal_rows(self, K, aux):
        """G itself: its 5 rows span a proper subspace of K's 6."""
        return self.jacobian(K, aux)

    def normal_multipliers(self, K, lam, aux):
        return self.k_multipliers(lam, aux), self.extra_hessian(K, lam, aux)

    def extra_hessian(self, K, lam, aux):
        """The part of d(G^T lambda)/dtheta that d(K^T lambda*)/dtheta at fixed lambda* leaves out:
        K_omega^T [m]x [a]x K_omega, from d a / d theta_j = omega_j x a."""
        a, _ = aux
        m = self.QdT.T @ np.array([lam[0], lam[1], 0.0])
        Ko = K[:3]
        return Ko.T @ (np.outer(a, m) - float(a @ m) * np.eye(3)) @ Ko

    def residual(self, Q, p):
        """sqrt(||a - a_d||^2 + ||p - p_d||^2): zero only at a = a_d (module docstring), never at a = -a_d
        where the Newton error e vanishes too."""
        a_z = float(self.QdT[2] @ Q[:, 2])  # a^_z = a . a_d
        return math.sqrt(self.error_terms(Q, p)[1] + (1.0 - a_z) ** 2)

    def spurious(self, Q, p):
        """The tool axis reversed (a . a_d <= 0): where e = [S a^; p - p_d] vanishes without the task done."""
        a_z = float(self.QdT[2] @ Q[:, 2])
        return "" if a_z > 0.0 else (reversed_axis(a_z) + "; another start (starts > 1, or another q0) "
                                      "finds the tool axis along the target's")

    def newton_jacobian(self, K, Q):
        """G itself: e's 5 rows are not a selection of K's 6."""
        return self.jacobian(K, (None, self.QdT @ Q[:, 2]))


class AxisTask(Task):
    """Point P at p_d [m] and the tool axis (the end frame's z axis) along a_d."""

    name = "axis"
    dim = 5
    has_orientation = True
    error_names = ("position_error", "axis_error")

    def make_target(self, target, *, z: float = 0.0) -> Target:
        """A 4x4 pose (its rotation's z axis is the axis), a (Q, p) pair, or an (axis, p) pair with a
        3-vector axis (any length but zero).

        Raises:
            TaskError: not numeric, wrong sizes, non-finite, a zero axis, or a rotation that is not
                orthonormal.
        """
        if isinstance(target, tuple) and len(target) == 2 and np.shape(target[0]) == (3,):
            axis = check_array(target[0], (3,), "an axis target's axis")
            p = check_array(target[1], (3,), "an axis target's position p [m]")
            if not np.linalg.norm(axis) > 1e-12:
                raise TaskError("an axis target's axis must be a nonzero 3-vector")
            return Target(self.name, p.copy(), frame_with_axis(axis))
        pose = PoseTask().make_target(target)
        return Target(self.name, pose.p, pose.Q)

    def errors_many(self, Q, p, Q_d, p_d):
        out = super().errors_many(Q, p, Q_d, p_d)
        out["axis_error"] = axis_angle_error(Q, Q_d)
        return out

    def branch_error(self, Q, Q_d):
        """The tool axis reversed (a . a_d <= 0), where r vanishes too (module docstring)."""
        a_z = float(Q[:, 2] @ Q_d[:, 2])
        return "" if a_z > 0.0 else reversed_axis(a_z)

    def span_rows(self, Q, K, Q_d):
        """The velocity form's rows [S (-[e_z]x) Q_d^T K_omega; K_pdot]: J's row space on the path."""
        return np.concatenate((_PERP @ (Q_d.T @ K[:3]), K[3:]))

    def ik_residual(self, target: Target) -> AxisResidual:
        return AxisResidual(target)

    def tracking_terms(self, formulation, Q, p, K, dk, sample) -> AxisTerms:
        return AxisTerms(formulation == "velocity", Q, p, K, dk, sample)
