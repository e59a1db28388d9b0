"""A scene's objects in a replay, and the closest pair marked at every frame (``replay_html(scene=...)``).

World objects are drawn once (translucent orange); objects attached to a robot frame and the two witness points
of the closest pair (red dots, at the pair's nearest points) move with the animation's keyframes. Meshes and
convex objects are drawn as triangle meshes (their hull for a convex object), primitives as meshcat's.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from kinredund.geometry.scene import Scene, SceneObject
from kinredund.ui.viz.scene import Frames

CELL_NODE = "cell"
CELL_COLOR = 0xE08A1F
CLOSEST_COLOR = 0xD0202A
#: meshcat's cylinders run along y; ours (coal's) along z
_Y_TO_Z = np.array([[1.0, 0, 0, 0], [0, 0, -1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])


def _triangles(obj: SceneObject) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    if obj.shape == "convex":
        hull = trimesh.convex.convex_hull(np.asarray(obj.params["points"], dtype=float))
        return np.asarray(hull.vertices), np.asarray(hull.faces)
    mesh = trimesh.load(obj.params["file"], force="mesh", process=False)
    if obj.params.get("convex", True):
        mesh = mesh.convex_hull
    return np.asarray(mesh.vertices) * np.asarray(obj.params.get("scale", 1.0), dtype=float), np.asarray(mesh.faces)


def _geometries(mc: SimpleNamespace, obj: SceneObject) -> list[tuple[object, np.ndarray]]:
    """(meshcat geometry, 4x4 transform in the object's frame) pieces drawing ``obj``."""
    g, p = mc.geometry, obj.params
    if obj.shape == "box":
        return [(g.Box(list(p["size"])), np.eye(4))]
    if obj.shape == "sphere":
        return [(g.Sphere(float(p["radius"])), np.eye(4))]
    if obj.shape in ("cylinder", "capsule"):
        pieces = [(g.Cylinder(float(p["length"]), float(p["radius"])), _Y_TO_Z)]
        if obj.shape == "capsule":
            for end in (-0.5, 0.5):
                pieces.append((g.Sphere(float(p["radius"])), mc.tf.translation_matrix([0, 0, end * p["length"]])))
        return pieces
    vertices, faces = _triangles(obj)
    return [(g.TriangularMeshGeometry(vertices, faces), np.eye(4))]


def draw_cell(vis, mc: SimpleNamespace, scene: Scene, frames: Frames, anim, keys: list[float]) -> None:
    """Draw ``scene``'s objects on ``vis`` and add their motion and the closest pair's witness points to
    ``anim`` at the keyframes ``keys`` (one per frame of ``frames``)."""
    material = mc.geometry.MeshLambertMaterial(color=CELL_COLOR, opacity=0.6, transparent=True)
    attached = []
    for name in scene.objects:
        obj = scene.object(name)
        node = vis[CELL_NODE][name]
        for k, (geom, local) in enumerate(_geometries(mc, obj)):
            node[str(k)].set_object(geom, material)
            node[str(k)].set_transform(local)
        if obj.attach_to is None:
            node.set_transform(obj.pose)
        else:
            attached.append(name)
    dot = mc.geometry.Sphere(0.01)
    red = mc.geometry.MeshLambertMaterial(color=CLOSEST_COLOR)
    for side in ("a", "b"):
        vis[CELL_NODE]["closest"][side].set_object(dot, red)
    for key, q in zip(keys, frames.q, strict=True):
        rec = scene.distances(q)
        with anim.at_frame(vis, key) as frame:
            for name in attached:
                frame[CELL_NODE][name].set_transform(scene.object_pose(name, q))
            if rec.closest is not None:
                k = rec.index(*rec.closest)
                frame[CELL_NODE]["closest"]["a"].set_transform(mc.tf.translation_matrix(rec.point_a[k]))
                frame[CELL_NODE]["closest"]["b"].set_transform(mc.tf.translation_matrix(rec.point_b[k]))
