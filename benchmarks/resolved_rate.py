"""Resolved-rate timing on the Panda and the CYBOTECH P-15 (issue 4).

Per robot, medians over one run: one evaluation of the scheme (K, dK, Lambda*, lambda* by Householder
QR, and the solve of R), one whole step in thesis mode and in the default mode (predictor + corrector),
and one plain pseudoinverse step. Run: ``python benchmarks/resolved_rate.py [--json FILE]``.
"""

from __future__ import annotations

import numpy as np
from _bench import parser, print_table, time_calls, write_json

from kinredund.closure import contract
from kinredund.examples.chapter4 import example_path
from kinredund.examples.panda_circle import panda_circle
from kinredund.resolved_rate import ResolvedRate, kkt_matrix, multipliers


def _setup(name):
    if name == "panda":
        robot, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
        return robot, path, index, q0
    from kinredund.examples.chapter4 import load_example

    ex = load_example("4.3")
    return ex.robot, example_path("4.3"), ex.index, ex.q0


def _eval_once(robot, index, q, s_twist):
    Q, p, K, dK = robot.kinematics.jacobian_derivative(q)
    _, grad, hess = index.evaluate(q)
    lam, _ = multipliers(K, grad)  # Eqs. (4.33)-(4.34)
    M = hess + contract(lam, dK)  # M* = Hess z + Lambda*, Eq. (4.37)
    return np.linalg.solve(kkt_matrix(M, K), np.concatenate([np.zeros(robot.nq), s_twist]))  # Eq. (4.36)


def bench(name: str, steps: int) -> dict:
    robot, path, index, q0 = _setup(name)
    s = path(0.0)
    twist = np.concatenate([s.omega, s.v])
    out = {"eval_us": time_calls(lambda: _eval_once(robot, index, q0, twist))["median_us"]}
    for key, mode, scheme in [("step_default_us", "default", "augmented"), ("step_default_velocity_us", "default",
                              "velocity"), ("step_thesis_us", "thesis", "augmented"),
                              ("pinv_us", "thesis", "pseudoinverse")]:
        rr = ResolvedRate(robot, path, index, q0, path.period / 200, mode=mode, scheme=scheme)
        out[key] = time_calls(rr.advance, repeat=steps, warmup=5)["median_us"]
    return out


def main() -> None:
    args = parser(__doc__.splitlines()[0]).parse_args()
    results = {name: bench(name, 1000) for name in ("panda", "cybotech_p15")}
    rows = [[n, r["eval_us"], r["step_default_us"], r["step_default_velocity_us"], r["step_thesis_us"], r["pinv_us"]]
            for n, r in results.items()]
    print_table(rows, ["robot", "eval us", "default step us", "default (velocity) us", "thesis step us", "pinv us"])
    write_json(args.json, {"robots": results, **results})


if __name__ == "__main__":
    main()
