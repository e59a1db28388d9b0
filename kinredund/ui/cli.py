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
import signal
import sys
import warnings
from pathlib import Path

from kinredund.errors import KinredundError, OutputPathError, TrackingError
from kinredund.io import json_ready, write_json
from kinredund.tasks import get_task
from kinredund.trajectory import RecordWarning
from kinredund.ui import options
from kinredund.ui.options import EXIT_FAILED, EXIT_INTERNAL, EXIT_OK, EXIT_USAGE, REPRODUCIBLE
from kinredund.ui.report import outcome, progress_for, wrote
from kinredund.ui.summary import in_cli_words, print_summary, print_table

__all__ = ["EXIT_FAILED", "EXIT_INTERNAL", "EXIT_OK", "EXIT_USAGE", "REPRODUCIBLE", "build_parser", "main"]


# -- commands --------------------------------------------------------------------------------------
def _cmd_generate_robots(args) -> int:
    from kinredund.model.generate import generate_robots

    wrote(*generate_robots(args.out))
    return EXIT_OK


def _cmd_robots(args) -> int:
    from kinredund.model.loader import robot_table

    rows = [(r.name, str(r.n), r.task, str(r.m), f"n - m = {r.n - r.m}", r.ee_frame, r.note) for r in robot_table()]
    print_table(("name", "n", "task", "m", "redundancy", "default frame", "source"), rows, right=(1, 3))
    return EXIT_OK


def _cmd_reproduce(args) -> int:
    name = args.example
    if name not in ("4.1", "4.2", "4.3"):  # the closed form and the plans fix their own settings
        parser = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)).choices
        given = [f"--{k}" for k in ("loops", "steps", "mode", "scheme")
                 if getattr(args, k) != parser["reproduce"].get_default(k)]
        if given:
            raise KinredundError(f"{', '.join(given)} apply to Examples 4.1-4.3 (tracking), not to {name}: leave "
                                 "them out")
    if name in ("6.2", "6.3"):
        from kinredund.ui.cli_plan import run_case

        return run_case(name, args, label=f"reproduce {name}")
    bar = progress_for(f"reproduce {name}", args)
    if name in ("4.1", "4.2", "4.3"):
        from kinredund.ui.reproduce import example

        try:
            with warnings.catch_warnings():  # said below, as a note: the thesis's schemes are compared as they are
                warnings.simplefilter("ignore", RecordWarning)
                traj = example(name, loops=args.loops, steps_per_loop=args.steps, mode=args.mode, scheme=args.scheme,
                               json_path=args.json, plot_path=args.plot,
                               progress=lambda d, n: bar(d, n, "tracking"))
        finally:
            bar.close()
        print(f"Example {name}: {args.scheme} scheme, {args.mode} mode, {args.loops} loop(s) of {args.steps} steps")
        print_summary(traj.summary())
        for key in ("loop_not_closed", "rate_burst"):
            if key in traj.meta:
                print(f"kinredund: note: {traj.meta[key]}", file=sys.stderr)
    else:
        from kinredund.ui.reproduce import helix

        bar(0, 1, "closed-form solutions along the helix")
        try:
            out = helix(json_path=args.json, plot_path=args.plot)
        finally:
            bar.close()
        print("Section 3.2: helix tracked by the hybrid closed-form IK")
        print_summary({k: v for k, v in out.items() if not isinstance(v, (list, dict))})
    wrote(args.json, args.plot)
    return EXIT_OK


def _write_partial(out, err: TrackingError) -> None:
    """``--partial FILE``: the record up to a tracking stop with the failure (cause, time, state) as JSON;
    a stop before the first step has none, which is said (not a silent missing file)."""
    if err.partial is None:
        print(f"kinredund: note: no partial record to write to {out}: the run stopped at its start", file=sys.stderr)
        return
    failure = {"cause": err.cause, "t": err.t, "q": err.q, "watched": err.watched, "message": str(err)}
    err.partial.save_json(out, extra={"failure": json_ready(failure)})
    print(f"wrote the partial record up to t = {err.partial.t[-1]:.6g} s to {out}", file=sys.stderr)


def _cmd_track(args) -> int:
    bar = progress_for(f"track {args.robot}", args)
    from kinredund.ik.solve import solve_ik
    from kinredund.tracking import track
    from kinredund.ui.cli_track import say_speed, stop_hint

    try:
        bar(0, 1, "loading the robot")
        # the baselines ignore the index while they step; their normality residual is measured against it
        robot, seed_q, path, duration, index = options.setup_for(args, args.robot)
        if robot.nq <= robot.task_dim:
            bar.clear()
            print(f"kinredund: note: {robot.name} has {robot.nq} joints for the {robot.task_dim} of its "
                  f"{robot.task!r} task: it is not redundant, so --index {args.index} has no effect",
                  file=sys.stderr)
        s0 = path(0.0)
        target = get_task(robot.task).target_from_sample(s0)
        bar(0, 1, "the optimal start (IK)")
        res = solve_ik(robot, target, index, q0=seed_q, starts=args.starts, bounds=True)  # within the limits
        if not res.converged:
            raise KinredundError(f"no starting configuration on the path: {res.reason}")
        # a closed path runs --loops loops of --steps steps; an open one --steps steps over its duration
        span = {} if duration is None else {"duration": duration, "steps": args.steps}
        span.update(options.scene_options(args, robot))
        try:
            with warnings.catch_warnings():  # said below, once, with the exit code
                warnings.simplefilter("ignore", RecordWarning)
                traj = track(robot, path, index, res.q, scheme=args.scheme, mode=args.mode,
                             steps_per_loop=args.steps, loops=args.loops, backend=args.backend,
                             progress=lambda d, n: bar(d, n, "tracking"), **span)
        except TrackingError as err:  # a run that stopped: a result that failed (exit 1), not bad input
            bar.close("failed")  # returned, not raised: the finally below would say done
            if args.partial is not None:
                # the partial record is this command's output: returning (not raising) lets its batch land
                _write_partial(args.partial, err)
            print(f"kinredund: tracking stopped: {err}{stop_hint(err, args)}", file=sys.stderr)
            return EXIT_FAILED
        failed = [traj.meta[k] for k in ("loop_not_closed", "rate_burst") if k in traj.meta]  # no success (track())
        if args.html:
            bar(0, 1, "the HTML replay")
            from kinredund.ui.viz import replay_html
            from kinredund.ui.viz.page import replay_title

            replay_html(traj, args.html, robot=robot, title=replay_title(traj, args.path))
        bar.close("failed" if failed else "done")  # exit 1 below: the progress does not say done
    finally:
        bar.close()
    print(f"{robot.name}: {args.path}, {args.scheme} scheme, {args.mode} mode, index {args.index}")
    print_summary(traj.summary())
    if args.json:
        traj.save_json(args.json)
    if args.plot:
        from kinredund.ui.plots import plot_joint_histories

        plot_joint_histories(traj, args.plot)
    wrote(args.json, args.plot, args.html)
    say_speed(traj, robot, args)
    for why in failed:
        print(f"kinredund: {why}", file=sys.stderr)
    return EXIT_FAILED if failed else EXIT_OK


def _cmd_ik(args) -> int:
    from kinredund.ik.solve import solve_ik
    from kinredund.model.loader import load_robot

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
    elif args.rpy is not None:
        raise KinredundError(f"--rpy gives an orientation, and {robot.name}'s {robot.task!r} task holds no orientation "
                             "(it reaches a point): leave --rpy out, or give a task with one (--task pose)")
    else:
        target = args.target
    index = None if args.index == "none" else options.index_for(robot, args.index)
    q0 = None if args.q0 is None else robot.check_q(args.q0, "--q0")
    res = solve_ik(robot, target, index, q0=q0, bounds=args.bounds, starts=args.starts, seed=args.seed)
    out = json_ready({"robot": robot.name, **dataclasses.asdict(res)})  # the IKResult's fields (docs/schema.md)
    print(json.dumps(out, indent=2))
    if args.json:
        write_json(args.json, out)
        wrote(args.json)
    return outcome(res.converged, f"IK did not converge: {res.reason}")


def _exit_on_signal(signum, frame) -> None:
    """A signal handler: unwind (``finally`` blocks run) and exit with 128 + the signal's number."""
    raise SystemExit(128 + signum)


def _cmd_play(args) -> int:
    if args.html is None and not args.live:
        raise KinredundError(f"say what to do with {args.result}: --html FILE writes a standalone replay, "
                             "--live serves it on a local meshcat server (both may be given)")
    from kinredund.ui.records import replay_record

    rec = replay_record(args.result)
    scene = None
    if args.scene is not None:  # drawn by both replays
        from kinredund.geometry import load_scene

        scene = load_scene(args.scene, rec.robot)
    if args.html is not None:
        from kinredund.ui.viz import replay_html

        wrote(replay_html(rec.trajectory, args.html, robot=rec.robot, title=rec.title, scene=scene))
    if args.live:
        import time

        from kinredund.ui.viz import play_live, stop_live

        url = play_live(rec.trajectory, robot=rec.robot, loop=True, scene=scene)
        # SIGTERM (kill, a service manager) stops the server as Ctrl-C does, then exits 143
        previous = signal.signal(signal.SIGTERM, _exit_on_signal)
        try:
            print(f"open {url} (Ctrl-C to stop)", flush=True)  # inside: a Ctrl-C right after it is the stop
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
        finally:
            stop_live(url)
            signal.signal(signal.SIGTERM, previous)
    return EXIT_OK


def _cmd_demo(args) -> int:
    from kinredund.ui.demo import run_demo

    return run_demo(args.out, quick=args.quick, quiet=args.quiet)  # the text: an empty one is refused


# -- the parser (kinredund.ui.options) --------------------------------------------------------------
COMMANDS = {"demo": _cmd_demo, "reproduce": _cmd_reproduce, "track": _cmd_track, "ik": _cmd_ik,
            "play": _cmd_play, "generate-robots": _cmd_generate_robots, "robots": _cmd_robots}


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand (:func:`kinredund.ui.options.build_parser`)."""
    return options.build_parser(COMMANDS)


#: the options that name an output, and its kind: every one is checked before any work (kinredund.io.check_outputs)
OUTPUT_OPTIONS = {"json": "file", "plot": "file", "html": "file", "csv": "file", "partial": "file", "bag": "folder"}
#: the inputs a command reads, by option, and their name in the message: an output may not replace one
INPUT_OPTIONS = {"result": "the record", "scene": "--scene", "path_file": "--path-file", "pairs": "--pairs"}
#: 128 + the signal number, as a shell reports a process ended by SIGINT or SIGPIPE
EXIT_SIGINT, EXIT_SIGPIPE = 130, 141


def _check_outputs(args) -> None:
    """Refuse every bad output path before any work (:func:`kinredund.io.check_outputs`): a directory, a
    device, a FIFO, a dangling symlink, a path under a file, a bag folder that exists, two options that
    would overwrite each other (compared resolved, the bag folder included), a plot suffix matplotlib
    does not write, an output that is an input of the command (the record, --scene, --path-file, --pairs)."""
    from kinredund.io import check_outputs, real_path

    outputs = check_outputs((f"--{name}", getattr(args, name, None), kind) for name, kind in OUTPUT_OPTIONS.items())
    inputs = {label: given for name, label in INPUT_OPTIONS.items() if (given := getattr(args, name, None)) is not None}
    for output, real in outputs.items():
        for label, given in inputs.items():
            if real == real_path(given):
                raise OutputPathError(getattr(args, output[2:]), f"{output} names {label} this command reads "
                                      f"({str(given)!r}): writing it would replace the input; give another path")
    if getattr(args, "plot", None) is not None:
        from kinredund.ui.plots import plot_format

        plot_format(args.plot, "--plot")


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

    batch = demo_out = None
    try:
        args = build_parser().parse_args(argv)
        _check_outputs(args)
        if args.command == "demo":
            demo_out = Path(args.out)
            code = args.func(args)
        else:
            with output_batch() as batch:
                code = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
        return code
    except KinredundError as err:
        print(f"kinredund: error: {in_cli_words(str(err))}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        kept = [] if batch is None else batch.kept  # checkpoints (a sweep file) stay, to be resumed
        words = f"kept {', '.join(map(str, kept))} (written as the run went: resume from it)" if kept \
            else "no output file was written"
        if demo_out is not None and demo_out.is_dir() and any(demo_out.iterdir()):
            words = f"the demo's files done so far stay in {demo_out}/"  # it writes each file as it is done
        print(f"kinredund: interrupted; {words}", file=sys.stderr)
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
