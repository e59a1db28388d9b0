"""The ``track`` command's path and its notes on the record (kept out of :mod:`kinredund.ui.cli`)."""

from __future__ import annotations

import sys

import numpy as np

from kinredund.errors import KinredundError
from kinredund.tasks import get_task


def path_for(args, robot, q_start: np.ndarray):
    """The path named by --path (argparse restricts it) and, for an open path, its duration [s] (else None).

    Circles and ellipses start at the pose of ``q_start``.
    """
    from kinredund import paths

    if args.path == "file":
        if args.path_file is None:
            raise KinredundError("--path file needs --path-file FILE (JSON with 't', 'p' and optionally 'Q', 'closed')")
        path, duration = paths.read_path_file(args.path_file)
        return path, (duration if path.period is None else None)
    T0 = robot.fk(q_start)
    p0 = T0[:3, 3]
    task = get_task(robot.task)
    center = args.center if args.center is not None else p0 - args.radius * np.array([1.0, 0.0, 0.0])
    if center.shape == (2,):  # in the plane of the start point (a planar arm's plane is z = 0)
        center = np.append(center, p0[2] if not task.planar else 0.0)
    held = T0[:3, :3] if task.has_orientation else None  # tasks with orientation hold the start's
    if args.path == "ellipse":  # in the horizontal plane of its centre, through the start point by default
        ellipse = paths.Ellipse(center, args.radius, args.radius / 2, rate=args.speed / args.radius)
        return (ellipse if held is None else _holding(ellipse, held)), None
    normal = args.normal if args.normal is not None else np.array([0.0, 0.0, 1.0])
    return paths.Circle(center, args.radius, args.speed, normal=tuple(normal), orientation=held), None


def _holding(path, Q0: np.ndarray):
    """``path`` (a point path) with the constant orientation Q0: a pose path (omega = 0)."""
    from kinredund.paths import FunctionPath

    def sample(t: float):
        s = path.sample(t)
        return Q0, s.p, np.zeros(3), s.v

    return FunctionPath(sample, period=path.period, has_orientation=True)


def say_speed(traj, robot, args) -> None:
    """A joint faster than its URDF velocity limit: which, how much, when, and the next step."""
    fastest = traj.speed_over_limits
    if fastest is None or not fastest[0] > 1.0:
        return
    ratio, j, t = fastest
    retime = f"`kinredund retime {args.json} --amax A`" if args.json else \
        "track again with --json RUN.json, then `kinredund retime RUN.json --amax A`"
    print(f"kinredund: note: joint {robot.joint_names[j]} runs at {ratio:.3g} times its URDF velocity limit "
          f"(at t = {t:.4g} s): the arm cannot run this motion at these times. Next step: {retime} (a time law "
          f"within the limits along the same joint path), or --speed {args.speed / ratio:.3g} or less",
          file=sys.stderr)


def stop_hint(err, args) -> str:
    """What to change on the command line after a tracking stop whose cause the path's size or place
    explains ("" where none does)."""
    if err.cause not in ("out_of_reach", "kinematic_singularity", "limits_infeasible") or args.path == "file":
        return ""
    where = "about --center" if args.center is not None else "beside the start point (its centre --radius along -x)"
    return (f". Hint: the {args.path} of radius {args.radius:g} m {where} may leave what the arm reaches from this "
            "start within its limits: try a smaller --radius, another --center or --normal, or another --q0")
