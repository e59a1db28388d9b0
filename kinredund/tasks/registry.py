"""The task kinds by name. To add a kind: one new file with a :class:`~kinredund.tasks.base.Task`
subclass, one line in :data:`TASKS`, and its tests (see docs/architecture.md)."""

from __future__ import annotations

from kinredund.errors import ChoiceError
from kinredund.tasks.axis import AxisTask
from kinredund.tasks.base import Task
from kinredund.tasks.planar import PlanarTask
from kinredund.tasks.pose import PoseTask
from kinredund.tasks.position import PositionTask

#: every task kind, by name (the task objects hold no state: one instance each)
TASKS: dict[str, Task] = {task.name: task for task in (PlanarTask(), PositionTask(), PoseTask(), AxisTask())}


def task_names() -> tuple[str, ...]:
    """The names of every task kind."""
    return tuple(TASKS)


def get_task(task: str | Task) -> Task:
    """The task object of a kind's name (a Task is returned as it is).

    Raises:
        ChoiceError: an unknown name (lists the known kinds).
    """
    if type(task) is str:  # the common case first (Task is an ABC: its isinstance costs more than the lookup)
        found = TASKS.get(task)
        if found is not None:
            return found
    if isinstance(task, Task):
        return task
    found = TASKS.get(task) if isinstance(task, str) else None
    if found is None:
        raise ChoiceError("task kind", task, task_names())
    return found
