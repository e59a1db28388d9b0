"""Chapter 6 timing: the whole off-line plan of Sections 6.2 and 6.3.

Per case, one run of ``kinredund.thesis.chapter6.run_case`` with its stages (samples or roadmap,
tracking, clearance verification) and the verdict. Section 6.2 stops at its feasibility check (the
policy is out of reach; a planar loop around the obstacle must sweep over it), so its time is that
check's. Run: ``python benchmarks/planning.py [--json FILE]``.
"""

from __future__ import annotations

import time

from _bench import parser, print_table, write_json

from kinredund.thesis.chapter6 import run_case


def bench(case: str) -> dict:
    t0 = time.perf_counter()
    result, _ = run_case(case)
    total = time.perf_counter() - t0
    s = result.summary()
    return {"total_s": total, "ok": result.ok, "stages_s": s["timings_s"], "steps": s["steps"],
            "clearance_min": s["clearance_min"], "position_error_max": s["position_error_max"],
            "reason": result.reason[:120]}


def main() -> None:
    args = parser(__doc__.splitlines()[0]).parse_args()
    results = {case: bench(case) for case in (("6.2",) if args.smoke else ("6.2", "6.3"))}
    rows = [[c, r["total_s"], r["stages_s"].get("roadmap_s", r["stages_s"].get("samples_s", 0.0)),
             r["stages_s"].get("tracking_s", 0.0), r["stages_s"].get("clearance_s", 0.0), str(r["ok"])]
            for c, r in results.items()]
    print_table(rows, ["case", "total s", "samples/roadmap s", "tracking s", "clearance s", "ok"])
    write_json(args.json, {"cases": results})


if __name__ == "__main__":
    main()
