"""The path of ``track`` and ``plan`` from their options (``--path``, ``--path-file``, ``--center``, ``--radius``,
``--speed``, ``--normal``: :func:`kinredund.ui.options.add_path`), and the options a path does not take refused."""

from __future__ import annotations

import numpy as np

from kinredund.errors import KinredundError
from kinredund.tasks import get_task

#: the circle's and ellipse's radius [m] and speed [m/s] where --radius and --speed are not given
RADIUS, SPEED = 0.1, 0.1


def path_for(args, robot, q_start: np.ndarray):
    """The path named by --path (argparse restricts it) and, for an open path, its duration [s] (else None).

    Circles and ellipses start at the pose of ``q_start``.
    """
    from kinredund import paths

    _check_path_options(args)
    if args.path == "file":
        if args.path_file is None:
            raise KinredundError("--path file needs --path-file FILE (JSON with 't', 'p' and optionally 'Q', 'closed')")
        path, duration = paths.read_path_file(args.path_file)
        check_file_for_task(args.path_file, path, robot)
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
    if task.planar and np.any(normal[:2] != 0.0):  # a tilted circle would be tracked as its shadow on the plane
        raise KinredundError(f"--normal {','.join(f'{v:g}' for v in normal)}: the {robot.task!r} task follows x and y "
                             "only, so the circle must lie in its plane: --normal 0,0,1 (or leave it out)")
    return paths.Circle(center, args.radius, args.speed, normal=tuple(normal), orientation=held), None


def _check_path_options(args) -> None:
    """Refuse an option the chosen --path does not take (it would be ignored: another path than described); then
    give --radius and --speed their defaults where the path takes them (the hints quote them)."""
    unused = {"file": ("--center", "--radius", "--speed", "--normal"), "ellipse": ("--normal",)}.get(args.path, ())
    given = [o for o in unused if getattr(args, o[2:]) is not None]
    if given:
        why = ": the file's samples fix the path's size and its times" if args.path == "file" else ""
        raise KinredundError(f"{' and '.join(given)} do(es) not apply to --path {args.path}{why}: leave it out")
    if args.path != "file" and args.path_file is not None:
        raise KinredundError(f"--path-file is read with --path file: give --path file too (--path is {args.path})")
    if args.path != "file":
        args.radius = RADIUS if args.radius is None else args.radius
        args.speed = SPEED if args.speed is None else args.speed


def check_file_for_task(file, path, robot) -> None:
    """Refuse a path file that says more than the robot's task follows, which would be dropped silently: rotations
    ('Q') for a task without orientation (planar, position), and a z that moves for a planar task (it follows x
    and y only: the path would be tracked as its shadow on the plane, as a tilted --normal would)."""
    from kinredund.paths.sampled import POINT_TOL

    task = get_task(robot.task)
    if path.has_orientation and not task.has_orientation:
        raise KinredundError(f"{file} holds rotations ('Q'), and {robot.name}'s {robot.task!r} task follows the "
                             "position only: the rotations would be ignored. Allowed: leave 'Q' out of the file, or "
                             "--task pose (or axis) to follow them too")
    z = path.points[:, 2]
    if task.planar and np.ptp(z) > POINT_TOL:
        raise KinredundError(f"{file} moves in z (from {z.min():.6g} to {z.max():.6g} m), and {robot.name}'s "
                             f"{robot.task!r} task follows x and y only: the path would be tracked as its shadow on "
                             f"the plane. Allowed: one z for every sample (within {POINT_TOL:g} m), 'p' in x, y only "
                             "(N x 2), or --task position to follow z too")


def _holding(path, Q0: np.ndarray):
    """``path`` (a point path) with the constant orientation Q0: a pose path (omega = 0)."""
    from kinredund.paths import FunctionPath

    def sample(t: float):
        s = path.sample(t)
        return Q0, s.p, np.zeros(3), s.v

    return FunctionPath(sample, period=path.period, has_orientation=True)
