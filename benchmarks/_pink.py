"""pink's differential IK on a path, as the planning benchmarks drive it (``random_tasks.py``, ``plan_peers.py``).

:class:`PinkTracker`: pin-pink with its default limits (configuration and velocity, from the URDF) and the daqp
solver; a ``FrameTask`` on the end-effector frame (position cost 1 /m, orientation cost 1 /rad about each of the
frame's axes that the robot's task holds: all three for a pose task, the two across the tool axis for an axis
task, none for a position task; gain 1), a ``PostureTask`` toward the index's reference (cost 1e-3); the target of
each step is the path's pose at its end (dead-beat: pink has no feed-forward input), ``integrate_inplace``.
:func:`run_pink` records a run of it; an exception of pink (a configuration outside its limits, an infeasible QP)
stops the run and is its result.
"""

from __future__ import annotations

import numpy as np

from kinredund.tasks import get_task

#: the PostureTask's cost [1 / rad]
POSTURE_COST = 1e-3


def orientation_costs(robot) -> np.ndarray:
    """The FrameTask's orientation cost about the end frame's x, y, z axes for the robot's task [1 / rad]."""
    task = get_task(robot.task)
    if not task.has_orientation:
        return np.zeros(3)
    return np.ones(3) if task.holds_rotation else np.array([1.0, 1.0, 0.0])  # a tool axis: free about z


def unique_frame(pin, model, frame_id: int) -> str:
    """A name that pink's ``getFrameId`` finds for the robot's end frame ``frame_id``: its own, or, where the model
    has several frames of that name (z1's ``gripperStator`` is a body and a joint frame), an operational frame
    added at the same place (the harness's concern, not pink's limitation)."""
    frame = model.frames[frame_id]
    if sum(f.name == frame.name for f in model.frames) == 1:
        return frame.name
    name = f"{frame.name}_end"
    model.addFrame(pin.Frame(name, frame.parentJoint, frame.parentFrame, frame.placement, pin.FrameType.OP_FRAME))
    return name


class PinkTracker:
    """pink's differential IK along ``path`` from ``q0`` with time step ``dt`` [s] (module docstring)."""

    def __init__(self, robot, path, reference, q0, dt: float):
        import pink
        import pinocchio as pin
        from pink.tasks import FrameTask, PostureTask

        model = pin.Model(robot.model)  # pink attaches its limits to the model: give it a copy
        frame = unique_frame(pin, model, robot.ee_frame_id)
        self.conf = pink.Configuration(model, model.createData(), np.asarray(q0, float))
        self.frame = FrameTask(frame, position_cost=1.0, orientation_cost=orientation_costs(robot))
        post = PostureTask(cost=POSTURE_COST)
        post.set_target(np.array(reference, float))
        self.tasks = [self.frame, post]
        self.path, self.dt, self.t = path, dt, 0.0
        self._se3, self._solve_ik = pin.SE3, pink.solve_ik

    def step(self) -> None:
        t1 = self.t + self.dt
        s = self.path(t1)
        self.frame.set_target(self._se3(np.eye(3) if s.Q is None else s.Q, s.p))
        v = self._solve_ik(self.conf, self.tasks, self.dt, solver="daqp")
        self.conf.integrate_inplace(v, self.dt)
        self.t = t1


def run_pink(robot, path, reference, q0, steps: int, dt: float):
    """(t [s], q, failure): ``steps`` steps of :class:`PinkTracker`, recorded from t = 0; ``failure`` is '' or
    the exception that stopped it (its type and message), the record then up to the last good point."""
    runner = PinkTracker(robot, path, reference, q0, dt)
    ts, qs = [0.0], [np.asarray(q0, float)]
    for _ in range(steps):
        try:
            runner.step()
        except Exception as err:  # noqa: BLE001 - a peer failing is a result, not a crash
            return np.array(ts), np.array(qs), f"{type(err).__name__}: {str(err)[:160]}"
        ts.append(runner.t)
        qs.append(np.array(runner.conf.q))
    return np.array(ts), np.array(qs), ""
