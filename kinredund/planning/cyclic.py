"""A cyclic, within-limits joint path for any arm and any closed path (Chapter 6's procedure, generalised).

:func:`plan` runs the thesis's off-line procedure of Section 6.2.2 with the user's own index z in place
of the obstacle policy, and the joint limits as hard bounds:

1. **Samples.** The path is sampled at N equally spaced times. At each sample the within-limits local
   minima of z on g(theta) = x(t_k) (Eq. 4.3 with the bounds; Eq. D.33 with the active limits) are
   found by the joint-level IK :func:`kinredund.ik.solve_ik` with ``bounds=True``: continued from the
   previous sample's minima (a forward sweep, then a backward one) and from random starts inside the
   limits. Every distinct minimum is a candidate: a *branch*.
2. **Branch choice.** One candidate per sample, so that consecutive choices are continuous and the
   sequence closes: the shortest closed walk through the layered candidate graph, with the joint
   distance ||q_b - q_a|| as the edge cost and an edge only where no joint moves by more than
   ``max_jump`` (dynamic programming over the start candidate,
   :func:`kinredund.planning.walk.choose`). Where no such walk exists (a fold of z: the local
   minimum followed ceases to exist and the remaining one is far away) the interval is *refined*: at
   its middle time the within-limits configuration on the path closest to the mean of its ends
   (the index of Eq. 6.25) is inserted, recursively, until every jump is below ``max_jump``.
3. **Estimates.** A periodic cubic spline theta*(t) through the chosen samples (:mod:`.spline`, Section
   6.2.2.2).
4. **Tracking.** The resolved-rate scheme with the time-varying index h = 1/2 ||theta - theta*(t)||^2
   and the spline's rate as feed-forward (Eqs. 6.23-6.28), ``loops`` loops, with the joint limits as
   hard constraints (``track(..., limits=True)``).
5. **Verification** (:mod:`.verify`): joint limits at every recorded point, the task error with the
   robot's own FK, closure after each loop, no joint jump. A motion that leaves the limits (the spline
   overshooting a sample held at a limit) gets a knot inserted at the worst point of each excursion and
   is tracked again (at most ``rounds`` times).

The samples are solved inside the limits shrunk by ``margin`` [rad or m]: between samples the tracked
joints follow the spline, which may overshoot a value held at a limit by a little; the margin keeps
that overshoot inside the real limits (the verification checks the real ones).

6. **Following z** (:mod:`.follow`, ``follow=True``): the verified reference motion is measured by an
   independent bounded solve of z at every recorded point; the index tracked becomes z itself wherever
   its bounded optimum exists near the motion and is strongly stable, the reference only across folds
   and singular stretches (a C^2 blend between them), and the blended motion replaces the reference
   motion when it passes the same verification. ``off_optimum`` and ``notes`` say exactly where the
   motion is not z's bounded optimum (measured: outside those intervals an independent solve from the
   planned configuration does not move it).

Where no closed walk exists at the sampling, sample times are added in the middle of the intervals the
walk cannot cross (:mod:`.sampling`, at most ``refine_samples``) before the plan says why. The options
are one validated :class:`~kinredund.planning.options.PlanOptions`; the causes of a failed plan are
:attr:`CyclicPlan.CAUSES`. A collision scene (options ``scene``, ``clearance``, ``self_clearance``) is held in
the candidates, the tracking and the verification, at and between the recorded points (:mod:`.keepout`); a
motion under a clearance fails with cause ``collision`` naming the pair and the time.

A pose path whose orientation turns once about an axis per loop (a circle's Frenet frame) admits no
within-limits joint path that closes after one loop (:mod:`.topology`); :func:`plan` says so at once, and
plans a joint motion that repeats every two loops when asked (``cycles=2``).

Joint values are taken as they are (no wrapping by whole turns): a motion inside the limits cannot gain
a turn on a joint whose range is under one turn, and on wider joints (the xArm7's +-2 pi) the two
representations of an angle are different candidates.

Units: times [s], joints [rad or m], positions [m].
"""

from __future__ import annotations

from time import perf_counter

import numpy as np

from kinredund.errors import TaskError
from kinredund.indices import Index
from kinredund.paths import Path
from kinredund.planning.keepout import verify_clearance
from kinredund.planning.options import PlanOptions
from kinredund.planning.pipeline import CLOSURE_TOL, TASK_TOL, Stage, Walk, check_plan_args, finish
from kinredund.planning.result import PlanResult, PlanSamples
from kinredund.planning.sampling import CandidateSet
from kinredund.planning.topology import RepeatedPath, orientation_loop_flips
from kinredund.planning.walk import inside_limits, off_optimum_intervals, shrunk_limits, walk_knots
from kinredund.tasks import get_task

#: ``kr.CyclicPlan``: the pipeline's one result (:class:`~kinredund.planning.result.PlanResult`)
CyclicPlan = PlanResult
#: the pipeline's one sample record (:class:`~kinredund.planning.result.PlanSamples`)
CyclicSamples = PlanSamples


def _check_args(robot, path, index, progress, meta) -> None:
    check_plan_args(robot, path, progress, meta, "plan")
    if not isinstance(index, Index):
        raise TaskError(f"index must be a kinredund.indices.Index, got {type(index).__name__}")
    if robot.nq <= robot.task_dim:
        raise TaskError(f"{robot.name} has {robot.nq} joints for a {robot.task_dim}-D {robot.task!r} task: "
                        "the cyclic planner needs a redundant arm (use robot.with_task('position'))")


def plan(robot, path: Path, index: Index, options: PlanOptions | None = None, *, q0=None, progress=None,
         meta: dict | None = None, **overrides) -> PlanResult:
    """Plan a cyclic within-limits joint motion along the closed ``path`` that follows z's optima.

    Args:
        robot: a redundant :class:`kinredund.Robot` (its task kind sets the target: pose, position, planar, axis).
        path: a closed path (with a period); pose and axis tasks need its orientation.
        index: the user's performance index z (:mod:`kinredund.indices`).
        options: the :class:`~kinredund.planning.options.PlanOptions` (samples, starts, seed, loops,
            steps_per_loop, max_jump, margin, max_candidates, budget, refine_samples, rounds, max_iter, cycles,
            follow, scene, clearance, self_clearance, spline); default its defaults. ``overrides``: any of those
            by name (``plan(..., samples=32)``), validated with them. A scene's pairs are kept apart (:mod:`.keepout`);
            ``cycles``: a path whose orientation loop is not contractible (:mod:`.topology`) admits no within-limits
            joint path that closes after an odd number of loops: the plan then fails at once and says so.
        q0: a start inside the limits (n,): the walk then starts (and ends) at the within-limits minimum
            of z reached from it at t = 0; default the shortest closed walk from any candidate.
        progress: ``progress(done, total, stage)`` (the pipeline's one signature).
        meta: extra entries for ``Trajectory.meta``.

    Returns:
        A :class:`~kinredund.planning.result.PlanResult`; ``ok=False`` with the reason and cause when a sample has
        no within-limits minimum, no continuous closed walk exists, the tracking fails, or the verification fails.

    Raises:
        PathError, TaskError: an open path, not an index, a non-redundant arm, a q0 outside the limits.
        OptionError: an option outside its range (:class:`~kinredund.planning.options.PlanOptions`), a scene
            of another robot, ``robot`` not a Robot, a ``progress`` that is not callable, a ``meta`` that is not a
            dict.
    """
    _check_args(robot, path, index, progress, meta)
    opt = PlanOptions.of(options, **overrides)
    opt.check_for(robot)
    keep = opt.keepout_for(robot)
    t0 = perf_counter()
    flips = orientation_loop_flips(path) if get_task(robot.task).holds_rotation else None
    if flips and opt.cycles % 2:
        return PlanResult(False, "the path's orientation turns once about an axis per loop (a loop of SO(3) that is "
                          "not contractible), and a joint path inside the limits maps to contractible loops "
                          f"only: no within-limits joint path closes after {opt.cycles} loop(s); plan with an even "
                          "number of cycles (kinredund.planning.topology)", timings={"total_s": perf_counter() - t0},
                          cycles=opt.cycles, cause="orientation_loop")
    user_path, path = path, (path if opt.cycles == 1 else RepeatedPath(path, opt.cycles))
    verify = None if keep is None else (lambda tr: (c := verify_clearance(keep, tr.t, tr.q), c.reason()))
    st = Stage(robot, shrunk_limits(robot, opt.margin), path, user_path, opt, index, verify,
               dict(meta or {}, planner="cyclic", index=type(index).__name__), progress, {}, t0)
    walk = _candidates_and_walk(st, q0, keep)
    return walk if isinstance(walk, PlanResult) else finish(st, walk)


def _candidates_and_walk(st: Stage, q0, keep) -> Walk | PlanResult:
    """Steps 1-2 (:mod:`.sampling`): the within-limits minima of z at the samples (a forward sweep with random
    starts, a backward sweep) and the shortest closed walk through them, refined where it breaks."""
    robot, opt, timings, t0 = st.robot, st.options, st.timings, st.t0
    period, n = float(st.path.period), opt.samples * opt.cycles
    cands = CandidateSet(st.inner, st.path, st.index, opt, np.arange(n) * period / n, keep)
    st.report(0, 1, "samples")
    if q0 is not None:
        q0 = robot.check_q(q0, "q0")
        if not inside_limits(robot, q0):
            raise TaskError(f"q0 must lie inside the joint limits of {robot.name}, got {np.round(q0, 6).tolist()}")
        if not cands.start_from(q0):
            under = cands.under_clearance() and f" that keeps the clearance ({cands.under_clearance()})"
            return PlanResult(False, f"no within-limits local minimum of the index{under} was reached from q0 at "
                              "t = 0", timings={"samples_s": perf_counter() - t0}, cycles=opt.cycles,
                              cause="no_minimum" if cands.rejected is None else "collision")
    missing = cands.collect()
    timings["samples_s"] = perf_counter() - t0
    if missing:
        return PlanResult(False, missing, timings=timings, cycles=opt.cycles,
                          cause="collision" if cands.collided else "no_minimum")
    t1 = perf_counter()
    st.report(0, 1, "closed walk")
    choice, refined, costs = cands.refined_walk()
    timings["walk_s"] = perf_counter() - t1
    ts, pools = np.array(cands.ts), cands.pools
    candidates, objective = tuple(np.array(p.q) for p in pools), tuple(np.array(p.z) for p in pools)
    if choice is None:
        bad = cands.broken(costs)
        where = f" (no continuous way from t = {ts[bad[0]]:.4g} s to {cands.end(bad[0]):.4g} s)" if bad else ""
        smp = PlanSamples(np.zeros(0), np.zeros((0, robot.nq)), (), (), ts, candidates, objective)
        return PlanResult(False, "no continuous closed walk through the within-limits minima"
                          f"{where} after {cands.added} added sample(s) (refine_samples={opt.refine_samples}, "
                          f"{len(ts)} samples in all): the minima followed end in folds that no within-limits "
                          f"self-motion of at most max_jump per knot joins{cands.under_clearance() and '; '}"
                          f"{cands.under_clearance()}", None, smp, timings=timings, cycles=opt.cycles,
                          cause="no_closed_walk")
    notes = ([f"the joint motion repeats every {opt.cycles} loops of the path"] if opt.cycles > 1 else []) + \
        ([f"{cands.added} sample(s) added where the closed walk broke"] if cands.added else [])
    return Walk(walk_knots(ts, pools, choice, refined), ts, candidates, objective,
                off_optimum=off_optimum_intervals(ts, period, pools, choice, cands.links, refined), notes=notes)


__all__ = ["CLOSURE_TOL", "TASK_TOL", "CyclicPlan", "CyclicSamples", "plan"]
