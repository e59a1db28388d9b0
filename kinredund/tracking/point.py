"""One evaluation of the tracking scheme at (theta, t): kinematics, task terms and index terms (Chapter 4).

:class:`Evaluator` holds the robot, path, index and formulation; :meth:`Evaluator.point` returns a
:class:`Point` with everything Eq. (4.24) needs there: r, J, xdot, grad z, Hess z, d(grad z)/dt, and
on demand M and the upper right-hand side (:meth:`Point.system`) and the first-order residual
(:meth:`Point.residual`).
"""

from __future__ import annotations

import numpy as np

from kinredund.indices import Index
from kinredund.model.robot import Robot
from kinredund.paths import Path
from kinredund.paths.base import checked
from kinredund.tasks import get_task, task_terms


class Point:
    """Everything the scheme evaluates at one (theta, t): kinematics, task terms, index terms.

    Attributes:
        q: joint values [rad or m]; t: time [s]; Q, p: end-effector rotation and position [m].
        sample: the path sample at t; terms: the task terms (r, J, xdot, basis).
        grad, hess: grad z and Hess z; dgrad_dt: d(grad z)/dt at fixed theta, or None.
    """

    __slots__ = ("q", "t", "Q", "p", "sample", "terms", "r", "J", "xdot", "basis", "grad", "hess", "dgrad_dt")

    def __init__(self, q, t, Q, p, sample, terms, grad, hess, dgrad_dt):
        self.q, self.t, self.Q, self.p, self.sample, self.terms = q, t, Q, p, sample, terms
        self.r, self.J, self.xdot, self.basis = terms.r, terms.J, terms.xdot, terms.basis
        self.grad, self.hess, self.dgrad_dt = grad, hess, dgrad_dt

    @property
    def base(self) -> Point:
        """The task's own evaluation (this point; an extended point's is the one it extends)."""
        return self

    def system(self, lam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(M, top) of Eq. (4.24) at this point for the multipliers lam.

        M = Hess z + Lambda (Eqs. 4.23, 4.37); top = -d(grad z)/dt - (dJ/dt)^T lambda at fixed theta, the
        upper right-hand side (``dgrad_dt`` is None for a time-invariant index: d(grad z)/dt = 0).
        """
        Lam, extra = self.terms.system(lam)
        if extra is None:
            top = np.zeros(len(self.grad)) if self.dgrad_dt is None else -self.dgrad_dt
        else:
            top = -extra if self.dgrad_dt is None else -self.dgrad_dt - extra
        return self.hess + Lam, top

    def residual(self, lam: np.ndarray) -> np.ndarray:
        """F = [grad z + J^T lambda; r]: the normality condition (4.5) and the task, zero on the optimum."""
        return np.concatenate([self.grad + self.J.T @ lam, self.r])


class Evaluator:
    """Evaluates the terms of the scheme for one robot, path, index and formulation.

    ``formulation``: ``augmented`` (displacement Jacobian) or ``velocity`` (velocity Jacobian, Eqs.
    4.30-4.42); the baselines use the augmented terms.
    """

    def __init__(self, robot: Robot, path: Path, index: Index | None, formulation: str):
        self.robot, self.path, self.index = robot, path, index
        self.task = robot.task
        self._task = get_task(robot.task)
        self.formulation = formulation
        self.n = robot.nq
        self._cache_t, self._cache = None, None
        self._zeros, self._zeros2 = np.zeros(self.n), np.zeros((self.n, self.n))
        self._index_at = None  # (q, grad z, Hess z) at t = 0 for the first evaluation there (keep_index_at)

    def keep_index_at(self, q: np.ndarray, terms: tuple | None) -> None:
        """The index's (z, grad z, Hess z) at q and t = 0 (:func:`~kinredund.ik.solve.check_index_at`'s): the first
        evaluation at this q (the same array) and t = 0 takes them instead of evaluating the index again."""
        self._index_at = None if terms is None else (q, terms[1], terms[2])

    def sample(self, t: float):
        """The path sample at t, cached (the corrector evaluates the same time several times).

        Not checked for finite values here (that costs a few microseconds per step): the stepper
        checks its results and calls :meth:`check_sample` to say where a non-finite value came from.
        """
        if self._cache_t != t:
            self._cache = self.path.sample(t)
            self._cache_t = t
        return self._cache

    def check_sample(self, t: float) -> None:
        """Raise PathError if the path's sample at t is not finite (says when)."""
        self.path(t)

    def checked_sample(self, t: float):
        """:meth:`sample` at t, checked as :meth:`check_sample` checks it (one sampling of the path for both)."""
        return checked(self.sample(t), t)

    def branch_error(self, pt: Point) -> str:
        """Why pt, where the task residual vanishes, is not on the path's branch ("" where it is):
        :meth:`kinredund.tasks.Task.branch_error`."""
        return self._task.branch_error(pt.Q, pt.sample.Q)

    def gradient(self, q: np.ndarray, t: float) -> np.ndarray:
        """grad z at (q, t) (zero without an index)."""
        return self._zeros if self.index is None else self.index.evaluate(q, t)[1]

    def point(self, q: np.ndarray, t: float, need_dJ: bool = True, sample=None) -> Point:
        """The :class:`Point` at (q, t); ``need_dJ=False`` skips dK (no :meth:`Point.system` then).

        ``sample``: the path sample at t where the caller has it.
        """
        kin = self.robot.kinematics
        s = self.sample(t) if sample is None else sample
        if need_dJ:
            Q, p, K, dk = kin.jacobian_hessian(q)
        else:
            (Q, p, K), dk = kin.jacobian(q), None
        return self._point(q, t, s, Q, p, K, dk)

    def start_point(self, q: np.ndarray, t: float) -> Point:
        """The :class:`Point` at (q, t) without dK (no :meth:`Point.system`) whose J is :meth:`point`'s bit for bit
        (:meth:`~kinredund.kinematics.state.Kinematics.jacobian_joints`): what a compiled start's checks and lambda
        read (the core evaluates afresh)."""
        Q, p, K = self.robot.kinematics.jacobian_joints(q)
        return self._point(q, t, self.sample(t), Q, p, K, None)

    def _point(self, q, t, s, Q, p, K, dk) -> Point:
        """The task and index terms at (q, t) from the kinematics there (``dk`` None: without dK)."""
        terms = task_terms(self.task, self.formulation, Q, p, K, dk, s)
        if self.index is None:
            grad, hess, dgdt = self._zeros, self._zeros2, self._zeros
        else:
            kept = self._index_at
            if kept is not None:  # (once: the first evaluation)
                self._index_at = None
            if kept is not None and kept[0] is q and t == 0.0:
                _, grad, hess = kept
            else:
                _, grad, hess = self.index.evaluate(q, t)
            dgdt = self.index.time_derivative_of_gradient(q, t) if self.index.time_varying else None
        return Point(q, t, Q, p, s, terms, grad, hess, dgdt)
