"""Resolved-rate timing on the Panda and the CYBOTECH P-15.

Paths, 200 steps per loop: the Panda's 0.1 m circle through its home pose with the tool rolling +-15 deg
about its axis (``panda_circle(wrist_amplitude=15 deg)``, the ``wrist15`` variant of ``peers.py``);
Example 4.3's circle with the Frenet frame on the P-15.

Per robot, medians over one run of:

- ``eval_us``, one evaluation of the scheme as the issue lists it (Jacobians, Lambda*, lambda*, solve),
  composed of the library's own pieces: ``Kinematics.jacobian_hessian`` (K, dK), ``Index.evaluate``,
  ``multipliers`` (lambda* by Householder QR), ``HessianContraction.contract`` (Lambda*), ``kkt_matrix``
  and LAPACK dgesv;
- ``eval_stepper_us``, one evaluation as the stepper itself makes it: ``ExplicitEuler._rates()`` of a
  ``Tracker(scheme="velocity", mode="thesis", qp_backend="kkt").stepper`` at the start of the path (K and dK
  from Pinocchio, the path sample, the task terms and the velocity correction of Eq. 4.29, grad z and
  Hess z, lambda* by Householder QR (Eqs. 4.33-4.34, recomputed at every call in thesis mode),
  M* = Hess z + Lambda* (Eqs. 4.37, 4.42), the LU factorisation of R with its condition estimate, and
  the solve of Eq. (4.36) for the joint and multiplier rates; the velocity form's M* is not symmetric,
  so the solve is always the LU one);
- one whole step (``Tracker.step``) in the default mode (predictor + corrector; the augmented
  form ``step_default_us`` and the velocity-Jacobian form ``step_default_velocity_us``), in thesis mode
  (``step_thesis_us``, augmented), and one plain pseudoinverse step (``pinv_us``);
- ``track_step_us``: a whole ``track()`` run with its defaults (two loops), per step, against
  ``tracker_step_us``, the bare ``Tracker.step()`` over the same two loops (the same steps, no record):
  ``track_over_step`` is their ratio (the recorder's cost; target <= 1.3). The record's diagnostics
  (normality residual, eigenvalues of M and of its projection, solver labels) are computed when first
  read: ``track_read_over_step`` is the same ratio with all of them read after each run.

On the Panda, the same run times pink's QP step on the same path (``pink_step_us``: FrameTask, daqp - the
solver pink's own examples pick when it is installed - no limits: the plain QP step the issue's 75 us
target names; ``pink_limits_step_us``: with pink's default limits) and gives our default step's ratio
to it: the target is relative to what pink takes on the same machine, because wall times on this VM
drift by up to 2x between runs. Each stepper is first timed alone (the step figures); the ratios come
from a second pass where our default steps and pink's take their steps in turn, one each per round, so
that drift and background load hit them alike (``in_turn_us``). With the joint limits held
(``limits=True``): the step on the same path (``step_limits_us``, no bound is met there) in turn with
pink's limited step (``limits_over_pink``), and the step over one loop of :data:`SWITCHING_CIRCLE`,
where joint 4 meets its limit and leaves it (median, mean, the median of the steps with joint 4 held and no
switch, the rate QP's share; the medians again on the Python stepper). With a Scene (issue 27):
the step with five obstacles and the robot's own pairs held apart against the step with the limits only, in
turn: both on the Python stepper (``scene_over_limits``, the issue's <= 1.5), and both on the default backend
(``scene_over_default``: where the core is built, the compiled steps with no row active, each checked for a
switch by the core's row guard in the same call; ``scene_python_over_default`` the scene step on the Python
stepper against it: the Python step between them slows the small limits-only step, so these flatter), and the two
compiled steps alone in turn, nothing between them (``scene_alone_over_default``, target <= 1.3); where the scene
step's time goes (``scene_breakdown_us``: the compiled distance
query, the Python around it, the stepper's rows, the rate QP, the rest) and the queries' share
(``scene_query_share``); and the whole run: ``track()`` with the scene against ``track()`` with the limits only (the
same path, dt and steps, in turn: ``track_scene_over_track``, target <= 1.5) and where the scene run's time goes
(``track_scene_breakdown_us``: the tracker's set-up, the steps, the record per step, the record's end, the checks of
the record). Run:
``python benchmarks/resolved_rate.py [--json FILE]`` and ``--plot FILE`` for a bar chart (``--scene``: the Panda's
scene figures only, a few minutes less) (pink comes with
``pip install .[bench]``; without it the pink columns are left out). The JSON holds ``robots`` (the
figures per robot) and ``keys`` (what each figure times).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from _bench import optional, parser, print_table, time_calls, time_in_turn, write_json
from scipy.linalg import lapack

from kinredund.problems import panda_circle
from kinredund.thesis.chapter4 import example_path
from kinredund.tracking import Tracker, track
from kinredund.tracking.explicit import ExplicitEuler
from kinredund.tracking.linalg import kkt_matrix, multipliers

#: what each figure of :func:`bench` times (written to the JSON as ``keys``)
KEYS = {
    "eval_us": "one evaluation (the issue's list): jacobian_hessian, Index.evaluate, multipliers (QR), "
               "HessianContraction.contract, kkt_matrix, dgesv",
    "eval_stepper_us": "one evaluation as the stepper makes it: Tracker(scheme='velocity', mode='thesis', "
                       "qp_backend='kkt').stepper._rates() at the path's start - K, dK, path sample, task terms, "
                       "grad/Hess z, lambda* by Householder QR, M* = Hess z + Lambda*, LU of R (dgetrf + "
                       "dgecon), solve of Eq. (4.36)",
    "step_default_us": "Tracker.step(), augmented scheme, default mode (predictor + Newton corrector)",
    "step_default_velocity_us": "Tracker.step(), velocity scheme, default mode",
    "step_thesis_us": "Tracker.step(), augmented scheme, thesis mode (Euler step, QP or LU)",
    # default mode: its Newton projection onto the task (in thesis mode its explicit steps leave the
    # wrist15 path by 1 cm within a quarter loop, a failure the tracker reports)
    "pinv_us": "Tracker.step(), pseudoinverse scheme, default mode",
    "pink_step_us": "pink FrameTask step, solve_ik with daqp, no limits (Panda)",
    "pink_limits_step_us": "pink FrameTask step, solve_ik with daqp, pink's default limits (Panda)",
    "step_limits_us": "Tracker.step() with the joint limits held (limits=True), augmented, default mode; on the "
                      "benchmark path no bound is met (the cost of watching them)",
    "step_limits_python_us": "step_limits_us on the Python stepper alone (backend='python'; the other Tracker "
                             "figures run on the default backend, the compiled core where it is built)",
    "limits_in_turn_us": "step_limits_us, step_limits_python_us and pink_limits_step_us timed in turn, one step "
                         "each per round (Panda)",
    "limits_over_pink": "limits_in_turn_us: step_limits_us / pink_limits_step_us (issue 28's target <= 0.25)",
    "limits_python_over_pink": "limits_in_turn_us: step_limits_python_us / pink_limits_step_us",
    "limits_compiled_over_python": "limits_in_turn_us: step_limits_us / step_limits_python_us",
    "switching_step_us": "median Tracker.step() with limits over one loop of SWITCHING_CIRCLE (a Panda pose "
                         "circle on which joint 4 meets its lower limit and leaves it again)",
    "switching_step_mean_us": "the mean of the same (the steps with a switch solve for its time: Brent's method)",
    "switching_held_step_us": "median of the same over the steps with joint 4 held on its limit and no switch (the "
                              "compiled core's reduced system where it is built)",
    "switching_step_python_us": "switching_step_us on the Python stepper (backend='python')",
    "switching_held_step_python_us": "switching_held_step_us on the Python stepper",
    "switching_steps_with_switch": "steps of that loop with a switch in them",
    "switching_loop_ms": "CPU time (thread_time) of one loop of SWITCHING_CIRCLE by Tracker.step() on the default "
                         "backend: the median of 5 loops after a first one",
    "switching_handed_back_ms": "of that loop, the CPU time of the steps the compiled core hands back to the Python "
                                "stepper (CompiledStep.hand_back: the switches, the chords that failed after them; "
                                "their corrector solves in the core, compiled_correct.py); NaN on the Python backend",
    "switching_handed_back_steps": "the steps handed back per loop (median)",
    "switching_qp_share": "share of that loop's step time spent in the rate QP (proxsuite, only at a switch "
                          "the LU route cannot decide), from a second run of the loop under cProfile",
    "in_turn_us": "the default steps (augmented, velocity) and pink's QP step timed in turn, one step each per "
                  "round (Panda)",
    "tracker_step_us": "median per step of the bare Tracker.step() over two loops (augmented, default mode)",
    "track_step_us": "median per step of track() with its defaults over two loops (the step and its record)",
    "track_over_step": "track_step_us / tracker_step_us (target <= 1.3)",
    "track_read_step_us": "track_step_us with the record's deferred diagnostics read after the run (per step)",
    "track_read_over_step": "track_read_step_us / tracker_step_us",
    "evals_per_step": "evaluations of the scheme per default-mode step (augmented), two loops",
    "predictor_miss_median": "median |q_predicted - q_corrected| [rad] of the default mode's predictor, second loop",
    "predictor_miss_max": "largest |q_predicted - q_corrected| [rad], second loop",
    "scene_in_turn_us": "Tracker.step() with a five-object scene and the self pairs held apart (scene=, 2 cm and "
                        "1 cm; SCENE_OBJECTS, none active on the path) in turn with the limits-only step, both on the "
                        "Python stepper (Panda)",
    "scene_over_limits": "scene_in_turn_us: step_scene_us / step_limits_us, the same backend (issue 27's target "
                         "<= 1.5)",
    "scene_default_in_turn_us": "the scene step in turn with the limits-only step, both on the default backend "
                                "(the compiled core where it is built: the scene's steps with no row active are "
                                "the core's, each checked for a switch by its row guard in the same call), and the "
                                "scene step on the Python "
                                "stepper (step_scene_python_us) in the same rounds",
    "scene_over_default": "scene_default_in_turn_us: step_scene_us / step_limits_us, default against default",
    "scene_python_over_default": "scene_default_in_turn_us: step_scene_python_us / step_limits_us (the scene on "
                                 "the Python stepper against the default limits-only step)",
    "scene_alone_in_turn_us": "the scene step and the limits-only step on the default backend alone, in turn (fresh "
                              "trackers, two steppers and nothing between them: in scene_default_in_turn_us the "
                              "Python scene step between them slows the small limits-only step), this thread's CPU "
                              "time per step (time.thread_time: the machine's other load left out)",
    "scene_alone_over_default": "scene_alone_in_turn_us: step_scene_us / step_limits_us, the honest figure of "
                                "scene_over_default (target <= 1.3)",
    "scene_backend": "the backend the scene run takes (python: compiled.unsupported names why)",
    "limits_backend": "the backend the limits-only run takes by default",
    "scene_breakdown_us": "the scene step's exclusive times per step [us] over 200 steps (means less the slowest "
                          "tenth): core (the compiled distance query: broadphase and coal), guard (the compiled "
                          "driver's row check of a step with no row active, RowGuard.clear inside the core's step, "
                          "by its own clock: kept and lowered values, the rows whose bounds lapse afresh, the "
                          "step's bound), query (the Python around the query: "
                          "SceneClearance._query, Workspace.query), rows (the stepper's row events and dip test), "
                          "qp (the rate QP at a weakly active row), rest (the step as without a scene), total (their "
                          "sum, with ~1 us per timed call)",
    "scene_query_share": "scene_breakdown_us: (core + guard + query) / total, the distance queries' share of the "
                         "scene step (the guard's bound arithmetic counted in)",
    "track_scene_us": "track() with the five-object scene and the self pairs held (scene=), two loops of 200 steps, "
                      "default backend: median time per step over rounds in turn with track_limits_us",
    "track_limits_us": "track() with the limits only (limits=True) on the same path, dt and steps, default backend, in "
                       "the same rounds",
    "track_scene_over_track": "track_scene_us / track_limits_us (target <= 1.5)",
    "track_scene_breakdown_us": "where the scene run's time goes, per step [us] (medians over the rounds of exclusive "
                                "times, timers around the parts: ~1 us per timed call more): setup (Tracker with the "
                                "scene: the constraint, its motion bound, the compiled check's workspace, the start), "
                                "steps (Tracker.step, and the runs of steps in one call of the core: Runs.advance, "
                                "their rows' record included), record (Recorder.add), end (Recorder.trajectory), "
                                "checks (the record's checks in track()), other (the rest of track()), total",
    "scene_pairs": "pairs the scene checks (rows of the constraint)",
    "scene_pairs_near": "of those, the pairs within the influence distance (computed by coal) at the end",
    "default_over_pink": "in_turn_us: step_default_us / pink_step_us",
    "default_velocity_over_pink": "in_turn_us: step_default_velocity_us / pink_step_us",
}


def _setup(name):
    if name == "panda":
        robot, path, index, q0 = panda_circle(wrist_amplitude=np.radians(15))
        return robot, path, index, q0
    from kinredund.thesis.chapter4 import load_example

    ex = load_example("4.3")
    return ex.robot, example_path("4.3"), ex.index, ex.q0


def _eval_once(robot, index, q, s_twist):
    """One evaluation of the velocity-Jacobian scheme (``eval_us``), from the library's pieces."""
    Q, p, K, dk = robot.kinematics.jacobian_hessian(q)  # K (Eq. 2.16) and dK (Eqs. 4.38-4.41)
    _, grad, hess = index.evaluate(q)
    lam, _ = multipliers(K, grad)  # Eqs. (4.33)-(4.34)
    M = hess + dk.contract(lam)  # M* = Hess z + Lambda*, Eqs. (4.37), (4.42)
    rhs = np.concatenate([np.zeros(robot.nq), s_twist])
    return lapack.dgesv(kkt_matrix(M, K), rhs)[2]  # Eq. (4.36), LU with partial pivoting


def _evaluator(robot, path, index, q0, dt) -> ExplicitEuler:
    """The stepper whose ``_rates()`` is "one evaluation as the stepper makes it" (``eval_stepper_us``).

    Thesis mode recomputes lambda* by QR at every evaluation (Eqs. 4.33-4.34) instead of integrating it;
    the velocity form's M* (Eq. 4.37) is not symmetric, so the rates always come from the LU factors of R
    (Eq. 4.36); ``qp_backend="kkt"`` says so explicitly. ``_rates()`` leaves q and t alone: every call
    evaluates the same point and sets ``qdot``, ``lamdot`` and ``lam``.
    """
    return Tracker(robot, path, index, q0, dt, scheme="velocity", mode="thesis", qp_backend="kkt", limits=False).stepper


def _pink_steps(robot, path, q0, dt, limits: bool):
    """pink's step on the same path, as benchmarks/peers.py runs it (pink and daqp installed)."""
    from peers import _Pink

    return _Pink(robot, path, q0, dt, posture=False, limits=limits).step


def predictor_figures(robot, path, index, q0, dt, loops: int = 2) -> dict:
    """How far the default mode's predictor misses and what that costs, over ``loops`` loops.

    ``evals_per_step``: evaluations of the scheme per step (1 when one Newton update ends the corrector,
    more where chord iterations follow); ``predictor_miss_median`` / ``_max``: |q_predicted -
    q_corrected| [rad] over the steps after the first loop (the predictor's start-up excluded).
    """
    rr = Tracker(robot, path, index, q0, dt, limits=False).stepper
    n, calls, misses = robot.nq, [0], []
    point, correct = rr.ev.point, rr._correct

    def counted_point(*args, **kwargs):
        calls[0] += 1
        return point(*args, **kwargs)

    def measured_correct(y):
        correct(y)
        misses.append(float(np.abs(y[:n] - rr.q).max()))

    rr.ev.point, rr._correct = counted_point, measured_correct
    steps = loops * round(path.period / dt)
    for _ in range(steps):
        rr.step()
    tail = np.array(misses[steps // loops:])
    return {"evals_per_step": calls[0] / steps, "predictor_miss_median": float(np.median(tail)),
            "predictor_miss_max": float(tail.max())}


def bench(name: str, steps: int) -> dict:
    robot, path, index, q0 = _setup(name)
    dt = path.period / 200
    s = path(0.0)
    twist = np.concatenate([s.omega, s.v])
    out = {"eval_us": time_calls(lambda: _eval_once(robot, index, q0, twist))["median_us"],
           "eval_stepper_us": time_calls(_evaluator(robot, path, index, q0, dt)._rates)["median_us"]}
    steppers = {key: Tracker(robot, path, index, q0, dt, mode=mode, scheme=scheme, limits=False).step
                for key, mode, scheme in [("step_default_us", "default", "augmented"),
                                          ("step_default_velocity_us", "default", "velocity"),
                                          ("step_thesis_us", "thesis", "augmented"),
                                          ("pinv_us", "default", "pseudoinverse")]}
    if name == "panda" and optional("pink", "daqp", what="the pink columns"):
        for key, limits in (("pink_step_us", False), ("pink_limits_step_us", True)):
            steppers[key] = _pink_steps(robot, path, q0, dt, limits)
    # each stepper alone, as a control loop runs it (its data stays in the caches)
    for key, step in steppers.items():
        out[key] = time_calls(step, repeat=steps, warmup=5)["median_us"]
    if "pink_step_us" in steppers:
        # then ours and pink's in turn, one step each per round: drift and background load hit both
        # alike, so the ratio holds even when the run's absolute times move (each evicts the other's
        # data from the caches, so these times are longer than the ones above)
        keys = ("step_default_us", "step_default_velocity_us", "pink_step_us")
        turn = {k: v["median_us"] for k, v in time_in_turn({k: steppers[k] for k in keys}, steps, 5).items()}
        out["in_turn_us"] = turn
        out["default_over_pink"] = turn["step_default_us"] / turn["pink_step_us"]
        out["default_velocity_over_pink"] = turn["step_default_velocity_us"] / turn["pink_step_us"]
    if name == "panda":
        steppers["step_limits_us"] = Tracker(robot, path, index, q0, dt, limits=True).step
        # the same on the Python stepper alone (the default backend is the compiled core where it is built)
        steppers["step_limits_python_us"] = Tracker(robot, path, index, q0, dt, limits=True, backend="python").step
        for key in ("step_limits_us", "step_limits_python_us"):
            out[key] = time_calls(steppers[key], repeat=steps, warmup=5)["median_us"]
        if "pink_limits_step_us" in steppers:
            keys = ("step_limits_us", "step_limits_python_us", "pink_limits_step_us")
            turn = {k: v["median_us"] for k, v in time_in_turn({k: steppers[k] for k in keys}, steps, 5).items()}
            out["limits_in_turn_us"] = turn
            out["limits_over_pink"] = turn["step_limits_us"] / turn["pink_limits_step_us"]
            out["limits_python_over_pink"] = turn["step_limits_python_us"] / turn["pink_limits_step_us"]
            out["limits_compiled_over_python"] = turn["step_limits_us"] / turn["step_limits_python_us"]
        out.update(switching_figures())
        out.update(switching_loop_figures())
        out.update({f"{k[:-3]}_python_us": v for k, v in switching_figures("python", share=False).items()
                    if k in ("switching_step_us", "switching_held_step_us")})
        out.update(scene_figures(robot, path, index, q0, dt, steps))
    out.update(predictor_figures(robot, path, index, q0, dt))
    # with their defaults (limits held) where the start is inside the limits; Example 4.3's is not
    out.update(record_figures(robot, path, index, q0, repeat=max(1, min(5, steps // 200)), limits=name == "panda"))
    return out


#: a Panda pose circle (z = 1/2 ||q - q_home||^2, 0.1 m/s) on which joint 4 meets its lower limit and
#: leaves it again, twice per loop: a configuration on it, the normal, the x axis, the radius [m]
#: (``tests/test_tracking_limits.py``'s ``panda_pose_circle``)
SWITCHING_CIRCLE = ([-0.0777, -1.1391, 0.2501, -2.9447, -0.306, 2.1239, 1.2622], [-0.0675, 0.2596, 0.9633],
                    [0.9464, -0.289, 0.1442], 0.0626)


def _switching_tracker(backend: str | None):
    """A Tracker on :data:`SWITCHING_CIRCLE` from the within-limits optimum (``backend``: its default where None)."""
    import kinredund
    from kinredund.indices import JointDeviation
    from kinredund.paths import Circle

    qs, n, ax, rad = (np.array(v, float) if isinstance(v, list) else v for v in SWITCHING_CIRCLE)
    robot = kinredund.load_robot("panda")
    n /= np.linalg.norm(n)
    ax -= (ax @ n) * n
    ax /= np.linalg.norm(ax)
    T = robot.fk(qs)
    path = Circle(T[:3, 3] - rad * ax, rad, 0.1, normal=tuple(n), axis_x=tuple(ax), orientation=T[:3, :3])
    index = JointDeviation(robot.home.copy())
    free = kinredund.solve_ik(robot, (T[:3, :3], T[:3, 3]), index, q0=qs)
    start = kinredund.solve_ik(robot, (T[:3, :3], T[:3, 3]), index, q0=free.q, bounds=True)
    return Tracker(robot, path, index, start.q, path.period / 200, backend=backend)


def _qp_share(backend: str | None, steps: int) -> float:
    """The share of the loop's time spent in the rate QP (the public ``tracking.linalg.bound_rate_qp``), from a
    second run under ``cProfile`` (no patching of the stepper; the profile's own overhead per Python call makes
    the share a rough figure, which is all it is for)."""
    import cProfile
    import pstats

    from kinredund.tracking import linalg

    tracker = _switching_tracker(backend)
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(steps):
        tracker.step()
    prof.disable()
    st = pstats.Stats(prof)
    code = linalg.bound_rate_qp.__code__
    qp = sum(v[3] for k, v in st.stats.items() if k == (code.co_filename, code.co_firstlineno, code.co_name))
    return float(qp / st.total_tt) if st.total_tt > 0 else 0.0


def switching_figures(backend: str | None = None, share: bool = True) -> dict:
    """The limited step over one loop of :data:`SWITCHING_CIRCLE`: median, mean, the median with a joint held
    (no switch), and where ``share``, the QP's share (:func:`_qp_share`); ``backend``: the Tracker's (its default where
    None)."""
    import time

    tracker = _switching_tracker(backend)
    stepper = tracker.stepper
    times, with_switch, held = np.empty(200), 0, np.zeros(200, bool)
    for k in range(200):
        before, was_held = len(stepper.switches), stepper.any_active
        t0 = time.perf_counter()
        tracker.step()
        times[k] = time.perf_counter() - t0
        with_switch += len(stepper.switches) > before
        held[k] = was_held and len(stepper.switches) == before
    out = {"switching_step_us": float(np.median(times) * 1e6), "switching_step_mean_us": float(times.mean() * 1e6),
           "switching_held_step_us": float(np.median(times[held]) * 1e6) if held.any() else float("nan"),
           "switching_steps_with_switch": with_switch}
    if share:
        out["switching_qp_share"] = _qp_share(backend, 200)
    return out


def switching_loop_figures(loops: int = 5) -> dict:
    """Whole loops of :data:`SWITCHING_CIRCLE` on the default backend (CPU time, thread_time: less shaken by a busy
    machine than the single steps' wall times) and the share of the steps handed back to the Python stepper."""
    import time

    tracker = _switching_tracker(None)
    compiled = getattr(tracker, "compiled", None)
    spent = [0.0, 0]
    if compiled is not None:
        hand_back = compiled.hand_back

        def timed(status):
            t0 = time.thread_time()
            hand_back(status)
            spent[0] += time.thread_time() - t0
            spent[1] += 1

        compiled.hand_back = timed
    for _ in range(200):  # the first loop: the set-up's first calls
        tracker.step()
    loop, back, count = [], [], []
    for _ in range(loops):
        spent[:] = [0.0, 0]
        t0 = time.thread_time()
        for _ in range(200):
            tracker.step()
        loop.append(time.thread_time() - t0)
        back.append(spent[0])
        count.append(spent[1])
    return {"switching_loop_ms": float(np.median(loop) * 1e3),
            "switching_handed_back_ms": float(np.median(back) * 1e3) if compiled is not None else float("nan"),
            "switching_handed_back_steps": float(np.median(count)) if compiled is not None else float("nan")}


#: five obstacles around the Panda circle's workspace (name, shape, size or radius [m], position [m]): clear of
#: the arm by 17-39 cm along the path (none active), the broadphase passing about 5 of the 124 pairs to coal
SCENE_OBJECTS = (("table", "box", [0.8, 0.8, 0.04], [0.45, 0.0, -0.05]),
                 ("post", "box", [0.06, 0.06, 0.8], [0.75, -0.35, 0.4]),
                 ("ball", "sphere", 0.06, [0.3, 0.45, 0.5]),
                 ("shelf", "box", [0.3, 0.2, 0.02], [0.3, -0.55, 0.7]),
                 ("lamp", "sphere", 0.05, [0.0, 0.0, 1.25]))


class _Sections:
    """Exclusive times [s] of named parts of a call tree: a part's time leaves out the parts it calls."""

    def __init__(self):
        self.spent, self._stack = {}, []

    def wrap(self, name: str, fn):
        self.spent.setdefault(name, 0.0)

        def timed(*args, **kwargs):
            now = time.perf_counter()
            if self._stack:  # pause the caller's part
                outer, since = self._stack[-1]
                self.spent[outer] += now - since
            self._stack.append((name, now))
            try:
                return fn(*args, **kwargs)
            finally:
                end = time.perf_counter()
                self.spent[name] += end - self._stack.pop()[1]
                if self._stack:
                    self._stack[-1] = (self._stack[-1][0], end)
        return timed


class _TimedCore:
    """The compiled distance query (``kinredund._core.DistanceQuery``) with its ``query`` timed."""

    def __init__(self, core, sections: _Sections):
        self.query, self.closest = sections.wrap("core", core.query), core.closest


def scene_breakdown(tracker, steps: int = 200) -> dict:
    """Where the scene step's time goes: the exclusive times per step [us] (a part leaves out the parts it
    calls), means over ``steps`` steps of ``tracker`` less the slowest tenth (steps the machine's load
    interrupted): ``core``, the compiled distance query itself (broadphase and coal, ``DistanceQuery.query``);
    ``guard``, the compiled driver's check of a step with no row active (``RowGuard.clear``, which the core's step
    runs: its own clock, ``RowGuard.seconds``, taken out of ``rest``; the rows' kept and lowered values, the rows
    whose bounds lapse afresh, the step's bound; where it rules a switch out, no ``rows`` or ``query``);
    ``query``, the Python around it (``SceneClearance._query`` and ``Workspace.query``: the kept last query, the
    values' lower bounds, the arrays); ``rows``, the stepper's handling of the rows (events, the dip test and
    its samples); ``qp``, the rate QP at a weakly active row; ``rest``, the step as without a scene (task,
    predictor, corrector, limits, watch; with a row active, also the rows' share of the system); ``total``,
    their sum (the step with these timers in: about 1 us per timed call more). Without the compiled core,
    ``core`` is 0 and the Python query is all in ``query``."""
    stepper = tracker.stepper
    constraint = stepper.general[0]
    ws = constraint.scene.workspace()
    sections, saved = _Sections(), ws._core
    if saved is not None:
        ws._core = _TimedCore(saved, sections)
    driver = getattr(tracker, "compiled", None)
    guard = getattr(getattr(driver, "guard", None), "compiled", None)  # the RowGuard the core's step runs
    patched = [(constraint, "_query", "query"), (ws, "query", "query"), (stepper, "_row_events", "rows"),
               (stepper, "_row_dips", "rows"), (stepper, "_qp_keeps_row", "qp")]
    for obj, attr, part in patched:
        setattr(obj, attr, sections.wrap(part, getattr(obj, attr)))
    step = sections.wrap("rest", tracker.step)
    per = {name: np.empty(steps) for name in ("core", "guard", "query", "rows", "qp", "rest", "total")}
    try:
        for k in range(steps):
            for name in sections.spent:
                sections.spent[name] = 0.0
            before = 0.0 if guard is None else guard.seconds
            step()
            if guard is not None:  # its own clock, inside the core's step (or a query's part): out of `rest`
                sections.spent["guard"] = guard.seconds - before
                sections.spent["rest"] -= sections.spent["guard"]
            for name in per:
                per[name][k] = sections.spent.get(name, 0.0) if name != "total" else sum(sections.spent.values())
    finally:
        for obj, attr, _ in patched:
            del obj.__dict__[attr]
        ws._core = saved
    calm = per["total"] <= np.percentile(per["total"], 90)  # the steps the machine's load did not interrupt
    mean = {k: float(v[calm].mean() * 1e6) for k, v in per.items()}
    share = (mean["core"] + mean["guard"] + mean["query"]) / mean["total"]
    return {"scene_breakdown_us": mean, "scene_query_share": share}


def scene_figures(robot, path, index, q0, dt, steps: int) -> dict:
    """The step with :data:`SCENE_OBJECTS` and the robot's own pairs held apart (2 cm, 1 cm) against the step
    with the limits only, in turn: both on the Python stepper, and both on the default backend (the compiled core
    where it is built), with the scene step on the Python stepper in the same rounds. Then where the default
    backend's scene step's time goes (:func:`scene_breakdown`)."""
    scene = _scene(robot)
    with_scene = Tracker(robot, path, index, q0, dt, scene=scene)
    scene_python = Tracker(robot, path, index, q0, dt, scene=scene, backend="python")
    python = Tracker(robot, path, index, q0, dt, limits=True, backend="python")
    default = Tracker(robot, path, index, q0, dt, limits=True)
    # in turn (one step of each per round, each step after the other's: their cache misses alike)
    same = {k: v["median_us"] for k, v in time_in_turn({"step_scene_us": scene_python.step,
                                                        "step_limits_us": python.step}, steps, 5).items()}
    other = {k: v["median_us"] for k, v in time_in_turn({"step_scene_us": with_scene.step,
                                                         "step_scene_python_us": Tracker(
                                                             robot, path, index, q0, dt, scene=scene,
                                                             backend="python").step,
                                                         "step_limits_us": default.step}, steps, 5).items()}
    # the two compiled steppers alone, fresh, in turn: no Python step between them to slow the small one; this
    # thread's CPU time (the other processes of a loaded machine left out)
    alone = {k: v["median_us"] for k, v in time_in_turn({
        "step_scene_us": Tracker(robot, path, index, q0, dt, scene=scene).step,
        "step_limits_us": Tracker(robot, path, index, q0, dt, limits=True).step}, steps, 5,
        clock=time.thread_time).items()}
    constraint = with_scene.stepper.general[0]
    return {"scene_in_turn_us": same, "scene_default_in_turn_us": other, "scene_alone_in_turn_us": alone,
            "scene_alone_over_default": alone["step_scene_us"] / alone["step_limits_us"],
            "scene_over_limits": same["step_scene_us"] / same["step_limits_us"],
            "scene_over_default": other["step_scene_us"] / other["step_limits_us"],
            "scene_python_over_default": other["step_scene_python_us"] / other["step_limits_us"],
            "scene_backend": with_scene.backend, "limits_backend": default.backend,
            **scene_breakdown(with_scene), "scene_pairs": constraint.size,
            "scene_pairs_near": len(scene.distance_rows(with_scene.q, constraint.influence).pairs),
            **track_scene_figures(robot, path, index, q0, repeat=3 if steps < 100 else 7)}


def _scene(robot):
    """A Scene of ``robot`` with :data:`SCENE_OBJECTS`."""
    import kinredund

    scene = kinredund.Scene(robot)
    for name, shape, size, pos in SCENE_OBJECTS:
        if shape == "box":
            scene.add_box(name, size, pos)
        else:
            scene.add_sphere(name, size, pos)
    return scene


def track_scene_figures(robot, path, index, q0, repeat: int = 7, loops: int = 2) -> dict:
    """``track()`` with :data:`SCENE_OBJECTS` (and the self pairs) against ``track()`` with the limits only: the same
    path, dt and steps, default backend, one run of each per round in turn (garbage collection off), the medians per
    step over ``repeat`` rounds. Then where the scene run's time goes (:func:`track_scene_breakdown`)."""
    import gc

    scene = _scene(robot)
    steps = 200 * loops
    runs = {"track_scene_us": lambda: track(robot, path, index, q0, loops=loops, scene=scene),
            "track_limits_us": lambda: track(robot, path, index, q0, loops=loops, limits=True)}
    per = {k: [] for k in runs}
    for fn in runs.values():  # warm-up
        fn()
    gc.disable()
    try:
        for _ in range(repeat):
            for key, fn in runs.items():
                t0 = time.perf_counter()
                fn()
                per[key].append((time.perf_counter() - t0) / steps * 1e6)
    finally:
        gc.enable()
    out = {k: float(np.median(v)) for k, v in per.items()}
    out["track_scene_over_track"] = out["track_scene_us"] / out["track_limits_us"]
    out["track_scene_breakdown_us"] = track_scene_breakdown(robot, path, index, q0, scene, repeat, loops)
    return out


def track_scene_breakdown(robot, path, index, q0, scene, repeat: int = 7, loops: int = 2) -> dict:
    """The scene run's exclusive times per step [us] by part (``track_scene_breakdown_us`` in :data:`KEYS`): the
    library's functions wrapped with timers for the run (and put back), medians over ``repeat`` runs."""
    from kinredund.tracking import compiled, recorder, runs
    from kinredund.tracking import run as run_module

    sections = _Sections()
    patched = [(run_module, "Tracker", "setup"), (compiled.CompiledStep, "step", "steps"),
               (runs.Runs, "advance", "steps"), (recorder.Recorder, "add", "record"),
               (recorder.Recorder, "trajectory", "end"), (run_module, "say_rate_burst", "checks"),
               (run_module, "say_open_loop", "checks")]
    saved = [(obj, attr, obj.__dict__[attr]) for obj, attr, _ in patched]
    whole = sections.wrap("other", track)
    steps = 200 * loops
    per: dict = {}
    try:
        for obj, attr, part in patched:
            setattr(obj, attr, sections.wrap(part, getattr(obj, attr)))
        for _ in range(repeat):
            for name in sections.spent:
                sections.spent[name] = 0.0
            whole(robot, path, index, q0, loops=loops, scene=scene)
            for name, spent in sections.spent.items():
                per.setdefault(name, []).append(spent / steps * 1e6)
            per.setdefault("total", []).append(sum(sections.spent.values()) / steps * 1e6)
    finally:
        for obj, attr, fn in saved:
            setattr(obj, attr, fn)
    return {k: float(np.median(v)) for k, v in per.items()}


def record_figures(robot, path, index, q0, repeat: int = 5, loops: int = 2, limits: bool = True) -> dict:
    """``track()`` with its defaults against the bare ``Tracker.step()`` over the same run, per step.

    Each of ``repeat`` rounds times one whole ``track()`` run of ``loops`` loops (200 steps each) and one
    loop of bare steps over the same run, in turn; the figures are the medians over the rounds of the
    time per step, so the ratio is the recorder's share, drift and load hitting both alike.
    """
    import gc
    import time

    steps = 200 * loops
    dt = path.period / 200
    per_track, per_read, per_step = [], [], []
    gc.disable()
    try:
        for _ in range(repeat):
            t0 = time.perf_counter()
            record = track(robot, path, index, q0, loops=loops, limits=limits)
            t1 = time.perf_counter()
            _ = record.solver, record.m_eigs, record.m_null_eigs, record.normality_residual  # computed on read
            per_track.append((t1 - t0) / steps)
            per_read.append((time.perf_counter() - t0) / steps)
            tracker = Tracker(robot, path, index, q0, dt, limits=limits)
            step = tracker.step
            t0 = time.perf_counter()
            for _ in range(steps):
                step()
            per_step.append((time.perf_counter() - t0) / steps)
    finally:
        gc.enable()
    a, r, b = (float(np.median(x) * 1e6) for x in (per_track, per_read, per_step))
    return {"track_step_us": a, "tracker_step_us": b, "track_over_step": a / b, "track_read_step_us": r,
            "track_read_over_step": r / b}


def write_plot(results: dict, path: Path) -> None:
    """Median times per robot as horizontal bars, with the issue's 40 and 75 us lines (written atomically)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from kinredund.ui.plots import save_figure

    labels = {"eval_us": "one evaluation (issue's list)", "eval_stepper_us": "one evaluation (stepper's _rates)",
              "step_default_us": "default step (augmented)",
              "step_default_velocity_us": "default step (velocity form)", "step_thesis_us": "thesis step",
              "pinv_us": "pseudoinverse step", "pink_step_us": "pink QP step (no limits)",
              "pink_limits_step_us": "pink QP step (limits)"}
    fig = Figure(figsize=(6 * len(results), 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(results), sharex=True, squeeze=False)[0]
    for ax, (name, res) in zip(axes, results.items(), strict=True):
        keys = [k for k in labels if k in res]
        colours = ["tab:gray" if k.startswith("pink") else "tab:blue" for k in keys]
        ax.barh([labels[k] for k in keys], [res[k] for k in keys], color=colours)
        ax.axvline(40.0, color="tab:orange", linestyle=":", linewidth=1, label="40 us (evaluation target)")
        ax.axvline(75.0, color="tab:red", linestyle="--", linewidth=1, label="75 us (default-step target)")
        ax.invert_yaxis()
        ax.set_title(name)
        ax.set_xlabel("median time [us] (one run)")
        ax.grid(True, axis="x", alpha=0.3)
    handles, names = axes[0].get_legend_handles_labels()
    fig.legend(handles, names, fontsize=8, loc="outside lower center", ncols=2)
    save_figure(fig, path)
    print(f"wrote {path}")


def print_scene(panda: dict) -> None:
    """Print the scene figures of :func:`scene_figures` (where they were measured)."""
    if "scene_over_limits" not in panda:
        return
    same, other, part = panda["scene_in_turn_us"], panda["scene_default_in_turn_us"], panda["scene_breakdown_us"]
    alone = panda["scene_alone_in_turn_us"]
    print(f"Panda, five-object scene and self pairs held: on the Python stepper, step {same['step_scene_us']:.3g} "
          f"us against {same['step_limits_us']:.3g} us with the limits only: {panda['scene_over_limits']:.2f} "
          f"(target <= 1.5); on the default backend ({panda['scene_backend']}), {other['step_scene_us']:.3g} us "
          f"against the limits-only step ({panda['limits_backend']}, {other['step_limits_us']:.3g} us): "
          f"{panda['scene_over_default']:.2f} (the Python stepper's scene step {other['step_scene_python_us']:.3g} "
          f"us: {panda['scene_python_over_default']:.2f}); the two compiled steps alone in turn: "
          f"{alone['step_scene_us']:.3g} us against {alone['step_limits_us']:.3g} us: "
          f"{panda['scene_alone_over_default']:.2f} (target <= 1.3)")
    print("  per scene step [us]: " + ", ".join(f"{k} {v:.3g}" for k, v in part.items())
          + f"; {100 * panda['scene_query_share']:.2g} % in the distance queries (core + guard + query; "
          f"{panda['scene_pairs_near']} of {panda['scene_pairs']} pairs computed)")
    print(f"  track() with the scene {panda['track_scene_us']:.3g} us per step against track() with the limits only "
          f"{panda['track_limits_us']:.3g} us: {panda['track_scene_over_track']:.2f} (target <= 1.5); the scene run "
          "per step [us]: " + ", ".join(f"{k} {v:.3g}" for k, v in panda["track_scene_breakdown_us"].items()))


def scene_only(steps: int, json_path: Path | None) -> None:
    """``--scene``: the Panda's scene figures alone (:func:`scene_figures`), printed and written as ``robots``."""
    robot, path, index, q0 = _setup("panda")
    panda = scene_figures(robot, path, index, q0, path.period / 200, steps)
    print_scene(panda)
    write_json(json_path, {"robots": {"panda": panda}, "keys": KEYS})


def main() -> None:
    p = parser(__doc__.splitlines()[0])
    p.add_argument("--plot", type=Path, default=None, help="write a bar chart of the times (png, svg, pdf)")
    p.add_argument("--scene", action="store_true", help="the Panda's scene figures only (scene_*)")
    args = p.parse_args()
    if args.scene:
        return scene_only(10 if args.smoke else 1000, args.json)
    results = {name: bench(name, 10 if args.smoke else 1000) for name in ("panda", "cybotech_p15")}
    cols = ["eval_us", "eval_stepper_us", "step_default_us", "step_default_velocity_us", "step_thesis_us", "pinv_us",
            "pink_step_us", "pink_limits_step_us"]
    rows = [[n] + [r.get(c, "-") for c in cols] for n, r in results.items()]
    print_table(rows, ["robot", "eval us", "eval (stepper) us", "default step us", "default (velocity) us",
                       "thesis step us", "pinv us", "pink QP step us", "pink (limits) us"])
    panda = results["panda"]
    if "default_over_pink" in panda:
        turn = panda["in_turn_us"]
        print(f"Panda, steps in turn: default {turn['step_default_us']:.3g} us, velocity form "
              f"{turn['step_default_velocity_us']:.3g} us, pink {turn['pink_step_us']:.3g} us; default step / pink QP "
              f"step: {panda['default_over_pink']:.2f} (augmented), {panda['default_velocity_over_pink']:.2f} "
              "(velocity form); target <= 1")
    if "step_limits_us" in panda:
        print(f"Panda, limits held: step {panda['step_limits_us']:.3g} us"
              + (f"; in turn with pink's limited step (daqp): {panda['limits_over_pink']:.2f} (target <= 0.25; "
                 f"the Python stepper {panda['limits_python_over_pink']:.2f})" if "limits_over_pink" in panda else "")
              + f"; on a circle with switches: median {panda['switching_step_us']:.3g} us, mean "
              f"{panda['switching_step_mean_us']:.3g} us ({panda['switching_steps_with_switch']} steps with a switch), "
              f"{100 * panda['switching_qp_share']:.2g} % of the time in the rate QP; with joint 4 held "
              f"{panda['switching_held_step_us']:.3g} us (the Python stepper "
              f"{panda['switching_held_step_python_us']:.3g} us); a whole loop {panda['switching_loop_ms']:.3g} ms "
              f"(CPU), of which {panda['switching_handed_back_ms']:.3g} ms in the "
              f"{panda['switching_handed_back_steps']:.0f} steps handed back to the Python stepper")
    print_scene(panda)
    for name, r in results.items():
        print(f"{name}: track() {r['track_step_us']:.3g} us per step against Tracker.step() {r['tracker_step_us']:.3g} "
              f"us: ratio {r['track_over_step']:.2f} (target <= 1.3); {r['track_read_over_step']:.2f} with its "
              "diagnostics read")
        print(f"{name}: default-mode predictor misses by {r['predictor_miss_median']:.2g} rad (median, largest "
              f"{r['predictor_miss_max']:.2g}); {r['evals_per_step']:.2f} evaluations per step")
    write_json(args.json, {"robots": results, "keys": KEYS})
    if args.plot is not None:
        write_plot(results, args.plot)


if __name__ == "__main__":
    main()
