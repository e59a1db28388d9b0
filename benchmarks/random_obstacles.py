"""Random circles with a sphere in the elbow's way: kinredund holding the clearance against pink.

Usage::

    python benchmarks/random_obstacles.py [--robot NAME] [--n N] [--loops L] [--seed S] [--json FILE]
                                          [--plot FILE] [--smoke]

Tasks, per robot (``panda`` and ``xarm7`` unless ``--robot`` names one; position task, z = 1/2 ||q -
q_home||^2), N per robot (default 20) drawn from ``np.random.default_rng(S)``:

- a circle: a configuration q_c uniform inside the limits (5 % off each end), the circle through its end
  point with the plane normal uniform on the sphere, radius uniform in 3-10 cm, 0.1 m/s; the start q0 is
  the within-limits optimum at t = 0 (``solve_ik(..., bounds=True)`` from q_c);
- reachable: the within-limits optimum (``track(..., limits=True)``, no sphere) completes one loop; a
  task that fails this screen is drawn again, and the rejections are counted;
- a sphere (radius uniform in 5-10 cm) where that optimum's elbow (the origin of ``panda_link4`` /
  ``link4``) passes: at a point P_k of its trajectory (k uniform in the middle 80 % of the loop), its
  center offset from P_k by radius - depth along a random direction normal to the elbow's velocity there,
  depth uniform in 1-3 cm, so the optimum runs into it; a sphere that holds the start q0 is drawn again
  (at most 20 times; then the task is drawn again). The free optimum's actual penetration is recorded.

Methods, from the same q0 with the time step T / steps (default 200), L loops (default 5):

- ``kinredund``: ``track(robot, path, z, q0, loops=L, constraints=[SphereClearance(...)])``. Every run
  either completes, holds the clearance (>= -1e-9 m at every point, recomputed) and closes (drift <=
  1e-10 rad after each loop), or stops with a named :class:`~kinredund.errors.TrackingError` cause at a
  configuration that is clear, on the path and inside the limits (checked afresh); the causes are
  counted, and a completed run that does not hold or close is counted as ``wrong``;
- ``pink_barrier`` and ``pink_barrier_sd0``: pin-pink with ``BodySphericalBarrier`` on the same frame
  point (``_clearance.py``), daqp, pink's default limits, the barrier's default ``safe_displacement_gain``
  (3) or 0: completed (no exception, position error <= 1 mm), its smallest clearance and its drift after
  L loops.

Figures per robot and method: completion rate (and for kinredund's ``collision`` stops, the
``underlying_cause`` they report), the smallest clearance over the runs that reached the end
(completed, or pink off the path; min and median of the per-run minima), those with a clearance below
-1 mm, the runs closed to 1e-10 rad and the closure after L loops (median, max; same runs), the stop
causes. pink is optional (``pip
install .[bench]``): without it its columns are skipped.
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import numpy as np
from _bench import parser, print_table, write_json
from _clearance import PINK_VARIANTS, PinkBarrier, figures, pink_missing

from kinredund.errors import KinredundError, TrackingError
from kinredund.ik import solve_ik
from kinredund.indices import JointDeviation
from kinredund.model.loader import load_robot
from kinredund.paths import Circle
from kinredund.tracking import SphereClearance, track

ROBOTS = {"panda": "panda_link4", "xarm7": "link4"}  # robot: its elbow frame
RADIUS_RANGE = (0.03, 0.10)  # [m], the circle
SPHERE_RANGE = (0.05, 0.10)  # [m]
DEPTH_RANGE = (0.01, 0.03)  # [m], how far the sphere reaches past the elbow's point
SPEED = 0.1  # [m/s]
HOLD_TOL, CLOSURE_TOL = 1e-9, 1e-10  # [m], [rad]: the bars
PINK_TRACK_TOL, PINK_INSIDE = 1e-3, -1e-3  # [m]: a pink run within 1 mm of the path; a clearance below -1 mm
MAX_DRAWS, SPHERE_DRAWS = 50, 20
METHODS = ("kinredund", *PINK_VARIANTS)


def _unit(v):
    return v / np.linalg.norm(v)


def _circle(robot, rng):
    """(path, q0) of a random circle through a random within-limits configuration's end point, or None."""
    qc = robot.random_configuration(rng, 0.05)
    p = robot.fk(qc)[:3, 3]
    n = _unit(rng.normal(size=3))
    ax = _unit(np.cross(n, rng.normal(size=3)))
    radius = float(rng.uniform(*RADIUS_RANGE))
    path = Circle(p - radius * ax, radius, SPEED, normal=tuple(n), axis_x=tuple(ax))
    start = solve_ik(robot, p, JointDeviation(robot.home.copy()), q0=qc, bounds=True)
    return (path, start.q) if start.converged else None


def beside(P: np.ndarray, rng: np.random.Generator) -> tuple[int, np.ndarray]:
    """(k, u): a point P[k] of the trajectory ``P`` (m, 3) [m], k uniform in its middle 80 %, and a unit
    direction u uniform among those normal to the trajectory's velocity there: where an object put at P[k] +
    (its reach - depth) u is run into (module docstring; also tests/test_clearance_property.py)."""
    k = int(rng.integers(len(P) // 10, len(P) - len(P) // 10))
    vel = P[k + 1] - P[k - 1]
    u = rng.normal(size=3)
    if np.linalg.norm(vel) > 0:
        u -= (u @ vel) / (vel @ vel) * vel
    return k, _unit(u)


def _sphere(robot, frame, free, q0, rng):
    """A sphere the free run's ``frame`` origin runs into and q0 is clear of, or None."""
    probe = SphereClearance(robot, frame, [0.0, 0.0, 0.0], 1.0)
    P = np.array([probe.point(q) for q in free.q])
    for _ in range(SPHERE_DRAWS):
        k, u = beside(P, rng)
        radius, depth = float(rng.uniform(*SPHERE_RANGE)), float(rng.uniform(*DEPTH_RANGE))
        c = SphereClearance(robot, frame, P[k] + (radius - depth) * u, radius)
        if c.values(q0)[0] > 0.0:
            return c, -float(min(c.values(q)[0] for q in free.q))
    return None


def reachable_circle(robot, rng: np.random.Generator, steps: int, max_draws: int = MAX_DRAWS):
    """(path, index, q0, free, rejected draws): a random circle (:func:`_circle`) whose within-limits optimum
    ``free`` (``track(..., limits=True)``, no obstacle, ``steps`` steps) completes one loop from q0, drawn
    again until one does (module docstring; also tests/test_clearance_property.py).

    Raises:
        RuntimeError: none of ``max_draws`` draws passes.
    """
    index = JointDeviation(robot.home.copy())
    for rejected in range(max_draws):
        case = _circle(robot, rng)
        if case is None:
            continue
        path, q0 = case
        try:
            free = track(robot, path, index, q0, loops=1, steps_per_loop=steps, diagnostics=False)
        except KinredundError:
            continue
        return path, index, q0, free, rejected
    raise RuntimeError(f"no task in {max_draws} draws on {robot.name}")


def draw(robot, frame, rng, steps: int):
    """(path, index, q0, sphere, penetration [m], rejected draws) of one task (module docstring)."""
    rejected = 0
    while rejected < MAX_DRAWS:
        path, index, q0, free, skipped = reachable_circle(robot, rng, steps, MAX_DRAWS - rejected)
        rejected += skipped
        found = _sphere(robot, frame, free, q0, rng)
        if found is not None:
            return path, index, q0, *found, rejected
        rejected += 1
    raise RuntimeError(f"no task in {MAX_DRAWS} draws on {robot.name}")


def run_ours(robot, path, index, q0, sphere, loops: int, steps: int) -> dict:
    try:
        tr = track(robot, path, index, q0, loops=loops, steps_per_loop=steps, constraints=[sphere],
                   diagnostics=False)
    except TrackingError as err:
        out = {"completed": False, "cause": err.cause, "underlying_cause": err.watched.get("underlying_cause"),
               "t": err.t, "stop_clear": None}
        if err.q is not None:  # where it stopped, checked afresh: clear, on the path, inside the limits
            q = np.asarray(err.q, float)
            out.update(stop_clear=float(sphere.values(q)[0]),
                       stop_off_path=float(np.linalg.norm(robot.fk(q)[:3, 3] - path(err.t).p)),
                       stop_outside=float(max(0.0, np.max(robot.lower - q), np.max(q - robot.upper))))
        return out
    except KinredundError as err:
        return {"completed": False, "cause": type(err).__name__, "message": str(err)[:200]}
    f = figures(robot, path, sphere, tr.t, tr.q, steps)
    held = f["clearance_min"] >= -HOLD_TOL and max(f["drift"]) <= CLOSURE_TOL
    return {"completed": True, "held_and_closed": bool(held), **_short(f)}


def run_pink(robot, path, index, q0, sphere, loops: int, steps: int, safe_gain: float | None) -> dict:
    runner = PinkBarrier(robot, path, index, q0, float(path.period) / steps, sphere, safe_gain)
    rec = [runner.state()]
    for _ in range(loops * steps):
        try:
            runner.step()
        except Exception as err:  # noqa: BLE001 - a peer failing is a result, not a crash
            return {"completed": False, "cause": type(err).__name__, "message": str(err)[:200]}
        rec.append(runner.state())
    ts, qs = zip(*rec, strict=True)
    f = figures(robot, path, sphere, ts, qs, steps)
    return {"completed": f["position_error_max"] <= PINK_TRACK_TOL, "cause": "" if f["position_error_max"]
            <= PINK_TRACK_TOL else "off_path", **_short(f)}


def _short(f: dict) -> dict:
    return {"clearance_min": f["clearance_min"], "drift": f["drift"], "position_error_max": f["position_error_max"]}


def run_robot(name: str, n: int, loops: int, seed: int, steps: int, pink: bool, progress=True) -> dict:
    robot, frame = load_robot(name, task="position"), ROBOTS[name]
    rng = np.random.default_rng(seed)
    tasks, rejected = [], 0
    for i in range(n):
        path, index, q0, sphere, depth, rej = draw(robot, frame, rng, steps)
        rejected += rej
        row = {"center": sphere.center.tolist(), "radius": sphere.radius, "penetration": depth,
               "circle_radius": path.radius}
        t0 = time.perf_counter()
        row["kinredund"] = run_ours(robot, path, index, q0, sphere, loops, steps)
        row["kinredund"]["time_s"] = time.perf_counter() - t0
        for m, safe_gain in PINK_VARIANTS.items() if pink else ():
            t0 = time.perf_counter()
            row[m] = run_pink(robot, path, index, q0, sphere, loops, steps, safe_gain)
            row[m]["time_s"] = time.perf_counter() - t0
        tasks.append(row)
        if progress:
            print(f"{name} {i + 1}/{n}: penetration {100 * depth:.1f} cm; " + ", ".join(
                f"{m} {'ok' if row[m]['completed'] else row[m]['cause']}" for m in METHODS if m in row),
                flush=True)
    return {"robot": name, "frame": frame, "n": n, "seed": seed, "rejected_draws": rejected, "tasks": tasks}


def summarise(result: dict, method: str) -> dict:
    """Counts and figures of one method over a robot's tasks (module docstring)."""
    rows = [r[method] for r in result["tasks"] if method in r]
    done = [r for r in rows if r["completed"]]
    ran = [r for r in rows if "clearance_min" in r]  # to the end (completed, or pink off the path)
    mins = [r["clearance_min"] for r in ran]
    closure = [r["drift"][-1] for r in ran]
    out = {"tasks": len(rows), "completed": len(done), "completion_rate": len(done) / len(rows) if rows else None,
           "clearance_min": min(mins, default=None),
           "clearance_min_median": float(np.median(mins)) if mins else None,
           "inside_by_1mm": sum(m < PINK_INSIDE for m in mins),
           "closed": sum(c <= CLOSURE_TOL for c in closure),
           "closure_median": float(np.median(closure)) if closure else None,
           "closure_max": max(closure, default=None),
           "causes": dict(Counter(r["cause"] for r in rows if not r["completed"])),
           "underlying_causes": dict(Counter(str(r.get("underlying_cause")) for r in rows if not r["completed"]
                                             and "underlying_cause" in r)),
           "time_median_s": float(np.median([r["time_s"] for r in rows])) if rows else None}
    if method == "kinredund":
        out["held_and_closed"] = sum(r["held_and_closed"] for r in done)
        out["stops_clear_on_path_inside"] = sum(  # to the tracker's bars, 1e-9 m and 1e-10 rad
            r.get("stop_clear") is not None and r["stop_clear"] >= -HOLD_TOL and r["stop_off_path"] <= HOLD_TOL
            and r["stop_outside"] <= CLOSURE_TOL for r in rows if not r["completed"])
        out["wrong"] = len(done) - out["held_and_closed"]  # completed without holding or closing
    return out


def write_plot(results: dict, path: Path) -> None:
    """Per robot: each task's smallest clearance, kinredund against pink (written atomically)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from kinredund.ui.plots import save_figure

    fig = Figure(figsize=(6 * len(results) + 1, 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(results), squeeze=False)[0]
    for ax, (name, res) in zip(axes, results.items(), strict=True):
        for m, marker in zip(METHODS, "ox+", strict=True):
            pts = [(i, 100 * r[m]["clearance_min"]) for i, r in enumerate(res["tasks"])
                   if "clearance_min" in r.get(m, {})]
            if pts:
                ax.plot(*zip(*pts, strict=True), marker, ls="none", label=m)
        stops = [(i, 100 * (r["kinredund"].get("stop_clear") or 0.0)) for i, r in enumerate(res["tasks"])
                 if not r["kinredund"]["completed"]]  # at the clearance of its last good state
        if stops:
            ax.plot(*zip(*stops, strict=True), "s", mfc="none", ls="none", label="kinredund stopped (named cause)")
        ax.plot(range(len(res["tasks"])), [-100 * r["penetration"] for r in res["tasks"]], "_", ms=10,
                label="within-limits optimum, no sphere")
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_title(f"{name}: smallest elbow clearance per task")
        ax.set_xlabel("task")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_ylabel("smallest clearance [cm]")
        ax.grid(True, alpha=0.3)
    axes[-1].legend(fontsize=8)
    save_figure(fig, path)
    print(f"wrote {path}")


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--robot", choices=tuple(ROBOTS), default=None, help="one robot (default: panda and xarm7)")
    p.add_argument("--n", type=int, default=20, help="tasks per robot (default 20)")
    p.add_argument("--loops", type=int, default=5, help="loops per run (default 5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the task generator (default 0)")
    p.add_argument("--plot", type=Path, default=None, help="write the figure to this file (png, svg, pdf)")
    p.add_argument("--quiet", action="store_true", help="no line per task")
    args = p.parse_args()
    if args.n < 1 or args.loops < 1:
        p.error(f"--n and --loops must be >= 1, got {args.n} and {args.loops}")
    n, loops, steps = (1, 1, 50) if args.smoke else (args.n, args.loops, 200)
    why = pink_missing()
    if why:
        print(f"skipped pink: {why}")
    t0 = time.perf_counter()
    results = {}
    for name in [args.robot] if args.robot else ROBOTS:
        res = run_robot(name, n, loops, args.seed, steps, why is None, progress=not args.quiet)
        res["summary"] = {m: summarise(res, m) for m in METHODS if why is None or m == "kinredund"}
        results[name] = res
    rows = []
    for name, res in results.items():
        for m, s in res["summary"].items():
            rows.append([name, m, s["tasks"], s["completed"], s.get("held_and_closed", "-"), s.get("wrong", "-"),
                         s["clearance_min"] if s["clearance_min"] is not None else "-", s["inside_by_1mm"],
                         s["closed"], s["closure_median"] if s["closure_median"] is not None else "-",
                         s["time_median_s"], ", ".join(f"{c} {k}" for c, k in s["causes"].items())])
    print_table(rows, ["robot", "method", "tasks", "completed", "held+closed", "wrong", "min clear m", "< -1 mm",
                       "closed", f"closure@{loops} med", "time med s", "stops"])
    for name, res in results.items():
        ours = res["summary"]["kinredund"]
        under = ours["underlying_causes"]
        if under:
            print(f"{name}: kinredund's collision stops, how: " + ", ".join(f"{c} {k}" for c, k in under.items())
                  + f"; clear, on the path and inside the limits: {ours['stops_clear_on_path_inside']}"
                  f"/{sum(under.values())}")
    wall = time.perf_counter() - t0
    print(f"whole run: {wall:.1f} s")
    out = {"robots": results, "skipped": {m: why for m in PINK_VARIANTS} if why else {},
           "settings": {"loops": loops, "steps_per_loop": steps, "seed": args.seed, "speed": SPEED}, "wall_s": wall}
    write_json(args.json, out)
    if args.plot is not None:
        write_plot(results, args.plot)


if __name__ == "__main__":
    main()
