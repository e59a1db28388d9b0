"""The map of a placement sweep: where the part can go, and how good each place is.

:func:`plot_sweep_map` draws two panels over the grid of part positions (x, y) [m] in the robot's base
frame: the share of the placements at each position (over yaw and z) that are feasible, and the best
value of the chosen criterion among them (:data:`kinredund.sweep.CRITERIA`); positions with no
feasible placement are grey. The robot's base is drawn at the origin (its x axis as an arrow) and the
best placement is starred. Same conventions as :mod:`kinredund.ui.plots` (Agg canvas, atomic write,
format from the suffix).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinredund.errors import KinredundError, check_choice
from kinredund.sweep.record import CRITERIA, PlacementRecord, best
from kinredund.ui.plots import save_figure

#: units of the criteria (``-``: a ratio or a mixed-unit figure); the command line prints them too
CRITERION_UNITS = {"margin": "rad", "sigma_min": "-", "speed": "-", "mean_z": "rad^2", "drift": "rad",
                   "clearance": "m"}
_UNIT_TEX = {"rad^2": "rad$^2$"}
#: axis labels of the criteria, with units
CRITERION_LABELS = {
    name: f"{text} [{_UNIT_TEX.get(CRITERION_UNITS[name], CRITERION_UNITS[name])}]"
    for name, text in (("margin", "smallest margin to the joint limits"), ("sigma_min", "smallest singular value of J"),
                       ("speed", "largest joint speed / its limit"), ("mean_z", "mean of z over the loop"),
                       ("drift", "loop drift"), ("clearance", "least clearance to the cell and itself"))
}


def _edges(values: np.ndarray) -> np.ndarray:
    """Cell edges around sorted cell centres (half-way between neighbours; +-0.05 m for a single one)."""
    if len(values) == 1:
        return np.array([values[0] - 0.05, values[0] + 0.05])
    mid = 0.5 * (values[1:] + values[:-1])
    return np.concatenate([[2 * values[0] - mid[0]], mid, [2 * values[-1] - mid[-1]]])


def sweep_maps(records, criterion: str = "margin") -> dict:
    """The gridded maps: ``x``, ``y`` (cell centres [m]), ``feasible`` (share of feasible placements per
    cell, NaN where the sweep had none) and ``quality`` (best criterion value among them, NaN if none)."""
    check_choice("sweep criterion", criterion, tuple(CRITERIA))
    records = list(records)
    if not records or not all(isinstance(r, PlacementRecord) for r in records):
        raise KinredundError("a sweep map needs a non-empty list of PlacementRecord")
    xs = np.unique(np.round([r.x for r in records], 9))
    ys = np.unique(np.round([r.y for r in records], 9))
    count = np.zeros((len(ys), len(xs)))
    ok = np.zeros((len(ys), len(xs)))
    quality = np.full((len(ys), len(xs)), np.nan)
    larger = CRITERIA[criterion][1]
    for r in records:
        i, j = np.searchsorted(ys, round(r.y, 9)), np.searchsorted(xs, round(r.x, 9))
        count[i, j] += 1
        v = r.value(criterion)
        if r.feasible:
            ok[i, j] += 1
            if v is not None and (np.isnan(quality[i, j]) or (v > quality[i, j] if larger else v < quality[i, j])):
                quality[i, j] = v
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.where(count > 0, ok / np.maximum(count, 1), np.nan)
    return {"x": xs, "y": ys, "feasible": share, "quality": quality}


def _draw_base(ax, size: float) -> None:
    """The robot's base at the origin: a disc and its x axis."""
    from matplotlib.patches import Circle

    ax.add_patch(Circle((0.0, 0.0), 0.35 * size, color="0.15", zorder=3))
    ax.annotate("", xy=(size, 0.0), xytext=(0.0, 0.0), zorder=4,
                arrowprops={"arrowstyle": "->", "color": "0.15", "lw": 1.5})
    ax.text(0.0, -0.6 * size, "robot base", ha="center", va="top", fontsize=8, zorder=4)


def sweep_map_figure(records, criterion: str = "margin", *, title: str | None = None):
    """The figure of :func:`plot_sweep_map` (a matplotlib Figure on an Agg canvas)."""
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    maps = sweep_maps(records, criterion)
    xe, ye = _edges(maps["x"]), _edges(maps["y"])
    fig = Figure(figsize=(11.0, 4.6), layout="constrained")
    FigureCanvasAgg(fig)
    ax_f, ax_q = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    m = ax_f.pcolormesh(xe, ye, np.ma.masked_invalid(maps["feasible"]), cmap="RdYlGn", vmin=0.0, vmax=1.0)
    fig.colorbar(m, ax=ax_f, label="feasible share of the placements (over yaw, z)")
    ax_f.set_title("feasibility")
    cmap = colormaps["viridis" if CRITERIA[criterion][1] else "viridis_r"].with_extremes(bad="0.8")
    q = np.ma.masked_invalid(maps["quality"])
    m = ax_q.pcolormesh(xe, ye, q, cmap=cmap)
    fig.colorbar(m, ax=ax_q, label=CRITERION_LABELS[criterion])
    ax_q.set_title(f"best {criterion} (grey: no feasible placement)")
    top = best(records, criterion, 1)
    span = max(xe[-1] - xe[0], ye[-1] - ye[0], 0.2)
    for ax in (ax_f, ax_q):
        _draw_base(ax, 0.06 * span)
        ax.set_xlabel("part x [m]")
        ax.set_ylabel("part y [m]")
        ax.set_xlim(min(xe[0], -0.1 * span), max(xe[-1], 0.1 * span))
        ax.set_ylim(min(ye[0], -0.1 * span), max(ye[-1], 0.1 * span))
        ax.set_aspect("equal")
        if top:
            near = "" if top[0].clearance is None else f", clearance {top[0].clearance:.3g} m"
            ax.plot(top[0].x, top[0].y, marker="*", ms=14, color="tab:red", mec="k", zorder=5,
                    label=f"best ({criterion}): yaw {np.degrees(top[0].yaw):.0f} deg{near}")
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), fontsize=8, frameon=False)
    if title:
        fig.suptitle(title)
    return fig


def plot_sweep_map(records, path: str | Path, criterion: str = "margin", *, title: str | None = None) -> Path:
    """Draw the feasibility and quality maps of a sweep to ``path`` (.png, .pdf, .svg); return the path.

    Raises:
        ChoiceError: an unknown criterion or file suffix; KinredundError: no records.
    """
    return save_figure(sweep_map_figure(records, criterion, title=title), path)
