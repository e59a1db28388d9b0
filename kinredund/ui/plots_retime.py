"""Figures of retimed records: joint positions, velocities and accelerations with their limits drawn.

:func:`plot_retimed` draws q [rad], qdot [rad/s] and qddot [rad/s^2] against time, one colour per joint,
with each joint's limits +-v_i and +-a_i as dashed lines of its colour (a limit more than
:data:`LIMIT_REACH` times above the motion it bounds is left out, so the curves are not squashed flat).
The limits are those the record was retimed under (``meta["retime"]["limits"]``) unless given. Written
atomically like every figure (:func:`kinredund.ui.plots.save_figure`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError
from kinredund.trajectory import Trajectory
from kinredund.ui.plots import legend_outside, save_figure

#: a joint's limit is drawn when it is at most this many times the largest value it bounds
LIMIT_REACH = 3.0


def _limits_of(traj: Trajectory, velocity, acceleration) -> tuple[np.ndarray | None, np.ndarray | None]:
    rec = traj.meta.get("retime", {}).get("limits", {}) if isinstance(traj.meta.get("retime"), dict) else {}
    v = velocity if velocity is not None else rec.get("velocity")
    a = acceleration if acceleration is not None else rec.get("acceleration")
    n = traj.q.shape[1]
    return tuple(None if x is None else np.broadcast_to(np.asarray(x, float), (n,)) for x in (v, a))


def retimed_figure(traj: Trajectory, *, velocity=None, acceleration=None, title: str | None = None):
    """The figure of :func:`plot_retimed` (a ``matplotlib.figure.Figure``).

    Args:
        traj: a record with ``qdot`` and ``qddot`` (:func:`kinredund.retime.retime` gives them).
        velocity, acceleration: limits to draw (a number or one per joint); default the record's own.
        title: the figure title; default the robot and the loop duration.

    Raises:
        KinredundError: a record without qdot or qddot, or one :meth:`Trajectory.checked` rejects.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not isinstance(traj, Trajectory):
        raise KinredundError(f"plot_retimed takes a kinredund Trajectory, got {type(traj).__name__}")
    tr = traj.checked()
    if tr.qdot is None or tr.qddot is None:
        raise KinredundError(f"the trajectory of {tr.robot!r} has no qdot/qddot: retime it first (kinredund retime)")
    v, a = _limits_of(tr, velocity, acceleration)
    fig = Figure(figsize=(8.0, 9.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(3, 1, k + 1) for k in range(3)]
    n = tr.q.shape[1]
    for j in range(n):
        c = f"C{j % 10}"
        axes[0].plot(tr.t, tr.q[:, j], color=c, label=f"$\\theta_{{{j + 1}}}$")
        axes[1].plot(tr.t, tr.qdot[:, j], color=c)
        axes[2].plot(tr.t, tr.qddot[:, j], color=c)
        for ax, lim, data in ((axes[1], v, tr.qdot[:, j]), (axes[2], a, tr.qddot[:, j])):
            # a limit far above the motion (the URDF's 1000 rad/s) would squash the curves flat: left out
            if lim is not None and lim[j] <= LIMIT_REACH * max(float(np.abs(data).max()), 1e-300):
                for sign in (1.0, -1.0):
                    ax.axhline(sign * lim[j], color=c, linestyle="--", linewidth=0.8, alpha=0.7)
    # one unit for the angle and its rates (the velocity and acceleration limits are given in rad/s, rad/s^2)
    labels = ("joint angle [rad]", "joint velocity [rad/s]", "joint acceleration [rad/s$^2$]")
    for ax, label in zip(axes, labels, strict=True):
        ax.set_ylabel(label)
        ax.set_xlabel("time [s]")
        ax.set_xlim(tr.t[0], tr.t[-1])
        ax.grid(True, alpha=0.3)
    legend_outside(axes[0])
    info = tr.meta.get("retime", {}) if isinstance(tr.meta.get("retime"), dict) else {}
    dur = info.get("loop_duration")
    axes[0].set_title(title if title is not None else
                      f"Retimed: {tr.robot}" + (f", {dur:.4g} s per loop" if isinstance(dur, float) else "")
                      + " (dashed: limits within reach)")
    return fig


def plot_retimed(traj: Trajectory, path: str | Path, *, velocity=None, acceleration=None,
                 title: str | None = None) -> Path:
    """q, qdot and qddot against time with the limits drawn (:func:`retimed_figure`), written to ``path``
    (``.png``, ``.pdf`` or ``.svg``) atomically; returns the path."""
    return save_figure(retimed_figure(traj, velocity=velocity, acceleration=acceleration, title=title), path)
