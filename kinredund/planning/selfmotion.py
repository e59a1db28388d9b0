"""Self-motions: moving the joints while the end point stays put (the null space of J, Chapter 4).

With one degree of redundancy among the joints that move the end point (the planar 3R of Section 6.2;
axes 1-4 of the P-15 of Section 6.3, its wrist axes meeting at P), the configurations that put P at a
given point form curves - the self-motion manifold. Where the policy's optimum jumps from one branch
to another (Section 6.2.2.1: "branch switching ... is essential for obstacle avoidance"), the arm must
travel along such a curve. :func:`trace` follows it from a configuration: a predictor step along the
null-space direction of the Jacobian of the active joints, then Newton (minimum-norm) corrector steps
back onto g(theta) = x. :func:`routes` traces both ways from one configuration to another.

Units: joints [rad or m], lengths [m].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.kinematics.angles import wrap_joints
from kinredund.tasks import get_task

#: corrector tolerance on the task residual [m]
CORRECTOR_TOL = 1e-11


def active_joints(robot) -> np.ndarray:
    """Indices of the joints that move the end point (nonzero position-Jacobian columns)."""
    rng = np.random.default_rng(1)
    cols = np.zeros(robot.nq)
    for q in (np.asarray(robot.home, float), rng.uniform(-1.0, 1.0, robot.nq)):
        cols += np.linalg.norm(robot.kinematics.jacobian(q)[2][3:], axis=0)
    return np.flatnonzero(cols > 1e-12)


def _project(robot, q: np.ndarray, target: np.ndarray, act: np.ndarray, rows: np.ndarray, iters: int = 12):
    """Minimum-norm Newton steps on the active joints onto p(q) = target (``rows``: the task's rows of K).

    Returns:
        (q, K) at the converged configuration (K its velocity Jacobian), or None if it does not converge.
    """
    for _ in range(iters):
        _, p, K = robot.kinematics.jacobian(q)
        e = p[rows - 3] - target
        if np.abs(e).max() < CORRECTOR_TOL:
            return q, K
        J = K[rows][:, act]
        step = np.linalg.lstsq(J, -e, rcond=None)[0]
        if np.abs(step).max() > 0.5:
            return None
        q = q.copy()
        q[act] += step
    return None


def _null_direction(K: np.ndarray, act: np.ndarray, rows: np.ndarray, previous: np.ndarray | None
                    ) -> np.ndarray | None:
    """The unit null-space direction of the task Jacobian (rows ``rows`` of K, active joints), signed
    to continue ``previous``; None where the null space is not one-dimensional."""
    J = K[rows][:, act]
    _, s, Vt = np.linalg.svd(J)
    if Vt.shape[0] - J.shape[0] != 1 or s[-1] < 1e-9 * max(1.0, s[0]):
        return None  # not one-dimensional, or singular here
    v = np.zeros(K.shape[1])
    v[act] = Vt[-1]
    if previous is not None and v @ previous < 0:
        v = -v
    return v


@dataclass(frozen=True)
class Route:
    """A traced self-motion from one configuration to another.

    Attributes:
        points: configurations along it (continuous, the first is the start), shape (K, n).
        length: its length in joint space [rad].
        reached: True when it ended at the goal (the last point is the goal's representation nearest
            the route's end).
    """

    points: np.ndarray
    length: float
    reached: bool


def trace(robot, target, q0, direction: int, goal=None, *, step: float = 0.05, max_length: float = 40.0,
          active: np.ndarray | None = None) -> Route:
    """Follow the self-motion through q0 (on p(q) = target) one way (``direction`` +1 or -1).

    Stops at ``goal`` (within ``step``, revolute joints compared modulo 2 pi), when the curve closes
    on itself, at a singular point, or after ``max_length`` [rad]. ``active`` is
    :func:`active_joints` of the robot (computed when not given).
    """
    act = active_joints(robot) if active is None else active
    rows = get_task(robot.task).point_rows  # the end point's rows of K (x, y for planar)
    target = np.asarray(target, float)
    q = np.asarray(q0, float).copy()
    goal = None if goal is None else np.asarray(goal, float)
    v = _null_direction(robot.kinematics.jacobian(q)[2], act, rows, None)
    if v is None:
        return Route(q[None], 0.0, False)
    v = direction * v
    pts = [q.copy()]
    length = 0.0
    h = step
    while length < max_length:
        if goal is not None:
            d = wrap_joints(goal - q, robot.revolute)
            if np.abs(d).max() <= step:
                pts.append(q + d)
                return Route(np.array(pts), length + float(np.linalg.norm(d)), True)
        projected = _project(robot, q + h * v, target, act, rows)
        if projected is None:
            if h < step / 64:
                break
            h *= 0.5
            continue
        qn, K = projected
        vn = _null_direction(K, act, rows, v)
        if vn is None:
            break
        length += float(np.linalg.norm(qn - q))
        q, v = qn, vn
        pts.append(q.copy())
        h = min(step, 2 * h)
        if len(pts) > 8 and np.abs(wrap_joints(q - pts[0], robot.revolute)).max() < 0.5 * step:
            break  # back at the start: a closed curve without the goal on it
    return Route(np.array(pts), length, False)


def routes(robot, target, qa, qb, *, step: float = 0.05, max_length: float = 40.0) -> list[Route]:
    """The self-motions from qa to qb (both ways round), those that reach it, shortest first."""
    act = active_joints(robot)
    out = [trace(robot, target, qa, d, qb, step=step, max_length=max_length, active=act) for d in (1, -1)]
    return sorted([r for r in out if r.reached], key=lambda r: r.length)
