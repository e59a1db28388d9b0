"""Robots: a Pinocchio model, its end-effector frame, joint limits and task kind (Chapter 2).

:func:`load_robot` is the entry point. It accepts a shipped name (the thesis's robots in ``robots/``),
a 7-axis arm of example-robot-data by name, or the path of any URDF file.

Task kinds set the task dimension m of Chapter 4: ``planar`` (x, y of point P: m = 2), ``position``
(p: m = 3) and ``pose`` (orientation and position: m = 6).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import pinocchio as pin

from kinredund.errors import (
    FrameNotFoundError,
    JointVectorError,
    KinredundError,
    UnknownRobotError,
    check_joint_vector,
)
from kinredund.kinematics.hd import REVOLUTE, HDTable
from kinredund.kinematics.state import Kinematics
from kinredund.model.catalog import SHIPPED_HOMES, SHIPPED_TABLES, SHIPPED_TASKS
from kinredund.model.urdf import EE_FRAME, load_urdf_model
from kinredund.tasks import get_task


@dataclass(frozen=True)
class _ERDArm:
    urdf: str
    ee_frame: str
    drop_joints: tuple[str, ...] = ()
    home: tuple[float, ...] | None = None


#: 7-axis arms of example-robot-data (6.0.0 ships URDFs only; loaded by path, see STACK.md)
ERD_ARMS = {
    "panda": _ERDArm(
        "panda_description/urdf/panda.urdf", "panda_hand",
        ("panda_finger_joint1", "panda_finger_joint2"),
        (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785),
    ),
    "xarm7": _ERDArm("xarm_description/urdf/xarm7.urdf", "link_eef", (), (0.0, -0.5, 0.0, 0.5, 0.0, 1.0, 0.0)),
}


def known_robots() -> list[str]:
    """Every name :func:`load_robot` accepts."""
    return sorted(SHIPPED_TABLES) + sorted(ERD_ARMS)


def shipped_robot_dir() -> Path:
    """The folder of the shipped URDF files: package data when installed, ``robots/`` in a checkout."""
    try:
        path = Path(str(resources.files("kinredund.robots")))
        if (path / "planar3r.urdf").exists():
            return path
    except ModuleNotFoundError:
        pass
    return Path(__file__).resolve().parent.parent / "robots"


def erd_share_dir() -> Path:
    """example-robot-data's ``robots`` folder (inside ``cmeel.prefix/share``)."""
    for entry in sys.path:
        candidate = Path(entry or ".") / "cmeel.prefix" / "share" / "example-robot-data" / "robots"
        if candidate.is_dir():
            return candidate
    raise KinredundError(
        "example-robot-data is not installed (pip install example-robot-data): "
        "no robots/ folder under cmeel.prefix/share on sys.path"
    )


class Robot:
    """A serial manipulator: Pinocchio model, end-effector frame, limits and task kind.

    Attributes:
        name: a short name.
        model: the Pinocchio model (never modified).
        ee_frame: the end-effector frame's name; point P is its origin.
        task: ``planar``, ``position`` or ``pose``.
        lower, upper: joint limits [rad or m], shape (nq,).
        hd: the HD table the model was built from, or None for URDF robots.
        urdf_path: the URDF file, when there is one (used by playback).
        package_dirs: folders for ``package://`` mesh paths.
        home: a default configuration inside the limits.
    """

    def __init__(
        self,
        name: str,
        model: pin.Model,
        ee_frame: str,
        task: str,
        *,
        hd: HDTable | None = None,
        urdf_path: Path | None = None,
        package_dirs: tuple[str, ...] = (),
        home: np.ndarray | None = None,
    ):
        get_task(task)  # ChoiceError for an unknown kind
        if not model.existFrame(ee_frame):
            raise FrameNotFoundError(ee_frame, [f.name for f in model.frames])
        if model.nq != model.nv:
            raise JointVectorError(
                f"model {name!r} has nq={model.nq} != nv={model.nv}: only revolute and prismatic joints "
                "(one coordinate each) are supported"
            )
        self.name = name
        self.model = model
        self.ee_frame = ee_frame
        self.task = task
        self.hd = hd
        self.urdf_path = urdf_path
        self.package_dirs = package_dirs
        self.lower = np.array(model.lowerPositionLimit, dtype=float)
        self.upper = np.array(model.upperPositionLimit, dtype=float)
        self.lower.flags.writeable = False
        self.upper.flags.writeable = False
        self.kinematics = Kinematics(model, model.getFrameId(ee_frame))
        mid = 0.5 * (self.lower + self.upper)
        self.home = np.array(home, dtype=float) if home is not None else np.where(np.isfinite(mid), mid, 0.0)
        if hd is not None:
            self.revolute = np.array([k == REVOLUTE for k in hd.kinds])
        else:
            self.revolute = np.array(
                [model.joints[j].shortname() not in _PRISMATIC_SHORTNAMES for j in range(1, model.njoints)]
            )

    # -- basic facts ------------------------------------------------------------------------------
    @property
    def nq(self) -> int:
        """The number of joints n."""
        return self.model.nq

    @property
    def task_dim(self) -> int:
        """The task dimension m: 2 (planar), 3 (position) or 6 (pose)."""
        return get_task(self.task).dim

    @property
    def joint_names(self) -> list[str]:
        """Joint names in the order of q."""
        return list(self.model.names)[1:]

    def with_task(self, task: str) -> Robot:
        """The same robot with another task kind (a new workspace; the model is shared)."""
        return Robot(
            self.name, self.model, self.ee_frame, task, hd=self.hd, urdf_path=self.urdf_path,
            package_dirs=self.package_dirs, home=self.home,
        )

    def __repr__(self) -> str:
        return f"Robot({self.name!r}, nq={self.nq}, ee_frame={self.ee_frame!r}, task={self.task!r})"

    # -- validation -------------------------------------------------------------------------------
    def check_q(self, q, what: str = "joint vector") -> np.ndarray:
        """Return q as a float array of length nq, or raise :class:`JointVectorError`."""
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

    def sample_box(self, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi): the box random configurations are drawn from. The joint limits, with unbounded
        ones (beyond 1e10) cut to [-pi, pi] (revolute) or [-1, 1] m (prismatic), shrunk by ``margin``
        (a fraction of each range) at either end."""
        wide = np.where(self.revolute, np.pi, 1.0)
        lo = np.where(self.lower > -1e10, self.lower, -wide)
        hi = np.where(self.upper < 1e10, self.upper, wide)
        span = hi - lo
        return lo + margin * span, hi - margin * span

    def random_configuration(self, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
        """A uniform sample of :meth:`sample_box` (the limits shrunk by ``margin``)."""
        return rng.uniform(*self.sample_box(margin))


_PRISMATIC_SHORTNAMES = {"JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned"}


def _load_erd(name: str, task: str | None, ee_frame: str | None) -> Robot:
    spec = ERD_ARMS[name]
    share = erd_share_dir()
    path = share / spec.urdf
    model, _ = load_urdf_model(path)
    if spec.drop_joints:
        ids = [model.getJointId(j) for j in spec.drop_joints]
        model = pin.buildReducedModel(model, ids, pin.neutral(model))
    return Robot(
        name, model, ee_frame or spec.ee_frame, task or "pose", urdf_path=path,
        package_dirs=(str(share.parent.parent),), home=np.array(spec.home) if spec.home else None,
    )


def _default_ee_frame(model: pin.Model) -> str:
    if model.existFrame(EE_FRAME):
        return EE_FRAME
    return model.frames[len(model.frames) - 1].name


def load_robot(name_or_path: str | Path, ee_frame: str | None = None, task: str | None = None) -> Robot:
    """Load a robot by shipped name, example-robot-data name, or URDF path.

    Args:
        name_or_path: ``planar3r``, ``planar3r_ch6``, ``puma7``, ``cybotech_p15``, ``panda``,
            ``xarm7``, or the path of a URDF file.
        ee_frame: the end-effector frame (point P is its origin). Default: ``ee`` for the shipped
            robots, the hand or flange for example-robot-data arms, and for a URDF file a frame
            named ``ee`` if there is one, else the last frame.
        task: ``planar``, ``position`` or ``pose``; default: the robot's own (``pose`` for URDF files).

    Raises:
        UnknownRobotError: the name is not known and no such file exists (lists the known names).
        URDFError: the file does not parse; the message says why.
        FrameNotFoundError: ``ee_frame`` is not in the model (lists the frames).
    """
    if task is not None:
        get_task(task)
    key = str(name_or_path)
    if key in SHIPPED_TABLES:
        path = shipped_robot_dir() / f"{key}.urdf"
        model, _ = load_urdf_model(path)
        return Robot(
            key, model, ee_frame or EE_FRAME, task or SHIPPED_TASKS[key], hd=SHIPPED_TABLES[key](),
            urdf_path=path, home=np.array(SHIPPED_HOMES[key]),
        )
    if key in ERD_ARMS:
        return _load_erd(key, task, ee_frame)
    path = Path(key)
    if path.suffix.lower() in (".urdf", ".xml") or path.exists():
        if not path.exists():
            raise UnknownRobotError(key, known_robots())
        model, _ = load_urdf_model(path)
        return Robot(
            path.stem, model, ee_frame or _default_ee_frame(model), task or "pose", urdf_path=path,
            package_dirs=(str(path.parent),),
        )
    raise UnknownRobotError(key, known_robots())


def robot_from_hd(table: HDTable, task: str = "pose") -> Robot:
    """A robot built straight from an HD table (no URDF on disk)."""
    from kinredund.model.urdf import hd_to_model

    return Robot(table.name, hd_to_model(table), EE_FRAME, task, hd=table)
