"""Tasks: what the end effector must do (Chapters 2 and 4).

One :class:`~kinredund.tasks.base.Task` subclass per kind, one file each: ``planar`` (x, y of point P,
m = 2), ``position`` (p, m = 3), ``pose`` (orientation and position, m = 6), ``axis`` (point and tool
axis, the spin about it free, m = 5). Ask the task object
(:func:`get_task`) for dimensions, targets, errors, the IK residual and the tracking terms.
"""

from __future__ import annotations

import numpy as np

from kinredund.tasks.base import FORMULATIONS, Target, Task, TaskResidual, TaskTerms
from kinredund.tasks.pose import orientation_error
from kinredund.tasks.registry import TASKS, get_task, task_names


def make_target(task: str | Task, target, *, z: float = 0.0) -> Target:
    """Validate ``target`` for a task kind (see each kind's :meth:`~kinredund.tasks.base.Task.make_target`).

    Raises:
        TaskError: what is wrong with the target; ChoiceError: an unknown task kind.
    """
    return get_task(task).make_target(target, z=z)


def task_residual(target: Target) -> TaskResidual:
    """The joint-level IK's residual for a validated target."""
    return get_task(target.task).ik_residual(target)


def task_terms(task: str | Task, formulation: str, Q, p, K, dk, sample) -> TaskTerms:
    """The resolved-rate scheme's terms of a task kind at one point (:meth:`Task.tracking_terms`)."""
    return get_task(task).tracking_terms(formulation, Q, p, K, dk, sample)


def pose_errors(Q: np.ndarray, p: np.ndarray, target: Target) -> tuple[float, float, float]:
    """(position error [m], trace error, vect error) of a configuration's (Q, p) against ``target``."""
    return get_task(target.task).errors(Q, p, target)


__all__ = ["FORMULATIONS", "TASKS", "Target", "Task", "TaskResidual", "TaskTerms", "get_task", "make_target",
           "orientation_error", "pose_errors", "task_names", "task_residual", "task_terms"]
