"""The ``kinredund check`` command: the least clearance of a saved motion in a scene, between samples too.

``check RESULT.json --scene F [--geometry mesh|convex] [--resolution M] [--pairs F] [--json F] [--plot F]``
reads a record (any kind ``kinredund play`` reads), the scene file around the record's robot, and runs
:func:`kinredund.geometry.motion.check_motion`. Exit 0 when the motion is free, 1 on contact (or a clearance
within the resolution), 2 on bad input.
"""

from __future__ import annotations

from pathlib import Path

from kinredund.ui.options import EXIT_FAILED, EXIT_OK, output_file, subcommand

CHECK_HELP = """Check a saved motion against a cell: the least clearance along it (signed distance [m] between
the robot, its self pairs, the scene's obstacles and what it carries), the pair and the time, checking between
the recorded points too (no point of the robot moves farther than a bound between two samples; stretches that
could come closer are halved until proven). Exact meshes by default. Exit 1 on contact."""


def _cmd_check(args) -> int:
    from kinredund.geometry import load_scene
    from kinredund.geometry.motion import check_motion
    from kinredund.io import write_json
    from kinredund.ui.records import replay_record

    rec = replay_record(args.result)
    scene = load_scene(args.scene, rec.robot, geometry=args.geometry, pairs=args.pairs)
    traj = rec.trajectory
    c = check_motion(scene, traj.t, traj.q, resolution=args.resolution)
    print(f"{rec.robot.name}: {len(traj.t)} samples, {len(scene.pairs)} pairs ({args.geometry}), "
          f"{c.evaluations} configurations evaluated")
    pair = " / ".join(c.min_pair) if c.min_pair else "(no pair checked)"
    print(f"  {'least clearance':18s} {c.min_distance:.6g} m (to within {c.resolution:g} m)")
    print(f"  {'pair':18s} {pair}")
    print(f"  {'at t':18s} {c.min_time:.6g} s")
    print(f"  {'verdict':18s} {'CONTACT' if c.contact else 'free'}")
    if args.json is not None:
        write_json(args.json, {"robot": rec.robot.name, "scene": str(args.scene), "geometry": args.geometry,
                               "min_distance": c.min_distance, "min_pair": c.min_pair, "min_time": c.min_time,
                               "contact": c.contact, "resolution": c.resolution, "evaluations": c.evaluations,
                               "t": c.t, "distance": c.distance, "pairs": [list(p) if p else None for p in c.pairs]},
                   indent=1)
        print(f"wrote {args.json}")
    if args.plot is not None:
        from kinredund.ui.plots_clearance import plot_clearance

        print(f"wrote {plot_clearance(c, args.plot, f'{rec.robot.name}: clearance along {Path(args.result).name}')}")
    return EXIT_FAILED if c.contact else EXIT_OK


def add_parser(sub) -> None:
    """Register ``check`` on the subcommand parsers of :func:`kinredund.ui.options.build_parser`."""
    from kinredund.geometry.motion import RESOLUTION

    p = subcommand(sub, "check", "check a saved motion against a cell's obstacles and itself (exit 1 on contact)",
                   CHECK_HELP, ["kinredund track panda --json run.json",
                                "kinredund check run.json --scene cell.json --plot clearance.png"], _cmd_check)
    p.add_argument("result", type=Path, help="a record (kinredund track/plan/reproduce --json)")
    p.add_argument("--scene", type=Path, required=True, help="the scene file (JSON, docs/schema.md)")
    p.add_argument("--geometry", choices=("mesh", "convex"), default="mesh",
                   help="the robot's meshes exact or as convex hulls (default: %(default)s)")
    p.add_argument("--resolution", type=float, default=RESOLUTION,
                   help="how closely the least clearance is found [m] (default: %(default)s)")
    p.add_argument("--pairs", type=Path,
                   help="a saved self-pair matrix (PairMatrix.save) (default: computed, seeded)")
    p.add_argument("--json", type=output_file,
                   help="write the clearance per sample and the verdict (default: not written)")
    p.add_argument("--plot", type=output_file,
                   help="plot the clearance over time (.png, .pdf, .svg) (default: not drawn)")
