"""Planning against pink: on random held-orientation circles, does ``kr.plan`` complete what pink completes?

Usage::

    python benchmarks/plan_peers.py [--robot NAME] [--n N] [--seed S] [--json FILE] [--plot FILE]

(``make bench`` runs it; the figures of the README come from ``--json out/plan_peers.json --plot
out/plan_peers.png``.)

Tasks (``benchmarks/_circles.py``): per robot N circles (default 6) drawn from ``np.random.default_rng(S)``
with the orientation held all along (``random_circle(..., orientations=("held",))``): tool-axis circles on the
6-axis arms ``kinova``, ``ur10``, ``z1`` and ``talos_arm`` (their task is the tool axis: the held orientation's
z axis and the point), pose circles on the 7-axis ``baxter``, ``pr2`` and ``panda``. A task is kept when the
robot's own task target has a within-limits solution at 48 points of the loop (``reachable``); the rejected
draws are counted. The index z is the generator's (a posture or mid-range).

Methods:

- ``pink``: pin-pink with daqp and its default limits (``benchmarks/_pink.py``: a FrameTask holding what the
  robot's task holds, a PostureTask toward z's reference), 2 loops of 200 steps from the within-limits
  optimum of z at t = 0 (``start_of``; where that solve does not converge, any within-limits solution
  there). It *completes the task within its limits* when it runs both loops
  without an exception, every recorded point inside the limits (pink's own tolerance, 1e-6 rad) and on the
  path to 1e-3 m and 1e-3 rad (dead-beat, without feed-forward it lags by ~1e-5 m). Its closure after the
  loops is reported, not required (pink does not plan a cyclic motion).
- ``kinredund``: ``kr.plan(robot, path, z, seed=S + i)`` with its defaults (24 samples, 2 loops of 200
  steps). It completes the task when the plan is ok, and the benchmark checks it again independently
  (``kinredund.planning.verify``): every recorded point inside the limits, on the path to 1e-9 (TASK_TOL), closed
  after every loop to 1e-10 (CLOSURE_TOL), no jump. A failure is reported with the plan's cause and reason.

The table prints per robot: tasks, pink's completions, kinredund's, kinredund's among pink's, the failure
causes of each; then the ratio *kinredund completions among pink's* over all robots (the target: >= 99 %).

Units: lengths [m], angles [rad], times [s].
"""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import numpy as np
from _bench import optional, parser, print_table, write_json
from _circles import drawn, start_of, task_arguments
from _pink import run_pink

from kinredund.model.loader import load_robot
from kinredund.planning.cyclic import CLOSURE_TOL, TASK_TOL, plan
from kinredund.planning.verify import verify_motion_on_path

AXIS_ROBOTS = ("kinova", "ur10", "z1", "talos_arm")
POSE_ROBOTS = ("baxter", "pr2", "panda")
ROBOTS = AXIS_ROBOTS + POSE_ROBOTS
STEPS_PER_LOOP, LOOPS = 200, 2
PINK_LIMIT_TOL = 1e-6  # [rad or m]: pink's own check_limits tolerance
PINK_TRACK_TOL = 1e-3  # [m] and [rad]


def pink_start(robot, path, start, seed: int):
    """pink's start: the within-limits optimum of z at t = 0 (``start_of``), else any within-limits solution of the
    task there (32 starts), else None."""
    if start.converged:
        return start.q
    from kinredund.ik.solve import solve_ik
    from kinredund.tasks import get_task

    res = solve_ik(robot, get_task(robot.task).target_at(path, 0.0), None, bounds=True, starts=32, seed=seed)
    return res.q if res.converged else None


def pink_result(robot, path, index, q0) -> dict:
    """pink's run of one task from ``q0`` and whether it completes the task within its limits (module docstring)."""
    if q0 is None:
        return {"completed": False, "cause": "no start: no within-limits solution of the task at t = 0"}
    t, q, failure = run_pink(robot, path, index.reference, q0, STEPS_PER_LOOP * LOOPS,
                             float(path.period) / STEPS_PER_LOOP)
    if failure:
        return {"completed": False, "cause": failure, "t_fail": float(t[-1])}
    c = verify_motion_on_path(robot, path, t, q, STEPS_PER_LOOP)
    out = {"limit_violation": c.limit_violation, "position_error_max": c.position_error_max,
           "orientation_error_max": c.orientation_error_max, "closure": list(c.closure)}
    if c.limit_violation > PINK_LIMIT_TOL:
        return {**out, "completed": False, "cause": f"outside its limits by {c.limit_violation:.3g}"}
    if max(c.position_error_max, c.orientation_error_max) > PINK_TRACK_TOL:
        return {**out, "completed": False, "cause": f"lost the path: {c.position_error_max:.3g} m, "
                                                    f"{c.orientation_error_max:.3g} rad"}
    return {**out, "completed": True, "cause": ""}


def kinredund_result(robot, path, index, seed: int) -> dict:
    """kr.plan's plan of one task, checked again independently (module docstring)."""
    res = plan(robot, path, index, seed=seed, loops=LOOPS, steps_per_loop=STEPS_PER_LOOP)
    out = {"ok": res.ok, "cause": res.cause, "reason": res.reason[:400], "timings_s": res.timings,
           "off_optimum": [list(iv) for iv in res.off_optimum], "notes": list(res.notes)}
    if not res.ok:
        return {**out, "completed": False}
    tr = res.trajectory
    c = verify_motion_on_path(robot, path, tr.t, tr.q, STEPS_PER_LOOP)
    closed = len(c.closure) >= LOOPS and max(c.closure) <= CLOSURE_TOL
    on_path = max(c.position_error_max, c.orientation_error_max) <= TASK_TOL
    verified = c.limit_violation == 0.0 and on_path and closed and not c.jumps
    out.update(limit_violation=c.limit_violation, position_error_max=c.position_error_max,
               orientation_error_max=c.orientation_error_max, closure=list(c.closure), jumps=len(c.jumps))
    if not verified:  # the plan said ok and the independent check disagrees: a kinredund bug, said loudly
        return {**out, "completed": False, "cause": "independent_check", "reason": f"the plan said ok but {c}"}
    return {**out, "completed": True}


def run_robot(name: str, n: int, seed: int, methods, progress: bool) -> dict:
    robot = load_robot(name)
    rows, rejected = [], 0
    for i, task, rej in drawn(robot, n, seed, orientations=("held",)):
        rejected += rej
        path, index = task.path(), task.performance_index(robot)
        row = {"task": task.to_dict()}
        for m in methods:
            t0 = time.perf_counter()
            if m == "pink":
                q0 = pink_start(robot, path, start_of(robot, task, seed + i), seed + i)
                row[m] = pink_result(robot, path, index, q0)
            else:
                row[m] = kinredund_result(robot, path, index, seed + i)
            row[m]["time_s"] = time.perf_counter() - t0
        rows.append(row)
        if progress:
            print(f"{name} ({robot.task}) {i + 1}/{n}: " + ", ".join(
                f"{m} {'ok' if row[m]['completed'] else 'fail (' + row[m]['cause'].split(':')[0] + ')'}"
                for m in methods), flush=True)
    return {"robot": name, "task_kind": robot.task, "n": n, "seed": seed, "rejected_draws": rejected, "tasks": rows}


def summarise(result: dict, methods) -> dict:
    rows = result["tasks"]
    out = {m: {"completed": sum(r[m]["completed"] for r in rows),
               "causes": dict(Counter(r[m]["cause"].split(":")[0] for r in rows if not r[m]["completed"]))}
           for m in methods}
    if "pink" in methods:
        pink_ok = [i for i, r in enumerate(rows) if r["pink"]["completed"]]
        ours = [i for i in pink_ok if rows[i]["kinredund"]["completed"]]
        out["kinredund_among_pink"] = {"pink": len(pink_ok), "kinredund": len(ours),
                                       "missed": [{"task": i, "cause": rows[i]["kinredund"]["cause"],
                                                   "reason": rows[i]["kinredund"]["reason"]}
                                                  for i in pink_ok if i not in ours]}
    return out


def write_plot(results: dict, path: Path) -> None:
    """Per robot: tasks, pink's completions, kinredund's, and kinredund's among pink's (bars)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from kinredund.ui.plots import save_figure

    fig = Figure(figsize=(11, 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    names = list(results)
    x = np.arange(len(names))
    bars = {"tasks": [results[r]["n"] for r in names],
            "pink completed (in its limits)": [results[r]["summary"]["pink"]["completed"] for r in names],
            "kinredund completed (verified)": [results[r]["summary"]["kinredund"]["completed"] for r in names],
            "kinredund among pink's": [results[r]["summary"]["kinredund_among_pink"]["kinredund"] for r in names]}
    width = 0.8 / len(bars)
    for k, (label, values) in enumerate(bars.items()):
        ax.bar(x + (k - 1.5) * width, values, width, label=label)
    ax.set_xticks(x, [f"{r}\n({results[r]['task_kind']})" for r in names])
    ax.set_ylabel("tasks")
    ax.set_title("Random held-orientation circles: pink (daqp) and kinredund's plan")
    fig.legend(*ax.get_legend_handles_labels(), fontsize=8, loc="outside right upper")
    save_figure(fig, path)
    print(f"wrote {path}")


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--plot", type=Path, default=None, help="write the figure to this file (png, svg, pdf)")
    args = task_arguments(p, ROBOTS, 6, "kinova")
    methods = ("pink", "kinredund") if optional("pink", "daqp", what="the pink column") else ("kinredund",)
    t0 = time.perf_counter()
    results = {}
    for name in ([args.robot] if args.robot else ROBOTS):
        res = run_robot(name, args.n, args.seed, methods, progress=not args.quiet)
        res["summary"] = summarise(res, methods)
        results[name] = res
    table = []
    for name, res in results.items():
        s = res["summary"]
        among = s.get("kinredund_among_pink")
        table.append([name, res["task_kind"], res["n"], s["pink"]["completed"] if "pink" in s else "-",
                      s["kinredund"]["completed"], f"{among['kinredund']}/{among['pink']}" if among else "-",
                      (", ".join(f"{k} {v}" for k, v in s["pink"]["causes"].items()) or "-") if "pink" in s else "-",
                      ", ".join(f"{k} {v}" for k, v in s["kinredund"]["causes"].items()) or "-"])
    print_table(table, ["robot", "task", "tasks", "pink", "kinredund", "kinredund/pink's", "pink fails",
                        "kinredund fails"])
    ratio = None
    if "pink" in methods:
        pink_total = sum(r["summary"]["kinredund_among_pink"]["pink"] for r in results.values())
        ours = sum(r["summary"]["kinredund_among_pink"]["kinredund"] for r in results.values())
        ratio = ours / pink_total if pink_total else None
        print(f"kinredund completions among pink's: {ours}/{pink_total}"
              + ("" if ratio is None else f" = {100 * ratio:.1f} %"))
        for name, res in results.items():
            for miss in res["summary"]["kinredund_among_pink"]["missed"]:
                print(f"  {name} task {miss['task']}: {miss['cause']}: {miss['reason'][:200]}")
    for name, res in results.items():
        for i, row in enumerate(res["tasks"]):
            k = row["kinredund"]
            if not k["completed"]:
                print(f"  kinredund {name} task {i}: {k['cause']}: {k['reason'][:200]}")
    print(f"total {time.perf_counter() - t0:.1f} s")
    write_json(args.json, {"benchmark": "plan_peers", "robots": results, "kinredund_among_pink": ratio,
                           "settings": {"steps_per_loop": STEPS_PER_LOOP, "loops": LOOPS,
                                        "pink_limit_tol": PINK_LIMIT_TOL, "pink_track_tol": PINK_TRACK_TOL}})
    if args.plot is not None and "pink" in methods:
        write_plot(results, args.plot)


if __name__ == "__main__":
    main()
