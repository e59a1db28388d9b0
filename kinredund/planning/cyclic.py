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
   :func:`kinredund.planning.branches.choose`). Where no such walk exists (a fold of z: the local
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

from dataclasses import dataclass, field
from time import perf_counter
from typing import ClassVar

import numpy as np

from kinredund.errors import KinredundError, PathError, TaskError
from kinredund.indices import Index, TimeVaryingReference
from kinredund.paths import Path
from kinredund.planning.follow import follow_optimum
from kinredund.planning.keepout import ClearanceCheck, verify_clearance, with_clearance
from kinredund.planning.options import PlanOptions
from kinredund.planning.sampling import CandidateSet
from kinredund.planning.spline import JointSpline
from kinredund.planning.stages import PLAN_CAUSES, check_cause
from kinredund.planning.topology import RepeatedPath, orientation_loop_flips
from kinredund.planning.verify import MotionCheck, verify_motion_on_path, worst_per_excursion
from kinredund.planning.walk import (
    closest_within_limits,
    inside_limits,
    off_optimum_intervals,
    shrunk_limits,
    target_at,
    walk_knots,
)
from kinredund.tasks import get_task
from kinredund.tracking import track
from kinredund.trajectory import Trajectory

#: a completed plan tracks the path to this [m] (and [rad] for orientation): the default-mode corrector
#: holds the task residual to ~1e-12, so this leaves three orders of round-off headroom
TASK_TOL = 1e-9
#: a completed plan closes to this after every loop [rad or m]: the tracked joints are the optimum of h
#: with a periodic reference, held by the corrector to ~1e-12, so the loop returns to them
CLOSURE_TOL = 1e-10


@dataclass(frozen=True)
class CyclicSamples:
    """The sample points, their candidates and the chosen walk.

    Attributes:
        t: the times of the spline's knots [s], shape (M,) (the N sample times and the refined ones).
        q: the chosen configurations there, shape (M, n).
        kind: per knot ``optimum`` (a within-limits local minimum of z), ``refined`` (inserted on a
            fold: the configuration closest to its neighbours' mean, not an optimum of z) or ``limit``
            (inserted where a tracked motion left the limits: the within-limits configuration closest to it).
        branch: per knot the chosen candidate's number at its sample (-1 for refined knots).
        sample_t: the N sample times [s].
        candidates: per sample the candidates found, each an array (c_k, n), lowest z first.
        objective: per sample the z of each candidate.
    """

    t: np.ndarray
    q: np.ndarray
    kind: tuple[str, ...]
    branch: tuple[int, ...]
    sample_t: np.ndarray
    candidates: tuple[np.ndarray, ...]
    objective: tuple[np.ndarray, ...]


@dataclass(frozen=True)
class CyclicPlan:
    """The outcome of :func:`plan`.

    Attributes:
        ok: the motion is complete, inside the limits, on the path (``TASK_TOL``), closed after every
            loop (``CLOSURE_TOL``) and without a joint jump, as checked by :mod:`.verify`.
        reason: "" when ok, else why not.
        trajectory: the tracked motion (None when planning stopped before tracking).
        samples: the samples and chosen branches (None when a sample has no candidate).
        check: the independent verification of ``trajectory`` (None without one).
        off_optimum: the time intervals [s] where the motion follows its reference rather than a local
            minimum of z (module docstring); empty when it follows z's optima throughout.
        notes: remarks that are not failures.
        timings: wall times of the stages [s].
        partial: what the tracker returned before it failed, when it failed and gave one.
        cycles: the joint motion repeats every ``cycles`` loops of the path.
        cause: a short machine-readable tag of the failure ("" when ok): ``orientation_loop`` (no closed
            joint path exists for this many cycles, :mod:`.topology`), ``no_minimum`` (a sample without a
            within-limits minimum), ``no_closed_walk``, ``tracking_failed``, ``verification``, ``collision``
            (with a scene: a sample whose minima are all under the clearance, a tracking stopped by a pair, or
            a verified motion under the clearance; the reason names the pair and the time).
        clearance: with a scene, the clearance verification of ``trajectory`` (:mod:`.keepout`), else None.
    """

    ok: bool
    reason: str
    trajectory: Trajectory | None
    samples: CyclicSamples | None
    check: MotionCheck | None
    off_optimum: tuple[tuple[float, float], ...] = ()
    notes: tuple[str, ...] = ()
    timings: dict = field(default_factory=dict)
    partial: Trajectory | None = None
    cycles: int = 1
    cause: str = ""
    clearance: ClearanceCheck | None = None

    #: the failure causes ("" when ok), as TrackingError.CAUSES: one vocabulary with the Chapter 6 planner's
    CAUSES: ClassVar[tuple[str, ...]] = PLAN_CAUSES

    def __post_init__(self) -> None:
        check_cause(self.ok, self.cause)

    def summary(self) -> dict:
        """Scalars and short lists: the figures a report prints."""
        s = self.samples
        return {"ok": self.ok, "reason": self.reason, "cause": self.cause, "cycles": self.cycles,
                "samples": None if s is None else int(s.sample_t.size),
                "knots": None if s is None else int(s.t.size),
                "refined": None if s is None else int(sum(k == "refined" for k in s.kind)),
                "limit_knots": None if s is None else int(sum(k == "limit" for k in s.kind)),
                "candidates": None if s is None else [int(len(c)) for c in s.candidates],
                "off_optimum": [list(iv) for iv in self.off_optimum],
                "check": None if self.check is None else self.check.to_dict(),
                "clearance": None if self.clearance is None else self.clearance.to_dict(),
                "notes": list(self.notes), "timings_s": {k: float(v) for k, v in self.timings.items()}}


def _check_args(robot, path, index) -> None:
    if not isinstance(path, Path) or path.period is None:
        raise PathError("plan() needs a closed path (a kinredund.paths.Path with a period)")
    if not isinstance(index, Index):
        raise TaskError(f"index must be a kinredund.indices.Index, got {type(index).__name__}")
    if robot.nq <= robot.task_dim:
        raise TaskError(f"{robot.name} has {robot.nq} joints for a {robot.task_dim}-D {robot.task!r} task: "
                        "the cyclic planner needs a redundant arm (use robot.with_task('position'))")


def plan(robot, path: Path, index: Index, options: PlanOptions | None = None, *, q0=None, progress=None,
         meta: dict | None = None, **overrides) -> CyclicPlan:
    """Plan a cyclic within-limits joint motion along the closed ``path`` that follows z's optima.

    Args:
        robot: a redundant :class:`kinredund.Robot` (its task kind sets the target: pose, position, planar).
        path: a closed path (with a period); pose tasks need its orientation.
        index: the user's performance index z (:mod:`kinredund.indices`).
        options: the :class:`~kinredund.planning.options.PlanOptions` (samples, starts, seed, loops,
            steps_per_loop, max_jump, margin, max_candidates, budget, rounds, max_iter, cycles); default
            its defaults. ``overrides``: any of those by name (``plan(..., samples=32)``), validated with them.
        q0: a start inside the limits (n,): the walk then starts (and ends) at the within-limits minimum
            of z reached from it at t = 0 (the branch the strict tracker would follow from q0); default
            the shortest closed walk from any candidate.
        The options' ``scene``, ``clearance``, ``self_clearance``: the scene's pairs kept apart (module
            docstring, :mod:`.keepout`).
        The options' ``cycles``: a path whose orientation loop is not contractible (:mod:`.topology`, a task
            holding the whole rotation) admits no within-limits joint path that closes after an odd number
            of loops: the plan then fails at once and says so (with 2 it may exist, though it needs the arm
            to swing wide). The samples cover ``cycles`` loops (N per loop) and the closure is checked after
            every ``cycles`` loops.
        progress: ``progress(done, total)`` during the tracking.
        meta: extra entries for ``Trajectory.meta``.

    Returns:
        A :class:`CyclicPlan`; ``ok=False`` with the reason when a sample has no within-limits minimum,
        no continuous closed walk exists at this sampling resolution, the tracking fails, or the
        verification does not pass.

    Raises:
        PathError, TaskError: an open path, not an index, a non-redundant arm, a q0 outside the limits.
        OptionError: an option outside its range (:class:`~kinredund.planning.options.PlanOptions`), a scene
            of another robot.
    """
    _check_args(robot, path, index)
    opt = PlanOptions.of(options, **overrides)
    opt.check_for(robot)
    keep = opt.keepout_for(robot)
    t0 = perf_counter()
    timings: dict[str, float] = {}
    flips = orientation_loop_flips(path) if get_task(robot.task).holds_rotation else None
    cycles = opt.cycles
    if flips and cycles % 2:
        return CyclicPlan(False, "the path's orientation turns once about an axis per loop (a loop of SO(3) that is "
                          "not contractible), and a joint path inside the limits maps to contractible loops "
                          f"only: no within-limits joint path closes after {cycles} loop(s); plan with an even "
                          "number of cycles (kinredund.planning.topology)", None, None, None,
                          timings={"total_s": perf_counter() - t0}, cycles=cycles,
                          cause="orientation_loop")
    user_path, path = path, (path if cycles == 1 else RepeatedPath(path, cycles))
    first_notes = [f"the joint motion repeats every {cycles} loops of the path"] if cycles > 1 else []
    period = float(path.period)
    n = opt.samples * cycles
    inner = shrunk_limits(robot, opt.margin)
    cands = CandidateSet(inner, path, index, opt, np.arange(n) * period / n, keep)

    # -- step 1: within-limits minima of z at the samples (forward sweep with random starts, backward sweep)
    if q0 is not None:
        q0 = robot.check_q(q0, "q0")
        if not inside_limits(robot, q0):
            raise TaskError(f"q0 must lie inside the joint limits of {robot.name}, got {np.round(q0, 6).tolist()}")
        if not cands.start_from(q0):
            under = cands.under_clearance() and f" that keeps the clearance ({cands.under_clearance()})"
            return CyclicPlan(False, f"no within-limits local minimum of the index{under} was reached from q0 at t = 0",
                              None, None, None, timings={"samples_s": perf_counter() - t0}, cycles=cycles,
                              cause="no_minimum" if cands.rejected is None else "collision")
    missing = cands.collect()
    timings["samples_s"] = perf_counter() - t0
    if missing:
        return CyclicPlan(False, missing, None, None, None, timings=timings, cycles=cycles,
                          cause="collision" if cands.collided else "no_minimum")

    # -- step 2: the shortest closed walk through the candidates, refined where it must be
    t1 = perf_counter()
    choice, refined, costs = cands.refined_walk()
    timings["walk_s"] = perf_counter() - t1
    ts, pools = np.array(cands.ts), cands.pools
    candidates = tuple(np.array(p.q) for p in pools)
    objective = tuple(np.array(p.z) for p in pools)
    if choice is None:
        n = len(ts)
        bad = cands.broken(costs)
        where = f" (no continuous way from t = {ts[bad[0]]:.4g} s to {cands.end(bad[0]):.4g} s)" if bad else ""
        smp = CyclicSamples(np.zeros(0), np.zeros((0, robot.nq)), (), (), ts, candidates, objective)
        return CyclicPlan(False, "no continuous closed walk through the within-limits minima"
                          f"{where} after {cands.added} added sample(s) (refine_samples={opt.refine_samples}, "
                          f"{n} samples in all): the minima followed end in folds that no within-limits "
                          f"self-motion of at most max_jump per knot joins{cands.under_clearance() and '; '}"
                          f"{cands.under_clearance()}", None, smp, None, timings=timings,
                          cycles=cycles, cause="no_closed_walk")
    links = cands.links
    if cands.added:
        first_notes.append(f"{cands.added} sample(s) added where the closed walk broke")
    rows = walk_knots(ts, pools, choice, refined)
    off = off_optimum_intervals(ts, period, pools, choice, links, refined)
    return _track_rounds(robot, inner, path, user_path, cycles, index, rows, ts, candidates, objective, off,
                         first_notes, opt, progress, meta, timings, t0, keep)


def _track_rounds(robot, inner, path, user_path, cycles, index, rows, ts, candidates, objective, off, notes, opt,
                  progress, meta, timings, t0, keep=None) -> CyclicPlan:
    """Steps 3-5 of :func:`plan`: spline, tracking, verification; re-planned with an inserted knot where
    the motion leaves the limits. ``path`` is the user's path run ``cycles`` times (one period of the
    joint motion), ``user_path`` the user's."""
    period = float(path.period)
    loops, rounds, max_iter = opt.loops, opt.rounds, opt.max_iter
    per_cycle = opt.steps_per_loop * cycles
    info = dict(meta or {}, planner="cyclic", index=type(index).__name__)
    for attempt in range(int(rounds) + 1):
        rows.sort(key=lambda r: r[0])
        kt = np.array([r[0] for r in rows])
        kq = np.array([r[1] for r in rows])
        smp = CyclicSamples(kt, kq, tuple(r[2] for r in rows), tuple(int(r[3]) for r in rows), ts, candidates,
                            objective)
        spl = JointSpline(kt, kq, period, np.zeros(robot.nq), "periodic")  # Section 6.2.2.2
        t1 = perf_counter()
        ref = TimeVaryingReference(spl, spl.rate)  # Eqs. (6.23)-(6.25)
        kw = {"limits": True, **opt.scene_kw()}
        try:
            traj = track(robot, path, ref, kq[0], steps_per_loop=per_cycle, loops=-(-int(loops) // cycles),
                         progress=progress, meta=dict(info, knots=len(kt), cycles=cycles), **kw)  # Eqs. (6.26)-(6.28)
        except KinredundError as err:
            timings["tracking_s"] = timings.get("tracking_s", 0.0) + perf_counter() - t1
            partial = getattr(err, "partial", None)
            cause = "collision" if getattr(err, "cause", "") == "collision" else "tracking_failed"
            return CyclicPlan(False, f"the tracking of the planned reference failed: {err}", None, smp, None, off,
                              tuple(notes), timings, partial, cycles, cause)
        timings["tracking_s"] = timings.get("tracking_s", 0.0) + perf_counter() - t1
        check = verify_motion_on_path(robot, user_path, traj.t, traj.q, per_cycle)
        if check.limit_violation > 0 and attempt < rounds:
            added = 0
            for k in worst_per_excursion(robot, traj.q):
                tk = float(traj.t[k]) % period
                ref_k = np.clip(traj.q[k], inner.lower, inner.upper)
                qk = closest_within_limits(inner, target_at(robot, path, tk), ref_k, seed=traj.q[k],
                                           max_iter=max_iter, fallback=True)
                if qk is not None and all(abs(tk - r[0]) > 1e-9 for r in rows):
                    rows.append((tk, qk, "limit", -1))
                    added += 1
            if added:
                notes.append(f"{added} knot(s) inserted where the motion left the limits by up to "
                             f"{check.limit_violation:.3g}")
                continue
        break
    reason = _verdict(check)
    if not reason:  # step 6: z's own optimum wherever it is strongly stable (planning.follow)
        traj, check, off = _follow(robot, path, user_path, index, ref, traj, per_cycle, opt, progress, info, notes,
                                   timings, keep)
    cause = "verification" if reason else ""
    clear = None
    if keep is not None and traj is not None:  # the clearance at and between the recorded points (planning.keepout)
        t1 = perf_counter()
        clear = verify_clearance(keep, traj.t, traj.q)
        timings["clearance_s"] = perf_counter() - t1
        if not clear.ok:
            reason, cause = "; ".join(filter(None, [clear.reason(), reason])), "collision"
    timings["total_s"] = perf_counter() - t0
    return CyclicPlan(not reason, reason, traj, smp, check, off, tuple(notes), timings, None, cycles, cause, clear)


def _follow(robot, path, user_path, index, ref, traj, per_cycle, opt, progress, info, notes, timings, keep):
    """Step 6 of :func:`plan` (:mod:`.follow`): (trajectory, check, off_optimum) of the motion that follows z
    wherever it can (accepted where it passes the checks, the clearance's too), the notes added to ``notes``."""
    t1 = perf_counter()
    accept = with_clearance(lambda tr: not _verdict(verify_motion_on_path(robot, user_path, tr.t, tr.q, per_cycle)),
                            keep)
    traj, off, note = follow_optimum(robot, path, index, ref, traj, per_cycle, -(-int(opt.loops) // opt.cycles),
                                     opt.max_jump, accept, progress, info, enabled=opt.follow,
                                     track_kw=opt.scene_kw())
    check = verify_motion_on_path(robot, user_path, traj.t, traj.q, per_cycle)
    timings["follow_s"] = perf_counter() - t1
    notes += ([note] if note else []) + [
        f"between t = {a:.4g} s and {b:.4g} s the motion follows its reference (a continuous within-limits "
        "path), not z's bounded optimum: that minimum ceases to exist or is not strongly stable there (a fold, a "
        "singular stretch, a clearance held)" for a, b in off]
    return traj, check, off


def _verdict(check: MotionCheck) -> str:
    """'' when the verification passes, else what failed."""
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


__all__ = ["CLOSURE_TOL", "TASK_TOL", "CyclicPlan", "CyclicSamples", "plan"]
