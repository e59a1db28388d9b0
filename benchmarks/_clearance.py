"""Shared pieces of the clearance benchmarks: pink with a sphere barrier, and the figures of a run.

- :class:`PinkBarrier`: pin-pink's differential IK on a position task with a posture task toward the
  index's reference and, for the obstacle, ``pink.barriers.BodySphericalBarrier`` between the watched frame
  and a frame added at the sphere's center (h = ||p_f - c||^2 - d_min^2 >= 0 with d_min = radius +
  clearance: the same set as our row c = ||p_f - c|| - radius - clearance >= 0); pink's default
  configuration and velocity limits, the daqp solver, the target of each step the path's point at its end
  (dead-beat: pink has no feed-forward input), ``integrate_inplace``. The barrier's gain is pink's default
  (1); its ``safe_displacement_gain`` is pink's default (3) or 0 (``PINK_VARIANTS``): the default adds a
  damping gamma ||v||^2 to the QP with gamma = 3 / ||grad h||^2 (large, as grad h = 2 (p_f - c)^T J_p is
  small), which holds the arm back from the path. ``pink.barriers.SelfCollisionBarrier``
  is not used: it watches pairs of the robot's own collision model (an obstacle outside the robot is not one
  of them) and needs smooth convex geometries, which the URDF meshes are not.
- :func:`figures`: the smallest clearance, the drift per loop and the position error of a recorded joint
  path, all computed afresh with the robot's FK.
"""

from __future__ import annotations

import numpy as np

from kinredund.kinematics.angles import joint_drift

POSTURE_COST = 1e-3  # [cost] / [rad], pink's README value; the frame task costs 1 /m (position only)
BARRIER_GAIN = 1.0  # pink's default
SOLVER = "daqp"  # pink's fastest solver, the one its examples pick
#: pink's barrier variants: name -> safe_displacement_gain (None: BodySphericalBarrier's default, 3)
PINK_VARIANTS = {"pink_barrier": None, "pink_barrier_sd0": 0.0}


def pink_missing() -> str | None:
    """Why pink with daqp cannot run here, or None (``pip install .[bench]`` installs both)."""
    try:
        import pink  # noqa: F401
        import qpsolvers
    except ImportError as err:
        return f"not installed: {err} (pip install .[bench])"
    if SOLVER not in qpsolvers.available_solvers:
        return f"the QP solver {SOLVER!r} is not installed (pip install .[bench])"
    return None


class PinkBarrier:
    """pink on the position task, with a ``BodySphericalBarrier`` for ``sphere`` (None: no barrier).

    Args:
        robot: a kinredund Robot (its model is copied: pink attaches its limits to it).
        path: the path (its points are the targets).
        index: the performance index; its ``reference`` is the posture task's target.
        q0: the start [rad].
        dt: the time step [s].
        sphere: a :class:`~kinredund.tracking.SphereClearance` or None.
        safe_gain: the barrier's ``safe_displacement_gain`` (None: pink's default).
    """

    def __init__(self, robot, path, index, q0, dt, sphere=None, safe_gain: float | None = None):
        import pink
        import pinocchio as pin
        from pink.barriers import BodySphericalBarrier
        from pink.tasks import FrameTask, PostureTask

        model = pin.Model(robot.model)
        self.barriers = []
        if sphere is not None:
            parent = model.frames[0].parentJoint  # the universe
            model.addFrame(pin.Frame("obstacle_center", parent, 0, pin.SE3(np.eye(3), sphere.center),
                                     pin.FrameType.OP_FRAME))
            extra = {} if safe_gain is None else {"safe_displacement_gain": safe_gain}
            self.barriers.append(BodySphericalBarrier((sphere.frame, "obstacle_center"),
                                                      d_min=sphere.radius + sphere.clearance, gain=BARRIER_GAIN,
                                                      **extra))
        self.conf = pink.Configuration(model, model.createData(), np.asarray(q0, float))
        self.frame = FrameTask(robot.ee_frame, position_cost=1.0, orientation_cost=0.0)
        post = PostureTask(cost=POSTURE_COST)
        post.set_target(np.array(index.reference, float))
        self.tasks = [self.frame, post]
        self.path, self.dt, self.t = path, dt, 0.0
        self._se3, self._solve_ik, self._rot = pin.SE3, pink.solve_ik, np.eye(3)

    def step(self) -> None:
        t1 = self.t + self.dt
        self.frame.set_target(self._se3(self._rot, self.path(t1).p))
        v = self._solve_ik(self.conf, self.tasks, self.dt, solver=SOLVER, barriers=self.barriers)
        self.conf.integrate_inplace(v, self.dt)
        self.t = t1

    def state(self) -> tuple[float, np.ndarray]:
        return self.t, np.array(self.conf.q)


def figures(robot, path, sphere, ts, qs, steps_per_loop: int) -> dict:
    """Figures of a recorded run (``ts``, ``qs`` from t = 0 at every step).

    Returns:
        ``clearance`` (per point [m]), ``clearance_min`` [m], ``drift`` (max |q(kT) - q(0)| after each
        completed loop k [rad], revolute joints modulo 2 pi; q(0) the record's first point: the tracker's start
        corrected onto the optimum, up to the IK's tolerance from the q0 it was given), ``position_error_max`` [m].
    """
    qs = np.asarray(qs, float)
    c = np.array([sphere.values(q)[0] for q in qs])
    err = [np.linalg.norm(robot.fk(q)[:3, 3] - path(t).p) for t, q in zip(ts, qs, strict=True)]
    loops = (len(qs) - 1) // steps_per_loop
    drift = [joint_drift(qs[0], qs[(k + 1) * steps_per_loop], robot.revolute) for k in range(loops)]
    return {"clearance": c.tolist(), "clearance_min": float(c.min()), "drift": drift,
            "position_error_max": float(max(err))}
