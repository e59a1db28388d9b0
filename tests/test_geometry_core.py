"""The compiled distance query (kinredund._core.DistanceQuery, src/core/distances.cpp) against the Python path
of kinredund/geometry/engine.py: the same pairs, distances, witness points, normals, rows and closest pair.

Both paths make the same Pinocchio and coal calls on the same placements with the same requests (GJK tolerance,
no warm start), so the distances and witness points agree to rounding; the rows are the same sums in another
order (rounding, kind 1 of the tolerance policy). The rows' own check against central differences on the
compiled path is tests/test_geometry.py (the default path wherever the core is built).
In CI (CI=true) the core must be there, as in tests/test_core_build.py.
"""

from __future__ import annotations

import functools
import os

import numpy as np
import pytest
from conftest import rounding

import kinredund as kr
from kinredund.errors import GeometryError
from kinredund.geometry import engine
from kinredund.geometry.motion import check_motion

if not os.environ.get("CI"):  # outside CI a machine without the core runs the Python path
    pytest.importorskip("kinredund._core")

#: central-difference step [rad] and bar on the rows, as in tests/test_geometry.py (kind 3)
FD_STEP = 1e-4
ROW_TOL = 10 * (FD_STEP**2 + 10 * engine.GJK_TOLERANCE / FD_STEP)
#: |d(q + h e) - 2 d(q) + d(q - h e)| / h^2 above which a distance has a kink within the step [m/rad^2]: a kink
#: of slope jump s at t from q makes it s (h - |t|) / h^2 and the central difference off by s (h - |t|) / (2 h),
#: which this bar keeps within ROW_TOL / 2; smooth distances of a metre-sized arm curve by ~1 m/rad^2 (kind 3)
KINK = ROW_TOL / FD_STEP


@functools.cache
def _pairs(name: str) -> kr.PairMatrix:
    return kr.Scene(kr.load_robot(name)).pair_matrix


def cell(name: str, compiled: bool) -> kr.Scene:
    """The robot's self pairs and five objects: a table, a ball, a post, a bar across the workspace and a tool
    held by the end effector (an attached object, checked against the robot and the world)."""
    r = kr.load_robot(name)
    s = kr.Scene(r, pairs=_pairs(name), compiled=compiled)
    reach = float(np.linalg.norm(r.fk(r.home)[:3, 3]))
    s.add_box("table", [3 * reach, 3 * reach, 0.04], {"xyz": [0.5 * reach, 0.0, -0.03]})
    s.add_sphere("ball", 0.1 * reach, [0.6 * reach, 0.4 * reach, 0.6 * reach])
    s.add_cylinder("post", 0.05 * reach, reach, {"xyz": [-0.6 * reach, 0.4 * reach, 0.5 * reach]})
    s.add_capsule("bar", 0.03 * reach, reach, {"xyz": [0.4 * reach, -0.5 * reach, 0.7 * reach], "rpy": [1.2, 0, 0]})
    s.add_box("tool", [0.02, 0.03, 0.12], {"xyz": [0.0, 0.0, 0.08], "rpy": [0.1, 0.2, 0.3]}, attach_to=r.ee_frame)
    return s


def _configurations(r: kr.Robot, count: int, seed: int) -> list[np.ndarray]:
    """The home pose and seeded ones over the whole joint box (many in contact: the near-contact normals)."""
    rng = np.random.default_rng(seed)
    return [r.home] + [r.random_configuration(rng, 0.0) for _ in range(count)]


@pytest.mark.parametrize("name", ["panda", "xarm7", "kinova"])
def test_compiled_query_is_the_python_query(name):
    core, py = cell(name, True), cell(name, False)
    assert core.workspace().compiled and not py.workspace().compiled
    assert core.pairs == py.pairs
    contacts = 0
    for q in _configurations(core.robot, 12, seed=5):
        for influence in (None, 0.0, 0.05, 0.3):
            a, b = core.distance_rows(q, influence=influence), py.distance_rows(q, influence=influence)
            assert a.pairs == b.pairs and np.array_equal(a.index, b.index)
            assert np.abs(a.d - b.d).max(initial=0.0) <= rounding()
            for x, y in ((a.point_a, b.point_a), (a.point_b, b.point_b), (a.normal, b.normal)):
                assert np.abs(x - y).max(initial=0.0) <= rounding()
            assert a.G.shape == b.G.shape
            assert np.abs(a.G - b.G).max(initial=0.0) <= rounding(np.abs(b.G).max(initial=1.0))
            da, db = core.distances(q, influence=influence), py.distances(q, influence=influence)
            assert da.pairs == db.pairs and np.abs(da.distance - db.distance).max(initial=0.0) <= rounding()
        (pa, d_a), (pb, d_b) = core.closest(q), py.closest(q)
        assert pa == pb and abs(d_a - d_b) <= rounding()
        # closest leaves the pairs it computed active: the compiled path's bound tightens as it goes, so fewer
        active = [np.array(x.workspace().gdata.activeCollisionPairs, dtype=bool) for x in (core, py)]
        assert active[0][core.pairs.index(pa)] and np.all(active[1] | ~active[0])
        contacts += d_b <= 0
    assert contacts > 0  # the near-contact normal rules (coal's own normal) were compared too


def test_compiled_rows_match_central_differences_with_an_attached_object():
    """xarm7: the compiled rows against central differences of the compiled distances (self pairs, world objects
    and the held tool), at seeded contact-free configurations.

    Hulls are polytopes: where the closest features switch within a step (a hull vertex overtaking another above
    the table) the distance has a kink and no derivative for central differences to find. Such entries show
    as a second difference beyond KINK (smooth stretches curve far less); the others are checked, and they must
    be the great majority.
    """
    s = cell("xarm7", True)
    free = [q for q in _configurations(s.robot, 20, seed=11) if s.min_distance(q) > 0.01][:3]
    assert free
    h, checked, total = FD_STEP, 0, 0
    for q in free:
        rows = s.distance_rows(q)
        d0 = s.distances(q).distance
        plus = np.array([s.distances(q + h * e).distance for e in np.eye(len(q))]).T  # (pairs, n)
        minus = np.array([s.distances(q - h * e).distance for e in np.eye(len(q))]).T
        fd = (plus - minus) / (2 * h)
        smooth = np.abs(plus - 2 * d0[:, None] + minus) <= KINK * h * h
        scale = np.maximum(1.0, np.abs(rows.G).max(axis=1))[:, None]
        assert np.all((np.abs(fd - rows.G) <= ROW_TOL * scale) | ~smooth)
        checked, total = checked + smooth.sum(), total + smooth.size
        assert any("tool" in p for p in rows.pairs)
    assert checked >= 0.9 * total


def test_compiled_query_refuses_what_does_not_fit():
    s = cell("panda", True)
    ws = s.workspace()
    with pytest.raises(ValueError, match="q has 6 entries"):
        ws.query(np.zeros(6), None)
    with pytest.raises(ValueError, match="limit must be a distance >= 0"):
        ws.query(np.zeros(7), float("nan"))
    with pytest.raises(TypeError):  # the outputs are written in place: a copy made to convert them is refused
        ws._core.query(np.zeros(7), None, False, np.empty(len(s.pairs)), np.empty((len(s.pairs), 10)))
    n, m = ws.centres.shape[:2]
    args = (ws.model, ws.data, ws.geometry, ws.gdata, ws.joints.astype(np.int64),
            ws.centres.reshape(n * m, 3), ws.radii.reshape(-1))
    with pytest.raises(ValueError, match="collision pair 0"):
        engine.compiled_core().DistanceQuery(*args, ws.second.astype(np.int64), ws.first.astype(np.int64))
    with pytest.raises(ValueError, match="bounding spheres"):
        engine.compiled_core().DistanceQuery(*args[:5], args[5][:-1], args[6][:-1], ws.first.astype(np.int64),
                                             ws.second.astype(np.int64))
    with pytest.raises(TypeError, match="pinocchio.GeometryModel"):
        engine.compiled_core().DistanceQuery(*args[:2], ws.gdata, *args[3:], ws.first.astype(np.int64),
                                             ws.second.astype(np.int64))


def test_compiled_true_without_the_core_is_refused(monkeypatch):
    monkeypatch.setattr(engine, "_CORE", None)
    with pytest.raises(GeometryError, match="without its compiled core"):
        cell("panda", True).workspace()
    s = cell("panda", None)
    assert not s.workspace().compiled  # the Python path, quietly
    monkeypatch.setattr(engine, "_CORE", engine.compiled_core())
    s.compiled = True  # the next query's workspace
    assert s.workspace().compiled and s.compiled


def test_motion_check_is_the_same_on_both_paths():
    """check_motion (``kinredund check``) on the compiled closest pair: the same least clearance, pair, time and
    configurations evaluated as on the Python path, for a Panda motion past the cell's objects."""
    core, py = cell("panda", True), cell("panda", False)
    r = core.robot
    t = np.linspace(0.0, 1.0, 6)
    q = r.home + np.outer(np.sin(np.pi * t), np.random.default_rng(2).uniform(-0.6, 0.6, r.nq))
    a, b = check_motion(core, t, q), check_motion(py, t, q)
    assert a.min_pair == b.min_pair and a.evaluations == b.evaluations and a.pairs == b.pairs
    assert abs(a.min_distance - b.min_distance) <= rounding() and abs(a.min_time - b.min_time) <= rounding()
    assert np.abs(a.distance - b.distance).max() <= rounding()


@pytest.mark.parametrize("compiled", [True, False])
def test_a_distance_does_not_depend_on_the_queries_before_it(compiled):
    """The Kinova's cell (large convex hulls): every distance at q_b is the same number whether or not the workspace
    was queried at q_a just before. coal's GJK solver of a pair kept its support-vertex hint from its last call,
    whatever the request's guess mode (distances differed within GJK's stopping tolerance); each query now
    starts the same (gjk.fresh_starts, fresh_distance in the core). Exact equality: the same computation either way."""
    r = kr.load_robot("kinova")
    configurations = _configurations(r, 16, seed=7)
    for q_a, q_b in zip(configurations[:-1], configurations[1:], strict=True):
        alone = cell("kinova", compiled).distances(q_b, influence=0.3)
        after = cell("kinova", compiled)
        after.distances(q_a, influence=0.3)
        after.closest(q_a)
        again = after.distances(q_b, influence=0.3)
        assert again.pairs == alone.pairs and np.array_equal(again.distance, alone.distance)
        assert after.closest(q_b) == cell("kinova", compiled).closest(q_b)
