"""What a standalone replay page shows around meshcat's viewer: a title, a time readout and a legend.

meshcat's static export is a page with the viewer and its control panel only. :func:`decorate_page`
adds a panel in the top-left corner (plain HTML and CSS, no network) with the title (robot, path,
scheme), a readout of the trajectory's time that follows the animation (read from the viewer's
animator ten times a second) and a legend of the colours of the scene. Where the browser gives no WebGL
context (meshcat would show a blank page), a notice in the middle of the page says so and what to do.
The elements carry ids (:data:`TITLE_ID`, :data:`TIME_ID`, :data:`LEGEND_ID`, :data:`NOTICE_ID`) that
the browser tests read.
"""

from __future__ import annotations

import html
import json

from kinredund.errors import KinredundError
from kinredund.trajectory import Trajectory

TITLE_ID = "kinredund-title"
TIME_ID = "kinredund-time"
LEGEND_ID = "kinredund-legend"
NOTICE_ID = "kinredund-no-webgl"


def replay_title(traj: Trajectory, path_label: str | None = None) -> str:
    """The page title: robot, path and scheme, e.g. ``panda: circle, augmented scheme (default mode)``.

    ``path_label`` names the path; default the example of ``traj.meta`` (``Example 4.3``), else
    ``closed path`` or ``open path``.
    """
    meta = traj.meta if isinstance(traj.meta, dict) else {}
    if path_label is None:
        example = meta.get("example")
        if example is not None:
            path_label = f"{'Section' if str(example).startswith(('3', '6')) else 'Example'} {example}"
        else:
            path_label = "closed path" if traj.loop_period is not None else "open path"
    if traj.scheme == "planner":
        return f"{traj.robot}: {path_label}, planned motion around the obstacle"
    if traj.scheme == "closed_form":
        return f"{traj.robot}: {path_label}, closed-form IK"
    return f"{traj.robot}: {path_label}, {traj.scheme} scheme ({traj.mode} mode)"


def _swatch(color: int | tuple[int, ...], shape: str) -> str:
    """A legend swatch; several colours (the world axes) give one small swatch each."""
    if isinstance(color, tuple):
        return "".join(_swatch(c, {"line": "short"}.get(shape, shape)) for c in color)
    css = {"line": "width:22px;height:3px", "short": "width:8px;height:3px", "dot": "width:9px;height:9px;"
           "border-radius:50%", "box": "width:14px;height:10px;opacity:0.6"}[shape]
    style = f"display:inline-block;{css};background:#{color:06x};margin-right:6px;vertical-align:middle"
    return f'<span style="{style}"></span>'


#: what the page says where the browser gives no WebGL context (meshcat draws nothing without one)
NO_WEBGL = ("This replay needs WebGL, which this browser does not provide here (it may be turned off, or the "
            "graphics driver blocked): the robot cannot be drawn. Open the file in a browser with WebGL and "
            "hardware acceleration enabled (chrome://gpu or about:support tells).")


def decorate_page(page: str, title: str, legend: list[tuple[str, int, str]], t0: float, duration: float) -> str:
    """``page`` (meshcat's static HTML) with the title, the time readout and the legend added.

    Args:
        page: the HTML of ``Visualizer.static_html()``.
        title: the title line.
        legend: (label, colour 0xRRGGBB or a tuple of them, ``line``/``dot``/``box``) per entry.
        t0: the trajectory time of the first frame [s].
        duration: the playback's length [s].

    Raises:
        KinredundError: ``page`` has no ``</body>`` to insert before.
    """
    if "</body>" not in page:
        raise KinredundError("the meshcat page has no </body>: cannot add the title and time readout")
    items = "".join(f"<div>{_swatch(color, shape)}{html.escape(label)}</div>" for label, color, shape in legend)
    panel = f"""
<div id="kinredund-overlay" style="position:absolute;left:12px;top:10px;z-index:10;pointer-events:none;
  font:14px/1.45 system-ui,sans-serif;color:#1d2330;background:rgba(255,255,255,0.82);padding:8px 12px;
  border-radius:6px;box-shadow:0 1px 4px rgba(0,0,0,0.15)">
  <div id="{TITLE_ID}" style="font-weight:600;font-size:15px">{html.escape(title)}</div>
  <div id="{TIME_ID}" style="font-variant-numeric:tabular-nums">t = {t0:.2f} s</div>
  <div id="{LEGEND_ID}" style="margin-top:4px;font-size:13px">{items}</div>
  <div style="margin-top:4px;font-size:11px;color:#555">play, pause and scrub: Open Controls, Animations</div>
</div>
<div id="{NOTICE_ID}" role="alert" style="display:none;position:absolute;left:50%;top:40%;z-index:11;
  transform:translate(-50%,-50%);max-width:36em;font:15px/1.5 system-ui,sans-serif;color:#5a1010;
  background:#fff4f2;border:1px solid #d9a59d;border-radius:6px;padding:14px 18px">{html.escape(NO_WEBGL)}</div>
<script>
(function () {{
  var t0 = {json.dumps(float(t0))}, duration = {json.dumps(float(duration))};
  var el = document.getElementById("{TIME_ID}");
  var gl = null;
  try {{
    var canvas = document.createElement("canvas");
    gl = window.WebGLRenderingContext && (canvas.getContext("webgl2") || canvas.getContext("webgl")
                                          || canvas.getContext("experimental-webgl"));
  }} catch (err) {{ gl = null; }}
  if (!gl) {{
    document.getElementById("{NOTICE_ID}").style.display = "block";
    el.textContent = "no WebGL: nothing to play";
    return;
  }}
  setInterval(function () {{
    var a = (typeof viewer !== "undefined" && viewer.animator) ? viewer.animator.time : 0;
    el.textContent = "t = " + (t0 + a).toFixed(2) + " s of " + (t0 + duration).toFixed(2) + " s";
  }}, 100);
}})();
</script>
"""
    head, tail = page.rsplit("</body>", 1)
    return head + panel + "</body>" + tail
