"""Scenes: objects added, moved and removed, scene files round-tripped, and bad input refused with the
project's errors naming what is wrong."""

from __future__ import annotations

import functools
import json
import os
import re

import numpy as np
import pytest

import kinredund as kr
from kinredund.errors import ChoiceError, FrameNotFoundError, GeometryError, KinredundError
from kinredund.geometry.engine import GJK_TOLERANCE

DIST_TOL = 10 * GJK_TOLERANCE  # as tests/test_geometry.py: GJK's stopping gap (kind 2)


@functools.cache
def panda() -> kr.Robot:
    return kr.load_robot("panda")


@functools.cache
def panda_pairs() -> kr.PairMatrix:
    return kr.Scene(panda()).pair_matrix


def new_scene(**kw) -> kr.Scene:
    return kr.Scene(panda(), pairs=panda_pairs(), **kw)


@pytest.fixture
def stl(tmp_path):
    import trimesh

    path = tmp_path / "part.stl"
    trimesh.creation.box([0.05, 0.08, 0.1]).export(path)
    return path


def full_scene(stl) -> kr.Scene:
    s = new_scene()
    s.add_box("table", [1.2, 0.8, 0.04], {"xyz": [0.5, 0.0, -0.03], "rpy": [0.0, 0.0, 0.1]})
    s.add_sphere("ball", 0.05, [0.4, 0.3, 0.5])
    s.add_cylinder("post", 0.04, 0.8, {"xyz": [-0.4, 0.3, 0.4], "quat": [0.0, 0.0, 0.3826834, 0.9238795]})
    s.add_capsule("bar", 0.02, 0.5, {"xyz": [0.3, -0.4, 0.6], "rpy": [1.2, 0.0, 0.0]})
    s.add_mesh("fixture", stl, {"xyz": [0.6, -0.2, 0.1]}, scale=[1.0, 2.0, 1.0])
    s.add_box("tool", [0.02, 0.02, 0.12], {"xyz": [0.0, 0.0, 0.12]}, attach_to="panda_hand")
    s.ignore("tool", "panda_link6_0")
    return s


def test_scene_file_round_trips(tmp_path, stl):
    s = full_scene(stl)
    path = kr.save_scene(s, tmp_path / "cell.json")
    data = json.loads(path.read_text())
    assert data["units"] == {"length": "m", "angle": "rad"} and data["objects"][4]["file"] == "part.stl"
    back = kr.load_scene(path, panda(), pairs=panda_pairs())
    assert back.objects == s.objects and back.pairs == s.pairs and back.ignored == s.ignored
    for name in s.objects:
        a, b = s.object(name), back.object(name)
        assert (a.shape, a.params, a.attach_to) == (b.shape, b.params, b.attach_to)
        assert np.abs(a.pose - b.pose).max() <= 1e-12  # through a quaternion: rounding of a few operations
    rng = np.random.default_rng(2)
    for q in (panda().home, panda().random_configuration(rng, 0.1)):
        assert np.abs(s.distances(q).distance - back.distances(q).distance).max() <= DIST_TOL
    again = json.loads(kr.save_scene(back, tmp_path / "again.json").read_text())["objects"]
    for one, two in zip(again, data["objects"], strict=True):  # written again: the same, poses to rounding
        p1, p2 = one.pop("pose"), two.pop("pose")
        assert one == two and np.abs(np.r_[p1["xyz"], p1["quat"]] - np.r_[p2["xyz"], p2["quat"]]).max() <= 1e-15


def test_objects_move_and_go():
    s = new_scene()
    s.add_sphere("ball", 0.05, [0.5, 0.0, 0.5])
    d0 = s.distances(panda().home)
    s.move("ball", [0.5, 0.0, 0.7])
    d1 = s.distances(panda().home)
    k = [p for p in d0.pairs if "ball" in p]
    assert k and any(abs(d0[p] - d1[p]) > 0.05 for p in k)
    s.remove("ball")
    assert "ball" not in s.objects and not any("ball" in p for p in s.pairs)
    assert len(s.pairs) == len(panda_pairs().enabled)


def test_attached_object_moves_with_its_frame():
    """A sphere 0.1 m along the hand's z axis keeps its distance to a sphere fixed 0.1 m further on: the pair
    rides on one body, so it is not checked; against the world it moves with the hand."""
    r = panda()
    s = new_scene()
    s.add_sphere("held", 0.03, [0.0, 0.0, 0.1], attach_to=r.ee_frame)
    rng = np.random.default_rng(4)
    for q in (r.home, r.random_configuration(rng, 0.1)):
        T = r.fk(q)
        s.add_sphere("probe", 0.02, (T[:3, 3] + T[:3, :3] @ [0.0, 0.0, 0.3]).tolist())
        assert abs(s.distances(q)["held", "probe"] - (0.2 - 0.05)) <= DIST_TOL
        s.remove("probe")


# -- bad input ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(("call", "error", "words"), [
    (lambda s: s.add_box("b", [0.1, -0.2, 0.1]), GeometryError, "box size"),
    (lambda s: s.add_sphere("b", -1.0), GeometryError, "sphere radius"),
    (lambda s: s.add_cylinder("b", 0.1, 0.0), GeometryError, "cylinder length"),
    (lambda s: s.add_capsule("b", float("nan"), 1.0), GeometryError, "capsule radius"),
    (lambda s: s.add_box("b", [0.1] * 3, np.diag([2.0, 1.0, 1.0, 1.0])), GeometryError, "not a rigid transform"),
    (lambda s: s.add_box("b", [0.1] * 3, np.diag([1.0, 1.0, -1.0, 1.0])), GeometryError, "not a rigid transform"),
    (lambda s: s.add_box("b", [0.1] * 3, {"xyz": [0, 0, 0], "quat": [0, 0, 0, 2]}), GeometryError, "unit quaternion"),
    (lambda s: s.add_box("b", [0.1] * 3, {"xyz": [0, 0, 0], "rpy": [0, 0, 0], "quat": [0, 0, 0, 1]}),
     GeometryError, "at most one"),
    (lambda s: s.add_sphere("b", 0.1, attach_to="no_such_frame"), FrameNotFoundError, "no_such_frame"),
    (lambda s: s.add_sphere("panda_link1_0", 0.1), GeometryError, "already in the scene"),
    (lambda s: s.remove("ghost"), ChoiceError, "ghost"),
    (lambda s: s.move("ghost", None), ChoiceError, "ghost"),
    (lambda s: s.ignore("panda_link0_0", "panda_link1_0"), ChoiceError, "does not check"),
    (lambda s: s.distances(panda().home)["panda_link0_0", "panda_link1_0"], ChoiceError, "pair"),
    (lambda s: s.distances([0.0] * 3), KinredundError, "shape"),
    (lambda s: s.distances(panda().home, influence=-0.1), GeometryError, "influence"),
    (lambda s: s.add_mesh("m", "/no/such/part.stl"), GeometryError, "does not exist"),
    (lambda s: s.add_mesh("m", "part.step"), GeometryError, "unknown type"),
])
def test_bad_input_is_refused_clearly(call, error, words):
    s = new_scene()
    with pytest.raises(error, match=words):
        call(s)


def test_a_corrupt_mesh_is_refused(tmp_path):
    bad = tmp_path / "broken.stl"
    bad.write_bytes(b"solid nothing\nthis is not a facet\n")
    with pytest.raises(GeometryError, match="broken.stl"):
        new_scene().add_mesh("m", bad)


def test_a_mesh_that_is_not_a_regular_file_is_refused_without_reading(tmp_path):
    """A scene's mesh file goes through the input check (kinredund.inputs): a FIFO is named as such before
    trimesh opens it (it said 'does not exist', and a FIFO that exists was never read through the check)."""
    fifo = tmp_path / "part.stl"
    os.mkfifo(fifo)
    with pytest.raises(GeometryError, match="part.stl.*a FIFO"):
        new_scene().add_mesh("m", fifo)
    folder = tmp_path / "folder.stl"
    folder.mkdir()
    with pytest.raises(GeometryError, match="folder.stl.*a directory"):
        new_scene().add_mesh("m", folder)


def test_bad_scene_files_are_refused(tmp_path):
    path = tmp_path / "cell.json"
    cases = [
        ({"format": "other"}, "not a scene file"),
        ({"format": "kinredund-scene", "units": {"length": "mm", "angle": "rad"}}, "units"),
        ({"format": "kinredund-scene", "objects": [{"name": "x", "shape": "cone"}]}, "unknown shape"),
        ({"format": "kinredund-scene", "objects": [{"name": "x", "shape": "box"}]}, "missing"),
        ({"format": "kinredund-scene", "objects": [{"name": "x", "shape": "sphere", "radius": 1, "colour": 2}]},
         "unknown"),
    ]
    for data, words in cases:
        path.write_text(json.dumps(data))
        with pytest.raises(GeometryError, match=words):
            kr.load_scene(path, panda(), pairs=panda_pairs())


def test_a_bad_object_of_a_scene_file_is_named_with_the_file(tmp_path):
    """A value the Scene refuses (a negative size, an unknown frame, a pose that is no rigid transform, a missing
    mesh) is reported with the file, the object's index and its name, as a malformed entry is. Reproducer:
    `kinredund check run.json --scene cell.json` said only "box size [m] must be three numbers > 0"."""
    path = tmp_path / "cell.json"
    objects = [({"name": "ok", "shape": "sphere", "radius": 0.1, "pose": {"xyz": [2.0, 0.0, 0.0]}}, None),
               ({"name": "table", "shape": "box", "size": [1.0, -0.5, 0.1]}, "three numbers > 0"),
               ({"name": "tool", "shape": "sphere", "radius": 0.1, "attach_to": "flange"}, "no frame 'flange'"),
               ({"name": "tilt", "shape": "sphere", "radius": 0.1, "pose": {"xyz": [1, 0, 0], "quat": [0, 0, 0, 2]}},
                "quat"),
               ({"name": "part", "shape": "mesh", "file": "part.stl"}, "part.stl")]
    for entry, words in objects[1:]:
        path.write_text(json.dumps({"format": "kinredund-scene", "objects": [objects[0][0], entry]}))
        with pytest.raises(GeometryError) as caught:
            kr.load_scene(path, panda(), pairs=panda_pairs())
        text = str(caught.value)
        assert text.startswith(f"{path}: object 1 ({entry['name']!r}): ") and words in text, text
    path.write_text(json.dumps({"format": "kinredund-scene", "objects": [objects[0][0]],
                                "ignored_pairs": [["ok", "nothing"]]}))
    with pytest.raises(GeometryError, match=rf"^{re.escape(str(path))}: ignored pair \['ok', 'nothing'\]: .*nothing"):
        kr.load_scene(path, panda(), pairs=panda_pairs())


def test_a_pair_matrix_of_another_robot_is_refused(tmp_path):
    other = kr.Scene(kr.load_robot("ur5")).pair_matrix
    with pytest.raises(GeometryError, match="pair matrix"):
        kr.Scene(panda(), pairs=other)
    path = tmp_path / "m.json"
    path.write_text(json.dumps({"format": "kinredund-pair-matrix", "robot": "x"}))
    with pytest.raises(GeometryError, match="malformed"):
        kr.PairMatrix.load(path)


def slider() -> kr.Robot:
    """An RP arm (a revolute base, a prismatic joint across its axis, 0 to 6 m): its two capsules are
    adjacent, so the robot has no candidate self pair at all."""
    from kinredund.kinematics.hd import HDTable
    from kinredund.model.robot import robot_from_hd

    table = HDTable(alpha=[np.pi / 2, 0.0], a=[0.5, 1.0], b=[0.0, 0.0], kinds="RP", lower=[-np.pi, 0.0],
                    upper=[np.pi, 6.0])
    return robot_from_hd(table, task="position")


def test_a_robot_without_candidate_self_pairs_gets_a_scene():
    """self_pairs with nothing to sample (every pair adjacent) raised AttributeError ('list' has no tolist)."""
    s = kr.Scene(slider())
    assert s.pair_matrix.enabled == () and s.pair_matrix.counts()["adjacent"] == 1
    s.add_sphere("ball", 0.05, [1.0, -3.0, 0.0])
    assert s.min_distance(np.array([0.0, 3.0])) < 0.0  # the slid capsule runs through the ball


def test_motion_bound_takes_a_prismatic_slide_into_account():
    """Turning the base moves the capsule beyond the slide by its distance from the axis (about 6 m at full
    slide): the bound of the distance change counted the offsets at q = 0 only (1.56 m/rad) and was 4x short."""
    s = kr.Scene(slider())
    s.add_sphere("ball", 0.05, [9.0, 0.0, 0.0])
    B = s.motion_bound()
    rng = np.random.default_rng(3)
    for _ in range(20):
        q1 = np.array([rng.uniform(-np.pi, np.pi), rng.uniform(0.0, 6.0)])
        q2 = np.clip(q1 + rng.uniform(-0.05, 0.05, 2), [-np.pi, 0.0], [np.pi, 6.0])
        change = np.abs(s.distances(q2).distance - s.distances(q1).distance)  # every pair, in s.pairs' order
        assert np.all(change <= B @ np.abs(q2 - q1) + 1e-12)


def test_check_motion_finds_the_contact_of_a_slid_link():
    """The slid capsule sweeps through ball B between two samples 1.2 m clear of it, while another stretch
    comes within 2 cm of ball A: with the slide left out of the joints' reach check_motion proved the sweep
    free (4 evaluations) and reported no contact; at q = (0, 6) the capsule is 0.1 m deep in B."""
    from kinredund.geometry.motion import check_motion

    s = kr.Scene(slider())
    q = np.array([[-0.3, 6.0], [0.3, 6.0], [0.9, 6.0]])
    s.add_sphere("B", 0.05, s.object_pose("joint_2_capsule", np.array([0.0, 6.0]))[:3, 3])
    s.add_sphere("A", 0.05, s.object_pose("joint_2_capsule", q[2])[:3, 3] + [0.0, 0.0, 0.12])
    assert min(s.min_distance(x) for x in q) > 0.0 and s.min_distance(np.array([0.0, 6.0])) < -0.09
    c = check_motion(s, [0.0, 1.0, 2.0], q)
    assert c.contact and c.min_pair == ("joint_2_capsule", "B") and c.min_distance < 0.0 and 0.0 < c.min_time < 1.0


def test_scene_clearance_skipped_values_stay_lower_bounds_on_a_slid_arm():
    """SceneClearance's values between exact queries (the last exact ones lowered by the motion bound) are
    never above the exact ones, also where a turn of the base swings the slid capsule; beyond the slide's
    limit (where the bound does not hold) they are exact."""
    s = kr.Scene(slider())
    s.add_sphere("ball", 0.05, [3.0, -3.0, 0.0])
    c = kr.SceneClearance(s, clearance=0.02, self_clearance=None, influence=20.0)
    c.values(np.array([0.0, 6.0]))  # exact here
    for q in ([0.02, 6.0], [0.05, 5.9], [0.0, 7.5]):
        exact = s.distances(np.array(q)).distance - c.clearances
        lower = c.values(np.array(q))
        assert np.all(lower <= exact + 1e-12)
    assert np.allclose(lower, exact, rtol=0.0, atol=1e-12)  # beyond the box: queried


@pytest.mark.parametrize("gap", [5e-13, 1e-11, 1e-9])
def test_normal_of_a_pair_within_a_micrometre(gap):
    """A ball right above the slid capsule: the normal from the capsule to the ball is +z. It was
    (p_b - p_a) / d: a zero vector at d <= 1e-12 m (a zero distance row) and 7e-7 off at 1e-11 m."""
    from kinredund.geometry.collision_model import CAPSULE_RADIUS

    s = kr.Scene(slider())
    q = np.array([0.3, 6.0])
    above = s.object_pose("joint_2_capsule", q)[:3, 3] + [0.0, 0.0, CAPSULE_RADIUS + 0.05 + gap]
    s.add_sphere("ball", 0.05, above)
    d = s.distances(q)
    k = d.index("joint_2_capsule", "ball")
    assert abs(d.distance[k] - gap) <= DIST_TOL
    assert np.allclose(d.normal[k], [0.0, 0.0, 1.0], rtol=0.0, atol=1e-9)
