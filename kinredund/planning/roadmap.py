"""Branch choice by a roadmap of the self-motion manifold, for arms of the CYBOTECH P-15 architecture
(Section 6.3).

Why: the policy's optima at the sample points (Eq. 6.44) do not join into a cyclic collision-free motion
on the scaled P-15 - their branches hand the arm from one side of the cylinder to the other, and the
transitions between them pass through it (:mod:`.branches` finds no cycle). The thesis leaves the branch
choice to "the trajectory planner's expert knowledge". Here the planner makes it from the whole
self-motion manifold instead:

1. **Closed-form self-motion.** For Table 4.1's architecture (axis 1 vertical at the base, links 2-3 in
   the vertical plane through it at azimuth theta1, the last link b5 along axis 5, P the wrist centre),
   the configurations putting P at a point are, for each theta1 on a grid, up to four (Fig. 6.10's planar
   equivalent): P . m = b5 cos(theta4) with m the arm plane's normal gives theta4 = +-acos(.), and links 2
   and 3 + b5 sin(theta4) solve a planar two-link problem (two elbows) - :func:`self_motion`.
   :func:`check_architecture` verifies these formulas against the robot's forward kinematics.
2. **Roadmap.** At ``slices`` times over the loop, every grid configuration whose links clear the
   obstacle by more than a margin is a node; nodes of the same or the next time slice whose joints differ
   by at most ``max_jump`` are joined. A cyclic motion is a path from a node at t = 0 to the same node
   one period later; among them Dijkstra's algorithm takes the one with the least sum of squared joint
   steps, moves within one time slice costing extra (:data:`SAME_SLICE_COST`) and used only when no
   cycle moves forward in time at every step. The margin is bisected to the largest one for which such
   a cycle exists.
   Screening uses a lower bound of the distance (exact inside, never above the truth outside), so a node
   accepted is at least that far from the obstacle.
3. The cycle's configurations, put back exactly on the path at their times, are the samples of the
   thesis's steps 2-4 (spline, resolved-rate tracking of Eq. 6.27, independent verification), as in
   :func:`kinredund.planning.planner.plan`.

Units: joints [rad], lengths [m], times [s].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from time import perf_counter

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from kinredund.errors import KinredundError, TaskError
from kinredund.kinematics.angles import wrap_joints
from kinredund.planning.clearance import PENETRATION_TOL, link_clearance
from kinredund.planning.obstacles import EllipticCylinder
from kinredund.planning.options import RoadmapOptions
from kinredund.planning.pipeline import Walk, finish
from kinredund.planning.planner import check_obstacle_args, obstacle_stage
from kinredund.planning.result import PlanResult
from kinredund.planning.spline import unwrap_samples
from kinredund.planning.walk import closest_on_path, target_at

#: cost of a move along the self-motion within one time slice, against squared joint steps [rad^2]: the
#: search advances in time wherever it can (the closest-point tracking follows slow self-motions only)
SAME_SLICE_COST = 1.0
#: the clearance margins [m] between which the roadmap's margin is bisected, and the bisection steps
MARGIN_RANGE = (0.0, 0.3)
MARGIN_BISECTIONS = 6
#: the twists of Table 4.1 (deg)
P15_ALPHA_DEG = (90.0, 180.0, -90.0, 90.0, 90.0, 90.0, -90.0)


@dataclass(frozen=True)
class Architecture:
    """The lengths of a Table 4.1 arm: b1 (shoulder height), a2, a3, b5 (the last link) [m]."""

    b1: float
    a2: float
    a3: float
    b5: float


def check_architecture(robot) -> Architecture:
    """The lengths of ``robot`` if it has Table 4.1's architecture, checked against its kinematics.

    Raises:
        TaskError: another architecture (the closed-form self-motion would not apply).
    """
    hd = robot.hd
    ok = hd is not None and hd.n == 7 and hd.kinds == "R" * 7
    if ok:
        ok = bool(np.allclose(np.degrees(hd.alpha), P15_ALPHA_DEG) and np.allclose(hd.theta0, 0.0)
                  and abs(hd.a[0]) + abs(hd.b[1]) + abs(hd.b[2]) + abs(hd.b[3]) + abs(hd.a[3]) < 1e-12
                  and np.allclose(hd.a[4:], 0.0) and np.allclose(hd.b[5:], 0.0))
    if not ok:
        raise TaskError(f"{robot.name} does not have the architecture of Table 4.1 (CYBOTECH P-15): the roadmap "
                        "of kinredund.planning.roadmap needs it; use kinredund.planning.planner.plan instead")
    arch = Architecture(float(hd.b[0]), float(hd.a[1]), float(hd.a[2]), float(hd.b[4]))
    rng = np.random.default_rng(0)
    q = rng.uniform(-math.pi, math.pi, (5, 4))
    pts = origins(arch, q)
    for k in range(5):
        fk = robot.kinematics.joint_origins(np.concatenate([q[k], np.zeros(robot.nq - 4)]))
        if np.abs(fk[[1, 2, 3, 5]] - pts[k, 1:]).max() > 1e-9:
            raise TaskError(f"{robot.name}: the closed-form self-motion disagrees with the forward kinematics")
    return arch


def origins(arch: Architecture, q: np.ndarray) -> np.ndarray:
    """Joint origins O1, O2, O3, O4 and P for joints q (..., 4), shape (..., 5, 3) [m] (Fig. 6.10)."""
    q = np.asarray(q, float)
    t1, t2, t3, t4 = (q[..., i] for i in range(4))
    zero = np.zeros_like(t1)
    h = np.stack([np.cos(t1), np.sin(t1), zero], -1)  # the arm plane's horizontal direction (Eq. 6.29)
    m = np.stack([-np.sin(t1), np.cos(t1), zero], -1)  # its normal (axes 2 and 3)
    z = np.array([0.0, 0.0, 1.0])
    o1 = np.zeros(t1.shape + (3,))
    o2 = o1 + arch.b1 * z
    o3 = o2 + arch.a2 * (np.cos(t2)[..., None] * h + np.sin(t2)[..., None] * z)
    u3 = np.cos(t2 - t3)[..., None] * h + np.sin(t2 - t3)[..., None] * z  # alpha2 = 180 deg: theta3 subtracts
    o4 = o3 + arch.a3 * u3
    z5 = np.cos(t4)[..., None] * m + np.sin(t4)[..., None] * u3  # the last link's direction (Eqs. 6.40-6.42)
    p = o4 + arch.b5 * z5
    return np.stack([o1, o2, o3, o4, p], axis=-2)


def self_motion(arch: Architecture, p, theta1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The (up to) four configurations with wrist centre p for each theta1: q (4, N, 4), valid (4, N)."""
    p = np.asarray(p, float)
    theta1 = np.asarray(theta1, float)
    m = np.stack([-np.sin(theta1), np.cos(theta1), np.zeros_like(theta1)], -1)
    h = np.stack([np.cos(theta1), np.sin(theta1), np.zeros_like(theta1)], -1)
    c4 = (m @ p) / arch.b5  # P . m = b5 cos(theta4): O4 lies in the arm plane
    valid4 = np.abs(c4) <= 1.0
    X, Z = h @ p, p[2] - arch.b1
    qs, ok = [], []
    for s4 in (1.0, -1.0):
        t4 = s4 * np.arccos(np.clip(c4, -1.0, 1.0))
        rho = arch.a3 + arch.b5 * np.sin(t4)  # links 3 and 4 in the plane: one link of length rho
        with np.errstate(divide="ignore", invalid="ignore"):
            cd = (X**2 + Z**2 - arch.a2**2 - rho**2) / (2.0 * arch.a2 * rho)
        good = valid4 & np.isfinite(cd) & (np.abs(cd) <= 1.0)
        for elbow in (1.0, -1.0):
            d = elbow * np.arccos(np.clip(np.nan_to_num(cd), -1.0, 1.0))
            t2 = np.arctan2(Z, X) - np.arctan2(rho * np.sin(d), arch.a2 + rho * np.cos(d))
            t3 = -d  # theta2 - theta3 = theta2 + d
            qs.append(np.stack([theta1, t2, t3, t4], -1))
            ok.append(good)
    return np.array(qs), np.array(ok)


@dataclass(frozen=True)
class Roadmap:
    """The roadmap's cycle.

    Attributes:
        t: the times of the cycle's configurations [s] (increasing, from 0).
        q: the configurations (4 arm joints), unwrapped, shape (K, 4).
        margin: the clearance margin the cycle was found with [m] (a lower bound on the grid).
    """

    t: np.ndarray
    q: np.ndarray
    margin: float


def _slices(arch, path, obstacle, ts, theta1, tool_tip, bound, report) -> tuple[np.ndarray, np.ndarray]:
    """(Q, C): the self-motion configurations (slices, 4 branches, grid, 4) at every time slice and their
    clearance (-inf where a link penetrates or the point is not reached)."""
    slices, grid = len(ts), len(theta1)
    Q = np.zeros((slices, 4, grid, 4))
    C = np.full((slices, 4, grid), -np.inf)
    for k, t in enumerate(ts):
        report(k)
        q, ok = self_motion(arch, path(t).p, theta1)
        pts = origins(arch, q).reshape(4 * grid, 5, 3)
        seg = np.stack([pts[:, 1:4], pts[:, 2:5]], axis=2)  # links O2-O3, O3-O4, O4-P: (4 grid, 3, 2, 3)
        c, pen, tip = link_clearance(obstacle, seg, tool_tip=tool_tip, distance=bound)
        whole_out = (pen + tip <= PENETRATION_TOL).reshape(4, grid)  # no point of the last link inside, P included
        Q[k] = q
        C[k] = np.where(ok & whole_out, c.min(axis=1).reshape(4, grid), -np.inf)
    return Q, C


def _edges(Q, slices: int, grid: int, max_jump: float, node):
    """The roadmap's candidate edges (same slice: index +-1, +-2 any branch; next slice: index -2..2 any
    branch) with joint jumps at most ``max_jump``: (src, dst, kind, same-slice flags, weights)."""
    K, B, I = np.meshgrid(np.arange(slices), np.arange(4), np.arange(grid), indexing="ij")
    src, dst, kind = [], [], []
    for bb in range(4):
        for di in (-2, -1, 0, 1, 2):
            J = (I + di) % grid
            for step in (0, 1):
                if step == 0 and bb == 0 and di == 0:
                    continue
                Kn = K + step
                qa = Q[K, B, I]
                qb = Q[Kn % slices, bb, J]
                close = np.abs(wrap_joints(qb - qa)).max(-1) <= max_jump
                src.append(node(K, B, I)[close])
                dst.append(node(Kn, bb, J)[close] if step else node(K, bb, J)[close])
                kind.append(np.stack([K[close], B[close], I[close], (Kn % slices)[close], np.full(close.sum(), bb),
                                      J[close]], -1))
    src, dst, kind = np.concatenate(src), np.concatenate(dst), np.concatenate(kind)
    dq = wrap_joints(Q[kind[:, 3], kind[:, 4], kind[:, 5]] - Q[kind[:, 0], kind[:, 1], kind[:, 2]])
    same = src // (4 * grid) == dst // (4 * grid)
    weight = np.sum(dq**2, axis=1) + np.where(same, SAME_SLICE_COST, 1e-6)
    return src, dst, kind, same, weight


def _decode(best, Q, ts, dt: float, grid: int) -> tuple[np.ndarray, np.ndarray]:
    """(times, joints) of a node sequence; within a slice the self-motion is spread over its interval."""
    by_slice: dict[int, list[np.ndarray]] = {}
    for nd in best[:-1]:
        k, rest = divmod(nd, 4 * grid)
        b, i = divmod(rest, grid)
        by_slice.setdefault(k, []).append(Q[k, b, i])
    times, qs = [], []
    for k in sorted(by_slice):
        chain = by_slice[k]
        for j, q in enumerate(chain):
            times.append(ts[k] + dt * j / len(chain))
            qs.append(q)
    q_arr, _ = unwrap_samples(np.array(qs), np.ones(4, bool))
    return np.array(times), q_arr


def roadmap_cycle(robot, path, obstacle, *, tool_tip: float, slices: int = 90, grid: int = 360,
                  max_jump: float = 0.25, progress=None) -> Roadmap:
    """The cyclic collision-free motion with the largest clearance margin on the roadmap (module docstring).

    The margin is bisected in :data:`MARGIN_RANGE` (:data:`MARGIN_BISECTIONS` steps); ``tool_tip`` [m] is
    the last link's tip left out of its clearance, as in
    :func:`~kinredund.planning.clearance.link_clearance`. ``progress(done, total, "roadmap")`` is called
    after each time slice and each bisection.

    Raises:
        TaskError: the arm is not of Table 4.1's architecture.
        KinredundError: no cycle even with a zero margin (the message says so).
    """
    arch = check_architecture(robot)
    period = float(path.period)
    # screening with a lower bound of the distance (exact inside, never above the truth outside)
    bound = obstacle.surface_bound if isinstance(obstacle, EllipticCylinder) else None
    theta1 = np.linspace(-math.pi, math.pi, grid, endpoint=False)
    ts = np.arange(slices) * period / slices
    total = slices + MARGIN_BISECTIONS + 1

    def report(done):
        if progress is not None:
            progress(done, total, "roadmap")

    Q, C = _slices(arch, path, obstacle, ts, theta1, tool_tip, bound, report)
    # candidate edges (same slice: index +-1, +-2 any branch; next slice: index -2..2 any branch)
    n_nodes = slices * 4 * grid + 4 * grid  # the last block is slice 0 again, one period later

    def node(k, b, i):
        return (k * 4 + b) * grid + i

    src, dst, kind, same, weight = _edges(Q, slices, grid, max_jump, node)
    cl_src = C[kind[:, 0], kind[:, 1], kind[:, 2]]
    cl_dst = C[kind[:, 3], kind[:, 4], kind[:, 5]]

    def cycle(margin, allow_same):
        keep = (cl_src > margin) & (cl_dst > margin) & (allow_same | ~same)
        g = coo_matrix((weight[keep], (src[keep], dst[keep])), shape=(n_nodes, n_nodes)).tocsr()
        starts = np.argwhere(C[0] > margin)
        order = np.argsort(-C[0][C[0] > margin])
        best_seq, best_cost = None, np.inf
        for b, i in starts[order][:24]:
            s = node(0, b, i)
            goal = node(slices, b, i)
            dist, pred = dijkstra(g, directed=True, indices=s, return_predecessors=True)
            if np.isfinite(dist[goal]) and dist[goal] < best_cost:
                seq = [goal]
                while seq[-1] != s:
                    seq.append(int(pred[seq[-1]]))
                best_seq, best_cost = seq[::-1], float(dist[goal])
        return best_seq

    report(slices)
    lo, hi = MARGIN_RANGE
    allow_same = False
    best = cycle(lo, allow_same)
    if best is None:
        allow_same = True  # no cycle that only moves forward in time: allow self-motions within a slice
        best = cycle(lo, allow_same)
    if best is None:
        raise KinredundError(f"no cyclic collision-free motion on the roadmap ({slices} times x {grid} azimuths x 4 "
                             "branches): the arm cannot go round this obstacle without touching it")
    best_margin = lo
    for j in range(MARGIN_BISECTIONS):
        report(slices + 1 + j)
        mid = 0.5 * (lo + hi)
        seq = cycle(mid, allow_same)
        if seq is None:
            hi = mid
        else:
            best, best_margin, lo = seq, mid, mid
    times, q_arr = _decode(best, Q, ts, period / slices, grid)
    return Roadmap(times, q_arr, float(best_margin))


def plan_roadmap(robot, path, obstacle, options: RoadmapOptions | None = None, *, progress=None,
                 meta: dict | None = None, **overrides) -> PlanResult:
    """Section 6.3's plan: the planning pipeline (:mod:`kinredund.planning.pipeline`) with the branch from
    :func:`roadmap_cycle` as its closed walk, then the pipeline's spline, tracking and verification.

    Args:
        robot, path, obstacle: a Table 4.1 arm, a closed path on the obstacle, the obstacle.
        options: the :class:`~kinredund.planning.options.RoadmapOptions` (slices, grid, max_jump,
            steps_per_loop, substeps, tool_tip, spline, check_doubling, ...); ``overrides`` by name.
        progress: ``progress(done, total, stage)``; meta: extra entries for ``Trajectory.meta``.

    Returns:
        A :class:`~kinredund.planning.result.PlanResult` (``samples.kind`` ``roadmap``); ``ok=False``
        with the reason when no cycle exists, the tracking fails or the verification fails or finds contact.

    Raises:
        TaskError: the arm is not of Table 4.1's architecture, ``obstacle`` not an Obstacle; PathError: ``path`` is
        not closed; OptionError: an option out of range (a bad ``tool_tip`` included), ``robot`` not a Robot, a
        ``progress`` that is not callable, a ``meta`` that is not a dict.
    """
    t_start, timings = perf_counter(), {}
    opt = RoadmapOptions.of(options, **overrides)
    check_obstacle_args(robot, path, obstacle, progress, meta, "plan_roadmap")
    opt.check_for(robot)
    extra = {"hd": {"alpha": robot.hd.alpha.tolist(), "a": robot.hd.a.tolist(), "b": robot.hd.b.tolist()}} \
        if robot.hd is not None else {}
    st, tool_tip = obstacle_stage(robot, path, obstacle, opt, planner="chapter6-roadmap", progress=progress,
                                  meta={**extra, **(meta or {})}, t0=t_start, timings=timings)
    try:
        rm = roadmap_cycle(robot, path, obstacle, slices=opt.slices, grid=opt.grid, tool_tip=tool_tip,
                           max_jump=opt.max_jump, progress=progress)
    except KinredundError as err:
        if isinstance(err, TaskError):
            raise
        timings["roadmap_s"] = perf_counter() - t_start
        return PlanResult(False, str(err), timings=timings, cause="no_closed_walk", link_names=st.link_names)
    timings["roadmap_s"] = perf_counter() - t_start
    st.info["roadmap_margin"] = rm.margin
    n_wrist, qs = robot.nq - 4, []
    for k, (t, q4) in enumerate(zip(rm.t, rm.q, strict=True)):  # put each configuration exactly on the path
        st.report(k, len(rm.t), "placing the roadmap on the path")
        ref = np.concatenate([q4, np.zeros(n_wrist)])
        res = closest_on_path(robot, target_at(robot, path, t), ref)
        qs.append(ref + wrap_joints(res.q - ref, robot.revolute) if res.converged else ref)
    q_u, turns = unwrap_samples(np.array(qs), robot.revolute)
    nan = np.full(len(st.link_names), np.nan)
    rows = [(t, q, "roadmap", -1, nan) for t, q in zip(rm.t, q_u, strict=True)]
    notes = [f"branch chosen on a roadmap of the self-motion manifold ({opt.slices} times x {opt.grid} azimuths x 4 "
             f"branches), clearance margin >= {rm.margin:.3g} m at its nodes"]
    return finish(st, Walk(rows, rm.t, turns=turns, off_optimum=((0.0, float(path.period)),), notes=notes))
