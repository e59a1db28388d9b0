"""A Scene's distances held as general inequality rows: every checked pair kept its clearance apart (issue 27).

One row per pair the :class:`~kinredund.geometry.scene.Scene` checks (its enabled self pairs and its objects'
pairs), identified by the pair's position in ``scene.pairs``, so that a row keeps its number, and the active
set its meaning, from step to step while witness points and normals move:

    c_k(theta) = d_k(theta) - clearance_k >= 0,   grad c_k = G_k = n_k^T (J_b(p_b) - J_a(p_a)),

with d_k the signed distance [m] of pair k (coal, through ``scene.distance_rows``), n_k the unit normal from
its first object to its second and p_a, p_b the witness points. ``clearance_k`` is ``self_clearance`` for a
pair of two objects that move with the robot (its links, and objects attached to it) and ``clearance`` for a
pair with a world obstacle (MoveIt Servo's defaults: 1 cm and 2 cm).

Only pairs whose bounding spheres come within ``influence`` [m] are computed exactly (the Scene's
broadphase); any other pair is farther apart than ``influence``, and its row reports the lower bound
``influence - clearance_k`` > 0 with a zero gradient. Such a row is never near zero, so it is never active
and no switch is located on it; a pair is computed exactly from the step on which it comes within
``influence`` (the default, the largest clearance + 5 cm, is far beyond a step's motion).

Between steps the stepper asks only for the values, to see whether a row has been reached. While every row
is far from zero these need no query: along a straight joint path pair k's distance changes by at most
sum_j B_kj |dq_j| (``Scene.motion_bound``; between configurations whose prismatic joints are within the
extent of their limits, which it takes for their slides), so the last exact values lowered by that amount are
lower bounds; a query is made when one of them comes within :data:`SKIP_MARGIN` of zero, and always for rows,
gradients and curvature. So ``values`` (and the record's smallest value per point) are exact near the
clearances and lower bounds elsewhere: exact wherever the smallest value is at or below :data:`SKIP_MARGIN`; above
it, exact or a lower bound above :data:`SKIP_MARGIN`. On the compiled backend the record's smallest value at a step
the core's check ran on (:meth:`SceneClearance.row_guard`) is that check's (``RowGuard.smallest``: its values at the
step's end, kept and lowered row by row, computed afresh at or below :data:`SKIP_MARGIN`), with the same guarantee;
above :data:`SKIP_MARGIN` its lower bounds are its own, not the Python stepper's.

The curvature term (the rows' share of M in the system, :meth:`SceneClearance.curvature`) is by default
taken by central differences of the rows (``curvature="differences"``: the active rows' pairs at 2n points,
made only while a row is active; one call of the compiled core where the queries are compiled, else 2n queries of
the near pairs), the true Hessian of the distance where it is twice differentiable. The
alternative ``curvature="witness"`` holds the witness points fixed to their bodies: sum_k w_k n_k^T
(Hess p_b - Hess p_a) from the kinematics layer's point Hessians (``Scene.distance_curvature``). It ignores
the surfaces' curvature at the witness points and the turning of the normal, so it is exact between flat
faces only. That does not move the first-order conditions the corrector holds (the task, c_A = 0,
grad z + J^T lambda - G_A^T nu = 0), but M also gives the rates (Eq. 4.24) and with them the predictor:
for a 5 cm sphere against the Panda's upper-arm hull it was 0.24 where the true Hessian is 2.2 (the
sphere's curvature), and on one placement the corrector then failed (t = 3.64 s) where the differences
went on; on the named test case both hold the clearance.

Smoothness: a sphere (any strictly convex object) against a hull has a continuously differentiable distance
while apart, so its row changes continuously as the witness feature changes (a face, an edge, a vertex).
Between two polytopes (two hulls: the self pairs) it is not where faces or edges come parallel (the witness
points are not unique): there the distance is the least of two smooth pieces (one per end of the parallel
features), its gradient jumps, and where the optimum presses the two faces together (a finger's pad laid
flat on a link) it sits on that corner, which would need both pieces as rows. One row per pair cannot hold
it: the corrector, switching between the pieces, does not converge and the strict step control stops the
run (``collision``); :meth:`SceneClearance.discontinuities` finds the jump (bisection of the witness points)
and the stop's message says so (measured on the Panda's hulls, panda_elbow_circle: the right finger's pad
against panda_link2's hull, witness points jumping 1.5 cm across 5e-5 rad of joint 5), naming the corner where
the polytope's vertex nearest the other object changes between either side (decided by the vertices' own distances,
not by the witness points): the two vertices whose distances to the other object are the two pieces
(:mod:`kinredund.geometry.polytopes`; there the finger box's edge, vertices 5 and 7).

Holding such a corner needs one row per piece (the vertex pieces dist(v, B) of the parallel feature's ends, and
edge-edge pieces), and a pair's pieces that change as the contact moves over the hulls' facets (a vertex piece
hands over smoothly to an edge-edge one where the witness point leaves the vertex): a row's function may change
only where the stepper does not hold it or where the two agree to second order, which a constraint alone, asked
for values and gradients at points, cannot see.
"""

from __future__ import annotations

import threading

import numpy as np

from kinredund.errors import OptionError, check_choice
from kinredund.geometry.polytopes import vertex_corner, vertex_piece
from kinredund.geometry.scene import Scene
from kinredund.tracking.constraints.base import DIFFERENCE_STEP, Constraint, RowCheck, weighted_differences

#: how :meth:`SceneClearance.curvature` is taken (class docstring)
CURVATURES = ("differences", "witness")
#: a values-only query is skipped while every row's lower bound stays above this [m] (class docstring)
SKIP_MARGIN = 0.005
#: how many exact answers :meth:`SceneClearance._query` keeps per thread (the last q's, by their bytes)
KEPT_QUERIES = 8
#: the default broadphase reach beyond the largest clearance [m]
INFLUENCE_MARGIN = 0.05
#: a pair's witness points that move by more than JUMP [m] across a joint move of at most JUMP_STEP [rad]
#: (bisected down to it) have jumped: its distance is not differentiable there (:meth:`discontinuities`)
JUMP, JUMP_STEP = 1e-6, 1e-10


def _clearance(value, what: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not (np.isfinite(v) and v >= 0.0) or isinstance(value, bool):
        raise OptionError(f"{what} must be a finite distance >= 0 [m], got {value!r}")
    return v


class SceneClearance(Constraint):
    """Every pair ``scene`` checks kept ``clearance`` [m] apart (``self_clearance`` [m] for the robot's own).

    Args:
        scene: the :class:`~kinredund.geometry.scene.Scene` (its robot must be the tracked one). Do not change
            it (add, move, ignore) while the constraint is in use: its rows are the scene's pairs at
            construction.
        clearance: the least distance [m] between the robot (and what it carries) and a world obstacle.
        self_clearance: the least distance [m] between two of the robot's objects (attached ones included);
            None leaves the robot's own pairs unchecked.
        influence: the broadphase distance [m] (> the clearances): pairs surely farther apart are not computed.
            Default: the largest clearance + :data:`INFLUENCE_MARGIN`.
        curvature: ``"differences"`` (default) or ``"witness"``: how the rows' second derivatives are taken
            (module docstring).

    Raises:
        OptionError: not a Scene, a clearance < 0 or not finite, an influence not above the clearances, a
            scene that checks no pair (with these settings).
    """

    cause = "collision"

    def __init__(self, scene: Scene, clearance: float = 0.02, self_clearance: float | None = 0.01,
                 influence: float | None = None, curvature: str = "differences"):
        check_choice("curvature of the distance rows", curvature, CURVATURES)
        self.curvature_mode = curvature
        if not isinstance(scene, Scene):
            raise OptionError(f"scene must be a kinredund Scene, got {type(scene).__name__}")
        self.scene, self.clearance = scene, _clearance(clearance, "the clearance")
        self.self_clearance = None if self_clearance is None else _clearance(self_clearance, "the self clearance")
        moving = set(scene.robot_objects) | {o for o in scene.objects if scene.object(o).attach_to is not None}
        self._scene_pairs = scene.pairs
        index, clear, owns = [], [], []
        for k, (a, b) in enumerate(self._scene_pairs):
            own = a in moving and b in moving
            if own and self.self_clearance is None:
                continue
            index.append(k)
            clear.append(self.self_clearance if own else self.clearance)
            owns.append(own)
        if not index:
            raise OptionError("the scene checks no pair (add an object, or check the robot's own pairs with "
                              "self_clearance=...)")
        self.index, self.clearances = np.array(index), np.array(clear)
        self._own = np.array(owns)  # (the robot's own pair: start_hint)
        # the pairs its queries compute (None: every pair of the scene): the others are no row here
        self._only = None if len(index) == len(self._scene_pairs) else self.index.astype(np.int64)
        self.pairs = tuple(self._scene_pairs[k] for k in index)
        self._row = np.full(len(self._scene_pairs), -1)
        self._row[self.index] = np.arange(len(index))
        self._pair_index = {p: k for k, p in enumerate(self._scene_pairs)}
        top = float(self.clearances.max())
        self.influence = top + INFLUENCE_MARGIN if influence is None else _clearance(influence, "the influence")
        if not self.influence > top:
            raise OptionError(f"the influence ({self.influence} m) must exceed the largest clearance ({top} m): "
                              "a pair beyond it must not be able to be under its clearance")
        robot = scene.robot  # row k's distance changes by at most bound[k] @ |dq| between q in the box |q| <= extent
        self._extent = np.where(robot.revolute, np.inf, np.maximum(np.abs(robot.lower), np.abs(robot.upper)))
        self._bound = scene.motion_bound(self._extent)[self.index]
        self._slides = np.flatnonzero(np.isfinite(self._extent))  # the prismatic joints (the box's only sides)
        self._revolute = not len(self._slides)  # no side: every q is in the box
        self._local = threading.local()

    def __getstate__(self) -> dict:
        """Everything but this thread's last query (the scene pickles as what rebuilds it)."""
        return {k: v for k, v in self.__dict__.items() if k != "_local"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        if tuple(self.scene.pairs) != tuple(self._scene_pairs):
            raise OptionError("the unpickled scene checks other pairs than the pickled one (a robot or a pair "
                              "matrix that changed in between): make the SceneClearance again")
        self._scene_pairs = self.scene.pairs  # the rebuilt scene's own tuple (the guard compares identity)
        self._local = threading.local()

    @property
    def size(self) -> int:
        return len(self.index)

    # whose joints the rows are of (the scene's robot's): the tracker refuses the constraint on another robot
    # (tracker.check_constraints_robot), as it refuses scene= of another robot
    @property
    def robot_name(self) -> str:
        return self.scene.robot.name

    @property
    def joint_names(self) -> list[str]:
        return list(self.scene.robot.joint_names)

    @property
    def model(self):
        """The Pinocchio model (a ``pin.Model``) of the scene's robot."""
        return self.scene.robot.model

    def names(self) -> list[str]:
        return [f"{a} and {b} kept {c:.4g} m apart" for (a, b), c in zip(self.pairs, self.clearances, strict=True)]

    def start_hint(self, rows) -> str:
        """For the robot's own pairs: some are that close wherever the arm goes (two covers on one roll joint, a
        wrist's links; the default pair matrix leaves out only pairs in contact), which no start can clear."""
        own = [self.pairs[r] for r in rows if r < len(self._own) and self._own[r]]  # (a corner piece: none)
        if not own:
            return ""
        a, b = own[0]
        return (f"; of the robot's own pairs, one that is this close wherever the arm goes cannot be cleared: give a "
                f"smaller self_clearance (now {self.self_clearance:g} m), or leave the pair out (scene.ignore({a!r}, "
                f"{b!r}))")

    def _query(self, q: np.ndarray, rows: bool = True) -> tuple:
        """(the scene's record of this constraint's pairs within the influence (None for values only; the scene's
        other pairs are not computed), its entries that are rows here, their rows, c (size,), G (size, n) or None)
        at q; G only where ``rows`` (a values-only query skips the Jacobians and the record). Kept for the last q of
        this thread, by the bytes of q (the stepper asks for values, rows and curvature at one q; equal bytes are
        equal values, so a kept answer is never stale), which the lowered values start from; and the last
        :data:`KEPT_QUERIES` exact answers kept the same way (the stepper comes back to a point after trying
        others: a step's start, a corrector's iterate), each a query's numbers, so whether one is kept changes
        no value."""
        self._check_scene()
        q = np.asarray(q, float)
        key = q.tobytes()
        last = self._local.__dict__.get("last")
        if last is not None:
            if key == last[0] and (last[2][4] is not None or not rows):
                return last[2]
            if not rows and (self._revolute or (self._boxed(q) and self._boxed(last[1]))):
                # far from every clearance: the last exact values, lowered
                lower = last[2][3] - self._bound @ np.abs(q - last[1])
                if lower.min() > SKIP_MARGIN:
                    return (None, None, None, lower, None)
        kept = self._local.__dict__.setdefault("kept", {})
        out = kept.get(key)
        if out is not None and (out[4] is not None or not rows):
            self._local.last = (key, q.copy(), out)
            return out
        c = self.influence - self.clearances  # the lower bound of the pairs beyond the influence
        if rows:
            rec = self.scene.distance_rows(q, self.influence, self._only)
            keep = self._row[rec.index]
            mine = np.flatnonzero(keep >= 0)
            here = keep[mine]
            c[here] = rec.d[mine] - self.clearances[here]
            G = np.zeros((len(self.index), len(q)))  # (a subclass may add rows after these)
            G[here] = rec.G[mine]
            out = (rec, mine, here, c, G)
        else:  # the values alone: the pairs' positions and distances (no record, no names)
            index, d = self.scene.pair_distances(q, self.influence, self._only)
            keep = self._row[index]
            mine = keep >= 0
            here = keep[mine]
            c[here] = d[mine] - self.clearances[here]
            out = (None, None, None, c, None)
        kept[key] = out
        if len(kept) > KEPT_QUERIES:
            del kept[next(iter(kept))]  # the oldest
        self._local.last = (key, q.copy(), out)
        return out

    def _check_scene(self) -> None:
        if self.scene.pairs is not self._scene_pairs:
            raise OptionError("the scene was changed after its SceneClearance was made: make a new one")

    def _boxed(self, q: np.ndarray) -> bool:
        """Is q where the motion bound holds (no prismatic joint slid beyond its limits' extent)?"""
        k = self._slides
        return True if not len(k) else bool(np.all(np.abs(q[k]) <= self._extent[k]))

    def values(self, q: np.ndarray) -> np.ndarray:
        return self._query(q, rows=False)[3].copy()

    def segment_lower_bounds(self, q0, q1, c0, c1, move) -> np.ndarray | None:
        """(c0 + c1 - B move) / 2 [m]: pair k's distance changes by at most B_k . |dq| along the way
        (``Scene.motion_bound``), so at any point of it c_k >= c0_k - B_k . m0 and >= c1_k - B_k . m1 with
        m0 + m1 <= move; None where q0 or q1 slid a prismatic joint beyond its limits' extent."""
        if not (self._revolute or (self._boxed(np.asarray(q0, float)) and self._boxed(np.asarray(q1, float)))):
            return None
        return 0.5 * (np.asarray(c0) + np.asarray(c1) - self._bound @ np.asarray(move, float))

    def gradients(self, q: np.ndarray) -> np.ndarray:
        return self._query(q)[4].copy()

    def row_guard(self, tol: float):
        """The compiled check of a step (``kinredund._core.RowGuard`` on a workspace of its own): the lowered values
        of :meth:`_query` (exact below :data:`SKIP_MARGIN`) and the test of :meth:`segment_lower_bounds`, in C++;
        None where the scene's queries run in Python, and for a subclass (its rows, values or bounds may differ from
        the ones the check knows: it gives its own check, or none)."""
        if type(self) is not SceneClearance:
            return None
        guard = self.scene.workspace(own=True).row_guard(self._row, self.clearances, self.influence, self._bound,
                                                         self._extent, tol, SKIP_MARGIN)
        return None if guard is None else _SceneGuard(guard, self.scene, self._scene_pairs,
                                                      self.curvature_mode == "differences")

    def rows_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        out = self._query(q)
        return out[3].copy(), out[4].copy()

    def distance(self, q: np.ndarray) -> np.ndarray:
        """The pairs' distances d [m] (size,), the ones beyond the influence as the lower bound ``influence``."""
        return self._query(q, rows=False)[3] + self.clearances

    def curvature(self, q: np.ndarray, w: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """sum_i w_i Hess c_i over ``rows``: central differences of the rows (``curvature="differences"``,
        the true Hessian where the distance is twice differentiable), or ``"witness"``: sum_i w_i n_i^T
        (Hess p_b - Hess p_a), the witness points fixed to their bodies (the surfaces' curvature left out:
        module docstring); rows beyond the influence contribute nothing.

        The differences are :meth:`Constraint.curvature`'s of :meth:`gradients`; where the scene's queries are
        compiled they are one call of the core (``Workspace.differences``) that computes only the pairs of
        ``rows`` at each point, each row as the full query computes it, summed as :meth:`Constraint.curvature` sums
        them (:func:`~kinredund.tracking.constraints.base.weighted_differences`): the same numbers; it leaves this
        thread's last query (at q) kept.

        Raises:
            OptionError: a row out of range, not one weight per row, or the scene changed after the constraint was
                made.
        """
        if self.curvature_mode == "differences":
            rows, w = np.asarray(rows, int), np.asarray(w, float)
            if rows.ndim != 1 or w.shape != rows.shape or (len(rows) and not (rows.min() >= 0
                                                                       and rows.max() < len(self.index))):
                raise OptionError(f"rows must be rows 0..{len(self.index) - 1} of the scene's pairs and w one weight "
                                  f"per row, got rows {rows.tolist()} and w {w.tolist()}")
            self._check_scene()  # (the compiled differences compute the scene's pairs directly)
            D = self.scene.workspace().differences(np.asarray(q, float), self.influence, self.index[rows],
                                                   DIFFERENCE_STEP)
            return super().curvature(q, w, rows) if D is None else weighted_differences(w, D)
        rec, mine, here, _, _ = self._query(q)
        weight = np.zeros(len(rec.pairs))
        pos = {int(r): int(k) for r, k in zip(here, mine, strict=True)}
        for wi, r in zip(np.asarray(w, float), np.asarray(rows, int), strict=True):
            if int(r) in pos:
                weight[pos[int(r)]] += wi
        if not np.any(weight):
            return np.zeros((len(q), len(q)))
        return self.scene.distance_curvature(np.asarray(q, float), rec, weight)

    def discontinuities(self, q: np.ndarray, dq: np.ndarray, rows) -> list[str]:
        """The rows among ``rows`` whose witness points jump on the segment q -> q + dq (module docstring).

        Per row: where the pair's witness points at the ends differ by more than :data:`JUMP`, the segment is
        bisected towards the half where they move more, down to :data:`JUMP_STEP` [rad]; witness points that
        still differ by more than :data:`JUMP` there have jumped (a continuous motion shrinks with the segment).
        """
        q, dq, out = np.asarray(q, float), np.asarray(dq, float), []
        for i in rows:
            pair = self.pairs[int(i)]
            cache = self._local.__dict__.setdefault("only", {})  # this thread's one-pair scenes
            one = cache.get(pair) or cache.setdefault(pair, self.scene.only([pair]))

            def witness(x, one=one):
                rec = one.distances(x)
                return np.concatenate([rec.point_a[0], rec.point_b[0]])

            a, b = q, q + dq
            wa, wb = witness(a), witness(b)
            if not np.linalg.norm(wb - wa) > JUMP:
                continue
            while np.abs(b - a).max() > JUMP_STEP:
                m = 0.5 * (a + b)
                wm = witness(m)
                a, wa, b, wb = (a, wa, m, wm) if np.linalg.norm(wm - wa) >= np.linalg.norm(wb - wm) else (m, wm, b, wb)
            jump = float(np.linalg.norm(wb - wa))
            if jump > JUMP:
                away = float(np.abs(a - q).max())
                note = _corner_note(one, pair, a, b)
                out.append(f"the distance of {pair[0]} and {pair[1]} is not differentiable {away:.2g} rad from a "
                           f"last good point: its witness points jump by {jump:.3g} m there (faces or edges of the two "
                           f"convex shapes parallel{note}), a corner one row per pair cannot hold")
        return out


class _SceneGuard(RowCheck):
    """:meth:`SceneClearance.row_guard`'s check for the scene as it was when the constraint was made: after a change
    of the scene it clears no step (the stepper's search then meets :meth:`SceneClearance._query`'s error). It holds
    the rows (``holds``) where their curvature is the central differences (``curvature="differences"``: the core
    computes those, not the witness form)."""

    __slots__ = ("_scene", "_pairs")

    def __init__(self, guard, scene: Scene, pairs: tuple, holds: bool):
        super().__init__(guard, holds, settles=False)  # compiled: the kinredund._core.RowGuard
        self._scene, self._pairs = scene, pairs

    def valid(self) -> bool:
        """Is the scene still the one the check was made for?"""
        return self._scene.pairs is self._pairs


def _corner_note(one: Scene, pair: tuple[str, str], a: np.ndarray, b: np.ndarray) -> str:
    """What the corner between a and b is, where a polytope's vertex nearest the other object changes between either
    side (the two ends of a parallel edge or face: :func:`~kinredund.geometry.polytopes.vertex_corner`), with the
    two vertex pieces' distances and how far apart their rates are at the midpoint; '' otherwise."""
    step = 1e-6 * (b - a) / np.abs(b - a).max()  # 1e-6 rad either side: clear of the parallel point itself
    corner = vertex_corner(one, 0, a - step, b + step)
    if corner is None:
        return ""
    side, i, j = corner
    m = 0.5 * (a + b)
    (di, gi), (dj, gj) = vertex_piece(one, 0, side, i, m), vertex_piece(one, 0, side, j, m)
    return (f": the least there of the distances of {pair[side]}'s vertices {i} and {j} to {pair[1 - side]}, "
            f"{di:.6g} and {dj:.6g} m, whose rates differ by {np.linalg.norm(gi - gj):.3g} m/rad")

