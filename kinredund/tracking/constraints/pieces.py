"""A Scene's pairs of polytopes held piece by piece: faces that come parallel held at their clearance (issue 27).

The distance of two convex polytopes A and B is the least of its pieces (:mod:`kinredund.geometry.polytopes`):
the distances psi_v = dist(v, B) of A's vertices, psi_w = dist(w, A) of B's, and the distance of an edge of A to
an edge of B where it is realised between the edges' interiors,

    d = min( min_v psi_v, min_w psi_w, chi ),   every piece >= d,

so d >= clearance exactly where every piece is. Each vertex piece is continuously differentiable while the vertex
is outside the other polytope (a point against a convex set: rate n^T (J_b(p_b) - J_a(p_a)) at the vertex and its
nearest point), so the pair's corners, where an edge or face of one comes parallel to a face of the other and d is
the least of two or more vertex pieces with different rates, are held as two or more smooth active rows.
:class:`CornerClearance` is :class:`~kinredund.tracking.constraints.scene.SceneClearance` with the pairs of two
polytopes (boxes, convex hulls) held that way: per such pair one row per vertex of either object (keys (pair,
object, vertex): their numbers never change), after the scene's rows. The pair's own row (d, SceneClearance's,
unchanged) stays: it is the edge-to-edge piece where that realises d, and elsewhere it equals its least vertex
piece (to coal's rounding, ~1e-16 m; measured), value and rate.

Two rows that are the same contact (equal values and rates: the pair's row and its realising vertex's, a vertex
against a vertex) are never held together (their gradients would be one row twice): the stepper swaps one for the
other where one reaches zero with the other active (:meth:`~kinredund.tracking.rows.GeneralRows._twin`), and
holds a vertex row rather than the pair's row it equals at the start of each step
(:meth:`CornerClearance.representative`). So an edge-to-edge contact that slides onto a vertex, and back, is a
hand-over of one row to the other at the point where they agree to first order, and a corner is held as its two
(or more) vertex rows.

What is held, and what not yet (measured on ``panda_elbow_circle``, tests/test_tracking_corners.py): the corner of
panda_link2_0 and the right finger is met (its vertex 5 reached at t = 6.93596 s, vertex 7 released 0.5 ms later);
the left finger's edge, held at vertex 7 on panda_link1_0's hull, comes across a ridge of that hull (two nearly
coplanar facets): the pair's row leaves vertex 7's at t = 6.94032 s and takes its place (the pair's row is not an
event while it equals a vertex row: :meth:`~kinredund.tracking.rows.GeneralRows._row_watch`; its own reach inside
a step is looked for before the first switch), and is held as vertex 5's from t = 6.95165 s and back again at
6.98481 s. With the left pair's row and the right finger's vertex 5 active, sigma_min of [J; G_A] falls 0.04 ->
0.021 and the step control predicts a fold at 7.02298 s; the right finger's vertex 7 row crosses zero inside the
sub-steps of that step (t = 7.00394 s): the step control looks for a switch inside a step it rejects for the watch
before it declares the fold (:meth:`~kinredund.tracking.switches.SwitchLocation.switch_within`), so that reach is
located and the fold prediction, the old active set's, goes (vertex 5 and the left pair's row are released there, the
left finger's vertex 7 held). There the optimum held on both fingers' vertex 7 rows (each equal to its pair's row to
1e-16 m) ends in a fold: continued independently (pseudo-arclength on its first-order conditions, the rows'
curvature by differences of their gradients: tests/test_tracking_corners.py's ``_held_branch``), its branch turns
back in t at t* = 7.025379 s, where the smallest eigenvalue of Z^T (Hess z + Lambda - sum_i nu_i Hess c_i) Z passes
zero (0.553 at 7.02512 s, 0.011 at the turn, negative on the saddle branch beyond it), the active set still valid
(multipliers 4.6 and 7.5, every other row positive, sigma_min of [J; G_A] 0.0124): no missed switch, no
discontinuous row (both rows' gradients agree with central differences of coal's vertex distances to 1e-10 m/rad
within 0.02 rad of the stop) and no singularity. Multi-start SQP (:func:`~kinredund.ik.rows.solve_ik_rows` with the
scene's rows, 25 starts) agrees: it finds this branch's minimum at 7.0253 and 7.02537 s (eigenvalue 0.37, 0.15) and
not at 7.0254, 7.0256 or 7.026 s, where a minimum 0.025 rad away (eigenvalue 1.02) and a distant one (0.23 rad, lower
z) remain. So the local optimum followed ends there, and no row per piece can hold it further: going on is a jump.

The eigenvalue's square falls ever faster towards t* (0.971 at 7.02185 s, 0.753 at 7.02446 s, 0.553 at 7.02512 s;
eig^2 / (t* - t) grows from 620 to 2600 1/s between 7.02446 s and 3 us before t*), so the watch's extrapolation from
its last two values (eig^2 linear) puts the crossing late, at 7.02588 s; the floor
sub-step (0.65 ms at 200 steps per loop) from 7.02512 s is tried, lands past t*, and its corrector diverges (longer
sub-steps land on the other minimum: the jump check rejects them). The run stops at its last requested time
(6.99353 s), cause ``collision`` (a row active), underlying ``fold``: its last good sub-step point 0.26 ms before t*,
the failed attempt at 7.02577 s past it. The fold is named because the stop looks a whole step ahead and takes the
crossing predicted first (:meth:`~kinredund.tracking.watch.Watch.ahead`: the eigenvalue's, before sigma_min's at
7.02623 s; it took sigma_min's, checked first, and said ``kinematic_singularity`` before). At 800 steps per loop the
run stops at the same fold as a jump at the floor (0.0225 rad in 0.164 ms from 7.02527 s), and the plain
SceneClearance (one row per pair, the same two contacts) also as a jump (from 7.02494 s, attempt to 7.02559 s).
"""

from __future__ import annotations

import numpy as np

from kinredund.errors import OptionError
from kinredund.geometry.polytopes import placed_pair, polytope, vertex_distances, vertex_lower_bounds
from kinredund.geometry.scene import Scene
from kinredund.tracking.constraints.scene import SceneClearance

#: pieces within this of their clearance [m] are computed exactly (module docstring)
PIECE_MARGIN = 0.01
#: a pair's distance within this of its least vertex piece [m] is realised at that vertex (coal agrees to ~1e-16)
VERTEX_GAP = 1e-12


class CornerClearance(SceneClearance):
    """:class:`~kinredund.tracking.constraints.scene.SceneClearance` with its pairs of two polytopes held as one row
    per piece (module docstring): their corners (faces that come parallel) held exactly.

    Args:
        scene, clearance, self_clearance, influence, curvature: as for SceneClearance.
        pairs: the pairs (names, as in ``scene.pairs``) held piece by piece; default every checked pair of two
            polytopes (boxes and convex hulls without a swept radius).

    Raises:
        OptionError: as SceneClearance; a pair that the constraint does not check or that is not two polytopes.
    """

    def __init__(self, scene: Scene, clearance: float = 0.02, self_clearance: float | None = 0.01,
                 influence: float | None = None, curvature: str = "differences", pairs=None):
        super().__init__(scene, clearance, self_clearance, influence, curvature)
        ws = scene.workspace()
        shapes = [p for p in (polytope(g.geometry) for g in ws.geometry.geometryObjects)]

        def sides(r):
            k = int(self.index[r])
            return k, shapes[int(ws.first[k])], shapes[int(ws.second[k])]

        if pairs is None:
            held = [r for r in range(super().size) if None not in sides(r)[1:]]
        else:
            held = []
            for p in pairs:
                p = tuple(p)
                if p not in self.pairs:
                    raise OptionError(f"pair {p} is not one this constraint checks (e.g. {self.pairs[0]})")
                r = self.pairs.index(p)
                if None in sides(r)[1:]:
                    raise OptionError(f"pair {p} is not two polytopes (boxes or convex hulls): it has no vertex pieces")
                held.append(r)
        self.held = np.array(sorted(set(held)), int)
        counts = [(len(sides(r)[1].vertices), len(sides(r)[2].vertices)) for r in self.held]
        start, offsets = super().size, []
        for na, nb in counts:
            offsets.append((start, start + na, start + na + nb))  # A's vertices, then B's
            start += na + nb
        self._offsets, self._total = offsets, start
        owner = np.full(start, -1)
        for j, (a, _, e) in enumerate(offsets):
            owner[a: e] = self.held[j]
        self._owner = owner  # each piece row's pair row (for its motion bound and clearance)

    @property
    def size(self) -> int:
        return self._total

    def names(self) -> list[str]:
        base = super().names()
        out = list(base)
        for j, r in enumerate(self.held):
            a, b = self.pairs[r]
            start, mid, end = self._offsets[j]
            out += [f"{base[r]}: {a}'s vertex {i}" for i in range(mid - start)]
            out += [f"{base[r]}: {b}'s vertex {i}" for i in range(end - mid)]
        return out

    def _pieces(self, q: np.ndarray, rows: bool) -> tuple:
        """(c (size,), G (size, n) or None) at q (module docstring), kept for this thread's last q."""
        q = np.asarray(q, float)
        key = (q.tobytes(), rows)
        last = self._local.__dict__.get("pieces")
        if last is not None and (last[0] == key or (last[0][0] == key[0] and last[0][1])):
            return last[1]
        rec, mine, here, c0, G0 = self._query(q, rows)
        c = np.empty(self._total)
        c[: len(c0)] = c0
        G = None
        if rows:
            G = np.zeros((self._total, len(q)))
            G[: len(c0)] = G0
        near = [j for j, r in enumerate(self.held) if c0[r] <= PIECE_MARGIN]
        for j, r in enumerate(self.held):
            start, _, end = self._offsets[j]
            c[start: end] = c0[r]  # a lower bound of every piece (the near pairs' are made exact below)
        if near:
            ws = self.scene.workspace()
            ws.place(q)
            for j in near:
                self._near_pair(ws, q, j, c, G)
        out = (c, G)
        self._local.pieces = (key, out)
        return out

    def _near_pair(self, ws, q, j, c, G) -> None:
        """Pair ``held[j]``'s piece rows into c (and G) at q, the workspace placed there (module docstring)."""
        r = int(self.held[j])
        k, clear = int(self.index[r]), float(self.clearances[r])
        objects = placed_pair(self.scene, k)
        start, mid, _ = self._offsets[j]
        for side, first in ((0, start), (1, mid)):
            bound = vertex_lower_bounds(objects, side) - clear
            c[first: first + len(bound)] = bound
            exact = np.flatnonzero(bound <= PIECE_MARGIN)
            if not len(exact):
                continue
            psi, pa, pb = vertex_distances(objects, side, exact)
            c[first + exact] = psi - clear
            if G is not None:
                n = pb - pa
                n /= np.linalg.norm(n, axis=1)[:, None]
                G[first + exact] = ws.rows(np.full(len(exact), k), n, np.vstack([pa, pb]))

    def values(self, q: np.ndarray) -> np.ndarray:
        return self._pieces(q, rows=False)[0].copy()

    def gradients(self, q: np.ndarray) -> np.ndarray:
        return self._pieces(q, rows=True)[1].copy()

    def rows_at(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c, G = self._pieces(q, rows=True)
        return c.copy(), G.copy()

    def segment_lower_bounds(self, q0, q1, c0, c1, move) -> np.ndarray | None:
        """SceneClearance's bounds for its rows, and per piece row (c0 + c1 - B_k move) / 2 with B_k its pair's
        motion bound (a piece moves no faster than the pair's objects)."""
        m = super().size
        base = super().segment_lower_bounds(q0, q1, np.asarray(c0)[:m], np.asarray(c1)[:m], move)
        if base is None:
            return None
        step = self._bound[self._owner.clip(0)] @ np.asarray(move, float)
        out = 0.5 * (np.asarray(c0, float) + np.asarray(c1, float) - step)
        out[:m] = base
        return out

    def curvature(self, q: np.ndarray, w: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """SceneClearance's for its rows, central differences of the gradients for the piece rows."""
        m, rows, w = super().size, np.asarray(rows, int), np.asarray(w, float)
        own = rows < m
        H = super().curvature(q, w[own], rows[own]) if np.any(own) else np.zeros((len(q), len(q)))
        if not np.all(own):
            H = H + self._differences(q, w[~own], rows[~own])
        return H

    def _differences(self, q, w, rows) -> np.ndarray:
        """sum_i w_i Hess c_i over piece ``rows``: central differences of their gradients (step 1e-6)."""
        return super(SceneClearance, self).curvature(q, w, rows)

    def representative(self, q: np.ndarray, row: int) -> int:
        """The row that stands for ``row`` at q when another row joins it: for a held pair's own row realised at a
        vertex (within :data:`VERTEX_GAP` of its least vertex piece) that vertex's row, else ``row`` itself."""
        r = int(row)
        if r >= super().size or r not in self.held:
            return r
        c, _ = self._pieces(q, rows=True)
        start, _, end = self._offsets[list(self.held).index(r)]
        i = start + int(np.argmin(c[start: end]))
        return i if c[i] <= c[r] + VERTEX_GAP else r

    def discontinuities(self, q: np.ndarray, dq: np.ndarray, rows) -> list[str]:
        """SceneClearance's for its rows (the piece rows are smooth: module docstring)."""
        m = super().size
        return super().discontinuities(q, dq, [r for r in rows if int(r) < m])
