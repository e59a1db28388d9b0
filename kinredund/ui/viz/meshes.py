"""Compact robot meshes for playback: a mesh file read once, as binary triangles grouped by colour.

meshcat stores a Collada (``.dae``) visual as its XML text, base64-encoded into the page: the Panda's
ten visual meshes are 10.5 MB of text (14 MB in the page). The same surfaces as float32 vertices with
shared corners and 16-bit triangle indices take about a fifth of that. :func:`compact_mesh` reads a
mesh file with trimesh (a dependency of yourdfpy), applies the file's own scene graph, merges
coincident vertices and groups the triangles by material colour, so each group draws with one
material. Results are cached per file, so a mesh used twice (the Panda's two fingers) is read once.

No meshcat here: :mod:`kinredund.ui.viz._meshcat` turns the arrays into scene objects.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Mesh formats read here; anything else is left to Pinocchio's meshcat loader.
COMPACT_FORMATS = (".dae", ".stl", ".obj", ".ply")


@dataclass(frozen=True)
class MeshPart:
    """Triangles of one colour.

    Attributes:
        vertices: corner positions in the mesh file's frame, shape (V, 3) [m, before the URDF's scale].
        faces: vertex indices per triangle, shape (F, 3), uint16 when V <= 65536 else uint32.
        color: RGBA in [0, 1], shape (4,).
    """

    vertices: np.ndarray
    faces: np.ndarray
    color: np.ndarray


def _part(mesh, color: np.ndarray) -> MeshPart:
    vertices = np.asarray(mesh.vertices, dtype=np.float32)
    faces = np.asarray(mesh.faces)
    dtype = np.uint16 if len(vertices) <= np.iinfo(np.uint16).max + 1 else np.uint32
    return MeshPart(vertices, faces.astype(dtype), color)


def _color_of(mesh) -> np.ndarray:
    """The RGBA colour [0, 1] of a trimesh mesh: its material's main colour, or its face colours' mean."""
    visual = mesh.visual
    material = getattr(visual, "material", None)
    if material is not None and getattr(material, "main_color", None) is not None:
        return np.asarray(material.main_color, dtype=float) / 255.0
    colors = getattr(visual, "face_colors", None)
    if colors is not None and len(colors):
        return np.asarray(colors, dtype=float).mean(axis=0) / 255.0
    return np.array([0.8, 0.8, 0.8, 1.0])


@functools.lru_cache(maxsize=128)
def _compact_cached(path: str, mtime_ns: int) -> tuple[MeshPart, ...] | None:
    try:
        import trimesh
    except ImportError:
        return None
    try:
        scene = trimesh.load(path, force="scene")
        meshes = scene.dump(concatenate=False)
    except Exception:  # noqa: BLE001 - any unreadable file falls back to meshcat's own loader
        return None
    groups: dict[tuple, list] = {}
    for mesh in meshes:
        if not len(getattr(mesh, "faces", ())):
            continue
        color = _color_of(mesh)
        groups.setdefault(tuple(np.round(color, 3)), []).append(mesh)
    parts = []
    for color, items in groups.items():
        merged = trimesh.util.concatenate(items) if len(items) > 1 else items[0].copy()
        merged.merge_vertices(merge_tex=True, merge_norm=True)
        parts.append(_part(merged, np.array(color)))
    return tuple(parts) or None


def compact_mesh(path: str | Path) -> tuple[MeshPart, ...] | None:
    """The triangles of the mesh file ``path`` grouped by colour, or None when it cannot be read here.

    A file is read once per process (cached by path and modification time).
    """
    p = Path(path)
    if p.suffix.lower() not in COMPACT_FORMATS or not p.is_file():
        return None
    return _compact_cached(str(p.resolve()), p.stat().st_mtime_ns)
