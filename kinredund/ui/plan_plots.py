"""Figures of the Chapter 6 plans: joint histories with the spline, clearance, and the arm around the obstacle.

- :func:`plan_figure`: for a tracked plan, the joint histories [deg] with the spline estimates
  theta*(t) dashed (Section 6.2.2.2; the thesis's Figs. 6.6-6.8 and 6.12-6.13) and the clearance of
  each link [m]; joints that never move are named in a note instead of being drawn on top of each
  other. For a plan that stopped before tracking (Section 6.2), the obstacle, the path and the reach
  that the normal-tool policy needs against the reach of the arm.
- :func:`snapshot_figure`: the arm drawn at a few times over one loop, in the style of Figs.
  6.14-6.22: a top view (x-y) and, for a spatial arm, a side view (x-z), each named, with the
  obstacle and the end point's path; the colour of an arm gives its time.

Written with matplotlib's object API on an Agg canvas, atomically (:func:`kinredund.ui.plots.save_figure`).
"""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError
from kinredund.planning.obstacles import EllipticCylinder, Obstacle, obstacle_from_dict
from kinredund.tasks import get_task
from kinredund.ui.plots import save_figure

#: A joint whose range over the motion is below this is drawn as "still" [rad].
STILL = 1e-6
_OBSTACLE = {"color": "tab:purple", "alpha": 0.3}


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _joint_label(j: int) -> str:
    return f"$\\theta_{{{j + 1}}}$"


def plan_figure(case: str, result, extra: dict, robot_name: str = ""):
    """The figure of :func:`plot_plan` (a ``matplotlib.figure.Figure``)."""
    tr = result.trajectory
    if tr is None:
        return _failed_figure(case, result, extra)
    fig = _figure(8.0, 6.4)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    q = np.degrees(tr.q)
    moving = [j for j in range(q.shape[1]) if np.ptp(tr.q[:, j]) > STILL]
    still = [j for j in range(q.shape[1]) if j not in moving]
    for j in moving:
        (line,) = ax1.plot(tr.t, q[:, j], lw=1.5, label=_joint_label(j))
        if result.q_spline is not None:
            ax1.plot(tr.t, np.degrees(result.q_spline[:, j]), "--", color=line.get_color(), lw=1.0, dashes=(4, 3))
    from matplotlib.lines import Line2D

    handles, labels = ax1.get_legend_handles_labels()
    if result.q_spline is not None:
        gap = float(np.degrees(np.abs(tr.q - result.q_spline).max()))
        handles += [Line2D([], [], color="0.2", lw=1.5), Line2D([], [], color="0.2", lw=1.0, ls="--", dashes=(4, 3))]
        labels += ["tracked", f"spline $\\theta^*(t)$\n(within {gap:.2g} deg:\nunder the solid lines)"]
    if still:
        values = ", ".join(f"{np.degrees(tr.q[0, j]):.3g}" for j in still)
        names = ", ".join(_joint_label(j) for j in still)
        handles.append(Line2D([], [], color="none"))
        labels.append(f"not drawn: {names}\nstill at {values} deg")
    ax1.legend(handles, labels, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", frameon=False)
    ax1.set_ylabel("joint angle [deg]")
    ax1.grid(True, alpha=0.3)
    if result.clearance is not None:
        for k, name in enumerate(result.clearance.names):
            # line styles as well as colours: links at the same clearance (6.3's links 1 and 2) stay visible
            ax2.plot(result.clearance.t, result.clearance.clearance[:, k], label=str(name),
                     linestyle=("-", "--", "-.", ":")[k % 4])
    ax2.axhline(0.0, color="k", lw=0.8, label="contact (0 m)")
    ax2.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small", frameon=False)
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("clearance to the obstacle [m]")
    ax2.set_xlim(tr.t[0], tr.t[-1])
    ax2.grid(True, alpha=0.3)
    verdict = "collision-free" if result.ok else "failed its check"
    who = f"{robot_name}, " if robot_name else ""
    fig.suptitle(f"Section {case}: {who}planned motion ({verdict}); joints and clearance per link")
    return fig


def _failed_figure(case: str, result, extra: dict):
    """The obstacle, the path on its boundary and the reach the policy needs, when no motion was tracked."""
    fig = _figure(7.5, 6.0)
    ax = fig.subplots()
    s = np.linspace(0, 2 * np.pi, 200)
    ring, _ = obstacle_from_dict(extra["obstacle"]).boundary(s)
    ax.fill(ring[:, 0], ring[:, 1], **_OBSTACLE, label="obstacle (its boundary is the end point's path)")
    feas = extra.get("feasibility")
    if feas is not None:
        r = feas["wrist_reach_available"]
        ax.plot(r * np.cos(s), r * np.sin(s), "k--", lw=1.0, label=f"reach of joint 3: $l_1 + l_2$ = {r:.2f} m")
        need = feas["wrist_reach_needed"]
        ax.plot(need * np.cos(s), need * np.sin(s), "r:", lw=1.2,
                label=f"reach the policy needs on the far side: {need:.2f} m")
    ax.plot([0], [0], "ko", label="base (joint 1)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), fontsize="small", frameon=False)
    reason = textwrap.fill(f"no plan: {result.reason}", 110)
    fig.suptitle(f"Section {case}: why the normal-tool policy cannot go round this obstacle", fontsize="medium")
    ax.set_title(reason, fontsize="x-small", loc="left")
    return fig


def plot_plan(case: str, result, extra: dict, path: str | Path, robot_name: str = "") -> Path:
    """Write :func:`plan_figure` to ``path`` (``.png``, ``.pdf`` or ``.svg``) atomically; return the path."""
    return save_figure(plan_figure(case, result, extra, robot_name), path)


# -- the arm at a few times (Figs. 6.14-6.22) ----------------------------------------------------------
def _side_outline(ax, obstacle: Obstacle) -> None:
    if isinstance(obstacle, EllipticCylinder):
        x = obstacle.center[0] + obstacle.a * np.array([-1.0, 1.0])
        top = obstacle.top_height(np.array([[x[0], obstacle.center[1]], [x[1], obstacle.center[1]]]))
        z0 = obstacle.z_range[0]
        ax.fill([x[0], x[1], x[1], x[0]], [z0, z0, top[1], top[0]], **_OBSTACLE, label="obstacle (section y = centre)")


def snapshot_figure(result, robot, obstacle: Obstacle, path_out: str | Path | None = None, times=None,
                    count: int = 6, title: str | None = None):
    """The arm of ``result.trajectory`` at ``times`` (default ``count`` equally spaced over the loop).

    A top view (x-y) and, for a spatial arm, a side view (x-z), side by side and named; each arm is a
    chain of its joint origins, coloured by time (colour bar); the obstacle and the desired end-point
    path are drawn in both. Saved to ``path_out`` when given (then the path is returned), else the
    figure is returned.

    Raises:
        KinredundError: the plan has no tracked motion.
    """
    from matplotlib import colormaps
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    tr = result.trajectory
    if tr is None:
        raise KinredundError("no tracked motion to draw: the plan stopped before tracking")
    ts = np.linspace(tr.t[0], tr.t[-1], count, endpoint=False) if times is None else np.asarray(times, float)
    idx = [int(np.argmin(np.abs(tr.t - t))) for t in ts]
    spatial = not get_task(robot.task).planar
    views = [("top view (x-y plane)", 0, 1, "x [m]", "y [m]")]
    if spatial:
        views.append(("side view (x-z plane)", 0, 2, "x [m]", "z [m]"))
    fig = _figure(6.0 * len(views) + 1.0, 5.4)
    axes = fig.subplots(1, len(views), squeeze=False)[0]
    norm = Normalize(tr.t[0], tr.t[-1])
    cmap = colormaps["viridis"]
    ring, _ = obstacle.boundary(np.linspace(0.0, 2 * np.pi, 200))
    for ax, (name, i, j, xl, yl) in zip(axes, views, strict=True):
        if j == 1:
            ax.fill(ring[:, 0], ring[:, 1], **_OBSTACLE, label="obstacle")
        else:
            _side_outline(ax, obstacle)
        ax.plot(tr.p_desired[:, i], tr.p_desired[:, j], color="tab:blue", lw=1.0, label="end point's path")
        for n, k in enumerate(idx):
            pts = robot.kinematics.joint_origins(tr.q[k])
            ax.plot(pts[:, i], pts[:, j], "-o", color=cmap(norm(tr.t[k])), ms=3, lw=1.6,
                    label="arm (joint origins)" if n == 0 else None)
        ax.plot([0], [0], "k^", ms=7, label="base")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(name)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncols=2, fontsize="small", frameon=False)
    fig.colorbar(ScalarMappable(norm=norm, cmap=cmap), ax=list(axes), label="time of the arm [s]", shrink=0.8)
    fig.suptitle(title if title is not None else
                 f"The arm at {len(idx)} times over the loop ({tr.t[-1] - tr.t[0]:.3g} s)")
    return fig if path_out is None else save_figure(fig, path_out)
