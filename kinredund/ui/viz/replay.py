"""Standalone HTML replays: one file that plays a trajectory offline in any browser.

The page is meshcat's own static export (``Visualizer.static_html``): the viewer's JavaScript, the
scene and the animation are all inside it, so double-clicking the file plays the motion with no
server and no network. The animation controls (play, pause, reset, time scrubber) are in the
"Animations" folder of the page's control panel.
"""

from __future__ import annotations

from pathlib import Path

from kinredund.io import atomic_write_text
from kinredund.model.robot import Robot
from kinredund.trajectory import Trajectory
from kinredund.ui.viz._meshcat import animated_visualizer, stop_visualizer
from kinredund.ui.viz.scene import MAX_FRAMES


def replay_html(
    traj: Trajectory,
    path: str | Path,
    robot: Robot | None = None,
    fps: float = 30,
    show_path: bool = True,
    *,
    loop: bool = True,
    max_frames: int = MAX_FRAMES,
) -> Path:
    """Write a standalone HTML file that replays ``traj`` in meshcat, at the trajectory's own speed.

    The page shows the robot's URDF visuals, the desired end-effector path (a blue line), a green
    marker on the reached end point, the obstacle of ``traj.meta["obstacle"]`` if there is one
    (purple, translucent), and a camera that frames them all. The motion is resampled to at most
    ``max_frames`` keyframes spread over the trajectory's duration, so a long run stays a small file.

    Args:
        traj: the trajectory to replay.
        path: the output file (its folder is created); written atomically.
        robot: the robot; default ``kinredund.load_robot(traj.robot)``.
        fps: keyframes per second of trajectory time [1/s].
        show_path: draw the desired path.
        loop: play in a loop (else once, stopping on the last frame).
        max_frames: the cap on the number of keyframes.

    Returns:
        The path written.

    Raises:
        KinredundError: an unknown robot, a trajectory that does not fit it, a malformed obstacle,
            or a meshcat server that does not start.
    """
    vis = animated_visualizer(traj, robot, loop=loop, fps=fps, show_path=show_path, max_frames=max_frames)
    try:
        html = vis.static_html()
    finally:
        stop_visualizer(vis)
    out = Path(path)
    atomic_write_text(out, html)
    return out
