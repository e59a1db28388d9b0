"""Playback: resampling, obstacle and camera geometry, standalone HTML replays, the live server and a
real browser (headless Chromium driven through the DevTools protocol).

Test data are synthetic trajectories built from forward kinematics: joints moving sinusoidally,
p = fk(q). The HTML replay is checked two ways: by decoding meshcat's scene commands (the
animation's keyframes against the robot's own joint origins) and by looking at it in Chromium.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import math
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest
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
    # the scene is shifted so that the camera's orbit centre is the centre of the scene
    shift = next(c for c in cmds if c["type"] == "set_transform" and c["path"] == "/meshcat")
    grid = next(c for c in cmds if c["type"] == "set_transform" and c["path"] == "/Grid")
    assert shift["matrix"] == grid["matrix"]


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


# -- a real browser --------------------------------------------------------------------------------
_TRAMPOLINE = """
import fcntl, os, sys
r, w = (fcntl.fcntl(int(fd), fcntl.F_DUPFD, 10) for fd in sys.argv[1:3])
for fd in sys.argv[1:3]:
    os.close(int(fd))
os.dup2(r, 3)
os.dup2(w, 4)
os.close(r)
os.close(w)
os.execv(sys.argv[3], sys.argv[3:])
"""


class Chromium:
    """Headless Chromium driven through the DevTools protocol over a pipe (its fds 3 and 4).

    The pipe needs no port and no websocket client. ``close`` asks the browser to quit (so that it
    reaps its own helper processes), waits for it, and kills its process group by PID if it hangs.
    """

    FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync"]

    def __init__(self, profile: Path):
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()
        # Chromium reads the DevTools pipe on fd 3 and writes on fd 4: a small trampoline moves our
        # ends there and execs the browser (same PID; no preexec_fn in this threaded process)
        args = [sys.executable, "-c", _TRAMPOLINE, str(to_child_r), str(from_child_w), shutil.which("chromium"),
                *self.FLAGS, f"--user-data-dir={profile}", "--remote-debugging-pipe", "about:blank"]
        self.proc = subprocess.Popen(args, pass_fds=(to_child_r, from_child_w), start_new_session=True,
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(to_child_r)
        os.close(from_child_w)
        self._buffer = b""
        self._next_id = 0

    def call(self, method: str, params: dict | None = None, session: str | None = None, timeout: float = 20.0):
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._to_child, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            while b"\0" not in self._buffer:
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([self._from_child], [], [], left)[0]:
                    raise TimeoutError(f"no answer to {method} in {timeout} s")
                chunk = os.read(self._from_child, 1 << 20)
                if not chunk:
                    raise EOFError(f"chromium closed the DevTools pipe during {method}")
                self._buffer += chunk
            raw, self._buffer = self._buffer.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def close(self) -> None:
        try:
            if self.proc.poll() is None:
                self.call("Browser.close", timeout=5)
            self.proc.wait(timeout=10)
        except (OSError, TimeoutError, EOFError, RuntimeError, subprocess.TimeoutExpired):
            if self.proc.poll() is None:
                os.killpg(self.proc.pid, signal.SIGKILL)  # the group of the browser we started
            self.proc.wait()
        finally:
            for fd in (self._to_child, self._from_child):
                try:
                    os.close(fd)
                except OSError:
                    pass


def orange_mask(img: np.ndarray) -> np.ndarray:
    """Pixels of the robot's orange (0.9, 0.55, 0.1) under any shading: hue about 28 deg, saturated."""
    r, g, b = (img[..., k].astype(float) for k in range(3))
    return (r > 90) & (r - b > 0.6 * r) & (g > 0.4 * r) & (g < 0.8 * r)


needs_chromium = pytest.mark.skipif(
    shutil.which("chromium") is None, reason="chromium is not installed (`make browser` installs it)"
)


CAMERA_PROBE = """({camera: viewer.camera.matrixWorld.elements,
  scene: viewer.scene_tree.find(["meshcat"]).object.matrixWorld.elements,
  target: viewer.controls.target.toArray()})"""


def two_frames(url: str, profile: Path, gap: float = 1.0):
    """Open ``url`` in headless Chromium (800x600) once meshcat has its animation; take two
    screenshots ``gap`` seconds apart (real time: --virtual-time-budget does not advance meshcat's
    clock). Returns (first, second, clock_first, clock_second, camera): RGB arrays, animation times
    [s], and the browser's camera in the robot's frame (see :func:`camera_in_robot_frame`).
    """
    from io import BytesIO

    from PIL import Image

    browser = Chromium(profile)
    try:
        target = next(t for t in browser.call("Target.getTargets")["targetInfos"] if t["type"] == "page")
        session = browser.call("Target.attachToTarget", {"targetId": target["targetId"], "flatten": True})[
            "sessionId"]
        browser.call("Emulation.setDeviceMetricsOverride",
                     {"width": 800, "height": 600, "deviceScaleFactor": 1, "mobile": False}, session)
        browser.call("Page.navigate", {"url": url}, session)

        def evaluate(expression: str):
            return browser.call("Runtime.evaluate", {"expression": expression, "returnByValue": True},
                                session)["result"].get("value")

        def screenshot() -> np.ndarray:
            data = browser.call("Page.captureScreenshot", {"format": "png"}, session)["data"]
            return np.asarray(Image.open(BytesIO(base64.b64decode(data))).convert("RGB"))

        deadline = time.monotonic() + 30
        while not evaluate("typeof viewer !== 'undefined' && viewer.animator.duration > 0"):
            assert time.monotonic() < deadline, "the page never loaded its animation"
            time.sleep(0.1)
        time.sleep(0.5)  # let the first frames render
        first, clock_first = screenshot(), evaluate("viewer.animator.time")
        time.sleep(gap)
        second, clock_second = screenshot(), evaluate("viewer.animator.time")
        camera = camera_in_robot_frame(evaluate(CAMERA_PROBE))
    finally:
        browser.close()
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
    assert clock_second - clock_first > 0.5  # the animation clock runs in real time
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
