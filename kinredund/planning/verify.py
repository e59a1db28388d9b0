"""Independent checks of a cyclic joint motion: limits, task error, closure, joint jumps.

:func:`verify_motion_on_path` looks only at the recorded times and joints, the robot's own forward
kinematics and the path; it does not trust any figure the solver that made the motion reports. It is
what :func:`kinredund.planning.cyclic.plan` runs on its result and what ``benchmarks/random_tasks.py``
runs on every method (ours, the planner, pink) alike.

Joint jumps: with d_k = ||q_{k+1} - q_k|| the joint change of step k, a step is a *jump* when d_k is
more than :data:`JUMP_FACTOR` times the largest change of its neighbours (the :data:`JUMP_NEIGHBOURS`
steps on either side) and more than :data:`JUMP_FLOOR`. A smooth motion sampled at a constant step has
d_k / max(neighbours) = 1 + O(dt); a branch switch inside one step (a fold jumped over) stands out by
orders of magnitude.

Units: times [s], joints [rad or m], positions [m], angles [rad].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.errors import PathError, check_array
from kinredund.paths import Path
from kinredund.tasks import get_task

#: a step is a jump when its joint change exceeds this multiple of its neighbours' largest change
JUMP_FACTOR = 4.0
#: steps on either side a step's joint change is compared with
JUMP_NEIGHBOURS = 2
#: joint changes below this are never jumps [rad]: a nearly still arm has steps of round-off size
JUMP_FLOOR = 1e-3


@dataclass(frozen=True)
class MotionCheck:
    """The figures of :func:`verify_motion_on_path`.

    Attributes:
        limit_violation: the largest excursion beyond a joint limit over all recorded points [rad or m]
            (0.0 when every point is inside).
        position_error_max: max |p(q) - p_d(t)| with the robot's FK [m].
        orientation_error_max: max angle of Q_d^T Q(q) (pose tasks), of the tool axis (axis tasks) [rad];
            0.0 for tasks without orientation.
        closure: max |q(kT) - q(0) - k turns| after each complete loop k = 1, 2, ... [rad or m], raw joint
            values (no wrapping: a motion inside limits narrower than a turn cannot gain one; ``turns`` are the
            whole turns the motion is planned to make per loop, zero unless given).
        step_max: the largest joint change of one step, max_k ||q_{k+1} - q_k|| [rad].
        jump_ratio_max: max_k d_k / max(neighbours' d) (1 + O(dt) for a smooth motion).
        jumps: the steps k (from q_k to q_{k+1}) that are jumps (module docstring).
        worst_limit_step: the recorded point of the worst limit excursion (-1 when inside).
    """

    limit_violation: float
    position_error_max: float
    orientation_error_max: float
    closure: tuple[float, ...]
    step_max: float
    jump_ratio_max: float
    jumps: tuple[int, ...]
    worst_limit_step: int

    @property
    def closure_max(self) -> float:
        """The largest closure figure (nan when not one loop is complete)."""
        return max(self.closure) if self.closure else float("nan")

    def to_dict(self) -> dict:
        """JSON-ready figures."""
        return {"limit_violation": self.limit_violation, "position_error_max": self.position_error_max,
                "orientation_error_max": self.orientation_error_max, "closure": list(self.closure),
                "step_max": self.step_max, "jump_ratio_max": self.jump_ratio_max, "jumps": list(self.jumps),
                "worst_limit_step": self.worst_limit_step}


def limit_excursion(robot, q) -> np.ndarray:
    """Per configuration, how far it lies beyond the joint limits [rad or m] (0 inside), shape (N,)."""
    q = np.atleast_2d(np.asarray(q, float))
    return np.maximum(np.maximum(robot.lower - q, q - robot.upper), 0.0).max(axis=1)


def worst_per_excursion(robot, q) -> list[int]:
    """The recorded point of the largest excursion beyond the limits in each run of consecutive points
    outside them."""
    over = limit_excursion(robot, q)
    out, k = [], 0
    while k < len(over):
        if over[k] > 0:
            j = k
            while j < len(over) and over[j] > 0:
                j += 1
            out.append(k + int(np.argmax(over[k:j])))
            k = j
        else:
            k += 1
    return out


def task_errors(robot, path: Path, t, q) -> tuple[np.ndarray, np.ndarray]:
    """(position error [m], orientation error [rad]) of each (t_k, q_k) with the robot's own FK.

    The errors are the robot's task's own (:meth:`kinredund.tasks.Task.errors_many`: a planar task
    compares x and y only); the orientation error is the angle of Q_d^T Q for a pose task, the tool
    axis's angle for an axis task, zeros for a task without orientation.
    """
    t = np.asarray(t, float)
    q = np.atleast_2d(np.asarray(q, float))
    task = get_task(robot.task)
    T = np.array([robot.fk(qk) for qk in q])
    samples = [path(float(tk)) for tk in t]
    Q, Q_d = T[:, :3, :3], np.array([s.Q for s in samples]) if task.has_orientation else None
    errors = task.errors_many(Q, T[:, :3, 3], Q_d, np.array([s.p for s in samples]))
    return errors["position_error"], task.orientation_angles(Q, Q_d)


def joint_jumps(q) -> tuple[float, float, tuple[int, ...]]:
    """(largest step change [rad], largest ratio to the neighbours, the jump steps): module docstring."""
    q = np.atleast_2d(np.asarray(q, float))
    d = np.linalg.norm(np.diff(q, axis=0), axis=1)
    if d.size < 2:
        return (float(d.max()) if d.size else 0.0), 1.0, ()
    ratios = np.ones_like(d)
    jumps = []
    for k in range(d.size):
        lo, hi = max(0, k - JUMP_NEIGHBOURS), min(d.size, k + JUMP_NEIGHBOURS + 1)
        nb = np.concatenate([d[lo:k], d[k + 1:hi]])
        ref = float(nb.max())
        ratios[k] = d[k] / ref if ref > 0 else (np.inf if d[k] > 0 else 1.0)
        if d[k] > JUMP_FLOOR and d[k] > JUMP_FACTOR * ref:
            jumps.append(k)
    return float(d.max()), float(ratios.max()), tuple(jumps)


def verify_motion_on_path(robot, path: Path, t, q, steps_per_loop: int | None = None, turns=None) -> MotionCheck:
    """Check a recorded motion (t_k, q_k) on ``path`` independently of whoever produced it.

    Args:
        robot: the :class:`kinredund.Robot` (its FK and limits are used).
        path: the path the motion should follow (closed for the closure figures).
        t: times [s], shape (N,); q: joints, shape (N, n).
        steps_per_loop: recorded steps per loop (the closure compares q_0 with q_{k s}); default the
            closed path's period over the time step.
        turns: the joint change the motion is meant to make per loop (whole turns of revolute joints) [rad],
            shape (n,); default zeros. The closure after loop k is max |q(kT) - q(0) - k turns|.

    Raises:
        PathError: times and joints of different lengths or non-finite.
    """
    t = check_array(t, (None,), "motion times [s]", PathError)
    q = check_array(q, (len(t), robot.nq), "motion joints", PathError)
    over = limit_excursion(robot, q)
    pos, ang = task_errors(robot, path, t, q)
    closure: list[float] = []
    shift = np.zeros(robot.nq) if turns is None else check_array(turns, (robot.nq,), "turns per loop [rad]", PathError)
    if path.period is not None and len(t) > 1:
        if steps_per_loop is None:
            steps_per_loop = int(round(float(path.period) / float(t[1] - t[0])))
        for loop, k in enumerate(range(steps_per_loop, len(t), steps_per_loop), start=1):
            closure.append(float(np.abs(q[k] - q[0] - loop * shift).max()))
    step, ratio, jumps = joint_jumps(q)
    worst = int(np.argmax(over)) if over.max() > 0 else -1
    return MotionCheck(float(over.max()), float(pos.max()), float(ang.max()), tuple(closure), step, ratio,
                       jumps, worst)
