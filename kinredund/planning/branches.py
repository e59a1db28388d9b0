"""The planner's branch choice at the sample points (Section 6.2.2.1) and the transitions between them.

At each sample point the policy index has several local minima (branches: elbow up or down, the arm
plane on either side of the obstacle, ...). The thesis leaves the choice, and where the arm changes
branch, to the planner's expertise. Here the planner decides by looking at the *transitions*:

- :func:`candidates`: the distinct collision-free local minima of the policy at one sample, from many
  seeds (:func:`kinredund.ik.solve_ik` with the policy index), in the planners' one candidate pool.
- :func:`transition`: how the arm gets from a candidate at one sample to a candidate at the next. The
  interval is bisected (:func:`kinredund.planning.walk.bisect_interval`, the planners' one bisection): at the
  middle time, the configuration on the path closest to
  the mean of its neighbours (Eq. 6.25's index) is inserted, until no joint jumps by more than
  ``max_jump`` between consecutive points - which keeps the spline estimate near the self-motion
  manifold, where the closest-point tracking of Eq. (6.27) is regular. Revolute joints may go either
  way round: the far end is also tried shifted by whole turns. The transition's cost is its joint
  "energy" (sum of squared jumps) plus a penalty on the worst link clearance along it when negative;
  a transition that cannot be refined costs infinity.
- :func:`kinredund.planning.walk.choose`: a cyclic dynamic programme over the candidates with these costs.

Units: joints [rad or m], times [s], lengths [m].
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from kinredund.ik.solve import solve_ik
from kinredund.indices import Index
from kinredund.kinematics.angles import wrap_joints
from kinredund.planning.clearance import PENETRATION_TOL, LinkModel, link_clearance, link_segments
from kinredund.planning.obstacles import Obstacle
from kinredund.planning.selfmotion import routes
from kinredund.planning.walk import CandidatePool, bisect_interval, closest_on_path
from kinredund.tasks import get_task

#: cost of a metre of penetration along a transition, against squared joint jumps [rad^2]
PENETRATION_PENALTY = 1e4


@dataclass(frozen=True)
class Candidate:
    """A collision-free local minimum of the policy at one sample: q, the index value, link clearance."""

    q: np.ndarray
    objective: float
    clearance: np.ndarray


@dataclass(frozen=True)
class Transition:
    """The refined way from one candidate to the next.

    Attributes:
        cost: energy + penalty (inf when it could not be refined).
        shift: whole turns added to the far end [rad], shape (n,).
        points: the inserted (t, q) in between, q continuous with the near end.
        min_clearance: the worst link clearance at the inserted points and both ends [m].
        clearance: the per-link clearance at each inserted point [m] (:func:`clearance_of`), one (k,)
            array per point.
    """

    cost: float
    shift: np.ndarray
    points: tuple
    min_clearance: float
    clearance: tuple = ()


def fit_limits(q: np.ndarray, lower, upper, revolute) -> np.ndarray | None:
    """q with revolute joints shifted by the fewest whole turns into the limits, or None if impossible."""
    q = q.copy()
    for i in range(q.size):
        if lower[i] - 1e-12 <= q[i] <= upper[i] + 1e-12:
            continue
        if not revolute[i]:
            return None
        shifted = q[i] + 2 * np.pi * np.arange(-3, 4)
        inside = shifted[(shifted >= lower[i]) & (shifted <= upper[i])]
        if inside.size == 0:
            return None
        q[i] = inside[np.argmin(np.abs(inside - q[i]))]
    return q


def clearance_of(robot, q, model: LinkModel, obstacle: Obstacle, radius: float, tool_tip: float) -> np.ndarray:
    """Per-link clearance at one configuration [m]; the last link gets -inf if it penetrates."""
    clear, pen, _ = link_clearance(obstacle, link_segments(robot, q, model), radius=radius, tool_tip=tool_tip)
    c = clear[0].copy()
    if pen[0] > PENETRATION_TOL:
        c[-1] = -pen[0] - 1.0
    return c


def candidates(robot, index: Index, target, seeds, model: LinkModel, obstacle: Obstacle, radius: float,
               tool_tip: float, max_iter: int, limit: int | None = None, counter: list | None = None) -> CandidatePool:
    """The distinct collision-free local minima (Eq. D.33 holds) of ``index`` on g = x from the seeds, in the
    planners' one :class:`~kinredund.planning.walk.CandidatePool` (modulo whole turns; each candidate's data is
    its per-link clearance [m]).

    Returns the pool with at most ``limit`` of them, lowest index value first (:func:`entries` lists them).
    """
    pool, counter = CandidatePool(robot.revolute), [0] if counter is None else counter
    for s in seeds:
        res = solve_ik(robot, target, index, q0=s, max_iter=max_iter)
        if not (res.converged and res.reduced_hessian_pd):
            continue
        q = fit_limits(res.q, robot.lower, robot.upper, robot.revolute)
        if q is None or any(pool.same(f, q) for f in pool.q):
            continue
        c = clearance_of(robot, q, model, obstacle, radius, tool_tip)
        if c.min() > 0:
            pool.add((q, float(res.objective)), counter, c)
    pool.sort(limit)
    return pool


def entries(pool: CandidatePool) -> list[Candidate]:
    """The candidates of an obstacle planner's pool as :class:`Candidate` records (q, objective, clearance)."""
    return [Candidate(q, z, c) for q, z, c in zip(pool.q, pool.z, pool.data, strict=True)]


def turn_shifts(d: np.ndarray, revolute) -> list[np.ndarray]:
    """Whole-turn shifts to try for the far end of a jump d: none first, then joints with |d_i| > pi/2
    by -1, 0 or +1 turn, smallest resulting jump first."""
    joints = [i for i in range(d.size) if revolute[i] and abs(d[i]) > 0.5 * np.pi]
    out = []
    for combo in itertools.product((0, -1, 1), repeat=len(joints)):
        if any(combo):
            s = np.zeros(d.size)
            s[joints] = 2 * np.pi * np.array(combo)
            out.append(s)
    out.sort(key=lambda s: float(np.abs(d + s).max()))
    return [np.zeros(d.size)] + out


def _chain_cost(robot, chain, ends: float, model, obstacle, radius, tool_tip) -> tuple[float, float, tuple]:
    """(energy, worst clearance, per-link clearance of the inner points) of a chain of configurations
    whose two ends (candidates) have the worst clearance ``ends`` [m] already known."""
    energy = float(sum(np.sum((chain[i + 1] - chain[i]) ** 2) for i in range(len(chain) - 1)))
    inner = tuple(clearance_of(robot, q, model, obstacle, radius, tool_tip) for q in chain[1:-1])
    return energy, float(min([ends] + [c.min() for c in inner])), inner


def _join(robot, path, points, max_jump, budget, max_iter):
    """Bisect every consecutive pair of (t, q) points; the full list of points, or None."""
    out = [points[0]]
    for (ta, qa), (tb, qb) in zip(points[:-1], points[1:], strict=True):
        mid = bisect_interval(robot, path, ta, qa, tb, qb, max_jump, budget, max_iter, bounds=False, wrap=True)
        if mid is None:
            return None
        out.extend(mid)
        out.append((tb, qb))
    return out


def _self_motion_ways(robot, path, ta, qa, tb, qb, max_jump, budget, max_iter):
    """Transitions through a self-motion: qa is carried to a quarter of the interval, qb back to three
    quarters, and the arm travels between them along the self-motion at mid-interval (both ways round);
    the route's points are spread over the middle half of the interval and put back on the path."""
    t1, tm, t2 = ta + 0.25 * (tb - ta), 0.5 * (ta + tb), tb - 0.25 * (tb - ta)
    out = []
    ra = closest_on_path(robot, get_task(robot.task).target_at(path, t1), qa, max_iter=max_iter)
    rb = closest_on_path(robot, get_task(robot.task).target_at(path, t2), qb, max_iter=max_iter)
    if not (ra.converged and rb.converged):
        return out
    a1 = qa + wrap_joints(ra.q - qa, robot.revolute)
    b2 = qb + wrap_joints(rb.q - qb, robot.revolute)
    target_m = get_task(robot.task).target_at(path, tm)
    ma = closest_on_path(robot, target_m, a1, max_iter=max_iter)
    mb = closest_on_path(robot, target_m, b2, max_iter=max_iter)
    if not (ma.converged and mb.converged):
        return out
    am = a1 + wrap_joints(ma.q - a1, robot.revolute)
    for route in routes(robot, get_task(robot.task).point_target(target_m.p), am, mb.q, step=0.5 * max_jump):
        pts = route.points
        keep = [0]
        for i in range(1, len(pts)):
            if np.abs(pts[i] - pts[keep[-1]]).max() >= 0.5 * max_jump:
                keep.append(i)
        if keep[-1] != len(pts) - 1:
            keep.append(len(pts) - 1)
        sel = pts[keep]
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(sel, axis=0), axis=1))])
        times = t1 + (t2 - t1) * (arc / arc[-1] if arc[-1] > 0 else np.linspace(0, 1, len(sel)))
        placed = [(ta, qa), (t1, a1)]
        ok = True
        for tt, c in zip(times[1:-1], sel[1:-1], strict=True):
            res = closest_on_path(robot, get_task(robot.task).target_at(path, tt), c, max_iter=max_iter)
            if not res.converged:
                ok = False
                break
            placed.append((tt, c + wrap_joints(res.q - c, robot.revolute)))
        if not ok:
            continue
        end = sel[-1]  # mb's representation at the route's end
        b2_end = end + wrap_joints(b2 - end, robot.revolute)
        qb_end = b2_end + wrap_joints(qb - b2_end, robot.revolute)
        placed += [(t2, b2_end), (tb, qb_end)]
        joined = _join(robot, path, placed, max_jump, budget, max_iter)
        if joined is not None:
            out.append((joined, qb_end - np.asarray(qb, float)))
    return out


def transition(robot, path, ta: float, a: Candidate, tb: float, b: Candidate, *, model: LinkModel, obstacle: Obstacle,
               radius: float, tool_tip: float, max_jump: float, budget: int, max_iter: int = 200) -> Transition:
    """The cheapest continuous way from candidate ``a`` at time ta to candidate ``b`` at tb.

    Tried in turn: direct bisection (:func:`~kinredund.planning.walk.bisect_interval`) with the far end shifted
    by the whole turns of
    :func:`turn_shifts`, then self-motions (:func:`_self_motion_ways`). The first collision-free one
    (at its points) is taken; otherwise the cheapest found. The candidates' clearances are not
    recomputed (a whole turn of a revolute joint does not move the links).
    """
    qa = np.asarray(a.q, float)
    qb = np.asarray(b.q, float)
    ends = float(min(a.clearance.min(), b.clearance.min()))
    near = qa + wrap_joints(qb - qa, robot.revolute)  # qb's representation nearest qa
    best = Transition(np.inf, near - qb, (), -np.inf)

    def consider(points, shift):
        nonlocal best
        chain = [q for _, q in points]
        energy, worst, inner = _chain_cost(robot, chain, ends, model, obstacle, radius, tool_tip)
        cost = energy + PENETRATION_PENALTY * max(0.0, -worst)
        if cost < best.cost:
            best = Transition(cost, shift, tuple(points[1:-1]), worst, inner)
        return worst > 0

    for shift in turn_shifts(near - qa, robot.revolute):
        end = near + shift
        pts = bisect_interval(robot, path, ta, qa, tb, end, max_jump, budget, max_iter, bounds=False, wrap=True)
        if pts is not None and consider([(ta, qa)] + list(pts) + [(tb, end)], end - qb):
            return best
    for points, shift in _self_motion_ways(robot, path, ta, qa, tb, qb, max_jump, budget, max_iter):
        if consider(points, shift):
            return best
    return best
