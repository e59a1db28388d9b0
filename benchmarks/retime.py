"""Retiming time for a 7-axis loop of 200 and 2000 samples.

The loop: the Panda's 0.1 m benchmark circle (``panda_circle``) tracked at 1 m/s, faster than its URDF
joint speeds allow, with 200 and 2000 steps per loop; the limits: the URDF's velocity limits and Franka's
documented acceleration limits (15, 7.5, 10, 12.5, 15, 20, 20 rad/s^2), and 500 rad/s^3 for the jerk law.
Per sample count, medians over a few runs [ms] of:

- ``toppra_ms``: the periodic TOPP-RA law alone (``time_law.toppra_law``: three loops from rest to rest,
  the middle one kept, and the uniform scaling into the limits);
- ``retime_ms``: the whole ``retime`` call for one loop (joint-path spline, TOPP-RA, the record);
- ``retime_10_loops_ms``: the same, chaining 10 loops into the record;
- ``jerk_ms``: ``retime`` with the jerk limit (TOPP-RA, then the smoothing over its window widths).

With the loop's duration before and after, and the fraction of samples with a limit within 1 %. Run:
``python benchmarks/retime.py [--json FILE]``. The first call also imports toppra (~0.3 s): it is
left out (a warm-up run).
"""

from __future__ import annotations

from _bench import parser, print_table, time_calls, write_json

from kinredund.model.loader import load_robot
from kinredund.problems import panda_circle
from kinredund.retime import limits_for, retime
from kinredund.retime.joint_path import joint_path
from kinredund.retime.time_law import toppra_law
from kinredund.tracking import track

AMAX = [15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0]
JMAX = 500.0
SAMPLES = (200, 2000)
REPEAT = 5


def bench(steps: int, repeat: int = REPEAT) -> dict:
    """The figures for one loop of ``steps`` samples (medians of ``repeat`` runs)."""
    robot, path, index, q0 = panda_circle(load_robot("panda"), speed=1.0)
    tr = track(robot, path, index, q0, steps_per_loop=steps)
    limits = limits_for(robot, AMAX)
    jerk_limits = limits_for(robot, AMAX, jerk=JMAX)
    jp = joint_path(tr, robot.revolute)
    res = retime(tr, limits, robot=robot)
    figures = {
        "samples": steps,
        "toppra_ms": time_calls(lambda: toppra_law(jp, limits), repeat=repeat, warmup=1)["median_us"] / 1e3,
        "retime_ms": time_calls(lambda: retime(tr, limits, robot=robot), repeat=repeat, warmup=1)["median_us"] / 1e3,
        "retime_10_loops_ms": time_calls(lambda: retime(tr, limits, robot=robot, loops=10), repeat=repeat,
                                         warmup=1)["median_us"] / 1e3,
        "jerk_ms": time_calls(lambda: retime(tr, jerk_limits, robot=robot), repeat=repeat, warmup=1)["median_us"] / 1e3,
        "tracked_loop_s": float(path.period),
        "retimed_loop_s": res.loop_duration,
        "active_fraction": res.active_fraction,
    }
    return figures


def main() -> None:
    args = parser(__doc__.splitlines()[0]).parse_args()
    rows = [bench(n, 1 if args.smoke else REPEAT) for n in (SAMPLES[:1] if args.smoke else SAMPLES)]
    keys = list(rows[0])
    print_table([[r[k] for k in keys] for r in rows], keys)
    write_json(args.json, {"rows": rows, "amax": AMAX, "jmax": JMAX, "repeat": 1 if args.smoke else REPEAT})


if __name__ == "__main__":
    main()
