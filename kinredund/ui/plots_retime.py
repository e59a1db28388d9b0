"""Figures of retimed records: joint positions, velocities and accelerations with their limits drawn.

:func:`plot_retimed` draws q [deg], qdot [rad/s] and qddot [rad/s^2] against time, one colour per joint,
with each joint's limits +-v_i and +-a_i as dashed lines of its colour. The limits are those the record
was retimed under (``meta["retime"]["limits"]``) unless given. Written atomically like every figure
(:func:`kinredund.ui.plots.save_figure`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError
from kinredund.trajectory import Trajectory
from kinredund.ui.plots import save_figure


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
    fig = Figure(figsize=(7.0, 9.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(3, 1, k + 1) for k in range(3)]
    n = tr.q.shape[1]
    for j in range(n):
        c = f"C{j % 10}"
        axes[0].plot(tr.t, np.degrees(tr.q[:, j]), color=c, label=f"$\\theta_{{{j + 1}}}$")
        axes[1].plot(tr.t, tr.qdot[:, j], color=c)
        axes[2].plot(tr.t, tr.qddot[:, j], color=c)
        for ax, lim in ((axes[1], v), (axes[2], a)):
            if lim is not None:
                for sign in (1.0, -1.0):
                    ax.axhline(sign * lim[j], color=c, linestyle="--", linewidth=0.8, alpha=0.7)
    labels = ("joint angle [deg]", "joint velocity [rad/s]", "joint acceleration [rad/s$^2$]")
    for ax, label in zip(axes, labels, strict=True):
        ax.set_ylabel(label)
        ax.set_xlabel("time [s]")
        ax.set_xlim(tr.t[0], tr.t[-1])
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="best", fontsize="small", ncols=min(n, 4))
    info = tr.meta.get("retime", {}) if isinstance(tr.meta.get("retime"), dict) else {}
    dur = info.get("loop_duration")
    axes[0].set_title(title if title is not None else
                      f"Retimed: {tr.robot}" + (f", {dur:.4g} s per loop" if isinstance(dur, float) else "")
                      + " (dashed: limits)")
    return fig


def plot_retimed(traj: Trajectory, path: str | Path, *, velocity=None, acceleration=None,
                 title: str | None = None) -> Path:
    """q, qdot and qddot against time with the limits drawn (:func:`retimed_figure`), written to ``path``
    (``.png``, ``.pdf`` or ``.svg``) atomically; returns the path."""
    return save_figure(retimed_figure(traj, velocity=velocity, acceleration=acceleration, title=title), path)
