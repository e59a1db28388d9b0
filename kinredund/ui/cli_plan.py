"""The ``kinredund plan`` command: a cyclic within-limits plan for any robot, or the thesis's Chapter 6 cases.

``plan ROBOT [--task ...] [--path circle|ellipse|file ...] [--index ...] [--samples N] [--scene F --clearance M
--self-clearance M|off] [--json F]`` runs
:func:`kinredund.planning.cyclic.plan` (``kr.plan``) on the robot's own task along a closed path built as
``track`` builds it (:func:`kinredund.ui.path_options.path_for`), and writes the planned motion as a
trajectory record (:meth:`kinredund.trajectory.Trajectory.save_json`, the plan's figures under the key
``plan``): ``play``, ``retime`` and ``export`` take it as they take ``track --json``. ``plan 6.2|6.3``
runs the thesis's cases as ``reproduce 6.2|6.3`` does.

Exit codes as every command (:mod:`kinredund.ui.cli`): 1 when the plan fails its own verification (the
cause and reason on stderr; with ``--partial FILE`` what the tracker recorded before it stopped).
"""

from __future__ import annotations

from kinredund.errors import KinredundError, OptionError
from kinredund.ui import options
from kinredund.ui.options import PLAN_PLOT_NOTE, at_least, output_file, subcommand
from kinredund.ui.report import outcome, progress_for, wrote
from kinredund.ui.summary import print_summary

#: the thesis's Chapter 6 cases, planned by their own configuration (:mod:`kinredund.thesis.chapter6`)
CASES = ("6.2", "6.3")
#: the default samples: the 6.2 planner's and the cyclic planner's (kinredund.planning.cyclic.plan)
CASE_SAMPLES, ROBOT_SAMPLES = 9, 24


def print_plan_summary(summary: dict) -> None:
    """A plan's summary (:meth:`kinredund.planning.result.PlanResult.summary`) as every plan prints it: its figures,
    then its check's and its clearance's as ``check.NAME`` and ``clearance.NAME``; a failure's reason is printed
    with the exit code (:func:`kinredund.ui.report.outcome`)."""
    print_summary({k: v for k, v in summary.items() if k not in ("reason", "check", "clearance")})
    for part in ("check", "clearance"):
        if summary.get(part) is not None:
            print_summary({f"{part}.{k}": v for k, v in summary[part].items()})


def run_case(case: str, args, label: str) -> int:
    """Run a Chapter 6 case (``reproduce 6.x`` and ``plan 6.x``); EXIT_FAILED when the plan fails its check."""
    bar = progress_for(label, args)
    from kinredund.ui.reproduce import plan_case, snapshot_path

    samples = getattr(args, "samples", None)
    more = {} if samples is None else {"samples": samples}
    try:
        result = plan_case(case, json_path=args.json, plot_path=args.plot, progress=bar, **more)
    except BaseException:
        bar.close()  # failed or interrupted (Progress.close reads the exception in flight)
        raise
    bar.close("done" if result.ok else "failed")
    print(f"Section {case}: off-line plan with collision avoidance")
    print_plan_summary(result.summary())
    wrote(args.json, args.plot)
    if args.plot is not None and result.trajectory is not None:
        wrote(snapshot_path(args.plot))
    return outcome(result.ok, f"plan failed: {result.reason}")


def _plan_robot(args) -> int:
    """``plan ROBOT``: the cyclic planner on the robot's task along the closed path of the options."""
    from kinredund.planning.cyclic import plan

    bar = progress_for(f"plan {args.target}", args)
    try:
        bar(0, 1, "loading the robot")
        robot, _, path, _, index = options.setup_for(args, args.target)
        if path.period is None:
            raise KinredundError("plan needs a closed path: a circle, an ellipse or a path file with 'closed': true")
        bar(0, 1, "samples, candidates and the closed walk")
        result = plan(robot, path, index, samples=ROBOT_SAMPLES if args.samples is None else args.samples,
                      starts=args.starts, seed=args.seed, loops=args.loops, steps_per_loop=args.steps,
                      q0=args.q0, refine_samples=args.refine_samples, follow=not args.no_follow,
                      progress=bar,
                      meta={"path": args.path, "index": args.index}, **options.scene_options(args, robot))
    except BaseException:
        bar.close()  # failed or interrupted (Progress.close reads the exception in flight)
        raise
    bar.close("done" if result.ok else "failed")
    summary = result.summary()
    print(f"{robot.name}: cyclic plan along a {args.path}, task {robot.task}, index {args.index}")
    print_plan_summary(summary)
    if result.trajectory is not None and args.json is not None:
        result.trajectory.save_json(args.json, extra={"plan": summary})
        wrote(args.json)
    if result.trajectory is not None and args.html is not None:
        from kinredund.ui.viz import replay_html

        wrote(replay_html(result.trajectory, args.html, robot=robot, title=f"{robot.name}: cyclic plan"))
    if args.plot is not None and result.trajectory is not None:
        from kinredund.ui.plots import plot_joint_histories

        plot_joint_histories(result.trajectory, args.plot)
        wrote(args.plot)
    if result.partial is not None and args.partial is not None:
        result.partial.save_json(args.partial, extra={"plan": summary})
        wrote(args.partial)
    return outcome(result.ok, f"plan failed ({result.cause}): {result.reason}")


def _cmd_plan(args) -> int:
    if args.target in CASES:
        given = [f"--{name}" for name in ("html", "partial") if getattr(args, name) is not None]
        if given:  # refused before any work, not silently left unwritten
            raise OptionError(f"{' and '.join(given)} apply to a robot's plan, not to the thesis's case {args.target}: "
                              f"write --json FILE, then `kinredund play FILE --html REPLAY.html`")
        return run_case(args.target, args, label=f"plan {args.target}")
    return _plan_robot(args)


def add_parser(sub) -> None:
    """Register ``plan`` on the subcommand parsers of :func:`kinredund.ui.options.build_parser`."""
    p = subcommand(
        sub, "plan", "plan a cyclic within-limits motion for any robot, or the thesis's cases 6.2 and 6.3",
        "ROBOT: plan a cyclic motion inside the joint limits along a closed path (samples, within-limits minima of "
        "the index, the shortest continuous closed walk through them, a spline, tracking and an independent check "
        "of limits, task error and closure); the JSON is a trajectory record that play, retime and export take. "
        "6.2 or 6.3: the collision-free plans of Chapter 6 (6.2 has none: the reason is printed). Exit code 1 when "
        "the plan fails its check.",
        ["kinredund plan ur5 --radius 0.05 --json ur5_plan.json",
         "kinredund retime ur5_plan.json --amax 5 --json timed.json && kinredund export timed.json --bag bag",
         "kinredund plan panda --index mid-range --samples 32 --html plan.html",
         "kinredund plan 6.3 --json plan.json --plot plan.png"], _cmd_plan)
    p.add_argument("target", metavar="ROBOT|6.2|6.3",
                   help="a robot name (see `kinredund robots`) or a URDF path; or the thesis section 6.2 or 6.3")
    p.add_argument("--ee-frame", metavar="FRAME", help="the end-effector frame of a URDF (default: the robot's own)")
    p.add_argument("--task", choices=options.task_names(),
                   help="what the end effector must follow: planar, position, pose or axis (default: the robot's "
                        "own task)")
    options.add_path(p)
    p.add_argument("--q0", type=options.vector, metavar="Q1,Q2,...",
                   help="a configuration inside the limits: the plan starts on the minimum of the index reached "
                        "from it [rad, m for prismatic joints] (default: the shortest closed walk from any minimum; "
                        "the path starts at the home pose)")
    p.add_argument("--index", choices=("home", "min-norm", "mid-range"), default="home",
                   help="the performance index whose within-limits minima the plan follows (default: %(default)s)")
    p.add_argument("--samples", type=at_least(4, "plan_samples"), metavar="N",
                   help=f"sample points per loop, at least 4 for the cubic spline (default: {ROBOT_SAMPLES} for a "
                        f"robot, {CASE_SAMPLES} for 6.2; 6.3 plans on a roadmap instead)")
    p.add_argument("--starts", type=at_least(1, "starts"), default=8, metavar="N",
                   help="random starts per sample (four times as many at the first) (default: %(default)s)")
    p.add_argument("--seed", type=at_least(0), default=0, help="seed of the random starts (default: %(default)s)")
    p.add_argument("--loops", type=at_least(1, "samples"), default=2, metavar="N",
                   help="loops tracked; the check requires closure after each (default: %(default)s)")
    p.add_argument("--steps", type=at_least(4, "samples"), default=200, metavar="N",
                   help="tracking steps per loop (default: %(default)s)")
    p.add_argument("--refine-samples", type=at_least(0, "plan_samples"), default=24, metavar="N",
                   help="sample times added where no closed walk exists at the sampling (default: %(default)s)")
    p.add_argument("--no-follow", action="store_true",
                   help="track the spline reference all along instead of z's own optimum wherever it is strongly "
                        "stable (default: follow z; off_optimum says where the motion is not z's optimum)")
    options.add_scene(p, "by the plan: its candidates, its tracking and its check, between the recorded points too "
                         "(a motion under a clearance fails with cause collision naming the pair and the time)")
    p.add_argument("--json", type=output_file, metavar="FILE", help="write the result as JSON (default: not written)")
    p.add_argument("--plot", type=output_file, metavar="FILE",
                   help=f"save the figure; the format follows the suffix: .png, .pdf or .svg{PLAN_PLOT_NOTE} "
                        "(default: not drawn)")
    p.add_argument("--html", type=output_file, metavar="FILE",
                   help="a robot's plan (not 6.2, 6.3): a standalone HTML replay (default: not written)")
    p.add_argument("--partial", type=output_file, metavar="FILE",
                   help="a robot's plan (not 6.2, 6.3) whose tracking stops: the record up to there "
                        "(default: not written)")
    options.add_quiet(p)
