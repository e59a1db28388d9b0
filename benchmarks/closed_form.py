"""Closed-form IK of the PUMA-derived 7-axis arm (issue 5): time per full solve, all branches.

Over seeded random reachable poses (forward kinematics of random joint vectors): the median and p95
time of one ``ClosedFormIK.solve_all`` (2 theta1 branches x 2 wrist branches), of the 2-D
redundancy problem alone, and of the thesis's polynomial route (building Eq. 3.81 and its roots).
When ``kinredund.ik`` is importable, ``solve_ik`` on the same poses and the same objective
(Eq. 3.30 as a JointDeviation on joints 3-4) from ``robot.home`` with 8 starts: its time, and how
often it reaches the closed form's minimum (within 1e-9 rad of one branch).
Run: ``python benchmarks/closed_form.py [--json FILE] [--poses N]``.
"""

from __future__ import annotations

import time

import numpy as np
from _bench import parser, print_table, write_json

from kinredund.closed_form import ClosedFormIK, polynomial_route, solve_redundancy
from kinredund.closed_form.polynomial import real_roots
from kinredund.closed_form.positioning import plane_radius2
from kinredund.closed_form.redundancy import wrap


def _per_call(fn, args_list, repeat: int = 5) -> np.ndarray:
    """Per-argument best-of-``repeat`` time [us] of ``fn(arg)``."""
    out = np.empty(len(args_list))
    for i, a in enumerate(args_list):
        best = np.inf
        for _ in range(repeat):
            t0 = time.perf_counter()
            fn(a)
            best = min(best, time.perf_counter() - t0)
        out[i] = best * 1e6
    return out


def _stats(ts: np.ndarray) -> dict:
    return {"median_us": float(np.median(ts)), "p95_us": float(np.percentile(ts, 95)), "count": int(ts.size)}


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--poses", type=int, default=300, help="random reachable poses (default 300)")
    p.add_argument("--ik-poses", type=int, default=30, help="poses for the solve_ik comparison (default 30)")
    args = p.parse_args()
    ik = ClosedFormIK()
    robot, geom = ik.robot, ik.geometry
    rng = np.random.default_rng(0)
    poses = [robot.fk(robot.random_configuration(rng)) for _ in range(args.poses)]
    rho2s = [plane_radius2(geom, T[:3, 3]) for T in poses]
    refs = ik.theta_references
    for T in poses[:20]:  # warm up
        ik.solve_all(T)
    results = {
        "solve_all": _stats(_per_call(ik.solve_all, poses)),
        "redundancy_2d": _stats(_per_call(lambda r2: solve_redundancy(geom, r2, refs), rho2s)),
        "polynomial_route": _stats(_per_call(lambda r2: real_roots(polynomial_route(geom, r2, refs).thesis),
                                             rho2s[:50], repeat=2)),
    }
    residual = max(b.fk_residual for T in poses for b in ik.solve_all(T))
    results["max_fk_residual"] = float(residual)
    rows = [[k, v["median_us"], v["p95_us"], v["count"]] for k, v in results.items() if isinstance(v, dict)]
    try:
        from kinredund.ik import solve_ik
        from kinredund.indices import JointDeviation
    except ImportError:
        solve_ik = None
    if solve_ik is not None:
        reference = np.zeros(robot.nq)
        reference[2:4] = ik.references
        index = JointDeviation(reference, np.array([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]))
        times, agree = [], 0
        for T in poses[:args.ik_poses]:
            t0 = time.perf_counter()
            res = solve_ik(robot, T, index, starts=8, seed=1)
            times.append((time.perf_counter() - t0) * 1e6)
            dist = min(np.abs(wrap(b.q - res.q)).max() for b in ik.solve_all(T))
            agree += int(res.converged and dist < 1e-9)
        results["solve_ik_8_starts"] = _stats(np.array(times))
        results["solve_ik_agreement"] = agree / len(times)
        rows.append(["solve_ik_8_starts", results["solve_ik_8_starts"]["median_us"],
                     results["solve_ik_8_starts"]["p95_us"], len(times)])
    print_table(rows, ["what", "median us", "p95 us", "poses"])
    print(f"max FK residual over all branches: {residual:.3g}")
    if "solve_ik_agreement" in results:
        print(f"solve_ik reached the closed-form minimum on {results['solve_ik_agreement']:.0%} of the poses")
    write_json(args.json, results)


if __name__ == "__main__":
    main()
