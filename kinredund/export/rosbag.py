"""ROS 2 bag export: one ``trajectory_msgs/msg/JointTrajectory`` message, written with ``rosbags``.

The bag (rosbag2 format version 8, sqlite3 storage: what ``ros2 bag play`` and the usual bag viewers
read) holds one message on :data:`DEFAULT_TOPIC`, the topic ros2_control's
``joint_trajectory_controller`` listens on: the robot's joint names, and one
``JointTrajectoryPoint`` per sample with positions, velocities and accelerations (empty when the record
has none) and ``time_from_start``. A ROS Duration holds whole nanoseconds: the times are rounded to them
(:func:`kinredund.retime.retime` already gives whole nanoseconds, which then read back exactly).
The message's bag timestamp and header stamp are 0.

The bag is written into a temporary folder beside the destination, then renamed: a failed write
leaves nothing, and a destination that exists is refused before anything is written.
"""

from __future__ import annotations

import os
import re
import sqlite3
from pathlib import Path, PurePath

import numpy as np

from kinredund.errors import KinredundError, OutputPathError
from kinredund.export.samples import ExportError, JointSamples, distinct_nanoseconds, from_nanoseconds
from kinredund.inputs import check_regular_file, file_kind, read_text
from kinredund.io import atomic_write_dir, check_new_folder
from kinredund.trajectory import Trajectory

MSGTYPE = "trajectory_msgs/msg/JointTrajectory"
DEFAULT_TOPIC = "/joint_trajectory_controller/joint_trajectory"
BAG_VERSION = 8
#: the longest ``time_from_start`` [s]: builtin_interfaces/msg/Duration's ``sec`` is an int32
MAX_DURATION = 2**31 - 1


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def check_bag_times(t) -> np.ndarray:
    """The times [s] as the whole nanoseconds a ``time_from_start`` (a ROS 2 Duration) holds.

    Raises:
        ExportError: a time before 0, past :data:`MAX_DURATION` (the Duration's ``sec`` is an int32), or
            two samples in one nanosecond (:func:`~kinredund.export.samples.distinct_nanoseconds`).
    """
    ns = distinct_nanoseconds(t)
    if ns[0] < 0:
        raise ExportError(f"a JointTrajectory's times start at 0 or later, got t[0] = {float(t[0])!r} s")
    if ns[-1] // 1_000_000_000 > MAX_DURATION:
        raise ExportError(f"the last time t = {float(t[-1]):.6g} s is past {MAX_DURATION} s, the longest "
                          "time_from_start a ROS 2 Duration holds (its sec field is a 32-bit integer)")
    return ns


def _message(samples: JointSamples, store):
    types = store.types
    Duration, Time = types["builtin_interfaces/msg/Duration"], types["builtin_interfaces/msg/Time"]
    Point = types["trajectory_msgs/msg/JointTrajectoryPoint"]
    empty = np.zeros(0)
    ns = check_bag_times(samples.t)
    points = []
    for k in range(len(ns)):
        sec, nsec = divmod(int(ns[k]), 1_000_000_000)
        points.append(Point(positions=samples.q[k].copy(),
                            velocities=empty if samples.qdot is None else samples.qdot[k].copy(),
                            accelerations=empty if samples.qddot is None else samples.qddot[k].copy(),
                            effort=empty, time_from_start=Duration(sec=sec, nanosec=nsec)))
    header = types["std_msgs/msg/Header"](stamp=Time(sec=0, nanosec=0), frame_id="")
    return types[MSGTYPE](header=header, joint_names=list(samples.joint_names), points=points)


#: one token of a ROS 2 name: letters, digits and underscores, not starting with a digit, no "__"
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def check_topic(topic) -> str:
    """``topic`` if it is a fully qualified ROS 2 topic name, else ExportError saying which rule it breaks.

    The rules of the ROS 2 design article "Topic and Service name mapping to DDS" (as rcl's
    ``rmw_validate_full_topic_name``): a ``/`` then tokens separated by single ``/``; each token
    letters, digits and underscores, not starting with a digit, without ``__``; no ``/`` at the end.
    A bag stores the fully qualified name, so ``~`` and ``{}`` substitutions and relative names are
    refused (write ``/ns/name``).
    """
    example = f"e.g. {DEFAULT_TOPIC}"
    if not isinstance(topic, str) or not topic:
        raise ExportError(f"the topic must be a non-empty ROS 2 name ({example}), got {topic!r}")
    if not topic.startswith("/"):
        raise ExportError(f"the topic {topic!r} is not fully qualified: a bag's topic starts with '/' ({example})")
    if topic == "/" or topic.endswith("/"):
        raise ExportError(f"the topic {topic!r} ends with '/': a ROS 2 name ends with a token ({example})")
    for token in topic[1:].split("/"):
        if not token:
            raise ExportError(f"the topic {topic!r} has an empty token ('//'): separate tokens with one '/'")
        if not _TOKEN.fullmatch(token) or "__" in token:
            raise ExportError(f"the topic {topic!r} has the token {token!r}: a ROS 2 token holds letters, digits and "
                              "single underscores only and does not start with a digit")
    return topic


def check_new_bag(folder: str | Path) -> Path:
    """``folder`` as a Path if nothing is there yet (:func:`kinredund.io.check_new_folder`), else ExportError
    (a bag is never overwritten)."""
    try:
        return check_new_folder(folder)
    except OutputPathError as err:
        raise ExportError(f"a ROS 2 bag: {err}") from err


def write_bag(data: JointSamples | Trajectory, folder: str | Path, joint_names=None,
              topic: str = DEFAULT_TOPIC) -> Path:
    """Write the samples (or a record's) as a ROS 2 bag folder; return the folder.

    Raises:
        ExportError: the folder exists already, the topic is not a ROS 2 name (:func:`check_topic`), the
            times do not fit a JointTrajectory (:func:`check_bag_times`), or the record is not a joint
            trajectory.
    """
    from rosbags.rosbag2 import Writer

    folder = check_new_bag(folder)
    topic = check_topic(topic)
    samples = data.checked() if isinstance(data, JointSamples) else JointSamples.from_trajectory(data, joint_names)
    store = _typestore()
    raw = store.serialize_cdr(_message(samples, store), MSGTYPE)

    def build(path: Path) -> None:
        from rosbags.rosbag2 import WriterError

        try:
            with Writer(path, version=BAG_VERSION) as writer:
                conn = writer.add_connection(topic, MSGTYPE, typestore=store)
                writer.write(conn, 0, raw)
        except (OSError, sqlite3.Error, WriterError) as err:  # a full disk shows as either of the first two
            raise OutputPathError(folder, f"the bag could not be written ({type(err).__name__}: {err}); nothing "
                                          "was left behind") from err

    atomic_write_dir(folder, build)  # with the command's other outputs (kinredund.io.output_batch)
    return folder


def read_bag(folder: str | Path, topic: str | None = None) -> JointSamples:
    """The samples of the first JointTrajectory message in a bag (on ``topic`` if given).

    Raises:
        ExportError: not a readable bag (:func:`check_bag_folder`), or no JointTrajectory message in it.
    """
    from rosbags.rosbag2 import Reader

    check_bag_folder(folder)
    store = _typestore()
    try:
        with Reader(folder) as reader:
            conns = [c for c in reader.connections if c.msgtype == MSGTYPE and (topic is None or c.topic == topic)]
            if not conns:
                raise ExportError(f"no {MSGTYPE} message{'' if topic is None else f' on {topic}'} in the bag {folder}")
            for _conn, _stamp, raw in reader.messages(connections=conns):
                msg = store.deserialize_cdr(raw, MSGTYPE)
                break
    except ExportError:
        raise
    except Exception as err:  # noqa: BLE001 - rosbags raises its own errors and OSError: report them as ours
        raise ExportError(f"cannot read the bag {folder}: {err}") from err
    pts = msg.points
    ns = np.array([p.time_from_start.sec * 1_000_000_000 + p.time_from_start.nanosec for p in pts], dtype=np.int64)
    more = {}
    for key, attr in (("qdot", "velocities"), ("qddot", "accelerations")):
        rows = [np.asarray(getattr(p, attr), float) for p in pts]
        more[key] = np.array(rows) if rows and all(len(r) == len(msg.joint_names) for r in rows) else None
    q = np.array([np.asarray(p.positions, float) for p in pts])
    return JointSamples(tuple(msg.joint_names), from_nanoseconds(ns), q, **more).checked()


#: what a bag is, said when something else is given
BAG_IS = "a ROS 2 bag is a folder holding metadata.yaml and the storage files it lists (.db3 or .mcap)"


def check_bag_folder(folder) -> Path:
    """``folder`` as a Path if it is a bag folder whose metadata.yaml and listed storage files are regular files
    (:func:`kinredund.inputs.check_regular_file`: a FIFO would block the reader, sqlite included).

    Raises:
        ExportError: naming the path and what it is instead, and what a bag is.
    """
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    path = Path(folder)
    if not path.is_dir():
        what = "a regular file" if path.is_file() else file_kind(os.stat(path).st_mode) if path.exists() else (
            "no such folder")
        raise ExportError(f"cannot read the bag {str(path)!r}: {what}; {BAG_IS}")
    try:
        listed = YAML(typ="safe").load(read_text(path / "metadata.yaml"))["rosbag2_bagfile_information"][
            "relative_file_paths"]
        for name in listed:
            check_regular_file(path / PurePath(str(name)).name)
    except KinredundError as err:
        raise ExportError(f"cannot read the bag {str(path)!r}: {err}; {BAG_IS}") from err
    except (YAMLError, TypeError, KeyError) as err:
        raise ExportError(f"cannot read the bag {str(path)!r}: its metadata.yaml does not list the storage files "
                          f"({type(err).__name__}: {err}); {BAG_IS}") from err
    return path
