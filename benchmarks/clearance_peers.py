"""A sphere in the elbow's way: kinredund holding the clearance against pink with its barrier.

Usage::

    python benchmarks/clearance_peers.py [--json FILE] [--plot FILE] [--loops N] [--smoke]

The case is the named Panda case of ``tests/test_tracking_clearance.py`` (``panda_elbow_sphere``): a
0.1333 m circle at 0.1 m/s (position task, z = 1/2 ||q - q_home||^2), whose within-limits optimum's elbow
(the origin of ``panda_link4``) passes 1-2 cm inside a 0.1 m sphere. Every method starts at the
within-limits optimum at t = 0 and takes the same time step T / 200, for N loops (default 20). Methods:

- ``kinredund``: ``Tracker(..., constraints=[SphereClearance(robot, "panda_link4", center, 0.1)])``, the
  default mode with the joint limits: argmin z s.t. the task, the limits and the clearance, held exactly;
- ``kinredund_free``: the same without the sphere (the within-limits optimum: how far it runs in);
- ``pink_barrier``: pin-pink with ``BodySphericalBarrier`` on the same frame point (``_clearance.py``
  says how: position task, posture task, daqp, pink's default limits), the barrier's defaults;
- ``pink_barrier_sd0``: the same with the barrier's ``safe_displacement_gain`` 0 (the default's damping
  holds the arm back from the path);
- ``pink``: the same without the barrier.

Figures per method: the smallest clearance over the run [m] (< 0: inside the sphere), the joint drift
max |q(kT) - q(0)| after each loop [rad], the largest position error [m], and the per-step time (median,
p95) [us] of one run with the methods stepped in turn (garbage collection off; a 2-core shared machine,
so the times are noisy). pink is optional (``pip install .[bench]``): without it its columns are skipped
and say so.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from _bench import parser, print_table, step_in_turn, summary_us, write_json
from _clearance import PINK_VARIANTS, PinkBarrier, figures, pink_missing

from kinredund.errors import check_choice
from kinredund.ik import solve_ik
from kinredund.indices import JointDeviation
from kinredund.model.loader import load_robot
from kinredund.paths import Circle
from kinredund.tracking import SphereClearance, Tracker
from kinredund.ui.plots import LOG_FLOOR

STEPS_PER_LOOP = 200
METHODS = ("kinredund", "kinredund_free", *PINK_VARIANTS, "pink")
#: the circle (a configuration on it, plane normal, start direction, radius [m]; 0.1 m/s) and the sphere
#: (frame, center [m], radius [m]) of tests/test_tracking_clearance.py's panda_elbow_sphere
CIRCLE = ([0.5981, -1.2209, -0.1932, -2.5949, -0.0485, 1.3779, 1.2498], [0.4405, -0.8901, 0.117],
          [0.8409, 0.3634, -0.401], 0.1333)
SPHERE = ("panda_link4", [-0.24356218286625106, 0.03667415030989367, 0.36861011797889254], 0.1)


def elbow_case():
    """(robot, path, index, q0, sphere): the Panda circle, z, the within-limits optimum at t = 0, the sphere."""
    robot = load_robot("panda", task="position")
    qs, normal, ax, radius = (np.array(v, float) for v in CIRCLE)
    normal /= np.linalg.norm(normal)
    ax -= (ax @ normal) * normal
    ax /= np.linalg.norm(ax)
    p = robot.fk(qs)[:3, 3]
    path = Circle(p - radius * ax, float(radius), 0.1, normal=tuple(normal), axis_x=tuple(ax))
    index = JointDeviation(robot.home.copy())
    free = solve_ik(robot, p, index, q0=qs)
    start = solve_ik(robot, p, index, q0=free.q, bounds=True)
    if not start.converged:
        raise RuntimeError("the within-limits optimum at the start was not found")
    return robot, path, index, start.q, SphereClearance(robot, *SPHERE)


class _Ours:
    def __init__(self, robot, path, index, q0, dt, sphere):
        self.rr = Tracker(robot, path, index, q0, dt, constraints=None if sphere is None else [sphere])
        self.step = self.rr.step

    def state(self):
        return self.rr.t, self.rr.q.copy()


def _make(method, robot, path, index, q0, dt, sphere):
    if method.startswith("kinredund"):
        return _Ours(robot, path, index, q0, dt, sphere if method == "kinredund" else None)
    if method in PINK_VARIANTS:
        return PinkBarrier(robot, path, index, q0, dt, sphere, PINK_VARIANTS[method])
    return PinkBarrier(robot, path, index, q0, dt)


def run(loops: int = 20, methods=METHODS, steps_per_loop: int = STEPS_PER_LOOP) -> dict:
    """Run the methods in turn; the figures as a JSON-ready dict.

    Returns:
        ``{"methods": {method: figures}, "skipped": {method: reason}, "settings": {...}}``; figures as
        :func:`_clearance.figures` plus ``step_us_median``, ``step_us_p95``, ``t`` (the recorded times [s]),
        or ``{"failed": reason}`` (with the figures up to the failure).
    """
    for m in methods:
        check_choice("method", m, METHODS)
    robot, path, index, q0, sphere = elbow_case()
    dt = path.period / steps_per_loop
    runners, skipped = {}, {}
    why = pink_missing()
    for m in methods:
        if m.startswith("pink") and why:
            skipped[m] = why
            continue
        runners[m] = _make(m, robot, path, index, q0, dt, sphere)
    times, rec, failed = step_in_turn(runners, loops * steps_per_loop)
    out = {}
    for m in runners:
        ts, qs = zip(*rec[m], strict=True)
        res = figures(robot, path, sphere, ts, qs, steps_per_loop)
        res.update(summary_us(times[m]) if times[m] else {}, t=list(ts))
        if m in failed:
            res["failed"] = failed[m]
        out[m] = res
    return {"methods": out, "skipped": skipped,
            "settings": {"robot": "panda", "task": "position", "frame": SPHERE[0], "center": SPHERE[1],
                         "radius": SPHERE[2], "loops": loops, "steps_per_loop": steps_per_loop, "dt": dt}}


def write_plot(results: dict, path: Path) -> None:
    """Clearance over the first two loops and drift per loop, one curve per method (written atomically)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from kinredund.ui.plots import save_figure

    fig = Figure(figsize=(13, 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax_c, ax_d = fig.subplots(1, 2)
    period = results["settings"]["dt"] * results["settings"]["steps_per_loop"]
    for k, (m, r) in enumerate(results["methods"].items()):
        style = "-" if m.startswith("kinredund") else "--"
        t = np.array(r["t"])
        first = t <= 2 * period + 1e-9  # the first two loops: the later ones repeat them (or drift: right)
        ax_c.plot(t[first], 100 * np.array(r["clearance"])[first], style, lw=2.5 if m == "kinredund" else 1,
                  zorder=3 if m == "kinredund" else 2, label=m)
        if r["drift"]:
            d = np.maximum(np.array(r["drift"]), LOG_FLOOR)
            ax_d.semilogy(np.arange(1, len(d) + 1), d, style, marker="os^v"[k % 4], ms=4, label=m)
    ax_c.axhline(0.0, color="k", lw=0.8)
    ax_c.set_xlabel("t [s]")
    ax_c.set_ylabel("elbow clearance from the sphere [cm]")
    ax_c.set_title("Panda circle, sphere in the elbow's way (first two loops)")
    ax_d.set_xlabel("loop")
    ax_d.set_ylabel(f"joint drift after the loop [rad] (floor {LOG_FLOOR:g})")
    ax_d.xaxis.get_major_locator().set_params(integer=True)
    for ax in (ax_c, ax_d):
        ax.grid(True, which="both", alpha=0.3)
    ax_d.legend(fontsize=8)
    save_figure(fig, path)
    print(f"wrote {path}")


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--plot", type=Path, default=None, help="write the figure to this file (png, svg, pdf)")
    p.add_argument("--loops", type=int, default=20, help="loops of the circle (default 20)")
    args = p.parse_args()
    if args.loops < 1:
        p.error(f"--loops must be >= 1, got {args.loops}")
    loops, steps = (1, 50) if args.smoke else (args.loops, STEPS_PER_LOOP)
    t0 = time.perf_counter()
    results = run(loops, steps_per_loop=steps)
    wall = time.perf_counter() - t0
    marks = sorted({1, 5, 20, loops} & set(range(1, loops + 1)))
    rows = []
    for m, r in results["methods"].items():
        drift = [r["drift"][k - 1] if k <= len(r["drift"]) else "-" for k in marks]
        rows.append([m, r["clearance_min"], *drift, r["position_error_max"], r.get("median_us", "-"),
                     r.get("p95_us", "-"), r.get("failed", "")[:70]])
    print_table(rows, ["method", "min clearance m", *(f"drift@{k}" for k in marks), "pos err m", "step us",
                       "p95 us", "failed"])
    for m, why in results["skipped"].items():
        print(f"skipped {m}: {why}")
    print(f"whole run: {wall:.1f} s")
    results["wall_s"] = wall
    write_json(args.json, results)
    if args.plot is not None:
        write_plot(results, args.plot)


if __name__ == "__main__":
    main()
