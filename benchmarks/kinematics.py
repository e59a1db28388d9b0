"""Kinematics timings: fk, K, and K with Lambda* (Chapters 2, 4 and 5).

Usage::

    python benchmarks/kinematics.py [--json FILE] [--number N] [--repeat R]

For the Panda and the CYBOTECH P-15, the per-call median time [us] of

- ``fk``: ``robot.kinematics.pose(q)`` (the end-effector pose (Q, p));
- ``K``: ``robot.kinematics.jacobian(q)`` (Q, p and the velocity Jacobian K of Eq. 2.16);
- ``K + Lambda*``: ``robot.kinematics.jacobian_derivative(q)`` (K and dK) followed by
  ``closure.contract(lam_star, dK)``, the matrix Lambda* = d(K^T lambda*)/dtheta of Eq. (4.37);
- ``K + Lambda* (fused)``: ``robot.kinematics.lambda_star(q, lam_star)``, the same result contracted
  straight from Pinocchio's buffer without the two copies of the tensor;

and the ratios "K + Lambda*" / "K". The script checks that both routes give the same arrays. For the
CYBOTECH, also the
recursive Jacobian of Eqs. (5.1)-(5.21) (``kinredund.kinematics.recursive.recursive_jacobian``, plain Python and
numpy) next to Pinocchio's K.

The internal kinematics calls are unchecked (no input validation), as the solvers use them. Each figure
is the median over ``--repeat`` runs of the mean time of ``--number`` calls (``_bench.timeit_us``: timing
each call on its own, as ``_bench.time_calls`` does, adds the timer's overhead to calls of 1-3 us). Prints a
table; with ``--json FILE`` writes the figures atomically (``_bench.write_json``).
"""

from __future__ import annotations

import importlib.metadata

import numpy as np
from _bench import parser, timeit_us, write_json

import kinredund
from kinredund.kinematics import closure
from kinredund.kinematics.recursive import recursive_jacobian

ROBOTS = ("panda", "cybotech_p15")
RECURSIVE_ROBOT = "cybotech_p15"


def bench_robot(name: str, number: int, repeat: int) -> dict:
    """Timings [us] and the check of the fused contraction for one robot."""
    r = kinredund.load_robot(name)
    rng = np.random.default_rng(0)
    q = r.random_configuration(rng, margin=0.1)
    lam = rng.normal(size=6)
    kin = r.kinematics

    def k_lambda_star():
        dK = kin.jacobian_derivative(q)[3]
        return closure.contract(lam, dK)

    reference = (*kin.jacobian(q), k_lambda_star())
    check = max(float(np.abs(a - b).max()) for a, b in zip(kin.lambda_star(q, lam), reference, strict=True))
    if check > 1e-12:
        raise SystemExit(f"{name}: Kinematics.lambda_star differs from closure.contract by {check:.3g}")
    out = {
        "nq": r.nq,
        "fk_us": timeit_us(lambda: kin.pose(q), number, repeat),
        "K_us": timeit_us(lambda: kin.jacobian(q), number, repeat),
        "K_lambda_star_us": timeit_us(k_lambda_star, number, repeat),
        "fused_K_lambda_star_us": timeit_us(lambda: kin.lambda_star(q, lam), number, repeat),
        "fused_max_abs_difference": check,
    }
    out["ratio_K_lambda_star_over_K"] = out["K_lambda_star_us"] / out["K_us"]
    out["fused_ratio_over_K"] = out["fused_K_lambda_star_us"] / out["K_us"]
    return out


def bench_recursive(number: int, repeat: int) -> dict:
    """The recursive Jacobian of Eqs. (5.1)-(5.21) next to Pinocchio's K on the CYBOTECH P-15."""
    r = kinredund.load_robot(RECURSIVE_ROBOT)
    rng = np.random.default_rng(1)
    q = r.random_configuration(rng, margin=0.1)
    err = max(
        float(np.abs(recursive_jacobian(r.hd, x) - r.velocity_jacobian(x)).max())
        for x in [q] + [r.random_configuration(rng) for _ in range(20)]
    )
    out = {
        "robot": RECURSIVE_ROBOT,
        "recursive_K_us": timeit_us(lambda: recursive_jacobian(r.hd, q), number, repeat),
        "pinocchio_K_us": timeit_us(lambda: r.kinematics.jacobian(q), number, repeat),
        "pinocchio_K_checked_us": timeit_us(lambda: r.velocity_jacobian(q), number, repeat),
        "max_abs_difference": err,
    }
    out["ratio_recursive_over_pinocchio"] = out["recursive_K_us"] / out["pinocchio_K_us"]
    return out


def format_table(robots: dict, rec: dict) -> str:
    """The printed table."""
    lines = [
        f"{'robot':<14}{'n':>3}{'fk':>8}{'K':>8}{'K+Lam*':>9}{'ratio':>7}   fused:{'K+Lam*':>9}{'ratio':>7}",
    ]
    for name, d in robots.items():
        lines.append(
            f"{name:<14}{d['nq']:>3}{d['fk_us']:>8.2f}{d['K_us']:>8.2f}{d['K_lambda_star_us']:>9.2f}"
            f"{d['ratio_K_lambda_star_over_K']:>7.2f}   {'':>6}"
            f"{d['fused_K_lambda_star_us']:>9.2f}{d['fused_ratio_over_K']:>7.2f}"
        )
    lines.append("[us per call; ratio = K+Lam* / K]")
    lines.append(
        f"recursive K (Eqs. 5.1-5.21) on {rec['robot']}: {rec['recursive_K_us']:.2f} us; Pinocchio K "
        f"{rec['pinocchio_K_us']:.2f} us (checked robot.velocity_jacobian {rec['pinocchio_K_checked_us']:.2f} us); "
        f"ratio {rec['ratio_recursive_over_pinocchio']:.1f}; max |difference| {rec['max_abs_difference']:.1e}"
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    cli = parser(__doc__.splitlines()[0])
    cli.add_argument("--number", type=int, default=2000, help="calls per timing run (default 2000)")
    cli.add_argument("--repeat", type=int, default=15, help="timing runs; the median is reported (default 15)")
    args = cli.parse_args(argv)
    if args.smoke:
        args.number, args.repeat = 2, 1
    if args.number < 1 or args.repeat < 1:
        cli.error("--number and --repeat must be positive")
    robots = {name: bench_robot(name, args.number, args.repeat) for name in ROBOTS}
    rec = bench_recursive(args.number, args.repeat)
    print(format_table(robots, rec))
    write_json(args.json, {
        "benchmark": "kinematics",
        "units": "microseconds per call (median over runs)",
        "number": args.number,
        "repeat": args.repeat,
        "numpy": np.__version__,
        "pinocchio": importlib.metadata.version("pin"),
        "robots": robots,
        "recursive": rec,
    })
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
