"""SceneClearance's answer kept for the last configuration (issue 27's step cost): never a stale one.

The constraint keeps its last query, keyed by the bytes of q, and between queries answers a values-only call
with the last exact values lowered by the motion bound (``Scene.motion_bound``). Each test here fails if a kept
answer were returned for another configuration: the same array changed in place, a configuration one rounding
step away, and a move towards an obstacle (where the last values are above the new distances, so only a lowered
or a fresh answer is below them). A fresh SceneClearance (nothing kept) gives the reference; the two compute the
same numbers the same way, so they agree to rounding (kind 1 of the tolerance policy).
"""

from __future__ import annotations

import numpy as np
from conftest import robot, rounding

import kinredund as kr

#: a 5 cm ball ahead of the Panda's hand at its home pose [m], and the clearances [m]
BALL, RADIUS, CLEARANCE, SELF = [0.5, 0.0, 0.66], 0.05, 0.02, 0.01


def _scene():
    r = robot("panda")
    sc = kr.Scene(r)
    sc.add_sphere("ball", RADIUS, BALL)
    return r, sc


def _fresh(sc) -> kr.SceneClearance:
    return kr.SceneClearance(sc, CLEARANCE, SELF)


def test_an_array_changed_in_place_is_queried_again():
    r, sc = _scene()
    con = _fresh(sc)
    q = r.home.copy()
    con.rows_at(q)
    q[3] += 0.3  # the same array object, other numbers
    c, G = con.rows_at(q)
    c_ref, G_ref = _fresh(sc).rows_at(q.copy())
    assert np.abs(c - c_ref).max() <= rounding(1.0)
    assert np.abs(G - G_ref).max() <= rounding(1.0)
    # and the values at that q are the kept exact ones, not the ones before the change
    assert np.abs(con.values(q) - c_ref).max() <= rounding(1.0)


def test_one_rounding_step_away_is_another_configuration():
    """A q one rounding step from the kept one is queried afresh (counted: the numbers barely differ), the same
    numbers in another array are not."""
    r, sc = _scene()
    con = _fresh(sc)
    calls, query = [0], sc.distance_rows

    def counted(*args, **kwargs):
        calls[0] += 1
        return query(*args, **kwargs)

    sc.distance_rows = counted
    q = r.home.copy()
    con.rows_at(q)
    con.rows_at(q.copy())  # equal numbers: kept
    assert calls[0] == 1
    q1 = q.copy()
    q1[0] = np.nextafter(q1[0], np.inf)
    _, G1 = con.rows_at(q1)
    assert calls[0] == 2
    assert np.abs(G1 - _fresh(sc).rows_at(q1)[1]).max() <= rounding(1.0)


def test_values_towards_an_obstacle_are_below_the_distance():
    """Moving the hand towards the ball: the kept values (from farther away) would be above the new distances;
    what comes back is at most the exact values there (a lowered bound or a new query), and the exact values
    once asked for with rows."""
    r, sc = _scene()
    con = _fresh(sc)
    qs = [r.home + s * np.array([0.0, 0.3, 0.0, 0.3, 0.0, 0.0, 0.0]) for s in np.linspace(0.0, 1.0, 6)]
    exact = [_fresh(sc).rows_at(q)[0] for q in qs]
    assert (exact[0] - exact[-1]).max() > 0.01  # the hand does come nearer (else the test shows nothing)
    con.rows_at(qs[0])
    for q, c_ref in zip(qs[1:], exact[1:], strict=True):
        v = con.values(q)
        assert np.all(v <= c_ref + rounding(1.0))
        assert np.abs(con.rows_at(q)[0] - c_ref).max() <= rounding(1.0)
