"""A tracker step with a clearance row active: the step while the stepper holds a scene's or a sphere's row.

    python benchmarks/scene_rows.py [--json FILE] [--rounds N] [--steps N] [--backends compiled,python,...]
                                    [--case ball|sphere]

The case (``--case``, default ``ball``) is tests/test_tracking_scene.py's ``panda_elbow_ball``: test_tracking_limits's
``panda_elbow_circle`` (a 13.3 cm circle on the Panda, z = 1/2 ||q - q_home||^2, the bounded optimum at its start) with
a 5 cm sphere where the free optimum's upper arm passes, held at 2 cm (``Tracker(..., scene=, clearance=0.02,
self_clearance=False)``: the robot's own pairs unchecked), dt = T / 200; or ``sphere``, clearance_peers.py's: the same
circle with the origin of ``panda_link4`` kept out of a 0.1 m sphere (``constraints=[SphereClearance(...)]``,
tests/test_tracking_clearance.py's ``panda_elbow_sphere``). Per round a fresh tracker takes ``--steps`` steps (default
400: two loops, the row met and left in each), each timed on its own (perf_counter) and sorted by whether a general row
was active after it (``stepper.rows``), the rounds of the backends in turn (``--backends``, the first one's figures
unsuffixed). Besides ``compiled`` and ``python``, the backend ``compiled-rows-in-python`` is the compiled one with the
rows held left to the Python stepper, as before the core held them (``kinredund.tracking.compiled.held_rows`` patched to
give None for those rounds), and ``compiled-no-check`` the compiled one without the constraint's compiled check (its
``row_guard`` patched to give None: every step searched for a switch by the Python stepper, and the steps with a row
held its own, as a sphere's were before ``FrameRows``), and ``compiled-python-search`` the compiled one with the
switches' search as before the core made it (``CoreCorrector.locate`` and the stepper's rows check,
``GeneralRows._rows_cleared``, patched off: Brent's method in Python, each of its evaluations a core solve, and every
step the Python stepper takes searched for a row's switch in Python). Figures, medians over the rounds of each round's
median [us]:

- ``scene_active_step_us``: a step with a row active (on the compiled backend the core's, the rows held in it:
  ``kinredund/tracking/compiled_rows.py``; a scene's rows' curvature by central differences,
  ``SceneClearance.curvature``, a sphere's analytic);
- ``scene_active_step_cpu_us``: the same in this thread's CPU time (``time.thread_time``: not the time the scheduler
  gives other processes on a loaded machine);
- ``scene_free_step_us``: a step with none (the core's step and its row check);
- ``scene_active_steps``: how many steps of a round had a row active;
- ``scene_track_ms``: ``track()`` of ``--steps`` / 200 loops on the case [ms] (switches included: their location is
  the Python stepper's, its corrector solves the core's);
- ``scene_active_step_us_python`` etc.: the same of the other backend, and ``active_ratio``, the second backend's
  row-active step over the first's, and ``track_ratio``, the same of ``track()``;
- ``agreement_q_max``: the compiled and the Python backend stepped in turn over ``--steps`` steps, the largest joint
  difference after a step [rad];
- ``switch_share``, ``switch_ms``, ``switches``: ``--rounds`` more ``track()`` runs of each backend (medians), the
  share of its time spent locating and stepping through the switches (the Python stepper's
  ``SwitchLocation._resolve_switches``, timed around each call), that time per switch [ms], and the switches (with the
  other backends' names appended, as above).

It runs on whichever kinredund is installed, so the figure of an older build is had by running this file with that
build's Python (the issue's before/after: run the two in turn, a few times each).
"""

from __future__ import annotations

import contextlib
import time

import numpy as np
from _bench import parser, print_table, write_json
from clearance_peers import elbow_case

import kinredund
from kinredund.tracking import SceneClearance, SphereClearance, Tracker, compiled, track
from kinredund.tracking.compiled_correct import CoreCorrector
from kinredund.tracking.rows import GeneralRows
from kinredund.tracking.switches import SwitchLocation

#: the ball's centre and radius [m] and the clearance [m] of panda_elbow_ball (tests/test_tracking_scene.py)
BALL, CLEARANCE = ([-0.3178, 0.2255, 0.3518], 0.05), 0.02


def setup(kind: str = "ball"):
    """(robot, path, index, q0, the tracker's options for the rows) of ``kind``: panda_elbow_ball (clearance_peers'
    circle, panda_elbow_circle, and a ball in a scene) or panda_elbow_sphere (clearance_peers' own case)."""
    robot, path, index, q0, sphere = elbow_case()
    if kind == "sphere":
        return robot, path, index, q0, {"constraints": [sphere]}
    scene = kinredund.Scene(robot)
    scene.add_sphere("ball", BALL[1], BALL[0])
    return robot, path, index, q0, {"scene": scene, "clearance": CLEARANCE, "self_clearance": False}


#: the pseudo-backends (module docstring): the compiled step with the rows held left to the Python stepper, without
#: the constraint's compiled check, and with the switches' search in Python
ROWS_IN_PYTHON, NO_CHECK, PYTHON_SEARCH = "compiled-rows-in-python", "compiled-no-check", "compiled-python-search"


@contextlib.contextmanager
def backend_of(name: str):
    """The Tracker backend of ``name`` (``compiled`` for the pseudo-backends, with what they switch off patched while
    the block runs)."""
    if name not in (ROWS_IN_PYTHON, NO_CHECK, PYTHON_SEARCH):
        yield name
        return
    with contextlib.ExitStack() as patches:
        if name == ROWS_IN_PYTHON:
            patches.enter_context(_patched(compiled, "held_rows", lambda *args: None))
        elif name == PYTHON_SEARCH:
            patches.enter_context(_patched(CoreCorrector, "locate", lambda *args: None))
            patches.enter_context(_patched(GeneralRows, "_rows_cleared", lambda *args: False))
        else:
            for cls in (SceneClearance, SphereClearance):
                patches.enter_context(_patched(cls, "row_guard", lambda self, tol: None))
        yield "compiled"


@contextlib.contextmanager
def _patched(owner, name: str, value):
    old = getattr(owner, name)
    setattr(owner, name, value)
    try:
        yield
    finally:
        setattr(owner, name, old)


def tracker(case, backend: str | None) -> Tracker:
    r, path, index, q0, rows = case
    return Tracker(r, path, index, q0, path.period / 200, backend=backend, **rows)


def one_round(case, steps: int, backend: str = "compiled") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(step times [s], this thread's CPU time per step [s], row active after each) of a fresh tracker's ``steps``
    steps on ``backend`` (a Tracker backend or :data:`ROWS_IN_PYTHON`)."""
    with backend_of(backend) as name:
        tr = tracker(case, name)
        times, cpu, active = np.empty(steps), np.empty(steps), np.zeros(steps, bool)
        for k in range(steps):
            t0, c0 = time.perf_counter(), time.thread_time()
            tr.step()
            times[k], cpu[k] = time.perf_counter() - t0, time.thread_time() - c0
            active[k] = bool(tr.stepper.rows)
    return times, cpu, active


def agreement(case, steps: int) -> float:
    """The largest joint difference [rad] between the compiled and the Python backend stepped in turn."""
    a, b = tracker(case, "compiled"), tracker(case, "python")
    worst = 0.0
    for _ in range(steps):
        a.step()
        b.step()
        worst = max(worst, float(np.abs(a.q - b.q).max()))
    return worst


def switch_time(case, steps: int, backend: str) -> tuple[float, float, int]:
    """(share of a ``track()``'s time in ``SwitchLocation._resolve_switches``, that time per switch [ms], switches)."""
    spent, inner = [0.0], SwitchLocation._resolve_switches

    def timed(self, snap):
        t0 = time.perf_counter()
        try:
            return inner(self, snap)
        finally:
            spent[0] += time.perf_counter() - t0

    r, path, index, q0, rows = case
    with _patched(SwitchLocation, "_resolve_switches", timed), backend_of(backend) as name:
        t0 = time.perf_counter()
        tr = track(r, path, index, q0, loops=max(1, steps // 200), steps_per_loop=200, backend=name, **rows)
        total = time.perf_counter() - t0
    count = len(tr.meta["switches"])
    return spent[0] / total, 1e3 * spent[0] / max(count, 1), count


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--rounds", type=int, default=5, help="fresh trackers to time (default 5)")
    p.add_argument("--steps", type=int, default=400, help="steps per round (default 400)")
    p.add_argument("--case", choices=("ball", "sphere"), default="ball", help="the rows' case (default ball)")
    p.add_argument("--backends", default="compiled,python",
                   help="the tracker backends to time, comma-separated, each round in turn (default compiled,python; "
                        "the first one's figures unsuffixed)")
    args = p.parse_args()
    rounds, steps = (1, 120) if args.smoke else (args.rounds, args.steps)
    backends = [b.strip() for b in args.backends.split(",") if b.strip()]
    case = setup(args.case)
    for b in backends:
        one_round(case, 20, b)  # warm-up: imports, the scene's workspace, the core's first calls
    per = {b: ([], [], [], [], []) for b in backends}  # active, active cpu, free [us], row-active counts, track [ms]
    r, path, index, q0, rows = case
    for _ in range(rounds):
        for b in backends:
            times, cpu, active = one_round(case, steps, b)
            active_us, active_cpu_us, free_us, counts, track_ms = per[b]
            with backend_of(b) as name:
                t0 = time.perf_counter()
                track(r, path, index, q0, loops=max(1, steps // 200), steps_per_loop=200, backend=name, **rows)
                track_ms.append(1e3 * (time.perf_counter() - t0))
            counts.append(int(active.sum()))
            active_us.append(1e6 * float(np.median(times[active])) if active.any() else float("nan"))
            active_cpu_us.append(1e6 * float(np.median(cpu[active])) if active.any() else float("nan"))
            free_us.append(1e6 * float(np.median(times[~active])))
    out = {}
    for i, b in enumerate(backends):
        tail = "" if i == 0 else f"_{b}"
        active_us, active_cpu_us, free_us, counts, track_ms = per[b]
        out |= {f"scene_track_ms{tail}": float(np.median(track_ms)),
                f"scene_active_step_us{tail}": float(np.median(active_us)),
                f"scene_active_step_cpu_us{tail}": float(np.median(active_cpu_us)),
                f"scene_free_step_us{tail}": float(np.median(free_us)),
                f"scene_active_steps{tail}": int(np.median(counts)), f"backend{tail}": b}
    if len(backends) > 1:
        out["active_ratio"] = out[f"scene_active_step_us_{backends[1]}"] / out["scene_active_step_us"]
        out["track_ratio"] = out[f"scene_track_ms_{backends[1]}"] / out["scene_track_ms"]
    for i, b in enumerate(backends):  # (medians over the rounds, the backends in turn)
        timed = np.array([switch_time(case, steps, b) for _ in range(rounds)])
        tail = "" if i == 0 else f"_{b}"
        out |= {f"switch_share{tail}": float(np.median(timed[:, 0])), f"switch_ms{tail}": float(np.median(timed[:, 1])),
                f"switches{tail}": int(timed[0, 2])}
    out |= {"agreement_q_max": agreement(case, steps), "case": args.case, "rounds": rounds, "steps": steps,
            "active_step_us_per_round": per[backends[0]][0]}
    print_table([[k, v] for k, v in out.items() if k != "active_step_us_per_round"], ["figure", "value"])
    write_json(args.json, out)


if __name__ == "__main__":
    main()
