"""The ``kinredund`` command line: parses arguments and calls the library (no logic lives here).

Exit codes: 0 success, 1 a result that failed its own check (e.g. IK not converged, plan collides),
2 bad arguments or input files (an error of the kinredund family), 3 unexpected internal errors.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .errors import KinredundError

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERNAL = 0, 1, 2, 3


def _cmd_generate_robots(args: argparse.Namespace) -> int:
    from .generate import generate_robots

    out = Path(args.out)
    for path in generate_robots(out):
        print(f"wrote {path}")
    return EXIT_OK


def _cmd_robots(args: argparse.Namespace) -> int:
    from .robot import known_robots, load_robot

    for name in known_robots():
        robot = load_robot(name)
        print(f"{name:14s} n={robot.nq}  task={robot.task:8s} m={robot.task_dim}  ee={robot.ee_frame}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = argparse.ArgumentParser(prog="kinredund", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    gen = sub.add_parser("generate-robots", help="write robots/*.urdf from the thesis's HD tables")
    gen.add_argument("--out", default="robots", help="output folder (default: robots)")
    gen.set_defaults(func=_cmd_generate_robots)
    rob = sub.add_parser("robots", help="list the robots load_robot knows")
    rob.set_defaults(func=_cmd_robots)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except KinredundError as err:
        print(f"kinredund: error: {err}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
