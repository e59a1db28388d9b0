"""Steps 1-2 of the cyclic planner (:func:`kinredund.planning.cyclic.plan`): the candidates at the sample
times and the closed walk through them, with the samples refined where the walk breaks.

:class:`CandidateSet` holds, per sample time, the within-limits local minima of z (Eq. 4.3 with the
joint limits as bounds) in a :class:`~kinredund.planning.walk.CandidatePool`, and the pairs of candidates
one continuation joined (the same branch). :meth:`CandidateSet.collect` fills them (a forward sweep
with the robot's home and random starts, the loop closed, a backward sweep); :meth:`CandidateSet.closed_walk`
finds the shortest closed walk with joint jumps below ``max_jump``, bisecting long edges (Section 6.2.2.1,
:func:`~kinredund.planning.walk.refine_walk`); where none exists, :meth:`CandidateSet.insert_sample` adds a
sample time in the middle of each interval the walk cannot cross, within the user's ``refine_samples``
budget (:class:`~kinredund.planning.options.PlanOptions`), before the planner says why it failed.

Units: times [s], joints [rad or m].
"""

from __future__ import annotations

import numpy as np

from kinredund.ik.solve import solve_ik
from kinredund.planning.walk import (
    CandidatePool,
    choose,
    continue_candidates,
    inside_limits,
    local_minimum,
    refine_walk,
    restrict_start,
    target_at,
    walk_costs,
)

#: after the first sample, whose random starts all run (they find the branches), a sample's random starts stop
#: after this many in a row that add no candidate to a pool the neighbours' continuation has filled: most
#: starts then reach no minimum or one the pool holds (about half the planner's IK time before), and a branch
#: that appears later is still found by the starts that do run and continued backward (:meth:`collect`)
SEED_PATIENCE = 2


class CandidateSet:
    """The samples of one plan: times, targets, candidate pools and the branch links between them.

    Attributes:
        ts: the sample times [s], increasing, in [0, period).
        targets: the task targets there.
        pools: the candidates per sample.
        links: pairs of candidate labels one continuation joined.
        start: the label of the start candidate at sample 0 (from ``q0``) or None.
        added: the samples inserted where the walk broke.
        keepout: the plan's scene and clearances (:class:`~kinredund.planning.keepout.Keepout`) or None: a
            minimum under a clearance is not a candidate; the minimum that keeps them, found from it by the
            bounded IK with the distance rows (:meth:`kinredund.planning.keepout.Keepout.minimum`), is.
        rejected: (pair, distance - clearance [m]) of the last minimum rejected so, or None.
        rejections: how many minima were rejected so.
        collided: a sample had no candidate while minima were rejected there for their clearance.
    """

    def __init__(self, inner, path, index, opt, ts, keepout=None):
        self.inner, self.path, self.index, self.opt = inner, path, index, opt
        self.period = float(path.period)
        self.ts = [float(t) for t in ts]
        self.targets = [target_at(inner, path, t) for t in self.ts]
        self.pools = [CandidatePool() for _ in self.ts]
        self.links: set = set()
        self.counter = [0]
        self.start: int | None = None
        self.added = 0
        self.rng = np.random.default_rng(opt.seed)
        self.box = inner.sample_box()
        self.keepout, self.rejected, self.rejections, self.collided = keepout, None, 0, False
        self._keep = None if keepout is None else self._clear
        self._hold = None if keepout is None else self._held

    def _clear(self, q) -> bool:
        """The keepout's verdict on a minimum, the last rejection remembered for the failure's message."""
        margin, pair = self.keepout.margins(q)
        if margin < 0.0:
            self.rejected, self.rejections = (pair, margin), self.rejections + 1
        return margin >= 0.0

    def _held(self, target, q) -> tuple | None:
        """The minimum that keeps the clearances from a minimum under them, or None
        (:meth:`kinredund.planning.keepout.Keepout.minimum`)."""
        return self.keepout.minimum(self.inner, target, self.index, q)

    def _minimum(self, k: int, seed) -> tuple | None:
        return local_minimum(self.inner, self.targets[k], self.index, seed, self.opt.max_iter, self._keep, self._hold)

    def _continue(self, a: int, b: int) -> None:
        continue_candidates(self.inner, self.targets, self.index, self.pools, a, b, self.links, self.counter,
                            self.opt.max_iter, self._keep, self._hold)

    def _seed_pool(self, k: int, tries: int, seed: int, patience: int | None = None) -> None:
        """Random starts at sample k; where none reaches a minimum, a within-limits point on the path from a
        pose-only multi-start seeds one. With ``patience``, a pool that holds candidates already (continued from
        the neighbours) stops after that many starts in a row that add none (no minimum, or one it holds)."""
        pool, idle = self.pools[k], 0
        for _ in range(tries):
            before = len(pool.q)
            pool.add(self._minimum(k, self.rng.uniform(*self.box)), self.counter)
            idle = idle + 1 if len(pool.q) == before and before > 0 else 0
            if patience is not None and idle >= patience:
                break
        if not self.pools[k].q:
            feasible = solve_ik(self.inner, self.targets[k], None, bounds=True, starts=4 * self.opt.starts, seed=seed)
            if feasible.converged:
                self.pools[k].add(self._minimum(k, feasible.q), self.counter)

    def under_clearance(self) -> str:
        """'' without rejections, else how many minima were rejected for their clearance and the last one's pair."""
        if self.rejected is None:
            return ""
        (a, b), margin = self.rejected
        return (f"{self.rejections} minima under the clearance were no candidates; the last: {a} and {b} "
                f"{-margin:.3g} m under it")

    def start_from(self, q0) -> bool:
        """The start candidate: the within-limits minimum reached from q0 at sample 0 (False: none)."""
        self.start = self.pools[0].add(self._minimum(0, q0), self.counter)
        return self.start >= 0

    def collect(self) -> str:
        """Step 1: the candidates at every sample; '' or why a sample has none."""
        n, opt = len(self.ts), self.opt
        for k in range(n):
            before = self.rejections
            if k > 0:
                self._continue(k - 1, k)
            tries = opt.starts * (4 if k == 0 else 1)
            if k == 0 and inside_limits(self.inner, self.inner.home):  # the robot's home seeds the first sample too
                self.pools[0].add(self._minimum(0, self.inner.home), self.counter)
            self._seed_pool(k, tries, opt.seed + k, None if k == 0 else SEED_PATIENCE)
            if not self.pools[k].q and self.rejections > before:
                self.collided = True
                return (f"sample {k + 1} of {n} (t = {self.ts[k]:.4g} s): every within-limits local minimum of the "
                        f"index found there is under the clearance ({self.under_clearance()})")
            if not self.pools[k].q:
                return (f"sample {k + 1} of {n} (t = {self.ts[k]:.4g} s) has no within-limits local minimum of the "
                        f"index ({tries} random starts and the previous sample's minima): the path may leave the "
                        "reachable set there")
            self.pools[k].trim(opt.max_candidates, keep=self.start if k == 0 else None)
        self._continue(n - 1, 0)  # close the loop
        for k in range(n - 1, 0, -1):  # backward: branches first found late, continued to the earlier samples
            self._continue(k, k - 1)
        self._continue(0, n - 1)
        for k, pool in enumerate(self.pools):
            pool.trim(2 * opt.max_candidates, keep=self.start if k == 0 else None)
        return ""

    def end(self, k: int) -> float:
        """The end time of interval k [s] (the next sample, or the period after the last)."""
        return self.ts[k + 1] if k + 1 < len(self.ts) else self.period

    def closed_walk(self) -> tuple:
        """Step 2: (choice, refined, costs) of the shortest closed walk, choice None where there is none."""
        opt = self.opt
        costs = walk_costs(self.pools, opt.max_jump)
        i0 = None if self.start is None else self.pools[0].label.index(self.start)
        restrict_start(costs, i0)
        refined: dict = {}
        choice, total = choose(costs)
        if choice is None or not np.isfinite(total):
            refine_walk(self.inner, self.path, np.array(self.ts), self.period, self.pools, costs, refined,
                        opt.max_jump, opt.budget, opt.max_iter)
            restrict_start(costs, i0)
            choice, total = choose(costs)
        return (choice if choice is not None and np.isfinite(total) else None), refined, costs

    def broken(self, costs) -> list[int]:
        """The intervals the walk cannot cross: no finite edge at all; else those where a candidate has no
        finite edge onward (a branch ending in a fold between the samples)."""
        n = len(self.ts)
        none = [k for k in range(n) if not np.isfinite(costs[k]).any()]
        return none or [k for k in range(n) if not np.isfinite(costs[k]).any(axis=1).all()]

    def insert_sample(self, k: int) -> bool:
        """A sample in the middle of interval k, its candidates continued from both neighbours and from random
        starts (False, nothing inserted, where it has none)."""
        tm = 0.5 * (self.ts[k] + self.end(k))
        nb = (k + 1) % len(self.ts)
        self.ts.insert(k + 1, tm)
        self.targets.insert(k + 1, target_at(self.inner, self.path, tm))
        self.pools.insert(k + 1, CandidatePool())
        m, after = k + 1, (nb + 1 if nb > k else nb)  # the neighbours' indices after the insertion
        for side in (k, after):
            self._continue(side, m)
            self._continue(m, side)
        self._seed_pool(m, self.opt.starts, self.opt.seed + len(self.ts), SEED_PATIENCE)
        if not self.pools[m].q:
            del self.ts[m], self.targets[m], self.pools[m]
            return False
        self.pools[m].trim(2 * self.opt.max_candidates)
        self.added += 1
        return True

    def refined_walk(self) -> tuple:
        """:meth:`closed_walk`, with samples inserted where it breaks within the ``refine_samples`` budget."""
        choice, refined, costs = self.closed_walk()
        while choice is None and self.added < self.opt.refine_samples:
            room = self.opt.refine_samples - self.added
            inserted = [k for k in sorted(self.broken(costs), reverse=True)[:room] if self.insert_sample(k)]
            if not inserted:
                break
            choice, refined, costs = self.closed_walk()
        return choice, refined, costs
