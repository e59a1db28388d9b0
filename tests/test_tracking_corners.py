"""Pairs of polytopes held piece by piece (issue 27): a finger's edge laid flat on a link's hull face, held.

Named configuration: test_tracking_self_clearance's FLAT (on ``panda_elbow_circle`` held 1 cm off itself), where
the right finger box's edge (vertices 5 and 7) comes parallel to a face of panda_link2's hull within 5e-5 rad of
joint 5: the pair's distance is the least of the two vertex pieces there, a corner. Named case: the run of
test_tracking_scene's ``test_the_hand_into_the_upper_arm_is_held_then_stops_named`` (the whole Panda held 1 cm
off itself), which stops ``collision`` at that corner with one row per pair; with
:class:`~kinredund.CornerClearance` it gets further and still stops, named (the slow test says where).

Bars: the issue's (1e-9 m clearance at every recorded point and switching time, from coal's pair distances
afresh; 1e-9 first-order conditions with the active piece rows, their gradients by central
differences of coal's vertex distances, step 1e-6 rad: O(1e-12) truncation for a distance whose second
derivative is O(1) m/rad^2, plus coal's 1e-9 GJK tolerance / 1e-6 = 1e-3 relative in the worst case, hence the
1e-6 m/rad bar on the rows themselves).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from test_tracking_limits import case
from test_tracking_self_clearance import FLAT

import kinredund as kr
from kinredund.errors import OptionError
from kinredund.geometry.polytopes import placed_pair, vertex_distances

PAIR = ("panda_link2_0", "panda_rightfinger_3")
SELF_CLEARANCE = 0.01


@functools.cache
def constraint() -> kr.CornerClearance:
    return kr.CornerClearance(kr.Scene(kr.load_robot("panda", task="position")), self_clearance=SELF_CLEARANCE)


def vertex_distance(sc: kr.Scene, k: int, side: int, i: int, q) -> float:
    """Vertex i of pair k's object ``side`` to the other object at q [m], from coal (independent of the rows)."""
    sc.distances(q)
    sc.workspace().place(np.asarray(q, float))
    return float(vertex_distances(placed_pair(sc, k), side, [i])[0][0])


def piece_row(c: kr.CornerClearance, pair, side: int, i: int) -> int:
    j = list(c.held).index(c.pairs.index(pair))
    start, mid, _ = c._offsets[j]
    return (start, mid)[side] + i


def test_the_corner_is_the_least_of_two_smooth_pieces():
    """At FLAT +- 1e-4 rad of joint 5 (either side of the corner) the pair's own row is its distance, the least of
    its vertex rows (to coal's 1e-9), and stands for a different one of the finger's vertices 5 and 7 either side;
    those are exact rows whose gradients are central differences of coal's vertex distances (1e-6 m/rad), each
    smooth across the corner while the two rates differ."""
    c = constraint()
    sc = c.scene
    k = sc.pairs.index(PAIR)
    r = c.pairs.index(PAIR)
    j = list(c.held).index(r)
    start, _, end = c._offsets[j]
    e = np.eye(7)
    grads, stands = [], []
    for s in (-1.0, 1.0):
        q = np.array(FLAT) + s * 1e-4 * e[4]
        vals, G = c.rows_at(q)
        d = sc.distances(q).as_dict()[PAIR]
        assert abs(vals[r] - (d - SELF_CLEARANCE)) <= 1e-9 and abs(vals[start: end].min() - vals[r]) <= 1e-9
        stands.append(c.representative(q, r))
        for i in (5, 7):
            row = piece_row(c, PAIR, 1, i)
            assert abs(vals[row] - (vertex_distance(sc, k, 1, i, q) - SELF_CLEARANCE)) <= 1e-9
            fd = np.array([(vertex_distance(sc, k, 1, i, q + 1e-6 * x) - vertex_distance(sc, k, 1, i, q - 1e-6 * x))
                           / 2e-6 for x in e])
            assert np.abs(G[row] - fd).max() <= 1e-6
        grads.append(G[[piece_row(c, PAIR, 1, 5), piece_row(c, PAIR, 1, 7)]])
    assert sorted(stands) == sorted(piece_row(c, PAIR, 1, i) for i in (5, 7))  # the corner: the realising vertex
    assert np.abs(grads[0] - grads[1]).max() <= 1e-3  # each piece smooth across the corner (2e-4 rad apart)
    assert np.linalg.norm(grads[0][0] - grads[0][1]) > 0.01  # the two rates differ (0.022 m/rad): the corner


#: the named case's configuration where the left finger's edge (vertices 5 and 7, both on their rows' zero) lies
#: across a ridge of panda_link1_0's hull (t = 6.94095 s of the CornerClearance run)
RIDGE = [-0.029090122586550284, -1.2718651994063495, -0.017369157206159194, -2.7519487946631633,
         -0.0124061351060702, 0.706328982931735, 0.7945438316220923]


def test_the_pair_row_stands_for_itself_only_edge_to_edge():
    """At FLAT the pair's row is realised at a vertex (it equals that vertex's row: not its own); at RIDGE the left
    finger's pair is 1.35e-6 m under both end vertices' rows (which are on zero): an edge-to-edge contact, where
    the pair's row stands for itself, its rate between the ends' (coal's witness inside the edge)."""
    c = constraint()
    left = ("panda_link1_0", "panda_leftfinger_3")
    r = c.pairs.index(left)
    vals, G = c.rows_at(np.array(RIDGE))
    ends = [piece_row(c, left, 1, i) for i in (5, 7)]
    assert np.all(np.abs(vals[ends]) <= 1e-12) and -2e-6 < vals[r] < -1e-6
    assert c.representative(np.array(RIDGE), r) == r
    s = np.linalg.lstsq(G[ends].T, G[r], rcond=None)[0]  # the pair's rate: a combination of the ends' to 1e-3
    assert np.linalg.norm(G[ends].T @ s - G[r]) <= 1e-3 * np.linalg.norm(G[r]) and np.all(s > 0)
    flat = c.pairs.index(PAIR)
    assert c.representative(np.array(FLAT), flat) != flat


def test_the_rows_are_named_and_pairs_checked():
    c = constraint()
    names = c.names()
    assert len(names) == c.size > len(c.pairs)
    assert names[piece_row(c, PAIR, 1, 7)].endswith("kept 0.01 m apart: panda_rightfinger_3's vertex 7")
    with pytest.raises(OptionError, match="not one this constraint checks"):
        kr.CornerClearance(c.scene, self_clearance=SELF_CLEARANCE, pairs=[("panda_link2_0", "nothing")])


def test_without_held_pairs_it_is_the_scene_clearance():
    c = constraint()
    plain = kr.SceneClearance(c.scene, self_clearance=SELF_CLEARANCE)
    none = kr.CornerClearance(c.scene, self_clearance=SELF_CLEARANCE, pairs=[])
    q = np.array(FLAT)
    assert none.size == plain.size and none.names() == plain.names()
    for a, b in zip(none.rows_at(q), plain.rows_at(q), strict=True):
        assert np.array_equal(a, b)


def test_segment_bounds_hold_inside_a_step():
    """The piece rows' lower bounds along a 0.02 rad move are under the values sampled inside it."""
    c = constraint()
    q0 = np.array(FLAT)
    q1 = q0 + 0.02 * np.array([0.3, -0.5, 0.2, 0.4, 1.0, -0.6, 0.1])
    c0, c1 = c.values(q0), c.values(q1)
    bound = c.segment_lower_bounds(q0, q1, c0, c1, np.abs(q1 - q0))
    for s in np.linspace(0.0, 1.0, 9):
        assert np.all(c.values(q0 + s * (q1 - q0)) >= bound - 1e-12)


@pytest.mark.slow
def test_the_hand_into_the_upper_arm_passes_the_corner_then_stops_at_the_fold_named():
    """On the run that stops at the corner with one row per pair, the corner of (panda_link2_0,
    panda_rightfinger_3) is met piece by piece (its vertex 5 reached, vertex 7 released) and the left finger's edge
    is handed from its vertex's row to the pair's (edge to edge across a ridge of link1's hull) and back; the right
    finger's vertex 7 row, crossing zero inside steps the step control rejects for a predicted fold, is reached there
    (located before the fold is declared). The optimum held on both fingers' vertex 7 rows then ends in a fold
    (pieces.py's docstring): continued independently from the last good sub-step point, its branch turns back in t
    with the reduced Hessian's eigenvalue (the rows' curvature included) crossing zero, the active set still valid
    (multipliers > 0, every other row >= 0, [J; G_A] regular). The run stops there, cause ``collision`` (a row
    active), underlying ``fold``, its last good sub-step point before the fold and within one floor sub-step of it,
    the failed attempt past it; the watched eigenvalue there is the independent one; the partial record keeps 1 cm
    at every point and switching time, and the first-order conditions hold on it with the active piece rows."""
    r, path, index, q0 = case("panda_elbow_circle")
    c = kr.CornerClearance(kr.Scene(r), self_clearance=SELF_CLEARANCE)
    with pytest.raises(kr.TrackingError) as err:
        kr.track(r, path, index, q0, constraints=[c])
    e = err.value
    w = e.watched
    assert e.cause == "collision" and w["underlying_cause"] == "fold" and 6.9 < e.t < path.period
    sw = [s for s in e.partial.meta["switches"] if s.get("constraint")]
    assert "panda_link2_0 and panda_rightfinger_3 kept 0.01 m apart: panda_rightfinger_3's vertex 5" in \
        [s["name"] for s in sw]
    assert min(c.scene.distances(np.array(s["q"])).min_distance for s in sw) >= SELF_CLEARANCE - 1e-9
    assert any("panda_link1_0 and panda_leftfinger_3" in n for n in w["constraints"])
    q, t = np.array(w["substep_q"]), w["substep_t"]
    assert c.scene.distances(q).min_distance >= SELF_CLEARANCE - 1e-9
    held = [i for i in np.flatnonzero(np.abs(c.values(q)) <= 1e-9) if i >= len(c.pairs)]  # piece rows at zero
    assert [c.names()[i].rsplit("'s ", 1)[1] for i in held] == ["vertex 7", "vertex 7"]  # both fingers'
    branch = _held_branch(r, path, index, c, q, t, held)
    assert abs(branch[0][1] - w["substep_reduced_hessian_min"]) <= 1e-6  # 0.553: the watch's is the true one
    top = int(np.argmax([b[0] for b in branch]))
    t_fold = branch[top][0]
    assert 0 < top < len(branch) - 1 and branch[top + 1][1] < 0.0 < branch[top - 1][1]  # the minimum turns: a fold
    assert all(b[2] > 0.01 and b[3] > 0.0 and b[4] >= -1e-12 for b in branch[: top + 1])
    assert t < t_fold < w["t_failed"] and t_fold - t <= w["min_substep"]  # 7.02512 < 7.02538 < 7.02577 s
    part = e.partial
    assert min(c.scene.distances(q).min_distance for q in part.q) >= SELF_CLEARANCE - 1e-9
    worst, seen = _kkt(r, index, part, c)
    assert seen > 10 and worst <= 1e-9


def _held_branch(r, path, index, c, q, t, rows, ds=2e-3) -> list[tuple]:
    """The optimum held on ``rows`` from (q, t) on, by pseudo-arclength continuation of its first-order conditions
    grad z + J^T lambda - G^T nu = 0, p(q) = x(t), c_rows(q) = 0 in (q, lambda, nu, t) (scaled 1, 1e-2, 1e-2, 1e2;
    step ``ds``), their Jacobian by central differences (1e-6 in the scaled variables: the rows' gradients, exact,
    differenced once), through the turn in t and three points beyond. Per point (t, the smallest eigenvalue of
    Z^T W Z with W the Lagrangian's Hessian and Z a null basis of [J; G_rows], sigma_min([J; G_rows]), the least
    multiplier nu, the least value of all the constraint's rows)."""
    n, k = len(q), len(rows)
    D = np.concatenate([np.ones(n), np.full(3 + k, 1e-2), [1e2]])

    def F(y):
        x = y / D
        qq, lam, nu, tt = x[:n], x[n: n + 3], x[n + 3: -1], x[-1]
        _, p, K = r.kinematics.jacobian(qq)
        vals, G = c.rows_at(qq)
        grad = index.evaluate(qq, tt)[1] + K[3:].T @ lam - G[rows].T @ nu
        return np.concatenate([grad, p - path.sample(tt).p, vals[rows]])

    def jac(y):
        return np.array([(F(y + 1e-6 * e) - F(y - 1e-6 * e)) / 2e-6 for e in np.eye(len(y))]).T

    def point(y):
        A = jac(y)
        W, B = A[:n, :n], A[n:, :n]  # the Lagrangian's Hessian, [J; G_rows] (the q columns are unscaled)
        sv, Vt = np.linalg.svd(B)[1:]
        Z = Vt[len(B):].T
        x = y / D
        return (x[-1], float(np.linalg.eigvalsh(Z.T @ (0.5 * (W + W.T)) @ Z)[0]), float(sv[-1]),
                float(x[n + 3: -1].min()), float(c.values(x[:n]).min()))

    _, _, K = r.kinematics.jacobian(q)
    G = c.rows_at(q)[1][rows]
    mult = np.linalg.lstsq(np.vstack([K[3:], -G]).T, -index.evaluate(q, t)[1], rcond=None)[0]
    y = D * np.concatenate([q, mult, [t]])
    tangent = None
    out = [point(y)]
    while len(out) < 200:
        tn = np.linalg.svd(jac(y))[2][-1]
        tangent = tn * (1.0 if (tn[-1] if tangent is None else tn @ tangent) > 0 else -1.0)
        y0 = y + ds * tangent
        y = y0.copy()
        for _ in range(20):
            f = np.concatenate([F(y), [tangent @ (y - y0)]])
            if np.linalg.norm(f) <= 1e-11:
                break
            y = y - np.linalg.solve(np.vstack([jac(y), tangent]), f)
        else:
            raise AssertionError(f"the continuation's corrector failed at t = {y[-1] / D[-1]:.8f} s")
        out.append(point(y))
        top = int(np.argmax([o[0] for o in out]))
        if top < len(out) - 3:
            return out
    raise AssertionError("the held branch does not turn back in t within 200 steps")


def _kkt(r, index, tr, c) -> tuple[float, int]:
    """(the largest ||Z^T grad z||, the points with a row active), Z a null basis of [J; G_active; e_fixed] with
    each active piece row's gradient by central differences of coal's vertex distance (the scene's own rows for
    the others); the active rows' least-squares multipliers >= -1e-9."""
    from test_tracking_clearance import kkt_check
    from test_tracking_scene import _Row

    class _Piece:
        def __init__(self, i):
            self.i = i

        def gradients(self, q):
            j = int(np.searchsorted([o[0] for o in c._offsets], self.i, side="right")) - 1
            start, mid, _ = c._offsets[j]
            k = int(c.index[c.held[j]])
            side, v = (0, self.i - start) if self.i < mid else (1, self.i - mid)
            e = np.eye(len(q))
            return np.array([[(vertex_distance(c.scene, k, side, v, q + 1e-6 * x)
                               - vertex_distance(c.scene, k, side, v, q - 1e-6 * x)) / 2e-6 for x in e]])

    rows = [_Row(c, i) if i < len(c.pairs) else _Piece(i) for i in range(c.size)]  # (the pairs' own: the scene's)
    return kkt_check(r, index, tr, rows)
