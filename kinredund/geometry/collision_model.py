"""The robot's collision model: its URDF's collision elements (or capsules) as a Pinocchio ``GeometryModel``.

:func:`robot_geometry` reads the collision elements of the robot's URDF through
``pin.buildGeomFromUrdfString`` on the full (unreduced) model, with ``package_dirs`` the folder above
example-robot-data, and moves every object onto the robot's own (possibly reduced) model by its link's name:
an object's pose relative to its link is constant, and the link frames survive ``load_robot(joints=...)``
with the locked joints folded into their placements (what ``pin.buildReducedModel`` does with a geometry
model). Meshes become convex hulls for ``geometry="convex"`` (the default) or stay exact BVHs for
``"mesh"``; primitives (boxes, spheres, cylinders, capsules) are kept as they are.

A robot without collision elements (an HD-table robot such as the thesis's arms, or a URDF without
``<collision>``) gets one capsule per moving body, from its joint's origin to the next joint's (the last
one to the end-effector frame), radius ``capsule_radius`` [m].

This module and :mod:`kinredund.geometry.scene` are the geometry layer's Pinocchio callers (docs/architecture.md).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin

from kinredund.errors import GeometryError, check_choice
from kinredund.geometry.shapes import GEOMETRY_KINDS, as_kind, positive
from kinredund.model.robot import Robot
from kinredund.model.urdf import load_urdf

#: the default radius of the capsules given to a robot without collision elements [m]
CAPSULE_RADIUS = 0.05


@dataclass(frozen=True, eq=False)
class RobotGeometry:
    """The robot's collision objects on its own model.

    Attributes:
        model: a ``pin.GeometryModel`` on ``robot.model`` with the robot's objects and no pairs (a
            :class:`~kinredund.geometry.scene.Scene` copies it and adds its own objects and pairs).
        names: the objects' names, in the model's order.
        links: the link (URDF) or body (capsules) each object belongs to.
        parent_link: link -> its nearest ancestor link with collision geometry ("" for a root): the
            adjacency of the link tree, with links without geometry skipped (as MoveIt does).
        kind: ``"convex"`` or ``"mesh"`` (how meshes were taken).
        source: ``"urdf"`` (the file's collision elements) or ``"capsules"``.
        srdf: the SRDF file whose disabled pairs apply, or None.
    """

    model: pin.GeometryModel
    names: tuple[str, ...]
    links: tuple[str, ...]
    parent_link: dict
    kind: str
    source: str
    srdf: Path | None


def robot_geometry(robot: Robot, geometry: str = "convex", *, capsule_radius: float = CAPSULE_RADIUS,
                   collision_urdf=None, srdf=None) -> RobotGeometry:
    """The robot's collision model (module docstring).

    Args:
        robot: a loaded robot.
        geometry: ``"convex"`` (meshes as convex hulls, the default) or ``"mesh"`` (exact triangle meshes).
        capsule_radius: the capsules' radius [m] for a robot without collision elements.
        collision_urdf: another URDF file whose collision elements to use, with the same link names (e.g.
            example-robot-data's ``panda_collision.urdf``, spheres and cylinders); default the robot's own.
        srdf: an SRDF file whose ``disable_collisions`` apply; default example-robot-data's for its arms
            (``srdf/<urdf name>.srdf``, or the name before its first ``_``), none otherwise.

    Raises:
        ChoiceError: an unknown ``geometry``.
        GeometryError: a collision mesh is missing or unreadable, a bad radius, or a missing SRDF.
    """
    check_choice("geometry", geometry, GEOMETRY_KINDS)
    radius = positive(capsule_radius, "capsule radius [m]")
    path = Path(collision_urdf) if collision_urdf is not None else robot.urdf_path
    if srdf is not None and not Path(srdf).is_file():
        raise GeometryError(f"SRDF file {str(srdf)!r} does not exist")
    if path is not None:
        found = _from_urdf(robot, Path(path), geometry)
        if found is not None:
            return RobotGeometry(*found, geometry, "urdf", Path(srdf) if srdf else default_srdf(Path(path)))
    return RobotGeometry(*_capsules(robot, radius), geometry, "capsules", Path(srdf) if srdf else None)


def default_srdf(urdf: Path) -> Path | None:
    """example-robot-data's SRDF for a URDF: ``../srdf/<stem>.srdf``, else ``../srdf/<stem up to _>.srdf``."""
    folder = urdf.parent.parent / "srdf"
    for stem in (urdf.stem, urdf.stem.split("_")[0]):
        if (folder / f"{stem}.srdf").is_file():
            return folder / f"{stem}.srdf"
    return None


def _from_urdf(robot: Robot, path: Path, geometry: str):
    """(model, names, links, parent_link) from the URDF's collision elements, or None if it has none."""
    dirs = tuple(str(d) for d in robot.package_dirs) or (str(path.parent),)
    objects, parents = _urdf_objects(str(path), path.stat().st_mtime_ns, geometry, dirs)
    if not objects:
        return None
    model = robot.model
    gm, names, links = pin.GeometryModel(), [], []
    for name, link, on_link, shape in objects:
        if not model.existFrame(link, pin.FrameType.BODY):
            raise GeometryError(f"{str(path)!r}: link {link!r} of collision object {name!r} is not a link "
                                f"of robot {robot.name!r}")
        fid = model.getFrameId(link, pin.FrameType.BODY)
        frame = model.frames[fid]
        gm.addGeometryObject(pin.GeometryObject(name, frame.parentJoint, fid, frame.placement * on_link, shape))
        names.append(name)
        links.append(link)
    return gm, tuple(names), tuple(links), dict(parents)


@functools.lru_cache(maxsize=32)
def _urdf_objects(path: str, mtime_ns: int, geometry: str, package_dirs: tuple) -> tuple[tuple, tuple]:
    """((name, link, pose on the link, coal shape) per collision element, (link, parent link) pairs) of a URDF
    file, read once per file version and kind (meshes and hulls take seconds on some arms; shapes are shared
    between scenes and never modified)."""
    parsed = load_urdf(path)
    full = parsed.model
    try:
        gm0 = pin.buildGeomFromUrdfString(full, parsed.text, pin.GeometryType.COLLISION,
                                          package_dirs=list(package_dirs))
    except (ValueError, RuntimeError) as err:
        raise GeometryError(f"cannot read the collision geometry of {path!r}: {err}") from err
    objects = []
    for g in gm0.geometryObjects:
        if g.geometry is None:
            raise GeometryError(f"{path!r}: collision object {g.name!r} has no shape (missing mesh?)")
        link = full.frames[g.parentFrame]
        on_link = link.placement.inverse() * g.placement  # constant: the object and its link share a joint
        objects.append((g.name, link.name, on_link, as_kind(g.geometry, geometry)))
    has_geometry = {link for _, link, _, _ in objects}
    return tuple(objects), tuple(_link_parents(full, has_geometry).items())


def _link_parents(full: pin.Model, has_geometry: set) -> dict:
    """link -> nearest ancestor link with geometry, through the frames' parents (joint frames skipped)."""
    frames = full.frames
    out = {}
    for f in frames:
        if f.type != pin.FrameType.BODY or f.name not in has_geometry:
            continue
        k, parent = full.getFrameId(f.name, pin.FrameType.BODY), ""
        while True:
            joint_frame = frames[k].parentFrame
            k = frames[joint_frame].parentFrame
            if k == joint_frame or k == 0:  # the root
                break
            if frames[k].type == pin.FrameType.BODY and frames[k].name in has_geometry:
                parent = frames[k].name
                break
        out[f.name] = parent
    return out


def _capsules(robot: Robot, radius: float):
    """A capsule per moving body (and the base's segment to joint 1), along the segment to the next joint."""
    model = robot.model
    children = {j: [c for c in range(1, model.njoints) if model.parents[c] == j] for j in range(model.njoints)}
    ee = model.frames[robot.ee_frame_id]
    gm, names, links, parent = pin.GeometryModel(), [], [], {}
    for j in range(model.njoints):
        ends = [model.jointPlacements[c].translation for c in children[j]]
        if ee.parentJoint == j:
            ends.append(ee.placement.translation)
        body = "base" if j == 0 else model.names[j]
        for k, end in enumerate(ends):
            length = float(np.linalg.norm(end))
            if length < 1e-9:
                continue
            turn = pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), end / length).toRotationMatrix()
            name = f"{body}_capsule" + (f"_{k}" if len(ends) > 1 else "")
            gm.addGeometryObject(pin.GeometryObject(name, j, 0, pin.SE3(turn, 0.5 * end), coal.Capsule(radius, length)))
            names.append(name)
            links.append(body)
        if j > 0:
            up = model.parents[j]
            parent[body] = "base" if up == 0 else model.names[up]
    if not names:
        raise GeometryError(f"robot {robot.name!r} has no link of non-zero length to put a capsule on")
    return gm, tuple(names), tuple(links), _skip_empty(parent, set(links))


def _skip_empty(parent: dict, has_geometry: set) -> dict:
    """body -> nearest ancestor body that has a capsule ("" for none)."""
    out = {}
    for body in has_geometry:
        up = parent.get(body, "")
        while up and up not in has_geometry:
            up = parent.get(up, "")
        out[body] = up
    return out
