"""Joint-level IK benchmark: the TRAC-IK protocol on the Panda and the xArm7 (Chapter 4.2, Appendix D).

Usage::

    python benchmarks/ik.py [--robot NAME] [--n N] [--json FILE] [--z-subset M] [--starts-subset S] [--backend-subset B]

Protocol (Beeson and Ames 2015, TRAC-IK): draw N configurations uniformly within the joint limits
(``np.random.default_rng(2015)``), take their forward pose as the target, and solve seeded at
mid-limits with tolerance 1e-5 and a 5 ms budget: ``solve_ik(robot, T, q0=mid, bounds=True, tol=1e-5,
timeout=0.005, starts=MAX_STARTS)`` (multi-start until solved or out of time; ``MAX_STARTS``, the most
solve_ik accepts, is never reached within the budget). A success is a converged
solve; with ``bounds=True`` every solution is within the limits (checked). Reported per robot:
success rate, median, mean and 95th-percentile wall time of the whole call [ms]; the same for the
unbounded pose solve (joint limits ignored), as a reference.

The 5 ms budget is wall time, so the success rate drops when other jobs share the CPU. Figures
that do not depend on the load go with it, on the first S targets solved without a budget (up to 64
starts): the fraction solved within k starts, the kinematics evaluations per target (calls of
``robot.kinematics.jacobian``, one per trial step of the pose-only solver) and the fraction solved
within E evaluations; and, as CPU time (``time.process_time``, less sensitive to the load than wall
time), the time per start and per evaluation.

On the first M targets the script also compares the mid-range index z = 1/2 sum (theta_i - mid_i)^2
(Eq. 4.49, all joints) of the plain pose solve with that of the constrained minimum
``solve_ik(robot, T, mid_range(...), q0=<pose solution>, bounds=True)``: how much lower z is there, and the
median wall time and mean CPU time of that constrained solve (the Newton iteration of :mod:`kinredund.ik.newton`,
the planner's kind of solve); and, on the first B targets (``--backend-subset``), that solve by the Python and the
compiled iteration (:mod:`kinredund.ik.compiled`) in turn: median wall time per solve, time per iteration, ratio,
and their agreement (solves converged on one backend only or at q more than 1e-9 apart, failed starts and those
failing for different causes on the two); the same agreement on B bounded solves that use proxsuite's box QPs more
(seeds 0.3 rad (sd) from a configuration reaching the target, three indices, two pulling joints onto their limits:
tests/test_ik_compiled.py's); and the core's own time per iteration (``IKCore.run`` alone, pose targets, unbounded).

Prints a table; with ``--json FILE`` writes the figures atomically. The default run (N = 10000 on
both robots) takes about 20 s on an unloaded 2-core machine.
"""

from __future__ import annotations

import time

import numpy as np
from _bench import parser, print_table, write_json

import kinredund
from kinredund.ik import compiled
from kinredund.ik.solve import MAX_STARTS, solve_ik
from kinredund.indices import mid_range
from kinredund.problems import near_seed_ik_problems

ROBOTS = ("panda", "xarm7")
TOL = 1e-5
BUDGET_S = 0.005
SEED = 2015
STARTS_K = (1, 2, 4, 8, 16, 64)
EVALS_E = (50, 100, 150, 200, 300)
#: the q difference [rad or m] beyond which two backends' solves disagree
Q_AGREE = 1e-9


def run_protocol(robot, targets: list[np.ndarray], *, bounds: bool) -> dict:
    """Solve every target seeded at mid-limits within the budget; success rate and wall times [ms]."""
    mid = 0.5 * (robot.lower + robot.upper)
    solve_ik(robot, targets[0], q0=mid, tol=TOL, bounds=bounds)  # warm-up (imports, first QP)
    ok = np.zeros(len(targets), dtype=bool)
    ms = np.zeros(len(targets))
    starts = np.zeros(len(targets), dtype=int)
    for i, T in enumerate(targets):
        t0 = time.perf_counter()
        res = solve_ik(robot, T, q0=mid, tol=TOL, bounds=bounds, starts=MAX_STARTS, timeout=BUDGET_S)
        ms[i] = (time.perf_counter() - t0) * 1e3
        ok[i], starts[i] = res.converged, res.starts
        if bounds and res.converged and np.any((res.q < robot.lower) | (res.q > robot.upper)):
            raise AssertionError("a bounded solve left the joint limits")
    return {
        "success_rate": float(ok.mean()), "median_ms": float(np.median(ms)), "mean_ms": float(ms.mean()),
        "p95_ms": float(np.percentile(ms, 95)), "mean_starts": float(starts.mean()), "n": len(targets),
    }


def starts_needed(robot, targets: list[np.ndarray]) -> dict:
    """Without a budget: the fraction solved within k starts and within E kinematics evaluations, the
    evaluations per target, and CPU time per start [ms] and per evaluation [us]."""
    mid = 0.5 * (robot.lower + robot.upper)
    kmax = STARTS_K[-1]
    used = np.zeros(len(targets), dtype=int)
    evals = np.zeros(len(targets), dtype=int)
    kin, calls = robot.kinematics, [0]
    plain = kin.jacobian

    def counted(q):
        calls[0] += 1
        return plain(q)

    kin.jacobian = counted  # count the pose-only solver's kinematics calls (restored below)
    runs = 0
    cpu0 = time.process_time()
    try:
        for i, T in enumerate(targets):
            calls[0] = 0
            res = solve_ik(robot, T, q0=mid, tol=TOL, bounds=True, starts=kmax)
            used[i] = res.starts if res.converged else kmax + 1
            evals[i] = calls[0] if res.converged else 10**9
            runs += res.starts
    finally:
        cpu = time.process_time() - cpu0
        del kin.jacobian
    done = evals < 10**9
    return {
        "solved_within_k_starts": {str(k): float((used <= k).mean()) for k in STARTS_K},
        "solved_within_e_evaluations": {str(e): float((evals <= e).mean()) for e in EVALS_E},
        "evaluations_mean": float(evals[done].mean()), "evaluations_median": float(np.median(evals[done])),
        "cpu_ms_per_start": 1e3 * cpu / runs, "cpu_ms_per_target": 1e3 * cpu / len(targets),
        "cpu_us_per_evaluation": 1e6 * cpu / max(1, int(evals[done].sum())), "n": len(targets),
    }


def z_comparison(robot, targets: list[np.ndarray]) -> dict:
    """Mid-range z of the plain (bounded) pose solve and of the constrained minimum seeded there."""
    index = mid_range(robot.lower, robot.upper)
    mid = 0.5 * (robot.lower + robot.upper)
    plain, best, ms, cpu = [], [], [], []
    for T in targets:
        pose = solve_ik(robot, T, q0=mid, tol=TOL, bounds=True, starts=64)
        if not pose.converged:
            continue
        t0, c0 = time.perf_counter(), time.process_time()
        cmin = solve_ik(robot, T, index, q0=pose.q, bounds=True, tol=1e-8)
        ms.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
        if cmin.converged:
            plain.append(index.value(pose.q))
            best.append(cmin.objective)
    plain, best = np.array(plain), np.array(best)
    return {
        "n": len(plain), "z_pose_median": float(np.median(plain)), "z_min_median": float(np.median(best)),
        "z_reduction_median": float(np.median(1.0 - best / plain)),
        "z_never_higher": bool(np.all(best <= plain + 1e-9)), "constrained_min_median_ms": float(np.median(ms)),
        "constrained_min_cpu_ms_mean": float(np.mean(cpu)),
    }


def agreement(pairs: list) -> dict:
    """Of (Python, compiled) results of the same solves: how many converged on one backend only or at q more than
    Q_AGREE apart, how many failed on both and of those how many for different causes (reasons that differ in more
    than their numbers), and the largest |q| difference of the solves converged on both [rad or m]."""
    both = [(a, b) for a, b in pairs if a.converged and b.converged]
    failed = [(a, b) for a, b in pairs if not (a.converged or b.converged)]
    dq = [float(np.abs(a.q - b.q).max()) for a, b in both]
    return {"n": len(pairs), "converged_disagreements": sum(a.converged != b.converged for a, b in pairs)
            + sum(d > Q_AGREE for d in dq), "failed_both": len(failed),
            "failed_different_cause": sum(a.cause != b.cause for a, b in failed),
            "max_dq_converged": max(dq, default=0.0)}


def near_seeds(robot, n: int) -> dict:
    """:func:`agreement` of the Python and compiled iterations on n bounded solves (tol 1e-8) of
    :func:`kinredund.problems.near_seed_ik_problems` (seeds 0.3 rad (sd) from a configuration reaching the target,
    indices in turn mid-range, a random reference and weights, a reference 1 rad beyond the upper limits: the last
    two hold joints on limits, box QPs, some for proxsuite)."""
    return agreement([tuple(solve_ik(robot, T, index, q0=q0, bounds=True, tol=1e-8, backend=b)
                            for b in ("python", "compiled")) for T, q0, index in near_seed_ik_problems(robot, n, SEED)])


def backends(robot, targets: list[np.ndarray]) -> dict:
    """The constrained minimum of :func:`z_comparison` by the Python and the compiled iteration in turn
    (:mod:`kinredund.ik.compiled`; one solve each per target, alternating, so both see the same load): median
    wall time per solve [ms], time per iteration [us] (total time over total iterations), their ratio,
    whether both gave the same q (to 1e-9) and iteration counts, and their :func:`agreement`."""
    index = mid_range(robot.lower, robot.upper)
    mid = 0.5 * (robot.lower + robot.upper)
    ms = {"python": [], "compiled": []}
    its = {"python": 0, "compiled": 0}
    same = True
    pairs = []
    for T in targets:
        pose = solve_ik(robot, T, q0=mid, tol=TOL, bounds=True, starts=64)
        if not pose.converged:
            continue
        out = {}
        for backend in ("python", "compiled"):
            t0 = time.perf_counter()
            out[backend] = solve_ik(robot, T, index, q0=pose.q, bounds=True, tol=1e-8, backend=backend)
            ms[backend].append((time.perf_counter() - t0) * 1e3)
            its[backend] += out[backend].iterations
        a, b = out["python"], out["compiled"]
        same &= a.iterations == b.iterations and bool(np.allclose(a.q, b.q, rtol=0.0, atol=Q_AGREE))
        pairs.append((a, b))
    med = {k: float(np.median(v)) for k, v in ms.items()}
    per_it = {k: 1e3 * float(np.sum(ms[k])) / max(1, its[k]) for k in ms}
    return {"n": len(ms["python"]), "python_median_ms": med["python"], "compiled_median_ms": med["compiled"],
            "median_ratio": med["compiled"] / med["python"], "python_us_per_iteration": per_it["python"],
            "compiled_us_per_iteration": per_it["compiled"], "same_results": bool(same),
            "agreement": agreement(pairs)}


def core_iteration_us(robot, n: int) -> float:
    """The core's own time per iteration [us]: ``IKCore.run`` alone (no solve_ik around it) on the converged
    unbounded starts of the mid-range minimum from n random pose targets, seeded 0.1 rad (sd) from their joints."""
    core = compiled.core_module()
    if core is None:
        return float("nan")
    ik = core.IKCore(robot.model, int(robot.ee_frame_id), compiled.CONSTANTS)
    index = mid_range(robot.lower, robot.upper)
    rng = np.random.default_rng(SEED)
    total, iterations, empty = 0.0, 0, np.zeros(0)
    for _ in range(n):
        qt = robot.random_configuration(rng)
        Q, p = robot.kinematics.pose(qt)
        q0 = qt + rng.normal(0.0, 0.1, robot.nq)
        t0 = time.perf_counter()
        out = ik.run(q0, 2, Q.copy(), p.copy(), index.weights, index.reference, robot.lower, robot.upper, False,
                     1e-10, 1e-10, 200, np.inf, 0, 0.0, np.inf, 0, q0, np.inf, empty, 0.0, 0.0)
        dt = time.perf_counter() - t0
        if out[0] == 0:  # converged: iterations 0..it, each one evaluation and its line search
            total, iterations = total + dt, iterations + out[1] + 1
    return 1e6 * total / max(1, iterations)


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--robot", choices=ROBOTS, default=None, help="one robot (default: both)")
    p.add_argument("--n", type=int, default=10000, help="number of random targets per robot")
    p.add_argument("--z-subset", type=int, default=200, help="targets used for the z comparison")
    p.add_argument("--starts-subset", type=int, default=1000, help="targets used for the starts-needed figures")
    p.add_argument("--backend-subset", type=int, default=200,
                   help="targets used for the compiled-against-Python constrained solves")
    args = p.parse_args()
    if args.smoke:
        args.robot, args.n, args.z_subset, args.starts_subset, args.backend_subset = "panda", 2, 2, 2, 2
    figures, rows, extra = {}, [], []
    for name in (args.robot,) if args.robot else ROBOTS:
        robot = kinredund.load_robot(name)
        rng = np.random.default_rng(SEED)
        targets = [robot.fk(robot.random_configuration(rng)) for _ in range(args.n)]
        bounded = run_protocol(robot, targets, bounds=True)
        free = run_protocol(robot, targets, bounds=False)
        need = starts_needed(robot, targets[: args.starts_subset])
        zc = z_comparison(robot, targets[: args.z_subset])
        bk = {**backends(robot, targets[: args.backend_subset]), "near_seeds": near_seeds(robot, args.backend_subset),
              "core_us_per_iteration": core_iteration_us(robot, args.backend_subset)}
        figures[name] = {**bounded, "unbounded": free, "starts_needed": need, "z_mid_range": zc, "backends": bk}
        for label, f in (("yes", bounded), ("no", free)):
            rows.append([name, label, f"{100 * f['success_rate']:.2f}", f["median_ms"], f["mean_ms"], f["p95_ms"],
                         f["mean_starts"]])
        within = ", ".join(f"{k}: {100 * v:.2f} %" for k, v in need["solved_within_k_starts"].items())
        by_evals = ", ".join(f"{e}: {100 * v:.2f} %" for e, v in need["solved_within_e_evaluations"].items())
        extra.append(f"{name}: solved within k starts (bounds, no budget, {need['n']} targets): {within}; "
                     f"CPU {need['cpu_ms_per_start']:.3f} ms per start")
        extra.append(f"{name}: kinematics evaluations per target: mean {need['evaluations_mean']:.1f}, median "
                     f"{need['evaluations_median']:.0f}; solved within E evaluations: {by_evals}; "
                     f"CPU {need['cpu_us_per_evaluation']:.1f} us per evaluation (all costs included)")
        extra.append(f"{name}: mid-range z, pose solve -> constrained minimum (median over {zc['n']}): "
                     f"{zc['z_pose_median']:.3g} -> {zc['z_min_median']:.3g} "
                     f"({100 * zc['z_reduction_median']:.1f} % lower; {zc['constrained_min_median_ms']:.2f} ms median "
                     f"wall, {zc['constrained_min_cpu_ms_mean']:.2f} ms mean CPU per constrained solve)")
        extra.append(f"{name}: constrained minimum, Python -> compiled iteration in turn ({bk['n']} targets): median "
                     f"{bk['python_median_ms']:.3f} -> {bk['compiled_median_ms']:.3f} ms per solve "
                     f"({bk['median_ratio']:.2f}x), {bk['python_us_per_iteration']:.0f} -> "
                     f"{bk['compiled_us_per_iteration']:.0f} us per iteration (whole solves); the core alone "
                     f"{bk['core_us_per_iteration']:.1f} us per iteration; same results: {bk['same_results']}")
        for what, ag in (("the constrained minimum", bk["agreement"]), ("near seeds, bounds", bk["near_seeds"])):
            extra.append(f"{name}: backends' agreement, {what} ({ag['n']} solves): {ag['converged_disagreements']} "
                         f"converged on one only or > {Q_AGREE:g} apart (largest difference of the others "
                         f"{ag['max_dq_converged']:.2g}); failed on both {ag['failed_both']}, for different causes "
                         f"{ag['failed_different_cause']}")
    print_table(rows, ["robot", "limits", "success %", "median ms", "mean ms", "p95 ms", "starts"])
    for line in extra:
        print(line)
    write_json(args.json, {"protocol": {"tol": TOL, "budget_s": BUDGET_S, "seed": SEED, "n": args.n}, **figures})


if __name__ == "__main__":
    main()
