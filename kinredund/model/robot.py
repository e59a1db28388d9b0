"""Robots: a Pinocchio model, its end-effector frame, joint limits and task kind (Chapter 2).

:func:`~kinredund.model.loader.load_robot` (also importable from here and from ``kinredund``) is the
entry point: it accepts a shipped name (the thesis's robots in ``robots/``), an arm of
example-robot-data by name (``kinredund.model.erd``), or the path of any URDF file.

Task kinds set the task dimension m of Chapter 4: ``planar`` (x, y of point P: m = 2), ``position``
(p: m = 3), ``axis`` (p and the direction of a tool axis, the spin about it free: m = 5) and ``pose``
(orientation and position: m = 6).

Threads: a :class:`Robot` may be shared between threads. Its model is never modified, and
``robot.kinematics`` (the Pinocchio ``Data`` workspace every solver computes in) is one
:class:`~kinredund.kinematics.state.Kinematics` per thread, made on first use in that thread.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from kinredund.errors import JointVectorError, KinredundError, OptionError, check_joint_vector
from kinredund.kinematics.hd import REVOLUTE, HDTable
from kinredund.kinematics.state import Kinematics, PerThread
from kinredund.model.frames import TOOL_AXIS_FRAME, resolve_frame
from kinredund.model.source import record_source, split_source
from kinredund.model.urdf import EE_FRAME
from kinredund.tasks import get_task

#: a joint limit (or velocity limit) at or beyond this magnitude is no limit at all: Pinocchio's default is
#: +-1.8e308, a continuous joint gets +-1e12 (``urdf.UNBOUNDED_LIMIT``)
NO_LIMIT = 1e10

_PRISMATIC_SHORTNAMES = {"JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned"}


def robot_revolute(model: pin.Model) -> np.ndarray:
    """Which joints of the model are revolute (True) rather than prismatic (False)."""
    return np.array([model.joints[j].shortname() not in _PRISMATIC_SHORTNAMES for j in range(1, model.njoints)],
                    dtype=bool)


class Robot:
    """A serial manipulator: Pinocchio model, end-effector frame, limits and task kind.

    Attributes:
        name: a short name.
        model: the Pinocchio model (never modified).
        ee_frame: the end-effector frame's name; point P is its origin.
        ee_frame_id: its index in ``model.frames``; ``ee_frame_info`` says which frame was taken
            when a joint and a link share the name (the link is preferred).
        task: ``planar``, ``position``, ``axis`` or ``pose``.
        tool_axis: the tool axis given to ``load_robot`` (unit, shape (3,)) in the frame it was given
            in; the ``axis`` task holds the z axis of ``ee_frame`` (a frame turned onto that axis).
        lower, upper: joint limits [rad or m], shape (nq,); +-1e12 for a joint without limits
            (a continuous joint, loaded as a revolute one).
        hd: the HD table the model was built from, or None for URDF robots.
        urdf_path: the URDF file, when there is one (used by playback).
        package_dirs: folders for ``package://`` mesh paths.
        home: a default configuration inside the limits.
        locked: joint name -> value of the joints of the file that were locked (``load_robot(joints=)``).
        continuous: the names of the joints that were continuous in the URDF.
        source: what :func:`kinredund.load_robot` reloads this robot from, options included
            (:mod:`kinredund.model.source`; a record stores it), or None for a robot not made by it.
        kinematics: this thread's :class:`~kinredund.kinematics.state.Kinematics` (one per thread).
    """

    def __init__(
        self,
        name: str,
        model: pin.Model,
        ee_frame: str,
        task: str,
        *,
        hd: HDTable | None = None,
        urdf_path=None,
        package_dirs: tuple[str, ...] = (),
        home: np.ndarray | None = None,
        tool_axis: np.ndarray | None = None,
        locked: dict | None = None,
        continuous: tuple[str, ...] = (),
    ):
        get_task(task)  # ChoiceError for an unknown kind
        if model.nq != model.nv:
            odd = [model.names[j] for j in range(1, model.njoints) if model.joints[j].nq != model.joints[j].nv]
            raise JointVectorError(
                f"model {name!r} has nq={model.nq} != nv={model.nv} (joints {', '.join(odd)}): only revolute and "
                "prismatic joints (one coordinate each) are supported; lock the others with load_robot(joints=...)"
            )
        self.ee_frame_id, self.ee_frame_info = resolve_frame(model, ee_frame)
        self.name = name
        self.model = model
        self.ee_frame = ee_frame
        self.task = task
        self.hd = hd
        self.urdf_path = urdf_path
        self.package_dirs = package_dirs
        self.tool_axis = np.array((0.0, 0.0, 1.0) if tool_axis is None else tool_axis, dtype=float)
        self.locked = dict(locked or {})
        self.continuous = tuple(continuous)
        self.source: str | None = None  # set by load_robot: what a record stores to reload it (model.source)
        self.lower = np.array(model.lowerPositionLimit, dtype=float)
        self.upper = np.array(model.upperPositionLimit, dtype=float)
        for a in (self.lower, self.upper, self.tool_axis):
            a.flags.writeable = False
        self._kinematics = PerThread(model, self.ee_frame_id)
        mid = 0.5 * (self.lower + self.upper)
        self.home = np.array(home, dtype=float) if home is not None else np.where(np.isfinite(mid), mid, 0.0)
        if hd is not None:
            self.revolute = np.array([k == REVOLUTE for k in hd.kinds])
        else:
            self.revolute = robot_revolute(model)

    @property
    def kinematics(self) -> Kinematics:
        """This thread's kinematics workspace (a Pinocchio ``Data``), made on first use in the thread.

        Solvers compute in it; a workspace shared between threads would mix their forward-kinematics
        passes (wrong poses with right joint values), so every thread gets its own (:class:`PerThread`).
        """
        return self._kinematics.get()

    # -- basic facts ------------------------------------------------------------------------------
    @property
    def nq(self) -> int:
        """The number of joints n."""
        return self.model.nq

    @property
    def task_dim(self) -> int:
        """The task dimension m: 2 (planar), 3 (position), 5 (axis) or 6 (pose)."""
        return get_task(self.task).dim

    @property
    def joint_names(self) -> list[str]:
        """Joint names in the order of q (a new list; read from the model once per model)."""
        kept = self.__dict__.get("_joint_names")
        if kept is None or kept[0] is not self.model:
            kept = self._joint_names = (self.model, tuple(self.model.names)[1:])
        return list(kept[1])

    def with_task(self, task: str) -> Robot:
        """The same robot with another task kind (a new workspace; the model is shared).

        A tool axis belongs to the tasks that hold one (``axis``): for another kind the end-effector frame is the
        one a turned tool axis was added to (the same origin), as ``load_robot(name, task=task)`` gives, and
        ``source`` drops the axis, so that a record or a pickled copy reloads this robot (``load_robot`` refuses a
        tool axis for such a task).
        """
        frame, axis, source = self.ee_frame, self.tool_axis, self.source
        if not get_task(task).takes_tool_axis:
            parent = self.model.frames[self.model.frames[self.ee_frame_id].parentFrame].name
            if not np.array_equal(axis, (0.0, 0.0, 1.0)) and frame == parent + TOOL_AXIS_FRAME:  # added by load_robot
                frame = parent
            axis = None
            if source is not None:
                base, options = split_source(source)
                options.pop("tool_axis", None)
                source = record_source(base, **options)
        other = Robot(
            self.name, self.model, frame, task, hd=self.hd, urdf_path=self.urdf_path,
            package_dirs=self.package_dirs, home=self.home, tool_axis=axis, locked=self.locked,
            continuous=self.continuous,
        )
        other.source = source
        return other

    def __repr__(self) -> str:
        return f"Robot({self.name!r}, nq={self.nq}, ee_frame={self.ee_frame!r}, task={self.task!r})"

    # -- validation -------------------------------------------------------------------------------
    def check_q(self, q, what: str = "joint vector") -> np.ndarray:
        """Return q as a float array of length nq, or raise :class:`JointVectorError`."""
        if type(q) is np.ndarray and q.dtype == np.float64 and q.shape == (self.model.nq,) \
                and sum(map(abs, q.tolist())) < math.inf:  # the common case (check_joint_vector returns q itself)
            return q
        return check_joint_vector(q, self.nq, self.name, what)

    # -- kinematics (validated wrappers over the kinematics layer) --------------------------------
    def fk(self, q) -> np.ndarray:
        """The 4x4 homogeneous end-effector pose [m]: Q_1 ... Q_n and p of Eq. (2.3)."""
        R, p = self.kinematics.pose(self.check_q(q))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, p
        return T

    def velocity_jacobian(self, q) -> np.ndarray:
        """K of Eq. (2.16), shape (6, n), rows [omega; pdot], world axes, at point P."""
        return self.kinematics.jacobian(self.check_q(q))[2]

    def position_jacobian(self, q) -> np.ndarray:
        """The pdot rows of K, shape (3, n) [m/rad]."""
        return self.kinematics.jacobian(self.check_q(q))[2][3:]

    def velocity_jacobian_derivative(self, q) -> np.ndarray:
        """dK/dtheta, shape (6, n, n): dK[a, i, k] = dK[a, i]/dtheta_k (Eqs. 4.38-4.41)."""
        return self.kinematics.jacobian_derivative(self.check_q(q))[3]

    def reach(self, joint: int, radius: float, extent=None) -> np.ndarray:
        """L (n,) [m/rad or m/m]: along a straight joint path, joint j moves every point within ``radius`` [m] of
        the origin of Pinocchio joint ``joint`` by at most L[j] |dq_j|.

        Up the chain each joint offset adds its length and a prismatic joint p its slide |q_p| (the triangle
        inequality), so a revolute joint j moves the points by at most their distance from its origin times
        |dq_j| (a prismatic one by |dq_j|). ``extent`` (n,) [rad or m] bounds |q_j| over the motion (only the
        prismatic joints' count); the default, max(|lower|, |upper|), holds within the robot's joint box.
        """
        model = self.model
        ext = np.maximum(np.abs(self.lower), np.abs(self.upper)) if extent is None else np.abs(extent)
        L, reach, j = np.zeros(model.nv), float(radius), int(joint)
        while j > 0:  # joint j moves the points: its origin is within `reach` of every one of them
            revolute = bool(self.revolute[j - 1])
            L[model.idx_vs[j]] = reach if revolute else 1.0
            reach += float(np.linalg.norm(model.jointPlacements[j].translation))
            reach += 0.0 if revolute else float(ext[model.idx_qs[j]])  # the slide moves the origin
            j = model.parents[j]
        return L

    def sample_box(self, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi): the box random configurations are drawn from. The joint limits, with unbounded
        ones (beyond :data:`NO_LIMIT`) cut to [-pi, pi] (revolute) or [-1, 1] m (prismatic), shrunk by ``margin``
        (a fraction of each range) at either end."""
        wide = np.where(self.revolute, np.pi, 1.0)
        lo = np.where(self.lower > -NO_LIMIT, self.lower, -wide)
        hi = np.where(self.upper < NO_LIMIT, self.upper, wide)
        span = hi - lo
        return lo + margin * span, hi - margin * span

    def random_configuration(self, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
        """A uniform sample of :meth:`sample_box` (the limits shrunk by ``margin``)."""
        return rng.uniform(*self.sample_box(margin))


def robot_from_hd(table: HDTable, task: str = "pose") -> Robot:
    """A robot built straight from an HD table (no URDF on disk)."""
    from kinredund.model.urdf import hd_to_model

    return Robot(table.name, hd_to_model(table), EE_FRAME, task, hd=table)


def check_robot(robot, error: type[KinredundError] = OptionError) -> Robot:
    """``robot`` if it is a :class:`Robot`, else ``error`` saying so (an entry point's first check: the attributes
    it reads next would fail as Python's AttributeError on None or a robot's name)."""
    if not isinstance(robot, Robot):
        raise error(f"robot must be a kinredund Robot (see kinredund.load_robot), got {type(robot).__name__}")
    return robot
