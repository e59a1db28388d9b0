"""The ``track`` command's notes on the record and its hints (kept out of :mod:`kinredund.ui.cli`)."""

from __future__ import annotations

import sys


def say_speed(traj, robot, args) -> None:
    """A joint faster than its URDF velocity limit: which, how much, when, and the next step."""
    fastest = traj.speed_over_limits
    if fastest is None or not fastest[0] > 1.0:
        return
    ratio, j, t = fastest
    slower = f"--speed {args.speed / ratio:.3g} or less" if args.path != "file" else \
        f"a path file whose times are {ratio:.3g} times as long"
    retime = f"`kinredund retime {args.json} --amax A`" if args.json else \
        "track again with --json RUN.json, then `kinredund retime RUN.json --amax A`"
    print(f"kinredund: note: joint {robot.joint_names[j]} runs at {ratio:.3g} times its URDF velocity limit "
          f"(at t = {t:.4g} s): the arm cannot run this motion at these times. Next step: {retime} (a time law "
          f"within the limits along the same joint path), or {slower}", file=sys.stderr)


def stop_hint(err, args) -> str:
    """What to change on the command line after a tracking stop whose cause the path's size or place
    explains ("" where none does)."""
    if err.cause not in ("out_of_reach", "kinematic_singularity", "limits_infeasible") or args.path == "file":
        return ""
    where = "about --center" if args.center is not None else "beside the start point (its centre --radius along -x)"
    return (f". Hint: the {args.path} of radius {args.radius:g} m {where} may leave what the arm reaches from this "
            "start within its limits: try a smaller --radius, another --center or --normal, or another --q0")
