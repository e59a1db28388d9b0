"""The arms of example-robot-data that :func:`~kinredund.model.loader.load_robot` knows by name.

example-robot-data 6.0.0 ships URDF files and meshes only (no Python module): they are found under
``cmeel.prefix/share/example-robot-data/robots`` on ``sys.path`` and loaded by path.

Each entry names the URDF, the joints kept (the others are locked: fingers, torso, head, the other
arm, wheels), the default end-effector frame and the default task: the task that makes the arm
redundant (n > m), so that the thesis's scheme has something to optimise. A 6-axis arm is redundant
for the 5-D tool-axis task (``axis``: the tool point and the direction of the tool's axis, the spin
about it free), a 7-axis arm for the pose task, a 5-axis arm for the position task.

Run ``kinredund robots`` for the table with joint counts.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from kinredund.errors import KinredundError


@dataclass(frozen=True)
class ERDArm:
    """One arm of example-robot-data.

    Attributes:
        urdf: the URDF file, relative to the ``robots`` folder.
        ee_frame: the default end-effector frame.
        task: the default task kind, the one that makes the arm redundant.
        joints: the joints kept, or None for every joint of the file.
        home: a home configuration [rad], or None for :func:`kinredund.model.loader.choose_home`'s.
        note: what the entry is, for ``kinredund robots``.
    """

    urdf: str
    ee_frame: str
    task: str
    joints: tuple[str, ...] | None = None
    home: tuple[float, ...] | None = None
    note: str = ""


def _chain(prefix: str, names, suffix: str = "") -> tuple[str, ...]:
    return tuple(f"{prefix}{n}{suffix}" for n in names)


#: elbow up, tool pointing down: away from the shoulder, elbow and wrist singularities
_UR_HOME = (0.0, -1.2, 1.6, -1.97, -1.57, 0.0)
_BAXTER = ("s0", "s1", "e0", "e1", "w0", "w1", "w2")
_PR2 = ("shoulder_pan", "shoulder_lift", "upper_arm_roll", "elbow_flex", "forearm_roll", "wrist_flex", "wrist_roll")

#: the arms of example-robot-data loadable by name
ERD_ARMS = {
    "panda": ERDArm(
        "panda_description/urdf/panda.urdf", "panda_hand", "pose", _chain("panda_joint", range(1, 8)),
        (0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785), "Franka Emika Panda, fingers locked",
    ),
    "xarm7": ERDArm(
        "xarm_description/urdf/xarm7.urdf", "link_eef", "pose", None, (0.0, -0.5, 0.0, 0.5, 0.0, 1.0, 0.0),
        "UFACTORY xArm 7",
    ),
    "ur3": ERDArm("ur_description/urdf/ur3_robot.urdf", "tool0", "axis", None, _UR_HOME, "Universal Robots UR3"),
    "ur5": ERDArm("ur_description/urdf/ur5_robot.urdf", "tool0", "axis", None, _UR_HOME, "Universal Robots UR5"),
    "ur10": ERDArm("ur_description/urdf/ur10_robot.urdf", "tool0", "axis", None, _UR_HOME, "Universal Robots UR10"),
    "kinova": ERDArm(
        "kinova_description/robots/kinova.urdf", "j2s6s200_end_effector", "axis", None, None,
        "Kinova Jaco2 (6 axes; joints 1, 4 and 6 continuous)",
    ),
    "z1": ERDArm(
        "z1_description/urdf/z1.urdf", "gripperStator", "axis", _chain("joint", range(1, 7)), None,
        "Unitree Z1, gripper locked",
    ),
    "so100": ERDArm(
        "so_arm_description/urdf/so100.urdf", "gripper", "position",
        ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll"), None,
        "SO-100 (5 axes), jaw locked",
    ),
    "so101": ERDArm(
        "so_arm_description/urdf/so101.urdf", "gripper_frame_link", "position",
        ("shoulder_pan", "shoulder_lift", "elbow_flex", "wrist_flex", "wrist_roll"), None,
        "SO-101 (5 axes), jaw locked",
    ),
    "baxter": ERDArm(
        "baxter_description/urdf/baxter.urdf", "left_gripper", "pose", _chain("left_", _BAXTER), None,
        "Rethink Baxter, left arm (the rest locked)",
    ),
    "baxter_right": ERDArm(
        "baxter_description/urdf/baxter.urdf", "right_gripper", "pose", _chain("right_", _BAXTER), None,
        "Rethink Baxter, right arm (the rest locked)",
    ),
    "tiago": ERDArm(
        "tiago_description/robots/tiago.urdf", "arm_tool_link", "pose", _chain("arm_", range(1, 8), "_joint"), None,
        "PAL TIAGo, arm (torso, head, hand and wheels locked)",
    ),
    "tiago_pro": ERDArm(
        "tiago_pro_description/robots/tiago_pro.urdf", "arm_left_tool_link", "pose",
        _chain("arm_left_", range(1, 8), "_joint"), None, "PAL TIAGo Pro, left arm (the rest locked)",
    ),
    "pr2": ERDArm(
        "pr2_description/urdf/pr2.urdf", "l_gripper_tool_frame", "pose", _chain("l_", _PR2, "_joint"), None,
        "Willow Garage PR2, left arm (forearm and wrist rolls continuous; the rest locked)",
    ),
    "talos_arm": ERDArm(
        "talos_data/robots/talos_left_arm.urdf", "gripper_left_base_link", "axis",
        _chain("arm_left_", range(2, 8), "_joint"), None, "PAL TALOS, left arm (6 axes in this file), gripper locked",
    ),
}


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
