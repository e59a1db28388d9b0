"""Random reachable circles: the strict tracker, the cyclic planner and pink side by side.

Usage::

    python benchmarks/random_tasks.py [--robot NAME] [--n N] [--seed S] [--json FILE]

Tasks (`benchmarks/_circles.py`, whose docstring is the full description): per robot (``panda``
and ``xarm7`` unless ``--robot`` names one), N tasks (default 300) drawn from
``np.random.default_rng(S)``: a configuration q_c uniform inside the limits (5 % off each end), the circle
centred on its end point p_c, radius uniform in 1-10 cm, the orientation either held at Q_c (plane
normal uniform on the sphere) or following the Frenet frame (Eq. 4.47; plane normal = Q_c's z axis, so
Q_d(0) = Q_c), speed uniform in 0.05-0.25 m/s, and the index either a JointDeviation to a second random
within-limits posture or mid_range (Eq. 4.49). A task is kept only when every one of 48 points of its loop
has a within-limits pose solution (``circles.reachable``); the rejections are counted. Each task runs
2 loops of 200 steps.

Methods, all from the same start q0 = ``circles.start_of(robot, task, S + i)``, i.e.
``solve_ik(robot, pose(0), z, bounds=True, starts=16, seed=S + i)`` for task i (the within-limits
optimum at t = 0):

- ``strict``: ``kinredund.track(robot, path, z, q0, steps_per_loop=200, loops=2, limits=True)``;
- ``planner``: ``kinredund.planning.cyclic.plan(robot, path, z)`` (24 samples, its defaults). On a
  Frenet circle the orientation turns once per loop, a loop of SO(3) no within-limits joint path can
  follow and close (``kinredund.planning.topology``): the planner says so at once (cause
  ``orientation_loop``), and the other methods cannot close there either;
- ``pink``: pin-pink's differential IK with its default limits (configuration and velocity) and the daqp
  solver: a ``FrameTask`` on the end-effector frame (costs 1 /m, 1 /rad, gain 1), a ``PostureTask`` toward
  the index's reference (cost 1e-3), the target of each step the path's pose at its end (dead-beat:
  pink has no feed-forward input), ``integrate_inplace``.

Figures per task and method, all checked independently by ``kinredund.planning.verify`` with the
robot's own FK: completed (2 loops without an exception, tracked to within 1 mm and 1e-3 rad at every
recorded point, and for the planner its ``ok``), inside the limits (every recorded point; tolerance
1e-12 rad for ours, pink's own ``check_limits`` tolerance 1e-6 rad for pink), closed after 2 loops
(max |q(2T) - q(0)| <= 1e-10 rad), the same modulo whole turns of the revolute joints, the max
tracking error [m] and orientation error [rad], the max joint step and the jumps (a step more than 4x
its neighbours', :mod:`kinredund.planning.verify`), the wall time [s]. For each failure: its cause
(the exception's ``cause`` field where it has one, else its type; the planner's reason) and whether the
configuration it reports lies on the path (<= 1e-6 m, FK) and inside the limits.

The summary table prints per robot and method: tasks, completed, completed inside the limits and closed,
median / max tracking error of the completions, completions with a jump, median time; then the planner's
completions among the tasks pink completes inside its limits, and the failure causes. Timings taken on a
loaded machine are noisy.
"""

from __future__ import annotations

import time
from collections import Counter

import numpy as np
from _bench import optional, parser, print_table, write_json
from _circles import drawn, start_of, task_arguments
from _pink import POSTURE_COST
from _pink import run_pink as run_pink_path

from kinredund.errors import KinredundError
from kinredund.kinematics.angles import joint_drift
from kinredund.model.loader import load_robot
from kinredund.planning.cyclic import plan
from kinredund.planning.verify import limit_excursion, task_errors, verify_motion_on_path
from kinredund.tracking import track

ROBOTS = ("panda", "xarm7")
METHODS = ("strict", "planner", "pink")
STEPS_PER_LOOP = 200
LOOPS = 2
LIMIT_TOL = {"strict": 1e-12, "planner": 1e-12, "pink": 1e-6}  # [rad]: pink's own check_limits tolerance
TRACK_TOL = 1e-3  # [m] and [rad]: a run that ends farther from the path than this has not tracked it
CLOSURE_TOL = 1e-10  # [rad]
ON_PATH_TOL = 1e-6  # [m]
PINK_CLOSURE_TOL = 1e-2  # [rad]: pink tracks to ~1e-5 m without feed-forward; its joints drift by more


def _figures(method, robot, path, t, q, completed: bool, cause: str = "", t_fail=None, q_fail=None) -> dict:
    """The per-method figures of one task (module docstring)."""
    out = {"completed": bool(completed), "cause": cause}
    tol = LIMIT_TOL[method]
    if completed:
        c = verify_motion_on_path(robot, path, t, q, STEPS_PER_LOOP)
        if c.position_error_max > TRACK_TOL or c.orientation_error_max > TRACK_TOL:
            out.update(completed=False, cause=f"lost the path: {c.position_error_max:.3g} m, "
                       f"{c.orientation_error_max:.3g} rad")
        out.update(inside=c.limit_violation <= tol, limit_violation=c.limit_violation,
                   closed=bool(len(c.closure) >= LOOPS and c.closure[LOOPS - 1] <= CLOSURE_TOL),
                   closure=c.closure[LOOPS - 1] if len(c.closure) >= LOOPS else None,
                   position_error_max=c.position_error_max, orientation_error_max=c.orientation_error_max,
                   step_max=c.step_max, jumps=len(c.jumps), jump_ratio_max=c.jump_ratio_max,
                   closure_modulo_turns=joint_drift(q[0], q[LOOPS * STEPS_PER_LOOP], robot.revolute))
    elif q_fail is not None and t_fail is not None:
        pos, ang = task_errors(robot, path, [float(t_fail)], [q_fail])
        out.update(failure_t=float(t_fail), failure_on_path=bool(pos[0] <= ON_PATH_TOL and ang[0] <= ON_PATH_TOL),
                   failure_position_error=float(pos[0]),
                   failure_inside=bool(limit_excursion(robot, q_fail)[0] <= tol))
    else:
        out.update(failure_t=None, failure_on_path=None, failure_inside=None)
    return out


def run_strict(robot, path, index, q0) -> dict:
    try:
        tr = track(robot, path, index, q0, steps_per_loop=STEPS_PER_LOOP, loops=LOOPS, diagnostics=False,
                   limits=True)
    except KinredundError as err:
        cause = getattr(err, "cause", None) or type(err).__name__
        q = getattr(err, "q", None)
        return _figures("strict", robot, path, None, None, False, f"{cause}: {str(err)[:160]}", getattr(err, "t", None),
                        None if q is None else np.asarray(q, float))
    return _figures("strict", robot, path, tr.t, tr.q, True)


def run_planner(robot, path, index, seed: int) -> dict:
    res = plan(robot, path, index, seed=seed, loops=LOOPS, steps_per_loop=STEPS_PER_LOOP)
    if res.ok:
        out = _figures("planner", robot, path, res.trajectory.t, res.trajectory.q, True)
        out["off_optimum"] = [list(iv) for iv in res.off_optimum]
        return out
    part = res.partial if res.partial is not None else res.trajectory
    out = _figures("planner", robot, path, None, None, False, f"{res.cause}: {res.reason[:200]}",
                   None if part is None else part.t[-1], None if part is None else part.q[-1])
    return out


def run_pink(robot, path, index, q0) -> dict:
    t, q, failure = run_pink_path(robot, path, index.reference, q0, STEPS_PER_LOOP * LOOPS,
                                  float(path.period) / STEPS_PER_LOOP)
    if failure:
        return _figures("pink", robot, path, None, None, False, failure, t[-1], q[-1])
    return _figures("pink", robot, path, t, q, True)


def run_robot(name: str, n: int, seed: int, progress=True, methods=METHODS) -> dict:
    robot = load_robot(name)
    tasks, rejected = [], 0
    for i, task, rej in drawn(robot, n, seed):
        rejected += rej
        path, index = task.path(), task.performance_index(robot)
        start = start_of(robot, task, seed + i)
        row = {"task": task.to_dict(), "start_converged": bool(start.converged)}
        for m in methods:
            t0 = time.perf_counter()
            if m == "strict":
                row[m] = run_strict(robot, path, index, start.q)
            elif m == "planner":
                row[m] = run_planner(robot, path, index, seed + i)
            else:
                row[m] = run_pink(robot, path, index, start.q)
            row[m]["time_s"] = time.perf_counter() - t0
        tasks.append(row)
        if progress:
            print(f"{name} {i + 1}/{n}: " + ", ".join(f"{m} {'ok' if row[m]['completed'] else 'fail'}"
                                                     for m in methods), flush=True)
    return {"robot": name, "n": n, "seed": seed, "rejected_draws": rejected, "tasks": tasks, "methods": list(methods)}


def summarise(result: dict) -> dict:
    """Per method: counts and figures of the completions and failures (module docstring)."""
    rows = result["tasks"]
    out = {}
    for m in result["methods"]:
        done = [r[m] for r in rows if r[m]["completed"]]
        good = [d for d in done if d["inside"] and d["closed"]]
        fails = [r[m] for r in rows if not r[m]["completed"]]
        err = [d["position_error_max"] for d in done]
        out[m] = {"tasks": len(rows), "completed": len(done), "inside_and_closed": len(good),
                  "inside": sum(d["inside"] for d in done), "closed": sum(d["closed"] for d in done),
                  "with_jump": sum(d["jumps"] > 0 for d in done),
                  "position_error_median": float(np.median(err)) if err else None,
                  "position_error_max": float(np.max(err)) if err else None,
                  "time_median_s": float(np.median([r[m]["time_s"] for r in rows])) if rows else None,
                  "failures": len(fails),
                  "failures_with_configuration": sum(f.get("failure_on_path") is not None for f in fails),
                  "failures_on_path_and_inside": sum(bool(f.get("failure_on_path")) and bool(f.get("failure_inside"))
                                                     for f in fails),
                  "causes": dict(Counter(f["cause"].split(":")[0] for f in fails))}
    if "pink" not in result["methods"]:
        return out
    pink_ok = [i for i, r in enumerate(rows) if r["pink"]["completed"] and r["pink"]["inside"]]
    plan_on = [i for i in pink_ok if rows[i]["planner"]["completed"]]
    pink_cyclic = [i for i in pink_ok if rows[i]["pink"]["closure_modulo_turns"] <= PINK_CLOSURE_TOL]
    out["planner_on_pink_completions"] = {
        "pink_completed_inside": len(pink_ok), "planner_completed": len(plan_on),
        "rate": len(plan_on) / len(pink_ok) if pink_ok else None,
        "pink_completed_inside_and_closed_modulo_turns": len(pink_cyclic),
        "planner_completed_of_those": sum(rows[i]["planner"]["completed"] for i in pink_cyclic),
        "pink_not_closed": [{"task": i, "closure_modulo_turns": rows[i]["pink"]["closure_modulo_turns"],
                             "planner_cause": rows[i]["planner"]["cause"].split(":")[0]}
                            for i in pink_ok if i not in pink_cyclic and not rows[i]["planner"]["completed"]]}
    return out


def main() -> None:
    args = task_arguments(parser(__doc__.splitlines()[0]), ROBOTS, 300, "panda")
    t0 = time.perf_counter()
    methods = METHODS if optional("pink", "daqp", what="the pink column") else tuple(m for m in METHODS if m != "pink")
    results = {}
    for name in ([args.robot] if args.robot else ROBOTS):
        res = run_robot(name, args.n, args.seed, progress=not args.quiet, methods=methods)
        res["summary"] = summarise(res)
        results[name] = res
    table = []
    for name, res in results.items():
        for m in methods:
            s = res["summary"][m]
            table.append([name, m, s["tasks"], s["completed"], s["inside_and_closed"], s["with_jump"],
                          s["position_error_median"] if s["position_error_median"] is not None else "-",
                          s["position_error_max"] if s["position_error_max"] is not None else "-",
                          s["time_median_s"], f"{s['failures_on_path_and_inside']}/{s['failures']}"])
    print_table(table, ["robot", "method", "tasks", "completed", "inside+closed", "jumps", "err med m",
                        "err max m", "time med s", "fail on path+inside"])
    for name, res in results.items():
        s = res["summary"]
        print(f"{name}: {res['rejected_draws']} draws rejected (not reachable)")
        pk = s.get("planner_on_pink_completions", {"pink_not_closed": []})
        if "pink" in methods:
            print(f"{name}: planner completes {pk['planner_completed']} of the {pk['pink_completed_inside']} tasks "
                  f"pink completes inside its limits, {pk['planner_completed_of_those']} of the "
                  f"{pk['pink_completed_inside_and_closed_modulo_turns']} where pink's joints also come back (modulo "
                  f"turns, to {PINK_CLOSURE_TOL:g} rad) after {LOOPS} loops")
        for miss in pk["pink_not_closed"]:
            print(f"  task {miss['task']}: pink completes without coming back (drift "
                  f"{miss['closure_modulo_turns']:.3g} rad modulo turns); planner: {miss['planner_cause']}")
        for m in methods:
            if s[m]["causes"]:
                print(f"  {m} failures: " + ", ".join(f"{k} x{v}" for k, v in s[m]["causes"].items()))
    wall = time.perf_counter() - t0
    print(f"whole run: {wall:.1f} s")
    write_json(args.json, {"results": results, "wall_s": wall,
                           "settings": {"n": args.n, "seed": args.seed, "steps_per_loop": STEPS_PER_LOOP,
                                        "loops": LOOPS, "strict_limits": True,
                                        "posture_cost": POSTURE_COST, "pink_solver": "daqp"}})


if __name__ == "__main__":
    main()
