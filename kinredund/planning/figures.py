"""Configuration snapshots of a planned motion with the obstacle (the style of Figs. 6.14-6.22).

Each panel draws the arm's links (segments between joint origins) at one time with the obstacle and
the end-point path: the xy-plane for planar arms, and for spatial arms a top view (xy) and a side view
(xz) with the cylinder's outline. Written with matplotlib's object API on an Agg canvas, atomically
(:func:`kinredund.ui.plots.save_figure`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError
from kinredund.planning.obstacles import EllipticCylinder, Obstacle


def snapshot_figure(result, robot, obstacle: Obstacle, path_out: str | Path, times=None, count: int = 9):
    """Draw the arm of ``result.trajectory`` at ``times`` (default ``count`` equally spaced) and save it.

    Raises:
        KinredundError: the plan has no tracked motion.
    """
    from matplotlib.figure import Figure

    from kinredund.ui.plots import save_figure

    tr = result.trajectory
    if tr is None:
        raise KinredundError("no tracked motion to draw: the plan stopped before tracking")
    ts = np.linspace(tr.t[0], tr.t[-1], count, endpoint=False) if times is None else np.asarray(times, float)
    idx = [int(np.argmin(np.abs(tr.t - t))) for t in ts]
    spatial = robot.task != "planar"
    cols = min(3, len(idx))
    rows = int(np.ceil(len(idx) / cols)) * (2 if spatial else 1)
    fig = Figure(figsize=(3.2 * cols, 2.8 * rows), layout="constrained")
    s = np.linspace(0.0, 2 * np.pi, 200)
    ring, _ = obstacle.boundary(s)
    for n, k in enumerate(idx):
        pts = robot.kinematics.joint_origins(tr.q[k])
        views = [(0, 1, "x [m]", "y [m]")] + ([(0, 2, "x [m]", "z [m]")] if spatial else [])
        for v, (i, j, xl, yl) in enumerate(views):
            r, c = divmod(n, cols)
            ax = fig.add_subplot(rows, cols, (r * len(views) + v) * cols + c + 1)
            if j == 1:
                ax.fill(ring[:, 0], ring[:, 1], color="tab:purple", alpha=0.3)
            elif isinstance(obstacle, EllipticCylinder):
                x = obstacle.center[0] + obstacle.a * np.array([-1.0, 1.0])
                top = obstacle.top_height(np.array([[x[0], obstacle.center[1]], [x[1], obstacle.center[1]]]))
                z0 = obstacle.z_range[0]
                ax.fill([x[0], x[1], x[1], x[0]], [z0, z0, top[1], top[0]], color="tab:purple", alpha=0.3)
            ax.plot(tr.p_desired[:, i], tr.p_desired[:, j], color="tab:blue", lw=0.6)
            ax.plot(pts[:, i], pts[:, j], "-o", color="k", ms=2.5, lw=1.4)
            ax.set_aspect("equal")
            ax.set_title(f"t = {tr.t[k]:.2f} s", fontsize=8)
            ax.set_xlabel(xl, fontsize=7)
            ax.set_ylabel(yl, fontsize=7)
            ax.tick_params(labelsize=6)
    return save_figure(fig, path_out)
