"""The main job (``kinredund demo`` / ``make demo``): every thesis example, reproduced into one folder.

Writes, into the output folder: ``summary.md`` (our figures next to the thesis's), ``summary.json``,
joint-history, error, eigenvalue and drift plots (PNG), and standalone HTML replays that play offline.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from kinredund.io import atomic_write_text, output_folder, write_json
from kinredund.tasks import get_task


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.2g}"
    return str(v)


def _chapter4(out: Path, loops: int, rows: list, data: dict, log, bar) -> None:
    from kinredund.thesis.chapter4 import THESIS_FIGURES, indefinite_interval, load_example, run_example
    from kinredund.ui.plots import plot_errors, plot_joint_histories, plot_loop_drift, plot_m_eigenvalues
    from kinredund.ui.viz import replay_html

    for name in ("4.1", "4.2", "4.3"):
        t0 = time.perf_counter()
        ex = load_example(name)
        settings = {
            "default": {"loops": loops},
            # one loop, as the thesis ran it: over many loops the explicit scheme leaves the optimum
            # (Example 4.3: the total drift from the start grows from 0.05 rad after the first loop to
            # 1.6 rad after the tenth)
            "thesis": {"loops": 1, "mode": "thesis"},
            "pseudoinverse": {"loops": loops, "scheme": "pseudoinverse"},
            "liegeois": {"loops": loops, "scheme": "liegeois"},
        }
        runs = {label: run_example(ex, progress=bar.prefixed(f"Example {name}, {label}"), **kw)
                for label, kw in settings.items()}
        thesis = THESIS_FIGURES[name]
        for label, tr in runs.items():
            s = tr.summary()
            rows.append([f"Example {name}", label, _fmt(s["position_error_max"]),
                         _fmt(s["trace_error_max"] if get_task(tr.task).has_orientation else None),
                         _fmt(s["vect_error_max"] if get_task(tr.task).has_orientation else None),
                         _fmt(s["normality_residual_max"]), _fmt(float(tr.loop_drift[-1])),
                         str(s["lu_steps"])])
            data[f"{name}/{label}"] = s
        rows.append([f"Example {name}", "thesis (1989)", _fmt(thesis.get("position_error")),
                     _fmt(thesis.get("trace_error")), _fmt(thesis.get("vect_error")), "-", "-",
                     thesis.get("note", "")])
        interval = indefinite_interval(runs["default"])
        data[f"{name}/m_indefinite_interval"] = interval
        tag = name.replace(".", "_")
        plot_joint_histories(runs["default"], out / f"example_{tag}_joints.png",
                             title=f"Example {name}: joint histories (default mode)")
        plot_errors(list(runs.values()), out / f"example_{tag}_errors.png", title=f"Example {name}: tracking errors")
        plot_loop_drift(list(runs.values()), out / f"example_{tag}_drift.png",
                        title=f"Example {name}: joint drift from the start after each loop (thesis mode: one "
                              "loop, as the thesis ran it)")
        plot_m_eigenvalues(runs["default"], out / f"example_{tag}_eigenvalues.png",
                           title=f"Example {name}: eigenvalues of M and the solver of each step")
        replay_html(runs["default"], out / f"example_{tag}.html", robot=ex.robot)
        log(f"Example {name}: done in {time.perf_counter() - t0:.1f} s")


def _chapter3(out: Path, rows: list, data: dict, log, bar) -> None:
    from kinredund.ui.reproduce import helix

    bar(0, 1, "Section 3.2")
    t0 = time.perf_counter()
    res = helix(json_path=out / "section_3_2.json", plot_path=out / "section_3_2_joints.png")
    scalars = {k: v for k, v in res.items() if isinstance(v, (int, float, str, bool)) or v is None}
    data["3.2"] = scalars
    refs = scalars.get("theta3_ref_deg"), scalars.get("theta4_ref_deg")
    rows.append(["Section 3.2", "closed form", _fmt(scalars.get("max_position_residual")), "-", "-",
                 _fmt(scalars.get("max_normality_residual")), "-",
                 f"theta3*, theta4* = {refs[0]:.3f}, {refs[1]:.3f} deg (thesis 94.08, 97.41)"])
    log(f"Section 3.2: done in {time.perf_counter() - t0:.1f} s")


def _chapter6(out: Path, rows: list, data: dict, log, bar) -> None:
    from kinredund.thesis.chapter6 import case_robot
    from kinredund.ui.reproduce import plan_case
    from kinredund.ui.viz import replay_html

    for case in ("6.2", "6.3"):
        t0 = time.perf_counter()
        tag = case.replace(".", "_")
        res = plan_case(case, json_path=out / f"section_{tag}.json", plot_path=out / f"section_{tag}.png",
                        progress=bar.prefixed(f"Section {case}"))
        s = res.summary()
        data[case] = s
        clearance = s.get("clearance_min")
        note = f"ok={res.ok}" + (f", min clearance {min(clearance):.3g} m" if clearance else "")
        if not res.ok:
            note += f": {res.reason}"
        rows.append([f"Section {case}", "planner", _fmt(s.get("position_error_max")), "-", "-",
                     _fmt(s.get("normality_residual_max")), _fmt(s.get("loop_drift")), note])
        if res.trajectory is not None:
            replay_html(res.trajectory, out / f"section_{tag}.html", robot=case_robot(case))
        log(f"Section {case}: done in {time.perf_counter() - t0:.1f} s")


def run_demo(out: str | Path, quick: bool = False, stream=None, quiet: bool = False) -> int:
    """Reproduce every example into ``out``; print the table; return the exit code (0 when all ran).

    Progress goes to standard error (:class:`kinredund.ui.progress.Progress`; nothing with ``quiet``).
    """
    from kinredund.ui.progress import Progress

    stream = stream or sys.stdout
    out = output_folder(out)  # a file or a device named by --out: OutputPathError (exit 2)
    bar = Progress("demo", quiet=quiet)

    def log(msg):
        bar.clear()
        print(msg, file=stream, flush=True)

    rows: list = []
    data: dict = {}
    failures = []
    try:
        for label, fn in (("Chapter 4", lambda: _chapter4(out, 2 if quick else 10, rows, data, log, bar)),
                          ("Chapter 3", lambda: _chapter3(out, rows, data, log, bar)),
                          ("Chapter 6", lambda: _chapter6(out, rows, data, log, bar))):
            try:
                fn()
            except Exception as err:  # noqa: BLE001 - report every failing chapter, then fail the run
                failures.append(f"{label}: {type(err).__name__}: {err}")
                log(f"{label} FAILED: {type(err).__name__}: {err}")
    except BaseException:
        bar.close()  # interrupted
        raise
    bar.close("failed" if failures else "done")
    header = ["example", "run", "position error [m]", "trace error", "vect error", "normality residual",
              "joint drift from the start after the last loop [rad]", "notes (LU steps / thesis)"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    table = "\n".join(lines)
    log("")
    log(table)
    atomic_write_text(out / "summary.md", "# kinredund demo: our figures next to the thesis's\n\n" + table + "\n")
    write_json(out / "summary.json", {"rows": rows, "figures": data, "failures": failures})  # NaN -> null
    log(f"\nwrote {len(list(out.iterdir()))} files into {out}/")
    if failures:
        log("FAILED: " + "; ".join(failures))
        return 1
    return 0
