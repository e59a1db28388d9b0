"""The off-line planner of Section 6.2.2: samples, spline, resolved-rate tracking, clearance check.

:func:`plan` runs the thesis's three steps and then checks the result independently:

1. **Samples** (Section 6.2.2.1): at each sample time the end-point target is solved at joint level,
   min z s.t. g(theta) = x (Eqs. 6.21-6.22 or 6.43-6.44), with the policy index of
   :mod:`kinredund.planning.policy` and :func:`kinredund.ik.solve_ik`, from many seeds. Every distinct
   local minimum (positive-definite reduced Hessian, Eq. D.33) whose links clear the obstacle is a
   candidate. The *branch* is the planner's choice (the thesis leaves it to the planner's expertise):
   among the candidates, a cyclic dynamic programme picks the sequence with the smallest sum of
   squared joint jumps between consecutive samples (closing the loop), so the arm changes branch only
   where it has to. ``seeds`` forces candidates (e.g. a branch) at chosen samples. Where no closed walk
   exists, samples are inserted in the intervals the walk cannot cross (at most ``refine_samples``).
2. **Estimates** (Section 6.2.2.2): a cubic spline through the samples (:mod:`.spline`).
3. **Tracking** (Section 6.2.2.3): the resolved-rate scheme of Chapter 4 with the time-varying index
   h = 1/2 ||theta - theta*(t)||^2 and the spline's rate as feed-forward (Eqs. 6.23-6.28), through
   :func:`kinredund.tracking.track` with the joint limits held: the tracked joints are the constrained
   optimum of h at each time, so where the branch switch happens is found by the tracking itself.
4. **Verification**: the pipeline's (:func:`kinredund.planning.pipeline.finish`, as every plan's: the limits
   at every recorded point, the path, closure after every loop modulo the walk's whole turns, no jump), then
   the obstacle's (:mod:`.clearance`): every link against the obstacle along the whole tracked motion, finer
   than the tracking steps. A plan that fails either, with any penetration or with a certified clearance that
   is not positive, is returned with ``ok=False``, the reason and the cause.

Steps 2-4 are the planning pipeline's (:mod:`kinredund.planning.pipeline`), configured here by the policy's
candidates and transitions (:class:`~kinredund.planning.options.ObstacleOptions`).

A fact about the planar case that the thesis does not mention: a planar arm whose end point goes once
around a convex obstacle and whose joints come back to their start sweeps over *every* point of the
obstacle at some time. (For an interior point x, the chain from the base to P, deformed continuously
over the loop, would otherwise be a null-homotopy in the plane minus x of the loop traced by P, which
winds once around x.) So no planar plan of Section 6.2 is collision-free; :func:`plan` says so in the
reason when it finds the penetration. In space an arm can pass over the top of a finite cylinder, and
the spatial case (Section 6.3) can be collision-free.

Units: times [s], joints [rad or m], lengths [m].
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from time import perf_counter

import numpy as np

from kinredund.errors import TaskError
from kinredund.indices import Index
from kinredund.paths import Path
from kinredund.planning.branches import candidates, entries, transition
from kinredund.planning.clearance import link_model, tool_tip_length, verify_motion, winding
from kinredund.planning.obstacles import Obstacle
from kinredund.planning.options import ObstacleOptions
from kinredund.planning.pipeline import Stage, Walk, check_plan_args, finish
from kinredund.planning.policy import PlanarPolicy, SpatialPolicy
from kinredund.planning.result import PlanResult
from kinredund.planning.walk import choose, shrunk_limits, target_at
from kinredund.tasks import get_task

#: (w1 [m^2], w2) of Eq. (6.21): the thesis's example values for sample point S5
DEFAULT_WEIGHTS = (1e-3, 1.0)

PolicyFactory = Callable[[object, Obstacle, np.ndarray, tuple], Index]


def default_policy(robot, obstacle: Obstacle, normal: np.ndarray, weights) -> Index:
    """The thesis's policy index for this robot: Eq. (6.21) for a planar 3R, Eq. (6.44) for a spatial arm.

    Raises:
        TaskError: a robot for which the thesis gives no policy (give ``policy=`` to :func:`plan`).
    """
    task = get_task(robot.task)
    if task.planar:
        hd = robot.hd
        if hd is None or hd.n != 3 or np.any(np.abs(hd.alpha) > 1e-12) or np.any(hd.b != 0) or hd.kinds != "RRR":
            raise TaskError("the planar policy (Eq. 6.21) needs a planar 3R arm built from an HD table; "
                            "give plan(..., policy=...) for other arms")
        return PlanarPolicy(obstacle, float(hd.a[0]), normal, weights, theta0=hd.theta0)
    if not task.has_orientation:
        pair = link_model(robot).pairs[-1]
        return SpatialPolicy(robot, obstacle, normal, link=(int(pair[0]), int(pair[1])), weights=weights)
    raise TaskError(f"plan() needs a planar or position task, got {robot.task!r} (use robot.with_task('position'))")


@dataclass(frozen=True)
class WristReach:
    """Whether the spatial policy's last link can lie along the normal at each target (Eq. 6.44).

    With the last link (length l) along the outward normal n at P, its joint sits at the wrist point
    W = P + l n, which the links before it must reach from the last joint origin that no joint moves
    (O2 for the P-15 architecture): ``|W - O| <= reach``, the chain length from O to W's joint.

    Attributes:
        origin: the fixed joint origin O [m], shape (3,).
        reach: the chain length from O to the last link's joint [m].
        wrist: the points W [m], shape (N, 3).
        distance: |W - O| [m], shape (N,).
        margin: reach - |W - O| [m], shape (N,) (negative: W out of reach).
        end_margin: reach + l - |P - O| [m], shape (N,) (negative: P itself out of reach).
    """

    origin: np.ndarray
    reach: float
    wrist: np.ndarray
    distance: np.ndarray
    margin: np.ndarray
    end_margin: np.ndarray


def wrist_reach(robot, points, normals, link=None) -> WristReach | None:
    """The :class:`WristReach` of the targets ``points`` (N, 3) with outward normals ``normals`` (N, 3).

    Args:
        robot: a spatial arm with revolute joints (None is returned for other arms).
        points, normals: the end-point targets [m] and the obstacle's outward unit normals there.
        link: the joint-origin indices (i, j) of the last link; default the last link of
            :func:`~kinredund.planning.clearance.link_model`.
    """
    if not np.all(robot.revolute):
        return None
    model = link_model(robot)
    i, j = (int(v) for v in (model.pairs[-1] if link is None else link))
    rng = np.random.default_rng(0)
    qs = [np.asarray(robot.home, float)] + [rng.uniform(-np.pi, np.pi, robot.nq) for _ in range(2)]
    pts = np.array([robot.kinematics.joint_origins(q) for q in qs])
    fixed = [m for m in range(i + 1) if np.abs(pts[:, m] - pts[0, m]).max() < 1e-9]
    o = int(fixed[-1])
    origin = pts[0, o]
    reach = float(np.linalg.norm(np.diff(pts[0, o:i + 1], axis=0), axis=1).sum())
    length = float(np.linalg.norm(pts[0, j] - pts[0, i]))
    p = np.asarray(points, float).reshape(-1, 3)
    n = np.asarray(normals, float).reshape(-1, 3)
    w = p + length * n
    dist = np.linalg.norm(w - origin, axis=1)
    end = reach + length - np.linalg.norm(p - origin, axis=1)
    return WristReach(origin, reach, w, dist, reach - dist, end)


def _reach_reason(wr: WristReach, ts, ps, names) -> str:
    """The failure reason of :func:`plan` for a :class:`WristReach` with a negative margin."""
    o = np.round(wr.origin, 4).tolist()
    if wr.end_margin.min() < 0:
        k = int(np.argmin(wr.end_margin))
        return (f"sample S{k + 1} (t = {ts[k]:.4g} s, p = {np.round(ps[k], 4).tolist()}) is out of reach: "
                f"{-wr.end_margin[k]:.4g} m beyond the arm's reach from {o}")
    bad = np.flatnonzero(wr.margin < 0)
    k = int(np.argmin(wr.margin))
    return (f"the last link ({names[-1]}) cannot lie along the obstacle's normal (Eq. 6.44) at "
            f"{bad.size} of {len(ts)} samples: at S{k + 1} (t = {ts[k]:.4g} s, p = {np.round(ps[k], 4).tolist()}) "
            f"its joint W = P + l n = {np.round(wr.wrist[k], 4).tolist()} is {wr.distance[k]:.4g} m from the "
            f"fixed joint origin {o}, {-wr.margin[k]:.4g} m beyond the reach {wr.reach:.4g} m of the links "
            "before it, so the policy's optima cannot be met there; plan with a policy of your own "
            "(policy=...), a larger arm, or, for the P-15 layout, kinredund.planning.roadmap.plan_roadmap, which "
            "chooses the branch on the self-motion manifold (Section 6.3 plans that way at scale 8)")


def check_obstacle_args(robot, path, obstacle, progress, meta, planner: str) -> None:
    """The checks of an obstacle plan's arguments (:func:`plan`'s and the roadmap's), before any work: every
    planner's (:func:`~kinredund.planning.pipeline.check_plan_args`), then an
    :class:`~kinredund.planning.obstacles.Obstacle` (TaskError)."""
    check_plan_args(robot, path, progress, meta, planner)
    if not isinstance(obstacle, Obstacle):
        raise TaskError(f"obstacle must be a kinredund.planning Obstacle, got {type(obstacle).__name__}")


def obstacle_stage(robot, path, obstacle: Obstacle, opt: ObstacleOptions, *, planner: str, progress, meta,
                   t0: float, timings: dict, notes=()) -> tuple[Stage, float]:
    """The pipeline's :class:`~kinredund.planning.pipeline.Stage` of an obstacle plan (this planner's and the
    roadmap's) and the tool tip [m]: the obstacle's clearance verified along the motion (:mod:`.clearance`,
    finer than the tracking steps), the obstacle and the links in the record's meta."""
    model = link_model(robot)
    names, tool_tip = model.names, tool_tip_length(model, opt.tool_tip)

    def verify(traj):
        rep = verify_motion(robot, obstacle, traj.t, traj.q, substeps=opt.substeps, radius=opt.link_radius,
                            tool_tip=tool_tip, check_doubling=opt.check_doubling, path=path)
        return rep, _contact_reason(robot, path, obstacle, rep, names)

    info = {"planner": planner, "obstacle": obstacle.to_dict(), "spline": opt.spline, "links": list(names),
            "link_lengths": model.lengths.tolist(), "link_radius": float(opt.link_radius),
            "tool_tip": float(tool_tip), **(meta or {})}
    st = Stage(robot, shrunk_limits(robot, opt.margin), path, path, opt, None, verify, info, progress, timings, t0,
               names)
    return st, tool_tip


def _contact_reason(robot, path, obstacle, rep, names) -> str:
    """'' when the verified motion clears the obstacle, else where it touches or penetrates it."""
    if rep.collision_free:
        return ""
    parts = [f"{nm} for t in [{a:.4g}, {b:.4g}] s (depth {d:.3g} m)" for nm, a, b, d in rep.intervals()[:6]]
    if not parts:
        k = int(np.argmin(rep.lower_bound))
        parts.append(f"{names[k]}: certified clearance {rep.lower_bound[k]:.3g} m is not positive")
    reason = "the motion touches or penetrates the obstacle: " + "; ".join(parts)
    if get_task(robot.task).planar and abs(winding(path, obstacle, float(path.period))) > 0.5:
        reason += (" - unavoidable here: a planar arm whose end point goes around a convex obstacle and "
                   "whose joints return to their start sweeps over every point of the obstacle "
                   "(see kinredund.planning.planner)")
    return reason


def _sample_candidates(st: Stage, obstacle, ts, tool_tip, counter) -> list | tuple[str, str]:
    """Step 1: the pool of collision-free local minima of the policy at every sample, or (cause, reason) where
    a sample has none (``check_reach``: the wrist-reach screen of the default policy)."""
    robot, path, opt = st.robot, st.path, st.options
    rng = np.random.default_rng(opt.seed)
    lo, hi = robot.sample_box()
    model = link_model(robot)
    ps = np.array([path(t).p for t in ts])
    if not get_task(robot.task).planar and not get_task(robot.task).has_orientation:
        wr = wrist_reach(robot, ps, obstacle.normal_at(ps))
        screen = opt.check_reach and opt.policy is None
        if wr is not None and (wr.end_margin.min() < 0 or (screen and wr.margin.min() < 0)):
            return "out_of_reach", _reach_reason(wr, ts, ps, model.names)
    pools, seeds, weights = [], dict(opt.seeds or {}), opt.weights_per_sample()
    for k, (t, p) in enumerate(zip(ts, ps, strict=True)):
        st.report(k, len(ts), "samples")
        index = (opt.policy or default_policy)(robot, obstacle, obstacle.normal_at(p), tuple(weights[k]))
        user = seeds.get(k)
        user = [] if user is None else ([user] if np.ndim(user) == 1 else list(user))
        seed_qs = [robot.check_q(s, f"seed of sample {k + 1}") for s in user]
        seed_qs += list(pools[-1].q) if pools else []
        seed_qs += [rng.uniform(lo, hi) for _ in range(int(opt.starts))]
        found = candidates(robot, index, target_at(robot, path, t), seed_qs, model, obstacle, opt.link_radius,
                           tool_tip, opt.max_iter, limit=opt.max_candidates, counter=counter)
        if not len(found):
            return "no_minimum", (
                f"sample S{k + 1} (t = {t:.4g} s, p = {np.round(p, 4).tolist()}) has no collision-free "
                f"configuration at a local minimum of the policy ({len(seed_qs)} seeds): the point may be out of "
                "reach, or the obstacle too large for the arm")
        pools.append(found)
    return pools


def _interval(st: Stage, obstacle, ts, pools, tool_tip, k: int) -> list:
    """The transitions (:func:`~kinredund.planning.branches.transition`) from every candidate of sample k to every
    candidate of the next (sample 0 after the last)."""
    robot, path, opt = st.robot, st.path, st.options
    n, model = len(ts), link_model(robot)
    tb = ts[k + 1] if k + 1 < n else float(path.period)
    return [[transition(robot, path, ts[k], a, tb, b, model=model, obstacle=obstacle, radius=opt.link_radius,
                        tool_tip=tool_tip, max_jump=opt.max_jump if opt.refine else np.inf, budget=opt.budget,
                        max_iter=opt.max_iter) for b in entries(pools[(k + 1) % n])] for a in entries(pools[k])]


def _insert_sample(st: Stage, obstacle, ts, pools, weights, trans, k: int, tool_tip, counter, rng) -> bool:
    """A sample in the middle of interval k (its weights those of sample k), its candidates from both neighbours'
    and from random seeds, and the transitions of its two intervals; False (nothing inserted) where it has none."""
    robot, path, opt, n = st.robot, st.path, st.options, len(ts)
    tm = 0.5 * (ts[k] + (ts[k + 1] if k + 1 < n else float(path.period)))
    p = path(tm).p
    index = (opt.policy or default_policy)(robot, obstacle, obstacle.normal_at(p), tuple(weights[k]))
    seeds = list(pools[k].q) + list(pools[(k + 1) % n].q) + [rng.uniform(*robot.sample_box())
                                                              for _ in range(opt.starts)]
    found = candidates(robot, index, target_at(robot, path, tm), seeds, link_model(robot), obstacle,
                       opt.link_radius, tool_tip, opt.max_iter, limit=opt.max_candidates, counter=counter)
    if not len(found):
        return False
    ts.insert(k + 1, tm)
    pools.insert(k + 1, found)
    weights.insert(k + 1, weights[k])
    trans[k] = _interval(st, obstacle, ts, pools, tool_tip, k)
    trans.insert(k + 1, _interval(st, obstacle, ts, pools, tool_tip, k + 1))
    return True


def _closed_walk(st: Stage, obstacle, ts, pools, weights, tool_tip, counter) -> tuple:
    """Step 2: (choice, transitions, samples added) of the cheapest closed walk, choice None where there is none;
    where the walk breaks, samples are inserted in the middle of the intervals it cannot cross (those without a
    continuous transition; else those where a candidate has none onward), within ``refine_samples``."""
    trans, added, rng = [], 0, np.random.default_rng([st.options.seed, 1])
    for k in range(len(ts)):
        st.report(k, len(ts), "transitions")
        trans.append(_interval(st, obstacle, ts, pools, tool_tip, k))
    while True:
        costs = [np.array([[tr.cost for tr in row] for row in mat]) for mat in trans]
        choice, total = choose(costs)
        if choice is not None and np.isfinite(total):
            return choice, trans, added
        n, room = len(ts), st.options.refine_samples - added
        bad = [k for k in range(n) if not np.isfinite(costs[k]).any()] or [
            k for k in range(n) if not np.isfinite(costs[k]).any(axis=1).all()]
        inserted = [k for k in sorted(bad, reverse=True)[:max(room, 0)]
                    if _insert_sample(st, obstacle, ts, pools, weights, trans, k, tool_tip, counter, rng)]
        if not inserted:
            return None, bad, added
        added += len(inserted)


def _walk(st: Stage, obstacle, ts, pools, tool_tip, counter) -> Walk | str:
    """Step 2 (:func:`_closed_walk`) and the knots of the chosen walk (whole turns accumulated), or why there is
    no closed walk."""
    robot, opt, period = st.robot, st.options, float(st.path.period)
    ts, weights = list(ts), [tuple(w) for w in opt.weights_per_sample()]
    choice, trans, added = _closed_walk(st, obstacle, ts, pools, weights, tool_tip, counter)
    if choice is None:
        where = f" (none from t = {ts[trans[0]]:.4g} s to the next sample)" if trans else ""
        return (f"no cyclic sequence of sample configurations with continuous transitions{where} after {added} "
                f"added sample(s) (refine_samples={opt.refine_samples}, {len(ts)} samples in all): raise "
                "refine_samples or the transitions' budget, or give other sample times")
    n = len(ts)
    rows, notes, acc = [], [f"{added} sample(s) added where the closed walk broke"] if added else [], np.zeros(robot.nq)
    for k in range(n):
        i = choice[k]
        rows.append((ts[k], pools[k].q[i] + acc, "optimum", i, pools[k].data[i]))
        tr = trans[k][i][choice[(k + 1) % n]]
        rows += [(tm, qm + acc, "refined", -1, cm) for (tm, qm), cm in zip(tr.points, tr.clearance, strict=True)]
        acc = acc + tr.shift
        if tr.min_clearance <= 0:
            notes.append(f"the transition between S{k + 1} and S{(k + 1) % n + 1} is not collision-free at its "
                         f"refined points (worst clearance {tr.min_clearance:.3g} m)")
    return Walk(rows, np.array(ts), tuple(np.array(p.q) for p in pools), tuple(np.array(p.z) for p in pools), acc,
                np.array(weights), ((0.0, period),), notes)


def plan(robot, path: Path, obstacle: Obstacle, options: ObstacleOptions | None = None, *, progress=None,
         meta: dict | None = None, **overrides) -> PlanResult:
    """Plan a collision-free cyclic motion of the end point along a closed path on the obstacle: the planning
    pipeline (:mod:`kinredund.planning.pipeline`) configured with the thesis's policy (module docstring).

    Args:
        robot: a planar robot (task ``planar``) or a spatial arm with a ``position`` task.
        path: a closed path (with a ``period``) on the obstacle's boundary.
        obstacle: an :class:`~kinredund.planning.obstacles.Obstacle`.
        options: the :class:`~kinredund.planning.options.ObstacleOptions` (samples or their times, weights,
            policy, seeds, starts, seed, spline, steps_per_loop, substeps, link_radius, tool_tip, check_doubling,
            refine, max_jump, budget, max_candidates, max_iter, check_reach, ...); ``overrides``: any of them by
            name (``plan(..., samples=12)``), validated with them.
        progress: ``progress(done, total, stage)``.
        meta: extra entries for ``Trajectory.meta``.

    Returns:
        A :class:`~kinredund.planning.result.PlanResult`; ``ok=False`` with the reason and cause when a sample has
        no collision-free solution, no closed walk exists, the tracking fails, or the verified motion leaves the
        limits or the path, does not close, or touches or penetrates the obstacle.

    Raises:
        TaskError: not an obstacle; PathError: an open path; OptionError: an option out of range (bad weights or
        sample times included), ``robot`` not a Robot, a ``progress`` that is not callable, a ``meta`` that is not a
        dict.
    """
    t0, timings = perf_counter(), {}
    opt = ObstacleOptions.of(options, **overrides)
    check_obstacle_args(robot, path, obstacle, progress, meta, "plan")
    opt.check_for(robot)
    ts = opt.times(float(path.period))
    st, tool_tip = obstacle_stage(robot, path, obstacle, opt, planner="chapter6", progress=progress, meta=meta,
                                  t0=t0, timings=timings)
    counter = [0]
    pools = _sample_candidates(st, obstacle, ts, tool_tip, counter)
    if isinstance(pools, tuple):
        timings["samples_s"] = perf_counter() - t0
        return PlanResult(False, pools[1], timings=timings, cause=pools[0], link_names=st.link_names)
    walk = _walk(st, obstacle, ts, pools, tool_tip, counter)
    timings["samples_s"] = perf_counter() - t0
    if isinstance(walk, str):
        return PlanResult(False, walk, timings=timings, cause="no_closed_walk", link_names=st.link_names)
    return finish(st, walk)
