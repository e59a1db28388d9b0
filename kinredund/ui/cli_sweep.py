"""``kinredund sweep``: where can the task run? A placement sweep from the command line.

Parses the arguments, builds the part path, the grid of placements and the index, and calls
:func:`kinredund.sweep.sweep` (serially, on a local Dask cluster, or on the cluster at ``--scheduler``);
prints the feasibility counts and the best placements, writes the sweep file (``--json``) and the map
(``--plot``). No logic lives here.
"""

from __future__ import annotations

import argparse
import math
from collections import Counter
from pathlib import Path

import numpy as np

from kinredund.errors import MAX_PLACEMENTS, KinredundError, OptionError, check_size
from kinredund.ui.options import add_quiet, add_robot, at_least, index_for, output_file, subcommand, vector
from kinredund.ui.progress import Progress

GRID_HELP = ("the placements: x0:x1:nx,y0:y1:ny[,yaw0:yaw1:nyaw] - nx values from x0 to x1 [m] (both included), "
             "ny from y0 to y1 [m], nyaw yaws from yaw0 to yaw1 [rad] about the base z axis (default yaw 0); "
             "the part origin's position in the robot's base frame")
#: how the summary line counts the placements that failed, by cause (kinredund.sweep.record.CAUSES); a cause
#: of the limited tracker (TrackingError.CAUSES) reads "stopped: CAUSE"
CAUSE_WORDS = {"start": "without a start", "path": "lost the path", "singularity": "at a singularity",
               "limits": "out of the joint limits", "speed": "over a velocity limit", "error": "with an error",
               "internal": "with an internal error", "worker": "lost with their worker",
               "collision": "in collision", "loop_not_closed": "with joints that do not close",
               "rate_burst": "with a rate burst"}


def parse_grid(text: str) -> dict:
    """``x0:x1:nx,y0:y1:ny[,yaw0:yaw1:nyaw]`` -> {"x": values [m], "y": values [m], "yaw": values [rad]}
    (every angle on the command line is in radians)."""
    parts = text.replace(" ", "").split(",")
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(f"expected x0:x1:nx,y0:y1:ny[,yaw0:yaw1:nyaw], got {text!r}")
    axes = {}
    for name, part in zip(("x", "y", "yaw"), parts, strict=False):
        fields = part.split(":")
        try:
            lo, hi, count = float(fields[0]), float(fields[1]), int(fields[2])
            if len(fields) != 3:
                raise ValueError(part)
        except (ValueError, IndexError) as err:
            raise argparse.ArgumentTypeError(f"the {name} range must be start:stop:count, got {part!r}") from err
        if not (math.isfinite(lo) and math.isfinite(hi)) or count < 1:
            raise argparse.ArgumentTypeError(f"the {name} range needs finite ends and a count >= 1, got {part!r}")
        if count > MAX_PLACEMENTS:  # before linspace allocates it
            raise argparse.ArgumentTypeError(f"the {name} range's count must be at most {MAX_PLACEMENTS}, got {count}")
        axes[name] = np.linspace(lo, hi, count)
    axes.setdefault("yaw", np.zeros(1))
    sizes = [len(v) for v in axes.values()]
    try:
        check_size(math.prod(sizes), f"the grid's placements ({' x '.join(map(str, sizes))})", "placements")
    except OptionError as err:
        raise argparse.ArgumentTypeError(str(err)) from err
    return axes


def add_parser(sub) -> None:
    """Register the ``sweep`` subcommand on the subparsers ``sub`` of :func:`kinredund.ui.cli.build_parser`."""
    from kinredund.sweep.record import CRITERIA

    p = subcommand(sub, "sweep", "placement sweep: track a part's closed path at many part poses (Dask)",
                   "Track a closed path given in a part frame with the part at every placement of a grid; report "
                   "which placements are feasible and the best ones.",
                   ["kinredund sweep panda --grid 0.3:0.6:4,-0.3:0.3:5 --plot map.png",
                    "kinredund sweep panda --grid 0.3:0.6:4,-0.3:0.3:5 --json sweep.jsonl --resume",
                    "kinredund sweep panda --grid 0.3:0.6:4,-0.3:0.3:5 --scene cell.json --clearance 0.02 "
                    "--criterion clearance"], run)
    add_robot(p)
    p.add_argument("--path", choices=("circle", "file"), default="circle",
                   help="circle: a circle about the part origin; file: a JSON path in part coordinates "
                        "(default: %(default)s)")
    p.add_argument("--path-file", type=Path,
                   help="for --path file: JSON with 't' [s], 'p' [m], optionally 'Q' (default: none)")
    p.add_argument("--radius", type=float, default=0.1, help="circle radius [m] (default 0.1)")
    p.add_argument("--speed", type=float, default=0.1, help="circle speed [m/s] (default 0.1)")
    p.add_argument("--normal", type=vector, help="circle normal in the part frame (default 0,0,1)")
    p.add_argument("--grid", type=parse_grid, required=True, help=GRID_HELP)
    p.add_argument("--z", type=float, help="the part origin's height [m] (default: the end effector's at home)")
    p.add_argument("--index", choices=("home", "min-norm", "mid-range"), default="home",
                   help="the performance index z (default home: 1/2 ||q - q_home||^2)")
    p.add_argument("--steps", type=at_least(1, "samples"), default=200, help="steps per loop (default 200)")
    p.add_argument("--loops", type=at_least(1, "samples"), default=1, help="loops per placement (default 1)")
    p.add_argument("--starts", type=at_least(1, "starts"), default=8,
                   help="IK starts for each start configuration (default 8)")
    p.add_argument("--seed", type=at_least(0), default=0, help="seed of the IK multi-start (default 0)")
    p.add_argument("--no-limits", action="store_true", help="do not ask the tracker to hold the joint limits "
                   "(a run leaving them is still infeasible; default: held)")
    p.add_argument("--speed-limit", action="store_true", help="a joint above its velocity limit is infeasible "
                   "(default: velocities not checked)")
    p.add_argument("--scene", type=Path, metavar="FILE",
                   help="a scene file (JSON, docs/schema.md) whose world objects are given in the part frame (they "
                        "move with the part, as the path does); each placement's motion is checked against them and "
                        "against the robot itself, between samples too (default: no scene)")
    p.add_argument("--clearance", type=float, default=0.0, metavar="C",
                   help="with --scene: a placement whose motion comes closer than C [m] to an object or to itself is "
                        "infeasible (cause collision; default 0: only contact)")
    p.add_argument("--resolution", type=float, metavar="M",
                   help="with --scene: how closely each motion's least clearance is found [m] (default 1e-3)")
    p.add_argument("--pairs", type=Path, metavar="FILE",
                   help="with --scene: a saved self-pair matrix (PairMatrix.save) (default: computed, seeded)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=at_least(0, "workers"), help="worker processes of the local Dask cluster "
                       "(default: this machine's cores; 0: serially in this process)")
    where.add_argument("--scheduler", help="run on an existing Dask cluster: its scheduler's address "
                       "(tcp://host:port; default: a local cluster)")
    p.add_argument("--batch-size", type=at_least(1, "placements"),
                   help="placements per Dask task (default: guided - large batches first, single placements last)")
    p.add_argument("--json", type=output_file, help="the sweep file, written as batches complete (.jsonl: JSON lines; "
                   "default: not written)")
    p.add_argument("--resume", action="store_true", help="resume the sweep in --json, running only what it lacks; "
                   "a --json file that does not exist yet starts the sweep (default: start anew)")
    p.add_argument("--plot", type=output_file,
                   help="the feasibility and quality map (.png, .pdf or .svg; default: not drawn)")
    p.add_argument("--criterion", choices=tuple(CRITERIA), default="margin",
                   help="what ranks the feasible placements (default margin: farthest from the joint limits)")
    p.add_argument("--top", type=at_least(0), default=5, help="best placements to print (default 5)")
    add_quiet(p)


def _part_path(args, robot):
    from kinredund.paths import read_path_file
    from kinredund.sweep.placement import part_circle
    from kinredund.ui.path_options import check_file_for_task

    if args.path == "file":
        if args.path_file is None:
            raise KinredundError("--path file needs --path-file FILE (JSON with 't', 'p' and optionally 'Q')")
        path, _ = read_path_file(args.path_file)
        check_file_for_task(args.path_file, path, robot)
        if path.period is None:
            raise KinredundError(f"{args.path_file}: a sweep needs a closed path ('closed': true)")
        return path
    normal = (0.0, 0.0, 1.0) if args.normal is None else tuple(args.normal)
    return part_circle(robot, args.radius, args.speed, normal=normal)


def _scene(args, robot):
    """The scene of ``--scene`` around ``robot`` (None without it); --clearance and --pairs need it."""
    if args.scene is None:
        if args.clearance or args.pairs is not None or args.resolution is not None:
            raise KinredundError("--clearance, --resolution and --pairs need --scene FILE (the cell whose distances "
                                 "they are)")
        return None
    from kinredund.geometry import load_scene

    return load_scene(args.scene, robot, pairs=args.pairs)


def run(args) -> int:
    """The ``sweep`` command; exit code 0 if some placement is feasible, else 1."""
    from kinredund.model.loader import load_robot
    from kinredund.sweep import best, grid, sweep
    from kinredund.ui.cli import EXIT_FAILED, EXIT_OK

    robot = load_robot(args.robot, ee_frame=args.ee_frame, task=args.task)
    path = _part_path(args, robot)
    z = float(robot.fk(robot.home)[2, 3]) if args.z is None else args.z
    placements = grid(x=args.grid["x"], y=args.grid["y"], z=z, yaw=args.grid["yaw"])
    if args.resume and args.json is None:
        raise KinredundError("--resume needs --json FILE (the sweep file to resume)")
    scene = _scene(args, robot)
    with Progress("sweep", quiet=args.quiet) as bar:  # a bar on a terminal, a line every few seconds elsewhere
        records = sweep(robot, path, index_for(robot, args.index), placements, steps_per_loop=args.steps,
                        loops=args.loops, limits=not args.no_limits, speed_limit=args.speed_limit,
                        starts=args.starts, seed=args.seed, scene=scene, clearance=args.clearance,
                        clearance_resolution=1e-3 if args.resolution is None else args.resolution,
                        workers=args.workers, scheduler=args.scheduler,
                        batch_size=args.batch_size, out=args.json, resume=args.resume,
                        progress=lambda done, total: bar(done, total, "placements"))
        bar.close("done" if any(r.feasible for r in records) else "failed")  # none feasible: exit 1 below
    causes = Counter(r.cause for r in records if not r.feasible)
    feasible = sum(r.feasible for r in records)
    print(f"{robot.name}: {len(records)} placements at z = {z:.3f} m, {feasible} feasible"
          + "".join(f", {n} {CAUSE_WORDS.get(c, f'stopped: {c}')}" for c, n in sorted(causes.items())))
    near = best(records, "clearance", 1)
    if scene is not None and near:
        print(f"largest clearance of a feasible placement: {near[0].clearance:.4g} m (#{near[0].placement}; "
              f"--clearance {args.clearance:g} m)")
    top = best(records, args.criterion, args.top)
    if top:
        from kinredund.ui.plots_sweep import CRITERION_UNITS

        unit = CRITERION_UNITS[args.criterion]
        print(f"best by {args.criterion}:")
        for r in top:
            near = ""
            if r.clearance is not None and args.criterion != "clearance":
                near = f"  clearance {r.clearance:.4g} m ({r.clearance_pair[0]}, {r.clearance_pair[1]})"
            print(f"  #{r.placement:<5d} x {r.x:+.3f} m  y {r.y:+.3f} m  yaw {r.yaw:+.3f} rad  "
                  f"{args.criterion} {r.value(args.criterion):.4g}" + (f" {unit}" if unit != "-" else "") + near)
    if args.json:
        print(f"wrote {args.json}")
    if args.plot:
        from kinredund.ui.plots_sweep import plot_sweep_map

        print(f"wrote {plot_sweep_map(records, args.plot, args.criterion, title=f'{robot.name}: placement sweep')}")
    return EXIT_OK if feasible else EXIT_FAILED
