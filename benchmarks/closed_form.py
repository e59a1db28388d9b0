"""Closed-form IK of the PUMA-derived 7-axis arm: time per full solve, all branches.

Over seeded random reachable poses (forward kinematics of random joint vectors): the median and p95
time of one ``ClosedFormIK.solve_all`` (2 theta1 branches x 2 wrist branches), of the 2-D
redundancy problem alone, and of the thesis's polynomial route (building Eq. 3.81 and its roots); the
largest forward-kinematics residual over the branches found. Then ``kinredund.ik.solve_ik`` on the first
``--ik-poses`` poses with the same objective (Eq. 3.30 as a JointDeviation on joints 3-4) from
``robot.home`` with 8 starts: its time, and how often it reaches the closed form's minimum (within
1e-9 rad of one branch).

Conditioning of the polynomial route (Eq. 3.81, degree 24, against its degree-12 factor), through
:func:`kinredund.closed_form.conditioning` with its defaults (relative coefficient perturbation 1e-12,
the worst of 20 seeded perturbations): the coefficient spread and the unperturbed root error along the
Section 3.2 helix (:func:`kinredund.thesis.helix_3_2.reproduce`, 91 samples), and at one near-degenerate
case: rho^2 = 1 m^2, references on the constraint curve (Eq. 3.25) with theta3* = 179.9 deg,
next to where the curve crosses theta3 = pi, so the constrained minimum of Eq. (3.31) is the reference.
Run: ``python benchmarks/closed_form.py [--json FILE] [--poses N] [--ik-poses N]``.
"""

from __future__ import annotations

import math
import time

import numpy as np
from _bench import best_of_us, parser, print_table, summary_us, write_json

from kinredund.closed_form import ClosedFormIK, conditioning, polynomial_route, solve_redundancy
from kinredund.closed_form.polynomial import real_roots
from kinredund.closed_form.positioning import plane_radius2
from kinredund.closed_form.redundancy import constraint_terms
from kinredund.ik.solve import solve_ik
from kinredund.indices import JointDeviation
from kinredund.kinematics.angles import wrap_joints
from kinredund.thesis.helix_3_2 import reproduce as helix_3_2

NEAR_DEGENERATE_RHO2 = 1.0  # [m^2]
NEAR_DEGENERATE_THETA3_DEG = 179.9  # the reference theta3*, 0.1 deg from where the curve crosses theta3 = pi
TRIALS = 20  # seeded coefficient perturbations (conditioning's default), relative size 1e-12


def _stats(ts_us: np.ndarray) -> dict:
    return {**summary_us(np.asarray(ts_us) * 1e-6), "count": int(np.size(ts_us))}


def near_degenerate(geom, theta3_deg: float = NEAR_DEGENERATE_THETA3_DEG, rho2: float = NEAR_DEGENERATE_RHO2) -> dict:
    """The minimum's root conditioning with references on the constraint curve next to theta3 = pi.

    theta4* solves Eq. (3.25) for theta3 = theta3*: (A + C c3) + (B + D c3) c4 - D s3 s4 = 0 (the lower of
    its two roots), so the constrained minimum of Eq. (3.31) is the reference itself (z = 0).
    """
    t3 = math.radians(theta3_deg)
    A, B, C, D = geom.constraint_coefficients(rho2)  # Eqs. (3.26)-(3.29)
    P, S, R0 = B + D * math.cos(t3), -D * math.sin(t3), A + C * math.cos(t3)
    half = math.acos(-R0 / math.hypot(P, S))
    t4 = min(float(wrap_joints(math.atan2(S, P) + sign * half)) for sign in (1.0, -1.0))
    off = constraint_terms((A, B, C, D), t3, t4)[0]  # Eq. (3.25)
    if abs(off) > 1e-12:
        raise SystemExit(f"near-degenerate case: the reference is off the constraint curve by {off:.3g} m^2")
    minimum = solve_redundancy(geom, rho2, (t3, t4), "sincos")
    c = conditioning(polynomial_route(geom, rho2, (t3, t4)), minimum.theta4, eps=1e-12, trials=TRIALS)
    return {"rho2": rho2, "theta3_ref_deg": theta3_deg, "theta4_ref_deg": math.degrees(t4),
            "objective_at_minimum": minimum.objective, "eps": c.eps, "trials": TRIALS,
            **{k: getattr(c, k) for k in ("root_condition_24", "root_condition_12", "root_error_24", "root_error_12",
                                          "perturbed_error_24", "perturbed_error_12")}}


def helix_conditioning() -> dict:
    """Medians and maxima of the polynomial route's conditioning along the Section 3.2 helix."""
    route = helix_3_2()["polynomial_route"]
    out = {"samples": len(route["root_error_24"])}
    for key in ("coefficient_spread_24", "coefficient_spread_12", "root_error_24", "root_error_12"):
        out[f"{key}_median"] = float(np.median(route[key]))
        out[f"{key}_max"] = float(np.max(route[key]))
    return out


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--poses", type=int, default=300, help="random reachable poses (default 300)")
    p.add_argument("--ik-poses", type=int, default=30, help="poses for the solve_ik comparison (default 30)")
    args = p.parse_args()
    if args.smoke:
        args.poses, args.ik_poses = 2, 1
    if args.poses < 1 or not 0 <= args.ik_poses <= args.poses:
        p.error(f"need --poses >= 1 and 0 <= --ik-poses <= --poses, got {args.poses} and {args.ik_poses}")
    ik = ClosedFormIK()
    robot, geom = ik.robot, ik.geometry
    rng = np.random.default_rng(0)
    poses = [robot.fk(robot.random_configuration(rng)) for _ in range(args.poses)]
    rho2s = [plane_radius2(geom, T[:3, 3]) for T in poses]
    refs = ik.theta_references
    for T in poses[:20]:  # warm up
        ik.solve_all(T)
    solve_times, branches = best_of_us(ik.solve_all, poses)
    results = {
        "solve_all": _stats(solve_times),
        "redundancy_2d": _stats(best_of_us(lambda r2: solve_redundancy(geom, r2, refs), rho2s)[0]),
        "polynomial_route": _stats(best_of_us(lambda r2: real_roots(polynomial_route(geom, r2, refs).thesis),
                                              rho2s[:50], repeat=2)[0]),
    }
    rows = [[k, v["median_us"], v["p95_us"], v["count"]] for k, v in results.items()]
    residual = max(b.fk_residual for found in branches for b in found)
    results["max_fk_residual"] = float(residual)
    if args.ik_poses:
        reference = np.zeros(robot.nq)
        reference[2:4] = ik.references
        index = JointDeviation(reference, np.array([0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0]))
        times, agree = [], 0
        for T, found in zip(poses[:args.ik_poses], branches, strict=False):
            t0 = time.perf_counter()
            res = solve_ik(robot, T, index, starts=8, seed=1)
            times.append((time.perf_counter() - t0) * 1e6)
            dist = min(np.abs(wrap_joints(b.q - res.q)).max() for b in found)
            agree += int(res.converged and dist < 1e-9)
        results["solve_ik_8_starts"] = _stats(np.array(times))
        results["solve_ik_agreement"] = agree / len(times)
        rows.append(["solve_ik_8_starts", results["solve_ik_8_starts"]["median_us"],
                     results["solve_ik_8_starts"]["p95_us"], len(times)])
    print_table(rows, ["what", "median us", "p95 us", "poses"])
    print(f"max FK residual over all branches: {residual:.3g}")
    if "solve_ik_agreement" in results:
        print(f"solve_ik reached the closed-form minimum on {results['solve_ik_agreement']:.0%} of the poses")
    h = results["helix_conditioning"] = helix_conditioning()
    print(f"Section 3.2 helix ({h['samples']} samples), degree 24 vs degree 12: coefficient spread median "
          f"{h['coefficient_spread_24_median']:.2g} (max {h['coefficient_spread_24_max']:.2g}) vs "
          f"{h['coefficient_spread_12_median']:.2g} (max {h['coefficient_spread_12_max']:.2g}); root error max "
          f"{h['root_error_24_max']:.2g} vs {h['root_error_12_max']:.2g} rad")
    nd = results["near_degenerate"] = near_degenerate(geom)
    print(f"near-degenerate case (rho^2 = {nd['rho2']:g} m^2, theta3* = {nd['theta3_ref_deg']:g} deg, "
          f"theta4* = {nd['theta4_ref_deg']:.3f} deg on the curve), degree 24 vs degree 12: root condition "
          f"{nd['root_condition_24']:.2g} vs {nd['root_condition_12']:.2g}; root error {nd['root_error_24']:.2g} vs "
          f"{nd['root_error_12']:.2g} rad; after a {nd['eps']:g} relative coefficient perturbation (worst of "
          f"{nd['trials']}) {nd['perturbed_error_24']:.2g} vs {nd['perturbed_error_12']:.2g} rad")
    write_json(args.json, results)


if __name__ == "__main__":
    main()
