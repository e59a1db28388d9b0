"""Clearance of a robot frame's origin from a sphere or a plane: general inequality rows (issue 27).

The first general constraints, needing only the kinematics layer (no collision library): the origin p_f of
a frame of the robot is kept at ``clearance`` [m] from an obstacle,

    sphere:  c(theta) = ||p_f(theta) - center|| - radius - clearance >= 0,  grad c = n^T J_p,  n = (p_f - center)/||.||
    plane:   c(theta) = normal^T (p_f(theta) - point) - clearance >= 0,     grad c = normal^T J_p,

with J_p the frame's translational Jacobian [m/rad]. The curvature terms (their share of M in the
system) are analytic: sum_a n_a Hess p_a (Pinocchio's kinematic Hessian), plus J_p^T (I - n n^T) J_p /
||p_f - center|| for the sphere. A distance row of a collision pair (n^T (J_a - J_b)) plugs in the same way.

Where the compiled core loads, :meth:`_FrameClearance.row_guard` gives the compiled step the same row
(``kinredund._core.FrameRows``, ``src/core/frame_rows.cpp``: the values, the gradient and the analytic curvature
above with the same Pinocchio calls, and the test of :meth:`_FrameClearance.segment_lower_bounds`), so that its steps
are checked for a switch and the row held in C++ (:mod:`kinredund.tracking.compiled_rows`).
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import OptionError
from kinredund.geometry.engine import compiled_core
from kinredund.kinematics.state import Kinematics, PerThread
from kinredund.model.frames import resolve_frame
from kinredund.model.robot import Robot
from kinredund.tracking.constraints.base import Constraint, RowCheck

#: the codes of the row's kind in ``kinredund._core.FrameRows``
SPHERE, PLANE = 0, 1


def _vector(value, what: str) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise OptionError(f"{what} must be 3 finite numbers [m], got {value!r}")
    return v


def _length(value, what: str, positive: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not (np.isfinite(v) and (v > 0.0 if positive else v >= 0.0)):
        raise OptionError(f"{what} must be a finite number {'>' if positive else '>='} 0 [m], got {value!r}")
    return v


class _FrameClearance(Constraint):
    """One inequality on the origin of a frame of ``robot`` (a Pinocchio workspace per thread, as
    ``Robot.kinematics``: a constraint may be shared between threads and pickled)."""

    cause = "collision"

    def __init__(self, robot: Robot, frame: str, clearance: float):
        if not isinstance(robot, Robot):
            raise OptionError(f"robot must be a kinredund Robot, got {type(robot).__name__}")
        self.frame_id, _ = resolve_frame(robot.model, frame)
        self.frame, self.clearance = frame, _length(clearance, "the clearance")
        # whose joints the rows are of: the tracker refuses the constraint on another robot (tracker.check_robot_of)
        self.robot_name, self.joint_names = robot.name, list(robot.joint_names)
        self._kinematics = PerThread(robot.model, self.frame_id)
        f = robot.model.frames[self.frame_id]  # joint j moves the frame's origin by at most reach[j] |dq_j|
        self._reach = robot.reach(f.parentJoint, float(np.linalg.norm(f.placement.translation)))
        self._extent = np.where(robot.revolute, np.inf, np.maximum(np.abs(robot.lower), np.abs(robot.upper)))

    @property
    def model(self):
        """The Pinocchio model (a ``pin.Model``) of the robot the constraint was made for."""
        return self._kinematics.model

    @property
    def _kin(self) -> Kinematics:
        return self._kinematics.get()

    @property
    def size(self) -> int:
        return 1

    def point(self, q: np.ndarray) -> np.ndarray:
        """The frame origin p_f(q) [m]."""
        return self._kin.pose(np.asarray(q, float))[1]

    def _normal(self, p: np.ndarray) -> tuple[np.ndarray, float]:
        """(the unit normal n of the row at p, the curvature factor 1/||p - c|| or 0)."""
        raise NotImplementedError

    def segment_lower_bounds(self, q0, q1, c0, c1, move) -> np.ndarray | None:
        """(c0 + c1 - L move) / 2 [m]: c changes at most as fast as the frame's origin moves, by at most
        L . |dq| (:meth:`~kinredund.model.robot.Robot.reach`); None where a prismatic joint slid beyond its
        limits' extent at an end."""
        if not all(np.all(np.abs(np.asarray(x, float)) <= self._extent) for x in (q0, q1)):
            return None
        return 0.5 * (np.asarray(c0) + np.asarray(c1) - float(self._reach @ np.asarray(move, float)))

    def gradients(self, q: np.ndarray) -> np.ndarray:
        return self.rows_at(q)[1]

    def _shape(self) -> tuple[int, np.ndarray, np.ndarray, float]:
        """(kind code, the sphere's centre or the plane's point [m], the plane's unit normal, the radius [m])."""
        raise NotImplementedError

    def row_guard(self, tol: float) -> RowCheck | None:
        """The compiled check and row (``kinredund._core.FrameRows``; module docstring), which the core holds too; None
        where the core is not built, the model has joints with nq != nv (the core's rows take q as nv entries), and for
        a subclass (its values, rows or bounds may differ from the ones FrameRows computes: it gives its own check, or
        none; as :meth:`~kinredund.tracking.constraints.scene.SceneClearance.row_guard`)."""
        core, model = compiled_core(), self._kinematics.model
        if type(self) not in (SphereClearance, PlaneClearance) or core is None or not hasattr(core, "FrameRows") \
                or model.nq != model.nv:
            return None
        kind, point, normal, radius = self._shape()
        return _FrameCheck(core.FrameRows(model, self.frame_id, kind, point, normal, radius, self.clearance,
                                          self._reach, self._extent, float(tol)), self)

    def _parameters(self) -> tuple:
        """What the compiled row copies (:meth:`row_guard`): the shape's numbers and the clearance."""
        kind, point, normal, radius = self._shape()
        return kind, *point.tolist(), *normal.tolist(), float(radius), float(self.clearance)

    def rows_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        _, p, K = self._kin.jacobian(np.asarray(q, float))
        return self._value(p), (self._normal(p)[0] @ K[3:])[None, :]  # n^T J_p (K's rows: [omega; pdot])

    def values(self, q: np.ndarray) -> np.ndarray:
        return self._value(self.point(q))

    def _value(self, p: np.ndarray) -> np.ndarray:
        """c at the frame origin p [m], shape (1,)."""
        raise NotImplementedError

    def curvature(self, q: np.ndarray, w: np.ndarray, rows: np.ndarray) -> np.ndarray:
        _, p, K, dk = self._kin.jacobian_hessian(np.asarray(q, float))
        n, inv = self._normal(p)
        w0 = float(np.sum(w))  # one row
        H = dk.contract(np.concatenate([np.zeros(3), n]))  # sum_a n_a Hess p_a
        if inv:
            Jp = K[3:]
            Jt = Jp - np.outer(n, n @ Jp)  # (I - n n^T) J_p
            H = H + inv * (Jp.T @ Jt)
        return w0 * 0.5 * (H + H.T)


class SphereClearance(_FrameClearance):
    """The origin of ``frame`` kept ``clearance`` [m] outside a sphere (``center`` [m], ``radius`` [m]).

    Raises:
        OptionError: a center that is not 3 finite numbers, a radius <= 0, a clearance < 0.
        FrameNotFoundError: no frame of that name (lists the frames).
    """

    def __init__(self, robot: Robot, frame: str, center, radius: float, clearance: float = 0.0):
        super().__init__(robot, frame, clearance)
        self.center, self.radius = _vector(center, "the sphere's center"), _length(radius, "the radius", True)

    def _normal(self, p: np.ndarray) -> tuple[np.ndarray, float]:
        d = p - self.center
        dist = float(np.sqrt(d @ d))
        if not dist > 0.0:
            raise OptionError(f"frame {self.frame} is at the sphere's center: its clearance has no gradient")
        return d / dist, 1.0 / dist

    def _shape(self) -> tuple[int, np.ndarray, np.ndarray, float]:
        return SPHERE, self.center, np.zeros(3), self.radius

    def _value(self, p: np.ndarray) -> np.ndarray:
        d = p - self.center
        return np.array([np.sqrt(d @ d) - self.radius - self.clearance])

    def names(self) -> list[str]:
        return [f"{self.frame} clear of sphere ({', '.join(f'{v:.4g}' for v in self.center)}; r {self.radius:.4g}) "
                f"by {self.clearance:.4g}"]


class PlaneClearance(_FrameClearance):
    """The origin of ``frame`` kept ``clearance`` [m] on the side of a plane its ``normal`` points to.

    Raises:
        OptionError: ``point`` or ``normal`` not 3 finite numbers, a zero normal, a clearance < 0.
    """

    def __init__(self, robot: Robot, frame: str, point, normal, clearance: float = 0.0):
        super().__init__(robot, frame, clearance)
        normal = _vector(normal, "the plane's normal")
        if not np.linalg.norm(normal) > 0.0:
            raise OptionError("the plane's normal must not be zero")
        self.origin, self.normal = _vector(point, "the plane's point"), normal / np.linalg.norm(normal)

    def _normal(self, p: np.ndarray) -> tuple[np.ndarray, float]:
        return self.normal, 0.0

    def _shape(self) -> tuple[int, np.ndarray, np.ndarray, float]:
        return PLANE, self.origin, self.normal, 0.0

    def _value(self, p: np.ndarray) -> np.ndarray:
        return np.array([self.normal @ (p - self.origin) - self.clearance])

    def names(self) -> list[str]:
        return [f"{self.frame} above plane ({', '.join(f'{v:.4g}' for v in self.normal)}) by {self.clearance:.4g}"]


class _FrameCheck(RowCheck):
    """:meth:`_FrameClearance.row_guard`'s check while the constraint keeps the numbers it was made with: after a
    change (its ``center`` moved, say) it clears no step and holds no row, so the Python stepper's search and step,
    which read the constraint afresh, decide (the core's copy would give another answer silently)."""

    __slots__ = ("_constraint", "_made")

    def __init__(self, compiled, constraint: _FrameClearance):
        super().__init__(compiled, holds=True)
        self._constraint, self._made = constraint, constraint._parameters()

    def valid(self) -> bool:
        return self._constraint._parameters() == self._made
