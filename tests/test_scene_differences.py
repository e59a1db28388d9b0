"""The compiled curvature of a Scene's rows (issue 28): ``DistanceQuery.differences`` through SceneClearance.curvature.

Where the scene's queries are compiled, SceneClearance.curvature (``curvature="differences"``) takes the central
differences of the active rows' G in one core call that computes only those pairs at each point
(``Workspace.differences``), and sums them as Constraint.curvature sums the rows of the full query. The named cases
are test_tracking_scene's panda_elbow_ball (a hull against a sphere) and test_tracking_self_clearance's hand by the
upper arm (hull against hull), each at the free optimum's configuration nearest the obstacle (rows under their
clearance there).

Bars: against Constraint.curvature's own differences (the Python route, through ``gradients``): the same rows from the
same Pinocchio and coal calls, summed by the same function, so equal to rounding, 1e-12 relative to max |H| (they are
in fact bit-for-bit equal here). Against central differences of the rows with a step ten times larger (1e-5 rad, taken
here from ``rows_at``): the two estimates differ by the larger step's truncation error h^2 |d^3 G| / 6 (h^2 = 1e-10
times third derivatives of a few 1e3 m/rad^3: a 5 cm sphere's curvature 1/r = 20 1/m over levers of up to 1 m, cubed)
and by the rows' own noise (GJK's tolerance) over the step, well under the bar 1e-6 max(1, |H|) (measured: 7e-9 on
|H| = 2.2 and 7e-10 on 0.21).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import test_tracking_scene as ball
import test_tracking_self_clearance as hand

import kinredund as kr
from kinredund.errors import GeometryError, OptionError
from kinredund.tracking.constraints.base import Constraint, weighted_differences

#: the independent differences' step [rad] and their bar relative to max(1, |H|) (module docstring)
FD_STEP, FD_BAR = 1e-5, 1e-6
#: the bar of the Python route's differences, relative to max |H| (module docstring)
SAME_BAR = 1e-12


@functools.cache
def case(name: str) -> tuple[np.ndarray, kr.SceneClearance]:
    """(q, constraint) of a named case: the free optimum's configuration nearest the obstacle."""
    if name == "panda_elbow_ball":
        sc, free = ball.setup()[4], ball.run(with_scene=False)
        q = free.q[int(np.argmin(ball.ball_distance(sc, free.q)))]
        return q, kr.SceneClearance(sc, clearance=ball.CLEARANCE, self_clearance=None)
    sc, free = hand.setup()[4], hand.run(with_scene=False)
    q = free.q[int(np.argmin(hand.least_distance(sc, free.q)))]
    return q, kr.SceneClearance(sc, self_clearance=hand.SELF_CLEARANCE)


def weighted_rows(name: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """(rows, weights) to take the curvature of: the lowest row alone, the two lowest, and the lowest twice."""
    q, c = case(name)
    low = np.argsort(c.values(q))
    return [(low[:1], np.array([0.37])), (low[:2], np.array([0.8, -0.45])), (low[[0, 0]], np.array([0.25, 0.5]))]


@pytest.mark.parametrize("name", ["panda_elbow_ball", "hand_by_the_upper_arm"])
def test_compiled_differences_are_the_python_differences(name):
    q, c = case(name)
    assert c.scene.workspace().compiled
    assert c.values(q).min() < 0  # a row under its clearance: the case the stepper holds
    for rows, w in weighted_rows(name):
        H = c.curvature(q, w, rows)
        P = Constraint.curvature(c, q, w, rows)  # the Python route: gradients at q +- 1e-6 e_k, all near pairs
        assert np.abs(H).max() > 0.1
        assert np.abs(H - P).max() <= SAME_BAR * np.abs(P).max()
        np.testing.assert_array_equal(H, H.T)


@pytest.mark.parametrize("name", ["panda_elbow_ball", "hand_by_the_upper_arm"])
def test_compiled_differences_against_wider_differences_of_the_rows(name):
    q, c = case(name)
    n = len(q)
    for rows, w in weighted_rows(name)[:2]:
        H = c.curvature(q, w, rows)
        D = np.array([c.rows_at(q + FD_STEP * e)[1][rows] - c.rows_at(q - FD_STEP * e)[1][rows] for e in np.eye(n)])
        wide = np.einsum("i,kic->ck", w, D) / (2 * FD_STEP)
        wide = 0.5 * (wide + wide.T)
        assert np.abs(H - wide).max() <= FD_BAR * max(1.0, np.abs(H).max())


def test_one_row_is_summed_as_the_general_rule():
    """weighted_differences' one-row product gives the numbers of w @ D[k] (the general rule), bit for bit."""
    rng = np.random.default_rng(3)
    D, w = rng.normal(size=(7, 1, 7)), rng.normal(size=1)
    H = np.empty((7, 7))
    for k in range(7):
        H[:, k] = w @ D[k] / (2 * 1e-6)
    np.testing.assert_array_equal(weighted_differences(w, D), 0.5 * (H + H.T))


def test_a_pair_beyond_the_influence_contributes_nothing():
    q, c = case("panda_elbow_ball")
    value, G = c.rows_at(q)
    far = int(np.flatnonzero(value == c.influence - c.clearances)[0])  # its pair beyond the influence: a lower bound
    assert not np.any(G[far])
    np.testing.assert_array_equal(c.curvature(q, np.array([1.0]), np.array([far])), np.zeros((len(q), len(q))))


def test_python_scenes_take_the_python_route():
    q, c = case("panda_elbow_ball")
    py = c.scene.only(c.scene.pairs)
    py.compiled = False
    assert py.workspace().differences(q, c.influence, np.array([0]), 1e-6) is None


def test_bad_pairs_weights_and_steps_are_refused():
    q, c = case("panda_elbow_ball")
    ws = c.scene.workspace()
    n = len(c.scene.pairs)
    with pytest.raises(GeometryError, match=rf"pair {n} is not a pair index \(0..{n - 1}\)"):
        ws.differences(q, c.influence, np.array([0, n]), 1e-6)
    with pytest.raises(GeometryError, match="pair indices"):
        ws.differences(q, c.influence, np.array([0.5]), 1e-6)
    with pytest.raises(GeometryError, match="finite step > 0"):
        ws.differences(q, c.influence, np.array([0]), 0.0)
    with pytest.raises(GeometryError, match="q has 6 entries"):
        ws.differences(q[:6], c.influence, np.array([0]), 1e-6)
    with pytest.raises(OptionError, match="one weight per row"):
        c.curvature(q, np.array([1.0, 2.0]), np.array([0]))
    with pytest.raises(OptionError, match=f"rows 0..{c.size - 1}"):
        c.curvature(q, np.array([1.0]), np.array([c.size]))


@pytest.mark.parametrize("compiled", [True, False])
def test_a_query_of_some_pairs_is_those_pairs_of_the_full_query(compiled):
    """``only``: the pairs asked for, within the limit, with the numbers the query of every pair gives them."""
    q, c = case("hand_by_the_upper_arm")
    sc = c.scene.only(c.scene.pairs)
    sc.compiled = compiled
    ws = sc.workspace()
    assert ws.compiled == compiled
    only = np.arange(0, len(sc.pairs), 3, dtype=np.int64)
    for limit in (None, c.influence):
        full, part = ws.query(q, limit, rows=True), ws.query(q, limit, rows=True, only=only)
        keep = np.isin(full[0], only)
        np.testing.assert_array_equal(part[0], full[0][keep])
        assert 0 < len(part[0]) < len(full[0])
        for a, b in zip(part[1:], full[1:], strict=True):
            np.testing.assert_array_equal(a, b[keep])  # each pair computed alone: the same calls, the same numbers
    with pytest.raises(GeometryError, match="increasing pair indices"):
        ws.query(q, None, only=np.array([3, 1], dtype=np.int64))
