"""Standalone HTML replays: one file that plays a trajectory offline in any browser.

The page is meshcat's own static export (``Visualizer.static_html``): the viewer's JavaScript, the
scene and the animation are all inside it, so double-clicking the file plays the motion with no
server and no network. The animation controls (play, pause, reset, time scrubber) are in the
"Animations" folder of the page's control panel; a panel in the top-left corner gives the title, the
trajectory's time and the legend (:mod:`kinredund.ui.viz.page`).

Size: a mesh file is sent once, as float32 corners and 16-bit triangle indices grouped by colour
(:mod:`kinredund.ui.viz.meshes`) instead of meshcat's base64 Collada text, and animation tracks that
never change are dropped. A one-loop Panda replay (``kinredund track panda --html``) went from 15.3 MB
(14.1 MB of it the meshes as base64 Collada text, 0.33 MB the animation) to 3.4 MB: meshes 2.2 MB,
animation 0.26 MB, meshcat's viewer script 0.85 MB.
"""

from __future__ import annotations

from pathlib import Path

from kinredund.io import atomic_write_text
from kinredund.model.robot import Robot
from kinredund.trajectory import Trajectory
from kinredund.ui.viz._meshcat import OBSTACLE_COLOR, PATH_COLOR, TRACER_COLOR, animated_visualizer, stop_visualizer
from kinredund.ui.viz.page import decorate_page, replay_title
from kinredund.ui.viz.scene import MAX_FRAMES, read_obstacle


def replay_html(
    traj: Trajectory,
    path: str | Path,
    robot: Robot | None = None,
    fps: float = 30,
    show_path: bool = True,
    *,
    loop: bool = True,
    max_frames: int = MAX_FRAMES,
    title: str | None = None,
    scene=None,
) -> Path:
    """Write a standalone HTML file that replays ``traj`` in meshcat, at the trajectory's own speed.

    The page shows the robot's URDF visuals on a floor grid (z = 0), the desired end-effector path (a
    blue line), the traced path (green dots) with a green marker on the reached end point, the
    obstacle of ``traj.meta["obstacle"]`` if there is one (purple, translucent), and a camera that
    frames them all; a corner panel gives the title, the time and the legend. The motion is resampled to at most
    ``max_frames`` keyframes spread over the trajectory's duration, so a long run stays a small file.

    Args:
        traj: the trajectory to replay.
        path: the output file (its folder is created); written atomically.
        robot: the robot; default ``kinredund.load_robot(traj.robot)``.
        fps: keyframes per second of trajectory time [1/s].
        show_path: draw the desired path.
        loop: play in a loop (else once, stopping on the last frame).
        max_frames: the cap on the number of keyframes.
        title: the title on the page; default robot, path and scheme (:func:`~kinredund.ui.viz.page.replay_title`).
        scene: a :class:`kinredund.Scene` around the robot: its objects are drawn (orange, translucent; attached
            ones move with their frame) and the closest pair's witness points marked (red dots) at every frame.

    Returns:
        The path written.

    Raises:
        KinredundError: an unknown robot, a trajectory that does not fit it, a malformed obstacle,
            or a meshcat server that does not start.
    """
    vis = animated_visualizer(traj, robot, loop=loop, fps=fps, show_path=show_path, max_frames=max_frames, cell=scene)
    try:
        html = vis.static_html()
    finally:
        stop_visualizer(vis)
    legend = [("desired path", PATH_COLOR, "line"), ("traced path (end point)", TRACER_COLOR, "dot")]
    if not show_path:
        legend = legend[1:]
    if read_obstacle(traj) is not None:
        legend.append(("obstacle", OBSTACLE_COLOR, "box"))
    if scene is not None:
        from kinredund.ui.viz.cell import CELL_COLOR, CLOSEST_COLOR

        legend += [("scene objects", CELL_COLOR, "box"), ("closest pair", CLOSEST_COLOR, "dot")]
    t = traj.t
    html = decorate_page(html, title if title is not None else replay_title(traj), legend,
                         float(t[0]), float(t[-1] - t[0]))
    out = Path(path)
    atomic_write_text(out, html)
    return out
