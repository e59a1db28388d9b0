"""Robot models: HD tables, generated URDF, shipped files, loading by name or path, and bad input."""

from __future__ import annotations

import io
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yourdfpy
from conftest import robot
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import kinredund
from kinredund.kinematics.hd import HDTable
from kinredund.model.catalog import SHIPPED_TABLES
from kinredund.model.generate import validated_urdf
from kinredund.model.loader import shipped_robot_dir
from kinredund.model.urdf import EE_FRAME, hd_to_model, hd_to_urdf, load_urdf_text_model

REPO = Path(__file__).resolve().parent.parent


@pytest.mark.parametrize("name", sorted(SHIPPED_TABLES))
def test_shipped_urdf_equals_generator_output(name):
    shipped = (REPO / "robots" / f"{name}.urdf").read_text()
    assert shipped == validated_urdf(SHIPPED_TABLES[name]())


def test_installed_package_finds_shipped_robots():
    folder = shipped_robot_dir()
    for name in SHIPPED_TABLES:
        assert (folder / f"{name}.urdf").is_file()
    assert kinredund.load_robot("planar3r").nq == 3


def test_built_wheel_ships_the_robots(tmp_path):
    """A plain wheel (not an editable install) must carry robots/*.urdf as kinredund/robots/."""
    out = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", str(tmp_path),
         str(REPO)],
        capture_output=True, text=True,
    )
    if out.returncode != 0:
        pytest.fail(f"wheel build failed: {out.stderr[-2000:]}")
    wheel = next(tmp_path.glob("kinredund-*.whl"))
    names = zipfile.ZipFile(wheel).namelist()
    for name in SHIPPED_TABLES:
        assert f"kinredund/robots/{name}.urdf" in names
    for init in (REPO / "kinredund").rglob("__init__.py"):  # every subpackage is in the wheel
        assert init.relative_to(REPO).as_posix() in names


def _angles(draw_n):
    return st.lists(st.floats(-np.pi, np.pi), min_size=draw_n, max_size=draw_n)


@st.composite
def hd_tables(draw):
    n = draw(st.integers(1, 7))
    fl = st.floats(-1.0, 1.0, allow_nan=False)
    alpha = draw(st.lists(st.floats(-np.pi, np.pi), min_size=n, max_size=n))
    a = draw(st.lists(fl, min_size=n, max_size=n))
    b = draw(st.lists(fl, min_size=n, max_size=n))
    kinds = "".join(draw(st.lists(st.sampled_from("RP"), min_size=n, max_size=n)))
    theta0 = draw(st.lists(st.floats(-np.pi, np.pi), min_size=n, max_size=n))
    return HDTable(alpha=alpha, a=a, b=b, kinds=kinds, theta0=theta0, name="random_arm")


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(table=hd_tables(), seed=st.integers(0, 2**16))
def test_random_hd_arms_load_identically_through_urdf(table, seed):
    """Direct model, Pinocchio-from-URDF and yourdfpy-from-URDF give the same FK as the HD product."""
    text = hd_to_urdf(table)
    direct, via_urdf = hd_to_model(table), load_urdf_text_model(text)
    ydf = yourdfpy.URDF.load(io.BytesIO(text.encode()), load_meshes=False)
    assert ydf.validate()
    q = np.random.default_rng(seed).uniform(table.lower, table.upper)
    d1, d2 = direct.createData(), via_urdf.createData()
    pin.framesForwardKinematics(direct, d1, q)
    pin.framesForwardKinematics(via_urdf, d2, q)
    T_ref = table.fk(q)
    assert np.abs(d1.oMf[direct.getFrameId(EE_FRAME)].homogeneous - T_ref).max() < 1e-12
    assert np.abs(d2.oMf[via_urdf.getFrameId(EE_FRAME)].homogeneous - T_ref).max() < 1e-12
    ydf.update_cfg({f"joint_{i + 1}": q[i] for i in range(table.n)})
    # yourdfpy's origins (trimesh's compose_matrix) take rpy angles below ~1e-8 as zero (a Hypothesis draw with
    # theta0 = 2.5e-12 moved its frame by 2.5e-12): its FK is compared where no angle is that small but nonzero
    if not any(0.0 < abs(x) < 1e-6 for x in (*table.alpha, *table.theta0)):
        assert np.abs(ydf.get_transform(EE_FRAME, "base_link") - T_ref).max() < 1e-12


@pytest.mark.parametrize(
    ("name", "nq", "task", "m"),
    [("planar3r", 3, "planar", 2), ("planar3r_ch6", 3, "planar", 2), ("puma7", 7, "pose", 6),
     ("cybotech_p15", 7, "pose", 6), ("panda", 7, "pose", 6), ("xarm7", 7, "pose", 6)],
)
def test_known_robots(name, nq, task, m):
    r = robot(name)
    assert (r.nq, r.task, r.task_dim) == (nq, task, m)
    assert r.lower.shape == r.upper.shape == (nq,) and np.all(r.lower < r.upper)
    assert np.all(np.isfinite(r.lower)) and np.all(np.isfinite(r.upper))
    T = r.fk(r.home)
    assert T.shape == (4, 4) and np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3))


def test_cybotech_limits_as_in_notes():
    r = robot("cybotech_p15")
    assert np.allclose(r.lower[:4], [-np.pi / 2, -np.pi / 4, -np.pi / 4, -np.pi / 3])
    assert np.allclose(r.upper[:4], [np.pi / 2, np.pi / 4, 3 * np.pi / 4, np.pi / 3])


def test_task_override_and_urdf_path_with_frame():
    r = kinredund.load_robot("puma7", task="position")
    assert r.task_dim == 3
    path = shipped_robot_dir() / "cybotech_p15.urdf"
    r2 = kinredund.load_robot(str(path), ee_frame="link_4")
    assert r2.ee_frame == "link_4" and r2.nq == 7
    assert kinredund.load_robot(str(path)).ee_frame == "ee"


# -- bad input --------------------------------------------------------------------------------------
def test_unknown_robot_lists_known_names():
    with pytest.raises(kinredund.UnknownRobotError) as err:
        kinredund.load_robot("kuka_iiwa")
    assert "kuka_iiwa" in str(err.value) and "panda" in str(err.value) and "planar3r" in str(err.value)


@pytest.mark.parametrize("name", ["", "   "])
def test_an_empty_robot_name_lists_known_names(name):
    """'' is no robot (it was read as the current folder: "cannot load URDF '/tmp': ... a directory")."""
    with pytest.raises(kinredund.UnknownRobotError, match=f"unknown robot '{name}': .* known names .*panda"):
        kinredund.load_robot(name)


def test_missing_urdf_file():
    with pytest.raises(kinredund.UnknownRobotError, match="nothere.urdf"):
        kinredund.load_robot("/tmp/nothere.urdf")


def test_urdf_that_does_not_parse_says_why(tmp_path):
    bad = tmp_path / "bad.urdf"
    bad.write_text(
        '<robot name="x"><link name="a"/><link name="b"/><joint name="j" type="revolute">'
        '<parent link="a"/><child link="b"/></joint></robot>'
    )
    with pytest.raises(kinredund.URDFError) as err:
        kinredund.load_robot(str(bad))
    assert "limits" in str(err.value)  # urdfdom's reason, not only "invalid"
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='x'><link name='a'>")
    with pytest.raises(kinredund.URDFError, match="not well-formed"):
        kinredund.load_robot(str(broken))
    wrong_root = tmp_path / "root.urdf"
    wrong_root.write_text("<sdf/>")
    with pytest.raises(kinredund.URDFError, match="<robot>"):
        kinredund.load_robot(str(wrong_root))


def test_missing_frame_lists_frames():
    with pytest.raises(kinredund.FrameNotFoundError) as err:
        kinredund.load_robot("planar3r", ee_frame="tool0")
    assert "tool0" in str(err.value) and "ee" in err.value.frames and "link_3" in str(err.value)


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"alpha": [0, 0], "a": [1.0], "b": [0, 0]}, "'a' must have shape (2,) for 2 joints"),
        ({"alpha": [0.0], "a": [np.nan], "b": [0.0]}, "non-finite"),
        ({"alpha": [[0.0]], "a": [1.0], "b": [0.0]}, "'alpha' must have shape (n,), got (1, 1)"),
        ({"alpha": [0.0], "a": [1.0], "b": [0.0], "kinds": "X"}, "R, P"),
        ({"alpha": [], "a": [], "b": []}, "at least one joint"),
        ({"alpha": [0.0], "a": [1.0], "b": [0.0], "lower": [1.0], "upper": [0.0]}, "lower < upper"),
        ({"alpha": ["x"], "a": [1.0], "b": [0.0]}, "'alpha' must be numeric"),
    ],
)
def test_bad_hd_tables(kwargs, needle):
    with pytest.raises(kinredund.HDTableError, match=re.escape(needle)):
        HDTable(**kwargs)


@pytest.mark.parametrize(
    ("q", "needle"),
    [([0.0, 0.0], r"shape \(3,\)"), ([0.0, np.nan, 0.0], "non-finite"), (["a", 0, 0], "numeric"),
     ([[0.0, 0.0, 0.0]], r"shape \(3,\)")],
)
def test_bad_joint_vectors(q, needle):
    r = robot("planar3r")
    for fn in (r.fk, r.velocity_jacobian, r.position_jacobian, r.velocity_jacobian_derivative):
        with pytest.raises(kinredund.JointVectorError, match=needle):
            fn(q)


def test_bad_task_kind():
    with pytest.raises(kinredund.ChoiceError, match="planar, position, pose, axis"):
        kinredund.load_robot("planar3r", task="orientation")


def test_generate_robots_command_writes_identical_files(tmp_path):
    from kinredund.ui.cli import main

    assert main(["generate-robots", "--out", str(tmp_path)]) == 0
    for name in SHIPPED_TABLES:
        assert (tmp_path / f"{name}.urdf").read_text() == (REPO / "robots" / f"{name}.urdf").read_text()
    assert not list(tmp_path.glob("*.tmp"))


def test_generate_robots_and_demo_refuse_an_empty_or_file_output_folder(tmp_path, monkeypatch, capsys):
    """--out "" wrote the URDFs (and the demo its folder) into the current folder, and generate-robots --out FILE
    said "cannot write 'FILE/planar3r.urdf': Not a directory": both are refused as demo --out FILE is
    (kinredund.io.output_folder), and nothing is written."""
    from kinredund.ui.cli import EXIT_USAGE, main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "file.txt").write_text("x")
    for command in ("generate-robots", "demo"):  # demo --out "" too (the same check)
        assert main([command, "--out", ""]) == EXIT_USAGE
        assert "the path is empty" in capsys.readouterr().err
    assert main(["generate-robots", "--out", "file.txt"]) == EXIT_USAGE
    assert "'file.txt': it exists and is not a folder" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]


def test_turn_into_limits_keeps_the_pose_and_lands_inside():
    """Angles turned by multiples of 2 pi land at the lowest value >= the lower limit, inside the limits
    where any turn can put them (ok), and the forward kinematics does not change."""
    from kinredund.kinematics.angles import turn_into_limits

    r = robot("panda")
    rng = np.random.default_rng(12)
    for _ in range(20):
        q = r.random_configuration(rng) + 2.0 * np.pi * rng.integers(-3, 4, r.nq)
        turned, ok = turn_into_limits(q, r.lower, r.upper)
        k = (turned - q) / (2.0 * np.pi)
        assert np.allclose(k, np.round(k), rtol=0, atol=1e-12)
        assert np.all(turned >= r.lower - 1e-12) and np.all(turned - 2.0 * np.pi < r.lower)
        assert np.array_equal(ok, turned <= r.upper)
        assert np.allclose(r.fk(np.where(ok, turned, q)), r.fk(q), atol=1e-12)


def test_sample_box_cuts_unbounded_limits():
    """random_configuration draws from Robot.sample_box: the limits shrunk by the margin, with
    unbounded revolute joints cut to [-pi, pi]."""
    r = robot("panda")
    lo, hi = r.sample_box(0.1)
    span = r.upper - r.lower
    assert np.array_equal(lo, r.lower + 0.1 * span) and np.array_equal(hi, r.upper - 0.1 * span)
    rng = np.random.default_rng(3)
    qs = np.array([r.random_configuration(rng, 0.1) for _ in range(5)])
    assert len({tuple(q) for q in qs}) == 5  # five draws, not one draw five times
    assert np.all((qs >= lo) & (qs <= hi))
    model = r.model.copy()
    lower, upper = model.lowerPositionLimit.copy(), model.upperPositionLimit.copy()
    lower[0], upper[0] = -1e300, 1e300
    model.lowerPositionLimit, model.upperPositionLimit = lower, upper
    wide = kinredund.Robot("wide", model, r.ee_frame, "pose")
    lo, hi = wide.sample_box()
    assert (lo[0], hi[0]) == (-np.pi, np.pi) and np.array_equal(lo[1:], r.lower[1:])
    assert np.all(np.isfinite(wide.random_configuration(np.random.default_rng(0))))
