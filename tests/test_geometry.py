"""Collision geometry (kinredund.geometry): closed-form distances, distance rows against central differences,
the self-pair matrix (SRDF, contact-free homes), the broadphase, hulls against meshes."""

from __future__ import annotations

import functools
import threading

import numpy as np
import pinocchio as pin
import pytest

import kinredund as kr
from kinredund.geometry import PairMatrix, robot_geometry
from kinredund.geometry.engine import GJK_TOLERANCE
from kinredund.geometry.pairs import srdf_disabled
from kinredund.kinematics.finite_diff import central_difference

#: GJK stops when its duality gap is below GJK_TOLERANCE: a separated distance is exact to about that [m]
#: (kind 2 of the tolerance policy; coal's sphere-box and sphere-capsule are closed forms, box-box is GJK)
DIST_TOL = 10 * GJK_TOLERANCE
#: central-difference step [rad] and the bar on the rows: O(h^2) truncation (curvature ~ 1/m) plus the
#: distance's error over the step (kind 3)
FD_STEP = 1e-4
ROW_TOL = 10 * (FD_STEP**2 + DIST_TOL / FD_STEP)


@functools.cache
def robot(name: str) -> kr.Robot:
    return kr.load_robot(name)


@functools.cache
def matrix(name: str) -> PairMatrix:
    """Each robot's pair matrix, computed once per session (a Scene takes it back)."""
    return kr.Scene(robot(name)).pair_matrix


def scene(name: str, **kw) -> kr.Scene:
    return kr.Scene(robot(name), pairs=matrix(name), **kw)


def _ee(r: kr.Robot, q) -> pin.SE3:
    T = r.fk(q)
    return pin.SE3(T[:3, :3], T[:3, 3])


# -- closed forms ---------------------------------------------------------------------------------------
def test_sphere_box_distance_is_the_closed_form():
    """A sphere carried by the end effector against a rotated box: |p - clamp(p)| - r in the box's frame."""
    r = robot("planar3r")
    s = scene("planar3r")
    s.add_sphere("ball", 0.3, [0.1, 0.2, 0.0], attach_to=r.ee_frame)
    box_pose = {"xyz": [7.0, 1.0, 0.5], "rpy": [0.2, -0.3, 0.7]}
    s.add_box("crate", [1.0, 0.8, 0.6], box_pose)
    half = np.array([0.5, 0.4, 0.3])  # the box's half sides [m]
    B = pin.SE3(pin.rpy.rpyToMatrix(0.2, -0.3, 0.7), np.array([7.0, 1.0, 0.5]))
    for q in ([0.0, 0.0, 0.0], [0.1, -0.2, 0.3], [0.3, 0.1, -0.4]):
        centre = _ee(r, q).act(np.array([0.1, 0.2, 0.0]))
        local = B.actInv(centre)
        expected = np.linalg.norm(local - np.clip(local, -half, half)) - 0.3
        assert expected > 0
        assert abs(s.distances(q)[("ball", "crate")] - expected) <= DIST_TOL


def _point_segment(p, a, b) -> float:
    t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return float(np.linalg.norm(p - (a + t * (b - a))))


def test_sphere_capsule_distance_is_the_closed_form():
    r = robot("planar3r")
    s = scene("planar3r")
    s.add_sphere("ball", 0.25, [0.0, 0.0, 0.5], attach_to=r.ee_frame)
    R = pin.rpy.rpyToMatrix(0.4, 0.0, 1.1)
    centre = np.array([5.0, 2.0, 1.0])
    s.add_capsule("pipe", 0.1, 2.0, {"xyz": centre.tolist(), "rpy": [0.4, 0.0, 1.1]})
    a, b = centre - R[:, 2], centre + R[:, 2]  # the segment: +-length/2 along the capsule's z axis
    for q in ([0.0, 0.0, 0.0], [0.2, 0.3, -0.5], [-0.2, 0.4, 0.1]):
        p = _ee(r, q).act(np.array([0.0, 0.0, 0.5]))
        expected = _point_segment(p, a, b) - 0.35
        assert expected > 0
        assert abs(s.distances(q)[("ball", "pipe")] - expected) <= DIST_TOL


def test_box_box_distance_when_separated():
    """A box on the end effector (axes of the ee frame) and a box turned 45 deg about z on its +x side: the
    turned box's vertical edge faces the carried box's +x face, at a gap of c - (a + b)/sqrt(2) - h."""
    r = robot("planar3r")
    q = np.zeros(3)
    T = _ee(r, q)
    s = scene("planar3r")
    s.add_box("carried", [0.4, 0.4, 0.4], attach_to=r.ee_frame)
    x0 = T.translation + T.rotation @ np.array([1.0, 0.0, 0.0])
    turn = np.eye(4)
    turn[:3, :3] = T.rotation @ pin.rpy.rpyToMatrix(0.0, 0.0, np.pi / 4)
    turn[:3, 3] = x0
    s.add_box("turned", [0.3, 0.5, 1.0], turn)
    expected = 1.0 - (0.15 + 0.25) / np.sqrt(2.0) - 0.2
    assert abs(s.distances(q)[("carried", "turned")] - expected) <= DIST_TOL
    s.move("turned", {"xyz": (T.translation + T.rotation @ np.array([0.0, 0.9, 0.0])).tolist()})
    R_ee = pin.rpy.matrixToRpy(T.rotation)
    s.move("turned", {"xyz": (T.translation + T.rotation @ np.array([0.0, 0.9, 0.0])).tolist(), "rpy": R_ee.tolist()})
    assert abs(s.distances(q)[("carried", "turned")] - (0.9 - 0.25 - 0.2)) <= DIST_TOL  # face to face along y


# -- rows -------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["panda", "puma7"])
def test_distance_rows_match_central_differences(name):
    """d_dot = G q_dot: every row against central differences of the distances, at seeded configurations
    (self pairs on hulls or capsules, a world sphere and capsule, a box carried by the end effector)."""
    r = robot(name)
    s = scene(name)
    reach = float(np.linalg.norm(r.fk(r.home)[:3, 3]))
    s.add_sphere("ball", 0.1 * reach, [0.6 * reach, 0.3 * reach, 0.5 * reach])
    s.add_capsule("bar", 0.05 * reach, reach, {"xyz": [-0.5 * reach, 0.2 * reach, 0.4 * reach], "rpy": [0.3, 1.2, 0]})
    s.add_box("tool", [0.03, 0.04, 0.1], {"xyz": [0.0, 0.0, 0.08], "rpy": [0.1, 0.2, 0.3]}, attach_to=r.ee_frame)
    rng = np.random.default_rng(7)
    for _ in range(3):
        q = r.random_configuration(rng, margin=0.1)
        rows = s.distance_rows(q)
        assert rows.G.shape == (len(s.pairs), r.nq) and len(rows.pairs) == len(s.pairs)

        def d(x, pairs=rows.pairs):
            return s.distances(x).distance  # the scene's pair order, the same as rows.pairs

        fd = central_difference(d, q, FD_STEP)
        scale = np.maximum(1.0, np.abs(rows.G).max(axis=1))
        assert np.all(np.abs(fd - rows.G).max(axis=1) <= ROW_TOL * scale)
        d_rows, G = s.distance_rows(q)  # unpacks as (d, G)
        assert np.allclose(d_rows, rows.d, rtol=0, atol=0) and G.shape == rows.G.shape


def test_broadphase_skips_only_pairs_beyond_the_influence():
    r = robot("panda")
    s = scene("panda")
    s.add_box("table", [1.2, 1.2, 0.04], {"xyz": [0.4, 0.0, -0.05]})
    s.add_sphere("ball", 0.06, [0.45, 0.25, 0.45])
    rng = np.random.default_rng(3)
    for influence in (0.0, 0.05, 0.2):
        for q in (r.home, r.random_configuration(rng, 0.1)):
            every = s.distances(q)
            near = s.distances(q, influence=influence)
            assert near.checked == len(every) == len(s.pairs)
            skipped = set(every.pairs) - set(near.pairs)
            assert all(every[p] > influence for p in skipped)
            assert all(abs(near[p] - every[p]) <= DIST_TOL for p in near.pairs)
            rows = s.distance_rows(q, influence=influence)
            assert rows.pairs == near.pairs


def test_min_distance_and_closest_agree_with_the_record():
    s = scene("panda")
    s.add_sphere("ball", 0.05, [0.3, 0.0, 0.6])
    q = robot("panda").home
    rec = s.distances(q)
    pair, d = s.closest(q)
    assert pair == rec.closest and abs(d - rec.min_distance) <= DIST_TOL
    assert abs(s.min_distance(q) - rec.min_distance) <= DIST_TOL


@pytest.mark.parametrize("collision", ["hulls", "primitives"])
def test_closest_by_bounds_is_the_least_of_every_pair(collision):
    """closest/min_distance compute only pairs whose bounding-sphere gap does not rule them out: over the whole
    joint box (penetrating configurations included, where a gap bound says nothing below 0) they must find the
    least of every pair's distance and its pair."""
    r = robot("panda")
    kw = {}
    if collision == "primitives":
        from kinredund.model.erd import erd_share_dir
        kw["collision_urdf"] = erd_share_dir() / "panda_description/urdf/panda_collision.urdf"
    s = kr.Scene(r, **kw) if kw else scene("panda")
    s.add_box("table", [1.2, 1.2, 0.04], {"xyz": [0.4, 0.0, -0.2]})  # below both models' bases
    s.add_sphere("ball", 0.06, [0.45, 0.25, 0.45])
    s.add_box("tool", [0.02, 0.02, 0.1], {"xyz": [0.0, 0.0, 0.3]}, attach_to="panda_hand")  # past the fingers
    rng = np.random.default_rng(7)
    least = []
    for q in [r.home] + [r.random_configuration(rng, 0.0) for _ in range(40)]:
        every = s.distances(q)
        pair, d = s.closest(q)
        assert pair == every.closest and abs(d - every.min_distance) <= DIST_TOL, (q, pair, every.closest)
        assert abs(s.min_distance(q) - every.min_distance) <= DIST_TOL
        least.append(every.min_distance)
    assert min(least) < 0 < max(least)  # both branches of the bound were taken


def test_workspaces_are_per_thread():
    s = scene("panda")
    r = robot("panda")
    qs = [r.random_configuration(np.random.default_rng(k), 0.1) for k in range(8)]
    expected = [s.distances(q).distance for q in qs]
    got = [None] * len(qs)

    def work(k):
        for _ in range(20):
            got[k] = s.distances(qs[k]).distance

    threads = [threading.Thread(target=work, args=(k,)) for k in range(len(qs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert all(np.abs(a - b).max() <= DIST_TOL for a, b in zip(got, expected, strict=True))


# -- pair matrix ------------------------------------------------------------------------------------
def test_srdf_pairs_are_honoured():
    r = robot("panda")
    geom = robot_geometry(r)
    assert geom.srdf is not None and geom.srdf.name == "panda.srdf"
    disabled = srdf_disabled(geom.srdf)
    assert len(disabled) >= 30
    link = dict(zip(geom.names, geom.links, strict=True))
    m = matrix("panda")
    for a, b in m.enabled:
        assert frozenset((link[a], link[b])) not in disabled
    by_srdf = [p for p, why in m.disabled.items() if why == "srdf"]
    assert by_srdf and all(frozenset((link[a], link[b])) in disabled for a, b in by_srdf)
    assert not set(scene("panda").pairs) & set(by_srdf)


def test_pair_matrix_round_trips_and_is_given_back(tmp_path):
    m = matrix("panda")
    path = m.save(tmp_path / "panda_pairs.json")
    back = PairMatrix.load(path)
    assert back == m and back.counts() == m.counts()
    assert kr.Scene(robot("panda"), pairs=path).pairs == kr.Scene(robot("panda"), pairs=m).pairs
    assert "self pairs checked" in m.summary()


FAST_HOMES = ["panda", "planar3r", "ur5", "puma7"]


def _home_is_contact_free(name: str) -> None:
    r = robot(name)
    s = scene(name)
    if s.pairs:
        assert s.min_distance(r.home) > 0.0, s.closest(r.home)


@pytest.mark.parametrize("name", FAST_HOMES)
def test_home_is_contact_free(name):
    _home_is_contact_free(name)


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in kr.known_robots() if n not in FAST_HOMES])
def test_every_robot_home_is_contact_free(name):
    _home_is_contact_free(name)


def test_hd_robot_gets_capsules_with_the_radius_given():
    r = kr.load_robot("cybotech_p15_x8")
    thin = robot_geometry(r, capsule_radius=0.05)
    thick = robot_geometry(r, capsule_radius=0.2)
    assert thin.source == "capsules" and thin.names == thick.names
    assert all(g.geometry.radius == 0.05 for g in thin.model.geometryObjects)
    assert all(g.geometry.radius == 0.2 for g in thick.model.geometryObjects)


# -- hulls and meshes ---------------------------------------------------------------------------------
def test_a_hull_is_never_farther_than_its_mesh(tmp_path):
    """Robot links (hulls against exact meshes) and a torus: at home a ball carried by the hand sits in the
    hole of a torus in the world, clear of the mesh, inside its hull."""
    import trimesh

    r = robot("panda")
    torus = tmp_path / "ring.stl"
    trimesh.creation.torus(0.1, 0.03).export(torus)
    hand = r.model.getFrameId("panda_hand")
    ring_pose = r.fk(r.home)  # the ee frame is panda_hand: the ring around the ball at home
    assert r.ee_frame_id == hand
    ring_pose[:3, 3] += ring_pose[:3, :3] @ np.array([0.0, 0.0, 0.05])
    scenes = {}
    for kind in ("convex", "mesh"):
        s = scene("panda", geometry=kind)
        s.add_sphere("ball", 0.02, [0.0, 0.0, 0.05], attach_to="panda_hand")
        s.add_mesh("ring", torus, ring_pose)
        s.add_mesh("pot", torus, {"xyz": [0.5, 0.3, 0.1], "rpy": [0.3, 0.2, 0.1]}, scale=[1.5, 1.0, 2.0])
        scenes[kind] = s
    assert scenes["convex"].pairs == scenes["mesh"].pairs
    rng = np.random.default_rng(5)
    for q in (r.home, r.random_configuration(rng, 0.1), r.random_configuration(rng, 0.1)):
        hull, mesh = scenes["convex"].distances(q), scenes["mesh"].distances(q)
        assert np.all(hull.distance <= mesh.distance + DIST_TOL)
    hull = scenes["convex"].distances(r.home)["ball", "ring"]
    mesh = scenes["mesh"].distances(r.home)["ball", "ring"]
    # the torus's facets (32 segments each way) bring its inner surface in by < 1 mm
    assert hull < 0 < mesh and abs(mesh - (0.1 - 0.03 - 0.02)) <= 1e-3


# -- the thesis's Chapter 6 obstacles against coal ------------------------------------------------------
@pytest.mark.parametrize("case", ["6.2", "6.3"])
def test_chapter6_obstacles_agree_with_coal(case):
    """The hand-written exact distances of planning/obstacles.py against coal's, on the obstacle's prism
    (its circumscribed 64-gon, bottom to top): a point's coal distance is at most the exact one (the prism
    holds the obstacle) and at least the exact one minus the prism's excess."""
    import coal

    from kinredund.geometry.shapes import convex
    from kinredund.thesis.chapter6 import case_setup

    _, _, obstacle = case_setup(case)
    segments = 64
    excess = max(obstacle.a, obstacle.b) * (1.0 / np.cos(np.pi / segments) - 1.0)
    prism = convex(obstacle.prism_points(segments))
    rng = np.random.default_rng(11)
    lo, hi = obstacle.heights(obstacle.center[:2])
    span = max(obstacle.a, obstacle.b)
    checked = 0
    for _ in range(200):
        p = obstacle.center + rng.uniform(-2.0, 2.0, 3) * [span, span, 0.0]
        p[2] = rng.uniform(lo, hi) if case == "6.2" else rng.uniform(lo - 0.5 * span, hi + 0.5 * span)
        exact = float(obstacle.signed_distance(p))
        if exact <= 1e-3:
            continue  # inside: EPA's depths are not what this checks
        req, res = coal.DistanceRequest(), coal.DistanceResult()
        d = coal.distance(prism, coal.Transform3s(), coal.Sphere(1e-6), coal.Transform3s(np.eye(3), p), req, res)
        d += 1e-6
        assert exact - excess - DIST_TOL <= d <= exact + DIST_TOL, (p, exact, d)
        checked += 1
    assert checked > 50


def test_chapter6_link_distances_agree_with_a_scene():
    """Section 6.2's planar arm as capsules of radius r against the ellipse in a Scene: each link's distance is
    planning/obstacles.py's segment distance minus r, to within the prism's excess."""
    from kinredund.thesis.chapter6 import case_setup

    robot_, _, obstacle = case_setup("6.2")
    radius = 0.02
    s = kr.Scene(robot_, capsule_radius=radius)
    s.add_convex("obstacle", obstacle.prism_points(64))
    excess = max(obstacle.a, obstacle.b) * (1.0 / np.cos(np.pi / 64) - 1.0)
    model = robot_.model
    rng = np.random.default_rng(2)
    for _ in range(20):
        q = robot_.random_configuration(rng)
        rec = s.distances(q)
        data = model.createData()
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        joints = [data.oMi[j].translation for j in range(1, model.njoints)]
        points = [*joints, data.oMf[robot_.ee_frame_id].translation]
        for j in range(1, model.njoints):
            exact = float(obstacle.segment_distance(points[j - 1], points[j], radius))
            if exact <= 1e-3:
                continue
            d = rec[(f"{model.names[j]}_capsule", "obstacle")]
            assert exact - excess - DIST_TOL <= d <= exact + 1e-9, (q, j, exact, d)  # golden section: 1e-10 m


@pytest.mark.parametrize("name", ["panda", "baxter", "ur5"])
def test_collision_objects_sit_where_pinocchio_puts_them(name):
    """The robot's objects moved onto its reduced model by link name against Pinocchio's own route
    (``pin.buildReducedModel`` with the geometry model, the locked joints at the robot's values): every object's
    world pose agrees at seeded configurations (to rounding)."""
    from kinredund.model.urdf import load_urdf

    r = robot(name)
    parsed = load_urdf(r.urdf_path)
    full = parsed.model
    gm0 = pin.buildGeomFromUrdfString(full, parsed.text, pin.GeometryType.COLLISION,
                                      package_dirs=list(r.package_dirs))
    q_full = pin.neutral(full)
    for joint, value in r.locked.items():
        q_full[full.idx_qs[full.getJointId(joint)]] = value
    locked = [full.getJointId(j) for j in r.locked]
    reduced, geom = pin.buildReducedModel(full, gm0, locked, q_full) if locked else (full, gm0)
    data, gdata = reduced.createData(), pin.GeometryData(geom)
    s = scene(name)
    rng = np.random.default_rng(9)
    for _ in range(3):
        q = r.random_configuration(rng, 0.1)
        pin.updateGeometryPlacements(reduced, data, geom, gdata, q)
        for k, g in enumerate(geom.geometryObjects):
            assert np.abs(s.object_pose(g.name, q) - gdata.oMg[k].homogeneous).max() <= 1e-12
