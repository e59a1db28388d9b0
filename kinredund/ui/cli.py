"""The ``kinredund`` command line: parses arguments and calls the library (no logic lives here).

Exit codes, for scripts: 0 success; 1 the run finished but its result failed its own check (IK not
converged, a plan that collides); 2 bad arguments, input files or a run the library refused (an error
of the kinredund family, printed as ``kinredund: error: ...``); 3 an unexpected internal error.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError
from kinredund.io import json_ready, write_json
from kinredund.tasks import get_task, task_names

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERNAL = 0, 1, 2, 3
REPRODUCIBLE = ("3.2", "4.1", "4.2", "4.3", "6.2", "6.3")
SCHEMES = ("augmented", "velocity", "pseudoinverse", "liegeois")

DESCRIPTION = """\
Kinematic control of redundant robot arms, after S. Mathur's 1989 McGill thesis: follow a path with
the end effector while the extra joints keep a performance index at its optimum, solve inverse
kinematics with joint limits, and plan collision-free cyclic motions. Every thesis example can be
reproduced, plotted and replayed in a web browser."""

EPILOG = """\
examples:
  kinredund demo --out out           reproduce every thesis example into out/ (figures, replays, summary)
  kinredund robots                   the robots you can name
  kinredund track panda --html panda.html
  kinredund reproduce 4.3 --plot joints.png
  kinredund plan 6.3 --json plan.json && kinredund play plan.json --html plan.html

Run `kinredund COMMAND --help` for the options of one command."""


class _Parser(argparse.ArgumentParser):
    """argparse with exit code 2 and our error prefix."""

    def error(self, message):  # noqa: D401 - argparse API
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"kinredund: error: {message}\n")


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and examples printed as written (their line breaks kept)."""


def _vector(text: str) -> np.ndarray:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from err
    if not values or not np.all(np.isfinite(values)):
        raise argparse.ArgumentTypeError(f"expected finite comma-separated numbers, got {text!r}")
    return np.array(values)


def _at_least(minimum: int):
    """An argparse type: an integer >= ``minimum`` (the bound the library checks too, so both agree)."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from err
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}, got {value}")
        return value

    return parse


_COUNT = _at_least(1)  # loops, steps and starts: kinredund.tracking.resolved_rate.track and kinredund.ik.solve_ik


def _progress(label: str, args):
    """The progress display of a command (:class:`kinredund.ui.progress.Progress`), shown at once."""
    from kinredund.ui.progress import Progress

    bar = Progress(label, quiet=getattr(args, "quiet", False))
    bar(0, 1, "starting")
    return bar


# -- printing ----------------------------------------------------------------------------------------
#: Units of the summary figures the commands print.
_UNITS = {"position_error_max": "m", "max_position_residual": "m", "clearance_min": "m",
          "clearance_lower_bound": "m", "clearance_doubling_change": "m", "penetration_max": "m",
          "spline_gap_max": "rad", "loop_drift": "rad", "theta3_ref_deg": "deg", "theta4_ref_deg": "deg",
          "max_joint_step_deg": "deg", "timings_s": "s", "wrist_reach_needed": "m", "wrist_reach_available": "m"}


def _number(v) -> str:
    return str(v) if isinstance(v, (bool, int, np.integer)) else f"{float(v):.3g}"


def _shown(value) -> bool:
    """Whether a summary value says something (not None, NaN, or an empty list or dict)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return False
    return not (isinstance(value, (list, tuple, dict, str)) and len(value) == 0)


def _format(key: str, value) -> str:
    unit = _UNITS.get(key, "")
    suffix = f" {unit}" if unit else ""
    if key == "loop_drift":  # a list per loop from tracking, one float from a plan: one format
        drift = [float(v) for v in (value if isinstance(value, (list, tuple, np.ndarray)) else [value])]
        return f"{drift[-1]:.3g} rad after loop {len(drift)}" + (
            f" (largest {max(drift):.3g} rad)" if len(drift) > 1 else "")
    if isinstance(value, dict):
        return ", ".join(f"{k.removesuffix('_s')} {_number(v)}{suffix}" for k, v in value.items() if _shown(v))
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, str) for v in value):
            return ", ".join(value)
        items = [_number(v) for v in value]
        text = f"[{', '.join(items)}]" if len(items) <= 7 else f"[{items[0]}, {items[1]}, ..., {items[-1]}] " \
            f"({len(items)} values)"
        return text + suffix
    if isinstance(value, (float, int, np.floating, np.integer)) and not isinstance(value, bool):
        return _number(value) + suffix
    return str(value)


def _print_summary(summary: dict) -> None:
    """Print ``summary`` as aligned ``name value unit`` rows, leaving out empty values (None, NaN, {})."""
    for key, value in summary.items():
        if _shown(value):
            print(f"  {key:26s} {_format(key, value)}")


def _wrote(*paths) -> None:
    for p in paths:
        if p is not None:
            print(f"wrote {p}")


# -- commands --------------------------------------------------------------------------------------
def _cmd_generate_robots(args) -> int:
    from kinredund.model.generate import generate_robots

    _wrote(*generate_robots(Path(args.out)))
    return EXIT_OK


def _cmd_robots(args) -> int:
    from kinredund.model.robot import known_robots, load_robot

    print(f"{'name':16s} {'joints':>6s}  {'task':8s} {'task rows':>9s}  end-effector frame")
    for name in known_robots():
        r = load_robot(name)
        print(f"{name:16s} {r.nq:6d}  {r.task:8s} {r.task_dim:9d}  {r.ee_frame}")
    return EXIT_OK


def _cmd_reproduce(args) -> int:
    name = args.example
    if name in ("6.2", "6.3"):
        return _plan(name, args, label=f"reproduce {name}")
    bar = _progress(f"reproduce {name}", args)
    if name in ("4.1", "4.2", "4.3"):
        from kinredund.thesis.chapter4 import reproduce

        try:
            traj = reproduce(name, loops=args.loops, steps_per_loop=args.steps, mode=args.mode, scheme=args.scheme,
                             json_path=args.json, plot_path=args.plot,
                             progress=lambda d, n: bar(d, n, "tracking"))
        finally:
            bar.close()
        print(f"Example {name}: {args.scheme} scheme, {args.mode} mode, {args.loops} loop(s) of {args.steps} steps")
        _print_summary(traj.summary())
    else:
        from kinredund.thesis.helix_3_2 import reproduce

        bar(0, 1, "closed-form solutions along the helix")
        try:
            out = reproduce(json_path=args.json, plot_path=args.plot)
        finally:
            bar.close()
        print("Section 3.2: helix tracked by the hybrid closed-form IK")
        _print_summary({k: v for k, v in out.items() if not isinstance(v, (list, dict))})
    _wrote(args.json, args.plot)
    return EXIT_OK


def _plan(case: str, args, label: str) -> int:
    """Run a Chapter 6 case (``reproduce 6.x`` and ``plan``); EXIT_FAILED when the plan fails its check."""
    bar = _progress(label, args)
    from kinredund.thesis.chapter6 import reproduce, snapshot_path

    more = {} if getattr(args, "samples", None) is None else {"samples": args.samples}
    try:
        result = reproduce(case, json_path=args.json, plot_path=args.plot, progress=bar, **more)
    finally:
        bar.close()
    print(f"Section {case}: off-line plan with collision avoidance")
    _print_summary({k: v for k, v in result.summary().items() if k != "reason"})  # a failure's reason: below
    _wrote(args.json, args.plot)
    if args.plot is not None and result.trajectory is not None:
        _wrote(snapshot_path(args.plot))
    if not result.ok:
        print(f"kinredund: plan failed: {result.reason}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _index_for(robot, name: str):
    """The index named by --index (argparse restricts ``name`` to home, min-norm and mid-range)."""
    from kinredund import indices

    if name == "min-norm":
        return indices.minimum_norm(robot.nq)
    if name == "mid-range":
        return indices.mid_range(robot.lower, robot.upper)
    return indices.JointDeviation(robot.home)


def _path_for(args, robot, q_start: np.ndarray):
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
    if args.path == "ellipse":
        center = args.center if args.center is not None else p0[:2] - np.array([args.radius, 0.0])
        return paths.Ellipse(center[:2], args.radius, args.radius / 2, rate=args.speed / args.radius), None
    normal = args.normal if args.normal is not None else np.array([0.0, 0.0, 1.0])
    center = args.center if args.center is not None else p0 - args.radius * np.array([1.0, 0.0, 0.0])
    if center.shape == (2,):
        center = np.append(center, p0[2] if not get_task(robot.task).planar else 0.0)
    # pose tasks hold the start orientation along the circle
    return paths.Circle(center, args.radius, args.speed, normal=tuple(normal),
                        orientation=T0[:3, :3] if get_task(robot.task).has_orientation else None), None


def _cmd_track(args) -> int:
    bar = _progress(f"track {args.robot}", args)
    from kinredund.ik.solve import solve_ik
    from kinredund.model.robot import load_robot
    from kinredund.tracking.resolved_rate import track

    try:
        bar(0, 1, "loading the robot")
        robot = load_robot(args.robot, ee_frame=args.ee_frame, task=args.task)
        seed_q = robot.home if args.q0 is None else robot.check_q(args.q0, "--q0")
        path, duration = _path_for(args, robot, seed_q)
        # the baselines ignore the index while they step; their normality residual is measured against it
        index = _index_for(robot, args.index)
        s0 = path(0.0)
        target = get_task(robot.task).target_from_sample(s0)
        bar(0, 1, "the optimal start (IK)")
        res = solve_ik(robot, target, index, q0=seed_q, starts=args.starts)
        if not res.converged:
            raise KinredundError(f"no starting configuration on the path: {res.reason}")
        # a closed path runs --loops loops of --steps steps; an open one --steps steps over its duration
        span = {} if duration is None else {"duration": duration, "steps": args.steps}
        traj = track(robot, path, index, res.q, scheme=args.scheme, mode=args.mode, steps_per_loop=args.steps,
                     loops=args.loops, progress=lambda d, n: bar(d, n, "tracking"), **span)
        if args.html:
            bar(0, 1, "the HTML replay")
            from kinredund.ui.viz import replay_html
            from kinredund.ui.viz.page import replay_title

            replay_html(traj, args.html, robot=robot, title=replay_title(traj, args.path))
    finally:
        bar.close()
    print(f"{robot.name}: {args.path}, {args.scheme} scheme, {args.mode} mode, index {args.index}")
    _print_summary(traj.summary())
    if args.json:
        traj.save_json(args.json)
    if args.plot:
        from kinredund.ui.plots import plot_joint_histories

        plot_joint_histories(traj, args.plot)
    _wrote(args.json, args.plot, args.html)
    return EXIT_OK


def _cmd_ik(args) -> int:
    from kinredund.ik.solve import solve_ik
    from kinredund.model.robot import load_robot

    robot = load_robot(args.robot, ee_frame=args.ee_frame, task=args.task)
    if get_task(robot.task).has_orientation:
        if args.target.shape != (3,) or args.rpy is None or args.rpy.shape != (3,):
            raise KinredundError(
                f"{robot.name} has a pose task: give --target x,y,z [m] and --rpy roll,pitch,yaw [rad], "
                "or --task position to reach the point with any orientation")
        from kinredund.kinematics.closure import rotation_from_invariants

        r_, p_, y_ = args.rpy
        Q = (rotation_from_invariants([0, 0, 1], y_) @ rotation_from_invariants([0, 1, 0], p_)
             @ rotation_from_invariants([1, 0, 0], r_))
        target = (Q, args.target)  # what kinredund.tasks.make_target takes
    else:
        target = args.target
    index = None if args.index == "none" else _index_for(robot, args.index)
    q0 = None if args.q0 is None else robot.check_q(args.q0, "--q0")
    res = solve_ik(robot, target, index, q0=q0, bounds=args.bounds, starts=args.starts, seed=args.seed)
    out = json_ready({"robot": robot.name, **dataclasses.asdict(res)})  # the IKResult's fields (docs/schema.md)
    print(json.dumps(out, indent=2))
    if args.json:
        write_json(args.json, out)
        _wrote(args.json)
    return EXIT_OK if res.converged else EXIT_FAILED


def _cmd_play(args) -> int:
    if args.html is None and not args.live:
        raise KinredundError(f"say what to do with {args.result}: --html FILE writes a standalone replay, "
                             "--live serves it on a local meshcat server (both may be given)")
    from kinredund.ui.records import replay_record

    rec = replay_record(args.result)
    if args.html is not None:
        from kinredund.ui.viz import replay_html

        _wrote(replay_html(rec.trajectory, args.html, robot=rec.robot, title=rec.title))
    if args.live:
        import time

        from kinredund.ui.viz import play_live, stop_live

        url = play_live(rec.trajectory, robot=rec.robot, loop=True)
        print(f"open {url} (Ctrl-C to stop)")
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            stop_live(url)
    return EXIT_OK


def _cmd_plan(args) -> int:
    return _plan(args.case, args, label=f"plan {args.case}")


def _cmd_demo(args) -> int:
    from kinredund.ui.demo import run_demo

    return run_demo(Path(args.out), quick=args.quick, quiet=args.quiet)


# -- the parser ------------------------------------------------------------------------------------
def _sub(sub, name: str, help_: str, description: str, examples: list[str]):
    epilog = "examples:\n" + "\n".join(f"  {e}" for e in examples)
    return sub.add_parser(name, help=help_, description=description, epilog=epilog, formatter_class=_Formatter)


def _add_outputs(p, *, html: bool = False) -> None:
    p.add_argument("--json", type=Path, metavar="FILE", help="write the result as JSON (default: not written)")
    p.add_argument("--plot", type=Path, metavar="FILE",
                   help="save the figure; the format follows the suffix: .png, .pdf or .svg (default: not drawn)")
    if html:
        p.add_argument("--html", type=Path, metavar="FILE",
                       help="write a standalone HTML replay that plays offline in a browser (default: not written)")


def _add_quiet(p) -> None:
    p.add_argument("--quiet", action="store_true",
                   help="no progress display on standard error (default: shown for runs over about 2 s)")


def _add_tracking(p) -> None:
    p.add_argument("--loops", type=_COUNT, default=1, metavar="N",
                   help="loops of the closed path to track (default: %(default)s)")
    p.add_argument("--mode", choices=("default", "thesis"), default="default",
                   help="default: implicit steps that stay on the optimum (cyclic); thesis: the thesis's explicit "
                        "Euler steps with velocity correction, Eq. (4.29) (default: %(default)s)")
    p.add_argument("--scheme", choices=SCHEMES, default="augmented",
                   help="augmented: the thesis's scheme on the displacement Jacobian (Eq. 4.24); velocity: the same "
                        "on the velocity Jacobian; pseudoinverse and liegeois: the baselines (Whitney 1972, "
                        "Liegeois 1977) (default: %(default)s)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    from kinredund import __version__

    parser = _Parser(prog="kinredund", description=DESCRIPTION, epilog=EPILOG, formatter_class=_Formatter)
    parser.add_argument("--version", action="version", version=f"kinredund {__version__}",
                        help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND")

    p = _sub(sub, "demo", "the main job: reproduce every thesis example into an output folder",
             "Reproduce every thesis example (Sections 3.2, 6.2, 6.3 and Examples 4.1-4.3) and write the figures, "
             "the HTML replays and a summary table next to the thesis's figures.",
             ["kinredund demo --out out", "kinredund demo --out /tmp/quick --quick"])
    p.add_argument("--out", default="out", metavar="DIR",
                   help="output folder, created if needed (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="2 loops instead of 10 per example, for a quick check "
                   "(default: 10 loops)")
    _add_quiet(p)
    p.set_defaults(func=_cmd_demo)

    p = _sub(sub, "reproduce", "reproduce a thesis example",
             "Reproduce one thesis example: 3.2 (closed-form IK along a helix), 4.1-4.3 (cyclic resolved-rate "
             "tracking), 6.2 and 6.3 (off-line planning around an obstacle). --loops, --steps, --mode and "
             "--scheme apply to 4.1-4.3.",
             ["kinredund reproduce 4.3 --loops 10 --plot joints.png",
              "kinredund reproduce 4.2 --scheme pseudoinverse --json 4_2.json",
              "kinredund reproduce 6.3 --json plan.json --plot plan.png"])
    p.add_argument("example", choices=REPRODUCIBLE, help="the thesis section or example")
    _add_tracking(p)
    p.add_argument("--steps", type=_COUNT, default=200, metavar="N",
                   help="steps per loop, as in the thesis (default: %(default)s)")
    _add_outputs(p)
    _add_quiet(p)
    p.set_defaults(func=_cmd_reproduce)

    p = _sub(sub, "track", "track a path with a robot",
             "Find the optimal start on the path (joint-level IK), then track the path with the resolved-rate "
             "scheme, keeping the extra joints at the optimum of the performance index.",
             ["kinredund track panda --html panda.html",
              "kinredund track planar3r --path ellipse --radius 0.5 --loops 3 --plot joints.png",
              "kinredund track xarm7 --task position --scheme pseudoinverse --json run.json"])
    p.add_argument("robot", help="a robot name (see `kinredund robots`) or the path of a URDF file")
    p.add_argument("--ee-frame", metavar="FRAME", help="the end-effector frame of a URDF (default: the robot's own)")
    p.add_argument("--task", choices=task_names(),
                   help="what the end effector must follow: planar (a point in the plane), position (a 3-D point), "
                        "pose (a point and an orientation) or axis (a point and the tool's axis) (default: the "
                        "robot's own task)")
    p.add_argument("--path", choices=("circle", "ellipse", "file"), default="circle",
                   help="circle and ellipse start at the end effector's start pose; file reads --path-file "
                        "(default: %(default)s)")
    p.add_argument("--path-file", type=Path, metavar="FILE",
                   help="for --path file: JSON with 't' [s], 'p' [m] and optionally 'Q', 'closed' (true when "
                        "absent); times count from the first sample (default: none)")
    p.add_argument("--center", type=_vector, metavar="X,Y[,Z]",
                   help="centre of the circle or ellipse [m] (default: --radius along -x from the start point)")
    p.add_argument("--radius", type=float, default=0.1, metavar="R",
                   help="radius of the circle, semi-major axis of the ellipse [m] (default: %(default)s)")
    p.add_argument("--speed", type=float, default=0.1, metavar="V",
                   help="speed along the path [m/s] (default: %(default)s)")
    p.add_argument("--normal", type=_vector, metavar="X,Y,Z",
                   help="normal of the circle's plane (default: 0,0,1, a horizontal circle)")
    p.add_argument("--q0", type=_vector, metavar="Q1,Q2,...",
                   help="a configuration near the start [rad, m for prismatic joints] (default: the robot's home)")
    p.add_argument("--index", choices=("home", "min-norm", "mid-range"), default="home",
                   help="the performance index kept at its optimum: distance from home, joint norm, or distance "
                        "from mid-range (Chapter 2); the baselines' normality residual is measured against it "
                        "(default: %(default)s)")
    _add_tracking(p)
    p.add_argument("--steps", type=_COUNT, default=200, metavar="N",
                   help="steps per loop of a closed path, steps in all of an open one (default: %(default)s)")
    p.add_argument("--starts", type=_COUNT, default=8, metavar="N",
                   help="IK starts tried for the optimal start configuration (default: %(default)s)")
    _add_outputs(p, html=True)
    _add_quiet(p)
    p.set_defaults(func=_cmd_track)

    p = _sub(sub, "ik", "joint-level (constrained) inverse kinematics",
             "Solve the joint-level problem of Eq. (4.3): reach the target and, with --index, minimise a "
             "performance index; prints the result as JSON. Exit code 1 when it does not converge.",
             ["kinredund ik planar3r --target 1.2,0.5 --index home",
              "kinredund ik panda --target 0.4,0.2,0.5 --rpy 3.1416,0,0 --bounds",
              "kinredund ik panda --target 0.4,0.2,0.5 --task position --index mid-range"])
    p.add_argument("robot", help="a robot name (see `kinredund robots`) or the path of a URDF file")
    p.add_argument("--target", type=_vector, required=True, metavar="X,Y[,Z]",
                   help="the end-effector point: x,y for planar tasks, x,y,z otherwise [m] (required)")
    p.add_argument("--rpy", type=_vector, metavar="R,P,Y",
                   help="roll, pitch, yaw of the target orientation [rad], for pose tasks (default: none; "
                        "without it use --task position)")
    p.add_argument("--ee-frame", metavar="FRAME", help="the end-effector frame of a URDF (default: the robot's own)")
    p.add_argument("--task", choices=task_names(),
                   help="planar, position (a 3-D point), pose (point and orientation) or axis (point and tool axis) "
                        "(default: the robot's own task)")
    p.add_argument("--index", choices=("none", "home", "min-norm", "mid-range"), default="none",
                   help="the performance index to minimise; none: any solution (default: %(default)s)")
    p.add_argument("--q0", type=_vector, metavar="Q1,Q2,...",
                   help="the first start [rad, m for prismatic joints] (default: the robot's home)")
    p.add_argument("--bounds", action="store_true", help="respect the joint limits (default: unbounded)")
    p.add_argument("--starts", type=_COUNT, default=1, metavar="N",
                   help="starts tried, the others random within the limits (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random starts (default: %(default)s)")
    p.add_argument("--json", type=Path, metavar="FILE", help="also write the result as JSON (default: not written)")
    p.set_defaults(func=_cmd_ik)

    p = _sub(sub, "plan", "off-line planning with collision avoidance (Chapter 6)",
             "Plan a collision-free cyclic motion around the obstacle of Section 6.2 (planar) or 6.3 (spatial): "
             "joint-level samples, a spline through them, resolved-rate tracking and a clearance check. Exit "
             "code 1 when the plan fails its check (6.2 has no collision-free plan: the reason is printed).",
             ["kinredund plan 6.3 --json plan.json --plot plan.png",
              "kinredund play plan.json --html plan.html"])
    p.add_argument("case", choices=("6.2", "6.3"), help="the thesis section")
    p.add_argument("--samples", type=_at_least(4), default=9, metavar="N",
                   help="sample points of the 6.2 planner, at least 4 for its cubic spline; 6.3 plans on a roadmap "
                        "instead (default: %(default)s)")
    _add_outputs(p)
    _add_quiet(p)
    p.set_defaults(func=_cmd_plan)

    p = _sub(sub, "play", "replay a result JSON in the browser",
             "Replay any JSON the commands write: a trajectory (track, reproduce 4.x), a plan (plan, "
             "reproduce 6.x) or the Section 3.2 helix (reproduce 3.2). Say what to do: --html, --live or both.",
             ["kinredund play run.json --html run.html", "kinredund play plan.json --live"])
    p.add_argument("result", type=Path, help="a JSON file written by track, reproduce or plan")
    p.add_argument("--html", type=Path, metavar="FILE",
                   help="write a standalone HTML replay that plays offline (default: not written)")
    p.add_argument("--live", action="store_true",
                   help="serve the replay on a local meshcat server until Ctrl-C (default: off)")
    p.set_defaults(func=_cmd_play)

    p = _sub(sub, "generate-robots", "write robots/*.urdf from the thesis's HD tables",
             "Write the URDF files of the thesis's robots from their Hartenberg-Denavit tables.",
             ["kinredund generate-robots --out robots"])
    p.add_argument("--out", default="robots", metavar="DIR", help="output folder (default: %(default)s)")
    p.set_defaults(func=_cmd_generate_robots)

    p = _sub(sub, "robots", "list the robots load_robot knows",
             "List the robot names that track, ik and the Python API accept, with their joints and task.",
             ["kinredund robots"])
    p.set_defaults(func=_cmd_robots)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except KinredundError as err:
        print(f"kinredund: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return EXIT_FAILED
    except Exception as err:  # noqa: BLE001 - the last line of defence, reported as internal
        print(f"kinredund: internal error: {type(err).__name__}: {err}", file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
