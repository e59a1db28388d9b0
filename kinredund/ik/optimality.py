"""The optimality conditions of the constrained problem of Eq. (4.3) at one configuration (Appendix D).

- first order, the normality condition (4.5)/(D.9)/(D.30): ``normality_residual`` = ||L^T grad z||;
- second order, Eq. (D.33): L^T (Hess z + Lambda) L positive definite, Lambda = d(K^T lambda*)/dtheta.

:func:`check_optimality` checks them anywhere (the answers of :func:`kinredund.ik.solve.solve_ik`, a tracked
record's points); :func:`check_index_at` validates an index on a joint vector (the IK's seed, the tracker's start).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from kinredund.errors import TaskError, check_flag
from kinredund.ik.common import RANK_TOL, OptimalityTerms, bound_kkt
from kinredund.indices import Index
from kinredund.paths import PathSample
from kinredund.tasks import Target, TaskResidual, get_task, make_target, task_residual


@dataclass(frozen=True)
class Optimality:
    """First- and second-order conditions at one configuration (see :func:`check_optimality`).

    Attributes:
        residual, normality_residual, objective, reduced_hessian_pd, reduced_hessian_min_eig: as in
            :class:`IKResult`.
        multipliers: lambda* (m,), K[rows]^T lambda* + grad z = 0 in the least-squares sense (Eq. 4.33).
        reduced_hessian: L^T (Hess z + Lambda*) L, symmetrised (k x k).
        null_space: L (n x k), orthonormal basis of the null space of K[rows] and the held limits.
        active: mask of the joint limits that hold (all False without bounds).
    """

    residual: float
    normality_residual: float
    objective: float
    reduced_hessian_pd: bool
    reduced_hessian_min_eig: float
    multipliers: np.ndarray
    reduced_hessian: np.ndarray
    null_space: np.ndarray
    active: np.ndarray


def ik_target(robot, target) -> Target:
    """``target`` as the robot's task's Target: a Target (of that task), a path's sample, or what
    :func:`kinredund.tasks.make_target` accepts.

    Raises:
        TaskError: a Target of another task kind, or a target the task does not take.
    """
    if isinstance(target, Target):
        if target.task != robot.task:
            raise TaskError(f"the target is for a {target.task!r} task but {robot.name} has task {robot.task!r}")
        return target
    if isinstance(target, PathSample):  # a path's sample: its point, and its rotation where the task has one
        task = get_task(robot.task)
        if task.has_orientation:
            return task.make_target((target.Q, target.p))
        return task.make_target(task.point_target(target.p), z=float(target.p[2]))
    return make_target(robot.task, target)


def check_index_at(robot, index, q: np.ndarray) -> tuple[float, np.ndarray, np.ndarray] | None:
    """Validate the index on q (the IK's seed, the tracker's start): its type, the shapes (n,) and (n, n) of
    its gradient and Hessian, finite values. Returns its (z, grad z, Hess z) at q (None without an index).

    Raises:
        TaskError: what is wrong (a JointDeviation of another length, a CustomIndex whose callables fail
            or return the wrong shapes or non-numbers) and what is needed.
    """
    if index is None:
        return None
    if not isinstance(index, Index):
        raise TaskError(f"index must be a kinredund.indices.Index (or None), got {type(index).__name__}")
    n = robot.nq
    try:
        z, grad, H = index.evaluate(q)
        z, grad, H = float(z), np.asarray(grad, dtype=float), np.asarray(H, dtype=float)
    except (ValueError, TypeError, IndexError) as err:
        raise TaskError(
            f"the index cannot be evaluated on a joint vector of {robot.name} ({n} joints; gradient/Hessian "
            f"shapes ({n},)/({n}, {n}) needed): {err}"
        ) from err
    if grad.shape != (n,) or H.shape != (n, n):
        raise TaskError(
            f"index gradient/Hessian must have shapes ({n},)/({n}, {n}) for {robot.name}, got {grad.shape}/{H.shape}"
        )
    if not (math.isfinite(z) and np.isfinite(grad).all() and np.isfinite(H).all()):
        raise TaskError("the index returned non-finite values at the seed")
    return z, grad, H


def check_optimality(robot, target, q, index: Index | None = None, *, bounds: bool = False) -> Optimality:
    """Residual, normality (D.9/D.30) and second-order (D.33) conditions of Eq. (4.3) at q.

    Args:
        robot: a :class:`kinredund.Robot`.
        target: what :func:`kinredund.tasks.make_target` accepts, a Target, or a path's sample
            (:class:`kinredund.paths.PathSample`: its point, and its rotation where the task holds one).
        q: joint vector (n,) [rad or m].
        index: the objective z; None gives only the residual.
        bounds: count the joint limits that q sits on (within 1e-9) as constraints.

    Raises:
        TaskError: bad target; JointVectorError: bad q.
    """
    q = robot.check_q(q, "q")
    bounds = check_flag(bounds, "bounds", TaskError)
    res = task_residual(ik_target(robot, target))
    return optimality_at(robot, res, q, index, bounds, check_index_at(robot, index, q))


def optimality_at(robot, res: TaskResidual, q: np.ndarray, index: Index | None, bounds: bool,
                zgh: tuple | None = None) -> Optimality:
    """:func:`check_optimality` on validated input; ``zgh`` is (z, grad z, Hess z) at q when known."""
    if index is None:
        Q, p = robot.kinematics.pose(q)
        empty = np.zeros((0, 0))
        return Optimality(
            res.residual(Q, p), 0.0, 0.0, False, float("nan"), np.zeros(0), empty, np.zeros((q.size, 0)),
            np.zeros(q.size, dtype=bool),
        )
    Q, p, K, dk = robot.kinematics.jacobian_hessian(q)
    z, grad, H = index.evaluate(q) if zgh is None else zgh
    _, aux = res.error(Q, p)
    normality, lam, L, active = bound_kkt(res.normal_rows(K, aux), grad, q, robot.lower, robot.upper, bounds)  # (D.30)
    lam_k, extra = res.normal_multipliers(K, lam, aux)
    return second_order(res.residual(Q, p), OptimalityTerms(normality, float(z), H, dk, lam_k, L, active, extra),
                        res.rows)


def second_order(residual: float, t: OptimalityTerms, rows: np.ndarray) -> Optimality:
    """The report of Eq. (D.33) from the first-order terms at one q (:func:`optimality_at`, or the
    converged iteration of a start of :func:`kinredund.ik.solve.solve_ik`)."""
    M = t.hessian + t.dk.contract(t.multipliers, rows)  # Hess z + Lambda*, Eq. (4.37)
    if t.extra is not None:
        M = M + t.extra
    L = t.null_space
    Br = L.T @ M @ L
    Br = 0.5 * (Br + Br.T)  # symmetric on the null space of K (Section 4.2)
    if Br.shape[0]:
        w = np.linalg.eigvalsh(Br)
        min_eig = float(w[0])
        pd = bool(min_eig > RANK_TOL * max(1.0, float(np.abs(w).max())))  # Eq. (D.33)
    else:
        min_eig, pd = float("inf"), True
    return Optimality(residual, t.normality, t.objective, pd, min_eig, t.multipliers, Br, L, t.active)
