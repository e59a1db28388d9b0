"""The clearance of a motion over time (``kinredund check --plot``): the least signed distance at each sample,
the least clearance found (between samples too) marked with its pair, and zero drawn. Written atomically
(:func:`kinredund.ui.plots.save_figure`)."""

from __future__ import annotations

from pathlib import Path

from kinredund.geometry.motion import Clearance
from kinredund.ui.plots import save_figure


def clearance_figure(c: Clearance, title: str = ""):
    """The figure of :func:`plot_clearance` (a ``matplotlib.figure.Figure``)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 3.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(c.t, 1e3 * c.distance, lw=1.2, label="least distance at the samples")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.plot([c.min_time], [1e3 * c.min_distance], "o", color="tab:red",
            label=f"least clearance {1e3 * c.min_distance:.2f} mm: {' / '.join(c.min_pair or ('-',))}")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("clearance [mm]")
    ax.set_title(title or ("contact" if c.contact else "free"))
    ax.legend(loc="best", fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def plot_clearance(c: Clearance, path: str | Path, title: str = "") -> Path:
    """Draw :func:`clearance_figure` to ``path`` (.png, .pdf, .svg); return the path."""
    return save_figure(clearance_figure(c, title), path)
