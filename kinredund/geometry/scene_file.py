"""Scene files: a cell's objects as JSON (docs/schema.md, "Scene file"), read by :func:`load_scene`.

Lengths are in metres, angles in radians; a pose is ``{"xyz": [...], "rpy": [...]}`` or
``{"xyz": [...], "quat": [x, y, z, w]}``; a mesh's ``file`` is relative to the scene file's folder (or
absolute). :func:`save_scene` writes poses as xyz + quaternion, atomically.
"""

from __future__ import annotations

import os
from pathlib import Path

from kinredund.errors import GeometryError, KinredundError
from kinredund.geometry.scene import SHAPES, Scene
from kinredund.geometry.shapes import pose_dict
from kinredund.io import read_json_object, write_json

FORMAT = "kinredund-scene"
UNITS = {"length": "m", "angle": "rad"}
#: the keys each shape takes besides name, shape, pose and attach_to
SHAPE_KEYS = {"box": ("size",), "sphere": ("radius",), "cylinder": ("radius", "length"),
              "capsule": ("radius", "length"), "convex": ("points",), "mesh": ("file", "scale", "convex")}
_OPTIONAL = {"scale", "convex"}


def scene_dict(scene: Scene, folder: Path | None = None) -> dict:
    """The JSON form of ``scene``; mesh files relative to ``folder`` when they lie under it."""
    objects = []
    for name in scene.objects:
        obj = scene.object(name)
        entry = {"name": name, "shape": obj.shape, **obj.params}
        if obj.shape == "mesh" and folder is not None:
            rel = os.path.relpath(obj.params["file"], folder)
            entry["file"] = obj.params["file"] if rel.startswith("..") else rel
        entry["pose"] = pose_dict(obj.pose)
        if obj.attach_to is not None:
            entry["attach_to"] = obj.attach_to
        objects.append(entry)
    return {"format": FORMAT, "version": 1, "units": dict(UNITS), "robot": scene.robot.name,
            "geometry": scene.geometry, "objects": objects, "ignored_pairs": [list(p) for p in scene.ignored]}


def save_scene(scene: Scene, path) -> Path:
    """Write ``scene`` as a scene file (atomically); return the path."""
    path = Path(path)
    return write_json(path, scene_dict(scene, path.resolve().parent), indent=1)


def load_scene(file, robot, *, pairs=None, geometry: str | None = None) -> Scene:
    """The scene of a scene file, around ``robot``.

    Args:
        file: the scene file (JSON, docs/schema.md).
        robot: the robot (``load_robot``); the file's ``robot`` field is informative.
        pairs: the self-pair matrix (see :class:`~kinredund.geometry.scene.Scene`).
        geometry: ``"convex"`` or ``"mesh"``; default the file's (``"convex"`` if it has none).

    Raises:
        GeometryError: the file is not a scene file, or an object is malformed (the message names it).
    """
    data = read_json_object(file)
    where = str(file)
    if data.get("format") != FORMAT:
        raise GeometryError(f"{where} is not a scene file: its 'format' must be {FORMAT!r}")
    units = data.get("units", UNITS)
    if units != UNITS:
        raise GeometryError(f"{where}: units must be {UNITS}, got {units!r}")
    objects = data.get("objects", [])
    if not isinstance(objects, list):
        raise GeometryError(f"{where}: 'objects' must be a list")
    scene = Scene(robot, geometry=geometry or data.get("geometry", "convex"), pairs=pairs)
    folder = Path(file).resolve().parent
    for k, entry in enumerate(objects):
        _add(scene, entry, folder, f"{where}: object {k}")
    for pair in data.get("ignored_pairs", []):
        if not (isinstance(pair, list) and len(pair) == 2):
            raise GeometryError(f"{where}: an ignored pair must be [name, name], got {pair!r}")
        try:
            scene.ignore(*pair)
        except KinredundError as err:
            raise GeometryError(f"{where}: ignored pair {pair!r}: {err}") from err
    return scene


def _add(scene: Scene, entry, folder: Path, where: str) -> None:
    if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
        raise GeometryError(f"{where} must be an object with a 'name', got {entry!r}")
    where = f"{where} ({entry['name']!r})"
    shape = entry.get("shape")
    if shape not in SHAPES:
        raise GeometryError(f"{where}: unknown shape {shape!r}; allowed: {', '.join(SHAPES)}")
    keys = SHAPE_KEYS[shape]
    allowed = {"name", "shape", "pose", "attach_to", *keys}
    missing = [k for k in keys if k not in entry and k not in _OPTIONAL]
    if missing or set(entry) - allowed:
        raise GeometryError(f"{where}: a {shape} takes {', '.join(keys)} (and pose, attach_to); "
                            f"missing {missing}, unknown {sorted(set(entry) - allowed)}")
    try:
        _place(scene, shape, entry, folder)
    except KinredundError as err:  # a value the Scene refuses: named with the file and the object
        raise GeometryError(f"{where}: {err}") from err


def _place(scene: Scene, shape: str, entry: dict, folder: Path) -> None:
    pose, attach = entry.get("pose"), entry.get("attach_to")
    name = entry["name"]
    if shape == "box":
        scene.add_box(name, entry["size"], pose, attach_to=attach)
    elif shape == "sphere":
        scene.add_sphere(name, entry["radius"], pose, attach_to=attach)
    elif shape == "cylinder":
        scene.add_cylinder(name, entry["radius"], entry["length"], pose, attach_to=attach)
    elif shape == "capsule":
        scene.add_capsule(name, entry["radius"], entry["length"], pose, attach_to=attach)
    elif shape == "convex":
        scene.add_convex(name, entry["points"], pose, attach_to=attach)
    else:
        scene.add_mesh(name, folder / str(entry["file"]), pose, scale=entry.get("scale", 1.0),
                       convex=entry.get("convex"), attach_to=attach)
