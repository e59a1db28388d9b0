"""A collision scene as a constraint of the cyclic planner (:func:`kinredund.planning.cyclic.plan`, issue 27).

``plan(..., scene=, clearance=, self_clearance=)`` keeps every pair the scene checks apart: ``clearance`` [m]
between the robot (and what it carries) and a world obstacle, ``self_clearance`` [m] between two of the
robot's own objects (None: those pairs unchecked). The per-pair clearances are the tracker's own
(:class:`~kinredund.tracking.constraints.scene.SceneClearance`), so the three places a plan holds them agree:

1. **Candidates** (:meth:`Keepout.margins`, :meth:`Keepout.minimum`): a within-limits minimum of z whose
   distance to some pair is under that pair's clearance is not a candidate (from the scene's own distances);
   from it the bounded joint-level IK with the distance rows as constraints
   (:func:`~kinredund.ik.rows.solve_ik_rows`) finds the minimum of z that keeps the clearances, the constrained
   optimum the tracker holds, which is (where it converges to a strict minimum and keeps every clearance). The
   walk's continuation then joins these as one branch, so a stretch where a clearance is active is no
   ``off_optimum`` stretch.
2. **Tracking**: the planned motion is tracked with the scene's distances as exact inequality constraints
   (``track(..., scene=, clearance=, self_clearance=)``).
3. **Verification** (:func:`verify_clearance`): independently of the tracker, each recorded point's distances
   afresh (``scene.distances``, every checked pair exactly) against its clearance within
   :data:`POINT_TOL`, and the stretches between the recorded points (joints linear) by
   :func:`~kinredund.geometry.motion.check_motion`, which proves them to within ``resolution``: the plan's
   motion keeps at least ``clearance - resolution`` between its points. The check runs on the scene's own
   geometry (its ``geometry``, said in the result): with convex hulls (the default) a hull is never farther
   than its mesh, so a clearance proven on the hulls holds on the exact meshes.

Units: times [s], joints [rad or m], distances [m].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kinredund.geometry.motion import check_motion
from kinredund.tracking.constraints.scene import SceneClearance

#: a recorded point keeps its clearance to this [m]: the tracker's corrector holds an active row to ~1e-12
POINT_TOL = 1e-9


@dataclass(frozen=True)
class ClearanceCheck:
    """The clearance verification of a planned motion (:func:`verify_clearance`).

    Attributes:
        ok: every recorded point keeps its pairs' clearances (within :data:`POINT_TOL`) and the motion between
            them keeps at least clearance - ``resolution``.
        point_margin: min over recorded points and pairs of (distance - clearance) [m].
        point_pair, point_time: that pair and its time [s].
        between_margin: min over the motion between points of (least distance - clearance) [m], per group of
            pairs (world and self), as proven by ``check_motion`` to within ``resolution``.
        between_pair, between_time: that pair and its time [s].
        geometry: the scene geometry checked (``convex`` hulls, or exact ``mesh``\\ es).
        resolution: the between-points resolution [m].
    """

    ok: bool
    point_margin: float
    point_pair: tuple[str, str] | None
    point_time: float
    between_margin: float
    between_pair: tuple[str, str] | None
    between_time: float
    geometry: str
    resolution: float

    def reason(self) -> str:
        """'' when ok, else which pair comes under its clearance, when and by how much."""
        if self.ok:
            return ""
        if self.point_margin < -POINT_TOL:
            a, b = self.point_pair
            return (f"the motion comes under the clearance: {a} and {b} at t = {self.point_time:.6g} s, "
                    f"{-self.point_margin:.3g} m under it")
        a, b = self.between_pair
        return (f"the motion between recorded points comes under the clearance: {a} and {b} near t = "
                f"{self.between_time:.6g} s, {-self.between_margin:.3g} m under it (resolution {self.resolution:g} m)")

    def to_dict(self) -> dict:
        """JSON-ready figures."""
        return {"ok": self.ok, "point_margin": self.point_margin, "point_pair": self.point_pair,
                "point_time": self.point_time, "between_margin": self.between_margin,
                "between_pair": self.between_pair, "between_time": self.between_time, "geometry": self.geometry,
                "resolution": self.resolution}


class Keepout:
    """The scene of a plan and its per-pair clearances (the tracker's :class:`SceneClearance` rows).

    Args:
        constraint: the :class:`~kinredund.tracking.constraints.scene.SceneClearance` of the plan's options.
        resolution: how closely the motion between recorded points is checked [m].
    """

    def __init__(self, constraint: SceneClearance, resolution: float):
        self.constraint, self.scene, self.resolution = constraint, constraint.scene, float(resolution)
        self._clear = dict(zip(constraint.pairs, constraint.clearances.tolist(), strict=True))

    def margins(self, q) -> tuple[float, tuple[str, str]]:
        """(min over checked pairs of distance - clearance [m], that pair) at q, every pair exactly."""
        rec = self.scene.distances(np.asarray(q, float))
        best, pair = np.inf, None
        for p, d in zip(rec.pairs, rec.distance.tolist(), strict=True):
            c = self._clear.get(p)
            if c is not None and d - c < best:
                best, pair = d - c, p
        return float(best), pair

    def minimum(self, robot, target, index, q) -> tuple[np.ndarray, float] | None:
        """(q, z) of the within-limits minimum of z on ``target`` that keeps every clearance, from ``q``
        (:func:`~kinredund.ik.rows.solve_ik_rows` with the scene's rows), or None where it does not converge to
        a strict minimum or some pair stays under its clearance (every pair checked exactly)."""
        from kinredund.ik.rows import solve_ik_rows

        res = solve_ik_rows(robot, target, index, [self.constraint], q)
        if not res.converged or self.margins(res.q)[0] < -POINT_TOL:
            return None
        return res.q, float(res.objective)

    def groups(self) -> list[tuple[set, float]]:
        """(pairs, clearance) per distinct clearance: the pairs check_motion checks together."""
        out: dict[float, set] = {}
        for p, c in self._clear.items():
            out.setdefault(c, set()).add(p)
        return [(pairs, c) for c, pairs in sorted(out.items())]


def verify_clearance(keep: Keepout, t, q) -> ClearanceCheck:
    """The module docstring's step 3 on the recorded motion (t, q): at the points, and between them."""
    t, q = np.asarray(t, float), np.atleast_2d(np.asarray(q, float))
    point = [keep.margins(qk) for qk in q]
    k = int(np.argmin([m for m, _ in point]))
    between, pair_b, time_b = np.inf, None, float("nan")
    for pairs, c in keep.groups():
        found = check_motion(keep.scene.only(pairs), t, q, resolution=0.5 * keep.resolution)  # to r/2
        if found.min_distance - c < between:
            between, pair_b, time_b = found.min_distance - c, found.min_pair, found.min_time
    ok = point[k][0] >= -POINT_TOL and between >= -0.5 * keep.resolution  # so the true minimum >= c - resolution
    return ClearanceCheck(bool(ok), float(point[k][0]), point[k][1], float(t[k]), float(between), pair_b, time_b,
                          keep.scene.geometry, keep.resolution)


def with_clearance(accept, keep: Keepout | None):
    """``accept(trajectory)`` and, with a keepout, its :func:`verify_clearance` passing too."""
    if keep is None:
        return accept
    return lambda tr: accept(tr) and verify_clearance(keep, tr.t, tr.q).ok
