"""Loading a robot: by name (the thesis's robots, the arms of example-robot-data) or from a URDF file.

:func:`load_robot` is the entry point. Beyond parsing (:func:`kinredund.model.urdf.load_urdf`) it

- keeps a chain of joints (``joints=``) and locks the others (``locked=`` gives their values) through
  ``pin.buildReducedModel`` (:mod:`kinredund.model.chain`);
- resolves the end-effector frame when a joint and a link share its name (:func:`resolve_frame`);
- chooses a home configuration that is not singular for the task (:func:`choose_home`).

Continuous joints arrive as revolute joints without limits (see ``urdf.UNBOUNDED_LIMIT``).
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
import pinocchio as pin

from kinredund.errors import (
    SIZES,
    ChoiceError,
    TaskError,
    UnknownRobotError,
    URDFError,
    check_array,
)
from kinredund.kinematics.state import Kinematics
from kinredund.model.catalog import SHIPPED_HOMES, SHIPPED_TABLES, SHIPPED_TASKS, TABLE_ROBOTS
from kinredund.model.chain import finite_mid, reduce_model
from kinredund.model.erd import ERD_ARMS, erd_share_dir
from kinredund.model.frames import TOOL_AXIS_FRAME, resolve_frame
from kinredund.model.robot import NO_LIMIT, Robot, robot_from_hd, robot_revolute
from kinredund.model.source import record_source, split_source
from kinredund.model.urdf import EE_FRAME, load_urdf
from kinredund.tasks import get_task, task_names
from kinredund.tasks.axis import frame_with_axis

#: a home is accepted when the task Jacobian's smallest singular value is at least this fraction of
#: its largest (1 / condition number); otherwise :func:`choose_home` searches nearby
HOME_CONDITION = 0.05
#: the number of seeded candidates :func:`choose_home` tries near the middle of the ranges
HOME_CANDIDATES = 64
#: limits beyond this are absent (continuous joints, +-1.8e308 defaults): a box of +-pi or +-1 m is used


def known_robots() -> list[str]:
    """Every name :func:`load_robot` accepts: the thesis's robots (shipped URDFs, then HD-table robots such
    as ``cybotech_p15_x8``), then the example-robot-data arms."""
    return sorted(SHIPPED_TABLES) + sorted(TABLE_ROBOTS) + sorted(ERD_ARMS)


@dataclass(frozen=True)
class RobotRow:
    """One line of ``kinredund robots``: a name, its joint count n, default task (dimension m) and frame."""

    name: str
    n: int
    task: str
    m: int
    ee_frame: str
    note: str


def robot_table() -> list[RobotRow]:
    """Every name of :func:`known_robots`, loaded, with its joints, default task and default frame.

    Raises:
        KinredundError: a catalogue arm does not load (example-robot-data missing or changed).
    """
    rows = []
    for name in known_robots():
        r = load_robot(name)
        note = ERD_ARMS[name].note if name in ERD_ARMS else TABLE_ROBOTS[name][2] if name in TABLE_ROBOTS \
            else "thesis robot (shipped)"
        rows.append(RobotRow(name, r.nq, r.task, r.task_dim, r.ee_frame, note))
    return rows


def shipped_robot_dir() -> Path:
    """The folder of the shipped URDF files: package data when installed, ``robots/`` in a checkout."""
    try:
        path = Path(str(resources.files("kinredund.robots")))
        if (path / "planar3r.urdf").exists():
            return path
    except ModuleNotFoundError:
        pass
    return Path(__file__).resolve().parent.parent.parent / "robots"


# -- tool axis and home -----------------------------------------------------------------------------
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def check_tool_axis(tool_axis) -> np.ndarray:
    """The unit tool axis in the end-effector frame from ``"x"``, ``"y"``, ``"z"`` (or ``"-z"``...) or a 3-vector."""
    if isinstance(tool_axis, str):
        sign, key = (-1.0, tool_axis[1:]) if tool_axis.startswith("-") else (1.0, tool_axis)
        if key not in _AXES:
            raise ChoiceError("tool axis", tool_axis, ["x", "y", "z", "-x", "-y", "-z", "a 3-vector"])
        return sign * np.array(_AXES[key])
    v = check_array(tool_axis, (3,), "tool axis ('x', 'y', 'z' or a 3-vector)", TaskError)  # no booleans
    big = float(np.abs(v).max())
    u = v / big if big > 0.0 else v  # (scaled first: the squares of entries over ~1e154 overflow to inf)
    length = float(np.linalg.norm(u))
    if not big * length >= 1e-9:
        raise TaskError(f"tool axis must be a finite non-zero 3-vector, got {tool_axis!r}")
    return u / length


def task_jacobian(K: np.ndarray, R: np.ndarray, task: str) -> np.ndarray:
    """Rows with the row space of the task's Jacobian at a configuration with rotation R and velocity
    Jacobian K (Eq. 2.16, [omega; pdot]), for conditioning checks: the task's own
    :meth:`~kinredund.tasks.Task.span_rows` with the path's rotation taken as R (the tool-axis task:
    pdot and the two components of omega normal to the axis a = R e_z; the spin about a is free).
    """
    return get_task(task).span_rows(R, K, R)


def conditioning(kin: Kinematics, q: np.ndarray, task: str) -> float:
    """sigma_min / sigma_max of the task Jacobian at q (0 at a singularity)."""
    R, _, K = kin.jacobian(q)
    s = np.linalg.svd(task_jacobian(K, R, task), compute_uv=False)
    return float(s[-1] / s[0]) if s[0] > 0 else 0.0


def choose_home(model: pin.Model, frame_id: int, task: str, revolute: np.ndarray) -> np.ndarray:
    """A home configuration inside the limits where the task Jacobian is well conditioned.

    The middle of the limits (0 for a joint without limits) when the task Jacobian's conditioning
    there is at least :data:`HOME_CONDITION`; otherwise, of :data:`HOME_CANDIDATES` configurations
    drawn with seed 0 within a quarter of each range about the middle (at most pi/4 rad, or 0.25 m),
    the best conditioned. A UR5's all-zero configuration (arm stretched) is singular and is replaced.
    """
    lo, hi = np.array(model.lowerPositionLimit, float), np.array(model.upperPositionLimit, float)
    wide = np.where(revolute, np.pi, 1.0)
    lo_box = np.where(np.abs(lo) < NO_LIMIT, lo, np.maximum(lo, -wide))
    hi_box = np.where(np.abs(hi) < NO_LIMIT, hi, np.minimum(hi, wide))
    mid = np.array([finite_mid(a, b) for a, b in zip(lo, hi, strict=True)])
    kin = Kinematics(model, frame_id)
    if conditioning(kin, mid, task) >= HOME_CONDITION:
        return mid
    reach = np.minimum(0.25 * (hi_box - lo_box), 0.25 * wide)
    rng = np.random.default_rng(0)
    cands = np.clip(mid + rng.uniform(-1.0, 1.0, (HOME_CANDIDATES, model.nq)) * reach, lo_box, hi_box)
    scores = [conditioning(kin, q, task) for q in cands]
    return cands[int(np.argmax(scores))]


# -- the entry point --------------------------------------------------------------------------------
def load_robot(name_or_path: str | Path, ee_frame: str | None = None, *, task: str | None = None,
               tool_axis=None, joints=None, locked=None) -> Robot:
    """Load a robot by shipped name, example-robot-data name, or URDF path.

    Args:
        name_or_path: a name of :func:`known_robots` (``kinredund robots`` lists them with their joints,
            default frame and task) or the path of a URDF file.
        ee_frame: the end-effector frame (point P is its origin). Default: ``ee`` for the shipped
            robots, the catalogue's frame for example-robot-data arms (``kinredund.model.erd``), and
            for a URDF file a frame named ``ee`` if there is one, else the last frame. Where a joint
            and a link share the name, the link is taken (``robot.ee_frame_info`` says which).
        task: ``planar``, ``position``, ``axis`` (tool point and tool axis, m = 5) or ``pose``.
            Default: the robot's own; for an example-robot-data arm the task that makes it redundant;
            ``pose`` for URDF files.
        tool_axis: for ``task="axis"``: the tool's axis in the end-effector frame, ``"x"``, ``"y"``,
            ``"z"`` (default), ``"-z"``... or a 3-vector. The axis task holds the z axis of the
            end-effector frame: for another axis a frame ``<ee_frame>_tool_axis`` is added at the same
            origin, its z axis along the tool axis, and becomes ``robot.ee_frame``.
        joints: the joints to keep, by name (q follows the model's order); the others are locked.
            Default: the catalogue's chain for a named arm, every joint for a URDF file.
        locked: joint name -> value [rad or m] for locked joints; default: a mimic joint follows its
            master, any other sits at the middle of its limits (0 without limits).

    Raises:
        UnknownRobotError: the name is not known and no such file exists (lists the known names).
        URDFError: the file does not parse or is refused; the message says why.
        FrameNotFoundError: ``ee_frame`` is not in the model (lists the frames) or no joint moves it.
        ChoiceError, JointVectorError, TaskError: a bad task, tool axis, joint name or locked value.
    """
    if isinstance(name_or_path, Path):
        key, stored = str(name_or_path), {}
    elif isinstance(name_or_path, str) and not name_or_path.strip():  # ('' was read as the folder '.')
        raise UnknownRobotError(name_or_path, known_robots())
    elif isinstance(name_or_path, str):
        key, stored = split_source(name_or_path)  # a record's name: options follow it (model.source)
    else:
        raise UnknownRobotError(repr(name_or_path), known_robots())
    ee_frame = stored.get("ee_frame") if ee_frame is None else ee_frame  # an argument given wins
    tool_axis = stored.get("tool_axis") if tool_axis is None else tool_axis
    joints = stored.get("joints") if joints is None else joints
    locked = stored.get("locked") if locked is None else locked
    if task is not None:
        get_task(task)  # ChoiceError for an unknown kind
    if tool_axis is not None and task is not None and not get_task(task).takes_tool_axis:
        raise TaskError(f"tool_axis is for a task that holds the tool's axis ({_axis_kinds()}), not {task!r}")
    axis = None if tool_axis is None else check_tool_axis(tool_axis)
    turned = axis is not None and not np.array_equal(axis, _AXES["z"])
    robot = _load(key, ee_frame, task, axis, turned, joints, locked)
    base = key if robot.urdf_path is None or key in known_robots() else str(robot.urdf_path)
    robot.source = record_source(base, ee_frame=ee_frame, tool_axis=axis, joints=joints, locked=locked)
    return robot


def _load(key: str, ee_frame, task, axis, turned: bool, joints, locked) -> Robot:
    """:func:`load_robot` once its options are checked."""
    if key in SHIPPED_TABLES:
        if joints is not None or locked is not None:
            raise ChoiceError("option for a thesis robot (joints=/locked= are for URDF arms)", key, ["none"])
        path = shipped_robot_dir() / f"{key}.urdf"
        task = task or SHIPPED_TASKS[key]
        model, frame = _with_tool_axis(load_urdf(path).model, EE_FRAME if ee_frame is None else ee_frame, axis, task)
        return Robot(key, model, frame, task, hd=SHIPPED_TABLES[key](), urdf_path=path,
                     home=np.array(SHIPPED_HOMES[key]), tool_axis=axis)
    if key in TABLE_ROBOTS:
        if joints is not None or locked is not None or ee_frame is not None or axis is not None:
            raise ChoiceError("option for a robot built from its HD table (it takes task= only)", key, ["task"])
        make, default_task, _ = TABLE_ROBOTS[key]
        return robot_from_hd(make(), task=task or default_task)
    if key in ERD_ARMS:
        spec = ERD_ARMS[key]
        share = erd_share_dir()
        custom = joints is not None or locked is not None
        # a record names its robot for reloading: a custom chain must not reload as the catalogue's
        frame = spec.ee_frame if ee_frame is None else ee_frame
        own = spec.home is not None and not custom and ee_frame is None and not turned
        return _from_urdf(
            f"{key}:custom" if custom else key, share / spec.urdf, frame, task or spec.task, axis,
            spec.joints if joints is None else joints, locked, (str(share.parent.parent),),
            np.array(spec.home) if own else None,
        )
    path = Path(key)
    if path.suffix.lower() in (".urdf", ".xml") or path.exists():
        if not path.exists():
            raise UnknownRobotError(key, known_robots())
        path = path.resolve()  # a record names the file: absolute, so that it reloads from any folder
        name = path.stem if path.stem not in known_robots() else str(path)  # never reloads as a catalogue arm
        return _from_urdf(name, path, ee_frame, task or "pose", axis, joints, locked, (str(path.parent),), None)
    raise UnknownRobotError(key, known_robots())


def _default_ee_frame(model: pin.Model) -> str:
    if model.existFrame(EE_FRAME):
        return EE_FRAME
    return model.frames[len(model.frames) - 1].name


def _axis_kinds() -> str:
    """The task kinds that take a tool axis, for messages: ``task='axis'``."""
    return " or ".join(f"task={name!r}" for name in task_names() if get_task(name).takes_tool_axis)


def _with_tool_axis(model: pin.Model, frame: str, axis: np.ndarray | None, task: str) -> tuple[pin.Model, str]:
    """(model, end-effector frame): for a tool axis other than z, a copy of the model with a frame at
    ``frame``'s origin whose z axis is the tool axis (the axis task holds the frame's z axis)."""
    if axis is not None and not get_task(task).takes_tool_axis:
        raise TaskError(f"tool_axis is for a task that holds the tool's axis ({_axis_kinds()}), and this robot's "
                        f"task is {task!r}: give one of those")
    if axis is None or np.array_equal(axis, _AXES["z"]):
        return model, frame
    fid, _ = resolve_frame(model, frame)
    base = model.frames[fid]
    name = frame + TOOL_AXIS_FRAME
    model = pin.Model(model)
    turn = pin.SE3(frame_with_axis(axis), np.zeros(3))
    model.addFrame(pin.Frame(name, base.parentJoint, fid, base.placement * turn, pin.FrameType.OP_FRAME))
    return model, name


def _from_urdf(name, path, ee_frame, task, axis, joints, locked, package_dirs, home) -> Robot:
    parsed = load_urdf(path)
    frame = _default_ee_frame(parsed.model) if ee_frame is None else ee_frame
    fid, _ = resolve_frame(parsed.model, frame)
    model, values = reduce_model(parsed.model, joints, locked, parsed.mimic, fid, str(path))
    limit, why = SIZES["joints"]
    if model.nv > limit:
        raise URDFError(str(path), f"{model.nv} moving joints, more than the {limit} kinredund takes ({why}): keep "
                                   "the arm's with joints=[...] (the others are locked)")
    model, frame = _with_tool_axis(model, frame, axis, task)
    if home is None and model.nq == model.nv:
        fid, _ = resolve_frame(model, frame)
        home = choose_home(model, fid, task, robot_revolute(model))
    continuous = tuple(n for n in parsed.continuous if model.existJointName(n))
    return Robot(name, model, frame, task, urdf_path=path, package_dirs=package_dirs, home=home,
                 tool_axis=axis, locked=values, continuous=continuous)
