"""Chapter 6 timing: the whole off-line plan of Sections 6.2 and 6.3.

Per case, one run of ``kinredund.thesis.chapter6.run_case`` with its stages (samples or roadmap,
tracking, clearance verification) and the verdict. Section 6.2 stops at its feasibility check (the
policy is out of reach; a planar loop around the obstacle must sweep over it), so its time is that
check's. Run: ``python benchmarks/planning.py [--json FILE]``.

Then the IK's backends (issue 28): ``kr.plan`` with its defaults on ``panda_circle()`` and on the xArm7's
``xarm7_fold`` circle (``benchmarks/_circles.py``), run with ``KINREDUND_BACKEND=auto`` (the compiled IK) and
``=python`` in turn (one plan of each per round, :func:`_bench.time_in_turn`; ``--rounds`` rounds): medians [s] of
the plan and of its stages (sampling: IK only). The variable switches the tracker's stepper too: the tracking
stage is timed apart.
"""

from __future__ import annotations

import os
import time

import numpy as np
from _bench import parser, print_table, time_in_turn, write_json
from _circles import NAMED_CASES

from kinredund.model.loader import load_robot
from kinredund.planning.cyclic import plan
from kinredund.problems import panda_circle
from kinredund.thesis.chapter6 import run_case

#: ``auto`` runs the compiled IK where the core supports the problem (the index JointDeviation; a plan's blended
#: indices of its follow stage are Python's under every backend), ``python`` the reference everywhere
IK_BACKENDS = ("auto", "python")
STAGES = ("samples_s", "follow_s", "tracking_s")


def bench(case: str) -> dict:
    t0 = time.perf_counter()
    result, _ = run_case(case)
    total = time.perf_counter() - t0
    s = result.summary()
    return {"total_s": total, "ok": result.ok, "stages_s": s["timings_s"], "steps": s["steps"],
            "clearance_min": s["clearance_min"], "position_error_max": s["position_error_max"],
            "reason": result.reason[:120]}


def _plans():
    """(name, robot, path, index) of the plans timed per IK backend."""
    robot, path, index, _ = panda_circle()
    yield "panda_circle", robot, path, index
    task, _ = NAMED_CASES["xarm7_fold"]
    xarm = load_robot("xarm7")
    yield "xarm7_fold", xarm, task.path(), task.performance_index(xarm)


def bench_ik_backends(rounds: int, smoke: bool) -> dict:
    """Per plan: medians [s] of the whole plan and of its stages with the compiled and the Python IK, in turn."""
    out = {}
    for name, robot, path, index in _plans():
        stages = {b: [] for b in IK_BACKENDS}

        def run(backend, robot=robot, path=path, index=index, stages=stages):
            before = os.environ.get("KINREDUND_BACKEND")
            os.environ["KINREDUND_BACKEND"] = backend
            try:
                result = plan(robot, path, index, samples=8 if smoke else 24)
            finally:
                if before is None:
                    del os.environ["KINREDUND_BACKEND"]
                else:
                    os.environ["KINREDUND_BACKEND"] = before
            stages[backend].append(result.summary()["timings_s"] | {"ok": result.ok})

        times = time_in_turn({b: (lambda b=b: run(b)) for b in IK_BACKENDS}, repeat=rounds, warmup=0 if smoke else 1)
        out[name] = {b: {"total_s": times[b]["median_us"] * 1e-6,
                         **{k: float(np.median([t.get(k, 0.0) for t in stages[b]])) for k in STAGES},
                         "ok": all(t["ok"] for t in stages[b])} for b in IK_BACKENDS}
        if smoke:
            break
    return out


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=5, help="plans per IK backend (medians over them)")
    args = p.parse_args()
    results = {case: bench(case) for case in (("6.2",) if args.smoke else ("6.2", "6.3"))}
    rows = [[c, r["total_s"], r["stages_s"].get("roadmap_s", r["stages_s"].get("samples_s", 0.0)),
             r["stages_s"].get("tracking_s", 0.0), r["stages_s"].get("clearance_s", 0.0), str(r["ok"])]
            for c, r in results.items()]
    print_table(rows, ["case", "total s", "samples/roadmap s", "tracking s", "clearance s", "ok"])
    ik = bench_ik_backends(1 if args.smoke else args.rounds, args.smoke)
    rows = [[name, b, r[b]["total_s"], r[b]["samples_s"], r[b]["follow_s"], r[b]["tracking_s"], str(r[b]["ok"])]
            for name, r in ik.items() for b in IK_BACKENDS]
    print_table(rows, ["plan", "IK backend", "median total s", "samples s (IK)", "follow s", "tracking s", "ok"])
    write_json(args.json, {"cases": results, "ik_backends": ik})


if __name__ == "__main__":
    main()
