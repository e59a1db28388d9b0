"""The candidate graph of the cyclic planner (:mod:`kinredund.planning.cyclic`): within-limits minima of z
at the sample points, their continuation from sample to sample, the layered graph and its refinement.

- :class:`CandidatePool`: the distinct within-limits local minima of z at one sample (Eq. 4.3 with the
  joint limits as bounds; Eq. D.33 on the null space of the active constraints), each labelled;
  :func:`continue_candidates` solves from every candidate of one sample at the next and records which
  labels one solve joined (the same branch).
- :func:`walk_costs`: the edges of the layered graph, the joint distance ||q_b - q_a|| where no joint
  moves by more than ``max_jump`` (else infinite); :func:`restrict_start` forces the walk's start.
- :func:`refine_walk` / :func:`bisect_interval`: an infinite edge made finite by inserting, at the
  middle time, the within-limits configuration on the path closest to the mean of its ends (the index
  of Eq. 6.25, :func:`closest_within_limits`), recursively, as the thesis asks of the sample points
  where the configuration changes fast (Section 6.2.2.1).
- :func:`walk_knots`, :func:`off_optimum_intervals`: the spline's knots along a chosen walk, and where
  the walk is not the continuation of one minimum.

Units: times [s], joints [rad or m].
"""

from __future__ import annotations

import copy

import numpy as np

from kinredund.ik.solve import solve_ik
from kinredund.indices import Index, JointDeviation
from kinredund.kinematics.angles import wrap_joints
from kinredund.paths import Path
from kinredund.tasks import get_task

#: two candidates closer than this (max-abs) are the same local minimum [rad or m]
SAME_CANDIDATE = 1e-6
#: the weight of z in the walk's edge costs [rad per unit of z]: it only breaks ties between equally long walks
Z_TIE = 1e-9
#: a candidate's task errors are at most this [m or rad]: a converged solve holds ~1e-12, a wrong branch ~1
ON_TARGET = 1e-8


def shrunk_limits(robot, margin: float):
    """A shallow copy of the robot whose limits are shrunk by ``margin`` (the model is shared, unchanged)."""
    inner = copy.copy(robot)
    span = robot.upper - robot.lower
    m = np.minimum(margin, 0.25 * span)
    inner.lower, inner.upper = robot.lower + m, robot.upper - m
    return inner


def target_at(robot, path: Path, t: float):
    """The IK target of the path at t for the robot's task kind (:meth:`kinredund.tasks.Task.target_at`).

    Raises:
        PathError: the task holds an orientation and the path gives none.
    """
    return get_task(robot.task).target_at(path, t)


def inside_limits(robot, q) -> bool:
    """Every joint of q within the robot's limits (inclusive)."""
    return bool(np.all(q >= robot.lower) and np.all(q <= robot.upper))


def on_target(robot, target, q, tol: float = ON_TARGET) -> bool:
    """Every error the task records (:meth:`kinredund.tasks.Task.error_values`, the robot's own FK) within
    ``tol`` at q: a solve's answer is a point of the path, not a stationary point elsewhere (a tool axis
    reversed against the target's is a zero of some residuals, not of the task's errors)."""
    T = robot.fk(q)
    errors = get_task(robot.task).error_values(T[:3, :3], T[:3, 3], target)
    return max(errors.values()) <= tol


def local_minimum(inner, target, index: Index, seed, max_iter: int, keep=None, hold=None):
    """A within-limits local minimum of z from ``seed`` (q, z) on the target, or None; with ``keep`` (a
    predicate of q: the plan's clearances, :class:`kinredund.planning.keepout.Keepout`) None too where it says no,
    unless ``hold`` (q -> (q, z) or None: the minimum that keeps the clearances, from q) finds one from there."""
    res = solve_ik(inner, target, index, q0=seed, bounds=True, max_iter=max_iter)
    if not (res.converged and res.reduced_hessian_pd and inside_limits(inner, res.q)
            and on_target(inner, target, res.q)):
        return None
    if keep is not None and not keep(res.q):
        held = None if hold is None else hold(target, res.q)
        return None if held is None or not (inside_limits(inner, held[0]) and on_target(inner, target, held[0])) \
            else held
    return res.q, float(res.objective)


def closest_on_path(robot, target, reference: np.ndarray, seed=None, max_iter: int = 200, bounds: bool = False):
    """A configuration on g(theta) = x locally closest to ``reference``: min 1/2 ||theta - reference||^2
    (the index of Eq. 6.25), from ``seed`` (default: the reference); with ``bounds`` inside the joint limits.
    The one closest-point solve of the planners (the Chapter 6 planner, the roadmap, the cyclic planner).

    The seed is first projected onto g = x by a pose-only solve: started exactly at the reference, the
    index's gradient and the multipliers are zero, and the IK's exact-penalty line search (whose weight
    is set from the multipliers) then cannot accept a step back onto g = x.

    Returns:
        The :class:`~kinredund.ik.solve.IKResult`.
    """
    seed = reference if seed is None else seed
    first = solve_ik(robot, target, None, q0=seed, bounds=bounds, max_iter=max_iter)
    start = first.q if first.converged else seed
    return solve_ik(robot, target, JointDeviation(reference), q0=start, bounds=bounds, max_iter=max_iter)


def closest_within_limits(inner, target, reference, seed=None, max_iter: int = 200, fallback: bool = False):
    """The within-limits configuration on g = x locally closest to ``reference`` (the index of Eq. 6.25,
    :func:`closest_on_path` with the limits as bounds), from ``seed`` (default
    the reference, clipped into the limits), or None. With ``fallback``, where that solve does not
    converge, the within-limits point on g = x a pose-only solve reaches from the seed.
    """
    seed = np.clip(np.asarray(reference if seed is None else seed, float), inner.lower, inner.upper)
    res = closest_on_path(inner, target, np.asarray(reference, float), seed=seed, max_iter=max_iter, bounds=True)
    if res.converged and inside_limits(inner, res.q):
        return res.q
    if not fallback:
        return None
    first = solve_ik(inner, target, None, q0=seed, bounds=True, max_iter=max_iter)
    return first.q if first.converged and inside_limits(inner, first.q) else None


class CandidatePool:
    """The candidates of one sample: distinct minima (q, z), each with a label unique over the plan and the
    configuration's data (an obstacle planner's link clearances, else None): the one pool of every planner.

    Args:
        revolute: with it, two candidates differing by whole turns of these joints are the same (the obstacle
            planner's unbounded solves); default (None) raw values (a within-limits minimum is its own).
    """

    def __init__(self, revolute=None):
        self.q: list[np.ndarray] = []
        self.z: list[float] = []
        self.label: list[int] = []
        self.data: list = []
        self.revolute = revolute

    def __len__(self) -> int:
        return len(self.q)

    def same(self, a, b) -> bool:
        """Whether two configurations are one candidate (:data:`SAME_CANDIDATE`, modulo turns with ``revolute``)."""
        d = a - b if self.revolute is None else wrap_joints(a - b, self.revolute)
        return bool(np.abs(d).max() < SAME_CANDIDATE)

    def add(self, found, counter: list, data=None) -> int:
        """Add (q, z) unless already there; its label (or -1 for None). ``counter``: [next label]."""
        if found is None:
            return -1
        q, z = found
        for i, c in enumerate(self.q):
            if self.same(c, q):
                return self.label[i]
        self.q.append(q)
        self.z.append(z)
        self.label.append(counter[0])
        self.data.append(data)
        counter[0] += 1
        return self.label[-1]

    def trim(self, limit: int, keep: int | None = None) -> None:
        """Keep the ``limit`` candidates of lowest z (in their order), and the one labelled ``keep``."""
        keep = sorted(set(np.argsort(self.z, kind="stable")[:limit].tolist())
                      | ({self.label.index(keep)} if keep is not None else set()))
        self.q, self.z, self.label, self.data = ([v[i] for i in keep] for v in (self.q, self.z, self.label, self.data))

    def sort(self, limit: int | None = None) -> None:
        """Lowest z first, at most ``limit`` kept (all with None)."""
        order = np.argsort(self.z, kind="stable")[:limit]
        self.q, self.z, self.label, self.data = ([v[i] for i in order] for v in (self.q, self.z, self.label, self.data))


def continue_candidates(inner, targets, index, pools, a, b, links, counter, max_iter, keep=None, hold=None) -> None:
    """Continue every candidate of sample a to sample b; the pairs of labels joined go into ``links``
    (``keep``, ``hold``: as for :func:`local_minimum`)."""
    for la, q in zip(list(pools[a].label), list(pools[a].q), strict=True):
        lb = pools[b].add(local_minimum(inner, targets[b], index, q, max_iter, keep, hold), counter)
        if lb >= 0:
            links.add(frozenset((la, lb)))


def bisect_interval(robot, path, ta, qa, tb, qb, max_jump, budget, max_iter, *, bounds: bool = True,
                    wrap: bool = False):
    """Points strictly inside (ta, tb) that bring every joint jump within ``max_jump``, or None: the one
    bisection of every planner (Section 6.2.2.1: sample points close to one another where the configuration
    changes fast).

    Recursive halving: the middle point is the configuration on the path closest to the mean of the
    interval's ends (the index of Eq. 6.25, :func:`closest_on_path`; with ``bounds`` the within-limits one,
    :func:`closest_within_limits`; with ``wrap`` its revolute joints taken by whole turns nearest the mean); it
    fails where that does not shrink the jump by 5 % (the ends are not joined by a short self-motion) or
    after ``budget`` inserted points.
    """
    left = [int(budget)]

    def middle(tm, mean):
        target = target_at(robot, path, tm)
        if bounds:
            return closest_within_limits(robot, target, mean, max_iter=max_iter)
        res = closest_on_path(robot, target, mean, max_iter=max_iter)
        if not res.converged:
            return None
        return mean + wrap_joints(res.q - mean, robot.revolute) if wrap else res.q

    def halve(t0, q0, t1, q1):
        jump = float(np.abs(q1 - q0).max())
        if jump <= max_jump:
            return []
        if left[0] <= 0:
            return None
        left[0] -= 1
        tm = 0.5 * (t0 + t1)
        qm = middle(tm, 0.5 * (q0 + q1))
        if qm is None or max(float(np.abs(qm - q0).max()), float(np.abs(q1 - qm).max())) >= 0.95 * jump:
            return None
        first = halve(t0, q0, tm, qm)
        second = None if first is None else halve(tm, qm, t1, q1)
        return None if second is None else [*first, (tm, qm), *second]

    return halve(ta, np.asarray(qa, float), tb, np.asarray(qb, float))


def walk_costs(pools, max_jump):
    """Edge costs of the layered graph: the joint distance where no joint jumps by more than max_jump, plus
    :data:`Z_TIE` times the mean z of its ends, so that of walks equally long (a branch and its copy shifted
    by whole turns on a wide joint) the one of lower z is chosen."""
    n = len(pools)
    out = []
    for k in range(n):
        A, B = np.array(pools[k].q), np.array(pools[(k + 1) % n].q)
        d = A[:, None, :] - B[None, :, :]
        za, zb = np.asarray(pools[k].z, float), np.asarray(pools[(k + 1) % n].z, float)
        c = np.linalg.norm(d, axis=2) + Z_TIE * 0.5 * (za[:, None] + zb[None, :])
        c[np.abs(d).max(axis=2) > max_jump] = np.inf
        out.append(c)
    return out


def refine_walk(inner, path, ts, period, pools, costs, refined, max_jump, budget, max_iter, tries=2):
    """Refine the infinite edges of each candidate toward its ``tries`` nearest successors; fills
    ``refined[(k, i, j)]`` with the inserted points and their cost into ``costs``."""
    n = len(pools)
    for k in range(n):
        tb = ts[k + 1] if k + 1 < n else period
        A, B = pools[k].q, pools[(k + 1) % n].q
        for i, qa in enumerate(A):
            dist = [float(np.linalg.norm(qb - qa)) for qb in B]
            for j in np.argsort(dist)[:tries]:
                if np.isfinite(costs[k][i, j]) or (k, i, int(j)) in refined:
                    continue
                pts = bisect_interval(inner, path, ts[k], qa, tb, B[j], max_jump, budget, max_iter)
                refined[(k, i, int(j))] = pts
                if pts is not None:
                    chain = [qa] + [q for _, q in pts] + [B[j]]
                    costs[k][i, j] = float(sum(np.linalg.norm(chain[m + 1] - chain[m]) for m in range(len(chain) - 1)))


def restrict_start(costs, i0: int | None) -> None:
    """With a start candidate i0 at sample 0: the walk leaves sample 0 from it and returns to it."""
    if i0 is not None:
        costs[0][np.arange(costs[0].shape[0]) != i0, :] = np.inf
        costs[-1][:, np.arange(costs[-1].shape[1]) != i0] = np.inf


def walk_knots(ts, pools, choice, refined):
    """The spline's knots (t, q, kind, branch) along the chosen walk."""
    n = len(ts)
    rows = []
    for k in range(n):
        i, j = choice[k], choice[(k + 1) % n]
        rows.append((ts[k], pools[k].q[i], "optimum", i))
        for tm, qm in refined.get((k, i, j)) or ():
            rows.append((tm, qm, "refined", -1))
    return rows


def off_optimum_intervals(ts, period, pools, choice, links, refined) -> tuple:
    """The intervals where the chosen walk is not the continuation of one minimum (module docstring)."""
    n = len(ts)
    out = []
    for k in range(n):
        i, j = choice[k], choice[(k + 1) % n]
        pair = frozenset((pools[k].label[i], pools[(k + 1) % n].label[j]))
        if refined.get((k, i, j)) or pair not in links:
            out.append((float(ts[k]), float(ts[k + 1] if k + 1 < n else period)))
    merged: list[list[float]] = []
    for a, b in out:
        if merged and abs(merged[-1][1] - a) < 1e-12:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    return tuple((a, b) for a, b in merged)


def choose(costs: list[np.ndarray]) -> tuple[list[int] | None, float]:
    """The cyclic sequence of candidates with the least total cost (dynamic programming over the start).

    Args:
        costs: costs[k][i, j] from candidate i at sample k to candidate j at sample k + 1 (the last
            matrix closes the loop back to sample 0).

    Returns:
        (the chosen candidate index per sample, the total cost); (None, inf) where no sequence is finite.
    """
    n = len(costs)
    best_total, best_path = np.inf, None
    for c0 in range(costs[0].shape[0]):
        acc = np.full(costs[0].shape[0], np.inf)
        acc[c0] = 0.0
        back = []
        for k in range(n - 1):
            tot = acc[:, None] + costs[k]
            back.append(np.argmin(tot, axis=0))
            acc = tot.min(axis=0)
        closing = acc + costs[n - 1][:, c0]
        j = int(np.argmin(closing))
        if closing[j] < best_total:
            path = [j]
            for k in range(n - 2, -1, -1):
                path.append(int(back[k][path[-1]]))
            best_total, best_path = float(closing[j]), path[::-1]
    return best_path, best_total
