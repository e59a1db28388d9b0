"""Figures of tracking runs: joint histories, pose errors, the eigenvalues of M, loop drift (Chapter 4).

Every function takes a :class:`~kinredund.trajectory.Trajectory` (or a list of them) and an output
path, draws with matplotlib's object API on an Agg canvas (no display, no pyplot state), writes the
file atomically (a temporary file in the same folder, then a rename) and returns the path. The
format follows the suffix: ``.png``, ``.pdf`` or ``.svg``.

- :func:`plot_joint_histories`: one curve per joint, time [s] on x, joint angle [deg] on y, in the
  style of the thesis's Figs. 4.3, 4.4, 4.7 and 4.8.
- :func:`plot_errors`: position error [m] and orientation errors (Example 4.3's trace error
  |tr Q - tr Q_d| and vect error ||vect Q - vect Q_d||, dimensionless: Q is a rotation matrix) against
  time, log scale.
- :func:`plot_m_eigenvalues`: the eigenvalues of M (Eq. 4.24) and of its projection on the null
  space of J against time; steps solved by LU instead of the QP of Theorem 2 are shaded.
- :func:`plot_loop_drift`: joint drift from the start at the end of each loop, one curve per scheme,
  log scale.

Legends sit to the right of their axes, off the data (:func:`legend_outside`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError, check_choice
from kinredund.io import atomic_write
from kinredund.trajectory import Trajectory

PLOT_FORMATS = ("png", "pdf", "svg")
#: Values below this are drawn at it on log scales (an exact zero has no logarithm).
LOG_FLOOR = 1e-17
_DPI = 120
#: the eigenvalue panels draw their zero line only when 0 lies within this share of the data's span of it
#: (else the line stretched a panel of values 0.94-1.06 from 0 to 1.1)
ZERO_LINE_REACH = 0.25


# -- helpers ---------------------------------------------------------------------------------------
def _as_list(trajs: Trajectory | Sequence[Trajectory]) -> list[Trajectory]:
    """The trajectories to draw, each validated by :meth:`Trajectory.checked` (arrays as numpy arrays)."""
    items = [trajs] if isinstance(trajs, Trajectory) else list(trajs)
    if not items:
        raise KinredundError("no trajectory to plot: give a Trajectory or a non-empty list of them")
    for k, tr in enumerate(items):
        if not isinstance(tr, Trajectory):
            raise KinredundError(f"item {k} is a {type(tr).__name__}, not a kinredund Trajectory")
    return [tr.checked() for tr in items]


def _required(traj: Trajectory, name: str, hint: str = "") -> np.ndarray:
    """``traj.<name>`` (a checked record's array), or KinredundError saying the run did not record it."""
    value = getattr(traj, name)
    if value is None or np.size(value) == 0:
        raise KinredundError(f"the {_label(traj)} trajectory of {traj.robot!r} has no {name}{hint}")
    return value


def _label(traj: Trajectory) -> str:
    return f"{traj.scheme} ({traj.mode})"


def legend_outside(ax, handles=None, labels=None, **kwargs):
    """The legend of ``ax`` to the right of its axes, off the data (a ``loc="best"`` legend still covered
    curves, e.g. Example 4.2's eigenvalues); the constrained layout makes room for it."""
    args = () if handles is None else (handles, labels)
    return ax.legend(*args, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0, fontsize="small",
                     frameon=False, **kwargs)


def _new_figure(rows: int = 1, height: float = 3.6, width: float = 8.0):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height * rows), layout="constrained")
    FigureCanvasAgg(fig)
    axes = [fig.add_subplot(rows, 1, k + 1) for k in range(rows)]
    return fig, axes


def save_figure(fig, path: str | Path) -> Path:
    """Write ``fig`` to ``path`` through a temporary file and a rename; return the path.

    Raises:
        ChoiceError: the suffix is not one of :data:`PLOT_FORMATS`.
    """
    path = Path(path)
    fmt = plot_format(path)
    return atomic_write(path, lambda fh: fig.savefig(fh, format=fmt, dpi=_DPI), "wb")


def plot_format(path: str | Path, what: str = "the plot") -> str:
    """The format a figure file takes from its suffix (``png``, ``pdf`` or ``svg``: :data:`PLOT_FORMATS`).

    Raises:
        ChoiceError: another suffix; KinredundError: none (``what`` names the file's option in the message).
    """
    suffix = Path(path).suffix.lower().lstrip(".")
    if not suffix:
        raise KinredundError(f"{what} {str(path)!r} has no suffix: the format follows it, give "
                             f"{', '.join('.' + f for f in PLOT_FORMATS[:-1])} or .{PLOT_FORMATS[-1]}")
    return check_choice(f"{what} format (file suffix)", suffix, PLOT_FORMATS)


def _log_positive(values: np.ndarray) -> np.ndarray:
    return np.maximum(np.abs(values), LOG_FLOOR)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the runs of True in ``mask`` (stop exclusive)."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(int)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


# -- joint histories (Figs. 4.3, 4.4, 4.7, 4.8) --------------------------------------------------
def plot_joint_histories(
    trajs: Trajectory | Sequence[Trajectory],
    path: str | Path,
    *,
    joints: Sequence[int] | None = None,
    revolute: Sequence[bool] | None = None,
    title: str | None = None,
) -> Path:
    """Joint histories: one curve per joint, time [s] on x, angle [deg] on y (thesis Figs. 4.3-4.8).

    Writes :func:`joint_histories_figure` to ``path`` (``.png``, ``.pdf`` or ``.svg``) atomically
    and returns the path.
    """
    return save_figure(joint_histories_figure(trajs, joints=joints, revolute=revolute, title=title), path)


def joint_histories_figure(
    trajs: Trajectory | Sequence[Trajectory],
    *,
    joints: Sequence[int] | None = None,
    revolute: Sequence[bool] | None = None,
    title: str | None = None,
):
    """The figure of :func:`plot_joint_histories` (a ``matplotlib.figure.Figure``).

    Args:
        trajs: a trajectory, or several (one panel each, stacked).
        joints: 0-based joint indices to draw (default all); the thesis splits the 7 joints of the
            CYBOTECH P-15 into Figs. 4.7 (joints 1-4) and 4.8 (joints 5-7).
        revolute: per joint, True for revolute (drawn in degrees) and False for prismatic (drawn in
            millimetres, on a second axis); default all revolute.
        title: the figure title; default the robot, scheme and mode.

    Raises:
        KinredundError: no trajectory, a record that :meth:`Trajectory.checked` rejects, or a joint
            index out of range.
    """
    items = _as_list(trajs)
    fig, axes = _new_figure(len(items))
    for ax, tr in zip(axes, items, strict=True):
        t, q = tr.t, tr.q
        n = q.shape[1]
        chosen = list(range(n)) if joints is None else [int(j) for j in joints]
        bad = [j for j in chosen if not 0 <= j < n]
        if bad:
            raise KinredundError(f"joint indices {bad} out of range: {tr.robot!r} has joints 0..{n - 1}")
        kinds = np.ones(n, dtype=bool) if revolute is None else np.asarray(revolute, dtype=bool)
        if kinds.shape != (n,):
            raise KinredundError(f"revolute must have one entry per joint ({n}), got {len(kinds)}")
        twin = None
        for j in chosen:
            if kinds[j]:
                ax.plot(t, np.degrees(q[:, j]), label=f"$\\theta_{{{j + 1}}}$")
            else:
                twin = twin or ax.twinx()
                twin.plot(t, 1e3 * q[:, j], linestyle="--", label=f"$b_{{{j + 1}}}$")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("joint angle [deg]")
        if twin is not None:
            twin.set_ylabel("joint displacement [mm]")
        ax.set_xlim(t[0], t[-1])
        ax.grid(True, alpha=0.3)
        handles, names = ax.get_legend_handles_labels()
        if twin is not None:
            more = twin.get_legend_handles_labels()
            handles, names = handles + more[0], names + more[1]
        legend_outside(twin or ax, handles, names)  # on the twin (drawn last) when there is one
        ax.set_title(title if title is not None else f"Joint histories: {tr.robot}, {_label(tr)}")
    return fig


# -- pose errors --------------------------------------------------------------------------------
def plot_errors(
    trajs: Trajectory | Sequence[Trajectory], path: str | Path, *, title: str | None = None
) -> Path:
    """Position and orientation errors against time, log scale: :func:`errors_figure`, written to ``path``."""
    return save_figure(errors_figure(trajs, title=title), path)


def errors_figure(trajs: Trajectory | Sequence[Trajectory], *, title: str | None = None):
    """Position error |p - p_d| [m] (``traj.position_error``) and orientation errors against time, log scale.

    The orientation panel (Example 4.3's trace and vect errors) appears when some trajectory has
    them. Several trajectories are overlaid, labelled by scheme and mode. Exact zeros are drawn at
    :data:`LOG_FLOOR`.

    Raises:
        KinredundError: no trajectory, a trajectory without ``position_error`` (every tracking run
            records it), or a record that :meth:`Trajectory.checked` rejects.
    """
    items = _as_list(trajs)
    has_orientation = any(tr.trace_error is not None or tr.vect_error is not None for tr in items)
    fig, axes = _new_figure(2 if has_orientation else 1)
    for k, tr in enumerate(items):
        color = f"C{k % 10}"
        err = _required(tr, "position_error")
        axes[0].semilogy(tr.t, _log_positive(err), color=color, label=_label(tr))
        if has_orientation:
            for name, style, what in (("trace_error", "-", "$|\\mathrm{tr}\\,Q - \\mathrm{tr}\\,Q_d|$"),
                                      ("vect_error", "--", "$\\|\\mathrm{vect}\\,Q - \\mathrm{vect}\\,Q_d\\|$")):
                val = getattr(tr, name)
                if val is not None:
                    axes[1].semilogy(tr.t, _log_positive(val), color=color, linestyle=style,
                                     label=f"{what}: {_label(tr)}")
    axes[0].set_ylabel("position error [m]")
    axes[0].set_title(title if title is not None else f"Pose errors: {items[0].robot}")
    if has_orientation:
        # the invariants of Example 4.3: tr Q = 1 + 2 cos(angle), vect Q = sin(angle) axis (dimensionless)
        axes[1].set_ylabel("orientation error\n(trace and vect of Q) [-]")
        axes[1].set_title("orientation: trace error (solid) and vect error (dashed), invariants of the "
                          "rotation Q", fontsize="small")
    for ax in axes:
        ax.set_xlabel("time [s]")
        ax.grid(True, which="both", alpha=0.3)
        legend_outside(ax)
    return fig


# -- eigenvalues of M and the QP/LU switch ------------------------------------------------------
def plot_m_eigenvalues(traj: Trajectory, path: str | Path, *, title: str | None = None) -> Path:
    """Eigenvalues of M against time, LU steps shaded: :func:`m_eigenvalues_figure` written to ``path``."""
    return save_figure(m_eigenvalues_figure(traj, title=title), path)


def m_eigenvalues_figure(traj: Trajectory, *, title: str | None = None):
    """Eigenvalues of M (Eq. 4.24) and of its null-space projection against time, LU steps shaded.

    Theorem 2: where M is positive definite the step is the QP; elsewhere the scheme solves the
    augmented system by LU. Runs of steps with ``traj.solver[i] == "lu"`` are shaded red, so the
    switch shows where the eigenvalues cross zero; runs of ``qp_aug`` steps (M indefinite but
    positive definite on the null space of J, solved as a QP with M + rho J^T J) are shaded yellow.

    Raises:
        KinredundError: ``traj`` is not one Trajectory, it has no ``m_eigs`` (only the augmented and
            velocity schemes record them), or :meth:`Trajectory.checked` rejects it.
    """
    from matplotlib.patches import Patch

    if not isinstance(traj, Trajectory):
        raise KinredundError(f"plot_m_eigenvalues draws one kinredund Trajectory, got a {type(traj).__name__}")
    (tr,) = _as_list(traj)
    t = tr.t
    hint = " (eigenvalues of M are recorded by the 'augmented' and 'velocity' schemes only)"
    eigs = _required(tr, "m_eigs", hint)
    null = tr.m_null_eigs
    fig, axes = _new_figure(2 if null is not None and null.size else 1)
    panels = [(axes[0], eigs, "$\\mu_{{{}}}(M)$", "eigenvalues of M")]
    if len(axes) == 2:
        panels.append((axes[1], null, "$\\mu_{{{}}}(N^T M N)$", "eigenvalues of M on null(J)"))
    labels = np.array(tr.solver if tr.solver else [""] * len(t), dtype=object)
    lu, aug = labels == "lu", labels == "qp_aug"
    for ax, values, fmt, ylabel in panels:
        for j in range(values.shape[1]):
            ax.plot(t, values[:, j], label=fmt.format(j + 1))
        low, high = float(values.min()), float(values.max())
        if low - ZERO_LINE_REACH * (high - low) <= 0.0 <= high + ZERO_LINE_REACH * (high - low):
            ax.axhline(0.0, color="black", linewidth=0.8)  # where the sign can change
        elif low > 0.0:
            ylabel += " (all > 0)"  # a zero line would stretch the panel from 0 (0 to 1.1 for 0.94-1.06)
        for mask, color, label in ((lu, "tab:red", "solved by LU"), (aug, "gold", r"solved by QP on $M + \rho J^T J$")):
            for k, (start, stop) in enumerate(_runs(mask)):
                right = t[min(stop, len(t) - 1)]
                ax.axvspan(t[start], right, color=color, alpha=0.15, linewidth=0, label=label if k == 0 else None)
        ax.set_xlabel("time [s]")
        ax.set_ylabel(ylabel)
        ax.set_xlim(t[0], t[-1])
        ax.grid(True, alpha=0.3)
        handles, names = ax.get_legend_handles_labels()
        handles.append(Patch(facecolor="white", edgecolor="0.6", linewidth=0.5))
        names.append("unshaded: solved by QP on M")
        legend_outside(ax, handles, names)
    lu_count = int(lu[1:].sum())  # labels of the steps: solver[0] is the start's (Trajectory.summary)
    axes[0].set_title(title if title is not None
                      else f"M along the path: {tr.robot}, {_label(tr)}, {lu_count} LU steps of {len(t) - 1}")
    return fig


# -- drift from the start, after each loop -----------------------------------------------------------------------------
_DRIFT_HINT = ": it is not a closed path (tracking records the drift per loop of closed paths only)"


def loop_drifts(traj: Trajectory) -> np.ndarray:
    """Joint drift at the end of each loop [rad]: ``traj.loop_drift``, which tracking records for closed paths.

    Raises:
        KinredundError: the trajectory has no ``loop_drift`` (an open path, or not a tracking run).
    """
    return _required(traj.checked(), "loop_drift", _DRIFT_HINT)


def plot_loop_drift(
    trajs: Trajectory | Sequence[Trajectory], path: str | Path, *, title: str | None = None
) -> Path:
    """Joint drift from the start after each loop, one curve per scheme, log: :func:`loop_drift_figure`
    written to ``path``."""
    return save_figure(loop_drift_figure(trajs, title=title), path)


def loop_drift_figure(trajs: Trajectory | Sequence[Trajectory], *, title: str | None = None):
    """Joint drift from the start at the end of each loop [rad] (``traj.loop_drift``: |q(k T) - q(0)|, not
    the change over one loop), one curve per trajectory, log scale.

    A cyclic scheme keeps the drift at round-off level; the pseudoinverse (Liegeois) drifts.

    Raises:
        KinredundError: a trajectory without ``loop_drift`` (see :func:`loop_drifts`).
    """
    items = _as_list(trajs)
    fig, axes = _new_figure(1)
    ax = axes[0]
    for k, tr in enumerate(items):
        drift = _required(tr, "loop_drift", _DRIFT_HINT)  # tr is checked: not loop_drifts(tr)
        loops = np.arange(1, len(drift) + 1)
        label = _label(tr) + (" (a single loop: one point)" if len(drift) == 1 else "")
        ax.semilogy(loops, _log_positive(drift), marker="o", color=f"C{k % 10}", label=label)
    ax.set_xlabel("loops run")
    ax.set_ylabel("joint drift from the start [rad]")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.grid(True, which="both", alpha=0.3)
    legend_outside(ax)
    ax.set_title(title if title is not None else f"Joint drift from the start after each loop: {items[0].robot}")
    return fig


__all__ = [
    "LOG_FLOOR",
    "PLOT_FORMATS",
    "plot_format",
    "errors_figure",
    "joint_histories_figure",
    "loop_drift_figure",
    "loop_drifts",
    "legend_outside",
    "m_eigenvalues_figure",
    "plot_errors",
    "plot_joint_histories",
    "plot_loop_drift",
    "plot_m_eigenvalues",
    "save_figure",
]
