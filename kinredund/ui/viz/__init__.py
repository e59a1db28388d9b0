"""Playback of trajectories in meshcat: standalone HTML replays and a live local viewer.

This subpackage is the only part of kinredund that imports meshcat, and it does so lazily, inside
the functions, so ``import kinredund.ui.viz`` costs nothing and works without meshcat installed.

- :func:`replay_html`: a single HTML file that plays a trajectory offline (double-click it).
- :func:`play_live`, :func:`stop_live`: a local meshcat server on 127.0.0.1 playing a trajectory.

An obstacle in ``traj.meta["obstacle"]`` is read with
:func:`kinredund.planning.obstacles.obstacle_from_dict` (the form ``Obstacle.to_dict`` writes).
"""

from kinredund.ui.viz.live import live_visualizer, play_live, stop_live
from kinredund.ui.viz.replay import replay_html
from kinredund.ui.viz.scene import resample

__all__ = [
    "live_visualizer",
    "play_live",
    "replay_html",
    "resample",
    "stop_live",
]
