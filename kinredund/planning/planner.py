"""The off-line planner of Section 6.2.2: samples, spline, resolved-rate tracking, clearance check.

:func:`plan` runs the thesis's three steps and then checks the result independently:

1. **Samples** (Section 6.2.2.1): at each sample time the end-point target is solved at joint level,
   min z s.t. g(theta) = x (Eqs. 6.21-6.22 or 6.43-6.44), with the policy index of
   :mod:`kinredund.planning.policy` and :func:`kinredund.ik.solve_ik`, from many seeds. Every distinct
   local minimum (positive-definite reduced Hessian, Eq. D.33) whose links clear the obstacle is a
   candidate. The *branch* is the planner's choice (the thesis leaves it to the planner's expertise):
   among the candidates, a cyclic dynamic programme picks the sequence with the smallest sum of
   squared joint jumps between consecutive samples (closing the loop), so the arm changes branch only
   where it has to. ``seeds`` forces candidates (e.g. a branch) at chosen samples.
2. **Estimates** (Section 6.2.2.2): a cubic spline through the samples (:mod:`.spline`).
3. **Tracking** (Section 6.2.2.3): the resolved-rate scheme of Chapter 4 with the time-varying index
   h = 1/2 ||theta - theta*(t)||^2 and the spline's rate as feed-forward (Eqs. 6.23-6.28), through
   :func:`kinredund.tracking.track`: the tracked joints are the constrained optimum of h at each
   time, so where the branch switch happens is found by the tracking itself.
4. **Verification** (:mod:`.clearance`): every link against the obstacle along the whole tracked
   motion, finer than the tracking steps. A plan with any penetration, or with a certified clearance
   that is not positive, is returned with ``ok=False`` and the reason.

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
from kinredund.planning.branches import Candidate, Transition, candidates, choose, transition
from kinredund.planning.clearance import link_model
from kinredund.planning.obstacles import Obstacle
from kinredund.planning.policy import PlanarPolicy, SpatialPolicy, check_weights
from kinredund.planning.stages import PlanResult, Samples, failure, tool_tip_length, track_and_verify
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


def _sample_times(samples, period: float) -> np.ndarray:
    if isinstance(samples, (int, np.integer)) and not isinstance(samples, bool):
        if samples < 4:
            raise TaskError(f"at least 4 sample points are needed for a cubic spline, got {samples}")
        return np.arange(int(samples)) * period / int(samples)
    try:
        t = np.asarray(samples, float)
    except (TypeError, ValueError) as err:
        raise TaskError(f"samples must be a count or sample times [s], got {samples!r}") from err
    if t.ndim != 1 or t.size < 4 or not np.all(np.isfinite(t)):
        raise TaskError(f"sample times must be at least 4 finite numbers, got {samples!r}")
    if t[0] != 0.0 or np.any(np.diff(t) <= 0) or t[-1] >= period:
        raise TaskError(f"sample times must start at 0, increase strictly and stay below the period {period:.6g} s")
    return t


def _weights(weights, n: int) -> np.ndarray:
    """The (w1, w2) of each of the n samples, shape (n, 2), each pair checked as the policy checks it."""
    try:
        w = np.asarray(weights, float)
    except (TypeError, ValueError) as err:
        raise TaskError(f"weights must be (w1, w2) or one pair per sample ({n}, 2), got {weights!r}") from err
    if w.shape == (2,):
        w = np.tile(w, (n, 1))
    if w.shape != (n, 2):
        raise TaskError(f"weights must be (w1, w2) or one pair per sample ({n}, 2), got shape {w.shape}")
    for k, pair in enumerate(w):
        check_weights(pair, f"the weights of sample S{k + 1}")
    return w


def _sample_candidates(robot, path, obstacle, ts, W, factory, model, seeds, starts, seed, link_radius, tool_tip,
                       max_iter, max_candidates, check_reach, progress) -> list[list[Candidate]] | tuple[str, str]:
    """Step 1 of :func:`plan`: the collision-free local minima of the policy at every sample, or (cause,
    reason) where a sample has none (``check_reach``: the wrist-reach screen of the default policy)."""
    rng = np.random.default_rng(seed)
    lo, hi = robot.sample_box()
    cands: list[list[Candidate]] = []
    ps = np.array([path(t).p for t in ts])
    if not get_task(robot.task).planar and not get_task(robot.task).has_orientation:
        wr = wrist_reach(robot, ps, obstacle.normal_at(ps))
        if wr is not None and (wr.end_margin.min() < 0 or (check_reach and wr.margin.min() < 0)):
            return "out_of_reach", _reach_reason(wr, ts, ps, model.names)
    for k, (t, p) in enumerate(zip(ts, ps, strict=True)):
        if progress is not None:
            progress(k, len(ts), "samples")
        index = factory(robot, obstacle, obstacle.normal_at(p), tuple(W[k]))
        user = seeds.get(k)
        user = [] if user is None else ([user] if np.ndim(user) == 1 else list(user))
        pool = [robot.check_q(s, f"seed of sample {k + 1}") for s in user]
        pool += [c.q for c in cands[-1]] if cands else []
        pool += [rng.uniform(lo, hi) for _ in range(int(starts))]
        target = get_task(robot.task).target_at(path, t)
        found = candidates(robot, index, target, pool, model, obstacle, link_radius, tool_tip, max_iter,
                           limit=max_candidates)
        if not found:
            return "no_minimum", (
                f"sample S{k + 1} (t = {t:.4g} s, p = {np.round(p, 4).tolist()}) has no collision-free "
                f"configuration at a local minimum of the policy ({len(pool)} seeds): the point may be out of "
                "reach, or the obstacle too large for the arm")
        cands.append(found)
    return cands


def _chosen_samples(robot, path, ts, W, cands, trans, choice, notes) -> Samples:
    """The samples along the chosen branches with the refined points of their transitions (whole turns
    accumulated); a transition that is not collision-free at its refined points goes into ``notes``."""
    n = ts.size
    rows = []  # (t, q, kind, candidate count, objective, clearance, weights)
    acc = np.zeros(robot.nq)
    for k in range(n):
        c = cands[k][choice[k]]
        rows.append((ts[k], c.q + acc, "policy", len(cands[k]), c.objective, c.clearance, W[k]))
        tr = trans[k][choice[k]][choice[(k + 1) % n]]
        for (tm, qm), cm in zip(tr.points, tr.clearance, strict=True):
            rows.append((tm, qm + acc, "refined", 0, np.nan, cm, np.full(2, np.nan)))
        acc = acc + tr.shift
        if tr.min_clearance <= 0:
            notes.append(f"the transition between S{k + 1} and S{(k + 1) % n + 1} is not collision-free at its "
                         f"refined points (worst clearance {tr.min_clearance:.3g} m)")
    smp = Samples(np.array([r[0] for r in rows]), np.array([path(r[0]).p for r in rows]),
                  np.array([r[1] for r in rows]), acc, tuple(r[3] for r in rows), np.array([r[4] for r in rows]),
                  np.array([r[5] for r in rows]), np.array([r[6] for r in rows]), tuple(r[2] for r in rows))
    return smp


def plan(
    robot,
    path: Path,
    obstacle: Obstacle,
    samples=9,
    weights=DEFAULT_WEIGHTS,
    *,
    policy: PolicyFactory | None = None,
    seeds: dict | None = None,
    starts: int = 12,
    seed: int = 0,
    spline: str = "periodic",
    steps_per_loop: int = 400,
    substeps: int = 8,
    link_radius: float = 0.0,
    tool_tip: float | None = None,
    check_doubling: bool = True,
    refine: bool = True,
    max_jump: float = 0.3,
    max_refine: int = 32,
    max_candidates: int | None = 4,
    max_iter: int = 200,
    check_reach: bool = True,
    progress=None,
    meta: dict | None = None,
) -> PlanResult:
    """Plan a collision-free cyclic motion of the end point along a closed path on the obstacle.

    Args:
        robot: a planar robot (task ``planar``) or a spatial arm with a ``position`` task.
        path: a closed path (with a ``period``) on the obstacle's boundary.
        obstacle: an :class:`~kinredund.planning.obstacles.Obstacle`.
        samples: the number of equally spaced sample points (from t = 0), or their times [s]
            (starting at 0, below the period).
        weights: (w1 [m^2], w2) of Eq. (6.21)/(6.44), or one pair per sample, shape (N, 2).
        policy: ``policy(robot, obstacle, normal, (w1, w2)) -> Index``; default :func:`default_policy`.
        seeds: {sample index: configuration or list of configurations} added to the seeds there.
        starts: random seeds per sample (uniform in the joint limits, ``np.random.default_rng(seed)``);
            the candidates of the previous sample are seeds too.
        seed: the random seed.
        spline: ``periodic`` (default) or ``natural`` (the thesis's), see :mod:`.spline`.
        steps_per_loop: resolved-rate steps over the loop.
        substeps: clearance checks per tracking step.
        link_radius: capsule radius of the links [m].
        tool_tip: the last link's tip excluded from its clearance [m]; default 1/6 of its length.
        check_doubling: repeat the clearance check at twice the resolution.
        refine: refine every transition between consecutive samples until no joint jumps by more than
            ``max_jump`` [rad] (at most ``max_refine`` inserted points per transition), see
            :mod:`.branches`. This keeps the estimate theta*(t) near the self-motion manifold, where the
            closest-point tracking of Eq. (6.27) is regular (the thesis: choose sample points close to
            one another where the configuration changes fast). The refined points join the samples
            (``kind`` ``refined``).
        max_candidates: the local minima kept per sample (lowest index value first), None for all.
        max_iter: iterations of each joint-level solve.
        check_reach: for a spatial arm with the default policy, fail at once (before any solve) when
            a sample's wrist point W = P + l n is beyond the reach of the links before the last one
            (:func:`wrist_reach`): the policy's last link cannot lie along the normal there (Eq. 6.44),
            and the branches found with it tilted do not join into a loop (Section 6.3 at scale 8).
            A sample whose end point itself is out of reach fails whatever this flag.
        progress: ``progress(done, total, stage)`` through the run; ``stage`` is ``samples``,
            ``transitions``, ``tracking`` or ``clearance``.
        meta: extra entries for ``Trajectory.meta``.

    Returns:
        A :class:`PlanResult`; ``ok=False`` with a reason when a sample has no collision-free
        solution, the tracking fails, or the verified motion touches or penetrates the obstacle.

    Raises:
        TaskError, PathError, ChoiceError: bad arguments (an open path, bad weights or sample times).
    """
    t_start = perf_counter()
    timings: dict[str, float] = {}
    if not isinstance(obstacle, Obstacle):
        raise TaskError(f"obstacle must be a kinredund.planning Obstacle, got {type(obstacle).__name__}")
    if path.period is None:
        raise TaskError("plan() needs a closed path (one with a period)")
    period = float(path.period)
    ts = _sample_times(samples, period)
    W = _weights(weights, ts.size)
    factory = policy or default_policy
    model = link_model(robot)
    names = model.names
    tool_tip = tool_tip_length(model, tool_tip)
    if not (np.isfinite(link_radius) and link_radius >= 0):
        raise TaskError(f"link_radius must be a number >= 0 [m], got {link_radius!r}")
    seeds = dict(seeds or {})
    notes: list[str] = []

    # -- step 1: the sample points at joint level (Eqs. 6.21-6.22) and the branch choice ----------
    cands = _sample_candidates(robot, path, obstacle, ts, W, factory, model, seeds, starts, seed, link_radius, tool_tip,
                               max_iter, max_candidates, check_reach and policy is None, progress)
    if isinstance(cands, tuple):
        timings["samples_s"] = perf_counter() - t_start
        return failure(cands[1], names, timings, cause=cands[0])
    n = ts.size
    trans: list[list[list[Transition]]] = []
    for k in range(n):
        if progress is not None:
            progress(k, n, "transitions")
        tb = ts[k + 1] if k + 1 < n else period
        nxt = cands[k + 1] if k + 1 < n else cands[0]
        trans.append([[transition(robot, path, ts[k], a, tb, b, model=model, obstacle=obstacle,
                                  radius=link_radius, tool_tip=tool_tip, max_jump=max_jump if refine else np.inf,
                                  budget=max_refine, max_iter=max_iter) for b in nxt] for a in cands[k]])
    costs = [np.array([[tr.cost for tr in row] for row in mat]) for mat in trans]
    choice, total = choose(costs)
    if choice is None or not np.isfinite(total):
        timings["samples_s"] = perf_counter() - t_start
        bad = [k for k in range(n) if not np.isfinite(costs[k]).any()]
        where = f" (none between S{bad[0] + 1} and S{(bad[0] + 1) % n + 1})" if bad else ""
        return failure(f"no cyclic sequence of sample configurations with continuous transitions{where}: "
                        "try more samples or other sample times", names, timings, cause="no_closed_walk")
    smp = _chosen_samples(robot, path, ts, W, cands, trans, choice, notes)
    timings["samples_s"] = perf_counter() - t_start
    return track_and_verify(robot, path, obstacle, smp, model, planner="chapter6", spline=spline,
                             steps_per_loop=steps_per_loop, substeps=substeps, link_radius=link_radius,
                             tool_tip=tool_tip, check_doubling=check_doubling, progress=progress,
                             meta=dict(meta or {}), timings=timings, t_start=t_start, notes=notes)
