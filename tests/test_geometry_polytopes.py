"""Polytope pieces of a distance (issue 27): where two hulls' features come parallel, the distance is the least of
two vertex pieces with different rates.

The named configuration is test_tracking_self_clearance's FLAT (on panda_elbow_circle, held 1 cm off itself): the
right finger's box has an edge nearly parallel to a face of panda_link2's hull, and across 1e-4 rad of joint 5
coal's witness point on the finger jumps between the edge's two ends (vertices 5 and 7). Checked here: the two
vertex pieces (each vertex's distance to the hull, coal) give the pair's distance as their least to GJK's
accuracy across the jump, each piece's row against central differences of its value on either side, the rows
differing at the corner (so one row per pair cannot hold it), the planes outward, and the separating-axis lower
bound of the module docstring. Also a regression: a distance-rows query with no pair within the influence on the
Python path (it raised ValueError from a reshape).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from test_tracking_self_clearance import FLAT

import kinredund as kr
from kinredund.geometry.engine import GJK_TOLERANCE
from kinredund.geometry.polytopes import placed_pair, polytope, vertex_corner, vertex_piece

PAIR = ("panda_link2_0", "panda_rightfinger_3")
#: GJK's stopping gap on separated distances (kind 2 of the tolerance policy), as tests/test_geometry_scene.py
DIST_TOL = 10 * GJK_TOLERANCE


@functools.cache
def one_pair() -> kr.Scene:
    r = kr.load_robot("panda", task="position")
    return kr.Scene(r).only([PAIR])


def swept(dq5: float) -> np.ndarray:
    q = np.array(FLAT)
    q[4] += dq5
    return q


def test_planes_are_outward_faces_of_every_object():
    """Every vertex of each of the Panda's polytopes is on or under each face plane, and each plane touches one."""
    sc = kr.Scene(kr.load_robot("panda"))
    for g in sc.workspace().geometry.geometryObjects:
        p = polytope(g.geometry)
        assert p is not None, g.name  # hulls and boxes
        heights = p.vertices @ p.normals.T - p.offsets  # (V, F)
        assert heights.max() <= 1e-12 and np.abs(heights.max(axis=0)).max() <= 1e-12
        assert np.allclose(np.linalg.norm(p.normals, axis=1), 1.0, atol=1e-12)
    assert polytope(kr.geometry.shapes.sphere(0.1)) is None


def test_the_jump_is_the_least_of_two_vertex_pieces():
    """Across the jump coal's distance is min(psi_5, psi_7) to GJK's accuracy, the lower piece switching where the
    witness point jumps; vertex_corner names the two vertices."""
    sc = one_pair()
    seen = set()
    for dq5 in np.linspace(0.0, 1e-4, 21):
        q = swept(dq5)
        d = sc.distances(q).distance[0]
        p5, p7 = vertex_piece(sc, 0, 1, 5, q)[0], vertex_piece(sc, 0, 1, 7, q)[0]
        assert abs(d - min(p5, p7)) <= DIST_TOL
        seen.add(int(p7 < p5))
    assert seen == {0, 1}  # both pieces lowest in turn
    assert vertex_corner(sc, 0, swept(0.0), swept(1e-4)) == (1, 5, 7)
    assert vertex_corner(sc, 0, swept(0.0), swept(1e-5)) is None  # the same vertex: no corner between
    # decided by the vertices' own distances, not coal's witness points (anywhere along a parallel edge): the same
    # answer from configurations a few ulps apart, and about the parallel point itself
    rng = np.random.default_rng(7)
    for _ in range(5):
        ulps = rng.integers(-4, 5, size=(2, 7)) * np.spacing(swept(0.0))
        assert vertex_corner(sc, 0, swept(0.0) + ulps[0], swept(1e-4) + ulps[1]) == (1, 5, 7)
    crossing = next(d for d in np.linspace(0.0, 1e-4, 201) if vertex_piece(sc, 0, 1, 7, swept(d))[0]
                    < vertex_piece(sc, 0, 1, 5, swept(d))[0])
    assert vertex_corner(sc, 0, swept(crossing - 1e-6), swept(crossing + 1e-6)) == (1, 5, 7)


@pytest.mark.parametrize("dq5", [0.0, 1e-4])
def test_each_piece_is_smooth_and_their_rows_differ(dq5):
    """Each vertex piece's row n^T (J_b(p_b) - J_a(p_a)) against central differences of its value (step 1e-6:
    O(1e-12) truncation, O(1e-10) rounding: bar 1e-8) on either side of the jump, and the two rows differ by
    far more at the corner: the distance's gradient jumps there."""
    sc = one_pair()
    q, E = swept(dq5), 1e-6 * np.eye(7)
    rows = {}
    for v in (5, 7):
        psi, row = vertex_piece(sc, 0, 1, v, q)
        fd = np.array([(vertex_piece(sc, 0, 1, v, q + e)[0] - vertex_piece(sc, 0, 1, v, q - e)[0]) / 2e-6 for e in E])
        assert np.abs(row - fd).max() <= 1e-8
        rows[v] = row
    assert np.linalg.norm(rows[5] - rows[7]) > 0.01


def test_face_planes_give_lower_bounds_of_the_distance():
    """The separating axis: along any face plane of one polytope, the other's lowest vertex height is <= the
    distance (random configurations; the bound is tight on the named pair, where d is realised on a face)."""
    r = kr.load_robot("panda", task="position")
    sc = kr.Scene(r)
    rng = np.random.default_rng(2)
    tight = []
    for _ in range(10):
        q = np.clip(np.array(FLAT) + rng.normal(0.0, 0.2, 7), r.lower, r.upper)
        rec = sc.distances(q)
        for k in range(len(sc.pairs)):
            ((Va, Na, Oa), _, _), ((Vb, Nb, Ob), _, _) = placed_pair(sc, k)
            bound = max((Va @ Nb.T - Ob).min(axis=0).max(), (Vb @ Na.T - Oa).min(axis=0).max())
            d = rec.distance[k]
            assert bound <= d + DIST_TOL, sc.pairs[k]
            tight.append(d - bound)
    assert min(tight) <= DIST_TOL  # somewhere the distance is realised on a face


@pytest.mark.parametrize("compiled", [False, True])
def test_distance_rows_with_no_pair_within_the_influence(compiled):
    """No pair within the influence: empty rows of the robot's width (the Python path raised ValueError)."""
    if compiled and kr.geometry.engine.compiled_core() is None:
        pytest.skip("kinredund was installed without its compiled core")
    r = kr.load_robot("panda")
    sc = kr.Scene(r, compiled=compiled)
    rec = sc.distance_rows(r.home, influence=0.0)
    assert rec.pairs == () and rec.G.shape == (0, r.nq) and len(rec.d) == 0
