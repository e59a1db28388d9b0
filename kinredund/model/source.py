"""What a record stores to reload its robot: the name or URDF path given to ``load_robot`` and its options.

A record (a trajectory, a partial record, a sweep header) names its robot by one string that
:func:`kinredund.load_robot` takes back (``docs/schema.md``): the catalogue name (``panda``), or the
absolute path of a URDF file, followed, when the robot was loaded with options that change it, by those
options as a JSON object: ``baxter{"joints":["left_s0",...],"locked":{"head_pan":0.2}}``. So a custom
chain (``joints=``, ``locked=``), another end-effector frame or a turned tool axis reloads as it was
tracked, in any process, rather than as the catalogue's default arm.
"""

from __future__ import annotations

import json

#: the options of ``load_robot`` a record keeps (the task is a field of the record itself)
OPTIONS = ("ee_frame", "tool_axis", "joints", "locked")


def record_source(base: str, *, ee_frame=None, tool_axis=None, joints=None, locked=None) -> str:
    """``base`` (a name or an absolute URDF path) with the options that were given, as one string.

    The options must be those ``load_robot`` accepted: the frame a string, the axis 3 numbers, the joints
    names, ``locked`` names to numbers. Floats are written by ``repr`` (they read back exactly).
    """
    given = {"ee_frame": None if ee_frame is None else str(ee_frame),
             "tool_axis": None if tool_axis is None else [float(v) for v in tool_axis],
             "joints": None if joints is None else [str(j) for j in joints],
             "locked": None if locked is None else {str(k): float(v) for k, v in dict(locked).items()}}
    given = {k: v for k, v in given.items() if v is not None}
    return base + json.dumps(given, separators=(",", ":")) if given else base


def split_source(text: str) -> tuple[str, dict]:
    """(base, options) of a string of :func:`record_source`; a plain name or path gives (text, {}).

    The options are the JSON object that ends the string, from the first '{' where one parses (a path may
    hold braces too: ``/data/arm{v2}/arm.urdf{"joints":[...]}``).
    """
    if not text.endswith("}"):
        return text, {}
    start = text.find("{", 1)
    while start > 0:
        try:
            options = json.loads(text[start:])
        except ValueError:
            options = None
        if isinstance(options, dict) and options and set(options) <= set(OPTIONS):  # record_source writes no {}
            return text[:start], options
        start = text.find("{", start + 1)
    return text, {}
