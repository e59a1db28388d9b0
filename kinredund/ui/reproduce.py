"""The thesis's reproductions with their figures: the thesis layer computes and writes the JSON
records (:mod:`kinredund.thesis`), this module adds the plots (``kinredund reproduce``, the demo)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure  # Agg canvas, no pyplot state

from kinredund.planning.result import PlanResult
from kinredund.thesis import chapter4, chapter6, helix_3_2
from kinredund.trajectory import Trajectory
from kinredund.ui.plan_plots import plot_plan, snapshot_figure
from kinredund.ui.plots import plot_joint_histories, save_figure


def example(name: str, *, loops: int = 1, steps_per_loop: int = 200, mode: str = "default",
            scheme: str = "augmented", json_path=None, plot_path=None, progress=None) -> Trajectory:
    """Example 4.1, 4.2 or 4.3 (:func:`kinredund.thesis.chapter4.reproduce`) and its joint-history plot."""
    traj = chapter4.reproduce(name, loops=loops, steps_per_loop=steps_per_loop, mode=mode, scheme=scheme,
                              json_path=json_path, progress=progress)
    if plot_path is not None:
        plot_joint_histories(traj, plot_path, title=f"Example {name}: joint histories ({mode}, {scheme})")
    return traj


def helix(samples: int = 91, json_path=None, plot_path=None) -> dict:
    """Section 3.2 (:func:`kinredund.thesis.helix_3_2.reproduce`) and its joint histories (Fig. 3.6)."""
    data = helix_3_2.reproduce(samples, json_path=json_path)
    if plot_path is not None:
        plot_helix_joints(data, Path(plot_path))
    return data


def plan_case(case: str, json_path=None, plot_path=None, progress=None, samples: int = 9) -> PlanResult:
    """Section 6.2 or 6.3 (:func:`kinredund.thesis.chapter6.reproduce`) and its plots; a tracked plan
    also gets its configuration snapshots at :func:`snapshot_path`."""
    result, extra, robot, obstacle = chapter6.reproduce(case, json_path=json_path, progress=progress,
                                                        samples=samples)
    if plot_path is not None:
        if progress is not None:
            progress(0, 1, "writing the plots")
        plot_plan(case, result, extra, plot_path, robot_name=robot.name)
        if result.trajectory is not None:  # configuration snapshots (Figs. 6.14-6.22) beside the main plot
            snapshot_figure(result, robot, obstacle, snapshot_path(plot_path),
                            title=f"Section {case}: {robot.name} at six times over the loop")
    return result


def snapshot_path(plot_path) -> Path:
    """Where :func:`plan_case` saves the configuration snapshots beside ``plot_path``: ``NAME_snapshots.EXT``."""
    p = Path(plot_path)
    return p.with_name(f"{p.stem}_snapshots{p.suffix}")


def plot_helix_joints(data: dict, path) -> None:
    """The joint histories along the Section 3.2 helix (Fig. 3.6) from :func:`kinredund.thesis.helix_3_2.reproduce`."""
    fig = Figure(figsize=(7.0, 4.5))
    ax = fig.add_subplot()
    q = np.degrees(np.array(data["q"]))
    for k in range(4):
        ax.plot(data["t"], q[:, k], label=f"theta{k + 1}")
    ax.set_xlabel("time [s] (t = 4 beta / pi)")
    ax.set_ylabel("joint angle [deg]")
    ax.set_title("Section 3.2: joint histories along the helix (Fig. 3.6)")
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)  # atomic, checks the format
