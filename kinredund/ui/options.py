"""The options of the ``kinredund`` command line: every subcommand, its help text, units, defaults and examples.

:func:`build_parser` takes the function each subcommand runs (from :mod:`kinredund.ui.cli`), so the
definitions here hold no logic. Every option's help gives its unit and its default (a test walks them).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from kinredund.errors import BACKENDS, OptionError, check_size
from kinredund.tasks import task_names
from kinredund.ui.path_options import RADIUS, SPEED, path_for

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


def vector(text: str) -> np.ndarray:
    """An argparse type: finite comma-separated numbers, as an array."""
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from err
    if not values or not np.all(np.isfinite(values)):
        raise argparse.ArgumentTypeError(f"expected finite comma-separated numbers, got {text!r}")
    return np.array(values)


def distance(text: str) -> float:
    """A distance >= 0 [m] for argparse."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and value >= 0.0):
        raise argparse.ArgumentTypeError(f"expected a distance >= 0 [m], got {text!r}")
    return value


def distance_or_off(text: str) -> float | bool:
    """A distance >= 0 [m], or ``off`` (False), for argparse."""
    return False if text == "off" else distance(text)


def output_file(text: str) -> Path:
    """An argparse type: the path of an output file (:func:`kinredund.io.file_path`: ``out.csv/`` names a
    folder and is refused, not turned into ``out.csv``)."""
    from kinredund.errors import OutputPathError
    from kinredund.io import file_path

    try:
        return file_path(text)
    except OutputPathError as err:
        raise argparse.ArgumentTypeError(f"{text!r}: {err.reason}") from err


def at_least(minimum: int, size: str | None = None):
    """An argparse type: an integer >= ``minimum`` and, for a ``size`` of :data:`kinredund.errors.SIZES`
    (``samples``, ``starts``, ``placements``, ``workers``), at most its limit: the bounds the library checks
    too, so both agree and a size too large is refused before any work starts."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from err
        if size is None:
            if value < minimum:
                raise argparse.ArgumentTypeError(f"must be an integer >= {minimum}, got {value}")
            return value
        try:
            return check_size(value, "the value", size, minimum=minimum)
        except OptionError as err:
            raise argparse.ArgumentTypeError(str(err).removeprefix("the value ")) from err

    return parse


_SAMPLES = at_least(1, "samples")  # loops and steps: the record holds loops x steps (kinredund.tracking.track)
_STARTS = at_least(1, "starts")  # kinredund.ik.solve_ik


# -- the parser ------------------------------------------------------------------------------------
def subcommand(sub, name: str, help_: str, description: str, examples: list[str], func):
    """The subcommand ``name`` on the subparsers ``sub``, running ``func(args)``, with its description and
    examples (the epilog) printed as written."""
    epilog = "examples:\n" + "\n".join(f"  {e}" for e in examples)
    p = sub.add_parser(name, help=help_, description=description, epilog=epilog, formatter_class=_Formatter)
    p.set_defaults(func=func)
    return p


def _sub(sub, commands: dict, name: str, help_: str, description: str, examples: list[str]):
    """:func:`subcommand` running ``commands[name]``."""
    return subcommand(sub, name, help_, description, examples, commands[name])


#: what --plot of a Chapter 6 plan writes besides the figure (kinredund.ui.reproduce.snapshot_path)
PLAN_PLOT_NOTE = ("; a plan that was tracked (6.3) also gets its configuration snapshots beside it, as "
                  "NAME_snapshots.EXT")


def _add_outputs(p, *, html: bool = False, quiet: bool = False, plot_note: str = "") -> None:
    p.add_argument("--json", type=output_file, metavar="FILE", help="write the result as JSON (default: not written)")
    p.add_argument("--plot", type=output_file, metavar="FILE",
                   help=f"save the figure; the format follows the suffix: .png, .pdf or .svg{plot_note} "
                        "(default: not drawn)")
    if html:
        p.add_argument("--html", type=output_file, metavar="FILE",
                       help="write a standalone HTML replay that plays offline in a browser (default: not written)")
    if quiet:
        add_quiet(p)


def index_for(robot, name: str):
    """The index named by --index (argparse restricts ``name`` to home, min-norm and mid-range)."""
    from kinredund import indices

    if name == "min-norm":
        return indices.minimum_norm(robot.nq)
    if name == "mid-range":
        return indices.mid_range(robot.lower, robot.upper)
    return indices.JointDeviation(robot.home)


def add_robot(p) -> None:
    p.add_argument("robot", help="a robot name (see `kinredund robots`) or the path of a URDF file")
    p.add_argument("--ee-frame", metavar="FRAME", help="the end-effector frame of a URDF (default: the robot's own)")
    p.add_argument("--task", choices=task_names(),
                   help="what the end effector must reach: planar (a point in the plane), position (a 3-D point), "
                        "pose (a point and an orientation) or axis (a point and the tool's axis) (default: the "
                        "robot's own task)")


def add_path(p) -> None:
    """The path options of ``track`` and ``plan``: --path, --path-file, --center, --radius, --speed, --normal."""
    p.add_argument("--path", choices=("circle", "ellipse", "file"), default="circle",
                   help="circle and ellipse start at the end effector's start pose; file reads --path-file "
                        "(default: %(default)s)")
    p.add_argument("--path-file", type=Path, metavar="FILE",
                   help="for --path file: JSON with 't' [s], 'p' [m] and optionally 'Q', 'closed' (true when "
                        "absent); times count from the first sample (default: none)")
    p.add_argument("--center", type=vector, metavar="X,Y[,Z]",
                   help="centre of the circle or ellipse [m] (default: --radius along -x from the start point)")
    # None when not given, so that --path file (whose samples fix both) can refuse them (path_options.py)
    p.add_argument("--radius", type=float, metavar="R",
                   help=f"radius of the circle, semi-major axis of the ellipse [m] (default: {RADIUS})")
    p.add_argument("--speed", type=float, metavar="V",
                   help=f"speed along the circle or ellipse [m/s] (default: {SPEED})")
    p.add_argument("--normal", type=vector, metavar="X,Y,Z",
                   help="normal of the circle's plane (default: 0,0,1, a horizontal circle)")


def setup_for(args, name: str):
    """(robot, start seed, path, open path's duration or None, index) of ``track`` and ``plan``: the robot
    ``name`` with --ee-frame and --task, the seed --q0 (default its home), the path of :func:`path_for`
    from there and the index of --index."""
    from kinredund.model.loader import load_robot

    robot = load_robot(name, ee_frame=args.ee_frame, task=args.task)
    seed_q = robot.home if args.q0 is None else robot.check_q(args.q0, "--q0")
    path, duration = path_for(args, robot, seed_q)
    return robot, seed_q, path, duration, index_for(robot, args.index)


def add_quiet(p) -> None:
    p.add_argument("--quiet", action="store_true",
                   help="no progress on standard error (default: a bar on a terminal, else a line per stage "
                        "and every 5 s)")


def add_scene(p, held: str) -> None:
    """``--scene FILE --clearance M --self-clearance M|off`` (``track``, ``plan``); :func:`scene_options` reads them."""
    p.add_argument("--scene", type=Path, metavar="FILE",
                   help="a scene file (JSON, docs/schema.md) whose objects, and the robot's own links, are held "
                        f"apart {held} (default: none)")
    p.add_argument("--clearance", type=distance, default=None, metavar="M",
                   help="with --scene: the least distance [m] from its obstacles (default: 0.02)")
    p.add_argument("--self-clearance", type=distance_or_off, default=None, metavar="M|off",
                   help="with --scene: the least distance [m] between the robot's own objects, or off "
                        "(default: 0.01)")


def scene_options(args, robot) -> dict:
    """``track()``'s and ``plan()``'s scene=, clearance=, self_clearance= from :func:`add_scene`'s options.

    Raises:
        OptionError: --clearance or --self-clearance without --scene.
    """
    if args.scene is None:
        if args.clearance is not None or args.self_clearance is not None:
            raise OptionError("--clearance and --self-clearance need --scene FILE")
        return {}
    from kinredund.geometry import load_scene

    return {"scene": load_scene(args.scene, robot), "clearance": args.clearance,
            "self_clearance": args.self_clearance}


def _add_tracking(p) -> None:
    p.add_argument("--loops", type=_SAMPLES, default=1, metavar="N",
                   help="loops of the closed path to track (default: %(default)s)")
    p.add_argument("--mode", choices=("default", "thesis"), default="default",
                   help="default: implicit steps that stay on the optimum (cyclic); thesis: the thesis's explicit "
                        "Euler steps with velocity correction, Eq. (4.29) (default: %(default)s)")
    p.add_argument("--scheme", choices=SCHEMES, default="augmented",
                   help="augmented: the thesis's scheme on the displacement Jacobian (Eq. 4.24); velocity: the same "
                        "on the velocity Jacobian; pseudoinverse and liegeois: the baselines (Whitney 1972, "
                        "Liegeois 1977) (default: %(default)s)")


def build_parser(commands: dict) -> argparse.ArgumentParser:
    """The argument parser of every subcommand; ``commands`` maps each subcommand's name to its function."""
    from importlib.metadata import version

    __version__ = version("kinredund")  # the installed distribution's, from pyproject.toml
    parser = _Parser(prog="kinredund", description=DESCRIPTION, epilog=EPILOG, formatter_class=_Formatter)
    parser.add_argument("--version", action="version", version=f"kinredund {__version__}",
                        help="print the version and exit")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser, metavar="COMMAND")

    p = _sub(sub, commands, "demo", "the main job: reproduce every thesis example into an output folder",
             "Reproduce every thesis example (Sections 3.2, 6.2, 6.3 and Examples 4.1-4.3) and write the figures, "
             "the HTML replays and a summary table next to the thesis's figures.",
             ["kinredund demo --out out", "kinredund demo --out /tmp/quick --quick"])
    p.add_argument("--out", default="out", metavar="DIR",
                   help="output folder, created if needed (default: %(default)s)")
    p.add_argument("--quick", action="store_true", help="2 loops instead of 10 per example, for a quick check "
                   "(default: 10 loops)")
    add_quiet(p)

    p = _sub(sub, commands, "reproduce", "reproduce a thesis example",
             "Reproduce one thesis example: 3.2 (closed-form IK along a helix), 4.1-4.3 (cyclic resolved-rate "
             "tracking), 6.2 and 6.3 (off-line planning around an obstacle). --loops, --steps, --mode and "
             "--scheme apply to 4.1-4.3.",
             ["kinredund reproduce 4.3 --loops 10 --plot joints.png",
              "kinredund reproduce 4.2 --scheme pseudoinverse --json 4_2.json",
              "kinredund reproduce 6.3 --json plan.json --plot plan.png"])
    p.add_argument("example", choices=REPRODUCIBLE, help="the thesis section or example")
    _add_tracking(p)
    p.add_argument("--steps", type=_SAMPLES, default=200, metavar="N",
                   help="steps per loop, as in the thesis (default: %(default)s)")
    _add_outputs(p, quiet=True, plot_note=PLAN_PLOT_NOTE)

    p = _sub(sub, commands, "track", "track a path with a robot",
             "Find the optimal start on the path (joint-level IK), then track the path with the resolved-rate "
             "scheme, keeping the extra joints at the optimum of the performance index.",
             ["kinredund track panda --html panda.html",
              "kinredund track planar3r --path ellipse --radius 0.5 --loops 3 --plot joints.png",
              "kinredund track xarm7 --task position --scheme velocity --json run.json"])
    add_robot(p)
    add_path(p)
    p.add_argument("--q0", type=vector, metavar="Q1,Q2,...",
                   help="a configuration near the start [rad, m for prismatic joints] (default: the robot's home)")
    p.add_argument("--index", choices=("home", "min-norm", "mid-range"), default="home",
                   help="the performance index kept at its optimum: distance from home, joint norm, or distance "
                        "from mid-range (Chapter 2); the baselines' normality residual is measured against it "
                        "(default: %(default)s)")
    _add_tracking(p)
    p.add_argument("--backend", choices=BACKENDS, default=None,
                   help="compiled: the default mode's ordinary steps in the compiled core (same results, faster); "
                        "python: every step in Python; auto: compiled where it can run (default: "
                        "$KINREDUND_BACKEND, else auto)")
    p.add_argument("--steps", type=_SAMPLES, default=200, metavar="N",
                   help="steps per loop of a closed path, steps in all of an open one (default: %(default)s)")
    p.add_argument("--starts", type=_STARTS, default=8, metavar="N",
                   help="IK starts tried for the optimal start configuration (default: %(default)s)")
    _add_outputs(p, html=True, quiet=True)
    p.add_argument("--partial", type=output_file, metavar="FILE",
                   help="where tracking stops (a fold, a singularity, the path out of reach, ...), write the record "
                        "up to there with the failure's cause, time and last good configuration as JSON, which "
                        "`kinredund play` replays (default: not written)")
    add_scene(p, "while tracking (the start is checked; a stop names the pair)")

    p = _sub(sub, commands, "ik", "joint-level (constrained) inverse kinematics",
             "Solve the joint-level problem of Eq. (4.3): reach the target and, with --index, minimise a "
             "performance index; prints the result as JSON. Exit code 1 when it does not converge.",
             ["kinredund ik planar3r --target 1.2,0.5 --index home",
              "kinredund ik panda --target 0.4,0.2,0.5 --rpy 3.1416,0,0 --bounds",
              "kinredund ik panda --target 0.4,0.2,0.5 --task position --index mid-range"])
    add_robot(p)
    p.add_argument("--target", type=vector, required=True, metavar="X,Y[,Z]",
                   help="the end-effector point: x,y for planar tasks, x,y,z otherwise [m] (required)")
    p.add_argument("--rpy", type=vector, metavar="R,P,Y",
                   help="roll, pitch, yaw of the target orientation [rad], for pose tasks (default: none; "
                        "without it use --task position)")
    p.add_argument("--index", choices=("none", "home", "min-norm", "mid-range"), default="none",
                   help="the performance index to minimise; none: any solution (default: %(default)s)")
    p.add_argument("--q0", type=vector, metavar="Q1,Q2,...",
                   help="the first start [rad, m for prismatic joints] (default: the robot's home)")
    p.add_argument("--bounds", action="store_true", help="respect the joint limits (default: unbounded)")
    p.add_argument("--starts", type=_STARTS, default=1, metavar="N",
                   help="starts tried, the others random within the limits (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random starts (default: %(default)s)")
    p.add_argument("--json", type=output_file, metavar="FILE",
                   help="also write the result as JSON (default: not written)")

    from kinredund.ui.cli_plan import add_parser as add_plan_parser  # plan: any robot, or 6.2 / 6.3

    add_plan_parser(sub)

    p = _sub(sub, commands, "play", "replay a result JSON in the browser",
             "Replay any JSON the commands write: a trajectory (track, reproduce 4.x), a plan (plan, "
             "reproduce 6.x) or the Section 3.2 helix (reproduce 3.2). Say what to do: --html, --live or both.",
             ["kinredund play run.json --html run.html", "kinredund play plan.json --live"])
    p.add_argument("result", type=Path, help="a JSON file written by track, reproduce or plan")
    p.add_argument("--html", type=output_file, metavar="FILE",
                   help="write a standalone HTML replay that plays offline (default: not written)")
    p.add_argument("--live", action="store_true",
                   help="serve the replay on a local meshcat server until Ctrl-C (default: off)")
    p.add_argument("--scene", type=Path, metavar="FILE",
                   help="a scene file (docs/schema.md) whose objects both replays (--html, --live) draw, the closest "
                        "pair marked (default: none)")

    p = _sub(sub, commands, "generate-robots", "write robots/*.urdf from the thesis's HD tables",
             "Write the URDF files of the thesis's robots from their Hartenberg-Denavit tables.",
             ["kinredund generate-robots --out robots"])
    p.add_argument("--out", default="robots", metavar="DIR", help="output folder (default: %(default)s)")

    p = _sub(sub, commands, "robots", "list the robots load_robot knows",
             "List the robot names that track, ik and the Python API accept, with their joints and task.",
             ["kinredund robots"])
    from kinredund.ui.cli_retime import add_parsers as add_retime_parsers  # retime, export (issue 16)

    add_retime_parsers(sub)
    from kinredund.ui.cli_sweep import add_parser as add_sweep_parser  # the placement sweep (its own module)

    add_sweep_parser(sub)
    from kinredund.ui.cli_check import add_parser as add_check_parser  # check a motion in a scene (issue 24)

    add_check_parser(sub)
    return parser
