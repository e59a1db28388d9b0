"""The ``kinredund`` command line: parses arguments and calls the library (no logic lives here).

Exit codes, for scripts (:func:`main`, docs/schema.md): 0 success; 1 the run finished but its result
failed its own check (IK not converged, a plan that collides: stderr says which); 2 bad arguments, input
files, output paths or a run the library refused (an error of the kinredund family, printed as
``kinredund: error: ...``); 3 an internal error (a bug, with a request to report it); 130 interrupted;
141 stdout closed by its reader.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError
from kinredund.io import json_ready, write_json
from kinredund.tasks import get_task, task_names

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERNAL = 0, 1, 2, 3
REPRODUCIBLE = ("3.2", "4.1", "4.2", "4.3", "6.2", "6.3")


class _Parser(argparse.ArgumentParser):
    """argparse with exit code 2 and our error prefix."""

    def error(self, message):  # noqa: D401 - argparse API
        self.print_usage(sys.stderr)
        self.exit(EXIT_USAGE, f"kinredund: error: {message}\n")


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


_COUNT = _at_least(1)  # loops, steps and starts: kinredund.tracking.track and kinredund.ik.solve_ik


def _progress(label: str):
    from kinredund.ui.progress import ProgressBar

    return ProgressBar(label)


def _print_summary(summary: dict) -> None:
    for key, value in summary.items():
        if isinstance(value, list) and len(value) > 6:
            value = f"[{value[0]:.3g}, ..., {value[-1]:.3g}] ({len(value)} values)"
        elif isinstance(value, float):
            value = f"{value:.3g}"
        print(f"  {key:24s} {value}")


# -- commands --------------------------------------------------------------------------------------
def _cmd_generate_robots(args) -> int:
    from kinredund.model.generate import generate_robots

    for path in generate_robots(Path(args.out)):
        print(f"wrote {path}")
    return EXIT_OK


def _cmd_robots(args) -> int:
    from kinredund.model.loader import robot_table

    print(f"{'name':14s} {'n':>2s}  {'task':8s} {'m':>1s}  {'redundancy':10s} {'default frame':24s} source")
    for row in robot_table():
        print(f"{row.name:14s} {row.n:2d}  {row.task:8s} {row.m:1d}  n - m = {row.n - row.m:<3d}"
              f"{row.ee_frame:24s} {row.note}")
    return EXIT_OK


def _cmd_reproduce(args) -> int:
    name = args.example
    if name in ("4.1", "4.2", "4.3"):
        from kinredund.thesis.chapter4 import reproduce

        traj = reproduce(name, loops=args.loops, steps_per_loop=args.steps, mode=args.mode, scheme=args.scheme,
                         json_path=args.json, plot_path=args.plot, progress=_progress(f"Example {name}"))
        print(f"Example {name} ({args.mode} mode, {args.scheme} scheme, {args.loops} loop(s), {args.steps} steps/loop)")
        _print_summary(traj.summary())
    elif name == "3.2":
        from kinredund.thesis.helix_3_2 import reproduce

        out = reproduce(json_path=args.json, plot_path=args.plot)
        print("Section 3.2: helix tracked by the hybrid closed-form IK")
        _print_summary({k: v for k, v in out.items() if not isinstance(v, (list, dict))})
    else:
        code = _plan(name, args.json, args.plot, label=f"Example {name}")
        if code != EXIT_OK:
            return code
    for p in (args.json, args.plot):
        if p is not None:
            print(f"wrote {p}")
    return EXIT_OK


def _plan(case: str, json_path, plot_path, samples=None, label: str = "planning") -> int:
    """Run a Chapter 6 case (``reproduce 6.x`` and ``plan``); EXIT_FAILED when the plan fails its check."""
    from kinredund.thesis.chapter6 import reproduce

    more = {} if samples is None else {"samples": samples}
    result = reproduce(case, json_path=json_path, plot_path=plot_path, progress=_progress(label), **more)
    print(f"Section {case}: off-line plan with collision avoidance")
    _print_summary(result.summary())
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
    from kinredund.ik.solve import solve_ik
    from kinredund.model.robot import load_robot
    from kinredund.tracking import track

    robot = load_robot(args.robot, ee_frame=args.ee_frame, task=args.task)
    seed_q = robot.home if args.q0 is None else robot.check_q(args.q0, "--q0")
    path, duration = _path_for(args, robot, seed_q)
    index = None if args.scheme == "pseudoinverse" else _index_for(robot, args.index)
    s0 = path(0.0)
    target = get_task(robot.task).target_from_sample(s0)
    res = solve_ik(robot, target, index, q0=seed_q, starts=args.starts)
    if not res.converged:
        raise KinredundError(f"no starting configuration on the path: {res.reason}")
    # a closed path runs --loops loops of --steps steps; an open one --steps steps over its duration
    span = {} if duration is None else {"duration": duration, "steps": args.steps}
    traj = track(robot, path, index, res.q, scheme=args.scheme, mode=args.mode, steps_per_loop=args.steps,
                 loops=args.loops, progress=_progress("tracking"), **span)
    print(f"{robot.name}: {args.path}, {args.scheme} scheme, {args.mode} mode")
    _print_summary(traj.summary())
    if args.json:
        traj.save_json(args.json)
        print(f"wrote {args.json}")
    if args.plot:
        from kinredund.ui.plots import plot_joint_histories

        plot_joint_histories(traj, args.plot)
        print(f"wrote {args.plot}")
    if args.html:
        from kinredund.ui.viz import replay_html

        replay_html(traj, args.html, robot=robot)
        print(f"wrote {args.html}")
    return EXIT_OK


def _cmd_ik(args) -> int:
    from kinredund.ik.solve import solve_ik
    from kinredund.model.robot import load_robot

    robot = load_robot(args.robot, ee_frame=args.ee_frame, task=args.task)
    if get_task(robot.task).has_orientation:
        if args.target.shape != (3,) or args.rpy is None or args.rpy.shape != (3,):
            raise KinredundError("a pose target needs --target x,y,z and --rpy roll,pitch,yaw [rad]")
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
    if not res.converged:
        print(f"kinredund: IK did not converge: {res.reason}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _cmd_play(args) -> int:
    from kinredund.trajectory import Trajectory

    traj = Trajectory.load_json(args.result)
    if args.html is None and not args.live:
        raise KinredundError("say what to do: --html FILE (standalone replay) and/or --live (meshcat server)")
    if args.html is not None:
        from kinredund.ui.viz import replay_html

        print(f"wrote {replay_html(traj, args.html)}")
    if args.live:
        import time

        from kinredund.ui.viz import play_live, stop_live

        url = play_live(traj, loop=True)
        print(f"open {url} (Ctrl-C to stop)")
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            stop_live(url)
    return EXIT_OK


def _cmd_plan(args) -> int:
    return _plan(args.case, args.json, args.plot, samples=args.samples)


def _cmd_demo(args) -> int:
    from kinredund.ui.demo import run_demo

    return run_demo(Path(args.out), quick=args.quick)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = _Parser(prog="kinredund", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("demo", help="the main job: reproduce every thesis example into an output folder")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--quick", action="store_true", help="fewer loops (for tests)")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("reproduce", help="reproduce a thesis example")
    p.add_argument("example", choices=REPRODUCIBLE)
    p.add_argument("--loops", type=_COUNT, default=1)
    p.add_argument("--steps", type=_COUNT, default=200, help="steps per loop (default 200, as the thesis)")
    p.add_argument("--mode", choices=("default", "thesis"), default="default")
    p.add_argument("--scheme", choices=("augmented", "velocity", "pseudoinverse", "liegeois"), default="augmented")
    p.add_argument("--json", type=Path)
    p.add_argument("--plot", type=Path)
    p.set_defaults(func=_cmd_reproduce)

    p = sub.add_parser("track", help="track a path with a robot")
    p.add_argument("robot", help="a robot name (see `kinredund robots`) or a URDF path")
    p.add_argument("--ee-frame")
    p.add_argument("--task", choices=task_names())
    p.add_argument("--path", choices=("circle", "ellipse", "file"), default="circle")
    p.add_argument("--path-file", type=Path,
                   help="for --path file: JSON with 't' [s], 'p' [m] and optionally 'Q', 'closed' (default true); "
                        "times count from the first sample")
    p.add_argument("--center", type=_vector)
    p.add_argument("--radius", type=float, default=0.1)
    p.add_argument("--speed", type=float, default=0.1)
    p.add_argument("--normal", type=_vector)
    p.add_argument("--q0", type=_vector, help="a configuration near the start (default: the robot's home)")
    p.add_argument("--index", choices=("home", "min-norm", "mid-range"), default="home")
    p.add_argument("--scheme", choices=("augmented", "velocity", "pseudoinverse", "liegeois"), default="augmented")
    p.add_argument("--mode", choices=("default", "thesis"), default="default")
    p.add_argument("--loops", type=_COUNT, default=1, help="loops of a closed path (default 1)")
    p.add_argument("--steps", type=_COUNT, default=200,
                   help="steps per loop of a closed path, steps in all of an open one (default 200)")
    p.add_argument("--starts", type=_COUNT, default=8)
    p.add_argument("--json", type=Path)
    p.add_argument("--plot", type=Path)
    p.add_argument("--html", type=Path)
    p.set_defaults(func=_cmd_track)

    p = sub.add_parser("ik", help="joint-level (constrained) inverse kinematics")
    p.add_argument("robot")
    p.add_argument("--target", type=_vector, required=True, help="x,y (planar) or x,y,z [m]")
    p.add_argument("--rpy", type=_vector, help="roll,pitch,yaw [rad] for pose tasks")
    p.add_argument("--ee-frame")
    p.add_argument("--task", choices=task_names())
    p.add_argument("--index", choices=("none", "home", "min-norm", "mid-range"), default="none")
    p.add_argument("--q0", type=_vector)
    p.add_argument("--bounds", action="store_true", help="respect the joint limits")
    p.add_argument("--starts", type=_COUNT, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", type=Path)
    p.set_defaults(func=_cmd_ik)

    p = sub.add_parser("plan", help="off-line planning with collision avoidance (Chapter 6)")
    p.add_argument("case", choices=("6.2", "6.3"))
    p.add_argument("--samples", type=_at_least(4), default=9,
                   help="sample points of the 6.2 planner (at least 4, as kinredund.planning.plan needs for its cubic "
                        "spline; 6.3 plans on a roadmap)")
    p.add_argument("--json", type=Path)
    p.add_argument("--plot", type=Path)
    p.set_defaults(func=_cmd_plan)

    p = sub.add_parser("play", help="replay a trajectory JSON in the browser")
    p.add_argument("result", type=Path)
    p.add_argument("--html", type=Path, help="write a standalone HTML replay")
    p.add_argument("--live", action="store_true", help="serve it live on a local meshcat server")
    p.set_defaults(func=_cmd_play)

    p = sub.add_parser("generate-robots", help="write robots/*.urdf from the thesis's HD tables")
    p.add_argument("--out", default="robots")
    p.set_defaults(func=_cmd_generate_robots)

    p = sub.add_parser("robots", help="list the robots load_robot knows")
    p.set_defaults(func=_cmd_robots)
    from kinredund.ui.cli_retime import add_parsers as add_retime_parsers  # retime, export (issue 16)
    add_retime_parsers(sub)
    from kinredund.ui.cli_sweep import add_parser as add_sweep_parser  # the placement sweep (its own module)
    add_sweep_parser(sub)
    return parser


#: the options that name an output file; every one is checked before any work (kinredund.io.check_output_path)
OUTPUT_OPTIONS = ("json", "plot", "html", "csv")  # --bag is a folder: kinredund.ui.cli_retime checks it
#: 128 + the signal number, as a shell reports a process ended by SIGINT or SIGPIPE
EXIT_SIGINT, EXIT_SIGPIPE = 130, 141


def _check_outputs(args) -> None:
    """Refuse every bad output path before any work: a directory, a device, a FIFO, a dangling symlink,
    a path under a file, a plot suffix matplotlib does not write, or two options naming one file."""
    from kinredund.errors import check_choice
    from kinredund.io import check_output_path

    seen: dict = {}
    for name in OUTPUT_OPTIONS:
        value = getattr(args, name, None)
        if value is None:
            continue
        target = check_output_path(value)
        if name == "plot":
            from kinredund.ui.plots import PLOT_FORMATS

            check_choice("--plot format (file suffix)", Path(value).suffix.lower().lstrip("."), PLOT_FORMATS)
        if target in seen:
            raise KinredundError(f"--{seen[target]} and --{name} name the same file {str(value)!r}")
        seen[target] = name


def _quiet_stdout() -> None:
    """After a broken pipe: point stdout at /dev/null so that the interpreter's last flush stays quiet."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # no real file descriptor (stdout replaced, e.g. under a test runner)
        pass


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code.

    Exit codes (docs/schema.md): 0 success; 1 a result that failed its own check (the message says
    which); 2 bad arguments or input, output paths included (``kinredund: error: ...``); 3 an internal
    error (a bug: please report it); 130 interrupted (Ctrl-C); 141 stdout closed by the reader (e.g.
    ``| head``), quietly. The output files of one command (``--json``, ``--plot``, ``--html``) land
    together or none does: every path is checked before the run, and the files are renamed into place
    only when the command ends (:func:`kinredund.io.output_batch`). ``demo`` writes each file of its
    folder as it is done.
    """
    from kinredund.io import output_batch

    try:
        args = build_parser().parse_args(argv)
        _check_outputs(args)
        if args.command == "demo":
            code = args.func(args)
        else:
            with output_batch():
                code = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
        return code
    except KinredundError as err:
        print(f"kinredund: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("kinredund: interrupted; no output file was written", file=sys.stderr)
        return EXIT_SIGINT
    except BrokenPipeError:
        _quiet_stdout()
        return EXIT_SIGPIPE
    except Exception as err:  # noqa: BLE001 - the last line of defence, reported as internal
        import traceback

        traceback.print_exc(file=sys.stderr)
        print(f"kinredund: internal error: {type(err).__name__}: {err}\n"
              "This is a bug in kinredund, not in your input: please report it with the command line and the "
              "traceback above.", file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
