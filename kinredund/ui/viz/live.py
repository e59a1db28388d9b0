"""Live playback on a local meshcat server (http and zmq on 127.0.0.1).

:func:`play_live` starts a server, loads the scene and the animation, and returns the page's URL;
the page's "Animations" folder has play, pause, reset and a time scrubber. :func:`stop_live` ends
the server process (by its PID). Servers still running when Python exits are ended by meshcat's
own ``atexit`` hook.
"""

from __future__ import annotations

import webbrowser

from kinredund.model.robot import Robot
from kinredund.trajectory import Trajectory
from kinredund.ui.viz._meshcat import animated_visualizer, stop_visualizer
from kinredund.ui.viz.scene import MAX_FRAMES

#: Running servers started by :func:`play_live`, by URL.
_LIVE: dict[str, object] = {}


def play_live(
    traj: Trajectory,
    robot: Robot | None = None,
    realtime: bool = True,
    loop: bool = False,
    open_browser: bool = False,
    *,
    fps: float = 30,
    show_path: bool = True,
    max_frames: int = MAX_FRAMES,
    scene=None,
) -> str:
    """Replay ``traj`` on a new local meshcat server and return the viewer's URL.

    The animation starts when a browser opens the URL; the page's "Animations" controls pause,
    resume, reset and scrub it. Stop the server with :func:`stop_live` (``vis.window.server_proc``
    is killed by PID and reaped).

    Args:
        traj: the trajectory.
        robot: the robot; default ``kinredund.load_robot(traj.robot)``.
        realtime: play at the trajectory's own speed; if False, one stored step per frame at ``fps``.
        loop: repeat forever (else once).
        open_browser: also open the URL in the system's web browser.
        fps, show_path, max_frames, scene: as in :func:`kinredund.ui.viz.replay_html` (``scene``, a
            :class:`kinredund.Scene`: its objects drawn, the closest pair marked at every frame).

    Returns:
        The viewer's URL, e.g. ``http://127.0.0.1:7000/static/``.

    Raises:
        KinredundError: as :func:`kinredund.ui.viz.replay_html`.
    """
    vis = animated_visualizer(traj, robot, loop=loop, fps=fps, show_path=show_path, max_frames=max_frames,
                              realtime=realtime, cell=scene)
    url = vis.url()
    _LIVE[url] = vis
    if open_browser:
        webbrowser.open(url, new=2)
    return url


def live_visualizer(url: str):
    """The ``meshcat.Visualizer`` of a server started by :func:`play_live` (to add to the scene)."""
    from kinredund.errors import ChoiceError

    if url not in _LIVE:
        raise ChoiceError("live viewer URL", url, list(_LIVE) or ["(none running)"])
    return _LIVE[url]


def stop_live(url: str | None = None) -> int:
    """Stop the server of ``url`` (or every server :func:`play_live` started); return how many stopped.

    Raises:
        ChoiceError: ``url`` is not a running server of :func:`play_live` (lists those running).
    """
    if url is not None:
        vis = live_visualizer(url)
        del _LIVE[url]
        stop_visualizer(vis)
        return 1
    count = 0
    while _LIVE:
        _, vis = _LIVE.popitem()
        stop_visualizer(vis)
        count += 1
    return count
