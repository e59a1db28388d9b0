"""Task kinds: the base classes every kind implements (Chapters 2 and 4).

A task says what the end effector must do: the task map g(theta) = x(t) of Eq. (4.1) with its
dimension m. Each kind (one file per kind: :mod:`~kinredund.tasks.planar`, :mod:`~kinredund.tasks.position`,
:mod:`~kinredund.tasks.pose`, :mod:`~kinredund.tasks.axis`) owns

- its dimension m and how a target is given and validated (:meth:`Task.make_target`);
- its errors for the record (:meth:`Task.errors`);
- the residual and Jacobian the joint-level IK drives to zero (:meth:`Task.ik_residual`, a
  :class:`TaskResidual`);
- the terms of the resolved-rate schemes (:meth:`Task.tracking_terms`, a :class:`TaskTerms`): the
  residual r, its Jacobian J, the desired rate xdot, Lambda = d(J^T lambda)/dtheta (Eq. 4.20 / 4.42)
  and (dJ/dt)^T lambda.

The kinds are registered by name in :mod:`kinredund.tasks.registry`; everything else asks the task
object (:func:`kinredund.tasks.get_task`) rather than branching on the name.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from kinredund.errors import KinredundError, PathError

if TYPE_CHECKING:
    from kinredund.kinematics.state import HessianContraction
    from kinredund.paths import Path, PathSample

#: the formulations of the resolved-rate scheme: displacement Jacobian J (Eq. 4.15) or twist K (Eq. 4.31)
FORMULATIONS = ("augmented", "velocity")


@dataclass(frozen=True)
class Target:
    """A validated target of the task kind ``task``: ``p`` (3,) [m] and ``Q`` (3x3, or None where the
    task has no orientation). Only ``task``'s own coordinates of ``p`` and ``Q`` are used."""

    task: str
    p: np.ndarray
    Q: np.ndarray | None = None


class TaskTerms:
    """r, J, xdot and the multiplier basis at one point; Lambda and (dJ/dt)^T lambda on demand.

    Attributes:
        r: the task residual (actual minus desired), zero on the path, (m,).
        J: its Jacobian dr/dtheta (m x n), full row rank away from singularities.
        xdot: the desired rate of the task coordinates (right-hand side of Eq. 4.15 / 4.31).
        basis: maps the multipliers to the closure 7-vector's (U) where the task keeps a subset of its
            rows, else None.
    """

    __slots__ = ("r", "J", "xdot", "basis", "_dk")

    def Lambda(self, lam: np.ndarray) -> np.ndarray:
        """d(J^T lam)/dtheta at fixed lam, (n, n): Lambda of Eq. (4.20) or Lambda* of Eq. (4.42)."""
        raise NotImplementedError

    def dJdt_T(self, lam: np.ndarray) -> np.ndarray | None:
        """(dJ/dt)^T lam at fixed theta, or None where J does not depend on time."""
        return None

    def system(self, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(Lambda(lam), dJdt_T(lam)) together: what one evaluation of Eq. (4.24) needs."""
        return self.Lambda(lam), self.dJdt_T(lam)

    def _hessian(self) -> HessianContraction:
        if self._dk is None:
            raise KinredundError("these task terms were evaluated without dK (need_dJ=False)")
        return self._dk


class TaskResidual(ABC):
    """e(theta), G(theta) and the reported residual for one validated target (Chapter 4.2, App. D).

    The constraints g(theta) = x of Eq. (4.1) are linearised as G dx = -g, Eq. (D.23).

    Attributes:
        target: the :class:`Target`.
        rows: the rows of K = [omega; pdot] that the error uses.
        row_selection: ``rows`` where they are a subset of K's, None where G uses all of K.
        m: the task dimension.
    """

    target: Target
    rows: np.ndarray
    row_selection: np.ndarray | None
    m: int

    @abstractmethod
    def error(self, Q: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(e, aux): the Newton error and what :meth:`jacobian` needs besides K (or None)."""

    @abstractmethod
    def error_terms(self, Q: np.ndarray, p: np.ndarray) -> tuple[tuple[float, ...], float]:
        """(e, ||e||^2) with e as a tuple of floats: the cheap form of :meth:`error`."""

    @abstractmethod
    def jacobian(self, K: np.ndarray, aux) -> np.ndarray:
        """G = de/dtheta (m x n) from K and the ``aux`` of :meth:`error`."""

    def k_multipliers(self, lam: np.ndarray, aux) -> np.ndarray:
        """lambda* with G^T lambda = K[rows]^T lambda*, for Lambda* = d(K^T lambda*)/dtheta (Eq. 4.37)."""
        return lam

    def normal_rows(self, K: np.ndarray, aux) -> np.ndarray:
        """Rows spanning the constraints' normal space at a solution, for the optimality check: K[rows]
        (the same span as G where G = T K[rows] with T invertible), or G itself."""
        return K[self.rows]

    def normal_multipliers(self, K: np.ndarray, lam: np.ndarray, aux) -> tuple[np.ndarray, np.ndarray | None]:
        """(lambda* on K[rows], :meth:`extra_hessian`) from the multipliers of :meth:`normal_rows`."""
        return lam, None

    def extra_hessian(self, K: np.ndarray, lam: np.ndarray, aux) -> np.ndarray | None:
        """The part of d(G^T lambda)/dtheta that d(K^T lambda*)/dtheta at fixed lambda* leaves out, or
        None where there is none on the solution set (the Lagrangian's Hessian is then M of Eq. 4.37)."""
        return None

    @abstractmethod
    def residual(self, Q: np.ndarray, p: np.ndarray) -> float:
        """||g(theta) - x||: the residual reported to the user. It vanishes only where the task is done
        (never at a spurious zero of :meth:`error`), so that ``residual < tol`` is convergence."""

    def spurious(self, Q: np.ndarray, p: np.ndarray) -> str:
        """Why (Q, p) does not do the task although :meth:`error` vanishes there (a spurious zero of the
        Newton error, e.g. the tool axis reversed), or "" where it does or where e has none."""
        return ""

    def newton_jacobian(self, K: np.ndarray, Q: np.ndarray) -> np.ndarray:
        """The Jacobian of the pose-only Levenberg-Marquardt steps (m x n): K[rows] (or K) where the error's
        rows are K's up to an invertible factor 1 + O(||e||) (point and pose tasks), else G itself."""
        return K if self.row_selection is None else K[self.row_selection]

    def scale(self) -> float:
        """A length scale of the target [m] for rounding-aware tolerances."""
        return float(np.abs(self.target.p).max())


class Task(ABC):
    """A task kind: its dimension, targets, errors, IK residual and tracking terms.

    Attributes:
        name: the kind's name (``robot.task``, the records' ``task``).
        dim: the task dimension m.
        planar: the task lives in the x-y plane (plots and cameras draw it from above).
        has_orientation: the task holds (part of) the orientation: it needs a path with orientation.
        point_rows: the rows of K = [omega; pdot] of the end point's coordinates that the task holds.
        error_names: the names of :meth:`error_values`, as the record's fields.
        holds_rotation: the task holds the whole rotation (a loop of the path's orientation that is not
            contractible then admits no within-limits joint path closing after one loop, :mod:`kinredund.
            planning.topology`).
    """

    name: str = ""
    dim: int = 0
    planar: bool = False
    has_orientation: bool = False
    point_rows: np.ndarray = np.array([3, 4, 5])
    error_names: tuple[str, ...] = ("position_error",)
    holds_rotation: bool = False

    @abstractmethod
    def make_target(self, target, *, z: float = 0.0) -> Target:
        """Validate a target given as the user gives it.

        Raises:
            TaskError: what is wrong with it and what the task takes.
        """

    def target_from_sample(self, sample: PathSample) -> Target:
        """The target of a path sample: its point and (where the task has one) its orientation.

        Not validated again: a path sample is (its constructor checks it).
        """
        return Target(self.name, np.asarray(sample.p, float), sample.Q if self.has_orientation else None)

    def target_at(self, path: Path, t: float) -> Target:
        """The target of ``path`` at time t [s] (:meth:`target_from_sample` of ``path(t)``).

        Raises:
            PathError: the task holds an orientation and the path gives none.
        """
        sample = path(float(t))
        if self.has_orientation and sample.Q is None:
            raise PathError(f"the {self.name} task needs a path with orientation (e.g. Circle(..., frenet=True) "
                            "or Circle(..., orientation=Q))")
        return self.target_from_sample(sample)

    @property
    def takes_tool_axis(self) -> bool:
        """The task holds one axis of the end frame (its z axis) and leaves the spin about it free:
        ``load_robot(..., tool_axis=...)`` chooses that axis."""
        return self.has_orientation and not self.holds_rotation

    @property
    def orientation_error_name(self) -> str | None:
        """The record's field that sums up the orientation error (the last of :attr:`error_names`), or
        None for a task without orientation."""
        return self.error_names[-1] if self.has_orientation else None

    def orientation_angles(self, Q: np.ndarray, Q_d: np.ndarray | None) -> np.ndarray:
        """The orientation error as an angle [rad] at N points (N,): the angle the task holds (the tool
        axis's for the axis task), zeros for a task without orientation.

        Args:
            Q, Q_d: reached and desired rotations (N, 3, 3) (Q_d None where the task has none).
        """
        if not self.has_orientation:
            return np.zeros(len(Q))
        p = np.zeros((len(Q), 3))
        return self.errors_many(Q, p, Q_d, p)[self.orientation_error_name]

    def point_target(self, p: np.ndarray) -> np.ndarray:
        """The IK target of an end point p (3,): the point's coordinates that the task holds."""
        return np.asarray(p, float)[self.point_rows - 3]

    def errors_many(self, Q: np.ndarray, p: np.ndarray, Q_d: np.ndarray | None, p_d: np.ndarray) -> dict:
        """The task's errors at N points by the record's names (:attr:`error_names`), arrays (N,):
        ``position_error`` [m] over the task's point coordinates, and where the task holds an
        orientation ``trace_error`` and ``vect_error`` (the thesis's invariants, Example 4.3) or
        ``axis_error`` [rad].

        Args:
            Q, Q_d: reached and desired rotations (N, 3, 3) (Q_d None where the task has none).
            p, p_d: reached and desired points (N, 3) [m].
        """
        i = self.point_rows - 3
        return {"position_error": np.linalg.norm(p[:, i] - p_d[:, i], axis=1)}

    def error_values(self, Q: np.ndarray, p: np.ndarray, target: Target) -> dict[str, float]:
        """:meth:`errors_many` at one point against a target."""
        Q_d = None if target.Q is None else target.Q[None]
        return {k: float(v[0]) for k, v in self.errors_many(Q[None], np.asarray(p)[None], Q_d, target.p[None]).items()}

    def branch_error(self, Q: np.ndarray, Q_d: np.ndarray | None) -> str:
        """Why a configuration with end rotation Q on which the tracking residual r vanishes is not on the
        path's branch (rotation Q_d; None for a task without orientation), or "" where it is.

        The tracking residuals of the tasks with orientation vanish at spurious points too (each kind's
        module docstring lists them): the tool axis reversed, a half turn about an axis. Those are
        rejected here, at the start of a run (:class:`~kinredund.tracking.stepper.Stepper`); a run that
        starts on the branch stays on it (r is held at ~1e-12 at every step and the spurious set lies at a
        finite distance from the path's: crossing it moves the end frame by pi/2 at least).
        """
        return ""

    def span_rows(self, Q: np.ndarray, K: np.ndarray, Q_d: np.ndarray | None) -> np.ndarray:
        """Rows with the row space of the tracking Jacobian J on the path, from K alone (the normality
        residual of Eq. (4.5) needs only that space): the point rows of K by default. ``Q_d``: the path's
        rotation at that time (None for a task without orientation)."""
        return K[self.point_rows]

    def errors(self, Q: np.ndarray, p: np.ndarray, target: Target) -> tuple[float, float, float]:
        """(position error [m], trace error |tr Q - tr Q_d|, vect error ||vect Q - vect Q_d||), the last
        two zero where the task does not hold them (:meth:`error_values` has every error of the task)."""
        e = self.error_values(Q, p, target)
        return e["position_error"], e.get("trace_error", 0.0), e.get("vect_error", 0.0)

    @abstractmethod
    def ik_residual(self, target: Target) -> TaskResidual:
        """The residual the joint-level IK drives to zero for ``target``."""

    @abstractmethod
    def tracking_terms(self, formulation: str, Q: np.ndarray, p: np.ndarray, K: np.ndarray,
                       dk: HessianContraction | None, sample: PathSample) -> TaskTerms:
        """The :class:`TaskTerms` at one configuration; ``dk`` may be None where Lambda is not needed.

        Args:
            formulation: ``augmented`` (displacement Jacobian, Eq. 4.15) or ``velocity`` (twist, Eq. 4.31).
            Q, p: the end-effector rotation and point [m].
            K: the velocity Jacobian (6 x n), rows [omega; pdot] (Eq. 2.16).
            dk: dK as a Hessian contraction, or None.
            sample: the path sample at this time.
        """

    def __repr__(self) -> str:
        return f"{type(self).__name__}(name={self.name!r}, dim={self.dim})"
