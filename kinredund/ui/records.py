"""Every JSON file the project writes, read back as something to replay (``kinredund play``).

Three kinds of records come out of the commands:

- a trajectory (``track --json``, ``reproduce 4.x --json``): :meth:`kinredund.trajectory.Trajectory.save_json`;
- a plan (``plan 6.x --json``, ``reproduce 6.x --json``): :func:`kinredund.thesis.chapter6.to_json_dict`,
  joints per time and the obstacle, on the robot of the case;
- the Section 3.2 helix (``reproduce 3.2 --json``): the first four joints of the PUMA-derived arm
  along the wrist centre's helix (:func:`kinredund.thesis.helix_3_2.reproduce`).

:func:`replay_record` turns any of them into a :class:`~kinredund.trajectory.Trajectory` with its
robot and a title; the end-effector positions of a plan are recomputed from its joints (forward
kinematics), those of the helix are its wrist centres.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError, check_array, shown
from kinredund.io import read_json_object
from kinredund.model.loader import load_robot
from kinredund.model.robot import Robot
from kinredund.trajectory import Trajectory


@dataclass(frozen=True)
class Replayable:
    """A record ready for playback: the trajectory, its robot, a title and the record's kind."""

    trajectory: Trajectory
    robot: Robot
    title: str
    kind: str
    #: a partial record's stop (``track --partial``: cause, t [s], q, watched, message; only the cause, "not
    #: recorded", for a record marked ``meta.partial`` without it), else None
    failure: dict | None = None


def record_kind(data: dict) -> str:
    """``trajectory``, ``plan`` or ``helix`` for a record's JSON object.

    Raises:
        KinredundError: the object is none of the kinds the project writes.
    """
    example = str(data.get("example", ""))
    if "p" in data and "robot" in data and "task" in data:
        return "trajectory"
    if example in ("6.2", "6.3") and "q" in data:
        return "plan"
    if example == "3.2" and "wrist_centre" in data:
        return "helix"
    raise KinredundError(
        "not a kinredund record: expected the JSON of `track --json` or `reproduce 4.x --json` (a trajectory), "
        "`plan 6.x --json` or `reproduce 6.x --json` (a plan), or `reproduce 3.2 --json` (the helix)")


def _motion(data: dict, what: str, columns: int | None) -> tuple[np.ndarray, np.ndarray]:
    """(t, q) of a plan or helix record, checked: N times and an (N, columns) array of finite numbers.

    Raises:
        KinredundError: a missing key or an array of the wrong kind or shape (a file posing as a record).
    """
    t = check_array(data.get("t"), (None,), f"{what}: times 't' [s]", KinredundError)
    q = check_array(data.get("q"), (len(t), columns), f"{what}: joint values 'q'", KinredundError,
                    f"{len(t)} times")
    if np.any(np.diff(t) <= 0.0):
        raise KinredundError(f"{what}: times 't' must be strictly increasing")
    return t, q


def _plan(data: dict) -> Replayable:
    from kinredund.thesis.chapter6 import case_setup

    case = str(data["example"])
    robot, path, _ = case_setup(case)
    if isinstance(data.get("t"), list) and not data["t"]:
        reason = data.get("reason") or "no reason recorded"
        raise KinredundError(f"the plan of Section {case} has no motion to replay (it failed: {reason})")
    t, q = _motion(data, f"the plan of Section {case}", robot.nq)
    p = np.array([robot.fk(qi)[:3, 3] for qi in q])
    desired = np.array([path(ti).p for ti in t])
    traj = Trajectory(robot=robot.name, task=robot.task, t=t, q=q, p=p, p_desired=desired, scheme="planner",
                      meta={"example": case, "obstacle": data.get("obstacle")})
    ok = "collision-free plan" if data.get("ok") else "plan that failed its check"
    return Replayable(traj, robot, f"{robot.name}: Section {case}, {ok}", "plan")


def _helix(data: dict) -> Replayable:
    if data.get("robot", "puma7") != "puma7":
        raise KinredundError(f"the Section 3.2 helix is tracked by puma7, not {data['robot']!r}")
    robot = load_robot("puma7")
    t, q4 = _motion(data, "the Section 3.2 helix", None)
    if q4.shape[1] > robot.nq:
        raise KinredundError(f"the Section 3.2 helix: 'q' has {q4.shape[1]} joints, {robot.name} has {robot.nq}")
    q = np.zeros((len(t), robot.nq))
    q[:, : q4.shape[1]] = q4  # the wrist joints are not part of Section 3.2's positioning problem: held at 0
    centre = check_array(data["wrist_centre"], (len(t), 3), "the Section 3.2 helix: 'wrist_centre' [m]",
                         KinredundError, f"{len(t)} times")
    traj = Trajectory(robot=robot.name, task="position", t=t, q=q, p=centre, p_desired=centre.copy(),
                      scheme="closed_form", meta={"example": "3.2"})
    return Replayable(traj, robot, f"{robot.name}: Section 3.2, wrist centre on the helix (closed form)", "helix")


def replay_record(path: str | Path) -> Replayable:
    """The record in the JSON file ``path`` (any kind the project writes), ready for playback.

    Raises:
        KinredundError: an unreadable file, a JSON object of no known kind, a failed plan without a
            motion, or a record that does not fit its robot.
    """
    data = read_json_object(path)
    kind = record_kind(data)
    if kind == "plan":
        return _plan(data)
    if kind == "helix":
        return _helix(data)
    from kinredund.ui.viz.page import replay_title

    traj = Trajectory.from_json_dict(data)
    failure = data.get("failure")
    if failure is not None and not (isinstance(failure, dict) and isinstance(failure.get("cause"), str)):
        raise KinredundError(f"{path}: 'failure' (a partial record's stop) must be an object with its 'cause', got "
                             f"{shown(failure)}")
    if failure is None and traj.meta.get("partial") is True:  # a library run's err.partial.save_json()
        failure = {"cause": "cause not recorded"}
    return Replayable(traj, load_robot(traj.robot, task=traj.task), replay_title(traj), kind, failure)
