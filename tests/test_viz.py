"""Playback: resampling, obstacle and camera geometry, standalone HTML replays, the live server and a
real browser (headless Chromium driven through the DevTools protocol).

Test data are synthetic trajectories built from forward kinematics: joints moving sinusoidally,
p = fk(q). The HTML replay is checked two ways: by decoding meshcat's scene commands (the
animation's keyframes against the robot's own joint origins) and by looking at it in Chromium.
"""

from __future__ import annotations

import base64
import dataclasses
import math
import os
import re
import subprocess
import sys
import tempfile
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
from _chromium import MESHCAT_READY, NO_WEBGL, needs_chromium, open_page, scrub
from conftest import robot

from kinredund import ChoiceError, JointVectorError, PathError, TaskError
from kinredund.planning.obstacles import OBSTACLE_KINDS, obstacle_from_dict
from kinredund.trajectory import Trajectory
from kinredund.ui.viz import play_live, replay_html, resample, stop_live
from kinredund.ui.viz.live import live_visualizer
from kinredund.ui.viz.scene import (
    CAMERA_FOV_DEG,
    camera_view,
    obstacle_corner_points,
    obstacle_frame,
    obstacle_outline,
    read_obstacle,
    to_camera_axes,
    unit_cylinder_transform,
)

PLANAR_OBSTACLE = {"kind": "ellipse", "center": [3.0, 3.0, 0.0], "a": 0.8, "b": 0.4, "angle": math.radians(20)}
ORANGE = np.array([0.9, 0.55, 0.1])  # the shipped robots' link colour


def synthetic(name: str = "planar3r", duration: float = 4.0, steps: int = 121, obstacle=None, seed: int = 0):
    """A trajectory whose joints move sinusoidally (one period over ``duration``), p from FK."""
    r = robot(name)
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, duration, steps)
    centre = np.clip(r.home + rng.uniform(-0.3, 0.3, r.nq), r.lower + 0.7, r.upper - 0.7)
    phase = rng.uniform(0.0, 2.0 * np.pi, r.nq)
    q = centre + 0.6 * np.sin(2.0 * np.pi * t[:, None] / duration + phase)
    p = np.array([r.fk(qi)[:3, 3] for qi in q])
    meta = {} if obstacle is None else {"obstacle": obstacle}
    return Trajectory(robot=name, task=r.task, t=t, q=q, p=p, p_desired=p.copy(), solver=("qp",) * steps, meta=meta)


def children() -> set[int]:
    """PIDs of the live (not zombie) child processes of this process."""
    out = set()
    me = os.getpid()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[1]) == me and fields[0] != "Z":
            out.add(int(entry))
    return out


def scene_commands(html: str) -> list[dict]:
    """Decode the msgpack scene commands embedded in meshcat's static HTML."""
    import umsgpack

    blobs = re.findall(r'data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"', html)
    return [umsgpack.unpackb(base64.b64decode(b)) for b in blobs]


def payload(obj) -> int:
    """Characters and bytes held in a decoded command (mesh files are embedded as text or bytes)."""
    if isinstance(obj, (str, bytes)):
        return len(obj)
    if hasattr(obj, "data") and isinstance(obj.data, bytes):  # msgpack extension (typed arrays)
        return len(obj.data)
    if isinstance(obj, dict):
        return sum(payload(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(payload(v) for v in obj)
    return 0


def floor_points(cmds: list[dict]) -> np.ndarray:
    """End points of the floor grid's lines (the ``/meshcat/floor`` LineSegments), shape (2 L, 3) [m]."""
    floor = next(c for c in cmds if c["type"] == "set_object" and c["path"] == "/meshcat/floor")
    assert floor["object"]["object"]["type"] == "LineSegments"
    array = floor["object"]["geometries"][0]["data"]["attributes"]["position"]["array"]
    return np.frombuffer(array.data, dtype=np.float32).reshape(-1, 3)


def track(animation: dict, path: str, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(times [frames], values) of one track of the animation of node ``path``."""
    for entry in animation["animations"]:
        if entry["path"] == path:
            for tr in entry["clip"]["tracks"]:
                if tr["name"] == "." + name:
                    keys = tr["keys"]
                    return np.array([k["time"] for k in keys]), np.array([k["value"] for k in keys])
    raise KeyError(f"no {name} track for {path}")


# -- pure geometry --------------------------------------------------------------------------------
def test_resample_realtime_keeps_the_clock_and_the_motion():
    traj = synthetic(duration=4.0, steps=121)
    frames = resample(traj, fps=30, max_frames=900, realtime=True)
    assert len(frames.times) == math.ceil(4.0 * 30) + 1
    assert frames.times[0] == 0.0 and frames.times[-1] == pytest.approx(4.0)
    # the frames fall between stored steps: linear interpolation of q
    for j in range(traj.q.shape[1]):
        np.testing.assert_allclose(frames.q[:, j], np.interp(frames.times, traj.t, traj.q[:, j]), atol=1e-12)
    capped = resample(traj, fps=30, max_frames=50, realtime=True)
    assert len(capped.times) == 50 and capped.times[-1] == pytest.approx(4.0)
    stepwise = resample(traj, fps=10, max_frames=900, realtime=False)
    np.testing.assert_allclose(stepwise.q, traj.q, atol=1e-12)
    np.testing.assert_allclose(np.diff(stepwise.times), 0.1)


def test_resample_rejects_bad_rates():
    traj = synthetic(steps=11)
    with pytest.raises(TaskError, match="fps"):
        resample(traj, fps=0)
    with pytest.raises(TaskError, match="max_frames"):
        resample(traj, max_frames=1)


def test_trajectory_check_names_the_problem():
    """Trajectory.checked, what playback (and the plots, and reading JSON) validate a record with."""
    traj = synthetic(steps=11)
    with pytest.raises(JointVectorError, match=r"shape \(11, 7\) for robot 'planar3r'"):
        traj.checked(7)
    bad_t = traj.t.copy()
    bad_t[5] = bad_t[4]
    with pytest.raises(PathError, match="increase"):
        dataclasses.replace(traj, t=bad_t).checked(3)
    with pytest.raises(PathError, match=r"p_desired \[m\] must have shape \(11, 3\)"):
        dataclasses.replace(traj, p_desired=traj.p_desired[:, :2]).checked()
    with pytest.raises(ChoiceError, match="trajectory task"):
        dataclasses.replace(traj, task="planer").checked()
    good = dataclasses.replace(traj, t=traj.t.tolist(), q=traj.q.tolist()).checked(3)  # lists become arrays
    assert isinstance(good.t, np.ndarray) and good.q.shape == (11, 3)
    # a record read from JSON goes through the same check
    data = traj.to_json_dict()
    data["q"][4] = data["q"][4][:2]  # a ragged list
    with pytest.raises(JointVectorError, match="trajectory q must be numeric"):
        Trajectory.from_json_dict(data)
    data = traj.to_json_dict()
    data["position_error"] = [0.0] * 10
    with pytest.raises(TaskError, match=r"position_error .*must have shape \(11,\)"):
        Trajectory.from_json_dict(data)
    back = Trajectory.from_json_dict(traj.to_json_dict())
    np.testing.assert_array_equal(back.q, traj.q)
    assert back.solver == traj.solver


@pytest.mark.parametrize("kind", OBSTACLE_KINDS)
def test_obstacle_transform_maps_the_unit_cylinder_onto_the_ellipse(kind):
    rng = np.random.default_rng(3)
    angle = 0.7
    spec = {"kind": kind, "center": [0.4, -0.2, 0.3], "a": 0.5, "b": 0.2, "angle": angle,
            "axis": [0.0, 0.0, 1.0], "height": 0.6}
    obs = obstacle_from_dict(spec)  # what build_scene reads from traj.meta["obstacle"]
    T = unit_cylinder_transform(obs)
    assert np.linalg.det(T[:3, :3]) > 0  # no reflection: meshcat decomposes it into rotation and scale
    s = rng.uniform(0, 2 * np.pi, 50)
    h = rng.uniform(-0.5, 0.5, 50)
    local = np.column_stack([np.cos(s), h, np.sin(s), np.ones(50)])  # rim of meshcat's y-axis cylinder
    world = (T @ local.T).T[:, :3] - obs.center
    R = obstacle_frame(obs)
    u, v, w = (world @ R).T
    np.testing.assert_allclose((u / 0.5) ** 2 + (v / 0.2) ** 2, 1.0, atol=1e-12)  # on the ellipse
    np.testing.assert_allclose(w, 0.6 * h, atol=1e-12)  # along the axis, over the height
    np.testing.assert_allclose(R[:, 0], [math.cos(angle), math.sin(angle), 0.0], atol=1e-12)  # major axis at psi
    # the unit cylinder's axis (local y, height 1) is drawn along the obstacle's own axis, over its height
    np.testing.assert_allclose(T[:3, :3] @ [0.0, 1.0, 0.0], 0.6 * np.asarray(obs.to_dict()["axis"]), atol=1e-12)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    # the rim, checked with the planner's exact distance instead of the frame: it is the obstacle's ellipse
    np.testing.assert_allclose(obs.ellipse_distance(world + obs.center), 0.0, atol=1e-12)
    np.testing.assert_allclose(obs.ellipse_distance(obstacle_outline(obs)), 0.0, atol=1e-12)
    corners = obstacle_corner_points(obs)
    np.testing.assert_allclose(np.sort(np.unique(np.round(corners[:, 2], 12))), [0.0, 0.6], atol=1e-12)


def test_obstacle_errors_name_the_key():
    def read(obstacle):
        return read_obstacle(synthetic(steps=3, obstacle=obstacle))

    assert read(None) is None
    with pytest.raises(ChoiceError, match="ellipse, elliptic_cylinder"):
        read({"kind": "box", "center": [0, 0, 0], "a": 1, "b": 1})
    with pytest.raises(TaskError, match=r"misses b;"):
        read({"kind": "ellipse", "center": [0, 0, 0], "a": 1})
    with pytest.raises(TaskError, match=r"semi-axis a( \[m\])? must be a finite number > 0"):
        read({"kind": "ellipse", "center": [0, 0, 0], "a": -1, "b": 1})
    # (the messages of kinredund.planning.obstacles before and after its shared checks: either names the key)
    with pytest.raises(TaskError, match=r"center (must be 2 or 3 finite numbers|\[m\] \(2 or 3 numbers\) must have "
                                        r"shape \(3,\), got \(4,\))"):
        read({"kind": "ellipse", "center": [0, 0, 0, 0], "a": 1, "b": 1})
    with pytest.raises(TaskError, match="axis along \\+Z"):
        read({"kind": "ellipse", "center": [0, 0, 0], "a": 1, "b": 1, "axis": [1, 0, 0]})
    with pytest.raises(TaskError, match=r"height( \[m\])? must be a finite number > 0"):
        read({"kind": "elliptic_cylinder", "center": [0, 0, 0], "a": 1, "b": 1, "height": 0})
    with pytest.raises(TaskError, match="center .* must be numeric, got 'abc'"):
        read({"kind": "ellipse", "center": "abc", "a": 1, "b": 1})
    with pytest.raises(TaskError, match="axis must be numeric"):
        read({"kind": "ellipse", "center": [0, 0, 0], "a": 1, "b": 1, "axis": "up"})
    with pytest.raises(TaskError, match="top_plane must be a dict with normal and point"):
        read({"kind": "elliptic_cylinder", "center": [0, 0, 0], "a": 1, "b": 1, "top_plane": {}})


def meshcat_camera_rotation() -> np.ndarray:
    """The rotation meshcat's viewer gives ``/Cameras/default/rotated``, read from its JavaScript bundle."""
    import meshcat

    bundle = Path(meshcat.__file__).parent / "viewer" / "dist" / "main.min.js"
    found = re.search(r"create_camera\(\)\{[^}]*?makeRotation([XYZ])\((-?)Math\.PI(?:/(\d+))?\)", bundle.read_text())
    assert found, "meshcat's create_camera no longer sets the rotated frame by makeRotation{X,Y,Z}(Math.PI/k)"
    axis, sign, div = found.groups()
    angle = (-1.0 if sign else 1.0) * math.pi / float(div or 1)
    c, s = math.cos(angle), math.sin(angle)
    k = "XYZ".index(axis)
    R = np.eye(3)
    i, j = [m for m in range(3) if m != k]
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


@pytest.mark.parametrize("planar", [True, False])
def test_camera_sees_every_scene_point(planar):
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(200, 3)) * [3.0, 1.0, 0.5] + [1.0, 2.0, 0.0]
    center, offset = camera_view(pts, planar)
    cam = center + offset
    half_fov = math.radians(CAMERA_FOV_DEG / 2)
    look = -offset / np.linalg.norm(offset)
    rays = pts - cam
    angles = np.arccos(np.clip(rays @ look / np.linalg.norm(rays, axis=1), -1, 1))
    assert angles.max() < half_fov
    # the camera's local position, through meshcat's own rotated frame, is the world offset; and the
    # camera's up axis (its y) is the world's up (z), so the robot stands upright on the screen
    R = meshcat_camera_rotation()
    np.testing.assert_allclose(R @ to_camera_axes(offset), offset, atol=1e-12)
    np.testing.assert_allclose(R[:, 1], [0.0, 0.0, 1.0], atol=1e-12)


def test_import_viz_does_not_import_meshcat():
    code = "import sys, kinredund.ui.viz, kinredund.ui.plots; print('meshcat' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "False"


# -- standalone HTML -------------------------------------------------------------------------------
def test_replay_html_holds_robot_path_obstacle_and_animation(tmp_path):
    traj = synthetic(duration=4.0, steps=121, obstacle=PLANAR_OBSTACLE)
    before = children()
    out = replay_html(traj, tmp_path / "sub" / "replay.html", fps=30)  # robot loaded from traj.robot
    assert children() == before  # the meshcat server is gone
    assert out == tmp_path / "sub" / "replay.html"
    assert sorted(p.name for p in out.parent.iterdir()) == ["replay.html"]  # no temporary file left
    html = out.read_text()
    assert "MeshCat.Viewer" in html
    cmds = scene_commands(html)
    objects = {c["path"] for c in cmds if c["type"] == "set_object"}
    visuals = {p for p in objects if p.startswith("/meshcat/robot/visuals/")}
    assert len(visuals) >= 3
    assert {"/meshcat/path/desired", "/meshcat/obstacle", "/meshcat/path/tracer"} <= objects
    desired = next(c for c in cmds if c["path"] == "/meshcat/path/desired")
    array = desired["object"]["geometries"][0]["data"]["attributes"]["position"]["array"]
    line = np.frombuffer(array.data, dtype=np.float32).reshape(-1, 3)  # a msgpack Float32Array extension
    np.testing.assert_allclose(line, traj.p_desired, atol=1e-5)

    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    fps = anim["animations"][0]["clip"]["fps"]
    keys, tracer = track(anim, "/meshcat/path/tracer", "position")
    assert keys[-1] / fps == pytest.approx(4.0)  # plays at the trajectory's own speed
    assert math.isinf(anim["options"]["repetitions"])  # loops by default
    # the joint-3 axis cylinder (visual link_3_0) sits at joint 3's origin: check every keyframe
    r = robot("planar3r")
    _, pos = track(anim, "/meshcat/robot/visuals/link_3_0", "position")
    clock = keys / fps
    for k in range(0, len(clock), 17):
        q = np.array([np.interp(clock[k], traj.t, traj.q[:, j]) for j in range(3)])
        np.testing.assert_allclose(pos[k], r.kinematics.joint_origins(q)[2], atol=1e-9)
        np.testing.assert_allclose(tracer[k], [np.interp(clock[k], traj.t, traj.p[:, i]) for i in range(3)],
                                   atol=1e-9)
    # the scene is shifted so that the camera's orbit centre is the centre of the scene; the floor is a
    # child of /meshcat (so it shifts with the robot) and meshcat's own 20 m grid is hidden
    shift = next(c for c in cmds if c["type"] == "set_transform" and c["path"] == "/meshcat")
    axes = next(c for c in cmds if c["type"] == "set_transform" and c["path"] == "/Axes")
    assert shift["matrix"] == axes["matrix"]
    hidden = [c for c in cmds if c["type"] == "set_property" and c["path"] == "/Grid"]
    assert [(c["property"], c["value"]) for c in hidden] == [("visible", False)]
    floor = floor_points(cmds)
    np.testing.assert_array_equal(floor[:, 2], 0.0)  # on z = 0 of the robot's frame
    reach = np.vstack([traj.p, traj.p_desired])[:, :2]
    assert np.all(floor[:, :2].min(axis=0) < reach.min(axis=0))  # under the whole motion
    assert np.all(floor[:, :2].max(axis=0) > reach.max(axis=0))
    # the page names the robot and the path, and has a time readout and a legend
    assert 'id="kinredund-title"' in html and "planar3r: closed path, augmented scheme" not in html
    assert "planar3r: open path, augmented scheme (default mode)" in html  # synthetic: no loop_period
    assert 'id="kinredund-time"' in html and "desired path" in html and "obstacle" in html


def test_replay_html_bad_input_leaves_nothing_behind(tmp_path):
    before = children()
    traj = synthetic(steps=11, obstacle={"kind": "sphere", "center": [0, 0, 0], "a": 1, "b": 1})
    with pytest.raises(ChoiceError, match="obstacle kind"):
        replay_html(traj, tmp_path / "x.html", robot=robot("planar3r"))
    with pytest.raises(JointVectorError, match="shape"):
        replay_html(synthetic(steps=11), tmp_path / "x.html", robot=robot("panda"))
    assert children() == before
    assert list(tmp_path.iterdir()) == []


def test_replay_html_panda_carries_its_meshes(tmp_path):
    obstacle = {"kind": "elliptic_cylinder", "center": [0.4, 0.3, 0.3], "a": 0.1, "b": 0.05, "height": 0.4}
    traj = synthetic("panda", duration=2.0, steps=41, obstacle=obstacle)
    out = replay_html(traj, tmp_path / "panda.html", robot=robot("panda"), fps=15)
    cmds = scene_commands(out.read_text())
    meshes = [c for c in cmds if c["type"] == "set_object" and c["path"].startswith("/meshcat/robot/visuals/")]
    assert len(meshes) >= 8  # link0..link7 and the hand, fingers included
    assert sum(payload(c["object"]) for c in meshes) > 100_000  # real meshes, not boxes


@pytest.mark.filterwarnings("ignore:the matrix subclass:PendingDeprecationWarning")  # inside pycollada
def test_panda_meshes_are_compact_and_match_the_collada_files(tmp_path):
    """The Panda's meshes go in as binary triangles: the corners span the same box as the Collada file
    read independently (pycollada, no trimesh), and the page is far smaller than meshcat's base64 text."""
    import collada

    from kinredund.ui.viz.meshes import compact_mesh

    r = robot("panda")
    share = Path(r.package_dirs[0]) / "example-robot-data" / "robots" / "panda_description" / "meshes" / "visual"
    dae = share / "link1.dae"
    parts = compact_mesh(dae)
    corners = np.vstack([p.vertices for p in parts])
    doc = collada.Collada(str(dae))
    raw = np.vstack([prim.vertex for geom in doc.scene.objects("geometry") for prim in geom.primitives()])
    np.testing.assert_allclose(corners.min(axis=0), raw.min(axis=0), atol=1e-5)  # float32 of metres
    np.testing.assert_allclose(corners.max(axis=0), raw.max(axis=0), atol=1e-5)
    assert all(p.faces.dtype == np.uint16 and p.faces.max() < len(p.vertices) for p in parts)
    assert compact_mesh(dae) is parts  # read once per process
    assert compact_mesh(share / "no_such_file.dae") is None

    traj = synthetic("panda", duration=2.0, steps=41)
    page = replay_html(traj, tmp_path / "panda.html", robot=r).read_text()
    meshes = [c for c in scene_commands(page) if c["type"] == "set_object" and "/visuals/" in c["path"]]
    assert all(c["object"]["geometries"][0]["type"] == "BufferGeometry" for c in meshes)
    # meshcat's Collada text of the ten visual files is 10.5 MB (14 MB in base64); the compact form is
    # under a quarter of the text
    text = sum(f.stat().st_size for f in share.glob("*.dae"))
    assert len(page) < 0.45 * text, (len(page), text)


def test_static_tracks_are_dropped_and_moving_ones_kept(tmp_path):
    traj = synthetic("panda", duration=2.0, steps=41)
    anim = next(c for c in scene_commands(replay_html(traj, tmp_path / "p.html", robot=robot("panda")).read_text())
                if c["type"] == "set_animation")
    paths = {a["path"] for a in anim["animations"]}
    assert "/meshcat/robot/visuals/panda_link0_0" not in paths  # the base never moves
    assert {"/meshcat/robot/visuals/panda_link7_0", "/meshcat/path/tracer"} <= paths


def test_floor_grid_spacing_and_extent():
    from kinredund.ui.viz.scene import floor_grid, nice_step

    assert [nice_step(v) for v in (0.03, 0.1, 0.11, 0.3, 0.7, 4.0)] == pytest.approx([0.05, 0.1, 0.2, 0.5, 1, 5])
    pts = np.array([[0.2, -0.3, 0.5], [0.7, 0.4, 0.0], [0.0, 0.0, 0.0]])
    grid = floor_grid(pts)
    lo, hi = grid.center - grid.half, grid.center + grid.half
    assert np.all(lo <= pts[:, :2].min(axis=0)) and np.all(hi >= pts[:, :2].max(axis=0))
    assert grid.half / grid.spacing == pytest.approx(round(grid.half / grid.spacing))  # whole cells
    assert np.allclose(grid.center / grid.spacing, np.round(grid.center / grid.spacing))  # centre on a line


# -- live server -----------------------------------------------------------------------------------
def test_play_live_serves_the_viewer_and_stops():
    traj = synthetic(steps=61)
    before = children()
    url = play_live(traj, robot=robot("planar3r"), realtime=False, loop=True)
    try:
        assert url.startswith("http://127.0.0.1:")
        proc = live_visualizer(url).window.server_proc
        with urllib.request.urlopen(url, timeout=10) as resp:
            assert resp.status == 200
            assert "meshcat" in resp.read().decode().lower()
        anim = next(c for c in scene_commands(live_visualizer(url).static_html()) if c["type"] == "set_animation")
        keys, _ = track(anim, "/meshcat/path/tracer", "position")
        np.testing.assert_array_equal(keys, np.arange(61))  # realtime=False: one stored step per frame
    finally:
        assert stop_live(url) == 1
    assert proc.returncode is not None
    with pytest.raises(ProcessLookupError):
        os.kill(proc.pid, 0)  # killed and reaped
    assert children() == before
    with pytest.raises((urllib.error.URLError, ConnectionError)):
        urllib.request.urlopen(url, timeout=5)
    with pytest.raises(ChoiceError, match="live viewer URL"):
        stop_live(url)


# -- a real browser (tests/_chromium.py) ------------------------------------------------------------
def orange_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the robot's orange (0.9, 0.55, 0.1) under any shading: hue about 28 deg, saturated."""
    r, g, b = (img[..., k].astype(float) for k in range(3))
    return (r > 90) & (r - b > 0.6 * r) & (g > 0.4 * r) & (g < 0.8 * r)


CAMERA_PROBE = """({camera: viewer.camera.matrixWorld.elements,
  scene: viewer.scene_tree.find(["meshcat"]).object.matrixWorld.elements,
  target: viewer.controls.target.toArray()})"""


#: the playback times the browser tests look at [s]: fixed, so no running clock is read
FRAME_TIMES = (0.5, 1.5)


def two_frames(url: str, profile: Path, times: tuple[float, float] = FRAME_TIMES):
    """Open ``url`` in headless Chromium (800x600) once meshcat has its animation (and check it plays);
    scrub the animation to each of ``times`` and take a screenshot there (a running clock, read twice,
    wrapped between the reads under load). Returns (first, second, clock_first, clock_second, camera): RGB
    arrays, the animation's times [s], and the browser's camera in the robot's frame (see
    :func:`camera_in_robot_frame`).
    """
    with open_page(url, profile) as page:
        page.wait_for(MESHCAT_READY, what="its animation")
        assert page.evaluate("viewer.animator.playing"), "the animation does not play on load"
        shots = []
        for t in times:
            scrub(page, t)
            shots.append((page.screenshot(), page.evaluate("viewer.animator.time")))
        camera = camera_in_robot_frame(page.evaluate(CAMERA_PROBE))
    (first, clock_first), (second, clock_second) = shots
    return first, second, clock_first, clock_second, camera


def camera_in_robot_frame(probe: dict) -> dict:
    """The three.js camera of :data:`CAMERA_PROBE` in the frame of the ``/meshcat`` node (the robot's
    world, z up): its position, the orbit target, its up axis (camera y) and view direction (camera -z)."""
    to_robot = np.linalg.inv(np.array(probe["scene"], dtype=float).reshape(4, 4).T)  # three.js: column-major
    cam = to_robot @ np.array(probe["camera"], dtype=float).reshape(4, 4).T
    target = to_robot @ np.append(np.array(probe["target"], dtype=float), 1.0)
    return {"position": cam[:3, 3], "target": target[:3], "up": cam[:3, 1], "view": -cam[:3, 2]}


def assert_robot_plays(first: np.ndarray, second: np.ndarray, clock_first: float, clock_second: float):
    """The robot's orange is on screen, stands out from the background, and moves between the frames."""
    assert first.shape == (600, 800, 3)
    robot_pixels = orange_mask(first)
    assert robot_pixels.sum() > 1000, "the robot's orange links are not on the screenshot"
    background = np.median(first.reshape(-1, 3), axis=0)
    assert np.abs(first[robot_pixels].mean(axis=0) - background).max() > 60
    assert (clock_first, clock_second) == pytest.approx(FRAME_TIMES, abs=1e-9)  # scrubbed there
    moved = orange_mask(second) ^ robot_pixels
    assert moved.sum() > 300, "the robot did not move between the two screenshots"
    changed = np.abs(second.astype(int) - first.astype(int)).max(axis=2) > 40
    assert changed.sum() > 500


@pytest.mark.browser
@needs_chromium
def test_replay_plays_in_headless_chromium(tmp_path):
    from PIL import Image

    traj = synthetic(duration=4.0, steps=121, obstacle=PLANAR_OBSTACLE)
    page = replay_html(traj, tmp_path / "replay.html", robot=robot("planar3r"))
    before = children()
    first, second, c1, c2, camera = two_frames(page.as_uri(),
                                               Path(tempfile.mkdtemp(prefix="chromium-", dir=tmp_path)))
    assert children() == before  # the browser is gone
    Image.fromarray(first).save(tmp_path / "frame_a.png")  # kept for a look (pytest's tmp_path)
    Image.fromarray(second).save(tmp_path / "frame_b.png")
    assert_robot_plays(first, second, c1, c2)
    # the browser's camera, in the robot's z-up frame, sits where camera_view put it (planar task: the
    # direction of its offset does not depend on the points), looks at the orbit target, and has the
    # robot's up (+z) pointing up on the screen with no roll
    _, offset = camera_view(np.zeros((2, 3)), planar=True)
    seen = camera["position"] - camera["target"]
    np.testing.assert_allclose(seen / np.linalg.norm(seen), offset / np.linalg.norm(offset), atol=1e-5)
    np.testing.assert_allclose(camera["view"], -seen / np.linalg.norm(seen), atol=1e-5)
    assert camera["up"][2] > 0.5
    assert abs(np.linalg.det(np.column_stack([camera["up"], [0.0, 0.0, 1.0], camera["view"]]))) < 1e-5


@pytest.mark.browser
@needs_chromium
def test_live_viewer_plays_in_headless_chromium(tmp_path):
    traj = synthetic(duration=4.0, steps=121)
    before = children()
    url = play_live(traj, robot=robot("planar3r"), loop=True)
    try:
        *frames, _ = two_frames(url, Path(tempfile.mkdtemp(prefix="chromium-", dir=tmp_path)))
    finally:
        stop_live(url)
    assert children() == before  # browser and server are gone
    assert_robot_plays(*frames)


def test_replay_titles_name_robot_path_and_method():
    from kinredund.ui.viz.page import replay_title

    traj = synthetic(steps=11)
    assert replay_title(traj, "circle") == "planar3r: circle, augmented scheme (default mode)"
    assert replay_title(dataclasses.replace(traj, meta={"example": "4.3"})).startswith("planar3r: Example 4.3,")
    plan = dataclasses.replace(traj, scheme="planner", meta={"example": "6.3"})
    assert replay_title(plan) == "planar3r: Section 6.3, planned motion around the obstacle"


@pytest.mark.browser
@needs_chromium
def test_replay_without_webgl_says_so_on_the_page(tmp_path):
    """Where the browser gives no WebGL context, meshcat draws nothing: the page says why instead of
    showing the title and the time over a blank page. With WebGL the notice stays hidden."""
    page_file = replay_html(synthetic(duration=2.0, steps=41), tmp_path / "replay.html", robot=robot("planar3r"))
    # innerText holds the rendered text only: a hidden notice is not in it
    probe = """({shown: document.body.innerText.includes("needs WebGL"), text: document.body.innerText,
                time: document.getElementById("kinredund-time").textContent})"""
    for flags, webgl in ((NO_WEBGL, False), ((), True)):
        profile = Path(tempfile.mkdtemp(prefix="chromium-", dir=tmp_path))
        with open_page(page_file.as_uri(), profile, extra_flags=flags) as page:
            page.wait_for("document.readyState === 'complete'", what="the loaded page")
            if webgl:
                page.wait_for(MESHCAT_READY, what="its animation")
            seen = page.evaluate(probe)
        assert seen["shown"] is not webgl, (flags, seen)
        if not webgl:
            assert "no WebGL" in seen["time"]


def _hue_saturation(color: int) -> tuple[float, float]:
    import colorsys

    h, _, s = colorsys.rgb_to_hls(*(((color >> k) & 0xFF) / 255.0 for k in (16, 8, 0)))
    return 360.0 * h, s


def test_path_colours_stay_clear_of_the_world_axes(tmp_path):
    """meshcat draws the world axes x, y, z in red, green and blue; the desired path was the z axis's blue
    and the traced path the y axis's green. Each colour of the paths is either unsaturated or at least
    40 deg of hue from every axis colour, and the legend names the axes."""
    html = replay_html(synthetic(steps=21), tmp_path / "r.html", robot=robot("planar3r")).read_text()
    cmds = scene_commands(html)
    desired = next(c for c in cmds if c["type"] == "set_object" and c["path"] == "/meshcat/path/desired")
    tracer = next(c for c in cmds if c["type"] == "set_object" and c["path"] == "/meshcat/path/tracer")
    traced = next(c for c in cmds if c["type"] == "set_object" and c["path"] == "/meshcat/path/traced")
    dots = traced["object"]["geometries"][0]["data"]["attributes"]["color"]["array"]
    rgb = np.frombuffer(dots.data, dtype=np.float32).reshape(-1, 3)[0]
    colours = {"desired path": desired["object"]["materials"][0]["color"],
               "tracer": tracer["object"]["materials"][0]["color"],
               "traced dots": int(round(rgb[0] * 255)) << 16 | int(round(rgb[1] * 255)) << 8 | int(round(rgb[2] * 255))}
    axes = [0xFF0000, 0x00FF00, 0x0000FF]
    for name, colour in colours.items():
        hue, saturation = _hue_saturation(colour)
        gaps = [min(abs(hue - _hue_saturation(a)[0]), 360.0 - abs(hue - _hue_saturation(a)[0])) for a in axes]
        assert saturation < 0.3 or min(gaps) >= 40.0, f"{name} #{colour:06x}: hue {hue:.0f} deg, gaps {gaps}"
    assert "world axes x, y, z" in html
