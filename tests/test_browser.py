"""The replay a user gets from ``kinredund track panda --html``, looked at in headless Chromium.

The floor must lie under the robot (the replays once showed meshcat's 20 m grid as an edge-on strip
near the horizon, above the arm), and the page must carry its title and a running time readout.
Checked two ways: from the scene the browser holds (the floor's plane, the robot's base and the
camera, read through the DevTools protocol) and from screenshots (the floor's pixels against the
robot's). Skips with the reason when no ``chromium`` is on PATH (``make browser`` installs it).
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from _chromium import MESHCAT_READY, needs_chromium, open_page, scrub

#: three.js: the floor's and the robot base's world matrices, the camera's, and the floor's end points
#: projected to normalised device coordinates (x, y in [-1, 1] on screen, z < 1 in front of the camera).
SCENE_PROBE = """(() => {
  const T = MeshCat.THREE;
  const floor = viewer.scene_tree.find(["meshcat", "floor", "<object>"]).object;
  const base = viewer.scene_tree.find(["meshcat", "robot", "visuals", "panda_link0_0"]).object;
  const cam = viewer.camera;
  cam.updateMatrixWorld();
  const pos = floor.geometry.attributes.position;
  const ndc = [], view = [];
  for (let i = 0; i < pos.count; i++) {
    const v = new T.Vector3().fromBufferAttribute(pos, i);
    floor.localToWorld(v);
    view.push(v.clone().applyMatrix4(cam.matrixWorldInverse).z);
    ndc.push(v.clone().project(cam).toArray());
  }
  return {floor: floor.matrixWorld.elements, base: base.matrixWorld.elements,
          camera: cam.matrixWorld.elements, ndc: ndc, view_z: view};
})()"""


#: animation times the test scrubs to [s of playback]
SCRUB_TIMES = (1.0, 3.5)


def show_only(page, visible: list[str]) -> np.ndarray:
    """A screenshot with only the named nodes of /meshcat shown (``floor``, ``robot``), axes hidden."""
    nodes = ["floor", "robot", "path"]
    js = "; ".join(f'viewer.scene_tree.find(["meshcat", "{n}"]).object.visible = {str(n in visible).lower()}'
                   for n in nodes)
    page.evaluate(js + '; viewer.scene_tree.find(["Axes"]).object.visible = false; viewer.animator.pause(); '
                  "viewer.set_dirty(); true")
    page.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => r(true))))")  # drawn
    return page.screenshot()


def differs(img: np.ndarray, background: np.ndarray) -> np.ndarray:
    return np.abs(img.astype(int) - background.astype(int)).max(axis=2) > 12


@pytest.fixture(scope="module")
def panda_page(tmp_path_factory):
    out = tmp_path_factory.mktemp("browser") / "panda.html"
    exe = Path(sys.executable).with_name("kinredund")
    run = subprocess.run([str(exe), "track", "panda", "--html", str(out)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    assert f"wrote {out}" in run.stdout
    return out


@pytest.mark.browser
@needs_chromium
def test_panda_replay_floor_under_the_robot_title_and_time(panda_page, tmp_path):
    from PIL import Image

    profile = Path(tempfile.mkdtemp(prefix="chromium-", dir=tmp_path))
    with open_page(panda_page.as_uri(), profile, 900, 650) as page:
        page.wait_for(MESHCAT_READY, what="its animation")
        page.wait_for('viewer.scene_tree.find(["meshcat", "robot", "visuals", "panda_link0_0"]).object.children'
                      ".length > 0", what="the robot's meshes")
        playing = page.evaluate("viewer.animator.playing")
        title = page.evaluate('document.getElementById("kinredund-title").textContent')
        readouts = []
        for t in SCRUB_TIMES:  # fixed times, not a running clock (which wrapped between two reads under load)
            scrub(page, t)
            page.wait_for(f'document.getElementById("kinredund-time").textContent.startsWith("t = {t:.2f} s")',
                          what=f"the readout at {t} s")
            readouts.append(page.evaluate('document.getElementById("kinredund-time").textContent'))
        legend = page.evaluate('document.getElementById("kinredund-legend").textContent')
        whole = page.screenshot()
        scene = page.evaluate(SCENE_PROBE)
        background = show_only(page, [])
        floor_img = show_only(page, ["floor"])
        robot_img = show_only(page, ["robot"])
    Image.fromarray(whole).save(tmp_path / "panda.png")  # kept for a look (pytest's tmp_path)

    # the title names the robot, the path and the scheme; the readout runs with the animation
    assert title == "panda: circle, augmented scheme (default mode)"
    pattern = r"t = (\d+\.\d\d) s of (\d+\.\d\d) s"
    shown = [tuple(map(float, re.fullmatch(pattern, text).groups())) for text in readouts]
    assert playing  # the replay plays when opened
    for (t, total), want in zip(shown, SCRUB_TIMES, strict=True):
        assert t == pytest.approx(want, abs=0.005)  # the readout follows the animation (2 decimals)
        assert total == pytest.approx(2 * np.pi, abs=0.01)  # one loop of radius 0.1 m at 0.1 m/s
    assert "desired path" in legend and "traced path" in legend and "world axes" in legend

    # the scene: in three.js (y up) the floor is horizontal, level with the robot's base (z = 0 of the
    # robot), the camera above it, and every end point of its lines in front of the camera (the 20 m
    # grid lost the lines that passed behind the camera)
    floor = np.array(scene["floor"]).reshape(4, 4).T
    base = np.array(scene["base"]).reshape(4, 4).T
    camera = np.array(scene["camera"]).reshape(4, 4).T
    np.testing.assert_allclose(floor[:3, :3] @ [0, 0, 1], [0, 1, 0], atol=1e-9)  # robot z -> three.js y
    assert floor[1, 3] == pytest.approx(base[1, 3], abs=1e-9)
    assert camera[1, 3] > floor[1, 3] + 0.2
    assert max(scene["view_z"]) < 0  # three.js cameras look down their -z
    ndc = np.array(scene["ndc"])
    assert np.all(np.abs(ndc[:, 2]) < 1)

    # the screenshots: the floor's pixels fill the lower part of the view and reach below the robot's
    floor_px = np.argwhere(differs(floor_img, background))
    robot_px = np.argwhere(differs(robot_img, background))
    assert len(floor_px) > 2000 and len(robot_px) > 5000
    rows = whole.shape[0]
    assert floor_px[:, 0].max() > robot_px[:, 0].max()  # the floor reaches lower on screen than the arm
    assert np.median(floor_px[:, 0]) > np.median(robot_px[:, 0])
    assert np.median(floor_px[:, 0]) > 0.5 * rows  # in the lower half, not a strip near the horizon
    assert floor_px[:, 0].max() - floor_px[:, 0].min() > 0.3 * rows  # seen from above, not edge-on


@pytest.mark.browser
@needs_chromium
def test_live_replay_of_a_scene_shows_its_objects(tmp_path):
    """``kinredund play RUN --live --scene CELL``, the command a user types, serves a page whose scene holds the
    cell's objects on screen (the live replay ignored --scene: only --html drew it)."""
    import json
    import os
    import signal

    from test_geometry_viz import assert_cell_shows

    exe = Path(sys.executable).with_name("kinredund")
    run, cell = tmp_path / "run.json", tmp_path / "cell.json"
    made = subprocess.run([str(exe), "track", "planar3r", "--steps", "40", "--quiet", "--json", str(run)],
                          capture_output=True, text=True, timeout=300)
    assert made.returncode == 0, made.stderr
    cell.write_text(json.dumps({"format": "kinredund-scene", "version": 1, "objects": [
        {"name": "wall", "shape": "box", "size": [0.2, 4.0, 1.0], "pose": {"xyz": [3.5, 0.0, 0.0]}}]}))
    proc = subprocess.Popen([str(exe), "play", str(run), "--live", "--scene", str(cell)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        import select

        assert select.select([proc.stdout], [], [], 120)[0], "no output in 120 s"  # a hang guard, not a speed bar
        line = proc.stdout.readline()  # "open URL (Ctrl-C to stop)", or "" if the command failed
        assert line.startswith("open http"), proc.stderr.read() if proc.poll() is not None else line
        assert_cell_shows(line.split()[1], tmp_path)
    finally:
        os.kill(proc.pid, signal.SIGINT)  # how a live replay ends; it stops its server
        try:
            proc.wait(timeout=60)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)  # the group this test started, by its PID
                proc.wait()
    assert proc.returncode == 0

