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
    """Whether the circle's target for the robot's own task (the pose for a pose task, the tool axis and point
    for an axis task) at each of ``points`` equally spaced times has a within-limits IK solution (task only,
    ``starts`` starts): the generator's screen (a task that fails it is drawn again)."""
    from kinredund.ik.solve import solve_ik
    from kinredund.tasks import get_task

    path, kind = task.path(), get_task(robot.task)
    for t in np.arange(points) * float(path.period) / points:
        if not solve_ik(robot, kind.target_at(path, float(t)), None, bounds=True, starts=starts, seed=seed).converged:
            return False
    return True


def _unit(v: np.ndarray) -> tuple:
    return tuple(float(x) for x in v / np.linalg.norm(v))


def random_circle(robot, rng: np.random.Generator, orientations: tuple[str, ...] = ORIENTATIONS) -> CircleTask:
    """One task of the generator (module docstring) for ``robot`` from ``rng``; ``orientations``: the kinds
    drawn from, with equal odds (``("held",)``: the orientation held all along)."""
    qc = robot.random_configuration(rng, CONFIGURATION_MARGIN)
    T = robot.fk(qc)
    Qc, pc = T[:3, :3], T[:3, 3]
    radius = float(rng.uniform(*RADIUS_RANGE))
    speed = float(rng.uniform(*SPEED_RANGE))
    orientation = orientations[int(rng.integers(len(orientations)))]
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


def draw(robot, rng: np.random.Generator, orientations: tuple[str, ...] = ORIENTATIONS,
         max_draws: int = 50) -> tuple[CircleTask, int]:
    """A :func:`reachable` task of :func:`random_circle` and the number of draws rejected before it.

    Raises:
        RuntimeError: none of ``max_draws`` draws is reachable.
    """
    for rejected in range(max_draws):
        task = random_circle(robot, rng, orientations)
        if reachable(robot, task):
            return task, rejected
    raise RuntimeError(f"no reachable circle in {max_draws} draws on {robot.name}")


def drawn(robot, n: int, seed: int, orientations: tuple[str, ...] = ORIENTATIONS):
    """The benchmarks' ``n`` tasks on ``robot`` from ``np.random.default_rng(seed)``: (i, task, rejected draws)."""
    rng = np.random.default_rng(seed)
    for i in range(n):
        task, rejected = draw(robot, rng, orientations)
        yield i, task, rejected


def task_arguments(p, robots: tuple[str, ...], n: int, smoke_robot: str):
    """The benchmarks' task options on the parser ``p`` (``--robot``, ``--n``, ``--seed``, ``--quiet``), parsed:
    ``--smoke`` is one task on ``smoke_robot``, quietly."""
    p.add_argument("--robot", choices=robots, default=None, help=f"one robot (default: {', '.join(robots)})")
    p.add_argument("--n", type=int, default=n, help=f"tasks per robot (default {n})")
    p.add_argument("--seed", type=int, default=0, help="seed of the task generator (default 0)")
    p.add_argument("--quiet", action="store_true", help="no line per task")
    args = p.parse_args()
    if args.smoke:
        args.robot, args.n, args.quiet = smoke_robot, 1, True
    if args.n < 1:
        p.error(f"--n must be >= 1, got {args.n}")
    return args


def start_of(robot, task: CircleTask, seed: int):
    """The start every method of the benchmark shares: the within-limits optimum of the task's index at
    t = 0 for the robot's own task by ``solve_ik(..., bounds=True, starts=16, seed=seed)`` (an
    :class:`~kinredund.ik.solve.IKResult`)."""
    from kinredund.ik.solve import solve_ik
    from kinredund.tasks import get_task

    target = get_task(robot.task).target_at(task.path(), 0.0)
    return solve_ik(robot, target, task.performance_index(robot), bounds=True, starts=16, seed=seed)


def _held(robot, center, radius, speed, normal, axis_x, Q, index="mid_range", reference=None) -> CircleTask:
    return CircleTask(robot, center, radius, speed, normal, axis_x, "held", Q, index, reference)


#: Tasks the generator drew (``np.random.default_rng(11)`` on the Panda, ``(12)`` on the xArm7), kept by
#: name with the seed of their start (:func:`start_of`):
#:
#: - ``panda_fold``: from its start the strict tracker without limits meets an algorithmic singularity (a
#:   fold of the unconstrained optimum, R singular with J of full rank) at t = 1.85 s; the within-limits
#:   optimum rides the lower limit of joint 2 instead.
#: - ``xarm7_fold``: the strict tracker without limits meets an algorithmic singularity at t = 0.40 s.
#: - ``panda_fold_followed`` (``default_rng(21)``): from its start the strict tracker without limits meets
#:   an algorithmic singularity at t = 0.89 s; the within-limits minimum of its branch ceases to exist
#:   twice in the loop, and the plan from that start follows its reference there.
#: - ``panda_limit``: the strict tracker without limits completes the loops, but 0.013 rad beyond a limit:
#:   the unconstrained optimum meets a limit.
NAMED_CASES: dict[str, tuple[CircleTask, int]] = {
    "panda_fold": (_held(
        "panda", (-0.4374239915514832, 0.411988598142515, 0.42218921602899434), 0.07848929013431506,
        0.06412068725073046, (-0.2092917110145177, -0.9188273981662223, 0.3345940705985478),
        (0.9778532505957198, -0.19665830038614993, 0.0716137779244694),
        ((-0.6731121553727186, -0.7195253910288438, -0.17088954899080863),
         (0.6650589370600773, -0.4878754214823251, -0.5653973676539039),
         (0.3234449513070392, -0.4942274625900841, 0.806921668252721))), 22),
    "xarm7_fold": (_held(
        "xarm7", (-0.31156826260412745, 0.010238446606960466, 0.8269664475215209), 0.07034594266490501,
        0.23932374067039558, (-0.13405764520530697, -0.7071839529290573, -0.6942041518758304),
        (0.9909735353489557, -0.0956669497972683, -0.09391105874431879),
        ((-0.057126660652616734, -0.49953420719241837, -0.8644085379537413),
         (0.9711704746730064, 0.17290893456001305, -0.16410487339725782),
         (0.23143995715107135, -0.84886281352994, 0.47525516308604926))), 2),
    "panda_fold_followed": (CircleTask(
        "panda", (-0.18931495395531306, -0.31477805961762595, 0.26895203878308205), 0.025826394683224396,
        0.16353983722013388, (0.3183031679169474, -0.6369556982914351, 0.7021186023088307),
        (0.947988973192218, 0.2138685388989285, -0.23574807480698953), "held",
        ((0.64454720935942, -0.22218247931676607, 0.731569436753367),
         (0.006046741827606228, -0.9553333393183701, -0.29546852235065935),
         (0.764540601812784, 0.19486702304768383, -0.6144139577746255)), "posture",
        (-0.7209401314110142, 0.9455273774030113, -2.8594318821450484, -1.3038465943266733, 0.507411561634219,
         0.20180540005672093, 1.5335792633377152)), 6),
    "panda_limit": (_held(
        "panda", (-0.3038354706244746, -0.20999219388889195, 0.4404219268770904), 0.05484417019412952,
        0.06573395172699154, (-0.6821970097963143, -0.5377298896912668, 0.4954329475898688),
        (0.7311684072940843, -0.5017144055540925, 0.462250381757047),
        ((0.020381349516606473, -0.993244941343246, -0.11423260081051119),
         (0.22353443494569014, 0.11589101704976904, -0.967781808343534),
         (0.9744829177494045, -0.005810220582891157, 0.22438646205015417))), 7),
}


__all__ = ["INDICES", "NAMED_CASES", "ORIENTATIONS", "RADIUS_RANGE", "SPEED_RANGE", "CircleTask", "random_circle",
           "reachable", "start_of"]
