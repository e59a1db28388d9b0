"""Random reachable circles: the task generator of ``benchmarks/random_tasks.py`` and the planner's tests.

:func:`random_circle` draws one task for a robot from a ``numpy`` generator:

- a configuration q_c uniform inside the joint limits (shrunk by 5 % of each range at either end);
  (Q_c, p_c) = FK(q_c);
- the radius r uniform in [0.01, 0.10] m;
- the orientation, with equal odds: ``held`` (Q_d = Q_c all along, the circle's plane normal uniform on
  the sphere) or ``frenet`` (Q_d the circle's Frenet frame [e_n, e_t, n] of Eq. 4.47, with the plane
  normal n = Q_c's z axis and the start direction e_1 = Q_c's x axis, so that Q_d(0) = Q_c);
- the centre c = p_c (the circle runs around a reachable point);
- the speed uniform in [0.05, 0.25] m/s (the step is T / steps_per_loop whatever the speed);
- the index, with equal odds: ``posture`` (JointDeviation to a second configuration uniform inside the
  limits) or ``mid_range`` (Eq. 4.49 over all joints).

A circle around a reachable point can still leave the within-limits workspace (with a held orientation
it often does): :func:`reachable` screens a task (a within-limits IK solution at 48 points of the loop),
and the benchmark draws again until a task passes, counting the rejections.

A :class:`CircleTask` is a plain record of these numbers, so a case found by the generator can be kept by
name (:data:`NAMED_CASES`) and rebuilt without the random stream.

Units: lengths [m], speeds [m/s], angles [rad].
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from kinredund.errors import check_choice
from kinredund.indices import Index, JointDeviation, mid_range
from kinredund.paths import Circle

RADIUS_RANGE = (0.01, 0.10)
SPEED_RANGE = (0.05, 0.25)
CONFIGURATION_MARGIN = 0.05
ORIENTATIONS = ("held", "frenet")
INDICES = ("posture", "mid_range")


@dataclass(frozen=True)
class CircleTask:
    """One circle task: what :func:`random_circle` drew (module docstring).

    Attributes:
        robot: the robot's name.
        center: c [m], (3,).
        radius: r [m].
        speed: [m/s].
        normal: the plane normal (3,).
        axis_x: the start direction e_1 (3,), normal to ``normal``.
        orientation: ``held`` or ``frenet``.
        Q: the held orientation (3x3 nested lists) for ``held``, else None.
        index: ``posture`` or ``mid_range``.
        reference: the posture of the ``posture`` index [rad], else None.
    """

    robot: str
    center: tuple
    radius: float
    speed: float
    normal: tuple
    axis_x: tuple
    orientation: str
    Q: tuple | None
    index: str
    reference: tuple | None

    def path(self) -> Circle:
        """The circle (a pose path)."""
        check_choice("circle orientation", self.orientation, ORIENTATIONS)
        if self.orientation == "held":
            return Circle(np.array(self.center), self.radius, self.speed, normal=self.normal, axis_x=self.axis_x,
                          orientation=np.array(self.Q))
        return Circle(np.array(self.center), self.radius, self.speed, normal=self.normal, axis_x=self.axis_x,
                      frenet=True)

    def performance_index(self, robot) -> Index:
        """The index z on ``robot``."""
        check_choice("circle index", self.index, INDICES)
        if self.index == "posture":
            return JointDeviation(np.array(self.reference))
        return mid_range(robot.lower, robot.upper)

    def to_dict(self) -> dict:
        """JSON-ready numbers."""
        return asdict(self)


def reachable(robot, task: CircleTask, points: int = 48, starts: int = 32, seed: int = 0) -> bool:
    """Whether the circle's pose at each of ``points`` equally spaced times has a within-limits IK solution
    (pose only, ``starts`` starts): the generator's screen (a task that fails it is drawn again)."""
    from kinredund.ik.solve import solve_ik
    from kinredund.tasks.target import make_target

    path = task.path()
    for t in np.arange(points) * float(path.period) / points:
        s = path(float(t))
        if not solve_ik(robot, make_target("pose", (s.Q, s.p)), None, bounds=True, starts=starts, seed=seed).converged:
            return False
    return True


def _unit(v: np.ndarray) -> tuple:
    return tuple(float(x) for x in v / np.linalg.norm(v))


def random_circle(robot, rng: np.random.Generator) -> CircleTask:
    """One task of the generator (module docstring) for ``robot`` from ``rng``."""
    qc = robot.random_configuration(rng, CONFIGURATION_MARGIN)
    T = robot.fk(qc)
    Qc, pc = T[:3, :3], T[:3, 3]
    radius = float(rng.uniform(*RADIUS_RANGE))
    speed = float(rng.uniform(*SPEED_RANGE))
    orientation = ORIENTATIONS[int(rng.integers(2))]
    if orientation == "held":
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = helper - (helper @ n) * n
        normal, axis_x, Q = _unit(n), _unit(e1), tuple(tuple(float(x) for x in row) for row in Qc)
    else:
        normal, axis_x, Q = _unit(Qc[:, 2]), _unit(Qc[:, 0]), None
    kind = INDICES[int(rng.integers(2))]
    ref = tuple(float(x) for x in robot.random_configuration(rng)) if kind == "posture" else None
    return CircleTask(robot.name, tuple(float(x) for x in pc), radius, speed, normal, axis_x, orientation, Q,
                      kind, ref)


__all__ = ["INDICES", "ORIENTATIONS", "RADIUS_RANGE", "SPEED_RANGE", "CircleTask", "random_circle", "reachable"]
