"""Convex polytopes of a scene's objects: vertices and outward face planes in the object's frame (issue 27).

The distance of two convex polytopes A and B is the least of finitely many pieces: the distances of A's vertices
to B, of B's vertices to A, and of A's edges to B's edges,

    d = min( min_v psi_v, min_w psi'_w, min_(e, f) chi_ef ),   psi_v = dist(v, B)  (:func:`vertex_piece`),

each piece >= d (a part of A against B). A vertex piece is continuously differentiable while apart (a point
against a convex set), its rate n^T (J_b(y) - J_a(v)) with y the point of B nearest v and n the unit vector from
v to y. Where an edge or a face of A comes parallel to a face of B (a finger's flat pad against a link's hull
face), the lowest vertex of the parallel feature changes: coal's witness points jump, and d is there the least
of two vertex pieces with different rates, a corner of d (:func:`vertex_corner` names it). Along the outward
normal m of a face plane of B (m . x <= o on B) the least height min_v (m . v - o) of A's vertices is a lower
bound of d (the separating axis theorem), equal to it where d is realised on that face.

Boxes and convex hulls are polytopes (a hull's planes from its vertices by qhull: coal's own stored normals and
offsets of a ``Convex`` are not outward planes in this convention); spheres, capsules and cylinders are not
taken (None).
"""

from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np


@dataclass(frozen=True)
class Polytope:
    """A convex polytope in its object's frame.

    Attributes:
        vertices: (V, 3) [m].
        normals: (F, 3) outward unit normals of its face planes.
        offsets: (F,) [m]: every point x of the polytope has normals @ x <= offsets.
    """

    vertices: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray

    def placed(self, rotation: np.ndarray, translation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(vertices, normals, offsets) in the world for the object at pose (rotation, translation)."""
        N = self.normals @ rotation.T
        return self.vertices @ rotation.T + translation, N, self.offsets + N @ translation


def polytope(geometry) -> Polytope | None:
    """The :class:`Polytope` of a coal shape (a Box or a Convex), or None for any other shape."""
    if isinstance(geometry, coal.Box) and geometry.getSweptSphereRadius() == 0.0:
        h = np.asarray(geometry.halfSide, float)
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        return Polytope(signs * h, np.vstack([np.eye(3), -np.eye(3)]), np.concatenate([h, h]))
    if isinstance(geometry, coal.ConvexBase) and geometry.getSweptSphereRadius() == 0.0:
        from scipy.spatial import ConvexHull

        V = np.array([geometry.point(i) for i in range(geometry.num_points)], float)
        eq = ConvexHull(V).equations  # n . x + e <= 0 on the hull, n outward unit
        return Polytope(V, eq[:, :3].copy(), -eq[:, 3])
    return None


def placed_pair(scene, k: int) -> tuple:
    """Pair k's objects (``scene.pairs[k]``) where this thread's last query of ``scene`` placed them: per object its
    polytope's (vertices, normals, offsets) in the world [m] (None: not a polytope), its coal shape and world pose."""
    ws = scene.workspace()
    out = []
    for i in (int(ws.first[k]), int(ws.second[k])):
        shape, M = ws.geometry.geometryObjects[i].geometry, ws.gdata.oMg[i]
        if i not in ws.polytopes:
            ws.polytopes[i] = polytope(shape)
        p = ws.polytopes[i]
        out.append((None if p is None else p.placed(M.rotation, M.translation), shape,
                    coal.Transform3s(M.rotation, M.translation)))
    return tuple(out)


def vertex_lower_bounds(objects, side: int) -> np.ndarray:
    """Lower bounds [m] (V,) of the distances of the vertices of ``objects[side]`` (a :func:`placed_pair`) to the
    other object: per vertex max_f (m_f . v - o_f) over the other's face planes (separating planes; exact where the
    nearest point is on a face's interior)."""
    V, (_, N, o) = objects[side][0][0], objects[1 - side][0]
    return np.max(V @ N.T - o, axis=1)


def vertex_distances(objects, side: int, which) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(psi [m] (m,), p_a (m, 3), p_b (m, 3)): the distances of the vertices ``which`` of ``objects[side]`` (a
    :func:`placed_pair`) to the other object and their nearest points, p_a on the pair's first object (coal, each
    vertex as a sphere of radius 0; signed: < 0 for a vertex inside the other object)."""
    V = objects[side][0][0]
    _, shape, pose = objects[1 - side]
    req = coal.DistanceRequest()
    req.enable_signed_distance, req.gjk_tolerance = True, 1e-9
    psi, pa, pb = np.empty(len(which)), np.empty((len(which), 3)), np.empty((len(which), 3))
    for m, i in enumerate(which):
        v = V[i]
        res = coal.DistanceResult()
        psi[m] = coal.distance(shape, pose, _POINT, coal.Transform3s(np.eye(3), v), req, res)
        y = np.array(res.getNearestPoint1())
        pa[m], pb[m] = (v, y) if side == 0 else (y, v)
    return psi, pa, pb


def vertex_piece(scene, k: int, side: int, i: int, q) -> tuple[float, np.ndarray]:
    """(psi [m], its row (n,) [m/rad]): the distance of vertex i of pair k's object ``side`` (0 its first, 1 its
    second: ``scene.pairs[k]``) to the pair's other object at q, and its rate n^T (J_b(p_b) - J_a(p_a)) with the
    nearest points (coal, the vertex as a sphere of radius 0). The vertex must be outside the other object (the row's
    normal is the unit vector between the two points)."""
    q = scene.distances(q).q  # (validated) places this thread's workspace at q
    psi, pa, pb = vertex_distances(placed_pair(scene, k), side, [i])
    n = (pb[0] - pa[0]) / np.linalg.norm(pb[0] - pa[0])
    ws = scene.workspace()
    ws.place(q)
    return float(psi[0]), ws.rows(np.array([k]), n[None], np.vstack([pa, pb]))[0]


#: a vertex is at the pair's distance within this [m] (vertex_corner)
VERTEX_TOL = 1e-7


def nearest_vertex(objects, side: int, d: float) -> int | None:
    """The vertex of ``objects[side]`` (a :func:`placed_pair` of two polytopes) nearest the other object, where its
    distance is the pair's distance ``d`` [m] to :data:`VERTEX_TOL`; None where every vertex is farther (the pair's
    distance realised on an edge's or a face's interior alone). Decided by the vertices' own distances (coal's
    distance of each vertex as a point; :func:`vertex_lower_bounds` rule out the far ones), not by the pair's witness
    points, which near a parallel edge or face coal may put anywhere along it."""
    which = np.flatnonzero(vertex_lower_bounds(objects, side) <= d + VERTEX_TOL)
    if not len(which):
        return None
    psi = vertex_distances(objects, side, which)[0]
    best = int(np.argmin(psi))
    return int(which[best]) if psi[best] <= d + VERTEX_TOL else None


def vertex_corner(scene, k: int, before, after) -> tuple[int, int, int] | None:
    """(side, i, j) where the vertex of pair k's object ``side`` nearest the other object, at the pair's distance
    (:func:`nearest_vertex`), is vertex i at configuration ``before`` and vertex j != i at ``after``: the two ends of an
    edge or face of that polytope lying parallel to the other object between the two (its distance the least of the
    two vertex pieces there); None otherwise (not two polytopes, or no such change of vertex)."""
    ends = []
    for q in (before, after):
        rec = scene.distances(q)
        objects = placed_pair(scene, k)
        if objects[0][0] is None or objects[1][0] is None:
            return None
        d = float(rec.distance[rec.index(*scene.pairs[k])])
        ends.append([nearest_vertex(objects, side, d) for side in (0, 1)])
    for side in (0, 1):
        i, j = ends[0][side], ends[1][side]
        if i is not None and j is not None and i != j:
            return side, i, j
    return None


_POINT = coal.Sphere(0.0)
