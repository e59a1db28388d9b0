"""Loading arms: example-robot-data by name, chains kept and joints locked, continuous joints, shared
frame names, the home pose, URDF input that must be refused, and robots shared between threads."""

from __future__ import annotations

import pickle
import sys
import threading

import numpy as np
import pinocchio as pin
import pytest
from conftest import rounding
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import kinredund
from kinredund import track
from kinredund.errors import (
    ChoiceError,
    FrameNotFoundError,
    JointVectorError,
    KinredundError,
    TaskError,
    URDFError,
)
from kinredund.ik.solve import solve_ik
from kinredund.indices import JointDeviation
from kinredund.model.erd import ERD_ARMS, erd_share_dir
from kinredund.model.loader import HOME_CONDITION, check_tool_axis, conditioning, known_robots, load_robot, robot_table
from kinredund.model.urdf import load_urdf
from kinredund.paths import Circle
from kinredund.tasks import TASKS

#: a tracked record at these step counts agrees with the path to round-off: the default mode corrects
#: every step to the closure tolerance (1e-12 on a ~1 m scale); 1e-9 m leaves room for a long arm
TRACK_TOL = 1e-9


def _circle(r: kinredund.Robot, radius: float = 0.01, normal=(0.0, 0.0, 1.0), axis_x=(1.0, 0.0, 0.0)):
    p0 = r.fk(r.home)[:3, 3]
    return p0, Circle(p0 - radius * np.asarray(axis_x), radius, 0.05, normal=normal, axis_x=axis_x)


def _track_circle(r: kinredund.Robot, **circle):
    """A short closed circle through the home pose's point, from the IK start with z = |q - home|^2 / 2."""
    index = JointDeviation(r.home)
    p0, path = _circle(r, **circle)
    start = solve_ik(r, p0, index)
    assert start.converged, start.reason
    return track(r, path, index, start.q, steps_per_loop=24, loops=1)


# -- every arm of the catalogue ---------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(ERD_ARMS))
def test_every_catalogue_arm_loads_with_its_frame_and_tracks_a_circle(name):
    spec = ERD_ARMS[name]
    r = load_robot(name)
    assert r.ee_frame == spec.ee_frame and r.task == spec.task
    assert r.nq == r.model.nv and r.nq > r.task_dim  # redundant for its default task
    if spec.joints is not None:
        assert r.joint_names == list(spec.joints)
    assert np.all((r.home >= r.lower) & (r.home <= r.upper))
    assert conditioning(r.kinematics, r.home, r.task) >= HOME_CONDITION / 2  # away from singular
    tr = _track_circle(r.with_task("position"))
    assert tr.position_error.max() < TRACK_TOL
    assert np.all(np.isfinite(tr.q)) and len(tr.t) == 25
    assert tr.loop_drift is not None and tr.loop_drift.max() < 1e-9  # a closed path, a closed joint path


@pytest.mark.parametrize("name", sorted(ERD_ARMS))
def test_every_catalogue_arm_tracks_a_circle_with_its_redundant_task(name):
    """Its default task (axis, pose or position), the orientation held at the home pose's."""
    r = load_robot(name)
    T = r.fk(r.home)
    radius = 0.01
    path = Circle(T[:3, 3] - radius * np.array([1.0, 0.0, 0.0]), radius, 0.05, orientation=T[:3, :3])
    index = JointDeviation(r.home)
    s0 = path(0.0)
    start = solve_ik(r, (s0.Q, s0.p) if r.task in ("pose", "axis") else s0.p, index)
    assert start.converged, start.reason
    tr = track(r, path, index, start.q, steps_per_loop=24, loops=1)
    assert tr.position_error.max() < TRACK_TOL and tr.loop_drift.max() < 1e-9
    if r.task == "axis":
        assert tr.summary()["axis_error_max"] < 1e-9  # [rad], corrected like the position every step


def test_robots_command_lists_every_name_with_joints_frame_and_task(capsys):
    from kinredund.ui.cli import main

    assert main(["robots"]) == 0
    out = capsys.readouterr().out
    rows = {row.name: row for row in robot_table()}
    assert sorted(rows) == sorted(known_robots())
    for name, row in rows.items():
        line = next(ln for ln in out.splitlines() if ln.split()[0] == name)
        assert f" {row.n} " in line and row.ee_frame in line and row.task in line
    assert (rows["ur5"].n, rows["ur5"].task, rows["ur5"].m) == (6, "axis", 5)
    assert (rows["kinova"].n, rows["baxter"].n, rows["so100"].n) == (6, 7, 5)


# -- continuous joints --------------------------------------------------------------------------------
def test_kinova_continuous_joints_are_revolute_angles_with_the_same_kinematics():
    r = load_robot("kinova")
    assert r.nq == r.model.nv == 6
    assert set(r.continuous) == {"j2s6s200_joint_1", "j2s6s200_joint_4", "j2s6s200_joint_6"}
    cont = [r.joint_names.index(n) for n in r.continuous]
    assert np.all(r.lower[cont] <= -1e10) and np.all(r.upper[cont] >= 1e10)  # no limits
    assert np.all(r.revolute)
    # the file as Pinocchio reads it: (cos, sin) for each continuous joint
    raw = pin.buildModelFromUrdf(str(erd_share_dir() / ERD_ARMS["kinova"].urdf))
    data, fid = raw.createData(), raw.getFrameId("j2s6s200_end_effector")
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(-3.0, 3.0, 6) + np.array([0, np.pi, np.pi, 0, np.pi, 0])
        q[cont] += 20.0  # several turns: an angle, not a point on the circle
        qraw = np.concatenate([[np.cos(v), np.sin(v)] if i in cont else [v] for i, v in enumerate(q)])
        pin.framesForwardKinematics(raw, data, qraw)
        assert np.allclose(r.fk(q), data.oMf[fid].homogeneous, atol=1e-12)  # two routes to one pose


def test_kinova_tracks_an_axis_free_position_circle_through_several_turns_of_a_continuous_joint():
    r = load_robot("kinova", task="position")
    tr = _track_circle(r, radius=0.02)
    assert tr.position_error.max() < TRACK_TOL


def test_pr2_left_arm_loads_with_two_continuous_rolls():
    r = load_robot("pr2")
    assert r.nq == 7 and set(r.continuous) == {"l_forearm_roll_joint", "l_wrist_roll_joint"}
    assert "torso_lift_joint" in r.locked and "r_shoulder_pan_joint" in r.locked


# -- chains and locked joints -------------------------------------------------------------------------
BAXTER_LEFT = ["left_s0", "left_s1", "left_e0", "left_e1", "left_w0", "left_w1", "left_w2"]


def test_baxter_left_arm_with_joints_matches_the_full_model():
    r = load_robot("baxter", "left_gripper", joints=BAXTER_LEFT)
    assert r.joint_names == BAXTER_LEFT and r.nq == 7
    full = pin.buildModelFromUrdf(str(erd_share_dir() / ERD_ARMS["baxter"].urdf))
    data, fid = full.createData(), full.getFrameId("left_gripper")
    q = r.home + 0.2
    qf = pin.neutral(full)
    for name, v in {**r.locked, **dict(zip(BAXTER_LEFT, q, strict=True))}.items():
        qf[full.idx_qs[full.getJointId(name)]] = v
    pin.framesForwardKinematics(full, data, qf)
    assert np.allclose(r.fk(q), data.oMf[fid].homogeneous, atol=1e-12)
    tr = _track_circle(r.with_task("position"))
    assert tr.position_error.max() < TRACK_TOL


def test_locked_values_move_the_kept_chain():
    low = load_robot("tiago", locked={"torso_lift_joint": 0.0})
    high = load_robot("tiago", locked={"torso_lift_joint": 0.3})
    assert high.locked["torso_lift_joint"] == 0.3
    dp = high.fk(low.home)[:3, 3] - low.fk(low.home)[:3, 3]
    assert np.allclose(dp, [0.0, 0.0, 0.3], atol=1e-12)  # a vertical prismatic torso


def test_baxter_right_arm_needs_its_own_frame():
    right = [n.replace("left", "right") for n in BAXTER_LEFT]
    with pytest.raises(TaskError, match="fixed to the base"):  # left_gripper no longer moves
        load_robot("baxter", joints=right)
    assert load_robot("baxter", "right_gripper", joints=right).joint_names == right


@pytest.mark.parametrize(
    ("kwargs", "error", "needle"),
    [
        ({"joints": ["left_s0", "nope"]}, ChoiceError, "nope"),
        ({"joints": "left_s0"}, ChoiceError, "list of joint names"),
        ({"joints": []}, ChoiceError, "empty"),
        ({"locked": {"left_s0": 0.1}}, ChoiceError, "locked joint"),
        ({"locked": {"head_pan": 9.0}}, JointVectorError, "head_pan"),
        ({"locked": {"head_pan": float("nan")}}, JointVectorError, "finite"),
        ({"locked": {"head_pan": True}}, JointVectorError, "finite number"),
    ],
)
def test_bad_joints_and_locked_values_are_named(kwargs, error, needle):
    with pytest.raises(error, match=needle):
        load_robot("baxter", **kwargs)


# -- frames ---------------------------------------------------------------------------------------------
def test_z1_frame_shared_by_a_joint_and_a_link_takes_the_link():
    r = load_robot("z1")  # the file as shipped
    assert r.model.frames[r.ee_frame_id].type == pin.FrameType.BODY
    assert "BODY" in r.ee_frame_info and "FIXED_JOINT" in r.ee_frame_info
    assert r.nq == 6


def test_so100_locked_joint_named_like_a_link_loads():
    r = load_robot("so100")  # its jaw joint and the gripper link are both called "gripper"
    assert r.nq == 5 and "gripper" in r.locked
    assert r.model.frames[r.ee_frame_id].type == pin.FrameType.BODY


def test_empty_ee_frame_is_refused_not_replaced():
    for name in ("panda", "planar3r"):
        with pytest.raises(FrameNotFoundError, match="non-empty"):
            load_robot(name, "")


def test_missing_frame_says_which_frame_a_shared_name_gives():
    with pytest.raises(FrameNotFoundError, match="link") as err:
        load_robot("z1", "tool0")
    assert "gripperStator" in err.value.frames


# -- home -------------------------------------------------------------------------------------------------
def test_ur5_file_without_home_gets_a_non_singular_one():
    path = erd_share_dir() / ERD_ARMS["ur5"].urdf
    r = load_robot(str(path), "tool0")  # a plain file: no catalogue home
    zero = np.zeros(6)
    assert conditioning(r.kinematics, zero, "pose") < 1e-9  # the stretched arm is singular
    assert conditioning(r.kinematics, r.home, "pose") >= HOME_CONDITION
    assert np.array_equal(load_robot(str(path), "tool0").home, r.home)  # deterministic


# -- non-redundant tasks ----------------------------------------------------------------------------
def test_ur5_pose_task_with_an_index_returns_the_unique_solution_with_a_note():
    r = load_robot("ur5", task="pose")
    q = r.home + 0.1
    res = solve_ik(r, r.fk(q), JointDeviation(r.home))
    assert res.converged and "no redundancy" in res.notes
    assert np.abs(res.q - q).max() < 1e-8  # the solution nearest the seed; Newton converges quadratically


def test_tool_axis_turns_a_frame_onto_the_axis():
    plain = load_robot("ur5")
    for axis, unit in (("-x", [-1.0, 0.0, 0.0]), ([0, 3, 4], [0.0, 0.6, 0.8])):
        r = load_robot("ur5", tool_axis=axis)
        assert np.allclose(r.tool_axis, unit, atol=1e-15) and r.ee_frame == "tool0_tool_axis"
        q = r.home + 0.3
        T, T0 = r.fk(q), plain.fk(q)
        assert np.allclose(T[:3, 3], T0[:3, 3], atol=1e-12)  # the same point P
        assert np.allclose(T[:3, 2], T0[:3, :3] @ unit, atol=1e-12)  # its z axis is the tool axis
        assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    assert load_robot("ur5", tool_axis="z").ee_frame == "tool0"
    # an axis whose squares overflow (hypothesis found 1.34e154: the norm was inf, the axis zero, the home NaN) and
    # one of tiny entries: the unit axis still
    for v in ([0.0, 3e300, 4e300], [0.0, 1e154, 1.34e154]):
        unit = np.array([0.0, 1.0, v[2] / v[1]]) / np.hypot(1.0, v[2] / v[1])
        # each side a few correctly rounded operations on entries <= 1 (a quotient, a sum of squares or a hypot, a
        # root, a quotient): at most 2 ulps of 1 each, whatever the BLAS kernel's order or fused multiply-add
        assert np.allclose(load_robot("ur5", tool_axis=v).tool_axis, unit, rtol=0, atol=4 * np.finfo(float).eps)
    assert np.allclose(check_tool_axis([3e-8, 0.0, 4e-8]), [0.6, 0.0, 0.8], atol=1e-15)


@pytest.mark.parametrize(
    ("kwargs", "error", "needle"),
    [
        ({"tool_axis": "w"}, ChoiceError, "tool axis"),
        ({"tool_axis": [0, 0, 0]}, TaskError, "non-zero"),
        ({"tool_axis": [0, 1e-300, 0]}, TaskError, "non-zero"),
        ({"task": "pose", "tool_axis": "z"}, TaskError, "task='axis'"),
    ],
)
def test_bad_tool_axis(kwargs, error, needle):
    with pytest.raises(error, match=needle):
        load_robot("ur5", **kwargs)
    if "task" not in kwargs:
        with pytest.raises(TaskError, match="task='axis'"):  # the Panda's own task is the pose task
            load_robot("panda", tool_axis="x")


# -- URDF input that Pinocchio accepts silently --------------------------------------------------------
def _urdf(joint2: str = "", axis: str = "0 0 1", lower: str = "-1", upper: str = "1", extra: str = "") -> str:
    return f"""<?xml version="1.0"?>
<robot name="two">
  <link name="base"/><link name="l1"/><link name="l2"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.3"/><axis xyz="{axis}"/><limit lower="{lower}" upper="{upper}" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.4 0 0"/><axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/>{joint2}</joint>
  {extra}
</robot>
"""


def _write(tmp_path, text, data: bytes | None = None):
    path = tmp_path / "arm.urdf"
    if data is None:
        path.write_text(text)
    else:
        path.write_bytes(data)
    return str(path)


def test_valid_small_urdf_loads(tmp_path):
    r = load_robot(_write(tmp_path, _urdf()), "l2", task="position")
    assert r.nq == 2


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"axis": "0 0 0"}, "axis '0 0 0'"),  # FK was not a rigid motion (det 0.45)
        ({"lower": "1", "upper": "-1"}, "lower limit 1.0 > upper limit -1.0"),
        ({"extra": '<joint name="j1" type="fixed"><parent link="base"/><child link="l3"/></joint><link name="l3"/>'},
         "two joints are named 'j1'"),
        ({"extra": '<joint name="j3" type="fixed"><parent link="base"/><child link="l2"/></joint>'},
         "closed\\s+chain"),
        ({"joint2": '<mimic joint="j1" multiplier="2"/>'}, "mimic"),
        ({"joint2": '<mimic joint="j9"/>'}, "'j9', which is not a joint"),
    ],
)
def test_urdf_defects_are_refused(tmp_path, kwargs, needle):
    with pytest.raises(URDFError, match=needle):
        load_robot(_write(tmp_path, _urdf(**kwargs)), "l2", task="position")


def test_zero_axis_was_not_a_rigid_motion(tmp_path):
    """Why the zero axis is refused: Pinocchio's own model of the file is not a rigid motion."""
    m = pin.buildModelFromXML(_urdf(axis="0 0 0"))
    d = m.createData()
    pin.framesForwardKinematics(m, d, np.array([0.7, 0.2]))
    assert abs(np.linalg.det(d.oMf[m.getFrameId("l2")].rotation) - 1.0) > 0.1


def test_mimic_joints_are_never_free_coordinates(tmp_path):
    path = _write(tmp_path, _urdf(joint2='<mimic joint="j1" multiplier="2" offset="0.1"/>'))
    with pytest.raises(URDFError, match="mimic another joint"):  # kept: its own coordinate would be wrong
        load_robot(path, "l2", task="position", joints=["j2"])
    with pytest.raises(URDFError, match="lock its master"):  # locked, it would not follow j1 and moves l2
        load_robot(path, "l2", task="position", joints=["j1"])
    r = load_robot(path, "l1", task="planar", joints=["j1"])  # off the end-effector's chain: harmless
    assert r.nq == 1 and "j2" in r.locked


def test_mimic_joint_default_lock_follows_the_locked_master(tmp_path):
    extra = ('<link name="l3"/><joint name="j3" type="revolute"><parent link="l1"/><child link="l3"/>'
             '<axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>')
    path = _write(tmp_path, _urdf(joint2='<mimic joint="j1" multiplier="2" offset="0.1"/>', extra=extra))
    r = load_robot(path, "l3", task="planar", joints=["j3"], locked={"j1": 0.3})
    assert r.locked["j2"] == pytest.approx(0.7, abs=1e-15)  # 2 * 0.3 + 0.1


def test_non_utf8_urdf_is_a_urdf_error(tmp_path):
    data = _urdf().replace('name="two"', 'name="tw\u00f6"').encode("latin-1")
    with pytest.raises(URDFError, match="not UTF-8"):
        load_robot(_write(tmp_path, "", data), "l2")


# -- threads ----------------------------------------------------------------------------------------------
def test_threads_sharing_a_robot_give_the_serial_records():
    r = load_robot("panda", task="position")
    radii = (0.01, 0.02, 0.03)
    serial = [_track_circle(r, radius=rad) for rad in radii]
    out: dict[int, object] = {}
    barrier = threading.Barrier(len(radii))

    qs = [r.home + 0.3 * k for k in range(len(radii))]
    poses = [r.fk(q) for q in qs]
    wrong = [0] * len(radii)

    def run(k):
        barrier.wait()
        out[k] = _track_circle(r, radius=radii[k])
        for _ in range(3000):  # a pose is two Pinocchio calls: another thread's pass between them
            wrong[k] += int(np.abs(r.fk(qs[k]) - poses[k]).max() > 1e-12)

    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # switch threads often: a shared workspace would be overwritten mid-step
    try:
        threads = [threading.Thread(target=run, args=(k,)) for k in range(len(radii))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        sys.setswitchinterval(old)
    assert wrong == [0] * len(radii)
    for k, ref in enumerate(serial):
        # the same arithmetic in the same order: agreement to round-off (the bug gave 0.09 m)
        assert np.abs(out[k].q - ref.q).max() < 1e-12
        assert np.abs(out[k].p - ref.p).max() < 1e-12
        assert out[k].position_error.max() < TRACK_TOL


def test_each_thread_has_its_own_workspace_and_the_robot_pickles():
    r = load_robot("ur5")
    seen = []
    t = threading.Thread(target=lambda: seen.append(r.kinematics))
    t.start()
    t.join()
    assert seen[0] is not r.kinematics and seen[0].data is not r.kinematics.data  # one Data per thread
    assert r.kinematics is r.kinematics  # made once per thread
    r2 = pickle.loads(pickle.dumps(r))
    assert np.allclose(r2.fk(r.home), r.fk(r.home), atol=1e-15)


def test_cli_ik_on_the_ur5_pose_task_with_an_index_exits_0(capsys):
    import json

    from kinredund.ui.cli import main

    r = load_robot("ur5", task="pose")
    T = r.fk(r.home + 0.1)
    rpy = pin.rpy.matrixToRpy(T[:3, :3])
    target, angles = (",".join(f"{v:.17g}" for v in x) for x in (T[:3, 3], rpy))
    code = main(["ik", "ur5", "--task", "pose", "--index", "home", f"--target={target}", f"--rpy={angles}"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["converged"] and "no redundancy" in out["notes"]


def test_a_custom_chain_of_a_catalogue_arm_is_not_recorded_under_the_catalogue_name():
    right = [n.replace("left", "right") for n in BAXTER_LEFT]
    r = load_robot("baxter", "right_gripper", joints=right)
    assert r.name != "baxter" and r.name not in known_robots()  # a record must not reload the left arm
    assert load_robot("baxter").name == "baxter"


_JUNK = st.one_of(
    st.none(), st.booleans(), st.integers(-3, 3), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8), st.sampled_from(["left_s0", "head_pan", "left_gripper", "z", "-y", "pose", "axis"]),
    st.lists(st.one_of(st.sampled_from(["left_s0", "left_w2", "head_pan"]), st.integers(), st.floats()), max_size=4),
    st.dictionaries(st.one_of(st.sampled_from(["head_pan", "left_s0", "right_w2"]), st.integers()),
                    st.one_of(st.floats(allow_nan=True), st.text(max_size=3), st.complex_numbers()), max_size=3),
    st.lists(st.complex_numbers(allow_nan=True), min_size=3, max_size=3),
)


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(option=st.sampled_from(["ee_frame", "task", "tool_axis", "joints", "locked"]), value=_JUNK)
def test_malformed_options_raise_only_the_project_errors(option, value):
    try:
        load_robot("ur5" if option == "tool_axis" else "baxter", **{option: value})
    except KinredundError:
        pass


def test_playback_draws_locked_joints_where_the_loader_locked_them(monkeypatch):
    """The visual model keeps every joint of the file: the locked ones must sit at robot.locked."""
    from collections import defaultdict
    from types import SimpleNamespace

    from kinredund.ui.viz import _meshcat
    from kinredund.ui.viz._meshcat import RobotVisuals

    class _Stub:  # Pinocchio's MeshcatVisualizer without a viewer: nothing is drawn
        def __init__(self, *args):
            pass

        def initViewer(self, **kwargs):  # noqa: N802 - Pinocchio's visualizer API
            pass

        def getViewerNodeName(self, geom, kind):  # noqa: N802
            return geom.name

    monkeypatch.setattr(_meshcat, "load_compact", lambda node, geom, mc: True)  # no mesh is loaded
    r = load_robot("tiago", locked={"torso_lift_joint": 0.3})
    visuals = RobotVisuals(r, defaultdict(object), SimpleNamespace(MeshcatVisualizer=_Stub))
    full = visuals.full_q(r.home)
    model = load_urdf(r.urdf_path).model  # the visual model's joints (continuous wheels as angles)
    assert full[model.idx_qs[model.getJointId("torso_lift_joint")]] == 0.3  # copied, not computed
    assert full[model.idx_qs[model.getJointId("arm_1_joint")]] == r.home[0]


def test_a_relative_urdf_path_is_stored_absolute_and_a_file_named_like_an_arm_keeps_its_path(tmp_path, monkeypatch):
    (tmp_path / "arms").mkdir()
    (tmp_path / "arms" / "panda.urdf").write_text(_urdf())
    monkeypatch.chdir(tmp_path)
    r = load_robot("arms/panda.urdf", "l2", task="position")
    assert r.urdf_path.is_absolute() and r.urdf_path == tmp_path / "arms" / "panda.urdf"
    assert r.name == str(r.urdf_path)  # "panda" would reload the catalogue's Panda from a record
    assert load_robot("arms/panda.urdf", "l2").nq == 2


def test_section_6_3_arm_loads_by_name_and_equals_the_planner_s():
    """`cybotech_p15_x8` (the 6.3 records' robot) reloads by name: the planner's arm, and Table 4.1 with
    every length times 8 (checked against the table itself, not against the function that scales it)."""
    from kinredund.model.catalog import cybotech_p15
    from kinredund.planning.spatial import scaled_p15

    r, ref, table = load_robot("cybotech_p15_x8"), scaled_p15(), cybotech_p15()
    assert r.name == ref.name and r.task == "position" and "cybotech_p15_x8" in kinredund.known_robots()
    assert np.array_equal(r.hd.alpha, table.alpha)  # copied, not computed
    assert np.abs(r.hd.a - 8.0 * np.asarray(table.a)).max() <= 1e-15 * max(1.0, np.abs(r.hd.a).max())
    assert np.abs(r.hd.b - 8.0 * np.asarray(table.b)).max() <= 1e-15 * max(1.0, np.abs(r.hd.b).max())
    rng = np.random.default_rng(3)
    for q in (r.random_configuration(rng) for _ in range(3)):
        assert np.abs(r.fk(q) - ref.fk(q)).max() < 1e-14  # the planner's arm is this model
    with pytest.raises(kinredund.ChoiceError):
        load_robot("cybotech_p15_x8", joints=["j1"])


def test_concurrent_urdf_parses_leave_the_process_stderr_where_it_was():
    """fd 2 is the process's: two captures interleaved (thread B starts while A's parser runs) used to end
    with fd 2 pointing at A's deleted temporary file (issue 26). The lock makes B wait for A."""
    import os

    from kinredund.model import urdf

    before = os.fstat(2)
    a_in, b_in, a_done = threading.Event(), threading.Event(), threading.Event()

    def slow_parse():  # thread A: still "parsing" when B starts its capture
        a_in.set()
        b_in.wait(0.5)  # with the lock, B cannot get in: A goes on after the timeout

    def quick_parse():  # thread B: ends after A, restoring what it saw as fd 2 (A's temporary file)
        b_in.set()
        a_done.wait(5.0)

    def first():
        urdf._capture_stderr_fd(slow_parse)
        a_done.set()

    a = threading.Thread(target=first)
    a.start()
    a_in.wait(5.0)
    b = threading.Thread(target=urdf._capture_stderr_fd, args=(quick_parse,))
    b.start()
    a.join()
    b.join()
    after = os.fstat(2)
    assert (after.st_dev, after.st_ino) == (before.st_dev, before.st_ino)
    robots = []
    threads = [threading.Thread(target=lambda: robots.append(load_robot("panda"))) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(robots) == 4 and (os.fstat(2).st_dev, os.fstat(2).st_ino) == (before.st_dev, before.st_ino)


def test_a_urdf_in_a_folder_with_braces_reloads_from_its_record_name(tmp_path):
    """A record names a URDF robot loaded with options as path + JSON options; the options were looked for
    from the first '{', so a file under a folder such as 'arm{v2}' could not be reloaded from its record."""
    import shutil

    from kinredund.model.loader import shipped_robot_dir

    folder = tmp_path / "arm{v2}"
    folder.mkdir()
    urdf = folder / "planar3r_ch6.urdf"
    shutil.copy(shipped_robot_dir() / "planar3r_ch6.urdf", urdf)
    r = kinredund.load_robot(urdf, "ee", task="planar")
    again = kinredund.load_robot(r.source, task="planar")
    assert again.urdf_path == r.urdf_path and again.ee_frame == "ee" and again.source == r.source
    q = r.home + 0.1
    assert np.abs(again.fk(q) - r.fk(q)).max() == 0.0  # the same model, built again from the same file


@pytest.mark.parametrize("task", sorted(TASKS))
def test_a_retasked_robot_pickles_and_reloads_as_itself(task):
    """``with_task`` from an axis robot with a turned tool axis: a pickled copy reloads from its ``source`` (what a
    record and a Dask worker use) as the same robot: the task, the end-effector frame and its pose. Reproducer: the
    source kept the tool axis, which load_robot refuses for a task without one ('position': TaskError)."""
    r = load_robot("panda", task="axis", tool_axis="x").with_task(task)
    back = pickle.loads(pickle.dumps(r))
    again = load_robot(back.source, task=back.task)
    assert (again.task, again.ee_frame, again.task_dim) == (task, r.ee_frame, r.task_dim)
    for q in np.random.default_rng(7).uniform(r.lower, r.upper, (5, r.nq)):
        np.testing.assert_allclose(again.fk(q), r.fk(q), rtol=0, atol=rounding(1.0))  # the same chain, computed twice
