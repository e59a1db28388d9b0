"""A scene in a replay (``replay_html(scene=...)``, ``play_live(scene=...)``, ``kinredund play --scene``): its
objects are drawn, an attached one follows its frame, and the closest pair's witness points are marked at every
keyframe."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from _chromium import MESHCAT_READY, needs_chromium, open_page
from test_viz import scene_commands, synthetic, track

import kinredund as kr
from kinredund.ui.viz import play_live, replay_html, stop_live
from kinredund.ui.viz.live import live_visualizer


def test_replay_draws_the_scene_and_marks_the_closest_pair(tmp_path):
    traj = synthetic(duration=2.0, steps=61)
    r = kr.load_robot("planar3r")
    scene = kr.Scene(r)
    scene.add_box("wall", [0.2, 4.0, 1.0], {"xyz": [3.5, 0.0, 0.0], "rpy": [0.0, 0.0, 0.3]})
    scene.add_capsule("held", 0.1, 0.5, {"xyz": [0.3, 0.0, 0.0], "rpy": [0.0, 1.5707963, 0.0]}, attach_to=r.ee_frame)
    html = replay_html(traj, tmp_path / "cell.html", robot=r, fps=15, scene=scene).read_text()
    cmds = scene_commands(html)
    objects = {c["path"] for c in cmds if c["type"] == "set_object"}
    assert {"/meshcat/cell/wall/0", "/meshcat/cell/held/0", "/meshcat/cell/held/1", "/meshcat/cell/held/2",
            "/meshcat/cell/closest/a", "/meshcat/cell/closest/b"} <= objects
    (anim,) = [c for c in cmds if c["type"] == "set_animation"]
    fps = anim["animations"][0]["clip"]["fps"]
    keys, held = track(anim, "/meshcat/cell/held", "position")
    _, near_a = track(anim, "/meshcat/cell/closest/a", "position")
    _, near_b = track(anim, "/meshcat/cell/closest/b", "position")
    for k in range(0, len(keys), 7):
        q = np.array([np.interp(keys[k] / fps, traj.t, traj.q[:, j]) for j in range(r.nq)])
        np.testing.assert_allclose(held[k], scene.object_pose("held", q)[:3, 3], atol=1e-6)  # float32 in meshcat
        rec = scene.distances(q)
        i = rec.index(*rec.closest)
        np.testing.assert_allclose(near_a[k], rec.point_a[i], atol=1e-6)
        np.testing.assert_allclose(near_b[k], rec.point_b[i], atol=1e-6)
    assert "scene objects" in html and "closest pair" in html


def test_live_replay_draws_the_scene_as_the_html_one(tmp_path):
    """``play_live(scene=)`` sends the viewer the cell ``replay_html(scene=)`` writes (the live replay drew no
    scene): the same objects, and the attached one's track at the same keyframes."""
    traj = synthetic(duration=2.0, steps=61)
    r = kr.load_robot("planar3r")
    scene = kr.Scene(r)
    scene.add_box("wall", [0.2, 4.0, 1.0], {"xyz": [3.5, 0.0, 0.0]})
    scene.add_sphere("held", 0.2, [0.3, 0.0, 0.0], attach_to=r.ee_frame)
    url = play_live(traj, robot=r, scene=scene)
    try:
        live = scene_commands(live_visualizer(url).static_html())
    finally:
        stop_live(url)
    page = scene_commands(replay_html(traj, tmp_path / "cell.html", robot=r, scene=scene).read_text())
    cell = [{c["path"] for c in cmds if c["type"] == "set_object" and c["path"].startswith("/meshcat/cell/")}
            for cmds in (live, page)]
    assert cell[0] == cell[1] >= {"/meshcat/cell/wall/0", "/meshcat/cell/held/0", "/meshcat/cell/closest/a"}
    anims = [next(c for c in cmds if c["type"] == "set_animation") for cmds in (live, page)]
    keys, held = zip(*(track(a, "/meshcat/cell/held", "position") for a in anims), strict=True)
    np.testing.assert_array_equal(keys[0], keys[1])  # the same keyframes (copied, not computed)
    np.testing.assert_array_equal(held[0], held[1])


def assert_cell_shows(url: str, tmp_path: Path) -> None:
    """Headless Chromium on the replay at ``url`` (a file or a live server) of a scene holding a ``wall``: the
    wall's node holds its mesh, and with only the scene's nodes shown the screenshot differs from the empty view
    by thousands of pixels."""
    visible = ('["floor", "robot", "path", "cell"].forEach(n => viewer.scene_tree.find(["meshcat", n]).object'
               '.visible = {cell}); viewer.scene_tree.find(["Axes"]).object.visible = false; '
               'viewer.animator.pause(); viewer.set_dirty(); true')
    profile = Path(tempfile.mkdtemp(prefix="chromium-", dir=tmp_path))
    with open_page(url, profile, 800, 600) as page:
        page.wait_for(MESHCAT_READY, what="its animation")
        count = page.evaluate('viewer.scene_tree.find(["meshcat", "cell", "wall", "0"]).object.children.length')
        page.evaluate(visible.replace("{cell}", 'n === "none"'))
        time.sleep(0.4)
        empty = page.screenshot()
        page.evaluate(visible.replace("{cell}", 'n === "cell"'))
        time.sleep(0.4)
        cell = page.screenshot()
    assert count > 0
    assert int((np.abs(cell.astype(int) - empty.astype(int)).max(axis=2) > 12).sum()) > 2000


@pytest.mark.browser
@needs_chromium
def test_scene_objects_show_in_a_real_browser(tmp_path):
    """The standalone replay: the wall, the held sphere and the two red dots are on screen."""
    traj = synthetic(duration=2.0, steps=61)
    r = kr.load_robot("planar3r")
    scene = kr.Scene(r)
    scene.add_box("wall", [0.2, 4.0, 1.0], {"xyz": [3.5, 0.0, 0.0]})
    scene.add_sphere("held", 0.2, [0.3, 0.0, 0.0], attach_to=r.ee_frame)
    assert_cell_shows(replay_html(traj, tmp_path / "cell.html", robot=r, scene=scene).as_uri(), tmp_path)
