"""The one planning pipeline: samples -> candidates -> closed walk -> spline -> tracking -> verification.

Every planner of :mod:`kinredund.planning` is a configuration of it. Steps 1-2 (the candidates at the
samples and the closed walk through them) are the configuration's: :func:`kinredund.planning.cyclic.plan`
(``kr.plan``: the within-limits minima of the user's z, :mod:`.sampling`), the Chapter 6 obstacle planner
:func:`kinredund.planning.planner.plan` (the minima of the obstacle policy, Eq. 6.21/6.44, joined by
:mod:`.branches`' transitions) and :func:`kinredund.planning.roadmap.plan_roadmap` (a roadmap of the self-motion
manifold, Section 6.3). All of them build their candidates from one pool (:class:`~.walk.CandidatePool`), bisect
with one function (:func:`~.walk.bisect_interval`) and hand :func:`finish` the knots of the chosen walk, which runs
the rest the same way for all:

3. **Estimates.** A cubic spline theta*(t) through the knots (:mod:`.spline`, Section 6.2.2.2), periodic
   modulo the walk's whole turns.
4. **Tracking.** The resolved-rate scheme with the time-varying index h = 1/2 ||theta - theta*(t)||^2 and the
   spline's rate as feed-forward (Eqs. 6.23-6.28), with the joint limits as hard constraints and the options'
   scene, if any. A motion that leaves the limits (the spline overshooting a knot held at a limit) gets a knot
   inserted at the worst point of each excursion and is tracked again (at most ``rounds`` times).
5. **Verification** (:mod:`.verify`), independent of the indices: the joint limits at every recorded point,
   the task error with the robot's own FK (:data:`TASK_TOL`), closure after every loop modulo the walk's
   whole turns (:data:`CLOSURE_TOL`), no joint jump; then the configuration's clearance check (a scene's pairs,
   :mod:`.keepout`; or an obstacle, :mod:`.clearance`).
6. **Following z** (:mod:`.follow`, with an index and ``follow``): z's own optimum wherever it is strongly
   stable, the reference only across folds and singular stretches; ``off_optimum`` says where the motion is
   not an optimum of the index.

``progress(done, total, stage)`` follows every planner's stages (one signature).

Units: times [s], joints [rad or m].
"""

from __future__ import annotations

from dataclasses import dataclass, field
from time import perf_counter

import numpy as np

from kinredund.errors import KinredundError, PathError, check_hooks
from kinredund.indices import TimeVaryingReference
from kinredund.model.robot import check_robot
from kinredund.paths import Path
from kinredund.planning.follow import follow_optimum
from kinredund.planning.result import PlanResult, PlanSamples
from kinredund.planning.spline import JointSpline
from kinredund.planning.verify import MotionCheck, verify_motion_on_path, worst_per_excursion
from kinredund.planning.walk import closest_within_limits, target_at
from kinredund.tracking import track

#: a completed plan tracks the path to this [m] (and [rad] for orientation): the default-mode corrector
#: holds the task residual to ~1e-12, so this leaves three orders of round-off headroom
TASK_TOL = 1e-9
#: a completed plan closes to this after every loop [rad or m]: the tracked joints are the optimum of h
#: with a periodic reference, held by the corrector to ~1e-12, so the loop returns to them
CLOSURE_TOL = 1e-10


def check_plan_args(robot, path, progress, meta, planner: str) -> None:
    """Every planner's first checks, before any work: a Robot (OptionError), a closed path (PathError), a callable
    ``progress`` and a dict ``meta`` or None (OptionError)."""
    check_robot(robot)
    if not isinstance(path, Path) or path.period is None:
        raise PathError(f"{planner}() needs a closed path (a kinredund.paths.Path with a period)")
    check_hooks(progress, meta)


@dataclass
class Walk:
    """What steps 1-2 of a configuration hand to :func:`finish`.

    Attributes:
        rows: the knots (t, q, kind, branch), or (t, q, kind, branch, clearance) with a per-link clearance.
        sample_t: the sample times [s]; candidates, objective: per sample the candidates and their index values.
        turns: the joint change over one period of the walk [rad], shape (n,) (zeros: none).
        weights: per sample the policy's (w1, w2), or None.
        off_optimum: the intervals [s] where the walk is not the continuation of one optimum.
        notes: remarks so far.
    """

    rows: list
    sample_t: np.ndarray
    candidates: tuple = ()
    objective: tuple = ()
    turns: np.ndarray | None = None
    weights: np.ndarray | None = None
    off_optimum: tuple = ()
    notes: list | None = None

    def samples(self, nq: int) -> PlanSamples:
        """The :class:`PlanSamples` of the knots as they stand (sorted by time)."""
        self.rows.sort(key=lambda r: r[0])
        rows = self.rows
        clear = [r[4] if len(r) > 4 else None for r in rows]
        clearance = None if all(c is None for c in clear) else np.array(
            [np.full(len(next(c for c in clear if c is not None)), np.nan) if c is None else c for c in clear])
        return PlanSamples(np.array([r[0] for r in rows]), np.array([r[1] for r in rows]).reshape(-1, nq),
                           tuple(r[2] for r in rows), tuple(int(r[3]) for r in rows), np.asarray(self.sample_t, float),
                           tuple(self.candidates), tuple(self.objective), self.turns, clearance, self.weights)


@dataclass
class Stage:
    """How :func:`finish` runs for one plan.

    Attributes:
        robot, inner: the robot and its copy with the limits shrunk by the options' margin.
        path: the path of one period of the joint motion (the user's, run ``cycles`` times); user_path: the user's.
        options: the plan's :class:`~kinredund.planning.options.PlanOptions` (or a subclass).
        index: the index z followed in step 6, or None (the reference all along).
        verify_clearance: ``verify_clearance(trajectory) -> (report, reason)`` of the configuration's obstacle or
            scene ('' when it passes), or None.
        info: the entries of ``Trajectory.meta``; progress: ``progress(done, total, stage)`` or None.
        timings: the stages' wall times [s] so far; t0: the plan's start (``perf_counter``).
        link_names: the links an obstacle's clearance is reported for.
    """

    robot: object
    inner: object
    path: object
    user_path: object
    options: object
    index: object = None
    verify_clearance: object = None
    info: dict | None = None
    progress: object = None
    timings: dict = field(default_factory=dict)
    t0: float = 0.0
    link_names: tuple = ()

    def report(self, done: int, total: int, stage: str) -> None:
        """``progress(done, total, stage)`` when there is one."""
        if self.progress is not None:
            self.progress(done, total, stage)


def verdict(check: MotionCheck) -> str:
    """'' when the verification passes, else what failed (it checks limits, path, closure and jumps)."""
    bad = []
    if check.limit_violation > 0:
        bad.append(f"leaves the joint limits by {check.limit_violation:.3g} (point {check.worst_limit_step})")
    if check.position_error_max > TASK_TOL or check.orientation_error_max > TASK_TOL:
        bad.append(f"misses the path by {check.position_error_max:.3g} m / {check.orientation_error_max:.3g} rad")
    if not check.closure or check.closure_max > CLOSURE_TOL:
        bad.append(f"does not close: {list(check.closure)}")
    if check.jumps:
        bad.append(f"jumps at steps {list(check.jumps)[:6]} (step ratio {check.jump_ratio_max:.3g})")
    return "" if not bad else "the verified motion " + "; ".join(bad)


def _track(st: Stage, walk: Walk, smp: PlanSamples, notes: list):
    """Steps 3-4 once: (spline, reference, trajectory) of the knots, or the failed :class:`PlanResult`."""
    opt, period = st.options, float(st.path.period)
    spl = JointSpline(smp.t, smp.q, period, smp.turns, opt.spline)  # Section 6.2.2.2
    ref = TimeVaryingReference(spl, spl.rate)  # Eqs. (6.23)-(6.25)
    t1 = perf_counter()
    try:
        traj = track(st.robot, st.path, ref, smp.q[0], steps_per_loop=opt.steps_per_loop * opt.cycles,
                     loops=-(-int(opt.loops) // opt.cycles), limits=True, **opt.scene_kw(),
                     progress=None if st.progress is None else lambda d, n: st.progress(d, n, "tracking"),
                     meta=dict(st.info or {}, knots=len(smp.t), cycles=opt.cycles,
                               samples=smp.to_dict()))  # Eqs. (6.26)-(6.28)
    except KinredundError as err:
        st.timings["tracking_s"] = st.timings.get("tracking_s", 0.0) + perf_counter() - t1
        cause = "collision" if getattr(err, "cause", "") == "collision" else "tracking_failed"
        return PlanResult(False, f"the tracking of the planned reference failed: {err}", None, smp,
                          off_optimum=walk.off_optimum, notes=tuple(notes), timings=st.timings,
                          partial=getattr(err, "partial", None), cycles=opt.cycles, cause=cause,
                          link_names=st.link_names)
    st.timings["tracking_s"] = st.timings.get("tracking_s", 0.0) + perf_counter() - t1
    return spl, ref, traj


def _limit_knots(st: Stage, walk: Walk, traj, turns) -> int:
    """Knots inserted at the worst point of each excursion beyond the limits (taken back to the first period,
    less its whole turns); how many."""
    period, added = float(st.path.period), 0
    for k in worst_per_excursion(st.robot, traj.q):
        tk = float(traj.t[k]) % period
        qk = traj.q[k] - (float(traj.t[k]) // period) * turns
        ref_k = np.clip(qk, st.inner.lower, st.inner.upper)
        qk = closest_within_limits(st.inner, target_at(st.robot, st.path, tk), ref_k, seed=qk,
                                   max_iter=st.options.max_iter, fallback=True)
        if qk is not None and all(abs(tk - r[0]) > 1e-9 for r in walk.rows):
            walk.rows.append((tk, qk, "limit", -1))
            added += 1
    return added


def _check(st: Stage, traj, turns) -> MotionCheck:
    per = st.options.steps_per_loop * st.options.cycles
    return verify_motion_on_path(st.robot, st.user_path, traj.t, traj.q, per, turns=turns)


def finish(st: Stage, walk: Walk) -> PlanResult:
    """Steps 3-6 (module docstring) from the knots of the chosen walk."""
    opt = st.options
    notes = list(walk.notes or ())
    for attempt in range(int(opt.rounds) + 1):
        smp = walk.samples(st.robot.nq)
        tracked = _track(st, walk, smp, notes)
        if isinstance(tracked, PlanResult):
            return tracked
        spl, ref, traj = tracked
        check = _check(st, traj, smp.turns)
        if check.limit_violation > 0 and attempt < opt.rounds:
            added = _limit_knots(st, walk, traj, smp.turns)
            if added:
                notes.append(f"{added} knot(s) inserted where the motion left the limits by up to "
                             f"{check.limit_violation:.3g}")
                continue
        break
    reason, off = verdict(check), walk.off_optimum
    if not reason and st.index is not None:  # step 6: z's own optimum wherever it is strongly stable
        traj, check, off = _follow(st, ref, traj, smp.turns, notes)
    clear, cause = None, "verification" if reason else ""
    if st.verify_clearance is not None:
        st.report(0, 1, "clearance")
        t1 = perf_counter()
        clear, why = st.verify_clearance(traj)
        st.timings["clearance_s"] = perf_counter() - t1
        if why:
            reason, cause = "; ".join(filter(None, [why, reason])), "collision"
        st.report(1, 1, "clearance")
    st.timings["total_s"] = perf_counter() - st.t0
    q_spline = spl.values(traj.t)
    return PlanResult(not reason, reason, traj, smp, check, off, tuple(notes), st.timings, None, opt.cycles, cause,
                      clear, q_spline, st.link_names, float(np.abs(traj.q - q_spline).max()))


def _follow(st: Stage, ref, traj, turns, notes):
    """Step 6 (:mod:`.follow`): (trajectory, check, off_optimum) of the motion that follows z wherever it can
    (accepted where it passes the checks, the clearance's too), the notes added to ``notes``."""
    t1, opt = perf_counter(), st.options

    def accept(tr) -> bool:
        if verdict(_check(st, tr, turns)):
            return False
        return st.verify_clearance is None or not st.verify_clearance(tr)[1]

    traj, off, note = follow_optimum(st.robot, st.path, st.index, ref, traj, opt.steps_per_loop * opt.cycles,
                                     -(-int(opt.loops) // opt.cycles), opt.max_jump, accept,
                                     None if st.progress is None else lambda d, n: st.progress(d, n, "following z"),
                                     st.info, enabled=opt.follow, track_kw=opt.scene_kw())
    check = _check(st, traj, turns)
    st.timings["follow_s"] = perf_counter() - t1
    notes += ([note] if note else []) + [
        f"between t = {a:.4g} s and {b:.4g} s the motion follows its reference (a continuous within-limits "
        "path), not z's bounded optimum: that minimum ceases to exist or is not strongly stable there (a fold, a "
        "singular stretch, a clearance held)" for a, b in off]
    return traj, check, off


__all__ = ["CLOSURE_TOL", "TASK_TOL", "Stage", "Walk", "finish", "verdict"]
