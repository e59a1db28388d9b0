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
import math
import sys
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError, OptionError, TrackingError
from kinredund.io import json_ready, write_json
from kinredund.tasks import get_task
from kinredund.ui import options
from kinredund.ui.options import EXIT_FAILED, EXIT_INTERNAL, EXIT_OK, EXIT_USAGE, REPRODUCIBLE

__all__ = ["EXIT_FAILED", "EXIT_INTERNAL", "EXIT_OK", "EXIT_USAGE", "REPRODUCIBLE", "build_parser", "main"]


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
    from kinredund.model.loader import robot_table

    print(f"{'name':14s} {'n':>2s}  {'task':8s} {'m':>1s}  {'redundancy':10s} {'default frame':24s} source")
    for row in robot_table():
        print(f"{row.name:14s} {row.n:2d}  {row.task:8s} {row.m:1d}  n - m = {row.n - row.m:<3d}"
              f"{row.ee_frame:24s} {row.note}")
    return EXIT_OK


def _cmd_reproduce(args) -> int:
    name = args.example
    if name in ("6.2", "6.3"):
        return _plan(name, args, label=f"reproduce {name}")
    bar = _progress(f"reproduce {name}", args)
    if name in ("4.1", "4.2", "4.3"):
        from kinredund.ui.reproduce import example

        try:
            traj = example(name, loops=args.loops, steps_per_loop=args.steps, mode=args.mode, scheme=args.scheme,
                             json_path=args.json, plot_path=args.plot,
                             progress=lambda d, n: bar(d, n, "tracking"))
        finally:
            bar.close()
        print(f"Example {name}: {args.scheme} scheme, {args.mode} mode, {args.loops} loop(s) of {args.steps} steps")
        _print_summary(traj.summary())
    else:
        from kinredund.ui.reproduce import helix

        bar(0, 1, "closed-form solutions along the helix")
        try:
            out = helix(json_path=args.json, plot_path=args.plot)
        finally:
            bar.close()
        print("Section 3.2: helix tracked by the hybrid closed-form IK")
        _print_summary({k: v for k, v in out.items() if not isinstance(v, (list, dict))})
    _wrote(args.json, args.plot)
    return EXIT_OK


def _plan(case: str, args, label: str) -> int:
    """Run a Chapter 6 case (``reproduce 6.x`` and ``plan``); EXIT_FAILED when the plan fails its check."""
    bar = _progress(label, args)
    from kinredund.ui.reproduce import plan_case, snapshot_path

    more = {} if getattr(args, "samples", None) is None else {"samples": args.samples}
    try:
        result = plan_case(case, json_path=args.json, plot_path=args.plot, progress=bar, **more)
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


def _write_partial(out, err: TrackingError) -> None:
    """``--partial FILE``: the record up to a tracking stop with the failure (cause, time, state) as JSON."""
    failure = {"cause": err.cause, "t": err.t, "q": err.q, "watched": err.watched, "message": str(err)}
    err.partial.save_json(out, extra={"failure": json_ready(failure)})
    print(f"wrote the partial record up to t = {err.partial.t[-1]:.6g} s to {out}", file=sys.stderr)


def _scene_options(args, robot) -> dict:
    """track()'s scene=, clearance=, self_clearance= from --scene, --clearance, --self-clearance."""
    if args.scene is None:
        if args.clearance is not None or args.self_clearance is not None:
            raise OptionError("--clearance and --self-clearance need --scene FILE")
        return {}
    from kinredund.geometry import load_scene

    return {"scene": load_scene(args.scene, robot), "clearance": args.clearance,
            "self_clearance": args.self_clearance}


def _cmd_track(args) -> int:
    bar = _progress(f"track {args.robot}", args)
    from kinredund.ik.solve import solve_ik
    from kinredund.model.robot import load_robot
    from kinredund.tracking import track

    try:
        bar(0, 1, "loading the robot")
        robot = load_robot(args.robot, ee_frame=args.ee_frame, task=args.task)
        seed_q = robot.home if args.q0 is None else robot.check_q(args.q0, "--q0")
        path, duration = _path_for(args, robot, seed_q)
        # the baselines ignore the index while they step; their normality residual is measured against it
        index = options.index_for(robot, args.index)
        s0 = path(0.0)
        target = get_task(robot.task).target_from_sample(s0)
        bar(0, 1, "the optimal start (IK)")
        res = solve_ik(robot, target, index, q0=seed_q, starts=args.starts, bounds=True)  # within the limits
        if not res.converged:
            raise KinredundError(f"no starting configuration on the path: {res.reason}")
        # a closed path runs --loops loops of --steps steps; an open one --steps steps over its duration
        span = {} if duration is None else {"duration": duration, "steps": args.steps}
        span.update(_scene_options(args, robot))
        try:
            traj = track(robot, path, index, res.q, scheme=args.scheme, mode=args.mode, steps_per_loop=args.steps,
                         loops=args.loops, progress=lambda d, n: bar(d, n, "tracking"), **span)
        except TrackingError as err:
            if args.partial is None or err.partial is None:
                raise
            # the partial record is this command's output: returning (not raising) lets its batch land
            _write_partial(args.partial, err)
            print(f"kinredund: error: {err}", file=sys.stderr)
            return EXIT_USAGE
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
    index = None if args.index == "none" else options.index_for(robot, args.index)
    q0 = None if args.q0 is None else robot.check_q(args.q0, "--q0")
    res = solve_ik(robot, target, index, q0=q0, bounds=args.bounds, starts=args.starts, seed=args.seed)
    out = json_ready({"robot": robot.name, **dataclasses.asdict(res)})  # the IKResult's fields (docs/schema.md)
    print(json.dumps(out, indent=2))
    if args.json:
        write_json(args.json, out)
        _wrote(args.json)
    if not res.converged:
        print(f"kinredund: IK did not converge: {res.reason}", file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK


def _cmd_play(args) -> int:
    if args.html is None and not args.live:
        raise KinredundError(f"say what to do with {args.result}: --html FILE writes a standalone replay, "
                             "--live serves it on a local meshcat server (both may be given)")
    from kinredund.ui.records import replay_record

    rec = replay_record(args.result)
    if args.html is not None:
        from kinredund.geometry import load_scene
        from kinredund.ui.viz import replay_html

        scene = None if args.scene is None else load_scene(args.scene, rec.robot)
        _wrote(replay_html(rec.trajectory, args.html, robot=rec.robot, title=rec.title, scene=scene))
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


# -- the parser (kinredund.ui.options) --------------------------------------------------------------
COMMANDS = {"demo": _cmd_demo, "reproduce": _cmd_reproduce, "track": _cmd_track, "ik": _cmd_ik, "plan": _cmd_plan,
            "play": _cmd_play, "generate-robots": _cmd_generate_robots, "robots": _cmd_robots}


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand (:func:`kinredund.ui.options.build_parser`)."""
    return options.build_parser(COMMANDS)


#: the options that name an output, and its kind: every one is checked before any work (kinredund.io.check_outputs)
OUTPUT_OPTIONS = {"json": "file", "plot": "file", "html": "file", "csv": "file", "partial": "file", "bag": "folder"}
#: 128 + the signal number, as a shell reports a process ended by SIGINT or SIGPIPE
EXIT_SIGINT, EXIT_SIGPIPE = 130, 141


def _check_outputs(args) -> None:
    """Refuse every bad output path before any work (:func:`kinredund.io.check_outputs`): a directory, a
    device, a FIFO, a dangling symlink, a path under a file, a bag folder that exists, two options that
    would overwrite each other (compared resolved, the bag folder included), a plot suffix matplotlib
    does not write."""
    from kinredund.errors import check_choice
    from kinredund.io import check_outputs

    check_outputs((f"--{name}", getattr(args, name, None), kind) for name, kind in OUTPUT_OPTIONS.items())
    if getattr(args, "plot", None) is not None:
        from kinredund.ui.plots import PLOT_FORMATS

        check_choice("--plot format (file suffix)", Path(args.plot).suffix.lower().lstrip("."), PLOT_FORMATS)


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

    batch = None
    try:
        args = build_parser().parse_args(argv)
        _check_outputs(args)
        if args.command == "demo":
            code = args.func(args)
        else:
            with output_batch() as batch:
                code = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
        return code
    except KinredundError as err:
        print(f"kinredund: error: {err}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        kept = [] if batch is None else batch.kept  # checkpoints (a sweep file) stay, to be resumed
        print("kinredund: interrupted; " + (f"kept {', '.join(map(str, kept))} (written as the run went: resume "
              "from it)" if kept else "no output file was written"), file=sys.stderr)
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
