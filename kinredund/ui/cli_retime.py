"""The ``kinredund retime`` and ``kinredund export`` commands: parse, call the library, report.

``retime RESULT.json --amax A [--vmax V] [--jmax J] [--tool-speed S] [--json F] [--csv F] [--bag D]``
retimes a tracking record (:func:`kinredund.retime.retime`); ``export RESULT.json --csv F | --bag D``
writes a record as CSV or a ROS 2 bag (:mod:`kinredund.export`). Every output is checked before any is
written (a bag folder that exists is refused), and each is written atomically, so a refused or failed
run leaves no file or folder.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError
from kinredund.ui.options import at_least, output_file, subcommand

RETIME_HELP = """Retime a tracking record (kinredund track --json) under joint speed and acceleration limits:
a new time law along the same optimal joint path (TOPP-RA, time-optimal; periodic for a closed path, so
loops chain without a stop; jerk-limited with --jmax). The output samples are the record's own points of
the joint path, at new times."""


def _limit(text: str) -> float | np.ndarray:
    """A number or comma-separated numbers (one per joint); the library checks they are finite and > 0."""
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected a number or comma-separated numbers, got {text!r}") from err
    if not values:
        raise argparse.ArgumentTypeError(f"expected a number or comma-separated numbers, got {text!r}")
    return values[0] if len(values) == 1 else np.array(values)


def _topic(text: str) -> str:
    """An argparse type: a fully qualified ROS 2 topic name (:func:`kinredund.export.rosbag.check_topic`)."""
    from kinredund.export.rosbag import check_topic
    from kinredund.export.samples import ExportError

    try:
        return check_topic(text)
    except ExportError as err:
        raise argparse.ArgumentTypeError(str(err)) from err


def _check_topic(args) -> None:
    """--topic without --bag: refused before any work (it would be ignored)."""
    if args.topic is not None and args.bag is None:
        raise KinredundError("--topic names the bag's topic: give --bag FOLDER too, or leave --topic out")


def check_partial(rec, args) -> None:
    """Refuse a partial record (a stopped run's, ``track --partial``) unless --allow-partial says it is wanted: its
    samples end where the run stopped, short of the path, and a CSV or a bag has no place to say so. Allowed, the
    stop is said on stderr (and kept in a JSON written)."""
    f = rec.failure
    if f is None:
        return
    t = f.get("t")
    when = f"t = {t:.6g} s" if isinstance(t, (int, float)) else "a time it did not record, after its last sample"
    what = (f"{args.result} is a partial record: its run stopped at {when} ({f['cause']}), so its samples end there, "
            "short of the path")
    if not args.allow_partial:
        raise KinredundError(f"{what}. Give --allow-partial to write it anyway, or a record of a run that completed")
    print(f"kinredund: note: {what}", file=sys.stderr)


def _write_outputs(traj, names, args, failure: dict | None = None) -> None:
    from kinredund.export import DEFAULT_TOPIC, write_bag, write_csv

    if getattr(args, "json", None) is not None:
        traj.save_json(args.json, extra=None if failure is None else {"failure": failure})
        print(f"wrote {args.json}")
    if args.csv is not None:
        print(f"wrote {write_csv(traj, args.csv, names)}")
    if args.bag is not None:
        print(f"wrote {write_bag(traj, args.bag, names, topic=args.topic or DEFAULT_TOPIC)}")


def _cmd_retime(args) -> int:
    from kinredund.retime import limits_for, retime
    from kinredund.retime.time_law import sample_ratios
    from kinredund.ui.records import replay_record

    _check_topic(args)
    rec = replay_record(args.result)  # a trajectory (track, plan ROBOT) or a plan of Chapter 6 (plan 6.x)
    check_partial(rec, args)
    traj, robot = rec.trajectory, rec.robot
    limits = limits_for(robot, args.amax, velocity=args.vmax, jerk=args.jmax, tool_speed=args.tool_speed)
    res = retime(traj, limits, robot=robot, loops=args.loops, closed=False if args.open else None,
                 rest_to_rest=args.rest_to_rest)
    out = res.trajectory
    law = res.law
    kind = "jerk-limited (smoothed TOPP-RA)" if law.kind == "jerk" else "time-optimal (TOPP-RA)"
    if res.rest_to_rest:
        shape = f"{res.loops} loop(s) from rest to rest"
    else:
        shape = "periodic, loops chain without a stop" if res.path.closed else "open path, rest to rest"
    print(f"{robot.name}: retimed {kind}, {shape}")
    per = " per loop" if res.path.closed and not res.rest_to_rest else ""
    print(f"  {'duration':24s} {res.path.period:.6g} s -> {law.duration:.6g} s{per}")
    print(f"  {'samples':24s} {len(out.t)} ({res.loops} loop(s))")
    print(f"  {'max |qdot| / vmax':24s} {float(np.max(np.abs(out.qdot) / limits.velocity)):.9f}")
    print(f"  {'max |qddot| / amax':24s} {float(np.max(np.abs(out.qddot) / limits.acceleration)):.9f}")
    ratios = sample_ratios(res.path, law, limits)
    for key, label in (("jerk", "max |qdddot| / jmax"), ("tool_speed", "max tool speed / limit")):
        if key in ratios:
            print(f"  {label:24s} {float(ratios[key].max()):.9f}")
    print(f"  {'samples with a limit':24s} {100 * res.active_fraction:.1f} % (within 1 % of it)")
    for note in res.notes:
        print(f"  note: {note}")
    _write_outputs(out, robot.joint_names, args, rec.failure)
    if args.plot is not None:
        from kinredund.ui.plots_retime import plot_retimed

        print(f"wrote {plot_retimed(out, args.plot)}")
    return 0


def _cmd_export(args) -> int:
    from kinredund.ui.records import replay_record

    if args.csv is None and args.bag is None:
        raise KinredundError("say what to write: --csv FILE and/or --bag FOLDER")
    _check_topic(args)
    rec = replay_record(args.result)
    check_partial(rec, args)
    _write_outputs(rec.trajectory, rec.robot.joint_names, args)
    return 0


def add_parsers(sub) -> None:
    """Register ``retime`` and ``export`` on the subcommand parsers of :func:`kinredund.ui.cli.build_parser`."""
    from kinredund.export import DEFAULT_TOPIC

    p = subcommand(sub, "retime", "retime a tracking record under joint speed/acceleration (and jerk) limits",
                   RETIME_HELP, ["kinredund track panda --json run.json",
                                 "kinredund retime run.json --amax 5 --vmax 1.5 --json timed.json --plot timed.png",
                                 "kinredund retime run.json --amax 5 --jmax 500 --bag timed_bag"], _cmd_retime)
    p.add_argument("result", type=Path, help="a trajectory JSON (kinredund track or plan --json)")
    p.add_argument("--amax", type=_limit, required=True,
                   help="joint acceleration limits [rad/s^2 or m/s^2]: one number or one per joint (URDFs have none)")
    p.add_argument("--vmax", type=_limit,
                   help="joint velocity limits [rad/s or m/s]: one number or one per joint (default: the URDF's)")
    p.add_argument("--jmax", type=_limit,
                   help="joint jerk limits [rad/s^3 or m/s^3]: a jerk-limited periodic law (closed paths only; "
                        "default: no jerk limit)")
    p.add_argument("--tool-speed", type=float, help="speed limit of the tool along its path [m/s] (default: none)")
    p.add_argument("--loops", type=at_least(1, "samples"),
                   help="loops to chain (closed paths; default: as many as the record has)")
    p.add_argument("--open", action="store_true",
                   help="retime a closed record as an open path from rest to rest (default: a closed record stays "
                        "periodic)")
    p.add_argument("--rest-to-rest", action="store_true",
                   help="closed paths: start the first loop from rest and stop at the end of the last (one "
                        "time-optimal law over all loops), for a controller that starts from standstill; default a "
                        "periodic loop law, which starts and ends at the loop's speed")
    p.add_argument("--json", type=output_file,
                   help="write the retimed record (with qdot, qddot) as JSON (default: not written)")
    p.add_argument("--csv", type=output_file,
                   help="write it as CSV: t, q_<joint>..., qdot_<joint>..., qddot_<joint>... (default: not written)")
    p.add_argument("--bag", type=Path, help="write it as a ROS 2 bag folder (must not exist): one "
                                            "trajectory_msgs/msg/JointTrajectory (default: not written)")
    p.add_argument("--topic", type=_topic,
                   help=f"with --bag: the bag's topic, a fully qualified ROS 2 name (default {DEFAULT_TOPIC})")
    p.add_argument("--plot", type=output_file,
                   help="plot q, qdot, qddot with the limits (.png, .pdf, .svg) (default: not drawn)")
    _add_allow_partial(p, "retime")

    p = subcommand(sub, "export", "write a trajectory record as CSV or a ROS 2 bag",
                   "Write a trajectory JSON as CSV (one row per sample, a header naming the joints) and/or a ROS 2 "
                   "bag holding one trajectory_msgs/msg/JointTrajectory.",
                   ["kinredund export run.json --csv run.csv", "kinredund export timed.json --bag timed_bag"],
                   _cmd_export)
    p.add_argument("result", type=Path, help="a trajectory JSON (kinredund track, plan or retime --json)")
    p.add_argument("--csv", type=output_file, help="the CSV file to write (default: not written)")
    p.add_argument("--bag", type=Path,
                   help="the ROS 2 bag folder to write, which must not exist (default: not written)")
    p.add_argument("--topic", type=_topic,
                   help=f"with --bag: the bag's topic, a fully qualified ROS 2 name (default {DEFAULT_TOPIC})")
    _add_allow_partial(p, "export")


def _add_allow_partial(p, command: str) -> None:
    p.add_argument("--allow-partial", action="store_true",
                   help=f"{command} a partial record (a stopped run's, track --partial) too: its samples end where the "
                        "run stopped, which is said on stderr (default: refused, naming the stop)")
